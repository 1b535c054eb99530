"""Read IMU and GPS tables (CSV or Parquet) into SI arrays in the body / ECEF frames, vectorised.

Parsing: ``pyarrow.csv`` (multi-threaded C++ parser; only the mapped columns are converted) or
``pyarrow.parquet``. Data columns are parsed as float64 (CSV text written with the shortest
round-trip representation, as Python's ``repr`` and Arrow write it, comes back bit-identical);
integer time columns stay int64 so integer nanoseconds are exact.

Time bases (``mapping.TimeSpec``) -> int64 ns since the Unix epoch, UTC (docs/conventions.md "Time"):

* integer columns: ``t * ns_per_unit`` (exact);
* float columns: whole and fractional parts scaled separately and rounded to the nanosecond; a
  float64 holds Unix seconds (~1.6e9) to about 0.24 us, T+ seconds to far below 1 ns;
* ``gps`` / ``gps_week``: through ``nav.timescales`` (leap-second table), ``iso`` through Arrow's
  ISO-8601 parser (zone suffixes honoured, no zone = UTC).

Units: ``value_SI = value * factor`` (``scenarios.importer.units``): one multiplication, ~1e-16
relative (exactly nothing when the factor is 1). Axes: ``v_b = R_bs v_s``; a signed permutation is
applied by column selection and negation (exact), a general rotation as a matrix product.

Errors (``UserError``) name the file, the column and the data row (1-based; for CSV also the line).
"""
from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav import earth
from nav.timescales import gps_to_utc_ns, gps_week_seconds_to_utc_ns
from scenarios.errors import UserError

from . import units as U
from .mapping import AxisMap, Covariance, GpsSpec, ImuSpec, TableSpec, TimeSpec


def _pa():
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pcsv
    return pa, pc, pcsv


@dataclass
class RawTable:
    """Columns read from one file (pyarrow arrays), the row count, and how to name a row."""
    file: Path
    format: str
    columns: dict
    nrows: int
    skip_rows: int = 0

    def row(self, i: int) -> str:
        """Human name of data row ``i`` (0-based): ``row 12 (line 13)`` for CSV."""
        if self.format == "csv":
            return f"row {i + 1} (line {i + 2 + self.skip_rows})"
        return f"row {i + 1}"


def header(spec: TableSpec) -> list[str]:
    """Column names of a table file (without parsing the data)."""
    path = spec.file
    if not path.exists():
        raise UserError(f"{path}: file not found")
    if spec.format == "parquet":
        import pyarrow.parquet as pq
        try:
            return list(pq.read_schema(path).names)
        except Exception as exc:  # noqa: BLE001 - pyarrow raises several types for bad files
            raise UserError(f"{path}: cannot read as Parquet ({exc})") from None
    with open(path, newline="", encoding="utf-8", errors="replace") as fh:
        for _ in range(spec.skip_rows):
            fh.readline()
        line = fh.readline()
    if not line.strip():
        raise UserError(f"{path}: empty file (no header line after {spec.skip_rows} skipped rows)")
    return [c.strip() for c in next(csv.reader([line], delimiter=spec.delimiter))]


def read_table(spec: TableSpec, columns: list[str], *, text_columns=(), float_columns=(), what: str = "") -> RawTable:
    """Read ``columns`` of a CSV / Parquet table; missing columns -> UserError listing the available ones.

    ``float_columns`` are converted to float64 while parsing; ``text_columns`` are kept as text;
    others (time columns) are typed by Arrow's inference (int64, double or timestamp).
    """
    pa, pc, pcsv = _pa()
    cols = list(dict.fromkeys(c for c in columns if c))
    names = header(spec)
    missing = [c for c in cols if c not in names]
    if missing:
        raise UserError(f"{spec.file}: missing column(s) {missing}{' for ' + what if what else ''}; "
                        f"the file has {names}")
    if spec.format == "parquet":
        import pyarrow.parquet as pq
        try:
            tab = pq.read_table(spec.file, columns=cols)
        except Exception as exc:  # noqa: BLE001
            raise UserError(f"{spec.file}: cannot read as Parquet ({exc})") from None
    else:
        types = {c: pa.float64() for c in float_columns}
        types.update({c: pa.string() for c in text_columns})
        try:
            tab = pcsv.read_csv(
                spec.file, read_options=pcsv.ReadOptions(skip_rows=spec.skip_rows, block_size=1 << 24),
                parse_options=pcsv.ParseOptions(delimiter=spec.delimiter),
                convert_options=pcsv.ConvertOptions(include_columns=cols, column_types=types))
        except pa.ArrowInvalid as exc:
            raise UserError(_csv_error(spec, cols, float_columns, str(exc))) from None
    out = {c: tab.column(c) for c in cols}
    return RawTable(spec.file, spec.format, out, tab.num_rows, spec.skip_rows)


