"""Mapping files (TOML): how the columns of a flight's tables and its footage become a horizon-nav log.

Format and examples: docs/import.md and scenarios/library/import/. Sketch::

    name = "my-flight"
    liftoff_utc = "2019-06-13T02:21:00Z"

    [imu]
    file = "imu.csv"                 # CSV or Parquet, relative to the mapping file
    sample = "rate"                  # or "increment"
    time = { column = "t", base = "mission", unit = "s" }
    gyro = { columns = ["gx", "gy", "gz"], unit = "deg/s" }
    accel = { columns = ["ax", "ay", "az"], unit = "g" }
    axes = ["+z", "-y", "+x"]        # body x, y, z from signed sensor axes (or { matrix = ... })

    [gps]
    file = "gps.csv"
    time = { column = "t", base = "mission", unit = "s" }
    position = { frame = "geodetic", columns = ["lat", "lon", "h"], angle_unit = "deg", unit = "m" }
    velocity = { frame = "ned", columns = ["vn", "ve", "vd"], unit = "m/s" }
    position_sigma = { value = 3.0, unit = "m" }

    [[cameras]]
    camera_file = "cam1.toml"
    mount = { azimuth_deg = 90.0, depression_deg = 20.0, roll_deg = 0.0 }
    payload_mask = "cam1_mask.png"     # optional: the vehicle's structure in view (non-zero = payload)
    [cameras.footage]
    video = "cam1.mp4"
    start_s = 0.0
    rate_hz = 30.0

Every table refuses unknown keys (typos) and every error names the mapping file and the key
(``scenarios.errors.UserError``). Paths are relative to the mapping file.
"""
from __future__ import annotations

import math
from scenarios.config.toml_file import read_toml
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nav.rotation import matrix_to_quat, quat_to_matrix
from nav.timescales import parse_utc
from scenarios.sim.camera_geometry import mount_rotation
from scenarios.errors import UserError

from . import units as U

TIME_BASES = ("iso", "unix", "gps", "gps_week", "mission")
#: 1-sigma position [m] and velocity [m/s] uncertainty per axis of a receiver class, the defaults
#: for a GPS table without uncertainty columns: a standalone code receiver (a few metres, 0.1-0.2 m/s
#: Doppler), with SBAS / differential corrections, RTK (centimetres) and PPP (decimetres)
RECEIVER_SIGMAS = {"standalone": (5.0, 0.2), "sbas": (2.0, 0.1), "dgps": (1.0, 0.1), "ppp": (0.2, 0.05),
                   "rtk": (0.05, 0.02)}
FORMATS = ("csv", "parquet")


@dataclass(frozen=True)
class TimeSpec:
    """How a time column becomes UTC ns.

    ``base``: ``"iso"`` (ISO-8601 UTC text, or a Parquet timestamp column; no zone = UTC),
    ``"unix"`` (number of ``unit`` since 1970-01-01 UTC, leap seconds not counted),
    ``"gps"`` (number of ``unit`` since the GPS epoch 1980-01-06, GPS time scale),
    ``"gps_week"`` (GPS seconds of week in ``column`` with the week in ``week_column`` or ``week``),
    ``"mission"`` (T+: ``unit`` since the mapping's ``liftoff_utc``). ``offset_s`` is added (a known
    clock offset of this sensor).
    """
    column: str
    base: str
    unit: str = "s"
    week_column: str | None = None
    week: int | None = None
    offset_s: float = 0.0


@dataclass(frozen=True)
class AxisMap:
    """Sensor frame s -> body frame b: ``v_b = R_bs @ v_s``. ``perm``/``signs`` is set for a signed
    permutation (applied exactly by column selection and negation)."""
    R_bs: np.ndarray
    perm: tuple[int, int, int] | None = None
    signs: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Triple:
    """Three columns in one unit (``factor`` to SI)."""
    columns: tuple[str, str, str]
    unit: str
    factor: float


@dataclass(frozen=True)
class Covariance:
    """GPS uncertainty: ``kind`` "sigma" (1 or 3 columns, or a constant ``value``) or "covariance"
    (6 columns xx, xy, xz, yy, yz, zz or 9 row-major); ``frame`` "ecef" or "ned"; ``factor`` to SI
    (of a sigma, or of a covariance = squared unit)."""
    kind: str
    columns: tuple[str, ...]
    value: float | None
    frame: str
    factor: float


