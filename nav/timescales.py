"""Time scales: UTC, TAI, TT and GPS time as integer nanoseconds.

The absolute time type of horizon-nav is ``int64`` nanoseconds since the Unix epoch, UTC
(docs/conventions.md, "Time"). Unix time does not count leap seconds, so an instant inside a positive
leap second (23:59:60) has no UTC stamp of its own; sensors that stamp in GPS or TAI time convert
through this module. TAI - UTC comes from the IERS leap-second table below (Bulletin C); TT = TAI
+ 32.184 s; GPS = TAI - 19 s.

Times before 1972-01-01 (where the integer-second table starts) or at or after
:data:`LEAP_TABLE_EXPIRES` raise ``ValueError`` unless ``beyond_table="hold"`` is passed, which keeps
the last known TAI - UTC (what ERFA and astropy do for future dates, with a warning).
"""
from __future__ import annotations

import datetime as _dt
import re

import numpy as np

NS_PER_S = 1_000_000_000
NS_PER_DAY = 86_400 * NS_PER_S
#: Julian date of the Unix epoch 1970-01-01T00:00:00.
JD_UNIX_EPOCH = 2440587.5
TT_MINUS_TAI_NS = 32_184_000_000
TAI_MINUS_GPS_NS = 19 * NS_PER_S
#: GPS time origin, 1980-01-06T00:00:00 UTC, in Unix ns (TAI - UTC was 19 s, so GPS = UTC then).
GPS_EPOCH_UTC_NS = 315_964_800 * NS_PER_S


def _unix_ns(y: int, m: int, d: int) -> int:
    return int(_dt.datetime(y, m, d, tzinfo=_dt.timezone.utc).timestamp()) * NS_PER_S


# (UTC instant from which TAI - UTC applies, TAI - UTC in seconds). IERS Bulletin C; no leap
# second has been announced after 2017-01-01 up to the end of 2026.
_LEAPS = [
    ((1972, 1, 1), 10), ((1972, 7, 1), 11), ((1973, 1, 1), 12), ((1974, 1, 1), 13),
    ((1975, 1, 1), 14), ((1976, 1, 1), 15), ((1977, 1, 1), 16), ((1978, 1, 1), 17),
    ((1979, 1, 1), 18), ((1980, 1, 1), 19), ((1981, 7, 1), 20), ((1982, 7, 1), 21),
    ((1983, 7, 1), 22), ((1985, 7, 1), 23), ((1988, 1, 1), 24), ((1990, 1, 1), 25),
    ((1991, 1, 1), 26), ((1992, 7, 1), 27), ((1993, 7, 1), 28), ((1994, 7, 1), 29),
    ((1996, 1, 1), 30), ((1997, 7, 1), 31), ((1999, 1, 1), 32), ((2006, 1, 1), 33),
    ((2009, 1, 1), 34), ((2012, 7, 1), 35), ((2015, 7, 1), 36), ((2017, 1, 1), 37),
]
LEAP_UTC_NS = np.array([_unix_ns(*d) for d, _ in _LEAPS], dtype=np.int64)
LEAP_TAI_MINUS_UTC_S = np.array([s for _, s in _LEAPS], dtype=np.int64)
#: First UTC instant the table no longer vouches for (it is known through the end of 2026).
LEAP_TABLE_EXPIRES = _unix_ns(2027, 1, 1)
TABLE_START = int(LEAP_UTC_NS[0])


def as_time_ns(t, name: str = "t") -> np.ndarray:
    """Check and convert a time stamp argument to ``int64`` nanoseconds.

    Accepts Python/numpy integers or integer arrays. Floats are refused (a float64 holds ns since
    1970 only to about 256 ns) unless they are integral; NaN raises ``ValueError`` naming ``name``.
    """
    a = np.asarray(t)
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: time stamps must be finite integer ns since the Unix epoch, got NaN/inf")
        if np.any(a != np.round(a)):
            raise ValueError(f"{name}: time stamps must be integer ns since the Unix epoch, got fractional floats")
        a = a.astype(np.int64)
    elif a.dtype.kind not in "iu":
        raise ValueError(f"{name}: expected integer ns since the Unix epoch, got dtype {a.dtype}")
    return a.astype(np.int64, copy=False)


def _check_range(utc_ns: np.ndarray, name: str, beyond_table: str) -> None:
    if beyond_table not in ("raise", "hold"):
        raise ValueError(f"beyond_table: expected 'raise' or 'hold', got {beyond_table!r}")
    if np.any(utc_ns < TABLE_START):
        bad = int(np.min(utc_ns))
        raise ValueError(f"{name}: {format_utc(bad)} is before 1972-01-01, where the leap-second table starts")
    if beyond_table == "raise" and np.any(utc_ns >= LEAP_TABLE_EXPIRES):
        bad = int(np.max(utc_ns))
        raise ValueError(
            f"{name}: {format_utc(bad)} is after the leap-second table (valid until "
            f"{format_utc(LEAP_TABLE_EXPIRES)}); pass beyond_table='hold' to assume no new leap seconds")


def tai_minus_utc_s(utc_ns, *, beyond_table: str = "raise", name: str = "utc_ns") -> np.ndarray:
    """TAI - UTC in whole seconds at the given UTC instants (IERS Bulletin C table)."""
    t = as_time_ns(utc_ns, name)
    _check_range(t, name, beyond_table)
    idx = np.searchsorted(LEAP_UTC_NS, t, side="right") - 1
    return LEAP_TAI_MINUS_UTC_S[idx]


def utc_to_tai_ns(utc_ns, *, beyond_table: str = "raise"):
    """UTC ns since the Unix epoch -> TAI ns on the same (Unix-epoch) origin."""
    t = as_time_ns(utc_ns, "utc_ns")
    return t + tai_minus_utc_s(t, beyond_table=beyond_table) * NS_PER_S