def _csv_error(spec: TableSpec, cols, float_columns, msg: str) -> str:
    """Turn a pyarrow CSV conversion error into a message naming the column and the row."""
    _, _, pcsv = _pa()
    import re
    m = re.search(r"CSV column #(\d+).*invalid value '([^']*)'", msg)
    if not m:
        return f"{spec.file}: cannot parse CSV ({msg})"
    bad = m.group(2)
    # find the column and row (error path only: read the columns as text and look)
    names = header(spec)
    col = names[int(m.group(1))] if int(m.group(1)) < len(names) else "?"
    try:
        import pyarrow as pa
        t = pcsv.read_csv(spec.file, read_options=pcsv.ReadOptions(skip_rows=spec.skip_rows),
                          parse_options=pcsv.ParseOptions(delimiter=spec.delimiter),
                          convert_options=pcsv.ConvertOptions(include_columns=[col],
                                                              column_types={col: pa.string()}))
        vals = t.column(col).to_pylist()
        i = vals.index(bad)
        where = f"row {i + 1} (line {i + 2 + spec.skip_rows})"
    except (ValueError, Exception):  # noqa: BLE001
        where = "a row"
    return f"{spec.file}: column {col!r} {where}: {bad!r} is not a number"


def floats(raw: RawTable, col: str, *, allow_missing: bool = False) -> np.ndarray:
    """float64 numpy array of a column; empty / NaN cells -> UserError naming the first row
    (or NaN when ``allow_missing``)."""
    pa, pc, _ = _pa()
    a = raw.columns[col]
    if (pa.types.is_string(a.type) or pa.types.is_large_string(a.type)) and not a.null_count:
        a = _text_to_number(raw, col, a)
    if not (pa.types.is_floating(a.type) or pa.types.is_integer(a.type)):
        raise UserError(f"{raw.file}: column {col!r} holds {a.type} values; expected numbers")
    if a.null_count:
        if not allow_missing:
            i = int(np.flatnonzero(a.is_null().to_numpy(zero_copy_only=False))[0])
            raise UserError(f"{raw.file}: column {col!r} {raw.row(i)}: empty or NaN value")
        a = a.cast(pa.float64()).fill_null(float("nan"))
    x = a.to_numpy().astype(np.float64, copy=False)
    if not allow_missing:
        bad = ~np.isfinite(x)
        if bad.any():
            i = int(np.argmax(bad))
            raise UserError(f"{raw.file}: column {col!r} {raw.row(i)}: value {x[i]} is not finite")
    return x


def _number_to_ns(raw: RawTable, col: str, unit: str) -> np.ndarray:
    pa, _, _ = _pa()
    a = raw.columns[col]
    if a.null_count:
        i = int(np.flatnonzero(a.is_null().to_numpy(zero_copy_only=False))[0])
        raise UserError(f"{raw.file}: time column {col!r} {raw.row(i)}: empty value")
    if pa.types.is_string(a.type) or pa.types.is_large_string(a.type):
        a = _text_to_number(raw, col, a)
    if pa.types.is_timestamp(a.type):
        raise UserError(f"{raw.file}: time column {col!r} holds timestamps; use base = 'iso' in its time table")
    k = U.TIME_NS[unit]
    x = a.to_numpy().astype(np.int64) if pa.types.is_integer(a.type) else floats(raw, col)
    big = np.abs(x) > 9.2e18 / k  # int64 ns hold +-292 years: beyond, the product would wrap around
    if big.any():
        i = int(np.argmax(big))
        raise UserError(f"{raw.file}: time column {col!r} {raw.row(i)}: {x[i]:.6g} {unit} is beyond the "
                        "+-292 years that int64 nanoseconds hold: is the time unit right?")
    if pa.types.is_integer(a.type):
        return x * np.int64(k)
    whole = np.floor(x)
    return whole.astype(np.int64) * np.int64(k) + np.round((x - whole) * k).astype(np.int64)


