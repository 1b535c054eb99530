"""Read horizon-nav flight logs (MCAP, ROS 2 / CDR) into numpy arrays, fast and defensively.

``read_log(path) -> FlightLog``: every topic as a ``Series`` of arrays (``log.imu.t_ns``,
``log.imu.gyro``, ...), images on demand, the metadata and the list of topics. Format:
docs/log-format.md.

Fast path: the file is scanned record by record by a numba kernel (``scenarios.flightlog._scan``), chunks
are decompressed one at a time, the payloads of each channel are gathered into a byte matrix and
decoded column-wise with the vectorised CDR codec ``scenarios.flightlog.format.Layout``. Any ROS 2 schema
without nested-message sequences takes this path (for foreign schemas of the same name the fields are
decoded as the schema says); ``tf2_msgs/TFMessage`` and other schemas go through the reference
decoder of ``mcap_ros2`` (``log.tf_static``, ``log.other``).

Problems in the file are reported with ``warnings.warn(..., LogWarning)`` and collected in
``log.issues``; the reader goes on with what it can read:

* truncated file / damaged chunk: every complete message before the damage is kept; the warning names
  the file and the last good time;
* unknown schema (not ROS 2 or not decodable): warning naming the topic; the topic is skipped;
* stamps out of order on a topic: sorted (stable) by time, warning with the first offending time;
  duplicate stamps on a topic: the first message kept, the others dropped, warning with the first time
  (except vectors and measurement records, where one stamp may carry several messages);
* NaN in a float field: kept, warning naming the topic, the first time and the count;
* header.stamp different from the MCAP log_time: warning (log_time is used).

A file that is not MCAP at all (or unreadable) raises ``LogFormatError`` (a ``UserError``) naming it.
"""
from __future__ import annotations

import os
import struct
import warnings
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from . import format as lf
from ._scan import OP_MESSAGE, MESSAGE_HEADER, gather_rows, scan_records
from ..errors import UserError

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_CHUNK, OP_METADATA, OP_DATA_END = 1, 2, 3, 4, 6, 12, 15
IMAGE_TYPE = "sensor_msgs/CompressedImage"


class LogWarning(UserWarning):
    """A problem in a log file that the reader worked around (see module docstring)."""


class LogFormatError(UserError):
    """The file cannot be read as an MCAP log at all."""


def format_time(t_ns: int) -> str:
    """int ns since the Unix epoch -> ``2019-06-13T02:21:00.050000000Z`` (for messages)."""
    t_ns = int(t_ns)
    s, ns = divmod(t_ns, 1_000_000_000)
    try:
        return datetime.fromtimestamp(s, timezone.utc).strftime("%Y-%m-%dT%H:%M:%S") + f".{ns:09d}Z"
    except (OverflowError, OSError, ValueError):
        return f"{t_ns} ns"


# --------------------------------------------------------------------------------------------
# Result types
# --------------------------------------------------------------------------------------------
class Series:
    """Messages of one topic as arrays: ``t_ns`` (N,) int64 (log_time = header.stamp, sorted) and one
    attribute per field (see docs/log-format.md, "Reader API", for the names and shapes)."""

    def __init__(self, topic: str, schema: str, t_ns: np.ndarray, fields: dict):
        self.topic = topic
        self.schema = schema
        self.t_ns = t_ns
        self.fields = fields

    def __getattr__(self, name):
        fields = self.__dict__.get("fields", {})
        if name in fields:
            return fields[name]
        raise AttributeError(f"topic {self.__dict__.get('topic')} has no field {name!r} "
                             f"(fields: {sorted(fields)})")

    def __len__(self) -> int:
        return len(self.t_ns)

    def __repr__(self) -> str:
        return f"Series({self.topic!r}, {self.schema}, n={len(self)}, fields={sorted(self.fields)})"


