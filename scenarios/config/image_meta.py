"""Per-image metadata sidecars for ``horizon-nav vision``: a CSV or JSON file giving each image's
time, height, latitude/longitude or position, matched by the image's file name.

Fields (CSV: a header row naming the columns; JSON: a list of objects, or an object mapping each
image name to an object), every one but ``image`` optional, an empty CSV cell or a JSON null
meaning "not given":

=========== ========================================================================
image       file name of the image (its base name is matched)
time        UTC, ISO 8601 (``2024-03-01T12:00:00.250Z``): the Moon's distance from the
            ephemeris (its apparent radius, `vision.config.FramePrior.moon_alpha`)
height_m    height above the WGS-84 ellipsoid [m] (the Earth cone, 003 eq. (5))
lat_deg     geodetic latitude [deg] (the local radius of curvature, 003 §2.8)
lon_deg     longitude [deg] (with lat_deg and height_m: the position, for the Moon's parallax)
x_m y_m z_m position in the Earth-fixed frame (ECEF) [m], all three or none; gives the height and
            latitude, so it excludes height_m, lat_deg and lon_deg
=========== ========================================================================

A bad value, an unknown column, a repeated image or a half-given position is a `UserError` naming
the file, the row (CSV: the line number; JSON: the entry) and the column.
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenarios.errors import UserError

__all__ = ["ImageMeta", "FIELDS", "read_image_meta"]

FIELDS = ("image", "time", "height_m", "lat_deg", "lon_deg", "x_m", "y_m", "z_m")


@dataclass(frozen=True)
class ImageMeta:
    """One image's metadata: UTC time [ns], height [m], latitude and longitude [rad], ECEF
    position [m]; None where not given (the position is filled in from latitude, longitude and
    height when all three are given, and height/latitude from the position)."""

    time_ns: int | None = None
    height_m: float | None = None
    lat: float | None = None
    lon: float | None = None
    x_e: np.ndarray | None = None


def _number(v, where: str, lo: float, hi: float, unit: str) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise UserError(f"{where}: {v!r} is not a number ({unit})") from None
    if not (math.isfinite(x) and lo <= x <= hi):
        raise UserError(f"{where}: {x:g}; expected {unit} in [{lo:g}, {hi:g}]")
    return x


def _meta(row: dict, where: str) -> ImageMeta:
    """The `ImageMeta` of one row (a dict of the given, non-empty fields)."""
    from nav import earth
    from nav.timescales import parse_utc

    t = None
    if "time" in row:
        try:
            t = parse_utc(str(row["time"]))
        except ValueError as exc:
            raise UserError(f"{where}, column time: {exc}") from None
    h = _number(row["height_m"], f"{where}, column height_m", -1e4, 5e7, "a height [m]") if "height_m" in row else None
    lat = _number(row["lat_deg"], f"{where}, column lat_deg", -90, 90, "a latitude [deg]") if "lat_deg" in row else None
    lon = _number(row["lon_deg"], f"{where}, column lon_deg", -360, 360, "a longitude [deg]") if "lon_deg" in row else None
    pos = [k for k in ("x_m", "y_m", "z_m") if k in row]
    x = None
    if pos:
        if len(pos) != 3:
            miss = sorted({"x_m", "y_m", "z_m"} - set(pos))
            raise UserError(f"{where}, column {miss[0]}: missing; the position needs x_m, y_m and z_m")
        given = [k for k in ("height_m", "lat_deg", "lon_deg") if k in row]
        if given:
            raise UserError(f"{where}, column {given[0]}: give either the position (x_m, y_m, z_m) or "
                            f"height_m/lat_deg/lon_deg, not both")
        x = np.array([_number(row[k], f"{where}, column {k}", -5e7, 5e7, "an ECEF coordinate [m]") for k in pos])
        la, lo, hh = earth.ecef_to_geodetic(x)
        return ImageMeta(t, float(hh), float(la), float(lo), x)
    la = None if lat is None else math.radians(lat)
    lo = None if lon is None else math.radians(lon)
    if la is not None and lo is not None and h is not None:
        x = np.asarray(earth.geodetic_to_ecef(la, lo, h), dtype=float)
    return ImageMeta(t, h, la, lo, x)


def _rows_csv(path: Path):
    """(where, row dict without empty cells) per data row of a CSV sidecar."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise UserError(f"{path}: cannot read the metadata file ({exc.strerror})") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise UserError(f"{path}: not a CSV text file ({exc})") from None
    if not rows:
        raise UserError(f"{path}: empty; expected a header row naming the columns {', '.join(FIELDS)}")
    head = [c.strip() for c in rows[0]]
    _check_columns(head, f"{path}, line 1")
    for i, r in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in r):
            continue
        if len(r) != len(head):
            raise UserError(f"{path}, line {i}: {len(r)} cells, the header has {len(head)}")
        yield f"{path}, line {i}", {k: c.strip() for k, c in zip(head, r) if c.strip()}


def _rows_json(path: Path):
    """(where, row dict without nulls) per entry of a JSON sidecar."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UserError(f"{path}: cannot read the metadata file ({exc.strerror})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not valid JSON ({exc})") from None
    if isinstance(doc, dict):
        doc = [{"image": k, **v} if isinstance(v, dict) else v for k, v in doc.items()]
    if not isinstance(doc, list):
        raise UserError(f"{path}: expected a list of objects or an object of image name -> object")
    for i, r in enumerate(doc, start=1):
        where = f"{path}, entry {i}"
        if not isinstance(r, dict):
            raise UserError(f"{where}: {type(r).__name__}; expected an object with the fields {', '.join(FIELDS)}")
        _check_columns(list(r), where)
        yield where, {k: v for k, v in r.items() if v is not None}


def _check_columns(names: list, where: str) -> None:
    bad = [c for c in names if c not in FIELDS]
    if bad:
        raise UserError(f"{where}, column {bad[0]!r}: unknown; expected {', '.join(FIELDS)}")
    if "image" not in names:
        raise UserError(f"{where}, column image: missing (the image file name each row is for)")


def read_image_meta(path) -> dict[str, ImageMeta]:
    """{image base name: `ImageMeta`} from a ``.csv`` or ``.json`` sidecar (module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: metadata file not found")
    suffix = p.suffix.lower()
    if suffix not in (".csv", ".json"):
        raise UserError(f"{p}: metadata file must be .csv or .json")
    out: dict[str, ImageMeta] = {}
    for where, row in (_rows_csv(p) if suffix == ".csv" else _rows_json(p)):
        name = Path(str(row.get("image", ""))).name
        if not name:
            raise UserError(f"{where}, column image: empty; expected the image file name")
        if name in out:
            raise UserError(f"{where}, column image: {name!r} given twice")
        out[name] = _meta(row, where)
    return out