def _text_to_number(raw: RawTable, col: str, a):
    """Time column read as text (CSV): int64 when every cell is an integer (exact ns), else float64
    (Arrow's parser rounds correctly); UserError naming the first bad row otherwise."""
    pa, pc, _ = _pa()
    for typ in (pa.int64(), pa.float64()):
        try:
            return pc.cast(a, typ)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            continue
    vals = a.to_pylist()  # error path only
    for i, v in enumerate(vals):
        try:
            float(v)
        except (TypeError, ValueError):
            hint = " (date/time text: use base = 'iso')" if re.search(r"\d[-:T]\d", str(v)) else ""
            raise UserError(f"{raw.file}: time column {col!r} {raw.row(i)}: {v!r} is not a number{hint}") from None
    raise UserError(f"{raw.file}: time column {col!r}: cannot read as numbers")


def times_ns(raw: RawTable, spec: TimeSpec, liftoff_ns: int) -> np.ndarray:
    """int64 UTC ns of every row (see the module docstring for the bases)."""
    pa, pc, _ = _pa()
    col = spec.column
    try:
        if spec.base == "iso":
            a = raw.columns[col]
            if pa.types.is_string(a.type) or pa.types.is_large_string(a.type):
                a = _parse_iso(raw, col, a)
            if not pa.types.is_timestamp(a.type):
                raise UserError(f"{raw.file}: time column {col!r} holds {a.type}; base 'iso' expects "
                                "ISO-8601 text like 2019-06-13T02:21:00.05Z or a timestamp column")
            if a.null_count:
                i = int(np.flatnonzero(a.is_null().to_numpy(zero_copy_only=False))[0])
                raise UserError(f"{raw.file}: time column {col!r} {raw.row(i)}: empty value")
            t = a.cast(pa.timestamp("ns", tz=a.type.tz)).cast(pa.int64()).to_numpy()
        elif spec.base == "unix":
            t = _number_to_ns(raw, col, spec.unit)
        elif spec.base == "mission":
            t = np.int64(liftoff_ns) + _number_to_ns(raw, col, spec.unit)
        elif spec.base == "gps":
            t = gps_to_utc_ns(_number_to_ns(raw, col, spec.unit), beyond_table="hold")
        elif spec.base == "gps_week":
            sec = floats(raw, col) * U.TIME[spec.unit]
            week = (np.full(raw.nrows, spec.week, np.int64) if spec.week is not None
                    else floats(raw, spec.week_column).astype(np.int64))
            t = gps_week_seconds_to_utc_ns(week, sec, beyond_table="hold")
        else:  # pragma: no cover - the mapping validates the base
            raise UserError(f"time base {spec.base!r}")
    except ValueError as exc:
        raise UserError(f"{raw.file}: time column {col!r}: {exc}") from None
    t = np.asarray(t, dtype=np.int64)
    if spec.offset_s:
        t = t + np.int64(round(spec.offset_s * 1e9))
    return t


def _parse_iso(raw: RawTable, col: str, a):
    pa, pc, _ = _pa()
    for typ in (pa.timestamp("ns", tz="UTC"), pa.timestamp("ns")):
        try:
            return pc.cast(a, typ)
        except pa.ArrowInvalid:
            continue
    vals = a.to_pylist()  # error path only: find the first bad row
    for i, v in enumerate(vals):
        try:
            pc.cast(pa.array([v]), pa.timestamp("ns", tz="UTC"))
        except pa.ArrowInvalid:
            try:
                pc.cast(pa.array([v]), pa.timestamp("ns"))
            except pa.ArrowInvalid:
                raise UserError(f"{raw.file}: time column {col!r} {raw.row(i)}: {v!r} is not an ISO-8601 "
                                "UTC time like 2019-06-13T02:21:00.05Z") from None
    raise UserError(f"{raw.file}: time column {col!r}: mixed ISO-8601 forms (some with a zone, some without)")