def tai_to_utc_ns(tai_ns, *, beyond_table: str = "raise"):
    """Inverse of :func:`utc_to_tai_ns`; instants inside a leap second map onto 00:00:00."""
    t = as_time_ns(tai_ns, "tai_ns")
    leap_tai = LEAP_UTC_NS + LEAP_TAI_MINUS_UTC_S * NS_PER_S
    idx = np.searchsorted(leap_tai, t, side="right") - 1
    if np.any(idx < 0):
        raise ValueError("tai_ns: before 1972-01-01, where the leap-second table starts")
    utc = t - LEAP_TAI_MINUS_UTC_S[idx] * NS_PER_S
    # Inside a leap second the TAI instant precedes the next table entry's UTC: clamp onto it.
    nxt = np.minimum(idx + 1, len(LEAP_UTC_NS) - 1)
    utc = np.where((idx + 1 < len(LEAP_UTC_NS)) & (utc >= LEAP_UTC_NS[nxt]), LEAP_UTC_NS[nxt], utc)
    _check_range(utc, "tai_ns", beyond_table)
    return utc


def utc_to_tt_ns(utc_ns, *, beyond_table: str = "raise"):
    """UTC -> Terrestrial Time, ns on the Unix-epoch origin (TT = TAI + 32.184 s)."""
    return utc_to_tai_ns(utc_ns, beyond_table=beyond_table) + TT_MINUS_TAI_NS


def tt_to_utc_ns(tt_ns, *, beyond_table: str = "raise"):
    return tai_to_utc_ns(as_time_ns(tt_ns, "tt_ns") - TT_MINUS_TAI_NS, beyond_table=beyond_table)


def utc_to_gps_ns(utc_ns, *, beyond_table: str = "raise"):
    """UTC -> GPS time in ns since the GPS epoch (1980-01-06)."""
    return utc_to_tai_ns(utc_ns, beyond_table=beyond_table) - TAI_MINUS_GPS_NS - GPS_EPOCH_UTC_NS


def gps_to_utc_ns(gps_ns, *, beyond_table: str = "raise"):
    """GPS time in ns since the GPS epoch -> UTC ns since the Unix epoch."""
    g = as_time_ns(gps_ns, "gps_ns")
    return tai_to_utc_ns(g + GPS_EPOCH_UTC_NS + TAI_MINUS_GPS_NS, beyond_table=beyond_table)


def gps_week_seconds_to_utc_ns(week, seconds, *, beyond_table: str = "raise"):
    """GPS week number (continuous, not modulo 1024) and seconds of week -> UTC ns."""
    week = np.asarray(week)
    seconds = np.asarray(seconds, dtype=np.float64)
    if not np.all(np.isfinite(seconds)):
        raise ValueError("seconds: GPS seconds of week must be finite")
    if np.any((seconds < 0) | (seconds >= 604800.0)):
        raise ValueError("seconds: GPS seconds of week must lie in [0, 604800)")
    gps_ns = week.astype(np.int64) * (604800 * NS_PER_S) + np.round(seconds * 1e9).astype(np.int64)
    return gps_to_utc_ns(gps_ns, beyond_table=beyond_table)


def ns_to_jd(t_ns) -> tuple[np.ndarray, np.ndarray]:
    """Two-part Julian date (jd1 + jd2) of ns on the Unix-epoch origin of any time scale.

    jd1 holds whole days (at midnight, .5) and jd2 the fraction, so that float64 keeps about
    10 ps of resolution (ERFA's recommended split).
    """
    t = as_time_ns(t_ns, "t_ns")
    days, rem = np.divmod(t, NS_PER_DAY)
    return JD_UNIX_EPOCH + days.astype(np.float64), rem.astype(np.float64) / NS_PER_DAY


def parse_utc(text: str) -> int:
    """ISO-8601 UTC text (``2019-06-13T02:21:00Z``, fractional seconds allowed) -> int ns."""
    if not isinstance(text, str):
        raise ValueError(f"time: expected an ISO-8601 UTC string, got {type(text).__name__}")
    s = text.strip()
    if s.endswith("Z"):
        s = s[:-1] + "+00:00"
    frac_ns = 0
    # datetime keeps microseconds only: split nanoseconds off by hand.
    if "." in s:
        head, tail = s.split(".", 1)
        digits = re.match(r"\d*", tail).group(0)
        tz = tail[len(digits):]
        frac_ns = int((digits + "000000000")[:9]) if digits else 0
        s = head + tz
    try:
        d = _dt.datetime.fromisoformat(s)
    except ValueError:
        raise ValueError(f"time: {text!r} is not an ISO-8601 UTC time like 2019-06-13T02:21:00Z") from None
    if d.tzinfo is None:
        d = d.replace(tzinfo=_dt.timezone.utc)
    d = d.astimezone(_dt.timezone.utc)
    whole = (d - _dt.datetime(1970, 1, 1, tzinfo=_dt.timezone.utc))
    return (whole.days * 86400 + whole.seconds) * NS_PER_S + frac_ns


def format_utc(t_ns: int, digits: int = 3) -> str:
    """int ns since the Unix epoch -> ISO-8601 UTC text with ``digits`` decimals of a second."""
    t = int(t_ns)
    sec, ns = divmod(t, NS_PER_S)
    base = _dt.datetime(1970, 1, 1, tzinfo=_dt.timezone.utc) + _dt.timedelta(seconds=sec)
    out = base.strftime("%Y-%m-%dT%H:%M:%S")
    if digits > 0:
        out += "." + f"{ns:09d}"[:digits]
    return out + "Z"