@dataclass(frozen=True)
class TableSpec:
    """Where a table is and how to read it."""
    file: Path
    format: str
    time: TimeSpec
    delimiter: str = ","
    skip_rows: int = 0
    unsorted: str = "error"  # "error" or "sort" (sort by time, keep the first of duplicate stamps)


@dataclass(frozen=True)
class ImuSpec:
    table: TableSpec
    sample: str  # "rate" or "increment"
    gyro: Triple
    accel: Triple
    axes: AxisMap
    dt_column: str | None = None
    dt_unit: str = "s"
    gyro_range: float | None = None  # declared sensor range [rad/s or rad per sample], SI
    accel_range: float | None = None
    imu_sample: str = "interval"  # "interval" (mean over the preceding interval) or "point" (instantaneous)


@dataclass(frozen=True)
class GpsSpec:
    table: TableSpec
    position_frame: str  # "ecef" or "geodetic"
    position: tuple[str, str, str]
    position_factor: float  # length unit (ECEF, or the geodetic height)
    angle_factor: float  # geodetic lat/lon
    velocity_frame: str | None
    velocity: tuple[str, str, str] | None
    velocity_factor: float
    position_cov: Covariance | None
    velocity_cov: Covariance | None
    num_satellites: str | None = None
    sigma_default: str = ""  # which uncertainties came from defaults (for the report's warning), "" = none
    fallback_sigmas: tuple[float, float] = (5.0, 0.2)  # [m], [m/s]: for rows whose uncertainty is missing or zero


@dataclass(frozen=True)
class FootageSpec:
    """Camera footage: a ``video`` file or an ``images`` folder, with time stamps from a CSV
    (``timestamps``: file + time spec + ``file_column`` / ``frame_column``), from the file names
    (``filename_regex`` with one group, read with ``filename_time``), or a start time + frame rate
    (``start_utc`` or ``start_s`` T+, ``rate_hz``; for a video the rate defaults to its frame rate).
    ``duration_s`` / ``frames`` declare how long the footage must be."""
    kind: str  # "video" or "images"
    path: Path
    timestamps: TableSpec | None = None
    file_column: str | None = None
    frame_column: str | None = None
    filename_regex: str | None = None
    filename_time: TimeSpec | None = None
    start_ns: int | None = None
    rate_hz: float | None = None
    duration_s: float | None = None
    frames: int | None = None
    pattern: str = "*"
    jpeg_quality: int = 95
    verify: bool = True
    bit_depth: int | None = None   #: significant bits of 16-bit frames; None: each frame's own (`to_8bit`)


@dataclass(frozen=True)
class CameraSpec:
    k: int
    camera_file: Path
    R_bc: np.ndarray
    q_bc: np.ndarray
    translation_m: np.ndarray
    footage: FootageSpec | None
    payload_mask: Path | None = None   #: image of the camera's size, non-zero = payload (ignored by the edge search)


@dataclass(frozen=True)
class Checks:
    """Plausibility thresholds of the validation report (SI). Defaults suit sounding rockets."""
    gyro_max_rad_s: float = 60.0  # 9.5 rev/s: above any sounding-rocket spin (5 Hz = 31 rad/s)
    gyro_quiet_max_rad_s: float = 5.0  # 10th percentile of |w| (the quietest tenth: coast, pad)
    accel_rest_min: float = 8.0  # |f| at rest [m/s^2] must lie in [min, max]
    accel_rest_max: float = 11.5
    height_min_m: float = -1000.0
    height_max_m: float = 3_000_000.0
    speed_max_mps: float = 9000.0
    gap_factor: float = 1.5  # a gap is a step > gap_factor x the median step
    #: a flat top below these magnitudes is not read as a clipped range: flight gyros and
    #: accelerometers have ranges of at least ~30 deg/s and 2 g, and a quantised rate that
    #: steps to a plateau below them holds one value for a second or more
    saturation_gyro_min_rad_s: float = 0.5
    saturation_accel_min: float = 2.0 * 9.80665
    span_max_h: float = 72.0  # a record spans at most this long and starts this close to lift-off
    errors_fatal: bool = True


