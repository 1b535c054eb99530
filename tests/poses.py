"""Camera poses for rendering and vision tests: a camera at a geodetic point looking at an azimuth
and depression, as R_ec (camera to ECEF) and x_e; and the exact limb rays of the WGS-84 ellipsoid
seen from such a pose."""
import math

import numpy as np

from nav import earth, ephemeris


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


# ------------------------------------------------------------------------------------------------
# views from a circular orbit at 500 km (the narrow pinhole camera's scenes)

T0_ORBIT_NS = (1_700_000_000 + 6 * 86400) * 10**9     # 2023-11-20: the Moon 96 deg from the Sun, half lit
H_ORBIT = 500e3


def orbit_poses(n: int, seed: int = 0):
    """(R_ec, x_e) of n views of the sunlit limb from a 500 km orbit at T0_ORBIT_NS: the camera at
    points 20-70 deg from the subsolar point (a sunlit limb, the Sun out of a narrow field of view),
    looking at the horizon towards the Sun's azimuth +-60 deg, the optical axis 18-26 deg below the
    local horizontal (the horizon dips 22.0 deg at 500 km), rolled by -30..30 deg."""
    rng = np.random.default_rng(seed)
    s = ephemeris.sun_position_e(T0_ORBIT_NS)
    s = s / np.linalg.norm(s)
    lat_s, lon_s = math.asin(s[2]), math.atan2(s[1], s[0])
    out = []
    for _ in range(n):
        dist, bearing = math.radians(rng.uniform(20, 70)), rng.uniform(0, 2 * math.pi)
        lat = math.asin(math.sin(lat_s) * math.cos(dist) + math.cos(lat_s) * math.sin(dist) * math.cos(bearing))
        lon = lon_s + math.atan2(math.sin(bearing) * math.sin(dist) * math.cos(lat_s),
                                 math.cos(dist) - math.sin(lat_s) * math.sin(lat))
        x = earth.geodetic_to_ecef(lat, lon, H_ORBIT)
        s_n = earth.R_en(lat, lon).T @ (ephemeris.sun_position_e(T0_ORBIT_NS) - x)
        az = math.degrees(math.atan2(s_n[1], s_n[0])) + rng.uniform(-60, 60)
        out.append(pose(az, rng.uniform(18.0, 26.0), h=H_ORBIT, lat=math.degrees(lat), lon=math.degrees(lon),
                        roll_deg=rng.uniform(-30, 30)))
    return out


def _ned_az_el(x, target_e):
    """Azimuth and elevation [deg] of the direction from x to target_e in the local NED frame."""
    lat, lon, _ = earth.ecef_to_geodetic(x)
    d = earth.R_en(lat, lon).T @ (target_e - x)
    d /= np.linalg.norm(d)
    return math.degrees(math.atan2(d[1], d[0])), -math.degrees(math.asin(d[2]))


def moon_poses(n: int, seed: int = 1, depression_deg=(12.0, 17.0)):
    """(R_ec, x_e) of n views with the Moon and the sunlit limb in the image: the vehicle where the
    Moon stands ``depression_deg`` (12-17 deg) below the local horizontal (above the limb, which
    dips 22 deg), on the Sun's side of the Moon (the limb below the Moon is in daylight, the Sun
    ~80 deg above the horizontal, out of view); the optical axis halfway between the Moon and the
    limb, +-3 deg in azimuth, rolled by -20..20 deg."""
    rng = np.random.default_rng(seed)
    m = ephemeris.moon_position_e(T0_ORBIT_NS)
    m = m / np.linalg.norm(m)
    s = ephemeris.sun_position_e(T0_ORBIT_NS)
    w0 = s - (s @ m) * m
    w0 /= np.linalg.norm(w0)
    out = []
    for _ in range(n):
        b = math.radians(rng.uniform(-30, 30))             # turn w0 about m
        w = math.cos(b) * w0 + math.sin(b) * np.cross(m, w0)
        a = math.radians(90 + rng.uniform(*depression_deg))
        up = math.cos(a) * m + math.sin(a) * w
        lat, lon, _ = earth.ecef_to_geodetic(up * (earth.A + H_ORBIT))
        x = earth.geodetic_to_ecef(lat, lon, H_ORBIT)
        az, el = _ned_az_el(x, ephemeris.moon_position_e(T0_ORBIT_NS))
        down = 0.5 * (-el + 22.0)
        out.append(pose(az + rng.uniform(-3, 3), down, h=H_ORBIT, lat=math.degrees(lat), lon=math.degrees(lon),
                        roll_deg=rng.uniform(-20, 20)))
    return out
