"""Unit names accepted in mapping files and their factors to SI (docs/conventions.md "Units").

Each quantity kind has a table ``name -> factor`` with ``value_SI = value * factor``. Names are
matched case-sensitively after removing spaces and normalising ``²`` / ``s2`` to ``s^2``; a few common
aliases (``dps``, ``m/s2``) are listed. A unit of the wrong kind (``m/s^2`` for a gyro) is an error
naming what was expected.
"""
from __future__ import annotations

import math
import re

G0 = 9.80665  # standard gravity [m/s^2] (the same constant as scenarios.sim.scenario.G0)
DEG = math.pi / 180.0
FT = 0.3048

RATE = {"rad/s": 1.0, "mrad/s": 1e-3, "deg/s": DEG, "dps": DEG, "deg/h": DEG / 3600.0,
        "rpm": 2.0 * math.pi / 60.0, "rev/s": 2.0 * math.pi, "Hz": 2.0 * math.pi}
ANGLE = {"rad": 1.0, "mrad": 1e-3, "urad": 1e-6, "deg": DEG, "arcsec": DEG / 3600.0}
ACCEL = {"m/s^2": 1.0, "g": G0, "mg": 1e-3 * G0, "ug": 1e-6 * G0, "ft/s^2": FT, "cm/s^2": 1e-2}
VELOCITY = {"m/s": 1.0, "km/s": 1e3, "cm/s": 1e-2, "ft/s": FT, "km/h": 1.0 / 3.6, "kn": 1852.0 / 3600.0,
            "g*s": G0}
LENGTH = {"m": 1.0, "km": 1e3, "cm": 1e-2, "mm": 1e-3, "ft": FT}
TIME = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "min": 60.0, "h": 3600.0}
#: integer nanoseconds per time unit (exact integer time conversion)
TIME_NS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1, "min": 60_000_000_000,
           "h": 3_600_000_000_000}

KINDS = {"angular rate": RATE, "angle": ANGLE, "acceleration": ACCEL, "velocity": VELOCITY,
         "length": LENGTH, "time": TIME}


def normalise(name: str) -> str:
    s = str(name).replace(" ", "").replace("²", "^2").replace("µ", "u").replace("°", "deg")
    s = re.sub(r"s2$", "s^2", s)
    s = {"deg/sec": "deg/s", "rad/sec": "rad/s", "m/sec": "m/s", "m/s/s": "m/s^2", "G": "g",
         "degrees": "deg", "radians": "rad", "knots": "kn", "sec": "s"}.get(s, s)
    return s


def factor(name: str, kind: str, where: str) -> float:
    """SI factor of unit ``name`` of quantity ``kind``; ValueError naming ``where`` otherwise."""
    table = KINDS[kind]
    n = normalise(name)
    if n in table:
        return table[n]
    other = [k for k, t in KINDS.items() if n in t]
    hint = f" ({name!r} is a unit of {other[0]})" if other else ""
    raise ValueError(f"{where}: unit {name!r} is not a unit of {kind}{hint}; expected one of {sorted(table)}")


def squared_factor(name: str, kind: str, where: str) -> float:
    """Factor of a covariance unit: ``"m^2"`` or ``"(m/s)^2"`` -> factor(base)^2."""
    n = normalise(name)
    m = re.fullmatch(r"\(?([^()]+?)\)?\^2", n)
    if not m:
        raise ValueError(f"{where}: covariance unit {name!r}: expected a squared unit like 'm^2' or '(m/s)^2'")
    return factor(m.group(1), kind, where) ** 2


# Unit hints in column names: "gx [deg/s]", "gyro_x (rad/s)", "gx_dps" ...
_BRACKET = re.compile(r"[\[(]([^\])]+)[\])]\s*$")
_SUFFIX = {"dps": "deg/s", "degps": "deg/s", "deg_s": "deg/s", "degs": "deg/s", "rad_s": "rad/s",
           "rads": "rad/s", "radps": "rad/s", "mps2": "m/s^2", "m_s2": "m/s^2", "ms2": "m/s^2",
           "mps": "m/s", "m_s": "m/s", "deg": "deg", "rad": "rad"}


def unit_in_name(column: str) -> str | None:
    """The unit a column name states (``"gx [deg/s]"`` -> ``"deg/s"``, ``"gx_dps"`` -> ``"deg/s"``),
    or None."""
    m = _BRACKET.search(column)
    if m:
        return normalise(m.group(1))
    low = column.lower()
    for suf, unit in sorted(_SUFFIX.items(), key=lambda kv: -len(kv[0])):
        if low.endswith("_" + suf):
            return unit
    return None


def check_column_units(columns, declared: str, kind: str, where: str) -> None:
    """Raise ValueError when column names state units that disagree with each other (mixed units in
    one triad) or with the declared unit."""
    stated = {c: unit_in_name(c) for c in columns}
    table = KINDS[kind]
    known = {c: u for c, u in stated.items() if u is not None and u in table}
    vals = {round(math.log(table[u]), 9) for u in known.values()}
    if len(vals) > 1:
        desc = ", ".join(f"{c!r} ({u})" for c, u in known.items())
        raise ValueError(f"{where}: mixed units: the column names state different units ({desc}); "
                         "convert the columns to one unit or split them into separate mappings")
    decl = factor(declared, kind, where)
    for c, u in known.items():
        if not math.isclose(table[u], decl, rel_tol=1e-12):
            raise ValueError(f"{where}: column {c!r} states unit {u} but the mapping declares "
                             f"unit = {declared!r}; fix the mapping's unit")