@dataclass(frozen=True)
class Mapping:
    path: Path
    text: str
    name: str
    liftoff_ns: int
    imu: ImuSpec | None
    gps: GpsSpec | None
    cameras: tuple[CameraSpec, ...]
    checks: Checks = field(default_factory=Checks)
    description: str = ""


# ------------------------------------------------------------------------------------------------
class _Ctx:
    """Error context: the mapping file and base directory."""

    def __init__(self, path: Path):
        self.path = path
        self.base = path.parent

    def err(self, where: str, msg: str) -> UserError:
        return UserError(f"{self.path} [{where}]: {msg}")


def _table(ctx: _Ctx, d: Any, where: str, allowed: set[str], required: set[str] = frozenset()) -> dict:
    if not isinstance(d, dict):
        raise ctx.err(where, f"expected a table, got {type(d).__name__}")
    unknown = set(d) - allowed
    if unknown:
        raise ctx.err(where, f"unknown key(s) {sorted(unknown)}; expected some of {sorted(allowed)}")
    missing = set(required) - set(d)
    if missing:
        raise ctx.err(where, f"missing key(s) {sorted(missing)}")
    return d


def _str(ctx, d, key, where, default=None, choices=None) -> str | None:
    v = d.get(key, default)
    if v is None:
        return None
    if not isinstance(v, str) or not v:
        raise ctx.err(where, f"key {key!r} = {v!r}; expected a non-empty string")
    if choices and v not in choices:
        raise ctx.err(where, f"key {key!r} = {v!r}; expected one of {list(choices)}")
    return v


def _num(ctx, d, key, where, default=None, positive=False) -> float | None:
    v = d.get(key, default)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ctx.err(where, f"key {key!r} = {v!r}; expected a finite number")
    if positive and v <= 0:
        raise ctx.err(where, f"key {key!r} = {v!r}; expected a positive number")
    return float(v)


def _cols(ctx, d, key, where, n: tuple[int, ...] = (3,)) -> tuple[str, ...]:
    v = d.get(key)
    if (not isinstance(v, list) or len(v) not in n or not all(isinstance(c, str) and c for c in v)):
        raise ctx.err(where, f"key {key!r} = {v!r}; expected a list of {' or '.join(map(str, n))} column names")
    return tuple(v)


def _unit(ctx, kind, name, where) -> float:
    try:
        return U.factor(name, kind, where)
    except ValueError as exc:
        raise UserError(f"{ctx.path}: {exc}") from None


def _path(ctx, v, where, key) -> Path:
    if not isinstance(v, str) or not v:
        raise ctx.err(where, f"key {key!r} = {v!r}; expected a file name (relative to the mapping file)")
    p = Path(v).expanduser()
    return p if p.is_absolute() else ctx.base / p


def parse_time(ctx: _Ctx, d: Any, where: str) -> TimeSpec:
    d = _table(ctx, d, where, {"column", "base", "unit", "week_column", "week", "offset_s"}, {"column", "base"})
    base = _str(ctx, d, "base", where, choices=TIME_BASES)
    unit = _str(ctx, d, "unit", where, default="s")
    if U.normalise(unit) not in U.TIME_NS:
        raise ctx.err(where, f"key 'unit' = {unit!r}; expected one of {list(U.TIME_NS)}")
    week = d.get("week")
    if week is not None and (isinstance(week, bool) or not isinstance(week, int) or week < 0):
        raise ctx.err(where, f"key 'week' = {week!r}; expected a non-negative integer (continuous GPS week)")
    if base == "gps_week" and (week is None) == ("week_column" not in d):
        raise ctx.err(where, "base 'gps_week' needs exactly one of 'week_column' or 'week'")
    if base != "gps_week" and (week is not None or "week_column" in d):
        raise ctx.err(where, f"'week' / 'week_column' only apply to base 'gps_week', not {base!r}")
    return TimeSpec(_str(ctx, d, "column", where), base, U.normalise(unit), _str(ctx, d, "week_column", where),
                    week, _num(ctx, d, "offset_s", where, default=0.0))


def _format_of(ctx, d, file: Path, where) -> str:
    fmt = _str(ctx, d, "format", where, choices=FORMATS)
    if fmt:
        return fmt
    suf = file.suffix.lower()
    if suf in (".csv", ".txt", ".tsv"):
        return "csv"
    if suf in (".parquet", ".pq"):
        return "parquet"
    raise ctx.err(where, f"cannot tell the format of {file.name!r} from its extension; set format = 'csv' or 'parquet'")