@dataclass
class OrderInfo:
    """What ``order_rows`` found: rows out of order and duplicate stamps (counts, first row)."""
    out_of_order: int = 0
    duplicates: int = 0
    first_row: str = ""
    sorted: bool = False


def order_rows(raw: RawTable, t: np.ndarray, unsorted: str, what: str,
               row_index: np.ndarray | None = None) -> tuple[np.ndarray | None, OrderInfo]:
    """Check that ``t`` strictly increases. ``unsorted = "error"``: UserError naming the first bad
    row; ``"sort"``: the index that sorts (stable) and keeps the first row of each duplicate stamp."""
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    info = OrderInfo()
    if len(bad) == 0:
        return None, info
    i = int(bad[0]) + 1
    row = raw.row(int(row_index[i]) if row_index is not None else i)
    info.out_of_order = int(np.count_nonzero(d < 0))
    info.duplicates = int(np.count_nonzero(d == 0))
    info.first_row = row
    if unsorted == "error":
        kind = "repeats" if d[i - 1] == 0 else "goes back"
        from nav.timescales import format_utc
        raise UserError(f"{raw.file}: time stamps are not increasing ({what}): {row} {kind} to "
                        f"{format_utc(int(t[i]), 6)} after {format_utc(int(t[i - 1]), 6)} "
                        f"({info.out_of_order} steps back, {info.duplicates} repeats in the file); "
                        f"fix the file or set unsorted = \"sort\" in the mapping's table")
    order = np.argsort(t, kind="stable")
    ts = t[order]
    keep = np.r_[True, np.diff(ts) > 0]
    info.duplicates = int(np.count_nonzero(~keep))
    info.sorted = True
    return order[keep], info


def apply_axes(v_s: np.ndarray, axes: AxisMap) -> np.ndarray:
    """``v_b = R_bs v_s`` for (N, 3) rows; exact for a signed permutation."""
    if axes.perm is not None:
        out = v_s[:, list(axes.perm)]
        neg = [i for i, s in enumerate(axes.signs) if s < 0]
        if neg:
            out[:, neg] = -out[:, neg]
        return out
    return v_s @ axes.R_bs.T


def _triad(raw: RawTable, cols, factor: float) -> np.ndarray:
    v = np.column_stack([floats(raw, c) for c in cols])
    return v * factor if factor != 1.0 else v


@dataclass
class ImuData:
    """IMU samples in SI, body frame: ``gyro`` [rad/s] and ``accel`` [m/s^2] (rates) or increments
    [rad], [m/s] with ``dt`` (N,) [s]; ``t_ns`` UTC; ``output`` "rate" / "increment"."""
    file: Path
    t_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    output: str
    dt: np.ndarray | None
    rows: int
    order: OrderInfo = field(default_factory=OrderInfo)
    gyro_range: float | None = None
    accel_range: float | None = None


def read_imu(spec: ImuSpec, liftoff_ns: int) -> ImuData:
    """Read, convert and axis-map an IMU table (module docstring)."""
    ts = spec.table.time
    data_cols = [*spec.gyro.columns, *spec.accel.columns] + ([spec.dt_column] if spec.dt_column else [])
    time_cols = [ts.column] + ([ts.week_column] if ts.week_column else [])
    raw = read_table(spec.table, time_cols + data_cols, float_columns=data_cols, what="[imu]",
                     text_columns=[ts.column])
    if raw.nrows == 0:
        raise UserError(f"{spec.table.file}: no data rows")
    t = times_ns(raw, ts, liftoff_ns)
    gyro = apply_axes(_triad(raw, spec.gyro.columns, spec.gyro.factor), spec.axes)
    accel = apply_axes(_triad(raw, spec.accel.columns, spec.accel.factor), spec.axes)
    dt = None
    if spec.sample == "increment":
        if spec.dt_column:
            dt = floats(raw, spec.dt_column) * U.TIME[spec.dt_unit]
    idx, info = order_rows(raw, t, spec.table.unsorted, "[imu]")
    if idx is not None:
        t, gyro, accel = t[idx], gyro[idx], accel[idx]
        dt = None if dt is None else dt[idx]
    if spec.sample == "increment" and dt is None:
        # interval of each increment = time since the previous sample; the first one takes the median step
        d = np.diff(t).astype(np.float64) / 1e9
        dt = np.r_[np.median(d) if len(d) else 0.0, d]
    return ImuData(spec.table.file, t, gyro, accel, spec.sample, dt, raw.nrows, info,
                   spec.gyro_range, spec.accel_range)


