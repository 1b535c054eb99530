"""Write horizon-nav flight logs (MCAP, ROS 2 messages in CDR): bulk numpy in, time-ordered file out.

Format: docs/log-format.md; definitions: ``scenarios.flightlog.format``.

Usage::

    with LogWriter("run.mcap", {"scenario": toml_text, "seed": 1, "liftoff_utc_ns": t0,
                                "kind": "simulated"}) as w:
        w.write_imu(t_ns, gyro, accel)           # (N,), (N, 3), (N, 3)
        w.write_gps(t_gps, x_e, v_e)
        w.advance(t_now)                          # optional: flush everything before t_now

Each ``write_*`` call may carry any time range in any order: messages are buffered and written in
``log_time`` order (ties in call order) when ``advance(t)`` promises that no message earlier than
``t`` will follow, and at ``close``. Writing a message earlier than an ``advance`` already passed
raises ValueError. Without ``advance`` everything is buffered until ``close``.

The file is written to a temporary file beside ``path`` and renamed on ``close``: an exception in
the ``with`` block leaves nothing at ``path`` unless ``partial_on_error=True``, which finalises a
valid log of what was written so far (metadata ``horizon-nav.status`` has ``complete = "false"``
and the reason); ``close(complete=False, reason=...)`` does the same explicitly (e.g. on Ctrl-C).
Message payloads are encoded with the vectorised codec ``scenarios.flightlog.format.Layout`` (checked
byte-for-byte against ``mcap_ros2``'s encoder in tests/test_log_format.py); ``tf2_msgs/TFMessage``
uses ``mcap_ros2``'s encoder. A batch of N messages of one layout becomes one ``(N, 31 + L)`` byte
matrix of complete MCAP Message records (``Layout.encode_groups`` with the record header in front);
batches are merged by ``log_time`` and cut into chunks by ``scenarios.flightlog._chunks.ChunkWriter``,
one compressor call per chunk: no per-message Python work, unlike ``mcap.writer.Writer.add_message``
(tests/benchmarks/test_bench_logs.py measures the write rate).
"""
from __future__ import annotations

import os
import tempfile
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import math

import numpy as np
from mcap_ros2._dynamic import serialize_dynamic

from . import format as lf
from ._chunks import MESSAGE_PREFIX, ChunkWriter, message_header, record_head, set_log_times

METADATA_NAME = "horizon-nav"
STATUS_NAME = "horizon-nav.status"
KINDS = ("simulated", "real", "solution")
REQUIRED_METADATA = ("scenario", "seed", "liftoff_utc_ns", "kind")
_COMPRESSION = {"zstd": "zstd", "lz4": "lz4", "none": ""}  # name -> MCAP chunk compression


def software_version() -> str:
    """Installed version of the ``horizon-nav`` distribution ("unknown" when not installed)."""
    try:
        return version("horizon-nav")
    except PackageNotFoundError:
        return "unknown"


def _times(t_ns, what: str) -> np.ndarray:
    t = np.asarray(t_ns)
    if t.ndim == 0:
        t = t.reshape(1)
    if t.ndim != 1 or not (np.issubdtype(t.dtype, np.integer)):
        raise ValueError(f"{what}: t_ns must be a 1-D array of int64 ns since the Unix epoch (got dtype "
                         f"{t.dtype}, shape {t.shape})")
    return t.astype(np.int64)


