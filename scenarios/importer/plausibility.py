"""Time plausibility of an import, checked before any table is read whole.

Each table's time column is probed (:func:`scenarios.importer.tables.probe_times`: the first and
the last rows, about 1 MiB from each end of a CSV, the first and last row groups of a Parquet
file), converted with the declared ``base`` and ``unit`` to approximate UTC seconds (float64,
which cannot overflow whatever the numbers), and checked:

* **start**: the record starts within ``span_max_h`` of the mapping's ``liftoff_utc`` (a flight log
  is recorded around its lift-off; Unix milliseconds read as seconds start in the year 51 000,
  GPS seconds of week read as Unix seconds in January 1970);
* **span**: last minus first stamp between 0 and ``span_max_h`` (a flight lasts minutes to hours);
* **rate**: the median step of the first rows gives a rate within the sensor's band (IMU 1 Hz to
  10 kHz, GPS 0.02 Hz to 100 Hz: a unit off by 1000 moves the rate out of both);
* **overlap**: the IMU and GPS records share some time.

A stream that fails is one line (``UserError``) saying what the declared unit gives and, when one
exists, which unit or base would fit (every base and unit is tried on the same numbers; GPS
seconds of week are tried with the week of the lift-off). The rest of the import then never sees
time stamps decades apart, so no allocation or window loop grows with them.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from nav.timescales import format_utc
from scenarios.errors import UserError

from . import tables as T
from .mapping import Mapping, TableSpec, TimeSpec

#: sample-rate bands [Hz]: an IMU runs from 1 Hz (slow telemetry) to 10 kHz (raw MEMS output); a
#: GNSS receiver from one fix a minute (a decimated log) to 100 Hz (the fastest receivers)
RATE_BAND_HZ = {"imu": (1.0, 10_000.0), "gps": (0.02, 100.0)}
UNITS = ("s", "ms", "us", "ns")
BASES = ("unix", "gps", "mission", "gps_week")
SEC_PER_WEEK = 604_800.0


@dataclass
class TimeStats:
    start_s: float  #: first stamp, UTC seconds since the Unix epoch (approximate)
    end_s: float
    rate_hz: float | None  #: 1 / median step of the first rows (None: fewer than two rows)

    @property
    def span_s(self) -> float:
        return self.end_s - self.start_s


def _stats(head, tail, spec: TimeSpec, liftoff_ns: int) -> TimeStats:
    th = T.times_s(head, spec, liftoff_ns)
    tt = T.times_s(tail, spec, liftoff_ns)
    both = np.r_[th, tt]
    d = np.diff(th)
    d = d[d > 0]
    return TimeStats(float(both.min()), float(both.max()), float(1.0 / np.median(d)) if d.size else None)


def _problems(name: str, st: TimeStats, liftoff_ns: int, span_max_s: float) -> list[str]:
    out = []
    lift = liftoff_ns / 1e9
    if not np.isfinite(st.start_s) or abs(st.start_s - lift) > span_max_s:
        out.append(f"starts {_when(st.start_s)}, {_dur(abs(st.start_s - lift))} from liftoff_utc")
    if st.span_s > span_max_s:
        out.append(f"spans {_dur(st.span_s)}")
    lo, hi = RATE_BAND_HZ[name]
    if st.rate_hz is not None and not lo <= st.rate_hz <= hi:
        out.append(f"runs at {st.rate_hz:.3g} Hz (expected {lo:g} to {hi:g} Hz)")
    return out


def _when(t_s: float) -> str:
    if not np.isfinite(t_s) or not -6e10 < t_s < 6e10:
        return f"at {t_s:.3g} s from 1970"
    if not 0 <= t_s < 4.1e9:
        return f"in the year {1970 + t_s / 31_557_600:.0f}"
    return format_utc(int(t_s * 1e9), 0)


def _dur(s: float) -> str:
    s = abs(s)
    if s >= 2 * 86400:
        return f"{s / 86400:.3g} days"
    if s >= 7200:
        return f"{s / 3600:.3g} h"
    return f"{s:.4g} s"


def _describe(spec: TimeSpec) -> str:
    if spec.base == "gps_week" and spec.week is not None and spec.week_column is None:
        return f"base = 'gps_week', week = {spec.week}, unit = '{spec.unit}'"
    return f"base = '{spec.base}', unit = '{spec.unit}'"


def _alternatives(spec: TimeSpec, head, tail, name, liftoff_ns, span_max_s):
    """Time specs (other unit and / or base) under which the same numbers pass every check."""
    if spec.base == "iso":
        return []
    from nav.timescales import utc_to_gps_ns
    week = int(utc_to_gps_ns(liftoff_ns, beyond_table="hold") // (SEC_PER_WEEK * 1e9))
    found = []
    for base in sorted(BASES, key=lambda b: b != spec.base):
        for unit in sorted(UNITS, key=lambda u: u != spec.unit):
            if (base, unit) == (spec.base, spec.unit):
                continue
            if base == "gps_week":
                alt = (replace(spec, base=base, unit=unit) if spec.base == "gps_week"
                       else replace(spec, base=base, unit=unit, week=week, week_column=None))
            elif spec.base == "gps_week":
                alt = replace(spec, base=base, unit=unit, week=None, week_column=None)
            else:
                alt = replace(spec, base=base, unit=unit)
            try:
                st = _stats(head, tail, alt, liftoff_ns)
            except UserError:
                continue
            if not _problems(name, st, liftoff_ns, span_max_s):
                found.append((alt, st))
    return found


def check_table_times(name: str, spec: TableSpec, where: str, liftoff_ns: int, span_max_s: float) -> TimeStats:
    """Probe one table's stamps and check them (module docstring); UserError on failure."""
    ts = spec.time
    head, tail, _ = T.probe_times(spec, [ts.column, ts.week_column])
    if head.nrows == 0:
        raise UserError(f"{spec.file}: no data rows")
    st = _stats(head, tail, ts, liftoff_ns)
    bad = _problems(name, st, liftoff_ns, span_max_s)
    if not bad:
        return st
    msg = (f"{spec.file}: {where}: {_describe(ts)} gives a record that " + ", ".join(bad)
           + (f" at {st.rate_hz:.3g} Hz" if st.rate_hz is not None and not any("Hz" in b for b in bad) else ""))
    alts = _alternatives(ts, head, tail, name, liftoff_ns, span_max_s)
    if alts:
        alt, a = alts[0]
        msg += (f"; {_describe(alt)} would give {_dur(a.span_s)}"
                + (f" at {a.rate_hz:.4g} Hz" if a.rate_hz is not None else "")
                + f" from {_when(a.start_s)}: fix [{where}]")
    else:
        msg += f"; no time unit or base fits these numbers: check [{where}] and liftoff_utc"
    raise UserError(msg)


def check_times(m: Mapping) -> dict:
    """Every table's time plausibility and the IMU / GPS overlap (module docstring); returns
    ``{stream: TimeStats}``. Raises UserError (one line) on the first problem."""
    span_max = m.checks.span_max_h * 3600.0
    out = {}
    if m.imu is not None:
        out["imu"] = check_table_times("imu", m.imu.table, "imu.time", m.liftoff_ns, span_max)
    if m.gps is not None:
        out["gps"] = check_table_times("gps", m.gps.table, "gps.time", m.liftoff_ns, span_max)
    if "imu" in out and "gps" in out:
        a, b = out["imu"], out["gps"]
        if a.end_s < b.start_s or b.end_s < a.start_s:
            lift = m.liftoff_ns / 1e9
            raise UserError(f"{m.path}: the IMU (T+{a.start_s - lift:.3f} to T+{a.end_s - lift:.3f} s) and the GPS "
                            f"(T+{b.start_s - lift:.3f} to T+{b.end_s - lift:.3f} s) records do not overlap: "
                            "check the time base, unit and offset_s of [imu.time] and [gps.time]")
    return out