_TABLE_KEYS = {"file", "format", "time", "delimiter", "skip_rows", "unsorted"}


def parse_table(ctx: _Ctx, d: dict, where: str) -> TableSpec:
    file = _path(ctx, d.get("file"), where, "file")
    delim = d.get("delimiter", "\t" if file.suffix.lower() == ".tsv" else ",")
    if not isinstance(delim, str) or len(delim) != 1:
        raise ctx.err(where, f"key 'delimiter' = {delim!r}; expected one character")
    skip = d.get("skip_rows", 0)
    if isinstance(skip, bool) or not isinstance(skip, int) or skip < 0:
        raise ctx.err(where, f"key 'skip_rows' = {skip!r}; expected a non-negative integer")
    if "time" not in d:
        raise ctx.err(where, "missing key 'time' (e.g. time = { column = \"t\", base = \"unix\", unit = \"s\" })")
    return TableSpec(file, _format_of(ctx, d, file, where), parse_time(ctx, d["time"], f"{where}.time"), delim, skip,
                     _str(ctx, d, "unsorted", where, default="error", choices=("error", "sort")))


def parse_axes(ctx: _Ctx, v: Any, where: str) -> AxisMap:
    """``["+x", "-z", "+y"]`` (body x, y, z = signed sensor axes), ``{ matrix = [[..], [..], [..]] }``
    (R_bs, rows = body axes in sensor coordinates) or ``{ quaternion = [x, y, z, w] }`` (q_bs)."""
    if v is None:
        return AxisMap(np.eye(3), (0, 1, 2), (1.0, 1.0, 1.0))
    if isinstance(v, list):
        ok = len(v) == 3 and all(isinstance(a, str) and len(a) == 2 and a[0] in "+-" and a[1] in "xyz" for a in v)
        if not ok:
            raise ctx.err(where, f"axes = {v!r}; expected three signed sensor axes like [\"+x\", \"-z\", \"+y\"]")
        perm = tuple("xyz".index(a[1]) for a in v)
        if sorted(perm) != [0, 1, 2]:
            raise ctx.err(where, f"axes = {v!r}: each sensor axis must appear once")
        signs = tuple(1.0 if a[0] == "+" else -1.0 for a in v)
        R = np.zeros((3, 3))
        R[np.arange(3), perm] = signs
        if np.linalg.det(R) < 0:
            raise ctx.err(where, f"axes = {v!r} is a reflection (left-handed, det = -1); flip one sign")
        return AxisMap(R, perm, signs)
    d = _table(ctx, v, where, {"matrix", "quaternion"})
    if len(d) != 1:
        raise ctx.err(where, "give exactly one of 'matrix' (R_bs) or 'quaternion' (q_bs, [x, y, z, w])")
    if "matrix" in d:
        try:
            R = np.asarray(d["matrix"], dtype=float)
        except (TypeError, ValueError):
            R = np.zeros(0)
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise ctx.err(where, f"matrix = {d['matrix']!r}; expected a 3x3 list of numbers")
        if np.max(np.abs(R @ R.T - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0:
            raise ctx.err(where, "matrix is not a rotation (R R^T = I within 1e-6, det = +1)")
    else:
        q = np.asarray(d["quaternion"], dtype=float) if isinstance(d["quaternion"], list) else np.zeros(0)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 0.5:
            raise ctx.err(where, f"quaternion = {d['quaternion']!r}; expected [x, y, z, w] with norm ~1")
        R = quat_to_matrix(q)
    # an exact signed permutation given as a matrix is applied exactly too
    if np.all(np.isin(R, (-1.0, 0.0, 1.0))) and np.all(np.sum(np.abs(R), axis=1) == 1):
        perm = tuple(int(i) for i in np.argmax(np.abs(R), axis=1))
        return AxisMap(R, perm, tuple(float(R[i, perm[i]]) for i in range(3)))
    return AxisMap(R)


def _triple(ctx, d, where, kind) -> Triple:
    d = _table(ctx, d, where, {"columns", "unit"}, {"columns", "unit"})
    cols = _cols(ctx, d, "columns", where)
    unit = _str(ctx, d, "unit", where)
    f = _unit(ctx, kind, unit, where)
    try:
        U.check_column_units(cols, unit, kind, where)
    except ValueError as exc:
        raise UserError(f"{ctx.path}: {exc}") from None
    return Triple(cols, unit, f)


def parse_imu(ctx: _Ctx, d: Any) -> ImuSpec:
    w = "imu"
    d = _table(ctx, d, w, _TABLE_KEYS | {"sample", "gyro", "accel", "axes", "dt_column", "dt_unit",
                                         "gyro_range", "accel_range", "imu_sample"}, {"file", "time", "gyro", "accel"})
    table = parse_table(ctx, d, w)
    sample = _str(ctx, d, "sample", w, default="rate", choices=("rate", "increment"))
    inc = sample == "increment"
    gyro = _triple(ctx, d["gyro"], f"{w}.gyro", "angle" if inc else "angular rate")
    accel = _triple(ctx, d["accel"], f"{w}.accel", "velocity" if inc else "acceleration")
    dt_unit = _str(ctx, d, "dt_unit", w, default="s")
    if U.normalise(dt_unit) not in U.TIME:
        raise ctx.err(w, f"key 'dt_unit' = {dt_unit!r}; expected one of {list(U.TIME)}")
    if "dt_column" in d and not inc:
        raise ctx.err(w, "'dt_column' only applies to sample = 'increment'")
    gr = _num(ctx, d, "gyro_range", w, positive=True)
    ar = _num(ctx, d, "accel_range", w, positive=True)
    point = _str(ctx, d, "imu_sample", w, default="interval", choices=("interval", "point"))
    if inc and point == "point":
        raise ctx.err(w, "imu_sample = 'point' applies to sample = 'rate' (an increment covers its interval)")
    return ImuSpec(table, sample, gyro, accel, parse_axes(ctx, d.get("axes"), f"{w}.axes"),
                   _str(ctx, d, "dt_column", w), U.normalise(dt_unit),
                   None if gr is None else gr * gyro.factor, None if ar is None else ar * accel.factor, point)


def _cov(ctx, d, where, kind, default_frame) -> Covariance | None:
    if d is None:
        return None
    is_cov = where.endswith("covariance")
    d = _table(ctx, d, where, {"columns", "column", "value", "unit", "frame"}, {"unit"})
    frame = _str(ctx, d, "frame", where, default=default_frame, choices=("ecef", "ned"))
    unit = _str(ctx, d, "unit", where)
    if is_cov:
        try:
            f = U.squared_factor(unit, kind, where)
        except ValueError as exc:
            raise UserError(f"{ctx.path}: {exc}") from None
        if set(d) & {"column", "value"}:
            raise ctx.err(where, "a covariance needs 'columns' (6: xx, xy, xz, yy, yz, zz, or 9 row-major)")
        return Covariance("covariance", _cols(ctx, d, "columns", where, (6, 9)), None, frame, f)
    f = _unit(ctx, kind, unit, where)
    given = [k for k in ("columns", "column", "value") if k in d]
    if len(given) != 1:
        raise ctx.err(where, "give exactly one of 'columns' (3 sigmas), 'column' (one sigma for all axes) or 'value'")
    if "columns" in d:
        return Covariance("sigma", _cols(ctx, d, "columns", where), None, frame, f)
    if "column" in d:
        return Covariance("sigma", (_str(ctx, d, "column", where),), None, frame, f)
    return Covariance("sigma", (), _num(ctx, d, "value", where, positive=True), frame, f)


def parse_gps(ctx: _Ctx, d: Any) -> GpsSpec:
    w = "gps"
    d = _table(ctx, d, w, _TABLE_KEYS | {"position", "velocity", "position_sigma", "position_covariance",
                                         "velocity_sigma", "velocity_covariance", "num_satellites",
                                         "sigma_pos_m", "sigma_vel_mps", "receiver"},
               {"file", "time", "position"})
    table = parse_table(ctx, d, w)
    p = _table(ctx, d["position"], f"{w}.position", {"frame", "columns", "unit", "angle_unit"}, {"frame", "columns"})
    pframe = _str(ctx, p, "frame", f"{w}.position", choices=("ecef", "geodetic"))
    pcols = _cols(ctx, p, "columns", f"{w}.position")
    pf = _unit(ctx, "length", _str(ctx, p, "unit", f"{w}.position", default="m"), f"{w}.position")
    if pframe == "ecef" and "angle_unit" in p:
        raise ctx.err(f"{w}.position", "'angle_unit' only applies to frame = 'geodetic'")
    af = _unit(ctx, "angle", _str(ctx, p, "angle_unit", f"{w}.position", default="deg"), f"{w}.position")
    vframe = vcols = None
    vf = 1.0
    if "velocity" in d:
        v = _table(ctx, d["velocity"], f"{w}.velocity", {"frame", "columns", "unit"}, {"frame", "columns"})
        vframe = _str(ctx, v, "frame", f"{w}.velocity", choices=("ecef", "ned"))
        vcols = _cols(ctx, v, "columns", f"{w}.velocity")
        vf = _unit(ctx, "velocity", _str(ctx, v, "unit", f"{w}.velocity", default="m/s"), f"{w}.velocity")
    default_frame = "ecef" if pframe == "ecef" else "ned"
    for a, b in (("position_sigma", "position_covariance"), ("velocity_sigma", "velocity_covariance")):
        if a in d and b in d:
            raise ctx.err(w, f"give one of {a!r} or {b!r}, not both")
    pc = _cov(ctx, d.get("position_sigma", d.get("position_covariance")),
              f"{w}.position_{'sigma' if 'position_sigma' in d else 'covariance'}", "length", default_frame)
    vc = _cov(ctx, d.get("velocity_sigma", d.get("velocity_covariance")),
              f"{w}.velocity_{'sigma' if 'velocity_sigma' in d else 'covariance'}", "velocity",
              vframe if vframe else default_frame)
    if vc is not None and vcols is None:
        raise ctx.err(w, "a velocity uncertainty is given but no 'velocity' columns")
    receiver = _str(ctx, d, "receiver", w, choices=tuple(RECEIVER_SIGMAS))
    sp, sv = _num(ctx, d, "sigma_pos_m", w, positive=True), _num(ctx, d, "sigma_vel_mps", w, positive=True)
    if sv is not None and vcols is None:
        raise ctx.err(w, "'sigma_vel_mps' is given but no 'velocity' columns")
    rp, rv = RECEIVER_SIGMAS[receiver or "standalone"]
    used = []
    if pc is None:
        pc = Covariance("sigma", (), sp if sp is not None else rp, "ecef", 1.0)  # isotropic: any frame
        used.append(f"sigma_pos_m = {pc.value:g} m")
    if vc is None and vcols is not None:
        vc = Covariance("sigma", (), sv if sv is not None else rv, "ecef", 1.0)
        used.append(f"sigma_vel_mps = {vc.value:g} m/s")
    note = ""
    if used:
        src = ("the mapping's sigma_pos_m / sigma_vel_mps" if sp is not None or sv is not None else "")
        src += (" and " if src and receiver else "") + (f"receiver = '{receiver}'" if receiver else "")
        note = (", ".join(used) + f" ({src or 'the default receiver class standalone'}); the table has no "
                "uncertainty columns")
    return GpsSpec(table, pframe, pcols, pf, af, vframe, vcols, vf, pc, vc, _str(ctx, d, "num_satellites", w),
                   note, (sp if sp is not None else rp, sv if sv is not None else rv))


def _start(ctx, d, where, liftoff_ns) -> int | None:
    if "start_utc" in d and "start_s" in d:
        raise ctx.err(where, "give one of 'start_utc' or 'start_s' (T+), not both")
    if "start_utc" in d:
        try:
            return parse_utc(d["start_utc"])
        except ValueError as exc:
            raise ctx.err(where, f"start_utc: {exc}") from None
    if "start_s" in d:
        return liftoff_ns + int(round(_num(ctx, d, "start_s", where) * 1e9))
    return None


def parse_footage(ctx: _Ctx, d: Any, where: str, liftoff_ns: int) -> FootageSpec:
    d = _table(ctx, d, where, {"video", "images", "timestamps", "filename_regex", "filename_time", "start_utc",
                               "start_s", "rate_hz", "duration_s", "frames", "pattern", "jpeg_quality", "verify",
                               "bit_depth"})
    if ("video" in d) == ("images" in d):
        raise ctx.err(where, "give exactly one of 'video' (a video file) or 'images' (a folder of images)")
    kind = "video" if "video" in d else "images"
    path = _path(ctx, d[kind], where, kind)
    sources = [k for k in ("timestamps", "filename_regex") if k in d] + (
        ["start"] if ("start_utc" in d or "start_s" in d) else [])
    if len(sources) != 1:
        raise ctx.err(where, "give exactly one time source: 'timestamps' (a CSV with one row per frame), "
                             "'filename_regex' + 'filename_time' (stamps in the file names), or "
                             "'start_utc' / 'start_s' with 'rate_hz' (start time + frame rate)")
    ts = fcol = frcol = regex = ftime = None
    if "timestamps" in d:
        t = _table(ctx, d["timestamps"], f"{where}.timestamps", _TABLE_KEYS | {"file_column", "frame_column"},
                   {"file", "time"})
        ts = parse_table(ctx, t, f"{where}.timestamps")
        fcol, frcol = _str(ctx, t, "file_column", where), _str(ctx, t, "frame_column", where)
        if kind == "images" and fcol is None:
            raise ctx.err(f"{where}.timestamps", "an image folder needs 'file_column' (the image file names)")
        if kind == "video" and fcol is not None:
            raise ctx.err(f"{where}.timestamps", "a video takes 'frame_column' (0-based frame index) or rows "
                                                 "in frame order, not 'file_column'")
    if "filename_regex" in d:
        if kind == "video":
            raise ctx.err(where, "'filename_regex' applies to image folders only")
        regex = _str(ctx, d, "filename_regex", where)
        import re
        try:
            if re.compile(regex).groups != 1:
                raise ctx.err(where, f"filename_regex {regex!r}: expected exactly one group (the time stamp)")
        except re.error as exc:
            raise ctx.err(where, f"filename_regex {regex!r}: {exc}") from None
        if "filename_time" not in d:
            raise ctx.err(where, "'filename_regex' needs 'filename_time' = { base = ..., unit = ... }")
        ft = dict(d["filename_time"]) if isinstance(d["filename_time"], dict) else d["filename_time"]
        if isinstance(ft, dict):
            ft.setdefault("column", "filename")
        ftime = parse_time(ctx, ft, f"{where}.filename_time")
    start = _start(ctx, d, where, liftoff_ns)
    rate = _num(ctx, d, "rate_hz", where, positive=True)
    if start is not None and rate is None and kind == "images":
        raise ctx.err(where, "an image folder with a start time needs 'rate_hz'")
    frames = d.get("frames")
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, int) or frames <= 0):
        raise ctx.err(where, f"key 'frames' = {frames!r}; expected a positive integer")
    q = d.get("jpeg_quality", 95)
    if isinstance(q, bool) or not isinstance(q, int) or not 1 <= q <= 100:
        raise ctx.err(where, f"key 'jpeg_quality' = {q!r}; expected an integer 1..100")
    verify = d.get("verify", True)
    if not isinstance(verify, bool):
        raise ctx.err(where, f"key 'verify' = {verify!r}; expected true or false")
    bits = d.get("bit_depth")
    if bits is not None and (isinstance(bits, bool) or not isinstance(bits, int) or not 9 <= bits <= 16):
        raise ctx.err(where, f"key 'bit_depth' = {bits!r}; expected the 16-bit frames' significant bits, "
                             "an integer 9..16")
    return FootageSpec(kind, path, ts, fcol, frcol, regex, ftime, start, rate,
                       _num(ctx, d, "duration_s", where, positive=True), frames,
                       _str(ctx, d, "pattern", where, default="*"), q, verify, bits)


