"""Camera footage -> time-stamped JPEG frames: video files (OpenCV) and image folders.

Time stamps (``mapping.FootageSpec``), one per frame, UTC ns:

* ``timestamps``: a CSV / Parquet table with one row per frame -- for an image folder a
  ``file_column`` naming the image file, for a video rows in frame order or a ``frame_column``
  (0-based frame index);
* ``filename_regex`` (image folders): one regex group of each file name holds the stamp, read with
  ``filename_time`` (a time base and unit, as the table time columns);
* ``start_utc`` / ``start_s`` and ``rate_hz``: frame i at ``start + i / rate`` (files in name order;
  for a video the rate defaults to the container's frame rate).

Frames are delivered in time order (``Footage.frames()``, a generator: a long video is never held
in memory). JPEG files are passed through byte for byte (after a structural check: SOI, frame
header with the camera's size, scan, EOI after the scan, and -- with ``verify`` -- a reduced-size
decode); other images and video frames are encoded as JPEG with ``jpeg_quality``. Errors name the
file and the frame: a frame of the wrong size, a corrupted or truncated frame, a video shorter than
its declared duration / frame count / time stamp list.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav.timescales import format_utc
from scenarios.errors import UserError

from .mapping import FootageSpec
from .tables import RawTable, order_rows, read_table, times_ns

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm")
_SOF = set(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def jpeg_structure(b: bytes) -> tuple[int, int, int] | None:
    """(width, height, offset of the first scan) of a JPEG, or None when the markers are broken."""
    if b[:2] != b"\xff\xd8":
        return None
    i, n, size = 2, len(b), None
    while i + 4 <= n:
        if b[i] != 0xFF:
            return None
        m = b[i + 1]
        if m == 0xFF:
            i += 1
            continue
        if m == 0x01 or 0xD0 <= m <= 0xD8:
            i += 2
            continue
        seg = int.from_bytes(b[i + 2:i + 4], "big")
        if m in _SOF and i + 9 <= n:
            size = (int.from_bytes(b[i + 7:i + 9], "big"), int.from_bytes(b[i + 5:i + 7], "big"))
        if m == 0xDA:
            return None if size is None else (size[0], size[1], i)
        i += 2 + seg
    return None


def check_jpeg(b: bytes, width: int, height: int, what: str, decode: bool) -> None:
    """UserError naming ``what`` unless ``b`` is a complete JPEG of width x height."""
    st = jpeg_structure(b)
    if st is None:
        raise UserError(f"{what}: corrupted JPEG (broken marker structure or no frame header / scan)")
    if (st[0], st[1]) != (width, height):
        raise UserError(f"{what}: image is {st[0]}x{st[1]} px but the camera file says {width}x{height}")
    if b.rfind(b"\xff\xd9") < st[2]:
        raise UserError(f"{what}: truncated JPEG (no end-of-image marker after the scan)")
    if decode:
        import cv2
        if cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_REDUCED_GRAYSCALE_8) is None:
            raise UserError(f"{what}: corrupted JPEG (cannot be decoded)")


def encode_jpeg(img: np.ndarray, quality: int, what: str, bits: int | None = None) -> tuple[bytes, int]:
    """(JPEG bytes, the source's significant bits) of a frame; 16-bit frames scaled to 8 bits by
    ``bits``, or by their own largest value when None (`scenarios.flightlog.jpeg.to_8bit`)."""
    import cv2

    from scenarios.flightlog.jpeg import to_8bit

    try:
        img, depth = to_8bit(img, what, bits)
    except ValueError as exc:
        raise UserError(f"{exc}: check the footage's 'bit_depth'" if bits else str(exc)) from None
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    ok, buf = cv2.imencode(".jpg", img, [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)])
    if not ok:
        raise UserError(f"{what}: JPEG encoding failed")
    return buf.tobytes(), depth


@dataclass
class Footage:
    """One camera's footage: ``t_ns`` (N,) stamps in time order, ``items`` (N,) files (images) or
    frame indices (video); counters filled while ``frames()`` runs."""
    spec: FootageSpec
    k: int
    width: int
    height: int
    t_ns: np.ndarray
    items: list
    declared: str = ""  # why N frames are expected (video)
    notes: list[str] = field(default_factory=list)
    passed_through: int = 0
    encoded: int = 0
    depths: dict = field(default_factory=dict)  # significant bits -> count of 16-bit frames scaled by them

    def _encode(self, img: np.ndarray, what: str) -> bytes:
        b, bits = encode_jpeg(img, self.spec.jpeg_quality, what, self.spec.bit_depth)
        self.encoded += 1
        if bits > 8:
            self.depths[bits] = self.depths.get(bits, 0) + 1
        return b

    def depth_note(self) -> tuple[str, str] | None:
        """(level, message) on how 16-bit frames were scaled, None without any: a warning when
        frames were scaled by different depths (their brightness then differs by the ratio)."""
        if not self.depths:
            return None
        said = ", ".join(f"{b} bits on {n}" for b, n in sorted(self.depths.items()))
        if self.spec.bit_depth is not None:
            return "info", f"16-bit frames scaled as {self.spec.bit_depth}-bit data (bit_depth): {said}"
        if len(self.depths) == 1:
            return "info", f"16-bit frames scaled by their largest values: {said}"
        top = max(self.depths)
        return "warning", (f"16-bit frames scaled by their own largest values, unevenly: {said} (a frame "
                           f"read as fewer bits is brightened); give the camera's depth, e.g. bit_depth = "
                           f"{top}, in the footage to scale them alike")

    @property
    def what(self) -> str:
        return f"camera {self.k} footage {self.spec.path}"

    def frames(self):
        """Yield ``(t_ns, jpeg_bytes)`` in time order; UserError on a bad frame."""
        if self.spec.kind == "images":
            yield from self._image_frames()
        else:
            yield from self._video_frames()

    def _image_frames(self):
        import cv2
        for t, f in zip(self.t_ns.tolist(), self.items):
            what = f"{f} (camera {self.k}, {format_utc(t)})"
            try:
                b = f.read_bytes()
            except OSError as exc:
                raise UserError(f"{what}: cannot read ({exc.strerror})") from None
            if f.suffix.lower() in (".jpg", ".jpeg") and b[:2] == b"\xff\xd8":
                check_jpeg(b, self.width, self.height, what, self.spec.verify)
                self.passed_through += 1
                yield t, b
                continue
            img = cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise UserError(f"{what}: corrupted or unsupported image (cannot be decoded)")
            if img.shape[:2] != (self.height, self.width):
                raise UserError(f"{what}: image is {img.shape[1]}x{img.shape[0]} px but the camera file says "
                                f"{self.width}x{self.height}")
            yield t, self._encode(img, what)

    def _video_frames(self):
        import cv2
        cap = cv2.VideoCapture(str(self.spec.path))
        if not cap.isOpened():
            raise UserError(f"{self.spec.path}: cannot open video (camera {self.k})")
        try:
            want = dict(zip(self.items, self.t_ns.tolist()))
            last = max(self.items) if self.items else -1
            i = 0
            while i <= last:
                ok, img = cap.read()
                if not ok or img is None:
                    raise UserError(
                        f"{self.spec.path}: video ends or cannot be decoded at frame {i} (camera {self.k}); "
                        f"{self.declared} ({last + 1} frames, up to {format_utc(want[last])}): the video is "
                        f"shorter than declared or frame {i} is corrupted")
                if i in want:
                    what = f"{self.spec.path} frame {i} (camera {self.k}, {format_utc(want[i])})"
                    if img.shape[:2] != (self.height, self.width):
                        raise UserError(f"{what}: frame is {img.shape[1]}x{img.shape[0]} px but the camera "
                                        f"file says {self.width}x{self.height}")
                    yield want[i], self._encode(img, what)
                i += 1
        finally:
            cap.release()


def _video_props(path: Path, k: int) -> tuple[int, float]:
    import cv2
    if not path.exists():
        raise UserError(f"{path}: video file not found (camera {k})")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise UserError(f"{path}: cannot open video (camera {k}); is it a video format FFmpeg reads?")
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    fps = float(cap.get(cv2.CAP_PROP_FPS))
    cap.release()
    return n, fps


def _image_files(spec: FootageSpec, k: int) -> list[Path]:
    if not spec.path.is_dir():
        raise UserError(f"{spec.path}: image folder not found (camera {k})")
    files = sorted(p for p in spec.path.glob(spec.pattern) if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
    if not files:
        raise UserError(f"{spec.path}: no image files matching {spec.pattern!r} (camera {k}); expected "
                        f"one of {IMAGE_EXTENSIONS}")
    return files


def _regex_times(spec: FootageSpec, files: list[Path], liftoff_ns: int) -> tuple[np.ndarray, list[Path], int]:
    import pyarrow as pa
    rx = re.compile(spec.filename_regex)
    vals, kept = [], []
    for f in files:
        m = rx.search(f.name)
        if m:
            vals.append(m.group(1))
            kept.append(f)
    if not kept:
        raise UserError(f"{spec.path}: no file name matches filename_regex {spec.filename_regex!r}")
    if spec.filename_time.base == "iso":
        arr = pa.array(vals)
    elif all(re.fullmatch(r"-?\d+", v) for v in vals):
        arr = pa.array([int(v) for v in vals], pa.int64())
    else:
        try:
            arr = pa.array([float(v) for v in vals], pa.float64())
        except ValueError as exc:
            raise UserError(f"{spec.path}: filename_regex {spec.filename_regex!r} captured a non-number ({exc})") from None
    raw = RawTable(spec.path, "names", {spec.filename_time.column: pa.chunked_array([arr])}, len(vals))
    return times_ns(raw, spec.filename_time, liftoff_ns), kept, len(files) - len(kept)


def plan_footage(spec: FootageSpec, k: int, width: int, height: int, liftoff_ns: int) -> Footage:
    """Find the frames of one camera's footage and their stamps (nothing decoded yet)."""
    notes: list[str] = []
    declared = ""
    if spec.kind == "images":
        files = _image_files(spec, k)
        if spec.timestamps is not None:
            ts = spec.timestamps
            raw = read_table(ts, [ts.time.column, spec.file_column] + ([ts.time.week_column] if ts.time.week_column else []),
                             text_columns=[spec.file_column, ts.time.column],
                             what=f"camera {k} time stamps")
            t = times_ns(raw, ts.time, liftoff_ns)
            names = raw.columns[spec.file_column].to_pylist()
            by_name = {f.name: f for f in files}
            items = []
            for i, nm in enumerate(names):
                f = by_name.get(Path(str(nm)).name)
                if f is None:
                    raise UserError(f"{ts.file}: {raw.row(i)}: image {nm!r} not found in {spec.path}")
                items.append(f)
            if len(files) > len(set(items)):
                notes.append(f"{len(files) - len(set(items))} image(s) in {spec.path} have no time stamp (skipped)")
            idx, info = order_rows(raw, t, ts.unsorted, f"camera {k} time stamps")
            if idx is not None:
                t, items = t[idx], [items[i] for i in idx]
                notes.append(f"time stamps sorted ({info.out_of_order} out of order, {info.duplicates} duplicates dropped)")
        elif spec.filename_regex is not None:
            t, items, skipped = _regex_times(spec, files, liftoff_ns)
            if skipped:
                notes.append(f"{skipped} image(s) whose names do not match the regex (skipped)")
            order = np.argsort(t, kind="stable")
            t, items = t[order], [items[i] for i in order]
            dup = np.flatnonzero(np.diff(t) == 0)
            if len(dup):
                raise UserError(f"{spec.path}: images {items[dup[0]].name!r} and {items[dup[0] + 1].name!r} have the "
                                f"same time stamp {format_utc(int(t[dup[0]]), 6)}")
        else:
            items = files
            t = spec.start_ns + np.round(np.arange(len(files)) * (1e9 / spec.rate_hz)).astype(np.int64)
        if spec.frames is not None and len(items) < spec.frames:
            raise UserError(f"{spec.path}: {len(items)} time-stamped images but frames = {spec.frames} declared (camera {k})")
        if spec.duration_s is not None and len(t) and (t[-1] - t[0]) / 1e9 < spec.duration_s - 1.5 * _step(t):
            raise UserError(f"{spec.path}: images span {(t[-1] - t[0]) / 1e9:.3f} s but duration_s = "
                            f"{spec.duration_s} declared (camera {k})")
        return Footage(spec, k, width, height, np.asarray(t, np.int64), items, notes=notes)

    # video
    n_container, fps = _video_props(spec.path, k)
    if spec.timestamps is not None:
        ts = spec.timestamps
        cols = [ts.time.column] + ([spec.frame_column] if spec.frame_column else []) + (
            [ts.time.week_column] if ts.time.week_column else [])
        raw = read_table(ts, cols, text_columns=[ts.time.column],
                         what=f"camera {k} time stamps")
        t = times_ns(raw, ts.time, liftoff_ns)
        if spec.frame_column:
            fr = raw.columns[spec.frame_column].to_numpy()
            if fr.dtype.kind not in "iu" or np.any(fr < 0):
                raise UserError(f"{ts.file}: column {spec.frame_column!r}: expected non-negative integer frame indices")
            items = fr.astype(np.int64)
        else:
            items = np.arange(len(t))
        idx, info = order_rows(raw, t, ts.unsorted, f"camera {k} time stamps")
        if idx is not None:
            t, items = t[idx], items[idx]
        if np.any(np.diff(items) <= 0):
            raise UserError(f"{ts.file}: frame indices in column {spec.frame_column!r} must increase with time "
                            "(each frame once, in time order)")
        declared = f"{ts.file} lists time stamps"
        items = items.tolist()
    else:
        rate = spec.rate_hz or fps
        if not rate or not math.isfinite(rate) or rate <= 0:
            raise UserError(f"{spec.path}: the video has no frame rate; set rate_hz (camera {k})")
        if spec.frames is not None:
            n, declared = spec.frames, f"the mapping declares frames = {spec.frames}"
        elif spec.duration_s is not None:
            n = int(round(spec.duration_s * rate))
            declared = f"the mapping declares duration_s = {spec.duration_s} at {rate:g} Hz"
        else:
            n, declared = n_container, "the container declares its frame count"
        if n <= 0:
            raise UserError(f"{spec.path}: no frames (camera {k}); set frames or duration_s")
        items = list(range(n))
        t = spec.start_ns + np.round(np.arange(n) * (1e9 / rate)).astype(np.int64)
    if n_container > 0 and max(items) >= n_container:
        raise UserError(f"{spec.path}: the video has {n_container} frames but {declared} ({max(items) + 1} frames): "
                        f"the video is shorter than declared (camera {k})")
    if n_container > max(items) + 1:
        notes.append(f"{n_container - max(items) - 1} video frame(s) after the last time stamp (skipped)")
    return Footage(spec, k, width, height, np.asarray(t, np.int64), list(items), declared, notes)


def _step(t: np.ndarray) -> float:
    return float(np.median(np.diff(t))) / 1e9 if len(t) > 1 else 0.0
