"""The horizon-nav flight-log format: ROS 2 message definitions, topic names and a vectorised CDR codec.

One place for the format (docs/log-format.md repeats the texts for readers of the docs):

* ``MSG_TEXTS``: every ROS 2 ``.msg`` text the logs use, standard ones (``sensor_msgs``,
  ``geometry_msgs``, ``tf2_msgs``, ``std_msgs``, ``builtin_interfaces``) and the project's own
  package ``horizon_nav_msgs``.
* ``schema_text(name)``: the full ``ros2msg`` schema (the definition followed by its dependencies,
  each after a line of 80 ``=`` and ``MSG: pkg/Type``) as stored in the MCAP Schema record.
* Topic names (``TOPIC_*``, ``camera_topic``) and frame ids.
* ``Layout``: an encoder/decoder for CDR (XCDR1, little endian, as ROS 2 and ``mcap_ros2`` write it)
  that works on many messages at once with numpy. Messages whose strings and sequences have the same
  lengths share a byte layout, so a batch is one ``(N, L)`` byte matrix and each field one column
  slice. Nested messages inside sequences (``tf2_msgs/TFMessage``) are not supported here; those go
  through the reference codec of ``mcap_ros2``.

CDR rules used (OMG DDS-XTypes 1.3, §7.4.1, "XCDR1"; ROS 2 ``rmw_fastrtps`` / ``mcap_ros2``): a
4-byte encapsulation header (``00 01 00 00`` = CDR little endian), then the fields in order; each
primitive is aligned to its own size (1, 2, 4 or 8) counted from the end of the encapsulation header;
a string is a ``uint32`` byte count including the terminating NUL, the bytes and the NUL; a sequence is
a ``uint32`` element count followed by the elements (alignment applies to each element, so an empty
sequence adds no padding); fixed arrays are the elements back to back; nested messages are inlined.
"""
from __future__ import annotations

import functools
import re
from dataclasses import dataclass

import numpy as np

# --------------------------------------------------------------------------------------------
# Topics and frames
# --------------------------------------------------------------------------------------------
TOPIC_IMU = "/imu"
TOPIC_IMU_INCREMENT = "/imu_increment"
TOPIC_GPS = "/gps"
TOPIC_TF_STATIC = "/tf_static"
TOPIC_TRUTH = "/truth/state"
TOPIC_NAV_FORWARD = "/nav/forward"
TOPIC_NAV_SMOOTHED = "/nav/smoothed"
TOPIC_NAV_INS_UNAIDED = "/nav/ins_unaided"
TOPIC_MEASUREMENTS = "/nav/measurements"
NAV_TOPICS = (TOPIC_NAV_FORWARD, TOPIC_NAV_SMOOTHED, TOPIC_NAV_INS_UNAIDED)

FRAME_BODY = "body"
FRAME_EARTH = "earth"  # ECEF (REP-105 name)

#: Suffixes of the per-camera topics ``/camera_<k>/<suffix>``.
CAMERA_SUFFIXES = ("camera_info", "image/compressed", "vectors", "truth", "payload_mask")
_CAMERA_RE = re.compile(r"^/camera_(\d+)/(" + "|".join(map(re.escape, CAMERA_SUFFIXES)) + r")$")


def camera_frame(k: int) -> str:
    """Frame id of camera ``k`` (1-based): ``camera_<k>``."""
    return f"camera_{int(k)}"


def camera_topic(k: int, suffix: str) -> str:
    """Topic ``/camera_<k>/<suffix>``; suffix one of ``CAMERA_SUFFIXES``."""
    if suffix not in CAMERA_SUFFIXES:
        raise ValueError(f"camera topic suffix {suffix!r}: expected one of {CAMERA_SUFFIXES}")
    if int(k) < 0:
        raise ValueError(f"camera index {k}: expected a non-negative integer")
    return f"/{camera_frame(k)}/{suffix}"


def parse_camera_topic(topic: str) -> tuple[int, str] | None:
    """``"/camera_2/vectors"`` -> ``(2, "vectors")``; None for other topics."""
    m = _CAMERA_RE.match(topic)
    return (int(m.group(1)), m.group(2)) if m else None


# --------------------------------------------------------------------------------------------
# Message definitions
# --------------------------------------------------------------------------------------------
PKG = "horizon_nav_msgs"