class ImageStream:
    """Compressed images of one camera, read on demand: ``t_ns`` (N,), ``len()``, ``stream[i]`` ->
    JPEG bytes (``format[i]`` the ROS ``format`` string)."""

    def __init__(self, topic: str, reader: "_Reader", t_ns, locations):
        self.topic = topic
        self.t_ns = t_ns
        self._reader = reader
        self._loc = locations  # (N, 3) int64: segment, offset, length
        self._format: list[str] | None = None

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def sizes(self) -> np.ndarray:
        """(N,) bytes of each image message (the JPEG plus a few dozen bytes of header), known
        without reading the images."""
        return np.asarray(self._loc[:, 2], np.int64)

    def _decode(self, i):
        seg, off, ln = (int(x) for x in self._loc[i])
        buf = self._reader.segment(seg)
        row = np.frombuffer(buf, np.uint8, count=ln, offset=off).reshape(1, ln)
        vals, ok = lf.known_layout(IMAGE_TYPE).decode(row, np.array([ln]))
        if not ok[0]:
            raise LogFormatError(f"{self._reader.path}: {self.topic} message {i} is damaged")
        return vals

    def __getitem__(self, i: int) -> bytes:
        return self.view(i).tobytes()

    def view(self, i: int) -> np.ndarray:
        """The JPEG bytes of image ``i`` as a read-only uint8 array viewing the log's decompressed
        chunk (no copy; it keeps that chunk alive): for copying many images into one buffer."""
        seg, off, ln = (int(x) for x in self._loc[i])
        buf = self._reader.segment(seg)
        span = _compressed_image_span(buf, off, ln)
        if span is None:
            # anything the direct parse does not accept goes through the general decoder, which
            # raises for a damaged message
            return np.asarray(self._decode(i)["data"][0], np.uint8)
        return np.frombuffer(buf, np.uint8, count=span[1], offset=span[0])

    def format(self, i: int) -> str:
        return str(self._decode(i)["format"][0])

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]


@dataclass
class Transform:
    """A static transform: child frame pose in the parent frame; ``q`` maps child vectors into the
    parent ([x, y, z, w]), ``translation`` the child origin in the parent [m]."""
    parent: str
    child: str
    translation: np.ndarray
    q: np.ndarray
    t_ns: int


@dataclass
class CameraLog:
    """Topics of camera k: ``info`` (CameraInfo Series), ``vectors``, ``truth``, ``images``."""
    k: int
    info: Series | None = None
    vectors: Series | None = None
    truth: Series | None = None
    images: ImageStream | None = None


@dataclass
class TopicInfo:
    topic: str
    schema: str
    message_encoding: str
    message_count: int


@dataclass
class FlightLog:
    """Everything read from one log. ``series`` maps topic -> Series; the properties name the
    horizon-nav topics (None when absent)."""
    path: Path
    metadata: dict[str, dict[str, str]]
    topics: dict[str, TopicInfo]
    series: dict[str, Series] = field(default_factory=dict)
    images: dict[int, ImageStream] = field(default_factory=dict)
    tf_static: dict[str, Transform] = field(default_factory=dict)
    other: dict[str, tuple[np.ndarray, list]] = field(default_factory=dict)
    issues: list[str] = field(default_factory=list)

    @property
    def info(self) -> dict[str, str]:
        """The ``horizon-nav`` metadata record (scenario, seed, software_version, liftoff_utc_ns, kind)."""
        return self.metadata.get("horizon-nav", {})

    @property
    def complete(self) -> bool | None:
        """True for a log closed normally, False for a finalised partial log, None when the status
        record is missing (truncated file or another writer)."""
        st = self.metadata.get("horizon-nav.status")
        return None if st is None else st.get("complete") == "true"

    imu = property(lambda self: self.series.get(lf.TOPIC_IMU))
    imu_increment = property(lambda self: self.series.get(lf.TOPIC_IMU_INCREMENT))
    gps = property(lambda self: self.series.get(lf.TOPIC_GPS))
    truth = property(lambda self: self.series.get(lf.TOPIC_TRUTH))
    measurements = property(lambda self: self.series.get(lf.TOPIC_MEASUREMENTS))

    @property
    def nav(self) -> dict[str, Series]:
        """{"forward"|"smoothed"|"ins_unaided": Series} for the NavSolution topics present."""
        return {t.rsplit("/", 1)[1]: self.series[t] for t in lf.NAV_TOPICS if t in self.series}

    @property
    def cameras(self) -> dict[int, CameraLog]:
        out: dict[int, CameraLog] = {}
        for topic, s in self.series.items():
            cam = lf.parse_camera_topic(topic)
            if cam:
                c = out.setdefault(cam[0], CameraLog(cam[0]))
                setattr(c, {"camera_info": "info", "vectors": "vectors", "truth": "truth"}[cam[1]], s)
        for k, im in self.images.items():
            out.setdefault(k, CameraLog(k)).images = im
        return dict(sorted(out.items()))