@dataclass
class GpsData:
    """GPS fixes: ``t_ns`` UTC, ``position`` / ``velocity`` (N, 3) ECEF [m], [m/s], covariances
    (N, 3, 3). Position-only fixes (no velocity mapped, ``has_velocity`` False) have NaN velocities
    and velocity covariances: "no measurement", never a zero velocity known exactly.
    ``sigma_default``: which uncertainties came from the mapping's defaults ("" = none)."""
    file: Path
    t_ns: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    position_cov: np.ndarray
    velocity_cov: np.ndarray
    num_satellites: np.ndarray
    has_velocity: bool
    rows: int
    dropped_rows: int = 0
    order: OrderInfo = field(default_factory=OrderInfo)
    sigma_default: str = ""


def _cov_matrix(raw: RawTable, c: Covariance | None, n: int, R_en: np.ndarray | None, keep) -> np.ndarray:
    if c is None:
        return np.zeros((n, 3, 3))
    if c.kind == "sigma":
        if c.value is not None:
            s = np.full((n, 3), c.value * c.factor)
        else:
            cols = [floats(raw, col, allow_missing=True)[keep] * c.factor for col in c.columns]
            s = np.column_stack(cols * 3 if len(cols) == 1 else cols)
        P = np.zeros((n, 3, 3))
        P[:, [0, 1, 2], [0, 1, 2]] = s * s
    else:
        v = np.column_stack([floats(raw, col, allow_missing=True)[keep] for col in c.columns]) * c.factor
        if v.shape[1] == 9:
            P = v.reshape(n, 3, 3)
        else:
            xx, xy, xz, yy, yz, zz = v.T
            P = np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)
    if c.frame == "ned":
        P = R_en @ P @ np.swapaxes(R_en, -1, -2)
    return np.nan_to_num(P)


