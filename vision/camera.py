"""Radially symmetric fisheye camera model (003, §3.2, eqs. (12)-(16)).

Model
-----
A ray ``p_c = [x, y, z]`` in the camera frame c (z along the optical axis, x right, y down;
docs/conventions.md) makes the angle ``theta = atan2(hypot(x, y), z)`` with the optical axis
(0 <= theta <= pi, so rays behind the image plane are allowed) and the azimuth
``phi = atan2(y, x)``. Its distorted radial distance in normalised image units is the odd
polynomial of 003, eq. (13)::

    r_d(theta) = k1 theta + k2 theta^3 + k3 theta^5 + k4 theta^7 + k5 theta^9

and the pixel (OpenCV convention: origin at the centre of the top-left pixel, u right, v down)::

    u = cx + fx r_d cos(phi),    v = cy + fy r_d sin(phi)

003 writes the same thing with the focal lengths folded in (eq. (14)); here the coefficients
``k`` are dimensionless and ``fx, fy`` carry the pixel scale. OpenCV's fisheye model
``theta_d = theta (1 + d1 theta^2 + d2 theta^4 + d3 theta^6 + d4 theta^8)`` is the special case
``k = [1, d1, d2, d3, d4]`` (zero skew). Any model with ``k1 > 0`` converts to OpenCV by folding
``k1`` into the focal lengths (``fx' = k1 fx``, ``d_i = k_{i+1} / k1``).

Valid range
-----------
``max_theta`` is the end of the monotonic range of ``r_d`` (the first angle in (0, pi] where
``dr_d/dtheta`` reaches 0, or pi). The model is accepted only if every image corner (pixel edges,
u in [-0.5, w - 0.5], v in [-0.5, h - 0.5]) lies inside ``r_d(max_theta)``: otherwise the
inverse is not unique over the field of view and the constructor raises ValueError. Rays beyond
``max_theta`` project to NaN; pixels beyond ``r_d(max_theta)`` (never inside the image) unproject
to NaN.

Unprojection (003, eq. (16): "theta is found by iteratively solving (13)") inverts the polynomial
with a table-initialised, bracket-safeguarded Newton iteration per pixel (numba kernels, which also
do the rest of the per-pixel arithmetic of `unproject`, `unproject_jacobian` and `project` in one
pass), to below 1e-12 rad, and returns unit rays (not points on the z = 1 plane, which do not
exist for theta >= 90 deg).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numba
import numpy as np

from vision._kernels import poly1, project1

__all__ = [
    "FisheyeCamera",
    "MODEL_NAME",
    "project",
    "unproject",
    "unproject_jacobian",
    "pixel_rays",
    "radial_distance",
    "radial_derivative",
    "inverse_radial",
    "from_opencv",
    "to_opencv",
    "from_camera_info",
    "to_camera_info",
    "from_fov",
    "atek_camera",
    "ATEK_OPENCV_D",
    "camera_from_dict",
    "camera_to_dict",
]

MODEL_NAME = "fisheye-odd-poly"
_NEWTON_TOL = 1e-13  # rad; stop criterion of the inverse (requirement: < 1e-12 rad)
_TABLE_SIZE = 4097


def _poly(k: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """r_d(theta), 003 eq. (13), Horner in theta^2."""
    t2 = theta * theta
    acc = np.zeros_like(theta) + k[-1]
    for c in k[-2::-1]:
        acc = acc * t2 + c
    return acc * theta


def _dpoly(k: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """dr_d/dtheta = sum (2i+1) k_i theta^(2i)."""
    t2 = theta * theta
    n = len(k)
    acc = np.zeros_like(theta) + (2 * n - 1) * k[-1]
    for i in range(n - 2, -1, -1):
        acc = acc * t2 + (2 * i + 1) * k[i]
    return acc


def _first_critical_angle(k: np.ndarray) -> float | None:
    """First theta in (0, pi] where dr_d/dtheta <= 0, or None (bisection-refined)."""
    th = np.linspace(0.0, math.pi, 20001)
    d = _dpoly(k, th)
    bad = np.nonzero(d <= 0.0)[0]
    if bad.size == 0:
        return None
    i = int(bad[0])
    if i == 0:
        return 0.0
    lo, hi = th[i - 1], th[i]
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _dpoly(k, np.array(mid)) > 0.0:
            lo = mid
        else:
            hi = mid
    return float(hi)


@dataclass(frozen=True)
class FisheyeCamera:
    """Intrinsics of a radially symmetric fisheye camera (003 eqs. (13)-(16)).

    Parameters
    ----------
    width, height : int
        Image size [px].
    fx, fy : float
        Focal lengths [px per normalised unit] (003's f_x, f_y).
    cx, cy : float
        Principal point [px], OpenCV convention (centre of the top-left pixel is (0, 0)).
    k : tuple of float
        1 to 5 coefficients of the odd polynomial r_d = k1 theta + k2 theta^3 + ... (003 eq. (13)),
        dimensionless; k1 > 0.
    name : str
        Free label (used in error messages and camera files).

    Derived (not constructor arguments): ``max_theta`` [rad], end of the monotonic range;
    ``max_radius`` = r_d(max_theta); ``fov_theta`` [rad], largest angle seen in the image
    (at the farthest image corner).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k: tuple[float, ...] = (1.0,)
    name: str = ""
    max_theta: float = field(init=False, repr=False, compare=False)
    max_radius: float = field(init=False, repr=False, compare=False)
    fov_theta: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        label = f"camera {self.name!r}" if self.name else "camera"
        k = tuple(float(c) for c in np.atleast_1d(np.asarray(self.k, dtype=float)))
        object.__setattr__(self, "k", k)
        if not 1 <= len(k) <= 5:
            raise ValueError(f"{label}: k must have 1 to 5 coefficients [k1..k5] (003 eq. (13)), "
                             f"got {len(k)}")
        for nm in ("width", "height"):
            v = getattr(self, nm)
            if int(v) != v or v <= 0:
                raise ValueError(f"{label}: {nm} must be a positive integer, got {v!r}")
            object.__setattr__(self, nm, int(v))
        for nm in ("fx", "fy", "cx", "cy"):
            v = float(getattr(self, nm))
            if not math.isfinite(v):
                raise ValueError(f"{label}: {nm} must be finite, got {v!r}")
            object.__setattr__(self, nm, v)
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"{label}: fx and fy must be positive, got fx={self.fx}, fy={self.fy}")
        if not all(math.isfinite(c) for c in k) or k[0] <= 0:
            raise ValueError(f"{label}: k = {list(k)} must be finite with k1 > 0")
        ka = np.asarray(k)
        crit = _first_critical_angle(ka)
        max_theta = math.pi if crit is None else crit
        max_radius = float(_poly(ka, np.array(max_theta)))
        # farthest image corner (pixel edges) in normalised units
        us = np.array([-0.5, self.width - 0.5])
        vs = np.array([-0.5, self.height - 0.5])
        corner_r = float(np.max(np.hypot(((us[:, None] - self.cx) / self.fx),
                                         ((vs[None, :] - self.cy) / self.fy))))
        if corner_r > max_radius:
            if crit is not None:
                raise ValueError(
                    f"{label}: distortion polynomial k = {list(k)} is not monotonic over the field of "
                    f"view: dr_d/dtheta <= 0 at theta = {math.degrees(crit):.3f} deg (r_d = "
                    f"{max_radius:.6g}), but the image corner needs r_d = {corner_r:.6g}; "
                    f"expected dr_d/dtheta > 0 up to the image corners")
            raise ValueError(
                f"{label}: image corners (r_d = {corner_r:.6g}) lie beyond theta = 180 deg "
                f"(r_d(pi) = {max_radius:.6g}) for k = {list(k)}; expected an image inside the "
                f"180 deg hemisphere-plus range of the polynomial")
        object.__setattr__(self, "max_theta", float(max_theta))
        object.__setattr__(self, "max_radius", max_radius)
        object.__setattr__(self, "fov_theta", float(inverse_radial(self, np.array(corner_r))))

    @property
    def K(self) -> np.ndarray:
        """3x3 pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def coefficients(self) -> np.ndarray:
        """k1..k5 padded with zeros to length 5."""
        out = np.zeros(5)
        out[: len(self.k)] = self.k
        return out


# ----------------------------------------------------------------------------------------------
# radial polynomial and its inverse


def radial_distance(camera: FisheyeCamera, theta: np.ndarray) -> np.ndarray:
    """r_d(theta) of 003 eq. (13) [normalised units]."""
    return _poly(np.asarray(camera.k), np.asarray(theta, dtype=float))


def radial_derivative(camera: FisheyeCamera, theta: np.ndarray) -> np.ndarray:
    """dr_d/dtheta."""
    return _dpoly(np.asarray(camera.k), np.asarray(theta, dtype=float))


_TABLES: dict[tuple[float, ...], tuple[np.ndarray, np.ndarray]] = {}
_RTABLES: dict[tuple[float, ...], tuple[float, np.ndarray, np.ndarray]] = {}


def _table(camera: FisheyeCamera) -> tuple[np.ndarray, np.ndarray]:
    """(r_d, theta) on a grid uniform in theta over [0, max_theta] (start of the reference inverse)."""
    key = camera.k + (camera.max_theta,)
    tab = _TABLES.get(key)
    if tab is None:
        th = np.linspace(0.0, camera.max_theta, _TABLE_SIZE)
        tab = (_poly(np.asarray(camera.k), th), th)
        if len(_TABLES) > 64:
            _TABLES.clear()
        _TABLES[key] = tab
    return tab


def _rtable(camera: FisheyeCamera) -> tuple[float, np.ndarray, np.ndarray]:
    """(1 / dr, theta, dr dtheta/dr_d) on a grid uniform in r_d over [0, max_radius] (theta by the
    reference inverse, once per camera; the slope is NaN where dr_d/dtheta = 0). The kernels find
    the bracket of r_d by one division instead of a binary search (whose data-dependent branches
    cost more than the Newton steps) and start from the cubic Hermite interpolant (~1e-14 rad off
    with 4097 points), so that one Newton step reaches the root."""
    key = camera.k + (camera.max_theta,)
    tab = _RTABLES.get(key)
    if tab is None:
        r = np.linspace(0.0, camera.max_radius, _TABLE_SIZE)
        th = _inverse_radial_bracketed(camera, r)
        th[-1] = camera.max_theta
        th = np.maximum.accumulate(th)
        d = _dpoly(np.asarray(camera.k), th)
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = np.where(d > 0.0, (camera.max_radius / (_TABLE_SIZE - 1)) / d, np.nan)
        tab = ((_TABLE_SIZE - 1) / camera.max_radius, th, slope)
        if len(_RTABLES) > 64:
            _RTABLES.clear()
        _RTABLES[key] = tab
    return tab


def inverse_radial(camera: FisheyeCamera, r_d: np.ndarray) -> np.ndarray:
    """theta with r_d(theta) = r_d, inverse of 003 eq. (13) (003 eq. (16): solved iteratively).

    Table interpolation for the start, then Newton steps kept inside a bisection bracket, per
    element (`_inverse_radial_kernel`) until the step is below 1e-13 rad. r_d outside
    [0, max_radius] gives NaN.
    """
    r_in = np.asarray(r_d, dtype=float)
    inv_dr, th_tab, sl_tab = _rtable(camera)
    out = _inverse_radial_kernel(np.ascontiguousarray(r_in.ravel()), np.asarray(camera.k), inv_dr, th_tab,
                                 sl_tab, camera.max_radius)
    return out.reshape(r_in.shape)


def _inverse_radial_bracketed(camera: FisheyeCamera, r_d: np.ndarray) -> np.ndarray:
    """The same inverse with all elements iterated together in numpy: Newton steps inside a
    bisection bracket from the coarse table's interpolation, to 1e-13 rad (`_rtable` builds the
    kernels' table with it; tests/test_camera.py checks the kernel against it)."""
    r_in = np.asarray(r_d, dtype=float)
    r = r_in.ravel()
    k = np.asarray(camera.k)
    r_tab, th_tab = _table(camera)
    bad = ~((r >= 0.0) & (r <= camera.max_radius))
    rr = np.where(bad, 0.0, r)
    theta = np.interp(rr, r_tab, th_tab)
    idx = np.clip(np.searchsorted(r_tab, rr), 1, len(r_tab) - 1)
    lo = th_tab[idx - 1]
    hi = th_tab[idx]
    for _ in range(100):
        f = _poly(k, theta) - rr
        df = _dpoly(k, theta)
        lo = np.where(f < 0.0, np.maximum(lo, theta), lo)
        hi = np.where(f > 0.0, np.minimum(hi, theta), hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            new = theta - f / df
        out = ~((new >= lo) & (new <= hi)) | ~np.isfinite(new)
        new = np.where(out, 0.5 * (lo + hi), new)
        step = np.abs(new - theta)
        theta = new
        if np.all(step < _NEWTON_TOL):
            break
    return np.where(bad, np.nan, theta).reshape(r_in.shape)


# ----------------------------------------------------------------------------------------------
# numba kernels: the per-pixel work of unproject / unproject_jacobian / project in one pass, with
# the formulas of the array versions (tests/vision_reference.py), which take ~40 array passes
# (Horner, Newton iterations, where/stack) over a few hundred edge pixels per call, several calls
# per frame: mostly per-call overhead.


@numba.njit(cache=True, nogil=True)
def _dpoly1(k, t):  # pragma: no cover - numba
    """dr_d/dtheta for one theta, the Horner scheme of `_dpoly`."""
    t2 = t * t
    n = k.shape[0]
    acc = (2 * n - 1) * k[n - 1]
    for i in range(n - 2, -1, -1):
        acc = acc * t2 + (2 * i + 1) * k[i]
    return acc


@numba.njit(cache=True, nogil=True)
def _inverse_radial_kernel(r, k, inv_dr, th_tab, sl_tab, max_radius):  # pragma: no cover - numba
    """`inverse_radial` of a 1-D array r: theta = r_d^-1(r_i) (NaN outside [0, max_radius]).

    Per element: the bracket [th_tab[j], th_tab[j+1]] of the grid uniform in r (`_rtable`,
    widened by 1e-14 rad for the rounding of its entries), a cubic Hermite start (linear where a
    slope is not finite or the cubic leaves the bracket), then Newton steps; a step leaving the
    (shrinking) bracket is replaced by bisection. Stops when the step is below _NEWTON_TOL
    (1e-13 rad; usually after the first step), at most 100 steps. The element loop and its body
    are one function: a per-element helper taking the tables (arrays) cost numba's atomic
    incref/decref of each of them per element (~5 % of a frame's time)."""
    m = r.shape[0]
    out = np.empty(m)
    jmax = th_tab.shape[0] - 2
    for i in range(m):
        ri = r[i]
        if not (ri >= 0.0 and ri <= max_radius):
            out[i] = math.nan
            continue
        x = ri * inv_dr
        j = min(int(x), jmax)
        lo, hi = th_tab[j], th_tab[j + 1]
        t = x - j
        m0, m1 = sl_tab[j], sl_tab[j + 1]
        t2 = t * t
        t3 = t2 * t
        theta = ((2.0 * t3 - 3.0 * t2 + 1.0) * lo + (t3 - 2.0 * t2 + t) * m0
                 + (3.0 * t2 - 2.0 * t3) * hi + (t3 - t2) * m1)
        if not (theta >= lo and theta <= hi):
            theta = lo + (hi - lo) * t
        lo -= 1e-14
        hi += 1e-14
        for _ in range(100):
            f = poly1(k, theta) - ri
            df = _dpoly1(k, theta)
            if f < 0.0:
                lo = max(lo, theta)
            elif f > 0.0:
                hi = min(hi, theta)
            new = theta - f / df if df != 0.0 else math.nan
            if not (new >= lo and new <= hi):
                new = 0.5 * (lo + hi)
            step = abs(new - theta)
            theta = new
            if step < _NEWTON_TOL:
                break
        out[i] = theta
    return out


@numba.njit(cache=True, nogil=True)
def _unproject_kernel(uv, fx, fy, cx, cy, k, inv_dr, th_tab, sl_tab, max_radius, jac):  # pragma: no cover
    """Unit rays (n, 3) of pixels uv (n, 2), and with ``jac`` their Jacobian (n, 3, 2) (else an
    empty (0, 3, 2) array): the formulas of `unproject` / `unproject_jacobian`."""
    n = uv.shape[0]
    rays = np.empty((n, 3))
    J = np.empty((n if jac else 0, 3, 2))
    k1 = k[0]
    k2 = k[1] if k.shape[0] > 1 else 0.0
    c_small = k2 / k1 ** 4 + 1.0 / (6.0 * k1 ** 3)
    xq = np.empty(n)
    yq = np.empty(n)
    rq = np.empty(n)
    for i in range(n):
        xq[i] = (uv[i, 0] - cx) / fx
        yq[i] = (uv[i, 1] - cy) / fy
        rq[i] = math.hypot(xq[i], yq[i])
    th = _inverse_radial_kernel(rq, k, inv_dr, th_tab, sl_tab, max_radius)
    for i in range(n):
        xd, yd, r_d, theta = xq[i], yq[i], rq[i], th[i]
        st = math.sin(theta)
        ct = math.cos(theta)
        if not jac:
            s = st / r_d if r_d > 0.0 else 0.0
            rays[i, 0] = s * xd
            rays[i, 1] = s * yd
            rays[i, 2] = ct
            continue
        dth = 1.0 / _dpoly1(k, theta)
        if theta < 1e-3:
            s = 1.0 / k1 - c_small * r_d * r_d
            a = -2.0 * c_small
            b = -1.0 / (k1 * k1)
        else:
            s = st / r_d
            a = (ct * dth * r_d - st) / (r_d * r_d * r_d)
            b = -st * dth / r_d
        rays[i, 0] = s * xd
        rays[i, 1] = s * yd
        rays[i, 2] = ct
        axy = a * xd * yd
        J[i, 0, 0] = (s + a * xd * xd) / fx
        J[i, 0, 1] = axy / fy
        J[i, 1, 0] = axy / fx
        J[i, 1, 1] = (s + a * yd * yd) / fy
        J[i, 2, 0] = b * xd / fx
        J[i, 2, 1] = b * yd / fy
    return rays, J


@numba.njit(cache=True, nogil=True)
def _project_kernel(p, fx, fy, cx, cy, k, max_theta):  # pragma: no cover - numba
    """Pixels (n, 2) of rays p (n, 3): the formulas of `project` (NaN beyond max_theta and for
    zero-length or straight-backward rays)."""
    n = p.shape[0]
    uv = np.empty((n, 2))
    for i in range(n):
        uv[i, 0], uv[i, 1] = project1(p[i, 0], p[i, 1], p[i, 2], fx, fy, cx, cy, k, max_theta)
    return uv


# ----------------------------------------------------------------------------------------------
# projection


def project(camera: FisheyeCamera, rays_c: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) [u, v] of camera-frame rays (..., 3) of any length (003 eqs. (13)-(14)).

    theta may exceed 90 deg (rays with z <= 0) up to ``camera.max_theta``; rays beyond it and
    zero-length rays give NaN.
    """
    p = np.asarray(rays_c, dtype=float)
    if p.shape[-1] != 3:
        raise ValueError(f"project: rays_c must have shape (..., 3), got {p.shape}")
    uv = _project_kernel(np.ascontiguousarray(p.reshape(-1, 3)), camera.fx, camera.fy, camera.cx, camera.cy,
                         np.asarray(camera.k), camera.max_theta)
    return uv.reshape(p.shape[:-1] + (2,))


def _pixels(uv: np.ndarray) -> np.ndarray:
    uv = np.asarray(uv, dtype=float)
    if uv.shape[-1] != 2:
        raise ValueError(f"unproject: uv must have shape (..., 2), got {uv.shape}")
    return uv


def _unproject(camera: FisheyeCamera, uv: np.ndarray, jac: bool):
    uv = _pixels(uv)
    inv_dr, th_tab, sl_tab = _rtable(camera)
    rays, J = _unproject_kernel(np.ascontiguousarray(uv.reshape(-1, 2)), camera.fx, camera.fy, camera.cx,
                                camera.cy, np.asarray(camera.k), inv_dr, th_tab, sl_tab, camera.max_radius, jac)
    lead = uv.shape[:-1]
    return rays.reshape(lead + (3,)), (J.reshape(lead + (3, 2)) if jac else None)


def unproject(camera: FisheyeCamera, uv: np.ndarray) -> np.ndarray:
    """Unit rays (..., 3) in the camera frame for pixels (..., 2); exact inverse of `project`.

    Implements 003 eqs. (14)-(16) on the unit sphere (000, eq. (3)) instead of the z = f plane, so
    theta >= 90 deg is representable. Pixels outside the valid radius give NaN. With
    q = [(u - cx)/fx, (v - cy)/fy], r_d = |q|, theta = r_d^-1(r_d) (`inverse_radial`):
    ray = [sin(theta) q / r_d, cos(theta)] (one numba pass, `_unproject_kernel`).
    """
    return _unproject(camera, uv, False)[0]


def unproject_jacobian(camera: FisheyeCamera, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (..., 3) and their Jacobian d ray / d [u, v] (..., 3, 2) [1/px].

    With q = [(u - cx)/fx, (v - cy)/fy], r_d = |q|, theta = r_d^-1(r_d) and s = sin(theta)/r_d:
    ray = [s q, cos theta], d(s q)/dq = s I + (s'(r_d)/r_d) q q^T,
    d cos(theta)/dq = -sin(theta) theta'(r_d) q^T / r_d, theta' = 1 / (dr_d/dtheta).
    Near the axis (theta < 1e-3) the two ratios use their series limits. Used to carry the pixel
    noise of 003 eq. (34) (which lives in distorted pixels) onto the unit rays. One numba pass
    (`_unproject_kernel`).
    """
    return _unproject(camera, uv, True)


def pixel_rays(camera: FisheyeCamera) -> np.ndarray:
    """Unit ray of every pixel centre, shape (height, width, 3), float64 (for the renderer)."""
    v, u = np.mgrid[0: camera.height, 0: camera.width].astype(float)
    return unproject(camera, np.stack([u, v], axis=-1))


# ----------------------------------------------------------------------------------------------
# converters


def from_opencv(K: np.ndarray, D: Sequence[float], width: int, height: int,
                name: str = "") -> FisheyeCamera:
    """Camera from OpenCV fisheye intrinsics (``cv2.fisheye``): K (3x3, zero skew), D = [d1..d4].

    theta_d = theta (1 + d1 theta^2 + ... + d4 theta^8) is 003 eq. (13) with k = [1, d1, .., d4].
    """
    K = np.asarray(K, dtype=float)
    D = np.asarray(D, dtype=float).ravel()
    if K.shape != (3, 3):
        raise ValueError(f"from_opencv: K must be 3x3, got shape {K.shape}")
    if K[0, 1] != 0.0:
        raise ValueError(f"from_opencv: K[0,1] (skew) = {K[0, 1]} is not supported; expected 0")
    if D.size != 4:
        raise ValueError(f"from_opencv: the OpenCV fisheye model has 4 distortion coefficients "
                         f"D = [d1, d2, d3, d4], got {D.size} ({D.tolist()}); a 5-coefficient D is "
                         f"OpenCV's pinhole (k1, k2, p1, p2, k3) model, which is not this model")
    return FisheyeCamera(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                         (1.0, *D.tolist()), name=name)


def to_opencv(camera: FisheyeCamera) -> tuple[np.ndarray, np.ndarray]:
    """(K, D) for ``cv2.fisheye``; k1 is folded into fx, fy (fx' = k1 fx, d_i = k_{i+1}/k1).

    Every model of this class is representable (k1 > 0 is enforced); the result projects
    identically.
    """
    c = camera.coefficients
    k1 = c[0]
    if not k1 > 0:
        raise ValueError(f"to_opencv: k1 = {k1} must be > 0 to fold into the focal length")
    K = np.array([[camera.fx * k1, 0.0, camera.cx], [0.0, camera.fy * k1, camera.cy], [0, 0, 1.0]])
    return K, c[1:] / k1


def from_camera_info(info: Mapping[str, Any] | Any) -> FisheyeCamera:
    """Camera from ROS ``sensor_msgs/CameraInfo`` fields (a mapping or an object with attributes).

    Requires ``distortion_model == "equidistant"`` (ROS name of the OpenCV fisheye model),
    ``D = [d1..d4]``, ``K`` (9, row-major), ``width``, ``height``. ``R`` must be identity and
    ``P`` (12) is ignored on input (it describes the rectified image).
    """
    get = (lambda n: info[n]) if isinstance(info, Mapping) else (lambda n: getattr(info, n))
    try:
        model = str(get("distortion_model"))
        D = np.asarray(get("D") if _has(info, "D") else get("d"), dtype=float)
        K = np.asarray(get("K") if _has(info, "K") else get("k"), dtype=float).reshape(3, 3)
        width, height = int(get("width")), int(get("height"))
    except (KeyError, AttributeError) as exc:
        raise ValueError(f"from_camera_info: missing CameraInfo field {exc}") from None
    if model != "equidistant":
        raise ValueError(f"from_camera_info: distortion_model {model!r} is not supported; "
                         f"expected 'equidistant'")
    if _has(info, "R") or _has(info, "r"):
        R = np.asarray(get("R") if _has(info, "R") else get("r"), dtype=float)
        if R.size == 9 and np.any(R) and not np.allclose(R.reshape(3, 3), np.eye(3)):
            raise ValueError("from_camera_info: R must be identity (monocular camera)")
    return from_opencv(K, D, width, height)


def _has(info: Any, name: str) -> bool:
    return name in info if isinstance(info, Mapping) else hasattr(info, name)


def to_camera_info(camera: FisheyeCamera) -> dict[str, Any]:
    """ROS ``sensor_msgs/CameraInfo`` fields: width, height, distortion_model "equidistant",
    D = [d1..d4], K (9), R = identity (9), P = [K | 0] (12), as plain lists."""
    K, D = to_opencv(camera)
    P = np.hstack([K, np.zeros((3, 1))])
    return {"width": camera.width, "height": camera.height, "distortion_model": "equidistant",
            "D": D.tolist(), "K": K.ravel().tolist(), "R": np.eye(3).ravel().tolist(),
            "P": P.ravel().tolist()}


def from_fov(width: int, height: int, fov_deg: float, k_shape: Sequence[float] = (1.0,),
             axis: str = "horizontal", name: str = "") -> FisheyeCamera:
    """Camera whose field of view along ``axis`` is ``fov_deg``; square pixels, centred.

    FOV here means the full angle between the rays through the two opposite image *edges*
    (pixel edges, u = -0.5 and u = width - 0.5 for "horizontal"; v for "vertical"; the two
    opposite corners for "diagonal"), measured through the principal point, which is put at the
    image centre ((width - 1)/2, (height - 1)/2). ``k_shape`` = [k1..k5] gives the distortion
    shape (default: equidistant r_d = theta); the focal length is fx = fy = half-extent / r_d(fov/2).
    """
    if not 0.0 < fov_deg < 360.0:
        raise ValueError(f"from_fov: fov_deg = {fov_deg} must be in (0, 360)")
    half = {"horizontal": width / 2.0, "vertical": height / 2.0,
            "diagonal": math.hypot(width, height) / 2.0}.get(axis)
    if half is None:
        raise ValueError(f"from_fov: axis {axis!r} must be 'horizontal', 'vertical' or 'diagonal'")
    k = np.asarray(k_shape, dtype=float)
    r_half = float(_poly(k, np.array(math.radians(fov_deg) / 2.0)))
    if not r_half > 0:
        raise ValueError(f"from_fov: r_d(fov/2) = {r_half} for k = {k.tolist()}; expected > 0")
    f = half / r_half
    return FisheyeCamera(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0,
                         tuple(k.tolist()), name=name)


#: OpenCV fisheye D chosen for the ATEK default (see `atek_camera`).
ATEK_OPENCV_D = (0.08, -0.01, 0.0, 0.0)


def atek_camera() -> FisheyeCamera:
    """Default for the ATEK/MAPHEUS-8 cameras (003 §7): 1920x1080, 94.4 deg horizontal FOV.

    003 gives only "1920x1080, FOV 94.4 deg, strongly distorted wide-angle lens" (a GoPro-like
    action camera). No calibration is published, so this is a plausible stand-in, not the flight
    calibration: an OpenCV fisheye model with D = [0.08, -0.01, 0, 0] (close to equidistant,
    slightly more compressed towards the edge, as action-camera lenses in their 16:9 "medium"
    modes are), principal point at the image centre, square pixels, and fx chosen so the
    horizontal FOV across the 1920 px width is exactly 94.4 deg. Resulting figures: fx = fy
    ~= 1110 px, vertical FOV ~= 54.8 deg, diagonal ~= 107.0 deg; at the left/right image edges the
    radius is ~20 % smaller than a pinhole with the same central focal length would give (strong
    barrel distortion). 003 §4 pairs "94.4 deg" with "1080 px", which could also be read as a
    vertical FOV; this model uses the horizontal reading (use `from_fov(..., axis="vertical")`
    for the other). The same model is in scenarios/library/cameras/atek_gopro.toml.
    """
    return from_fov(1920, 1080, 94.4, k_shape=(1.0, *ATEK_OPENCV_D), axis="horizontal",
                    name="atek_gopro")


# ----------------------------------------------------------------------------------------------
# dict form (camera files; the file I/O is in scenarios/config/camera.py)

_DICT_KEYS = {"width", "height", "fx", "fy", "cx", "cy", "model", "k", "opencv_D", "name"}


def camera_from_dict(d: Mapping[str, Any], where: str = "camera") -> FisheyeCamera:
    """Camera from the [camera] table of a camera file.

    Keys: width, height, fx, fy, cx, cy (numbers), model = "fisheye-odd-poly" (optional, the only
    model), and exactly one of k = [k1..k5] (003 eq. (13)) or opencv_D = [d1..d4] (OpenCV fisheye,
    meaning k = [1, d1..d4]); optional name. ``where`` prefixes error messages (e.g. the file
    name): errors name the key and the expected value.
    """
    if not isinstance(d, Mapping):
        raise ValueError(f"{where}: expected a table of camera parameters, got {type(d).__name__}")
    unknown = set(d) - _DICT_KEYS
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {sorted(unknown)}; expected {sorted(_DICT_KEYS)}")
    model = d.get("model", MODEL_NAME)
    if model != MODEL_NAME:
        raise ValueError(f"{where}: key 'model' = {model!r}; expected {MODEL_NAME!r}")
    vals: dict[str, Any] = {}
    for key in ("width", "height"):
        if key not in d:
            raise ValueError(f"{where}: missing key {key!r} (positive integer, pixels)")
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise ValueError(f"{where}: key {key!r} = {v!r}; expected a positive integer")
        vals[key] = v
    for key in ("fx", "fy", "cx", "cy"):
        if key not in d:
            raise ValueError(f"{where}: missing key {key!r} (number, pixels)")
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{where}: key {key!r} = {v!r}; expected a finite number")
        vals[key] = float(v)
    has_k, has_d = "k" in d, "opencv_D" in d
    if has_k == has_d:
        raise ValueError(f"{where}: give exactly one of 'k' = [k1..k5] or 'opencv_D' = [d1..d4]")
    key = "k" if has_k else "opencv_D"
    seq = d[key]
    if (not isinstance(seq, (list, tuple)) or
            not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in seq)):
        raise ValueError(f"{where}: key {key!r} = {seq!r}; expected a list of numbers")
    if has_k:
        if not 1 <= len(seq) <= 5:
            raise ValueError(f"{where}: key 'k' has {len(seq)} entries; expected 1 to 5 [k1..k5]")
        k = tuple(float(c) for c in seq)
    else:
        if len(seq) != 4:
            raise ValueError(f"{where}: key 'opencv_D' has {len(seq)} entries; expected 4 [d1..d4]")
        k = (1.0, *(float(c) for c in seq))
    name = d.get("name", "")
    if not isinstance(name, str):
        raise ValueError(f"{where}: key 'name' = {name!r}; expected a string")
    try:
        return FisheyeCamera(vals["width"], vals["height"], vals["fx"], vals["fy"], vals["cx"],
                             vals["cy"], k, name=name)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def camera_to_dict(camera: FisheyeCamera) -> dict[str, Any]:
    """The [camera] table for `camera_from_dict` (k written as given, with model name)."""
    out: dict[str, Any] = {}
    if camera.name:
        out["name"] = camera.name
    out.update({"model": MODEL_NAME, "width": camera.width, "height": camera.height,
                "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
                "k": list(camera.k)})
    return out
