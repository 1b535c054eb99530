"""The Sun or the Moon beside the Earth's edge: hidden behind the Earth, or seen through its air.

Why
---
From a camera above the atmosphere the Sun and the Moon always lie beyond the Earth. A disc found
inside the Earth's disc is therefore not the body but something on the Earth (a cloud, a glint
on the sea), however well a circle fits it; and a body that stands just above the Earth's edge
is seen through the air, which bends its light by up to a degree (003's covariance knows nothing
of that). Without a predicted direction (`horizon-nav vision`, no attitude) the Moon's search
covers the whole frame, and on horizon views without the Moon the clouds offer Moon-sized discs.

Geometry
--------
Angles are measured from the Earth's nadir e (the frame's Earth vector). The Earth's edge lies
at the angle ``theta_E`` from e (the median over the edge rays nearest the body's azimuth about
e: the edge is a cone only on a sphere) at the tangent height ``h_E`` (the record's edge
height). A ray at the angle theta from e passes the Earth at the tangent height

    h_t(theta) = h_E + r (sin theta - sin theta_E),

r the observer's distance from the Earth's centre (a sphere of radius ``r sin theta_E - h_E``
about the nadir; the ray's closest approach is ``r sin theta``, and the camera itself for theta
beyond 90 deg). A disc of centre b and angular
radius alpha_b has its lowest point at ``theta_low = angle(b, e) - alpha_b``; its clearance is
``theta_low - theta_E``. A disc whose clearance is below ``OccultationOptions.min_clearance_deg``
is rejected: entirely below the edge it is not the body; reaching into the edge it is partly
hidden, and the Earth's bright limb joins its outline.

Refraction
----------
Above the edge the light of the limb the disc was fitted to crosses the air at the tangent height
of its lowest ray, ``h_low = h_t(theta)`` at the smallest theta among the fit's rays (for a Moon
lit from above, its upper limb), which is lower the lower the edge: the edge's height is taken at
``max(0, h_E - edge_sigmas sigma_E)`` (a brightness edge is not below the ground). A ray grazing
a spherically layered exponential atmosphere at the height h is bent by

    delta(h) = (n(h) - 1) sqrt(2 pi R / H(h))                                     (1)

(the leading term of the bending integral of a spherically symmetric refractivity that decays with
the scale height H over a sphere of radius R, as radio occultation uses it; Fjeldbo, Kliore &
Eshleman 1971, Astron. J. 76, 123), with ``n - 1`` the refractivity of air at the ground, 2.77e-4
(visible light, 15 C, 1013.25 hPa), scaled by the density of the U.S. Standard Atmosphere 1976
(`STANDARD_DENSITY`) and H its local density scale height. It gives 1.01 deg at the ground, 0.42
deg at 10 km, 0.019 deg at 30 km and 0.004 deg at 40 km; the quadrature of the bending integral
over the same air gives 1.12 deg at the ground (twice the astronomical refraction at the horizon,
2 x 34.5' = 1.15 deg), 9 % more than (1) there, and agrees with (1) within 5 % from 10 km up
(`tests/test_occultation.py`). The light is bent towards the Earth, so the image of the disc is
lifted away from it, each ray by the bending at its own tangent height: a circle fitted to those
rays moves away from the Earth by at most ``delta(h_low)``. The direction is not corrected (the
edge's true height and the air's state are not known well enough); the covariance gains
``(delta(h_low) / 2)^2`` along the great circle through e and b, so that its 3 sigma covers 1.5
times the largest shift.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from nav.earth import R_MEAN
from nav.rotation import tangent_basis
from vision.fitting import median

__all__ = ["STANDARD_DENSITY", "REFRACTIVITY_GROUND", "REFRACTION_CEILING_M", "EarthEdge", "refraction_bending",
           "edge_angle", "clearance", "tangent_height", "occultation_reason", "refraction_covariance"]

#: U.S. Standard Atmosphere 1976: geometric height [m], density [kg/m^3]
STANDARD_DENSITY = np.array([
    [0.0, 1.2250], [5e3, 7.3643e-1], [10e3, 4.1351e-1], [15e3, 1.9476e-1], [20e3, 8.8910e-2],
    [25e3, 4.0084e-2], [30e3, 1.8410e-2], [35e3, 8.4634e-3], [40e3, 3.9957e-3], [45e3, 1.9663e-3],
    [50e3, 1.0269e-3], [60e3, 3.0968e-4], [70e3, 8.2829e-5], [80e3, 1.8458e-5], [90e3, 3.416e-6],
    [100e3, 5.604e-7]])
_LN_DENSITY = np.log(STANDARD_DENSITY[:, 1])
#: tangent height [m] above which the bending is negligible (5e-6 rad, 0.0003 deg, at 60 km)
REFRACTION_CEILING_M = 60e3
#: refractivity n - 1 of air at the ground (visible light, 15 C, 1013.25 hPa)
REFRACTIVITY_GROUND = 2.77e-4


def refraction_bending(h_m) -> np.ndarray:
    """Bending [rad] of a ray whose tangent height is ``h_m`` [m] (eq. (1) of the module
    docstring; heights below 0 are taken at 0, above 100 km the density's last scale height
    continues).

    Examples
    --------
    >>> round(float(np.degrees(refraction_bending(0.0))), 2)
    1.01
    """
    h = np.clip(np.asarray(h_m, dtype=float), 0.0, None)
    z, rho = STANDARD_DENSITY[:, 0], _LN_DENSITY
    i = np.clip(np.searchsorted(z, h, side="right") - 1, 0, z.size - 2)
    slope = (rho[i + 1] - rho[i]) / (z[i + 1] - z[i])        # -1 / H of the layer
    ln_rho = rho[i] + slope * (h - z[i])
    return REFRACTIVITY_GROUND * np.exp(ln_rho - rho[0]) * np.sqrt(2.0 * math.pi * R_MEAN * -slope)


@dataclass(frozen=True)
class EarthEdge:
    """The Earth's edge as one frame saw it.

    e_c : (3,) unit Earth vector (the nadir the angles are measured from).
    rays : (n, 3) unit rays of the edge's inlier pixels, camera frame.
    height_m, height_sigma_m : the edge's tangent height and its 1-sigma [m] (the record's).
    r_m : the observer's distance from the Earth's centre [m].

    The rays' angles from e_c and their azimuths about it (in a tangent basis of e_c) are
    computed once, on construction; `edge_angle` then costs one azimuth and a partial sort.
    """

    e_c: np.ndarray
    rays: np.ndarray
    height_m: float
    height_sigma_m: float
    r_m: float
    basis: np.ndarray = field(init=False, repr=False)
    theta: np.ndarray = field(init=False, repr=False)
    azimuth: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        e = np.asarray(self.e_c, dtype=float)
        basis = tangent_basis(e).T                       # rows t1, t2
        rays = np.asarray(self.rays, dtype=float)
        xy = rays @ basis.T
        object.__setattr__(self, "basis", basis)
        object.__setattr__(self, "theta", np.arccos(np.clip(rays @ e, -1.0, 1.0)))
        object.__setattr__(self, "azimuth", np.arctan2(xy[:, 1], xy[:, 0]))

    def height(self, sigmas: float = 0.0) -> float:
        """The edge's tangent height [m] less ``sigmas`` of its sigmas (0 m when not finite; a
        sigma that is not finite is not taken off)."""
        h = self.height_m if math.isfinite(self.height_m) else 0.0
        return h - sigmas * self.height_sigma_m if math.isfinite(self.height_sigma_m) else h


def edge_angle(edge: EarthEdge, b_c: np.ndarray, n_near: int = 16) -> float:
    """Angle [rad] of the Earth's edge from ``edge.e_c`` at the azimuth of the direction ``b_c``:
    the median over the ``n_near`` edge rays nearest that azimuth (NaN without rays)."""
    if edge.azimuth.size == 0:
        return math.nan
    x, y = edge.basis @ np.asarray(b_c, dtype=float)
    d = np.abs((edge.azimuth - math.atan2(y, x) + math.pi) % (2.0 * math.pi) - math.pi)
    k = min(n_near, d.size)
    near = np.argpartition(d, k - 1)[:k] if k < d.size else slice(None)
    return median(edge.theta[near])


def clearance(edge: EarthEdge, b_c: np.ndarray, alpha_b: float) -> tuple[float, float]:
    """(clearance [rad] of the lowest point of the disc of centre ``b_c`` and angular radius
    ``alpha_b`` above the Earth's edge, the edge's angle theta_E [rad]); module docstring."""
    theta_b = float(np.arccos(np.clip(b_c @ edge.e_c, -1.0, 1.0)))
    theta_e = edge_angle(edge, b_c)
    return theta_b - alpha_b - theta_e, theta_e


def tangent_height(r_m: float, h_e: float, theta: float, theta_e: float) -> float:
    """Tangent height [m] of the ray at the angle ``theta`` [rad] from the nadir, seen from the
    distance ``r_m`` from the Earth's centre, the edge at ``theta_e`` and the tangent height
    ``h_e`` [m] (module docstring; beyond 90 deg the ray rises from the camera, which is then its
    lowest point)."""
    return h_e + r_m * (math.sin(min(theta, 0.5 * math.pi)) - math.sin(min(theta_e, 0.5 * math.pi)))


def occultation_reason(edge: EarthEdge, b_c: np.ndarray, alpha_b: float, min_clearance: float, body: str) -> str:
    """"" or why the disc of centre ``b_c`` (unit, camera frame) and angular radius ``alpha_b``
    [rad] is not the ``body`` seen clear of the Earth: its clearance is below ``min_clearance``
    [rad] (module docstring). Three cases: the disc reaches into the edge (its top above it);
    the whole disc is below the brightness edge but its top ray passes above the ground (seen
    through the air, bent by up to `refraction_bending` of its lowest visible ray, partly
    hidden); the top ray meets the ground too (inside the Earth's disc: not the body)."""
    b = np.asarray(b_c, dtype=float)
    c, theta_e = clearance(edge, b, alpha_b)
    if c >= min_clearance or not math.isfinite(c):          # no edge ray: nothing to test against
        return ""
    below = (f"its lowest point {math.degrees(-c):.2f} deg below the edge "
             f"(min_clearance_deg {math.degrees(min_clearance):g})")
    if c + 2.0 * alpha_b >= 0.0:
        return f"reaches into the Earth's edge (partly hidden behind it, seen through its air): {below}"
    h_e = edge.height()
    h_top = tangent_height(edge.r_m, h_e, theta_e + c + 2.0 * alpha_b, theta_e)
    if h_top <= 0.0:
        return f"inside the Earth's disc, not the {body} (it is never in front of the Earth): {below}"
    bend = math.degrees(float(refraction_bending(tangent_height(edge.r_m, h_e, theta_e + c, theta_e))))
    return (f"below the Earth's brightness edge, seen through its air (its top at a tangent height of "
            f"{h_top / 1e3:.0f} km, bent by up to {bend:.2f} deg, partly hidden): {below}")


def refraction_covariance(edge: EarthEdge, b_c: np.ndarray, rays: np.ndarray, edge_sigmas: float) -> np.ndarray:
    """Covariance term [rad^2] (3, 3) of the refraction of the disc of centre ``b_c`` fitted to
    the unit ``rays`` (n, 3) above the Earth's ``edge``: ``(delta(h_low) / 2)^2`` along the great
    circle through the Earth's nadir and ``b_c``, h_low the tangent height of the lowest of the
    rays with the edge ``edge_sigmas`` sigmas low (module docstring)."""
    b = np.asarray(b_c, dtype=float)
    e = edge.e_c
    theta_e = edge_angle(edge, b)
    if not math.isfinite(theta_e) or len(rays) == 0:
        return np.zeros((3, 3))
    theta_low = float(np.min(np.arccos(np.clip(np.asarray(rays, dtype=float) @ e, -1.0, 1.0))))
    h_low = tangent_height(edge.r_m, max(0.0, edge.height(edge_sigmas)), max(theta_low, theta_e), theta_e)
    u = e - (e @ b) * b                          # towards the Earth along the great circle through b
    n = float(np.linalg.norm(u))
    if n == 0.0:
        return np.zeros((3, 3))
    u /= n
    return (0.5 * float(refraction_bending(h_low))) ** 2 * np.outer(u, u)