def read_gps(spec: GpsSpec, liftoff_ns: int) -> GpsData:
    """Read a GPS table: ECEF or geodetic positions, ECEF or NED velocities, sigmas / covariances.
    Rows without a position (empty cells: no fix) are dropped and counted."""
    ts = spec.table.time
    cov_cols = [c for cv in (spec.position_cov, spec.velocity_cov) if cv is not None for c in cv.columns]
    data_cols = [*spec.position, *(spec.velocity or ()), *cov_cols] + (
        [spec.num_satellites] if spec.num_satellites else [])
    time_cols = [ts.column] + ([ts.week_column] if ts.week_column else [])
    raw = read_table(spec.table, time_cols + data_cols, float_columns=data_cols, what="[gps]",
                     text_columns=[ts.column])
    if raw.nrows == 0:
        raise UserError(f"{spec.table.file}: no data rows")
    p = np.column_stack([floats(raw, c, allow_missing=True) for c in spec.position])
    v = (np.column_stack([floats(raw, c, allow_missing=True) for c in spec.velocity])
         if spec.velocity else np.zeros_like(p))
    keep = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(v), axis=1)
    if not spec.velocity:
        v = np.full_like(p, np.nan)
    raw_keep = keep
    t = times_ns(raw, ts, liftoff_ns)[keep]
    p, v = p[keep], v[keep]
    n = len(t)
    if spec.position_frame == "geodetic":
        lat, lon, h = p[:, 0] * spec.angle_factor, p[:, 1] * spec.angle_factor, p[:, 2] * spec.position_factor
        if np.any(np.abs(lat) > np.pi / 2):
            i = int(np.flatnonzero(keep)[np.argmax(np.abs(lat) > np.pi / 2)])
            raise UserError(f"{raw.file}: column {spec.position[0]!r} {raw.row(i)}: latitude "
                            f"{p[np.argmax(np.abs(lat) > np.pi / 2), 0]:g} beyond 90 deg: is angle_unit "
                            f"(declared {'rad' if spec.angle_factor == 1.0 else 'deg'}) right?")
        x = earth.geodetic_to_ecef(lat, lon, h)
    else:
        x = p * spec.position_factor if spec.position_factor != 1.0 else p
        lat = lon = None
    need_ned = spec.velocity_frame == "ned" or any(
        c is not None and c.frame == "ned" for c in (spec.position_cov, spec.velocity_cov))
    R = None
    if need_ned and n:
        if lat is None:
            lat, lon, _ = earth.ecef_to_geodetic(x)
        R = earth.R_en(lat, lon)
    if spec.velocity:
        v = v * spec.velocity_factor if spec.velocity_factor != 1.0 else v
        if spec.velocity_frame == "ned":
            v = np.einsum("nij,nj->ni", R, v)
    Pp = _cov_matrix(raw, spec.position_cov, n, R, raw_keep)
    Pv = (_cov_matrix(raw, spec.velocity_cov, n, R, raw_keep) if spec.velocity
          else np.full((n, 3, 3), np.nan))
    note = spec.sigma_default
    for P, name, sig, on in ((Pp, "position", spec.fallback_sigmas[0], True),
                             (Pv, "velocity", spec.fallback_sigmas[1], spec.velocity is not None)):
        bad = ~_positive_definite(P) if on and n else np.zeros(0, bool)
        if bad.any():  # a zero or missing uncertainty would make the filter reject the fix (or trust it fully)
            P[bad] = np.eye(3) * sig * sig
            note += ("; " if note else "") + (f"{int(bad.sum())} fix(es) with a zero, missing or non-positive "
                                              f"{name} uncertainty take {sig:g} {'m' if name == 'position' else 'm/s'}")
    ns = (np.nan_to_num(floats(raw, spec.num_satellites, allow_missing=True)[keep]).astype(np.uint16)
          if spec.num_satellites else np.zeros(n, np.uint16))
    idx, info = order_rows(raw, t, spec.table.unsorted, "[gps]", np.flatnonzero(keep))
    if idx is not None:
        t, x, v, Pp, Pv, ns = t[idx], x[idx], v[idx], Pp[idx], Pv[idx], ns[idx]
    return GpsData(spec.table.file, t, x, v, Pp, Pv, ns, spec.velocity is not None, raw.nrows,
                   int(np.count_nonzero(~keep)), info, note)


def _positive_definite(P: np.ndarray) -> np.ndarray:
    """Per (3, 3) matrix: finite, symmetric and positive definite (smallest eigenvalue > 0)."""
    ok = np.all(np.isfinite(P), axis=(1, 2))
    ok &= np.all(np.abs(P - np.swapaxes(P, 1, 2)) <= 1e-9 * np.abs(P).max(axis=(1, 2), initial=0)[:, None, None],
                 axis=(1, 2))
    ev = np.linalg.eigvalsh(np.where(ok[:, None, None], P, np.eye(3)))
    return ok & (ev[:, 0] > 0)


# ------------------------------------------------------------------------------------------------
# time probe: the first and last rows of a table, read without parsing the rest of the file
PROBE_BYTES = 1 << 20  #: bytes read from each end of a CSV file by :func:`probe_times`


