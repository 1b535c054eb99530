"""Limb models for the Earth-nadir fit: the spherical Earth of 003 §2.4 and the oblate (WGS-84)
Earth of 003 §2.8 handled with the scaled-sphere transform of 000 §2.4.

The cone fit (`vision.nadir.nadir_from_horizon`) assumes a sphere: the limb rays form a circular
cone about the direction to the centre. The WGS-84 ellipsoid is not a sphere; its limb seen from
``x_e`` is a slightly non-circular cone, and fitting a circular one biases the direction by up to
~0.19 deg (003 §2.8, fig. 8). Two models are offered, both as a `LimbModel` that maps camera rays
into the frame where the limb *is* a circular cone and maps the fitted direction back:

- `sphere_model` (no prior; 003 §2.8): the ellipsoid is replaced by the sphere of radius ``r``
  (the local radius of curvature, ``nav.earth.radius_of_curvature``) and the cone half-angle is
  003 eq. (5), ``alpha = asin((r + d) / (r + H))``. The fitted direction is the centre of that
  substitute sphere, i.e. close to the local *normal* (the direction of gravity), not the
  geocentric direction -x_e/|x_e| of the filter's observation equation (003 eq. (39)); the
  difference is the spherical-model error reported here.
- `ellipsoid_model` (with a position prior x_e and an attitude prior R_ec; 000's ellipsoid model):
  the limb of the ellipsoid inflated by the effective atmosphere thickness d, with semi-axes
  (a + d, a + d, b + d), becomes a sphere of radius a + d under ``S = diag(1, 1, (a + d)/(b + d))``
  (lines map to lines, tangency is preserved). In that space the limb rays
  ``p_s = S R_ec p_c / |S R_ec p_c|`` lie exactly on the circular cone about ``-S x_e`` with
  ``alpha_s = asin((a + d)/|S x_e|)``; the fitted ``e_s`` maps back to the geocentric direction
  ``e_e = S^-1 e_s / |S^-1 e_s|`` (S^-1 (-S x_e) = -x_e) and into the camera with ``R_ec^T``.
  A prior attitude error psi rotates all rays together; since S differs from the identity by
  ``f ~ 1/298``, the output moves by ``~ f |psi|`` times the in-plane lever, i.e. the
  correction's sensitivity to the attitude prior is second order (tests/test_oblate.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from nav import earth
from vision.nadir import norm3, horizon_alpha

__all__ = ["LimbModel", "sphere_model", "ellipsoid_model", "gaussian_radius", "is_above"]


@dataclass(frozen=True)
class LimbModel:
    """Where the limb is a circular cone.

    Attributes
    ----------
    kind : "sphere" or "ellipsoid".
    alpha : cone half-angle in the fit frame [rad].
    M : (3, 3) linear map camera ray -> fit-frame ray (before normalisation); identity for the
        sphere, ``S R_ec`` for the ellipsoid.
    M_inv : its inverse (fit-frame direction -> camera direction, before normalisation).
    radius : radius of the (substitute) sphere [m]: r for the sphere, a for the ellipsoid.
    alpha_rate : d alpha / d d [rad/m], for the atmosphere-thickness term of the covariance.
    """

    kind: str
    alpha: float
    M: np.ndarray
    M_inv: np.ndarray
    radius: float
    alpha_rate: float

    def to_fit(self, rays_c: np.ndarray) -> np.ndarray:
        """Camera rays (m, 3) -> unit rays in the fit frame."""
        if self.kind == "sphere":
            return rays_c
        r = np.asarray(rays_c, dtype=float)
        return _map_unit_rows(np.ascontiguousarray(r.reshape(-1, 3)), self.M).reshape(r.shape)

    def to_camera(self, e_fit: np.ndarray) -> np.ndarray:
        """Fitted unit direction in the fit frame -> unit direction in the camera frame."""
        if self.kind == "sphere":
            return e_fit
        e = self.M_inv @ e_fit
        return e / norm3(e)

    def cone_angle_change(self, dd) -> np.ndarray:
        """``alpha(d + dd) - alpha(d)`` [rad]: how much wider the cone of a limb ``dd`` [m] higher
        is (003 eq. (5), ``sin alpha = (r + d) / |x|`` in the fit frame, ``|x| = 1 / (alpha_rate
        cos alpha)``). Exact where ``alpha_rate dd`` is not: from 100 km up, a limb 35 km higher
        is 1.3x the linear angle (the rate grows as the cone closes in on the horizon's dip)."""
        s = math.sin(self.alpha) + np.asarray(dd, dtype=float) * self.alpha_rate * math.cos(self.alpha)
        return np.arcsin(np.minimum(np.maximum(s, -1.0), 1.0)) - self.alpha

    def height_change(self, dalpha) -> np.ndarray:
        """The inverse of `cone_angle_change`: ``dd`` [m] with ``alpha(d + dd) = alpha(d) + dalpha``."""
        return ((np.sin(self.alpha + np.asarray(dalpha, dtype=float)) - math.sin(self.alpha))
                / (self.alpha_rate * math.cos(self.alpha)))


def gaussian_radius(lat: float) -> float:
    """sqrt(M N): the mean radius of curvature at geodetic latitude ``lat`` [rad] (the geometric
    mean of the normal-section radii over all azimuths), for `sphere_model` when the viewing
    azimuth is unknown."""
    return float(math.sqrt(earth.radius_of_curvature(lat, 0.0) * earth.radius_of_curvature(lat, math.pi / 2)))


@numba.njit(cache=True)
def _map_unit_rows(R, M):  # pragma: no cover - numba
    """Rows of ``R @ M.T``, each normalised (`LimbModel.to_fit` of an (m, 3) array; called several
    times per frame on 100-512 rays: one pass instead of numpy's matmul, norm and divide)."""
    out = np.empty((R.shape[0], 3))
    for i in range(R.shape[0]):
        x = M[0, 0] * R[i, 0] + M[0, 1] * R[i, 1] + M[0, 2] * R[i, 2]
        y = M[1, 0] * R[i, 0] + M[1, 1] * R[i, 1] + M[1, 2] * R[i, 2]
        z = M[2, 0] * R[i, 0] + M[2, 1] * R[i, 1] + M[2, 2] * R[i, 2]
        n = math.sqrt(x * x + y * y + z * z)
        out[i, 0], out[i, 1], out[i, 2] = x / n, y / n, z / n
    return out


def sphere_model(height_m: float, radius_m: float, atmosphere_m: float = 0.0) -> LimbModel:
    """Spherical Earth of radius ``radius_m`` seen from ``height_m`` above it (003 eq. (5))."""
    if not (math.isfinite(height_m) and height_m > atmosphere_m):
        raise ValueError(f"height {height_m} m: expected a finite height above the effective "
                         f"atmosphere thickness d = {atmosphere_m} m (003 eq. (5))")
    a = horizon_alpha(height_m, radius_m, atmosphere_m)
    rate = 1.0 / ((radius_m + height_m) * math.cos(a))
    I = np.eye(3)
    return LimbModel("sphere", a, I, I, float(radius_m), rate)


def _inflated(x_e: np.ndarray, atmosphere_m: float) -> tuple[float, float, np.ndarray]:
    """(|S x_e|, a, S): the distance of ``x_e`` in the frame S = diag(1, 1, a/b) that makes the
    WGS-84 ellipsoid inflated by ``atmosphere_m`` the sphere of radius a = A + atmosphere_m."""
    a, b = earth.A + atmosphere_m, earth.B + atmosphere_m
    s = np.array([1.0, 1.0, a / b])
    return float(np.linalg.norm(s * np.asarray(x_e, dtype=float))), a, s


def is_above(x_e: np.ndarray, atmosphere_m: float) -> bool:
    """Whether the position ``x_e`` [m] lies outside the WGS-84 ellipsoid inflated by
    ``atmosphere_m`` (the condition for `ellipsoid_model`'s cone to exist).

    Examples
    --------
    >>> is_above(np.array([earth.A + 30e3, 0.0, 0.0]), 45e3), is_above(np.array([earth.A + 30e3, 0.0, 0.0]), 10e3)
    (False, True)
    """
    xs, a, _ = _inflated(x_e, atmosphere_m)
    return xs > a


def ellipsoid_model(x_e: np.ndarray, R_ec: np.ndarray, atmosphere_m: float = 0.0) -> LimbModel:
    """WGS-84 ellipsoid inflated by ``atmosphere_m`` seen from ``x_e`` with attitude prior
    ``R_ec`` (camera -> e), see the module docstring."""
    x = np.asarray(x_e, dtype=float)
    R = np.asarray(R_ec, dtype=float)
    if x.shape != (3,) or R.shape != (3, 3) or not (np.isfinite(x).all() and np.isfinite(R).all()):
        raise ValueError(f"ellipsoid_model: x_e {x.shape}, R_ec {R.shape}; expected finite (3,), (3, 3)")
    xs, a, s = _inflated(x, atmosphere_m)
    if not xs > a:
        raise ValueError(f"ellipsoid_model: position {x} m is not above the ellipsoid + "
                         f"{atmosphere_m} m atmosphere")
    alpha = math.asin(a / xs)
    M = s[:, None] * R            # S R_ec
    M_inv = R.T / s[None, :]      # R_ec^T S^-1
    rate = 1.0 / (xs * math.cos(alpha))
    return LimbModel("ellipsoid", alpha, M, M_inv, float(a), rate)
