"""WGS-84 Earth model: ellipsoid, geodetic coordinates, local NED frame, J2 gravity, curvature.

The filter's navigation frame is e (ECEF, WGS-84; 003 §2.2.3, §6). Everything here is vectorised
over leading axes: positions are ``(..., 3)`` arrays in metres, angles in radians.

References: NIMA TR8350.2 (WGS-84, 003 ref. [27]); Groves (2013), *Principles of GNSS, inertial and
multisensor integrated navigation systems* (003 ref. [15]), §2.4 and §2.4.7 (gravity).
"""
from __future__ import annotations

import numpy as np

from nav.checks import as_vectors, as_finite

#: WGS-84 semi-major axis [m].
A = 6378137.0
#: WGS-84 flattening.
F = 1.0 / 298.257223563
#: Semi-minor axis [m].
B = A * (1.0 - F)
#: First eccentricity squared.
E2 = F * (2.0 - F)
#: Second eccentricity squared.
EP2 = E2 / (1.0 - E2)
#: Earth's gravitational constant including the atmosphere [m^3/s^2].
GM = 3.986004418e14
#: Second zonal harmonic, J2 = -sqrt(5) * C20 with C20 = -4.84166774985e-4 (EGM2008 / WGS-84).
J2 = 1.082629821313e-3
#: Earth rotation rate [rad/s].
OMEGA_E = 7.292115e-5
#: Earth rotation vector in e [rad/s].
OMEGA_IE_E = np.array([0.0, 0.0, OMEGA_E])
#: WGS-84 normal gravity on the ellipsoid at the equator and the poles [m/s^2] (Somigliana).
GAMMA_EQUATOR = 9.7803253359
GAMMA_POLE = 9.8321849378
#: Mean radius R1 = (2a + b) / 3 [m], for spherical-Earth approximations.
R_MEAN = (2.0 * A + B) / 3.0


def geodetic_to_ecef(lat, lon, h) -> np.ndarray:
    """Geodetic latitude, longitude [rad] and ellipsoidal height [m] -> ECEF position [m]."""
    lat = as_finite(lat, "lat")
    lon = as_finite(lon, "lon")
    h = as_finite(h, "h")
    if np.any(np.abs(lat) > np.pi / 2 + 1e-12):
        raise ValueError("lat: geodetic latitude must lie in [-pi/2, pi/2] rad")
    sl, cl = np.sin(lat), np.cos(lat)
    n = A / np.sqrt(1.0 - E2 * sl * sl)
    return np.stack([(n + h) * cl * np.cos(lon),
                     (n + h) * cl * np.sin(lon),
                     (n * (1.0 - E2) + h) * sl], axis=-1)