def probe_times(spec: TableSpec, columns: list[str]) -> tuple[RawTable, RawTable, int]:
    """The time ``columns`` of the first and the last rows of a table, as two ``RawTable``, and an
    estimate of the row count: a CSV is read ``PROBE_BYTES`` from each end (the tail's first, cut
    line is dropped), a Parquet file its first and last row groups. Memory and time do not depend
    on the file's size, so the time checks run before anything is allocated for the whole table."""
    pa, pc, pcsv = _pa()
    cols = list(dict.fromkeys(c for c in columns if c))
    names = header(spec)
    missing = [c for c in cols if c not in names]
    if missing:
        raise UserError(f"{spec.file}: missing column(s) {missing}; the file has {names}")
    if spec.format == "parquet":
        import pyarrow.parquet as pq
        try:
            pf = pq.ParquetFile(spec.file)
            n, g = pf.metadata.num_rows, pf.num_row_groups
            head = pf.read_row_group(0, columns=cols) if g else pa.table({c: [] for c in cols})
            tail = pf.read_row_group(g - 1, columns=cols) if g else head
        except Exception as exc:  # noqa: BLE001 - pyarrow raises several types for bad files
            raise UserError(f"{spec.file}: cannot read as Parquet ({exc})") from None
        return (RawTable(spec.file, "parquet", {c: head.column(c) for c in cols}, head.num_rows),
                RawTable(spec.file, "parquet", {c: tail.column(c) for c in cols}, tail.num_rows), n)
    size = spec.file.stat().st_size
    with open(spec.file, "rb") as fh:
        first = fh.read(PROBE_BYTES)
        lines = first.split(b"\n", spec.skip_rows + 1)
        if len(lines) < spec.skip_rows + 2:
            raise UserError(f"{spec.file}: no data rows")
        header_line = lines[spec.skip_rows] + b"\n"
        body = lines[-1]
        if size <= 2 * PROBE_BYTES:  # small file: all of it
            body += fh.read()
            head_bytes = last = body
        else:
            head_bytes = body[:body.rfind(b"\n") + 1]
            fh.seek(size - PROBE_BYTES)
            last = fh.read()
            last = last[last.find(b"\n") + 1:]
    types = {c: pa.string() for c in cols}

    def parse(b: bytes):
        import io
        try:
            return pcsv.read_csv(io.BytesIO(header_line + b), read_options=pcsv.ReadOptions(use_threads=False),
                                 parse_options=pcsv.ParseOptions(delimiter=spec.delimiter),
                                 convert_options=pcsv.ConvertOptions(include_columns=cols, column_types=types))
        except pa.ArrowInvalid as exc:
            raise UserError(f"{spec.file}: cannot parse CSV ({exc})") from None

    h, t = parse(head_bytes), parse(last)
    est = int(round(size / max(len(head_bytes), 1) * h.num_rows)) if h.num_rows else 0
    return (RawTable(spec.file, "csv", {c: h.column(c) for c in cols}, h.num_rows, spec.skip_rows),
            RawTable(spec.file, "csv", {c: t.column(c) for c in cols}, t.num_rows, spec.skip_rows), est)


def times_s(raw: RawTable, spec: TimeSpec, liftoff_ns: int) -> np.ndarray:
    """Approximate UTC seconds since the Unix epoch (float64, leap seconds ignored) of every row:
    the plausibility checks' time, which cannot overflow whatever the numbers and the unit."""
    pa, _, _ = _pa()
    if spec.base == "iso":
        return times_ns(raw, spec, liftoff_ns) / 1e9
    a = raw.columns[spec.column]
    if pa.types.is_timestamp(a.type):
        raise UserError(f"{raw.file}: time column {spec.column!r} holds timestamps; use base = 'iso' in its time table")
    x = floats(raw, spec.column) * U.TIME[spec.unit] + spec.offset_s
    if spec.base == "unix":
        return x
    if spec.base == "mission":
        return liftoff_ns / 1e9 + x
    # GPS time runs ahead of UTC by the leap seconds since 1980: those at the lift-off (exact near it)
    from nav.timescales import utc_to_gps_ns
    gps0 = GPS_EPOCH_S - (GPS_EPOCH_S * 1e9 + int(utc_to_gps_ns(liftoff_ns, beyond_table="hold")) - liftoff_ns) / 1e9
    if spec.base == "gps":
        return gps0 + x
    week = (np.full(raw.nrows, spec.week, np.float64) if spec.week is not None
            else floats(raw, spec.week_column))
    return gps0 + week * 604800.0 + x


GPS_EPOCH_S = 315_964_800.0  #: 1980-01-06T00:00:00Z in Unix seconds
