"""Camera poses for rendering and vision tests: a camera at a geodetic point looking at an azimuth
and depression, as R_ec (camera to ECEF) and x_e; and the exact limb rays of the WGS-84 ellipsoid
seen from such a pose."""
import math

import numpy as np

from nav import earth


def pose(az_deg, down_deg=20.0, h=230e3, lat=67.89, lon=21.10, roll_deg=0.0):
    """Camera at (lat, lon, h) looking ``down_deg`` below the local horizontal at azimuth ``az_deg``,
    image x horizontal (optionally rolled about the optical axis)."""
    la, lo = math.radians(lat), math.radians(lon)
    x = earth.geodetic_to_ecef(la, lo, h)
    az, el = math.radians(az_deg), -math.radians(down_deg)
    z_n = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])
    x_n = np.cross([0.0, 0.0, 1.0], z_n)
    x_n /= np.linalg.norm(x_n)
    R_nc = np.column_stack([x_n, np.cross(z_n, x_n), z_n])
    r = math.radians(roll_deg)
    Rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return earth.R_en(la, lo) @ R_nc @ Rz, np.asarray(x)


def ellipsoid_limb_rays(x_e: np.ndarray, R_ec: np.ndarray, n: int = 720,
                        atmosphere_m: float = 0.0) -> np.ndarray:
    """Exact limb rays (n, 3) in the camera frame of the WGS-84 ellipsoid (+ d) seen from x_e:
    the circle of tangency in the scaled frame mapped back (an independent construction: the
    rays are tangent to the ellipsoid, which the tests verify with `scenarios.sim.render.ray_ellipsoid`)."""
    a, b = earth.A + atmosphere_m, earth.B + atmosphere_m
    s = np.array([1.0, 1.0, a / b])
    xs = s * np.asarray(x_e, dtype=float)
    r = np.linalg.norm(xs)
    e = -xs / r
    alpha = math.asin(a / r)
    u = np.cross(e, [0.0, 0.0, 1.0]) if abs(e[2]) < 0.9 else np.cross(e, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(e, u)
    psi = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    p_s = math.cos(alpha) * e + math.sin(alpha) * (np.cos(psi)[:, None] * u + np.sin(psi)[:, None] * v)
    p_e = p_s / s
    p_e /= np.linalg.norm(p_e, axis=1, keepdims=True)
    return p_e @ np.asarray(R_ec, dtype=float)  # rows: R_ec^T p_e
