"""``horizon-nav ephem``: Sun and Moon seen from a point at a UTC time (azimuth, elevation, range)."""
from __future__ import annotations

import json

import numpy as np

from nav import earth, ephemeris, timescales
from nav.rotation import angle_between

NAME = "ephem"
HELP = "Sun and Moon azimuth/elevation/apparent radius from a geodetic point at a UTC time"


def add_arguments(p) -> None:
    p.add_argument("--time", default="2019-06-13T02:21:00Z", help="UTC, ISO-8601 (default: ATEK lift-off)")
    p.add_argument("--lat", type=float, default=67.89, help="geodetic latitude [deg] (default Esrange)")
    p.add_argument("--lon", type=float, default=21.10, help="longitude [deg]")
    p.add_argument("--height", type=float, default=0.0, help="height above the ellipsoid [m]")
    p.add_argument("--dut1", type=float, default=0.0, help="UT1 - UTC [s] (default 0)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def look_angles(t_ns: int, lat: float, lon: float, h: float, dut1: float = 0.0) -> dict:
    """Azimuth/elevation [deg] of Sun and Moon from a geodetic point (lat, lon in rad)."""
    x = earth.geodetic_to_ecef(lat, lon, h)
    R_ne = earth.R_en(lat, lon).T
    out = {"time_utc": timescales.format_utc(t_ns), "lat_deg": np.degrees(lat), "lon_deg": np.degrees(lon),
           "height_m": h, "earth_horizon_dip_deg": float(np.degrees(np.arccos(earth.R_MEAN / (earth.R_MEAN + max(h, 0.0)))))}
    for body, pos, radius in (("sun", ephemeris.sun_position_e, ephemeris.SUN_RADIUS),
                              ("moon", ephemeris.moon_position_e, ephemeris.MOON_RADIUS)):
        X = pos(t_ns, dut1_s=dut1)
        d_n = R_ne @ ((X - x) / np.linalg.norm(X - x))
        out[body] = {
            "azimuth_deg": float(np.degrees(np.arctan2(d_n[1], d_n[0])) % 360.0),
            "elevation_deg": float(np.degrees(-np.arcsin(d_n[2]))),
            "range_m": float(np.linalg.norm(X - x)),
            "apparent_radius_deg": float(np.degrees(ephemeris.apparent_radius(X, x, radius))),
            "parallax_deg": float(np.degrees(angle_between(X - x, X))),
        }
    return out


def run(args) -> int:
    t = timescales.parse_utc(args.time)
    res = look_angles(t, np.radians(args.lat), np.radians(args.lon), args.height, args.dut1)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"{res['time_utc']}  lat {res['lat_deg']:.4f} deg  lon {res['lon_deg']:.4f} deg  h {args.height:.0f} m")
    print(f"{'body':6s} {'azimuth':>10s} {'elevation':>10s} {'range [km]':>14s} {'radius':>9s} {'parallax':>9s}")
    for body in ("sun", "moon"):
        b = res[body]
        print(f"{body:6s} {b['azimuth_deg']:9.3f}° {b['elevation_deg']:9.3f}° {b['range_m'] / 1e3:14.1f} "
              f"{b['apparent_radius_deg']:8.4f}° {b['parallax_deg']:8.4f}°")
    print(f"geometric horizon dip below the local horizontal: {res['earth_horizon_dip_deg']:.3f}°")
    return 0