def ecef_to_geodetic(x_e) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF position -> geodetic latitude, longitude [rad] and ellipsoidal height [m].

    Bowring's iteration on the parametric latitude (Bowring 1976), run until the latitude moves by
    less than 1e-15 rad (3 iterations cover -1 km to 2000 km; a fixed cap of 8 guards the loop).
    The height uses ``p cos(lat) + z sin(lat) - a sqrt(1 - e^2 sin^2 lat)``, which is well
    conditioned at every latitude including the poles. Round trip error is far below 1 mm.
    """
    x = as_vectors(x_e, "x_e")
    px, py, z = x[..., 0], x[..., 1], x[..., 2]
    p = np.hypot(px, py)
    if np.any((p == 0) & (z == 0)):
        raise ValueError("x_e: the Earth's centre has no geodetic coordinates")
    lon = np.arctan2(py, px)
    u = np.arctan2(z * A, p * B)  # parametric latitude, first guess
    lat = np.arctan2(z + EP2 * B * np.sin(u) ** 3, p - E2 * A * np.cos(u) ** 3)
    for _ in range(8):
        u = np.arctan2((1.0 - F) * np.sin(lat), np.cos(lat))
        new = np.arctan2(z + EP2 * B * np.sin(u) ** 3, p - E2 * A * np.cos(u) ** 3)
        done = np.all(np.abs(new - lat) < 1e-15)
        lat = new
        if done:
            break
    sl, cl = np.sin(lat), np.cos(lat)
    h = p * cl + z * sl - A * np.sqrt(1.0 - E2 * sl * sl)
    return lat, lon, h


def R_en(lat, lon) -> np.ndarray:
    """Rotation from local north-east-down (n) at (lat, lon) into ECEF (e): ``v_e = R_en @ v_n``."""
    lat = as_finite(lat, "lat")
    lon = as_finite(lon, "lon")
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    north = np.stack([-sl * co, -sl * so, cl], axis=-1)
    east = np.stack([-so, co, np.zeros_like(so)], axis=-1)
    down = np.stack([-cl * co, -cl * so, -sl], axis=-1)
    return np.stack([north, east, down], axis=-1)


def gravitation_e(x_e) -> np.ndarray:
    """Gravitational acceleration (mass attraction only) in e with the J2 term [m/s^2].

    Groves (2013) eq. (2.142). Use it for inertial-frame dynamics; add the centrifugal term
    (:func:`gravity_e`) for the Earth-fixed frame.
    """
    x = as_vectors(x_e, "x_e")
    r2 = np.sum(x * x, axis=-1)
    if np.any(r2 < (0.5 * A) ** 2):
        raise ValueError("x_e: position is deep inside the Earth (|x| < a/2); the J2 model does not apply")
    r = np.sqrt(r2)
    zr2 = x[..., 2] ** 2 / r2
    k = 1.5 * J2 * (A * A / r2)
    fxy = 1.0 + k * (1.0 - 5.0 * zr2)
    fz = 1.0 + k * (3.0 - 5.0 * zr2)
    scale = -GM / (r2 * r)
    return np.stack([scale * fxy * x[..., 0], scale * fxy * x[..., 1], scale * fz * x[..., 2]], axis=-1)


def centrifugal_e(x_e) -> np.ndarray:
    """Centrifugal acceleration -omega x (omega x x) in e [m/s^2]."""
    x = as_vectors(x_e, "x_e")
    w2 = OMEGA_E * OMEGA_E
    return np.stack([w2 * x[..., 0], w2 * x[..., 1], np.zeros_like(x[..., 2])], axis=-1)


def gravity_e(x_e) -> np.ndarray:
    """Gravity (gravitation with J2 plus centrifugal) in e [m/s^2]: what a plumb line feels.

    On the ellipsoid its magnitude matches WGS-84 normal gravity (Somigliana) to about 1e-4 m/s^2;
    the difference is the J4 and higher terms that the J2 truncation leaves out.
    """
    return gravitation_e(x_e) + centrifugal_e(x_e)


def normal_gravity(lat) -> np.ndarray:
    """WGS-84 normal gravity magnitude on the ellipsoid, Somigliana's closed form [m/s^2]."""
    lat = as_finite(lat, "lat")
    k = (B * GAMMA_POLE) / (A * GAMMA_EQUATOR) - 1.0
    s2 = np.sin(lat) ** 2
    return GAMMA_EQUATOR * (1.0 + k * s2) / np.sqrt(1.0 - E2 * s2)


def meridian_radius(lat) -> np.ndarray:
    """Radius of curvature of the meridian, M = a (1 - e^2) / (1 - e^2 sin^2 lat)^(3/2) [m]."""
    s2 = np.sin(as_finite(lat, "lat")) ** 2
    return A * (1.0 - E2) / (1.0 - E2 * s2) ** 1.5


def prime_vertical_radius(lat) -> np.ndarray:
    """Radius of curvature in the prime vertical, N = a / sqrt(1 - e^2 sin^2 lat) [m]."""
    s2 = np.sin(as_finite(lat, "lat")) ** 2
    return A / np.sqrt(1.0 - E2 * s2)


def radius_of_curvature(lat, azimuth) -> np.ndarray:
    """Radius of curvature of the ellipsoid's normal section at ``azimuth`` (from north, east
    positive) [m]: Euler's theorem 1/R = cos^2(az)/M + sin^2(az)/N.

    003 §2.8 approximates the ellipsoid near the horizon by the sphere tangent at the user's location
    whose radius is this curvature taken normal to the viewing direction.
    """
    az = as_finite(azimuth, "azimuth")
    m = meridian_radius(lat)
    n = prime_vertical_radius(lat)
    return 1.0 / (np.cos(az) ** 2 / m + np.sin(az) ** 2 / n)


def radius_of_curvature_along(x_e, d_e) -> np.ndarray:
    """Radius of curvature of the ellipsoid below ``x_e`` in the vertical plane containing the
    direction ``d_e`` (any ECEF vector; its horizontal part sets the azimuth) [m]."""
    x = as_vectors(x_e, "x_e")
    d = as_vectors(d_e, "d_e")
    lat, lon, _ = ecef_to_geodetic(x)
    d_n = np.einsum("...ji,...j->...i", R_en(lat, lon), d)
    horiz = np.hypot(d_n[..., 0], d_n[..., 1])
    if np.any(horiz < 1e-12 * np.linalg.norm(d, axis=-1)):
        raise ValueError("d_e: a vertical direction has no azimuth; the curvature is undefined")
    return radius_of_curvature(lat, np.arctan2(d_n[..., 1], d_n[..., 0]))