# --------------------------------------------------------------------------------------------
# Record parsing helpers
# --------------------------------------------------------------------------------------------
def _compressed_image_span(buf, off: int, ln: int) -> tuple[int, int] | None:
    """``(start, length)`` in ``buf`` of the ``data`` bytes of one little-endian CDR
    ``sensor_msgs/CompressedImage`` message at ``buf[off:off + ln]``, or None when it does not
    parse as one. The same bytes as the general decoder (:meth:`ImageStream._decode`,
    tests/test_log_format.py), read directly: that decoder works on message matrices, and its set-up cost for a single
    message would be paid once per frame in the vision workers and again for the recording.

    Layout after the 4-byte encapsulation header (0, 1, options), each 4-byte length aligned to 4
    from there: ``stamp`` (int32 sec, uint32 nanosec), ``frame_id`` (length incl. NUL, bytes),
    ``format`` (likewise), ``data`` (length, bytes)."""
    if ln < 24 or buf[off] != 0 or buf[off + 1] != 1:
        return None
    base, end = off + 4, off + ln
    p = 8                                    # after the stamp
    for _ in range(2):                       # frame_id, format
        p = (p + 3) & ~3
        if base + p + 4 > end:
            return None
        p += 4 + struct.unpack_from("<I", buf, base + p)[0]
    p = (p + 3) & ~3
    if base + p + 4 > end:
        return None
    n = struct.unpack_from("<I", buf, base + p)[0]
    start = base + p + 4
    if start + n > end:
        return None
    return start, n


class _Body:
    """Sequential little-endian reader of one record body (raises struct.error/ValueError when short)."""

    def __init__(self, data: bytes):
        self.d = data
        self.p = 0

    def _take(self, n):
        if self.p + n > len(self.d):
            raise ValueError("record too short")
        b = self.d[self.p:self.p + n]
        self.p += n
        return b

    def u16(self):
        return struct.unpack("<H", self._take(2))[0]

    def u32(self):
        return struct.unpack("<I", self._take(4))[0]

    def u64(self):
        return struct.unpack("<Q", self._take(8))[0]

    def string(self):
        return bytes(self._take(self.u32())).decode("utf-8", "replace")

    def bytes_(self, n):
        return bytes(self._take(n))

    def str_map(self):
        end = self.u32() + self.p
        out = {}
        while self.p < end:
            k = self.string()
            out[k] = self.string()
        return out


class _Reader:
    def __init__(self, path: Path, data: bytes):
        self.path = path
        self.data = data
        self.chunks: list[tuple[int, int, str, int]] = []  # (records offset, length, compression, size)
        self._cache: tuple[int, bytes] | None = None
        self.issues: list[str] = []

    def __getstate__(self):
        """Pickled as the file's path, size and digest of its first MiB with the chunk table (the
        image streams sent to another process): the receiver maps the file again."""
        return {"path": self.path, "chunks": self.chunks, "issues": self.issues,
                "identity": _identity(self.data)}

    def __setstate__(self, st):
        self.path, self.chunks, self.issues = st["path"], st["chunks"], st["issues"]
        self._cache = None
        try:
            self.data = _map(self.path)
        except OSError as e:
            raise LogFormatError(f"{self.path}: cannot read log ({e.strerror or e})") from None
        if _identity(self.data) != st["identity"]:
            raise LogFormatError(f"{self.path}: the log changed while it was being read")

    def warn(self, msg: str) -> None:
        self.issues.append(msg)
        warnings.warn(msg, LogWarning, stacklevel=4)

    def decompress(self, i: int) -> bytes:
        off, ln, comp, size = self.chunks[i]
        raw = memoryview(self.data)[off:off + ln]    # the decompressors read the map itself: no copy
        if comp == "":
            return bytes(raw)
        if comp == "zstd":
            import zstandard
            return zstandard.ZstdDecompressor().decompress(raw, max_output_size=size)
        if comp == "lz4":
            import lz4.frame
            return lz4.frame.decompress(raw)
        raise ValueError(f"unsupported chunk compression {comp!r}")

    def segment(self, seg: int) -> bytes:
        """Segment -1 is the file itself (top-level messages); i >= 0 the decompressed chunk i."""
        if seg < 0:
            return self.data
        if self._cache is None or self._cache[0] != seg:
            self._cache = (seg, self.decompress(seg))
        return self._cache[1]