def parse_mount(ctx: _Ctx, d: Any, where: str) -> np.ndarray:
    """``{ quaternion = [x, y, z, w] }`` (q_bc: camera -> body) or ``{ azimuth_deg, depression_deg,
    roll_deg }`` (scenarios.sim.camera_geometry.mount_rotation) -> R_bc."""
    d = _table(ctx, d, where, {"quaternion", "azimuth_deg", "depression_deg", "roll_deg"})
    if "quaternion" in d:
        if len(d) != 1:
            raise ctx.err(where, "give either 'quaternion' or the angles azimuth_deg / depression_deg / roll_deg")
        q = np.asarray(d["quaternion"], dtype=float) if isinstance(d["quaternion"], list) else np.zeros(0)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > 1e-3:
            raise ctx.err(where, f"quaternion = {d['quaternion']!r}; expected a unit [x, y, z, w] (q_bc)")
        return quat_to_matrix(q)
    for k in ("azimuth_deg", "depression_deg"):
        if k not in d:
            raise ctx.err(where, f"missing key {k!r} (or give 'quaternion')")
    return mount_rotation(_num(ctx, d, "azimuth_deg", where), _num(ctx, d, "depression_deg", where),
                          _num(ctx, d, "roll_deg", where, default=0.0))


def parse_camera(ctx: _Ctx, d: Any, i: int, liftoff_ns: int) -> CameraSpec:
    w = f"cameras[{i}]"
    d = _table(ctx, d, w, {"k", "camera_file", "mount", "translation_m", "footage", "payload_mask"},
               {"camera_file", "mount"})
    k = d.get("k", i + 1)
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ctx.err(w, f"key 'k' = {k!r}; expected a camera number >= 1")
    R = parse_mount(ctx, d["mount"], f"{w}.mount")
    tr = d.get("translation_m", [0.0, 0.0, 0.0])
    try:
        tr = np.asarray(tr, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise ctx.err(w, f"translation_m = {d.get('translation_m')!r}; expected [x, y, z] in metres") from None
    fs = parse_footage(ctx, d["footage"], f"{w}.footage", liftoff_ns) if "footage" in d else None
    q = d["mount"].get("quaternion")
    if q is not None:  # as given (bit for bit) when already unit to 1e-12, else normalised
        q_bc = np.asarray(q, float)
        q_bc = q_bc if abs(np.linalg.norm(q_bc) - 1.0) < 1e-12 else q_bc / np.linalg.norm(q_bc)
    else:
        q_bc = matrix_to_quat(R)
    mask = _path(ctx, d["payload_mask"], w, "payload_mask") if "payload_mask" in d else None
    return CameraSpec(k, _path(ctx, d["camera_file"], w, "camera_file"), R, q_bc, tr, fs, mask)


def parse_checks(ctx: _Ctx, d: Any) -> Checks:
    names = set(Checks.__dataclass_fields__)
    d = _table(ctx, d, "checks", names)
    kw = {}
    for k, v in d.items():
        if k == "errors_fatal":
            if not isinstance(v, bool):
                raise ctx.err("checks", f"errors_fatal = {v!r}; expected true or false")
            kw[k] = v
        else:
            kw[k] = _num(ctx, d, k, "checks")
    return Checks(**kw)


def load_mapping(path: str | Path) -> Mapping:
    """Read and validate a mapping file; UserError naming the file and key on any problem."""
    doc, text = read_toml(path, "mapping file")
    return mapping_from_dict(doc, Path(path), text)


def mapping_from_dict(doc: dict, path: Path, text: str = "") -> Mapping:
    ctx = _Ctx(Path(path))
    _table(ctx, doc, "top level", {"name", "description", "liftoff_utc", "imu", "gps", "cameras", "checks"},
           {"liftoff_utc"})
    try:
        liftoff = parse_utc(doc["liftoff_utc"])
    except ValueError as exc:
        raise ctx.err("top level", f"liftoff_utc: {exc}") from None
    if not any(k in doc for k in ("imu", "gps", "cameras")):
        raise ctx.err("top level", "nothing to import: give at least one of [imu], [gps], [[cameras]]")
    cams = doc.get("cameras", [])
    if not isinstance(cams, list):
        raise ctx.err("cameras", "expected [[cameras]] tables")
    cameras = tuple(parse_camera(ctx, c, i, liftoff) for i, c in enumerate(cams))
    ks = [c.k for c in cameras]
    if len(set(ks)) != len(ks):
        raise ctx.err("cameras", f"camera numbers k = {ks} repeat")
    return Mapping(ctx.path, text, _str(ctx, doc, "name", "top level", default=ctx.path.stem), liftoff,
                   parse_imu(ctx, doc["imu"]) if "imu" in doc else None,
                   parse_gps(ctx, doc["gps"]) if "gps" in doc else None, cameras,
                   parse_checks(ctx, doc.get("checks", {})),
                   _str(ctx, doc, "description", "top level") or "")