MSG_TEXTS: dict[str, str] = {
    # ---- standard ROS 2 types (as in ROS 2 Humble/Jazzy, comments trimmed) ----
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
    "geometry_msgs/TransformStamped": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n"),
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "sensor_msgs/Imu": (
        "std_msgs/Header header\n"
        "geometry_msgs/Quaternion orientation\n"
        "float64[9] orientation_covariance\n"
        "geometry_msgs/Vector3 angular_velocity\n"
        "float64[9] angular_velocity_covariance\n"
        "geometry_msgs/Vector3 linear_acceleration\n"
        "float64[9] linear_acceleration_covariance\n"),
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n",
    "sensor_msgs/RegionOfInterest": (
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"),
    "sensor_msgs/CameraInfo": (
        "std_msgs/Header header\n"
        "uint32 height\n"
        "uint32 width\n"
        "string distortion_model\n"
        "float64[] d\n"
        "float64[9] k\n"
        "float64[9] r\n"
        "float64[12] p\n"
        "uint32 binning_x\n"
        "uint32 binning_y\n"
        "sensor_msgs/RegionOfInterest roi\n"),
    # ---- project types ----
    f"{PKG}/EcefFix": (
        "# GNSS receiver fix in ECEF (WGS-84). header.stamp = measurement time (UTC), frame_id \"earth\".\n"
        "std_msgs/Header header\n"
        "float64[3] position  # m, ECEF\n"
        "float64[3] velocity  # m/s, ECEF\n"
        "float64[9] position_covariance  # m^2, 3x3 row major\n"
        "float64[9] velocity_covariance  # (m/s)^2, 3x3 row major\n"
        "uint16 num_satellites\n"
        "int8 status  # STATUS_* below\n"
        "int8 STATUS_NO_FIX=-1\n"
        "int8 STATUS_FIX=0\n"
        "int8 STATUS_SBAS_FIX=1\n"
        "int8 STATUS_GBAS_FIX=2\n"),
    f"{PKG}/ImuIncrement": (
        "# Increment-output IMU sample over (stamp - dt, stamp]. frame_id \"body\".\n"
        "std_msgs/Header header\n"
        "float64[3] delta_angle  # rad, body frame\n"
        "float64[3] delta_velocity  # m/s, body frame\n"
        "float64 dt  # s, integration interval\n"),
    f"{PKG}/DirectionVector": (
        "# Direction to a body measured by a camera, in the camera frame. frame_id \"camera_<k>\".\n"
        "std_msgs/Header header\n"
        "string target  # \"earth\" (nadir), \"sun\" or \"moon\"\n"
        "float64[3] vector  # unit vector, camera frame\n"
        "float64[9] covariance  # 3x3 row major\n"
        "float64[9] covariance_overbound  # 3x3 row major\n"
        "float64 residual  # fit residual of the conic\n"
        "uint32 pixel_count  # edge pixels used\n"
        "uint32 inlier_count\n"
        "string conic_type  # \"ellipse\", \"hyperbola\" or \"\"\n"
        "float64 alpha  # rad, apparent angular radius of the body\n"
        "float64[3] edge_sensitivity  # 1/m, d vector / d edge height (Earth, the height estimated by the filter); NaN: none\n"
        "float64 edge_height  # m, the Earth edge height the vector was fitted at; NaN: none\n"
        "float64 edge_height_sigma  # m, its 1-sigma (covariance excludes it where edge_sensitivity is set)\n"
        "float64 edge_height_arc  # m, the arc's own (prior-free) edge height; NaN: none\n"
        "float64 edge_height_arc_sigma  # m, its 1-sigma; inf or NaN: none\n"
        "uint16 SCHEMA_VERSION=2\n"),
    f"{PKG}/TruthState": (
        "# Simulated true vehicle state. frame_id \"earth\".\n"
        "std_msgs/Header header\n"
        "float64[3] position_e  # m, ECEF\n"
        "float64[3] velocity_e  # m/s, ECEF\n"
        "float64[4] q_eb  # body->ECEF attitude, [x, y, z, w]\n"
        "float64[3] angular_rate_b  # rad/s, body w.r.t. inertial, in body\n"
        "float64[3] specific_force_b  # m/s^2, in body\n"),
    f"{PKG}/CameraTruth": (
        "# Simulated truth seen by camera k at the image time. frame_id \"camera_<k>\".\n"
        "std_msgs/Header header\n"
        "float64[3] nadir_c  # unit vector to the Earth centre, camera frame\n"
        "float64[3] sun_c  # unit vector to the Sun, camera frame\n"
        "float64[3] moon_c  # unit vector to the Moon, camera frame\n"
        "bool horizon_visible\n"
        "string conic_type  # \"ellipse\", \"hyperbola\" or \"\"\n"
        "bool sun_in_view\n"
        "bool moon_in_view\n"
        "float64 earth_fraction  # fraction of the image covered by the Earth\n"
        "float64[3] misalignment  # rad, true psi_c (003 eq. 50)\n"),
    f"{PKG}/NavSolution": (
        "# Navigation solution. frame_id \"earth\".\n"
        "std_msgs/Header header\n"
        "float64[3] position_e  # m, ECEF\n"
        "float64[3] velocity_e  # m/s, ECEF\n"
        "float64[4] q_eb  # body->ECEF attitude, [x, y, z, w]\n"
        "float64[] state  # estimated parameters in the order of state_names (fed-back error states 0)\n"
        "float64[] covariance  # n x n error-state covariance, row major\n"
        "string[] state_names  # names of the n states; may be empty (then those of the first message)\n"),
    f"{PKG}/MeasurementRecord": (
        "# One measurement offered to the filter. frame_id \"earth\".\n"
        "std_msgs/Header header\n"
        "string source  # e.g. \"gps\", \"camera_1/earth\"\n"
        "bool used\n"
        "string reason  # why it was rejected, \"\" when used\n"
        "float64[] innovation\n"
        "float64[] innovation_covariance  # m x m, row major\n"
        "float64 nis  # normalised innovation squared\n"),
}

#: Earlier definitions of versioned project types, which the reader still reads: type -> {version:
#: message text}. A versioned type's text declares ``uint16 SCHEMA_VERSION=<n>`` (none: version 1).
SCHEMA_VERSIONS: dict[str, dict[int, str]] = {
    f"{PKG}/DirectionVector": {
        1: MSG_TEXTS[f"{PKG}/DirectionVector"].split("float64[3] edge_sensitivity")[0],
        2: MSG_TEXTS[f"{PKG}/DirectionVector"]},
}


def schema_version(schema: str) -> int:
    """The ``SCHEMA_VERSION`` constant of a schema's top-level message (the text before the first
    ``MSG:`` section), 1 when it has none."""
    top = re.split(r"^=+\s*$", schema, maxsplit=1, flags=re.M)[0]
    m = re.search(r"^\s*uint16\s+SCHEMA_VERSION\s*=\s*(\d+)\s*(#.*)?$", top, flags=re.M)
    return int(m.group(1)) if m else 1


#: Topic-independent: which schema each kind of topic uses.
SCHEMA_IMU = "sensor_msgs/msg/Imu"
TYPE_OF_TOPIC = {
    TOPIC_IMU: "sensor_msgs/Imu",
    TOPIC_IMU_INCREMENT: f"{PKG}/ImuIncrement",
    TOPIC_GPS: f"{PKG}/EcefFix",
    TOPIC_TF_STATIC: "tf2_msgs/TFMessage",
    TOPIC_TRUTH: f"{PKG}/TruthState",
    TOPIC_NAV_FORWARD: f"{PKG}/NavSolution",
    TOPIC_NAV_SMOOTHED: f"{PKG}/NavSolution",
    TOPIC_NAV_INS_UNAIDED: f"{PKG}/NavSolution",
    TOPIC_MEASUREMENTS: f"{PKG}/MeasurementRecord",
}
CAMERA_TYPES = {
    "camera_info": "sensor_msgs/CameraInfo",
    "image/compressed": "sensor_msgs/CompressedImage",
    "payload_mask": "sensor_msgs/CompressedImage",
    "vectors": f"{PKG}/DirectionVector",
    "truth": f"{PKG}/CameraTruth",
}

PRIMITIVES = {  # name -> numpy little-endian dtype
    "bool": "u1", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1",
    "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4",
    "int64": "<i8", "uint64": "<u8", "float32": "<f4", "float64": "<f8",
}


def type_of_topic(topic: str) -> str | None:
    """Short type name (``pkg/Type``) a horizon-nav topic uses, None for other topics."""
    if topic in TYPE_OF_TOPIC:
        return TYPE_OF_TOPIC[topic]
    cam = parse_camera_topic(topic)
    return CAMERA_TYPES[cam[1]] if cam else None


def ros2_name(short: str) -> str:
    """``"sensor_msgs/Imu"`` -> ``"sensor_msgs/msg/Imu"`` (the schema name ROS 2 tools expect)."""
    pkg, name = short.split("/")
    return f"{pkg}/msg/{name}"


def short_name(name: str) -> str:
    """``"sensor_msgs/msg/Imu"`` -> ``"sensor_msgs/Imu"``; short names pass through."""
    parts = name.split("/")
    return f"{parts[0]}/{parts[-1]}" if len(parts) >= 2 else name


# --------------------------------------------------------------------------------------------
# Parsing .msg texts
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Field:
    """One field of a message: ``array`` None for a scalar, -1 for a sequence, n for ``T[n]``."""
    name: str
    type: str
    array: int | None


_CONST_RE = re.compile(r"^\S+\s+[A-Za-z_]\w*\s*=")
_FIELD_RE = re.compile(r"^([A-Za-z_][\w/]*)(<=\d+)?(\[(<=)?(\d*)\])?\s+([A-Za-z_]\w*)(\s+.*)?$")


def parse_msg(text: str, package: str) -> list[Field]:
    """Fields of one ``.msg`` text (constants and comments skipped).

    Bounded strings and sequences (``string<=N``, ``T[<=N]``) are encoded like unbounded ones in
    CDR and parse as such. Raises ValueError naming the line it cannot read.
    """
    fields = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if _CONST_RE.match(line):  # constant "type NAME=value"
            continue
        m = _FIELD_RE.match(line)
        if not m:
            raise ValueError(f"message definition line {raw!r}: cannot parse (expected 'type name')")
        typ, _, arr, bounded, size, name = m.group(1), m.group(2), m.group(3), m.group(4), m.group(5), m.group(6)
        if typ not in PRIMITIVES and typ not in ("string", "wstring"):
            parts = typ.split("/")
            if len(parts) == 1:
                typ = "std_msgs/Header" if typ == "Header" else f"{package}/{typ}"
            else:
                typ = f"{parts[0]}/{parts[-1]}"
        array = None if arr is None else (-1 if (bounded or size == "") else int(size))
        fields.append(Field(name, typ, array))
    return fields


def parse_schema(name: str, text: str) -> dict[str, list[Field]]:
    """Parse a full ``ros2msg`` schema (main text + ``MSG: pkg/Type`` sections) -> {type: fields}."""
    main = short_name(name)
    sections = re.split(r"^={10,}\s*$", text, flags=re.M)
    out = {main: parse_msg(sections[0], main.split("/")[0])}
    for sec in sections[1:]:
        m = re.search(r"^\s*MSG:\s*(\S+)\s*$", sec, flags=re.M)
        if not m:
            continue
        dep = short_name(m.group(1))
        out[dep] = parse_msg(sec[m.end():], dep.split("/")[0])
    return out


def _dependencies(short: str, seen: list[str]) -> list[str]:
    for f in parse_msg(MSG_TEXTS[short], short.split("/")[0]):
        if f.type in MSG_TEXTS and f.type not in seen:
            seen.append(f.type)
            _dependencies(f.type, seen)
    return seen


def schema_text(short: str) -> str:
    """Full ``ros2msg`` schema text of type ``short`` (``pkg/Type``) with its dependencies."""
    if short not in MSG_TEXTS:
        raise ValueError(f"message type {short!r}: not a horizon-nav log type ({sorted(MSG_TEXTS)})")
    parts = [MSG_TEXTS[short].rstrip("\n")]
    for dep in _dependencies(short, []):
        parts.append("=" * 80 + f"\nMSG: {dep}\n" + MSG_TEXTS[dep].rstrip("\n"))
    return "\n".join(parts) + "\n"


# --------------------------------------------------------------------------------------------
# Vectorised CDR codec
# --------------------------------------------------------------------------------------------
class NotVectorisable(Exception):
    """The message type has a construct the vectorised codec does not handle."""


@dataclass(frozen=True)
class Leaf:
    """A primitive or string field at ``path`` ("header.stamp.sec") after inlining nested messages."""
    path: str
    type: str          # primitive name or "string"
    array: int | None  # None scalar, -1 sequence, n fixed


def flatten(short: str, msgdefs: dict[str, list[Field]]) -> list[Leaf]:
    """Inline nested messages of ``short`` into a list of leaves (raises NotVectorisable)."""
    leaves: list[Leaf] = []

    def walk(typ: str, prefix: str):
        if typ not in msgdefs:
            raise NotVectorisable(f"type {typ} has no definition")
        fields = msgdefs[typ]
        if not fields:
            raise NotVectorisable(f"type {typ} is empty")
        for f in fields:
            path = prefix + f.name
            if f.type in PRIMITIVES or f.type == "string":
                if f.type == "string" and f.array is not None and f.array >= 0:
                    raise NotVectorisable(f"{path}: fixed string arrays")
                leaves.append(Leaf(path, f.type, f.array))
            elif f.type == "wstring":
                raise NotVectorisable(f"{path}: wstring")
            else:
                if f.array is not None:
                    raise NotVectorisable(f"{path}: arrays of messages")
                walk(f.type, path + ".")

    walk(short, "")
    return leaves


def strided_view(rows: np.ndarray, col: int, dtype, k: int) -> np.ndarray:
    """``(m, k)`` view of dtype ``dtype`` on the bytes ``col:col + k*itemsize`` of every row of the
    C-contiguous uint8 matrix ``rows`` (unaligned access is fine for numpy)."""
    dt = np.dtype(dtype)
    m, width = rows.shape
    return np.ndarray((m, k), dt, buffer=rows, offset=col, strides=(width, dt.itemsize))


def _align(pos, a):
    """Align a CDR position (counted from the start of the buffer incl. the 4-byte header)."""
    return (pos - 4 + a - 1) // a * a + 4


@dataclass(frozen=True)
class _Const:
    """A field value shared by every message of a batch: ``row`` its elements (1-D, wire dtype),
    ``count`` the element count (for sequences)."""
    row: np.ndarray
    count: int


class Layout:
    """Vectorised CDR codec of one message type.

    ``encode(values, n)`` -> list of ``n`` payloads (bytes, with encapsulation header);
    ``decode(rows, lengths)`` -> dict path -> array, where ``rows`` is an ``(N, W)`` uint8 matrix of
    payloads (zero padded) and ``lengths`` their byte counts.

    Values per leaf path: scalars as ``(N,)`` arrays (or a scalar to broadcast), fixed arrays as
    ``(N, n)``, sequences as ``(N, m)`` arrays (same length) or a list of N 1-D arrays, strings as a
    str or a sequence of N str, string sequences as a list of N lists of str.
    """

    def __init__(self, short: str, msgdefs: dict[str, list[Field]] | None = None):
        if msgdefs is None:
            msgdefs = {t: parse_msg(MSG_TEXTS[t], t.split("/")[0]) for t in MSG_TEXTS}
        self.name = short
        self.leaves = flatten(short, msgdefs)
        self.signature = tuple((lf.path, lf.type, lf.array) for lf in self.leaves)

    # ---------------- encode ----------------
    def encode(self, values: dict, n: int) -> list[bytes]:
        """Encode ``n`` messages -> list of ``n`` payloads (bytes, with encapsulation header)."""
        n = int(n)
        out: list[bytes] = [b""] * n
        for idx, rows in self.encode_groups(values, n):
            L = rows.shape[1]
            blob = rows.tobytes()
            if idx is None:
                out = [blob[i * L:(i + 1) * L] for i in range(n)]
            else:
                for j, i in enumerate(idx.tolist()):
                    out[i] = blob[j * L:(j + 1) * L]
        return out

    def encode_groups(self, values: dict, n: int, prefix: int = 0,
                      head=None) -> list[tuple[np.ndarray | None, np.ndarray]]:
        """Encode ``n`` messages as byte matrices, one per group of messages that share a layout.

        Returns a list of ``(idx, rows)``: ``idx`` the message indices of the group in ascending
        order (None: all ``n`` messages, the usual case of one layout), ``rows`` a C-contiguous
        ``(len(idx), prefix + L)`` uint8 matrix whose columns ``prefix:`` are the CDR payloads
        (``L`` bytes each, encapsulation header included) and whose first ``prefix`` columns are
        ``head(L)`` (``prefix`` bytes, e.g. an MCAP Message record header; zeros when ``head`` is
        None) for the caller to complete.

        Values that are the same in every message (scalars, one row, ``np.broadcast_to`` views,
        a single str) are written once into a template row that is copied to all rows; only the
        varying fields are written column by column.
        """
        n = int(n)
        if n == 0:
            return []
        prepared = []  # (leaf, data) with data normalised; _Const for values shared by all messages
        var_cols = []  # per-message variable sizes (string byte lengths, sequence counts)
        for lf in self.leaves:
            if lf.path not in values:
                raise ValueError(f"{self.name}: field {lf.path!r} missing")
            v = values[lf.path]
            if lf.type == "string":
                if lf.array is None:
                    enc = _encode_strings(v, n, f"{self.name}.{lf.path}")
                    prepared.append((lf, enc))
                    if isinstance(enc, list):
                        var_cols.append(np.array([len(b) for b in enc]))
                else:  # string sequence: list of N lists
                    if isinstance(v, (list, tuple)) and len(v) == n and all(isinstance(x, (list, tuple)) for x in v):
                        lists = [[s.encode() for s in x] for x in v]
                    else:
                        raise ValueError(f"{self.name}.{lf.path}: expected a list of {n} lists of str")
                    prepared.append((lf, lists))
                    var_cols.append(np.array([len(x) for x in lists], dtype=np.int64))
                    for j in range(max((len(x) for x in lists), default=0)):
                        var_cols.append(np.array([len(x[j]) if j < len(x) else -1 for x in lists]))
                continue
            dt = np.dtype(PRIMITIVES[lf.type])
            if lf.array == -1:
                if isinstance(v, np.ndarray) and v.ndim == 2 and v.shape[0] == n:
                    if v.strides[0] == 0:  # broadcast view: one sequence for all messages
                        prepared.append((lf, _Const(np.ascontiguousarray(v[0], dtype=dt), v.shape[1])))
                    else:
                        prepared.append((lf, np.asarray(v, dtype=dt)))
                else:
                    if len(v) != n:
                        raise ValueError(f"{self.name}.{lf.path}: expected {n} sequences, got {len(v)}")
                    lst = [np.ascontiguousarray(np.asarray(x, dtype=dt).reshape(-1)) for x in v]
                    prepared.append((lf, lst))
                    var_cols.append(np.array([len(x) for x in lst], dtype=np.int64))
            else:
                k = 1 if lf.array is None else lf.array
                arr = np.asarray(v)
                const = None
                if arr.ndim == 0:
                    const = arr.reshape(1)
                elif arr.size == k and (arr.shape[0] != n or (arr.ndim == 1 and k > 1)):
                    const = arr.reshape(k)  # one value (k elements) for every message
                elif arr.shape[0] == n and arr.strides[0] == 0 and arr.size == n * k:
                    const = arr[0].reshape(k)
                if const is not None:
                    if lf.type == "bool":
                        const = const.astype(bool)
                    prepared.append((lf, _Const(np.ascontiguousarray(np.broadcast_to(const, (k,)), dtype=dt), k)))
                    continue
                if lf.type == "bool":
                    arr = arr.astype(bool)
                arr = np.asarray(arr, dtype=dt)
                if arr.size != n * k:
                    raise ValueError(f"{self.name}.{lf.path}: expected shape ({n}, {k}) values, got {np.shape(v)}")
                prepared.append((lf, arr.reshape(n, k)))
        groups: list = [None]
        if var_cols:
            key = np.stack(var_cols, axis=1)
            if not np.all(key == key[0]):
                _, inv = np.unique(key, axis=0, return_inverse=True)
                inv = inv.reshape(-1)
                order = np.argsort(inv, kind="stable")
                cuts = np.flatnonzero(np.diff(inv[order])) + 1
                groups = np.split(order, cuts)
        return [(idx, self._encode_group(prepared, idx, n, prefix, head)) for idx in groups]

    def _encode_group(self, prepared, idx, n, prefix=0, head=None):
        """Encode the messages ``idx`` (None: all) that share one layout into an (m, prefix + L) matrix."""
        first = 0 if idx is None else int(idx[0])
        m = n if idx is None else len(idx)
        sel = (lambda a: a) if idx is None else (lambda a: a[idx])
        # pass 1: offsets
        pos = 4
        plan = []
        for lf, data in prepared:
            if lf.type == "string" and lf.array is None:
                nb = data[1] if isinstance(data, tuple) else len(data[first])
                pos = _align(pos, 4)
                plan.append((pos, nb))
                pos += 4 + nb + 1
            elif lf.type == "string":
                items = data[first]
                pos = _align(pos, 4)
                offs = [pos]
                pos += 4
                for s in items:
                    pos = _align(pos, 4)
                    offs.append(pos)
                    pos += 4 + len(s) + 1
                plan.append(offs)
            else:
                size = np.dtype(PRIMITIVES[lf.type]).itemsize
                if lf.array == -1:
                    if isinstance(data, _Const):
                        cnt = data.count
                    else:
                        cnt = data.shape[1] if isinstance(data, np.ndarray) else len(data[first])
                    pos = _align(pos, 4)
                    cpos = pos
                    pos += 4
                    if cnt:
                        pos = _align(pos, size)
                    plan.append((cpos, pos, cnt))
                    pos += cnt * size
                else:
                    k = 1 if lf.array is None else lf.array
                    pos = _align(pos, size)
                    plan.append(pos)
                    pos += k * size
        # pass 2: a template row with everything shared by the group, then the varying fields, each
        # written through a strided view of its own dtype (one element per row: fast in numpy)
        tmpl = np.zeros(prefix + pos, dtype=np.uint8)
        if head is not None:
            tmpl[:prefix] = np.frombuffer(head(pos), np.uint8)
        tmpl[prefix + 1] = 1  # encapsulation: CDR little endian
        var = []  # (column in the payload, (m, k) values)

        def u32(x):
            return np.array([x], "<u4").view(np.uint8)

        def put(col, row):
            tmpl[prefix + col:prefix + col + row.nbytes] = row.view(np.uint8)

        for (lf, data), p in zip(prepared, plan):
            if lf.type == "string" and lf.array is None:
                start, nb = p
                put(start, u32(nb + 1))
                if nb:
                    if isinstance(data, tuple):
                        put(start + 4, np.frombuffer(data[0], np.uint8))
                    else:
                        items = data if idx is None else [data[i] for i in idx]
                        var.append((start + 4, np.frombuffer(b"".join(items), np.uint8).reshape(m, nb)))
            elif lf.type == "string":
                items = data if idx is None else [data[i] for i in idx]
                put(p[0], u32(len(items[0])))
                for j, start in enumerate(p[1:]):
                    nb = len(items[0][j])
                    put(start, u32(nb + 1))
                    if nb:
                        var.append((start + 4, np.frombuffer(b"".join(x[j] for x in items), np.uint8).reshape(m, nb)))
            elif lf.array == -1:
                cpos, start, cnt = p
                put(cpos, u32(cnt))
                if cnt:
                    if isinstance(data, _Const):
                        put(start, data.row)
                    elif isinstance(data, np.ndarray):
                        var.append((start, sel(data)))
                    else:
                        var.append((start, np.stack(data if idx is None else [data[i] for i in idx])))
            elif isinstance(data, _Const):
                put(p, data.row)
            else:
                var.append((p, sel(data)))
        rows = np.empty((m, prefix + pos), dtype=np.uint8)
        rows[:] = tmpl
        for start, v in var:
            strided_view(rows, prefix + start, v.dtype, v.shape[1])[...] = v
        return rows

    # ---------------- decode ----------------
    def decode(self, rows: np.ndarray, lengths: np.ndarray) -> tuple[dict, np.ndarray]:
        """Decode an ``(N, W)`` payload matrix. Returns ``(values, ok)``; ``ok[i]`` is False for a
        message that is too short for its own fields (its values are garbage)."""
        n, width = rows.shape
        lengths = np.asarray(lengths, dtype=np.int64)
        ok = (lengths >= 4) & (rows[:, 0] == 0) & (rows[:, 1] == 1)
        out: dict = {}
        pos: int | np.ndarray = 4
        ar = np.arange(n)

        def take(p, nbytes, need=None):
            """(N, nbytes) bytes at per-message position p; ``ok`` cleared where a message is shorter
            than ``p + need`` (``need`` per message, default nbytes; 0 where the field is absent).
            Bytes past a row's width read as its last byte (callers mask them)."""
            nonlocal ok
            need = nbytes if need is None else need
            ok &= (lengths >= p + need) | (np.asarray(need) == 0)
            if np.ndim(p) == 0 and p + nbytes <= width:
                return rows[:, p:p + nbytes]
            if nbytes == 0:
                return np.zeros((n, 0), np.uint8)
            idx = np.minimum(np.asarray(p).reshape(-1, 1) + np.arange(nbytes), width - 1)
            return rows[ar[:, None], idx] if idx.shape[0] == n else rows[:, idx[0]]

        def collapse(p):
            if np.ndim(p) and n and np.all(p == p[0]):
                return int(p[0])
            return p

        def u32(p, need=None):
            return np.ascontiguousarray(take(p, 4, need)).view("<u4").reshape(n).astype(np.int64)

        for lf in self.leaves:
            if lf.type == "string" and lf.array is None:
                pos = _align(pos, 4)
                cnt = u32(pos)
                cnt = np.where(ok, cnt, 0)
                out[lf.path] = self._strings(take, pos + 4, cnt, n)
                pos = collapse(pos + 4 + cnt)
            elif lf.type == "string":
                pos = _align(pos, 4)
                cnt = np.where(ok, u32(pos), 0)
                pos = pos + 4
                lists: list[list[str]] = [[] for _ in range(n)]
                for j in range(int(cnt.max()) if n else 0):
                    has = cnt > j
                    pj = _align(pos, 4)
                    nb = np.where(has & ok, u32(pj, np.where(has, 4, 0)), 0)
                    s = self._strings(take, pj + 4, nb, n)
                    for i in np.flatnonzero(has):
                        lists[i].append(str(s[i]))
                    pos = collapse(np.where(has, pj + 4 + nb, pos))
                out[lf.path] = lists
            else:
                dt = np.dtype(PRIMITIVES[lf.type])
                size = dt.itemsize
                if lf.array == -1:
                    pos = _align(pos, 4)
                    cnt = np.where(ok, u32(pos), 0)
                    pos = pos + 4
                    pos = collapse(np.where(cnt > 0, _align(pos, size), pos))
                    fits = cnt * size <= lengths - pos  # a damaged count must not allocate gigabytes
                    ok &= fits
                    cnt = np.where(fits, cnt, 0)
                    counts = np.unique(cnt)
                    if len(counts) <= 1:
                        c = int(counts[0]) if len(counts) else 0
                        b = take(pos, c * size)
                        out[lf.path] = np.ascontiguousarray(b).view(dt).reshape(n, c)
                    else:
                        vals = np.empty(n, dtype=object)
                        pa = np.broadcast_to(np.asarray(pos), (n,))
                        for c in counts.tolist():
                            sel = np.flatnonzero(cnt == c)
                            idx = np.minimum(pa[sel, None] + np.arange(c * size), width - 1)
                            arr = np.ascontiguousarray(rows[sel[:, None], idx]).view(dt).reshape(len(sel), c)
                            for j, i in enumerate(sel.tolist()):
                                vals[i] = arr[j]
                        out[lf.path] = vals
                    pos = collapse(pos + cnt * size)
                else:
                    k = 1 if lf.array is None else lf.array
                    pos = _align(pos, size)
                    b = take(pos, k * size)
                    arr = np.ascontiguousarray(b).view(dt).reshape(n, k)
                    if lf.type == "bool":
                        arr = arr != 0
                    out[lf.path] = arr[:, 0] if lf.array is None else arr
                    pos = pos + k * size
        return out, ok

    @staticmethod
    def _strings(take, p, cnt, n):
        """Decode strings of byte count ``cnt`` (incl. NUL) at ``p`` -> (N,) str array."""
        nb = np.maximum(cnt - 1, 0)
        mx = int(nb.max()) if n else 0
        if mx == 0:
            return np.full(n, "", dtype="<U1")
        b = np.array(take(p, mx, nb + (cnt > 0)))
        b[np.arange(mx)[None, :] >= nb[:, None]] = 0
        s = b.view(f"S{mx}").reshape(n)
        if n and np.all(s == s[0]):
            return np.full(n, s[0].decode("utf-8", "replace"))
        try:
            return s.astype(str)  # ASCII fast path
        except UnicodeDecodeError:
            return np.array([x.decode("utf-8", "replace") for x in s])


@functools.lru_cache(maxsize=None)
def known_layout(short: str, version: int | None = None) -> Layout:
    """Codec of a horizon-nav type from ``MSG_TEXTS`` (cached); ``version``: of a versioned type,
    that version's definition (``SCHEMA_VERSIONS``)."""
    if version is None:
        return Layout(short)
    defs = {t: parse_msg(MSG_TEXTS[t], t.split("/")[0]) for t in MSG_TEXTS}
    defs[short] = parse_msg(SCHEMA_VERSIONS[short][version], short.split("/")[0])
    return Layout(short, defs)


def _encode_strings(v, n, what):
    """Normalise string values: a single str -> (bytes, len) tuple; N str -> list of bytes."""
    if isinstance(v, str):
        b = v.encode("utf-8")
        return (b, len(b))
    if isinstance(v, np.ndarray) and v.ndim == 0:
        b = str(v).encode("utf-8")
        return (b, len(b))
    if len(v) != n:
        raise ValueError(f"{what}: expected one str or {n} str, got {len(v)}")
    items = [str(x).encode("utf-8") for x in v]
    if all(x == items[0] for x in items):
        return (items[0], len(items[0]))
    return items


def stamp_fields(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """int64 ns since the Unix epoch -> (sec int32, nanosec uint32) of builtin_interfaces/Time."""
    t = np.asarray(t_ns, dtype=np.int64)
    if t.size and (t.min() < 0 or t.max() >= (2**31) * 10**9):
        raise ValueError("time stamps: expected int64 ns since 1970 before 2038-01-19 (int32 seconds)")
    return (t // 1_000_000_000).astype(np.int32), (t % 1_000_000_000).astype(np.uint32)


def header_values(t_ns: np.ndarray, frame_id: str) -> dict:
    """Leaf values of ``std_msgs/Header`` for stamps ``t_ns`` and one frame id."""
    sec, nsec = stamp_fields(t_ns)
    return {"header.stamp.sec": sec, "header.stamp.nanosec": nsec, "header.frame_id": frame_id}