# --------------------------------------------------------------------------------------------
# read_log
# --------------------------------------------------------------------------------------------
def _identity(data) -> tuple:
    """Size and a digest of the first MiB of a log's bytes (enough to tell a replaced file)."""
    import hashlib
    return len(data), hashlib.blake2b(data[:1 << 20], digest_size=16).hexdigest()


def _map(path: Path):
    """The file's bytes as a read-only memory map (an empty file: ``b""``): a long video log is
    not copied into this process (images are read on demand, and forked vision workers share the
    pages); the bytes stay valid when the file is replaced by a new one (new inode)."""
    import mmap
    with open(path, "rb") as f:
        if os.fstat(f.fileno()).st_size == 0:
            return b""
        return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)


def read_log(path, topics=None, *, include_images: bool = True) -> FlightLog:
    """Read a horizon-nav MCAP log.

    Parameters
    ----------
    path : the ``.mcap`` file.
    topics : optional collection of topic names to decode (default all); others are only listed.
    include_images : keep an ``ImageStream`` per camera (images are decoded on demand either way).

    Returns
    -------
    FlightLog. Problems are warned about (``LogWarning``) and listed in ``log.issues``.

    Raises
    ------
    LogFormatError : the file cannot be opened or is not MCAP.
    """
    path = Path(path)
    try:
        data = _map(path)
    except OSError as e:
        raise LogFormatError(f"{path}: cannot read log ({e.strerror or e})") from None
    if len(data) < 8 or data[:8] != MAGIC:
        raise LogFormatError(f"{path}: not an MCAP file (the first 8 bytes are not the MCAP magic)")
    rd = _Reader(path, data)
    buf = np.frombuffer(data, np.uint8)
    want = None if topics is None else set(topics)

    schemas: dict[int, tuple[str, str, bytes]] = {}
    channels: dict[int, tuple[str, int, str]] = {}
    metadata: dict[str, dict[str, str]] = {}
    # per channel: list of parts (segment, payload, offsets, lengths, log_times), see _part
    raw: dict[int, list] = {}
    last_good = [None]  # last log_time of a complete message

    def handle_meta_records(b, ops, offs, lens, where):
        for i in np.flatnonzero((ops == OP_SCHEMA) | (ops == OP_CHANNEL) | (ops == OP_METADATA)):
            body = _Body(b[int(offs[i]):int(offs[i]) + int(lens[i])])
            try:
                if ops[i] == OP_SCHEMA:
                    sid = body.u16()
                    name, enc = body.string(), body.string()
                    schemas[sid] = (name, enc, body.bytes_(body.u32()))
                elif ops[i] == OP_CHANNEL:
                    cid, sid = body.u16(), body.u16()
                    channels[cid] = (body.string(), sid, body.string())
                else:
                    name = body.string()
                    metadata[name] = body.str_map()
            except (ValueError, struct.error):
                rd.warn(f"{path}: damaged record (opcode {int(ops[i])}) in {where}; skipped")

    def _is_image_channel(c: int) -> bool | None:
        """None: the channel is not declared yet (MCAP declares it first; a damaged file may not)."""
        if c not in channels:
            return None
        return lf.short_name(schemas.get(channels[c][1], ("",))[0]) == IMAGE_TYPE

    def handle_messages(seg, b, ops, offs, lens, chans, logts):
        m = (ops == OP_MESSAGE) & (chans >= 0)
        if not m.any():
            return
        idx = np.flatnonzero(m)
        ch, lt = chans[idx], logts[idx]
        last_good[0] = int(lt.max()) if last_good[0] is None else max(last_good[0], int(lt.max()))
        for c in np.unique(ch):
            sel = idx[ch == c]
            o = offs[sel] + MESSAGE_HEADER
            ln = lens[sel] - MESSAGE_HEADER
            c = int(c)
            raw.setdefault(c, []).append(_part(seg, b, o, ln, logts[sel], _is_image_channel(c)))

    ops, offs, lens, chans, logts, stop = scan_records(buf, 8, len(buf))
    # a complete file ends with the Footer record followed by the magic
    end_ok = (stop == len(buf) - 8 and data[-8:] == MAGIC and len(ops) and ops[-1] == OP_FOOTER)
    handle_meta_records(data, ops, offs, lens, "the file")
    handle_messages(-1, buf, ops, offs, lens, chans, logts)
    for i in np.flatnonzero(ops == OP_CHUNK):
        body = _Body(data[int(offs[i]):int(offs[i]) + min(int(lens[i]), 4096)])
        try:
            body.u64(), body.u64()
            size = body.u64()
            body.u32()
            comp = body.string()
            rec_len = body.u64()
        except (ValueError, struct.error):
            rd.warn(f"{path}: damaged chunk header at byte {int(offs[i])}; chunk skipped")
            continue
        rec_off = int(offs[i]) + body.p
        if rec_off + rec_len > int(offs[i]) + int(lens[i]):
            rd.warn(f"{path}: damaged chunk at byte {int(offs[i])}; chunk skipped")
            continue
        rd.chunks.append((rec_off, rec_len, comp, size))
        seg = len(rd.chunks) - 1
        try:
            cdata = rd.decompress(seg)
        except Exception as e:  # zstd/lz4 raise their own error types
            rd.warn(f"{path}: chunk at byte {int(offs[i])} cannot be decompressed ({e}); chunk skipped")
            continue
        cb = np.frombuffer(cdata, np.uint8)
        c_ops, c_offs, c_lens, c_ch, c_lt, c_stop = scan_records(cb, 0, len(cb))
        handle_meta_records(cdata, c_ops, c_offs, c_lens, f"chunk at byte {int(offs[i])}")
        handle_messages(seg, cb, c_ops, c_offs, c_lens, c_ch, c_lt)
        if c_stop != len(cb):
            rd.warn(f"{path}: chunk at byte {int(offs[i])} is damaged after {len(c_ops)} records; "
                    f"the rest of the chunk is skipped")
    if not end_ok:
        lg = "no message" if last_good[0] is None else f"last good message at {format_time(last_good[0])}"
        rd.warn(f"{path}: truncated or damaged at byte {int(stop)} of {len(data)}; "
                f"kept every complete message before it ({lg})")

    # ---------------- decode per channel ----------------
    log = FlightLog(path=path, metadata=metadata, topics={}, issues=rd.issues)
    for cid, parts in sorted(raw.items()):
        if cid not in channels:
            rd.warn(f"{path}: messages of unknown channel id {cid}; skipped")
            continue
        topic, sid, msg_enc = channels[cid]
        sname, senc, stext = schemas.get(sid, ("", "", b""))
        n_msgs = sum(len(p[3]) for p in parts)
        log.topics[topic] = TopicInfo(topic, sname, msg_enc, n_msgs)
        if want is not None and topic not in want:
            continue
        _decode_channel(log, rd, topic, sname, senc, stext, msg_enc, parts, include_images)
    return log