def _vec(x, n: int, k: int, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape == (k,) or a.shape == (1, k):
        a = np.broadcast_to(a.reshape(1, k), (n, k))
    if a.shape == (n,) and k == 1:
        a = a.reshape(n, 1)
    if a.shape != (n, k):
        raise ValueError(f"{what}: expected shape ({n}, {k}), got {np.shape(x)}")
    return a


def _cov(x, n: int, k: int, what: str) -> np.ndarray:
    """(k,k), (N,k,k) or (N,k*k) -> (N, k*k) row major; None -> zeros. One matrix for all comes
    back as a broadcast view (the codec writes it once)."""
    if x is None:
        return np.broadcast_to(np.zeros((1, k * k)), (n, k * k))
    a = np.asarray(x, dtype=np.float64)
    if a.shape in ((k, k), (k * k,)):
        return np.broadcast_to(a.reshape(1, k * k), (n, k * k))
    if a.shape in ((n, k, k), (n, k * k)):
        return a.reshape(n, k * k)
    raise ValueError(f"{what}: expected shape ({k}, {k}), ({n}, {k}, {k}) or ({n}, {k * k}), got {a.shape}")


def _scalar(x, n: int, what: str, dtype=np.float64) -> np.ndarray:
    a = np.asarray(x, dtype=dtype)
    if a.ndim == 0:
        return np.full(n, a, dtype=dtype)
    if a.shape != (n,):
        raise ValueError(f"{what}: expected a scalar or shape ({n},), got {a.shape}")
    return a


def _merge_records(batches: list, src: np.ndarray, off: np.ndarray, ln: np.ndarray) -> np.ndarray:
    """The records ``batches[src[i]]`` bytes ``off[i]:off[i] + ln[i]`` (each batch an (m, L) uint8
    matrix of records), i in order, back to back in one uint8 array.

    Consecutive records taken from one batch at consecutive offsets form a run copied as one slice,
    so the Python work is per run (at most one per record, far fewer when one topic dominates a
    time span). A numba gather would need a typed list of the batches, whose construction is
    compiled anew in every process.
    """
    n = len(src)
    if n == 0:
        return np.zeros(0, np.uint8)
    brk = np.flatnonzero((src[1:] != src[:-1]) | (off[1:] != off[:-1] + ln[:-1])) + 1
    first = np.concatenate([[0], brk])
    last = np.concatenate([brk, [n]]) - 1
    views = [memoryview(np.ascontiguousarray(b)).cast("B") for b in batches]
    data = b"".join([views[s][a:e] for s, a, e in zip(src[first].tolist(), off[first].tolist(),
                                                        (off[last] + ln[last]).tolist())])
    return np.frombuffer(data, np.uint8)


def _xyz(prefix: str, a: np.ndarray) -> dict:
    return {f"{prefix}.x": a[:, 0], f"{prefix}.y": a[:, 1], f"{prefix}.z": a[:, 2]}


def _strs(x, n: int, what: str):
    if isinstance(x, str):
        return x
    x = list(x)
    if len(x) != n:
        raise ValueError(f"{what}: expected one str or {n} str, got {len(x)}")
    return [str(s) for s in x]


class LogWriter:
    """Context manager that writes one horizon-nav MCAP log (see module docstring).

    Parameters
    ----------
    path : output file (``.mcap``); replaced atomically on close.
    metadata : dict with ``scenario`` (TOML text), ``seed``, ``liftoff_utc_ns``, ``kind``
        (``"simulated"``, ``"real"`` or ``"solution"``); more keys are kept. ``software_version`` is
        added. Written as the MCAP metadata record ``"horizon-nav"`` (all values as str).
    compression : ``"zstd"`` (default; see docs/log-format.md for the measurement), ``"lz4"``, ``"none"``.
    chunk_size : uncompressed bytes per MCAP chunk.
    partial_on_error : when True, an exception in the ``with`` block finalises a valid partial log
        instead of discarding it.
    """

    def __init__(self, path, metadata: dict, *, compression: str = "zstd", chunk_size: int = 1 << 20,
                 partial_on_error: bool = False):
        self.path = Path(path)
        missing = [k for k in REQUIRED_METADATA if k not in metadata]
        if missing:
            raise ValueError(f"log metadata: missing keys {missing} (required: {list(REQUIRED_METADATA)})")
        if str(metadata["kind"]) not in KINDS:
            raise ValueError(f"log metadata kind {metadata['kind']!r}: expected one of {KINDS}")
        if compression not in _COMPRESSION:
            raise ValueError(f"compression {compression!r}: expected one of {list(_COMPRESSION)}")
        self.metadata = {k: str(v) for k, v in metadata.items()}
        self.metadata.setdefault("software_version", software_version())
        self.partial_on_error = partial_on_error
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.name}.", suffix=".tmp")
        self._tmp = Path(tmp)
        self._file = os.fdopen(fd, "wb")
        self._writer = ChunkWriter(self._file, chunk_size=chunk_size, compression=_COMPRESSION[compression])
        self._writer.start(profile="ros2", library=f"horizon-nav/{self.metadata['software_version']}")
        self._writer.add_metadata(METADATA_NAME, self.metadata)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        # buffered batches in call order: (t (m,), channel id, records (m, 31 + L) uint8, t sorted?)
        self._pending: list[tuple[np.ndarray, int, np.ndarray, bool]] = []
        self._watermark = np.iinfo(np.int64).min
        self._names_written: set[str] = set()
        self._closed = False
        self.message_count = 0

    # ---------------- plumbing ----------------
    def _channel(self, topic: str, short: str) -> int:
        if topic not in self._channels:
            if short not in self._schemas:
                self._schemas[short] = self._writer.register_schema(
                    lf.ros2_name(short), "ros2msg", lf.schema_text(short).encode())
            self._channels[topic] = self._writer.register_channel(topic, "cdr", self._schemas[short])
        return self._channels[topic]

    def _put(self, topic: str, short: str, t: np.ndarray, values: dict) -> None:
        if self._closed:
            raise ValueError(f"{self.path}: log writer already closed")
        n = len(t)
        if n == 0:
            return
        if t.min() < self._watermark:
            raise ValueError(f"{topic}: message at t_ns={int(t.min())} is before advance({self._watermark}); "
                             "write each time range before advancing past it")
        cid = self._channel(topic, short)
        groups = lf.known_layout(short).encode_groups(values, n, prefix=MESSAGE_PREFIX, head=record_head(cid))
        for idx, rows in groups:
            ti = t if idx is None else t[idx]
            set_log_times(rows, ti)
            self._queue(ti, cid, rows)

    def _queue(self, t: np.ndarray, cid: int, rows: np.ndarray) -> None:
        """Buffer complete Message records ``rows`` of channel ``cid`` at times ``t``."""
        self._pending.append((t, cid, rows, bool(np.all(t[1:] >= t[:-1]))))

    def advance(self, t_ns: int) -> None:
        """Write every buffered message with time < ``t_ns``; later writes must be >= ``t_ns``."""
        self._flush(int(t_ns))
        self._watermark = max(self._watermark, int(t_ns))

    def _flush(self, before: int | None) -> None:
        """Hand the buffered messages with time < ``before`` (None: all) to the chunk writer in
        time order (ties in call order: a stable merge of the batches)."""
        if not self._pending:
            return
        take, keep = [], []
        for t, c, rows, srt in self._pending:
            if before is None:
                take.append((t, c, rows, srt))
                continue
            if srt:
                k = int(np.searchsorted(t, before, side="left"))
                lo, hi = (t[:k], c, rows[:k], True), (t[k:], c, rows[k:], True)
            else:
                m = t < before
                k = int(np.count_nonzero(m))
                lo, hi = (t[m], c, rows[m], False), (t[~m], c, rows[~m], False)
            if k == len(t):
                take.append((t, c, rows, srt))
            elif k == 0:
                keep.append((t, c, rows, srt))
            else:
                take.append(lo)
                keep.append(hi)
        self._pending = keep
        if not take:
            return
        if len(take) == 1:
            t, c, rows, srt = take[0]
            if not srt:
                order = np.argsort(t, kind="stable")
                t, rows = t[order], rows[order]
            n = len(t)
            self._writer.write_messages(t, np.full(n, c), np.full(n, rows.shape[1]),
                                        np.ascontiguousarray(rows).reshape(-1))
        else:  # merge: the batches' records joined in time order, then cut into chunks
            t = np.concatenate([p[0] for p in take])
            ch = np.concatenate([np.full(len(p[0]), p[1]) for p in take])
            ln = np.concatenate([np.full(len(p[0]), p[2].shape[1]) for p in take])
            src = np.concatenate([np.full(len(p[0]), i) for i, p in enumerate(take)])
            off = np.concatenate([np.arange(len(p[0])) * p[2].shape[1] for p in take])
            order = np.argsort(t, kind="stable")
            self._writer.write_messages(t[order], ch[order], ln[order],
                                        _merge_records([p[2] for p in take], src[order], off[order], ln[order]))
        self.message_count += sum(len(p[0]) for p in take)

    def add_metadata(self, name: str, values: dict) -> None:
        """A further MCAP metadata record ``name`` (values written as str), e.g. a result known
        only at the end of a run."""
        self._writer.add_metadata(name, {str(k): str(v) for k, v in values.items()})

    def close(self, complete: bool = True, reason: str = "") -> Path:
        """Flush, finish the MCAP file and rename it to ``path``. ``complete=False`` marks a partial
        log (status metadata) but still leaves a valid file. Returns the path."""
        if self._closed:
            return self.path
        self._flush(None)
        self._writer.add_metadata(STATUS_NAME, {"complete": "true" if complete else "false",
                                                "reason": str(reason), "message_count": str(self.message_count)})
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        # mkstemp makes the file private (0600); a finished log gets the usual umask permissions.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(self._tmp, 0o666 & ~umask)
        os.replace(self._tmp, self.path)
        self._closed = True
        return self.path

    def discard(self) -> None:
        """Abandon the log: close and delete the temporary file; nothing appears at ``path``."""
        if self._closed:
            return
        self._closed = True
        try:
            self._file.close()
        finally:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        elif self.partial_on_error:
            self.close(complete=False, reason=f"{exc_type.__name__}: {exc}")
        else:
            self.discard()
        return False

    def __del__(self):
        if not getattr(self, "_closed", True):
            self.discard()

    # ---------------- topics ----------------
    def write_imu(self, t_ns, gyro, accel, *, gyro_covariance=None, accel_covariance=None) -> None:
        """``sensor_msgs/Imu`` on ``/imu``: angular rate [rad/s] and specific force [m/s^2] in body.

        ``orientation_covariance[0] = -1`` (no orientation, REP-145); the rate/acceleration
        covariances are 0 (unknown) unless given as (3, 3) or (N, 3, 3).
        """
        t = _times(t_ns, lf.TOPIC_IMU)
        n = len(t)
        g = _vec(gyro, n, 3, "/imu gyro")
        a = _vec(accel, n, 3, "/imu accel")
        v = lf.header_values(t, lf.FRAME_BODY)
        v.update({"orientation.x": 0.0, "orientation.y": 0.0, "orientation.z": 0.0, "orientation.w": 1.0,
                  "orientation_covariance": np.r_[-1.0, np.zeros(8)],
                  "angular_velocity_covariance": _cov(gyro_covariance, n, 3, "/imu gyro_covariance"),
                  "linear_acceleration_covariance": _cov(accel_covariance, n, 3, "/imu accel_covariance")})
        v.update(_xyz("angular_velocity", g))
        v.update(_xyz("linear_acceleration", a))
        self._put(lf.TOPIC_IMU, "sensor_msgs/Imu", t, v)

    def write_imu_increment(self, t_ns, delta_angle, delta_velocity, dt) -> None:
        """``ImuIncrement`` on ``/imu_increment``: increments [rad], [m/s] over (t - dt, t]."""
        t = _times(t_ns, lf.TOPIC_IMU_INCREMENT)
        n = len(t)
        v = lf.header_values(t, lf.FRAME_BODY)
        v.update({"delta_angle": _vec(delta_angle, n, 3, "delta_angle"),
                  "delta_velocity": _vec(delta_velocity, n, 3, "delta_velocity"),
                  "dt": _scalar(dt, n, "dt")})
        self._put(lf.TOPIC_IMU_INCREMENT, f"{lf.PKG}/ImuIncrement", t, v)

    def write_gps(self, t_ns, position, velocity, position_covariance=None, velocity_covariance=None,
                  num_satellites=0, status=0) -> None:
        """``EcefFix`` on ``/gps``: ECEF position [m], velocity [m/s], 3x3 covariances."""
        t = _times(t_ns, lf.TOPIC_GPS)
        n = len(t)
        v = lf.header_values(t, lf.FRAME_EARTH)
        v.update({"position": _vec(position, n, 3, "/gps position"),
                  "velocity": _vec(velocity, n, 3, "/gps velocity"),
                  "position_covariance": _cov(position_covariance, n, 3, "/gps position_covariance"),
                  "velocity_covariance": _cov(velocity_covariance, n, 3, "/gps velocity_covariance"),
                  "num_satellites": _scalar(num_satellites, n, "num_satellites", np.uint16),
                  "status": _scalar(status, n, "status", np.int8)})
        self._put(lf.TOPIC_GPS, f"{lf.PKG}/EcefFix", t, v)

    def write_camera_info(self, k: int, t_ns, width: int, height: int, K, D=(), *,
                          distortion_model: str = "plumb_bob", R=None, P=None) -> None:
        """``sensor_msgs/CameraInfo`` on ``/camera_<k>/camera_info`` (one or more stamps).

        ``K`` (3, 3) intrinsics [px]; ``D`` distortion coefficients of ``distortion_model`` (ROS
        names: "plumb_bob", "rational_polynomial", "equidistant"); ``R`` defaults to I, ``P`` to [K | 0].
        """
        topic = lf.camera_topic(k, "camera_info")
        t = _times(t_ns, topic)
        n = len(t)
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
        R = np.eye(3) if R is None else np.asarray(R, dtype=np.float64).reshape(3, 3)
        P = np.hstack([K, np.zeros((3, 1))]) if P is None else np.asarray(P, dtype=np.float64).reshape(3, 4)
        D = np.asarray(D, dtype=np.float64).reshape(1, -1)
        v = lf.header_values(t, lf.camera_frame(k))
        v.update({"height": int(height), "width": int(width), "distortion_model": distortion_model,
                  "d": np.repeat(D, n, axis=0), "k": K.reshape(9), "r": R.reshape(9), "p": P.reshape(12),
                  "binning_x": 0, "binning_y": 0, "roi.x_offset": 0, "roi.y_offset": 0, "roi.height": 0,
                  "roi.width": 0, "roi.do_rectify": False})
        self._put(topic, "sensor_msgs/CameraInfo", t, v)

    def write_camera(self, k: int, t_ns, camera) -> None:
        """`write_camera_info` of a `vision.camera` model: its ROS distortion model and coefficients
        (`vision.camera.to_camera_info`: "equidistant" for a fisheye, "plumb_bob" or
        "rational_polynomial" for a pinhole)."""
        from vision.camera import to_camera_info

        info = to_camera_info(camera)
        self.write_camera_info(k, t_ns, camera.width, camera.height, info["K"], info["D"],
                               distortion_model=info["distortion_model"])

    def write_image(self, k: int, t_ns, jpeg, *, format: str = "jpeg") -> None:
        """``sensor_msgs/CompressedImage`` on ``/camera_<k>/image/compressed``: one bytes object
        with a scalar stamp, or a list of them with (N,) stamps."""
        topic = lf.camera_topic(k, "image/compressed")
        t = _times(t_ns, topic)
        imgs = [jpeg] if isinstance(jpeg, (bytes, bytearray, memoryview)) else list(jpeg)
        if len(imgs) != len(t):
            raise ValueError(f"{topic}: {len(t)} stamps but {len(imgs)} images")
        v = lf.header_values(t, lf.camera_frame(k))
        v.update({"format": format, "data": [np.frombuffer(bytes(b), np.uint8) for b in imgs]})
        self._put(topic, "sensor_msgs/CompressedImage", t, v)

    def write_payload_mask(self, k: int, t_ns: int, mask) -> None:
        """The payload mask of camera k (003 §3.1, fig. 9: the vehicle's structure at the image
        edge, ignored by the edge search) as one ``sensor_msgs/CompressedImage`` on
        ``/camera_<k>/payload_mask``: a PNG of the camera's size, 255 = payload (ignored), 0 = scene;
        ``format`` = ``"png; payload mask"``."""
        import cv2
        m = np.asarray(mask)
        if m.ndim != 2 or m.size == 0:
            raise ValueError(f"/camera_{k}/payload_mask: expected a (height, width) array, got shape {m.shape}")
        ok, png = cv2.imencode(".png", np.where(m > 0, 255, 0).astype(np.uint8))
        if not ok:
            raise ValueError(f"/camera_{k}/payload_mask: PNG encoding failed")
        topic = lf.camera_topic(k, "payload_mask")
        t = _times(np.array([t_ns], np.int64), topic)
        v = lf.header_values(t, lf.camera_frame(k))
        v.update({"format": "png; payload mask", "data": [png.reshape(-1)]})
        self._put(topic, "sensor_msgs/CompressedImage", t, v)

    def write_tf_static(self, t_ns: int, mounts: dict) -> None:
        """``tf2_msgs/TFMessage`` on ``/tf_static``: camera mounts, parent "body", child "camera_<k>".

        ``mounts``: {k: (translation_b [m] (3,), q_bc [x, y, z, w] (4,))}; ``q_bc`` maps camera-frame
        vectors into the body frame (the TF convention: the child's pose in the parent frame).
        """
        t = _times(t_ns, lf.TOPIC_TF_STATIC)
        if len(t) != 1:
            raise ValueError("/tf_static: expected one time stamp")
        if self._closed:
            raise ValueError(f"{self.path}: log writer already closed")
        if t[0] < self._watermark:
            raise ValueError(f"/tf_static: message at t_ns={int(t[0])} is before advance({self._watermark}); "
                             "write each time range before advancing past it")
        sec, nsec = lf.stamp_fields(t)
        transforms = []
        for k, (trans, q) in sorted(mounts.items()):
            trans = np.asarray(trans, dtype=np.float64).reshape(3)
            q = np.asarray(q, dtype=np.float64).reshape(4)
            transforms.append({
                "header": {"stamp": {"sec": int(sec[0]), "nanosec": int(nsec[0])}, "frame_id": lf.FRAME_BODY},
                "child_frame_id": lf.camera_frame(k),
                "transform": {"translation": dict(zip("xyz", map(float, trans))),
                              "rotation": dict(zip("xyzw", map(float, q)))}})
        short = "tf2_msgs/TFMessage"
        enc = serialize_dynamic(short, lf.schema_text(short))[short]
        payload = np.frombuffer(bytes(enc({"transforms": transforms})), np.uint8)
        rows = np.empty((1, MESSAGE_PREFIX + len(payload)), np.uint8)
        rows[0, MESSAGE_PREFIX:] = payload
        cid = self._channel(lf.TOPIC_TF_STATIC, short)
        message_header(rows, cid, t)
        self._queue(t, cid, rows)

    def write_vectors(self, k: int, t_ns, target, vector, covariance, covariance_overbound=None, *,
                      residual=0.0, pixel_count=0, inlier_count=0, conic_type="", alpha=0.0,
                      edge_sensitivity=None, edge_height=math.nan, edge_height_sigma=math.nan,
                      edge_height_arc=math.nan, edge_height_arc_sigma=math.nan) -> None:
        """``DirectionVector`` on ``/camera_<k>/vectors``: unit vectors in the camera frame.

        ``target`` and ``conic_type``: one str or N str; covariances (3, 3), (N, 3, 3) or (N, 9);
        ``covariance_overbound`` defaults to ``covariance``. Earth edge height (docs/log-format.md):
        ``edge_sensitivity`` (3,) or (N, 3) [1/m] (default NaN: none), ``edge_height*`` [m], one
        value or N.
        """
        topic = lf.camera_topic(k, "vectors")
        t = _times(t_ns, topic)
        n = len(t)
        tg = _strs(target, n, f"{topic} target")
        bad = {tg} - {"earth", "sun", "moon"} if isinstance(tg, str) else set(tg) - {"earth", "sun", "moon"}
        if bad:
            raise ValueError(f"{topic} target {sorted(bad)}: expected 'earth', 'sun' or 'moon'")
        cov = _cov(covariance, n, 3, f"{topic} covariance")
        v = lf.header_values(t, lf.camera_frame(k))
        v.update({"target": tg, "vector": _vec(vector, n, 3, f"{topic} vector"), "covariance": cov,
                  "covariance_overbound": cov if covariance_overbound is None
                  else _cov(covariance_overbound, n, 3, f"{topic} covariance_overbound"),
                  "residual": _scalar(residual, n, "residual"),
                  "pixel_count": _scalar(pixel_count, n, "pixel_count", np.uint32),
                  "inlier_count": _scalar(inlier_count, n, "inlier_count", np.uint32),
                  "conic_type": _strs(conic_type, n, f"{topic} conic_type"),
                  "alpha": _scalar(alpha, n, "alpha"),
                  "edge_sensitivity": _vec(np.full(3, np.nan) if edge_sensitivity is None else edge_sensitivity, n, 3,
                                           f"{topic} edge_sensitivity"),
                  "edge_height": _scalar(edge_height, n, "edge_height"),
                  "edge_height_sigma": _scalar(edge_height_sigma, n, "edge_height_sigma"),
                  "edge_height_arc": _scalar(edge_height_arc, n, "edge_height_arc"),
                  "edge_height_arc_sigma": _scalar(edge_height_arc_sigma, n, "edge_height_arc_sigma")})
        self._put(topic, f"{lf.PKG}/DirectionVector", t, v)

    def write_truth(self, t_ns, position_e, velocity_e, q_eb, angular_rate_b, specific_force_b) -> None:
        """``TruthState`` on ``/truth/state`` (q_eb scalar-last [x, y, z, w])."""
        t = _times(t_ns, lf.TOPIC_TRUTH)
        n = len(t)
        v = lf.header_values(t, lf.FRAME_EARTH)
        v.update({"position_e": _vec(position_e, n, 3, "position_e"),
                  "velocity_e": _vec(velocity_e, n, 3, "velocity_e"), "q_eb": _vec(q_eb, n, 4, "q_eb"),
                  "angular_rate_b": _vec(angular_rate_b, n, 3, "angular_rate_b"),
                  "specific_force_b": _vec(specific_force_b, n, 3, "specific_force_b")})
        self._put(lf.TOPIC_TRUTH, f"{lf.PKG}/TruthState", t, v)

    def write_camera_truth(self, k: int, t_ns, nadir_c, sun_c, moon_c, horizon_visible, conic_type,
                           sun_in_view, moon_in_view, earth_fraction, misalignment) -> None:
        """``CameraTruth`` on ``/camera_<k>/truth``."""
        topic = lf.camera_topic(k, "truth")
        t = _times(t_ns, topic)
        n = len(t)
        v = lf.header_values(t, lf.camera_frame(k))
        v.update({"nadir_c": _vec(nadir_c, n, 3, "nadir_c"), "sun_c": _vec(sun_c, n, 3, "sun_c"),
                  "moon_c": _vec(moon_c, n, 3, "moon_c"),
                  "horizon_visible": _scalar(horizon_visible, n, "horizon_visible", bool),
                  "conic_type": _strs(conic_type, n, f"{topic} conic_type"),
                  "sun_in_view": _scalar(sun_in_view, n, "sun_in_view", bool),
                  "moon_in_view": _scalar(moon_in_view, n, "moon_in_view", bool),
                  "earth_fraction": _scalar(earth_fraction, n, "earth_fraction"),
                  "misalignment": _vec(misalignment, n, 3, "misalignment")})
        self._put(topic, f"{lf.PKG}/CameraTruth", t, v)

    def write_nav(self, topic: str, t_ns, position_e, velocity_e, q_eb, covariance, *, state=None,
                  state_names=()) -> None:
        """``NavSolution`` on ``topic`` (one of ``logformat.NAV_TOPICS``).

        ``covariance`` (N, n, n) or (N, n*n); ``state`` (N, m) estimated parameters (default none);
        ``state_names`` (n names) go into the first message of the topic only.
        """
        if topic not in lf.NAV_TOPICS:
            raise ValueError(f"nav topic {topic!r}: expected one of {lf.NAV_TOPICS}")
        t = _times(t_ns, topic)
        n = len(t)
        cov = np.asarray(covariance, dtype=np.float64)
        if cov.ndim == 3:
            cov = cov.reshape(cov.shape[0], cov.shape[1] * cov.shape[2])
        if cov.ndim != 2 or cov.shape[0] != n:
            raise ValueError(f"{topic} covariance: expected (N, n, n) or (N, n*n) with N={n}, got {np.shape(covariance)}")
        st = np.zeros((n, 0)) if state is None else np.asarray(state, dtype=np.float64)
        if st.size != n * (st.size // max(n, 1)) or (n and st.shape[0] != n):
            raise ValueError(f"{topic} state: expected (N, m) with N={n}, got {np.shape(state)}")
        st = st.reshape(n, -1) if n else np.zeros((0, 0))
        names = [list(map(str, state_names)) if (i == 0 and topic not in self._names_written) else []
                 for i in range(n)]
        if state_names and n:
            self._names_written.add(topic)
        v = lf.header_values(t, lf.FRAME_EARTH)
        v.update({"position_e": _vec(position_e, n, 3, "position_e"),
                  "velocity_e": _vec(velocity_e, n, 3, "velocity_e"), "q_eb": _vec(q_eb, n, 4, "q_eb"),
                  "state": st, "covariance": cov, "state_names": names})
        self._put(topic, f"{lf.PKG}/NavSolution", t, v)

    def write_measurement(self, t_ns, source, used, reason, innovation, innovation_covariance, nis) -> None:
        """``MeasurementRecord`` on ``/nav/measurements``: innovations may differ in size per message
        (list of 1-D arrays) or share one (N, m) array; covariances flattened m x m."""
        t = _times(t_ns, lf.TOPIC_MEASUREMENTS)
        n = len(t)

        def seq(x, what):
            if isinstance(x, np.ndarray) and x.ndim >= 2 and x.shape[0] == n:
                return x.reshape(n, -1).astype(np.float64)
            if len(x) != n:
                raise ValueError(f"/nav/measurements {what}: expected {n} arrays, got {len(x)}")
            return [np.asarray(e, dtype=np.float64).reshape(-1) for e in x]

        v = lf.header_values(t, lf.FRAME_EARTH)
        v.update({"source": _strs(source, n, "/nav/measurements source"),
                  "used": _scalar(used, n, "used", bool), "reason": _strs(reason, n, "/nav/measurements reason"),
                  "innovation": seq(innovation, "innovation"),
                  "innovation_covariance": seq(innovation_covariance, "innovation_covariance"),
                  "nis": _scalar(nis, n, "nis")})
        self._put(lf.TOPIC_MEASUREMENTS, f"{lf.PKG}/MeasurementRecord", t, v)