def _part(seg: int, b, o, ln, lt, image: bool | None) -> tuple:
    """One chunk's (or the file's top level's) messages of one channel, ``(segment, payload,
    offsets, lengths, log_times)``, in the form that does not keep the decompressed chunk alive
    (a video log is several times the memory otherwise; each chunk is freed once scanned):

    * images (``image`` True): only where they are, ``payload`` None (:class:`ImageStream` reads
      them on demand);
    * other messages: their payloads gathered now, ``payload`` the zero-padded (n, max length)
      byte matrix and ``offsets`` None;
    * a channel not declared yet (``image`` None, a damaged file): the chunk itself, ``b``.
    """
    if image:
        return seg, None, o, ln, lt
    if image is None:
        return seg, b, o, ln, lt
    return seg, gather_rows(b, o, ln, int(ln.max())), None, ln, lt


def _part_rows(part: tuple, width: int, rd: "_Reader") -> np.ndarray:
    """The (n, width) zero-padded payload matrix of a :func:`_part` (images: read from ``rd``)."""
    seg, b, o, ln, _ = part
    if o is not None:
        if b is None:
            b = np.frombuffer(rd.segment(seg), np.uint8)
        return gather_rows(b, o, ln, width)
    if b.shape[1] >= width:
        return b
    return np.pad(b, ((0, 0), (0, width - b.shape[1])))


def _layout_for(sname: str, senc: str, stext: bytes, msg_enc: str) -> lf.Layout | None:
    """Vectorised codec for a channel, None when it has no fast path."""
    if senc != "ros2msg" or msg_enc != "cdr":
        return None
    short = lf.short_name(sname)
    try:
        defs = lf.parse_schema(sname, stext.decode("utf-8"))
        return lf.Layout(short, defs)
    except (lf.NotVectorisable, ValueError, UnicodeDecodeError):
        return None


def _decode_channel(log, rd, topic, sname, senc, stext, msg_enc, parts, include_images):
    path = rd.path
    t = np.concatenate([p[4] for p in parts])
    if len(t) == 0:
        return
    short = lf.short_name(sname)
    layout = _layout_for(sname, senc, stext, msg_enc)
    if short == "tf2_msgs/TFMessage" or (senc == "ros2msg" and layout is None):
        _decode_by_message(log, rd, topic, sname, senc, stext, msg_enc, parts)
        return
    if layout is None:
        rd.warn(f"{path}: topic {topic}: unknown schema {sname!r} (encoding {senc!r}/{msg_enc!r}); skipped")
        return
    version = _known_version(path, topic, short, stext)
    if short not in lf.MSG_TEXTS:
        rd.warn(f"{path}: topic {topic}: unknown schema {sname!r}; decoded generically "
                "(fields named as in its definition)")
    elif layout.signature != lf.known_layout(short, version).signature:
        rd.warn(f"{path}: topic {topic}: schema {sname!r} differs from horizon-nav's definition; "
                "decoded as the file's schema says")
    if short == IMAGE_TYPE:
        loc = np.concatenate([np.stack([np.full(len(p[2]), p[0]), p[2], p[3]], axis=1) for p in parts])
        order = _validate_times(rd, topic, t, short)
        if include_images:
            cam = lf.parse_camera_topic(topic)
            stream = ImageStream(topic, rd, t[order], loc[order])
            if cam and cam[1] == "image/compressed":
                log.images[cam[0]] = stream
            else:
                log.other[topic] = (stream.t_ns, stream)
        return
    width = max(int(p[3].max()) for p in parts)
    mats = [_part_rows(p, width, rd) for p in parts]
    rows = mats[0] if len(mats) == 1 else np.concatenate(mats)
    lengths = np.concatenate([p[3] for p in parts])
    vals, ok = layout.decode(rows, lengths)
    del rows, mats
    if not ok.all():
        bad = np.flatnonzero(~ok)
        rd.warn(f"{path}: topic {topic}: {len(bad)} message(s) too short for schema {sname} "
                f"(first at {format_time(t[bad[0]])}); dropped")
        vals = _select(vals, ok)
        t = t[ok]
    if "header.stamp.sec" in vals:
        stamp = vals["header.stamp.sec"].astype(np.int64) * 1_000_000_000 + vals["header.stamp.nanosec"]
        diff = np.flatnonzero(stamp != t)
        if len(diff):
            rd.warn(f"{path}: topic {topic}: header.stamp differs from log_time in {len(diff)} message(s) "
                    f"(first at log_time {format_time(t[diff[0]])}); log_time used")
    order = _validate_times(rd, topic, t, short)
    if order is not None and not (len(order) == len(t) and np.all(order[1:] > order[:-1])):
        vals = _select(vals, order)
        t = t[order]
    fields = _shape_fields(short, vals)
    _check_nan(rd, topic, t, fields)
    log.series[topic] = Series(topic, sname, t, fields)


def _known_version(path, topic: str, short: str, stext: bytes) -> int | None:
    """The schema version of a versioned project type (`scenarios.flightlog.format.SCHEMA_VERSIONS`),
    None for other types; a version this reader does not know raises LogFormatError (its fields
    may mean something else: no guessing)."""
    known = lf.SCHEMA_VERSIONS.get(short)
    if known is None:
        return None
    v = lf.schema_version(stext.decode("utf-8", "replace"))
    if v not in known:
        raise LogFormatError(f"{path}: topic {topic}: {short} schema version {v} is not one this reader knows "
                             f"(versions {', '.join(str(k) for k in sorted(known))}); read it with the horizon-nav "
                             "that wrote it or a newer one")
    return v


def _select(vals: dict, idx) -> dict:
    out = {}
    for k, v in vals.items():
        if isinstance(v, list):
            ii = np.flatnonzero(idx) if np.asarray(idx).dtype == bool else idx
            out[k] = [v[i] for i in ii]
        else:
            out[k] = v[idx]
    return out


#: Schemas whose messages legitimately share a stamp: several vectors of one frame (Earth and Sun),
#: several measurement records of one filter epoch.
MULTI_PER_STAMP = frozenset({f"{lf.PKG}/DirectionVector", f"{lf.PKG}/MeasurementRecord"})


def _validate_times(rd, topic, t, short: str = "") -> np.ndarray:
    """Indices that sort ``t`` (stable) and drop duplicate stamps, warning about either. Schemas in
    :data:`MULTI_PER_STAMP` keep every message of a stamp, in file order."""
    path = rd.path
    d = np.diff(t)
    order = np.arange(len(t))
    if np.any(d < 0):
        first = int(np.flatnonzero(d < 0)[0]) + 1
        rd.warn(f"{path}: topic {topic}: time stamps out of order ({int(np.sum(d < 0))} step(s) back, first at "
                f"{format_time(t[first])}); sorted by time")
        order = np.argsort(t, kind="stable")
    ts = t[order]
    dup = np.flatnonzero(np.diff(ts) == 0) + 1
    if len(dup) and short not in MULTI_PER_STAMP:
        rd.warn(f"{path}: topic {topic}: {len(dup)} duplicate time stamp(s) (first at {format_time(ts[dup[0]])}); "
                "kept the first message of each stamp")
        keep = np.ones(len(ts), bool)
        keep[dup] = False
        order = order[keep]
    return order


#: DirectionVector fields where NaN means "none" (a vector without an Earth edge height)
EDGE_FIELDS = ("edge_sensitivity", "edge_height", "edge_height_sigma", "edge_height_arc", "edge_height_arc_sigma")


def _check_nan(rd, topic, t, fields):
    bad = np.zeros(len(t), bool)
    no_velocity = set()
    if topic == lf.TOPIC_GPS and isinstance(fields.get("velocity"), np.ndarray):
        # a position-only fix carries NaN velocity and velocity covariance: no measurement, not bad data
        if np.isnan(fields["velocity"].reshape(len(t), -1)).all(axis=1).all():
            no_velocity = {"velocity", "velocity_covariance"}
    if lf.parse_camera_topic(topic) and lf.parse_camera_topic(topic)[1] == "vectors":
        no_velocity = set(EDGE_FIELDS)   # NaN there: the vector has no edge height (docs/log-format.md)
    for name, v in fields.items():
        if name in no_velocity:
            continue
        if topic == lf.TOPIC_MEASUREMENTS and name == "nis" and isinstance(fields.get("used"), np.ndarray):
            # a record that was not used (a TRIAD attitude, a measurement refused before its
            # gate) has no NIS: NaN there means "none", not bad data
            bad |= np.isnan(np.asarray(v, float)) & np.asarray(fields["used"], bool)
            continue
        if isinstance(v, np.ndarray) and v.dtype.kind == "f" and v.shape[:1] == (len(t),):
            bad |= np.isnan(v.reshape(len(t), -1)).any(axis=1)
        elif isinstance(v, np.ndarray) and v.dtype == object and v.shape == (len(t),):
            bad |= np.array([np.isnan(x).any() for x in v], bool)
    if bad.any():
        i = np.flatnonzero(bad)
        rd.warn(f"{rd.path}: topic {topic}: NaN in {len(i)} message(s) (first at {format_time(t[i[0]])}); kept")


_VEC_NAMES = (("x", "y", "z", "w"), ("x", "y", "z"))


def _shape_fields(short: str, vals: dict) -> dict:
    """Generic leaf dict -> user fields: header dropped (frame_id kept), x/y/z(/w) groups stacked,
    3x3 covariances and CameraInfo matrices reshaped, Imu aliases gyro/accel."""
    out: dict = {}
    groups: dict[str, dict[str, np.ndarray]] = {}
    for k, v in vals.items():
        if k.startswith("header."):
            if k == "header.frame_id":
                out["frame_id"] = v
            continue
        if "." in k:
            pre, last = k.rsplit(".", 1)
            groups.setdefault(pre, {})[last] = v
            continue
        out[k] = v
    for pre, g in groups.items():
        stacked = False
        for names in _VEC_NAMES:
            if set(g) == set(names) and all(isinstance(g[n], np.ndarray) and g[n].dtype == np.float64 for n in names):
                out[pre] = np.stack([g[n] for n in names], axis=1)
                stacked = True
                break
        if not stacked:
            for last, v in g.items():
                out[f"{pre}.{last}"] = v
    for k, v in list(out.items()):
        if isinstance(v, np.ndarray) and v.ndim == 2 and v.dtype == np.float64:
            if v.shape[1] == 9 and (k.endswith("covariance") or k.endswith("overbound") or
                                    (short == "sensor_msgs/CameraInfo" and k in ("k", "r"))):
                out[k] = v.reshape(-1, 3, 3)
            elif short == "sensor_msgs/CameraInfo" and k == "p" and v.shape[1] == 12:
                out[k] = v.reshape(-1, 3, 4)
    if short == "sensor_msgs/Imu":
        out["gyro"] = out.get("angular_velocity")
        out["accel"] = out.get("linear_acceleration")
    if short == f"{lf.PKG}/NavSolution":
        names = out.get("state_names", [])
        out["state_names"] = next((list(x) for x in names if len(x)), [])
        cov = out.get("covariance")
        if isinstance(cov, np.ndarray) and cov.dtype == np.float64:
            n = int(round(np.sqrt(cov.shape[1])))
            if n * n == cov.shape[1]:
                out["covariance"] = cov.reshape(len(cov), n, n)  # len(): n may be 0
            if n == 1 and len(cov) and np.isnan(cov).all():
                # a 1x1 NaN block is the "no covariance" placeholder some solution logs carry
                # (/nav/ins_unaided): read as what it stands for, an empty covariance
                out["covariance"] = np.zeros((len(cov), 0, 0))
    if short == f"{lf.PKG}/MeasurementRecord":
        ic = out.get("innovation_covariance")
        if isinstance(ic, np.ndarray) and ic.dtype == np.float64:
            m = int(round(np.sqrt(ic.shape[1])))
            if m * m == ic.shape[1]:
                out["innovation_covariance"] = ic.reshape(len(ic), m, m)
        elif isinstance(ic, np.ndarray):
            out["innovation_covariance"] = np.array(
                [x.reshape(int(round(np.sqrt(len(x)))), -1) if len(x) else x.reshape(0, 0) for x in ic] + [None],
                dtype=object)[:-1]
    return out


def _decode_by_message(log, rd, topic, sname, senc, stext, msg_enc, parts):
    """Decode a channel message by message with mcap_ros2's decoder (tf_static and exotic schemas)."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    path = rd.path
    why = ""
    try:
        dec = DecoderFactory().decoder_for(msg_enc, Schema(id=0, name=sname, encoding=senc, data=stext))
    except Exception as e:  # the reference decoder raises assorted errors on bad schemas
        dec, why = None, f": {e}"
    if dec is None:
        rd.warn(f"{path}: topic {topic}: unknown schema {sname!r} (encoding {senc!r}/{msg_enc!r}){why}; skipped")
        return
    t_all, msgs = [], []
    for part in parts:
        rows = _part_rows(part, int(part[3].max()), rd)
        for r, li, ti in zip(rows, part[3].tolist(), part[4].tolist()):
            try:
                msgs.append(dec(r[:li].tobytes()))
                t_all.append(ti)
            except Exception:
                rd.warn(f"{path}: topic {topic}: message at {format_time(ti)} cannot be decoded; dropped")
    t = np.array(t_all, dtype=np.int64)
    order = _validate_times(rd, topic, t)
    t = t[order]
    msgs = [msgs[i] for i in order]
    if lf.short_name(sname) == "tf2_msgs/TFMessage":
        for ti, m in zip(t.tolist(), msgs):
            for tr in m.transforms:
                tt, q = tr.transform.translation, tr.transform.rotation
                log.tf_static[tr.child_frame_id] = Transform(
                    tr.header.frame_id, tr.child_frame_id, np.array([tt.x, tt.y, tt.z]),
                    np.array([q.x, q.y, q.z, q.w]), ti)
    else:
        if lf.short_name(sname) not in lf.MSG_TEXTS:
            rd.warn(f"{path}: topic {topic}: schema {sname!r} is not a horizon-nav type; "
                    "decoded message by message into log.other")
        log.other[topic] = (t, msgs)
