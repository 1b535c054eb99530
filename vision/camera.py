"""Camera models and their common interface: the radially symmetric fisheye (003, §3.2, eqs.
(12)-(16), `FisheyeCamera`; OpenCV's fisheye is k = [1, d1..d4]), the equidistant fisheye
(`EquidistantCamera`, k = [1]) and the pinhole with OpenCV's distortion (`PinholeCamera`,
vision/pinhole.py). `project`, `unproject`, `unproject_jacobian`, `pixel_rays` and `fov_deg`
take any of them; docs/cameras.md describes the models, their conversions and the camera files.
The rest of this docstring describes the fisheye.

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
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, Sequence, Union

import numba
import numpy as np

from vision._kernels import FISHEYE, poly1, project1
from vision._intrinsics import Intrinsics, check_intrinsics
from vision.pinhole import PinholeCamera, pinhole_unproject

__all__ = [
    "FisheyeCamera",
    "EquidistantCamera",
    "PinholeCamera",
    "Camera",
    "CAMERA_TYPES",
    "check_camera",
    "check_intrinsics",
    "fov_deg",
    "describe",
    "ROS_MODELS",
    "MODELS",
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

MODEL_NAME = "fisheye"
MODEL_NAME_LEGACY = "fisheye-odd-poly"
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
class FisheyeCamera(Intrinsics):
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

    k: tuple[float, ...] = (1.0,)
    name: str = ""
    model: ClassVar[str] = "fisheye"

    def __post_init__(self) -> None:
        label = check_intrinsics(self)
        k = tuple(float(c) for c in np.atleast_1d(np.asarray(self.k, dtype=float)))
        object.__setattr__(self, "k", k)
        if not 1 <= len(k) <= 5:
            raise ValueError(f"{label}: k must have 1 to 5 coefficients [k1..k5] (003 eq. (13)), "
                             f"got {len(k)}")
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
        object.__setattr__(self, "_prm", np.array([self.fx, self.fy, self.cx, self.cy, max_theta, *k]))
        object.__setattr__(self, "fov_theta", float(inverse_radial(self, np.array(corner_r))))

    @property
    def coefficients(self) -> np.ndarray:
        """k1..k5 padded with zeros to length 5."""
        out = np.zeros(5)
        out[: len(self.k)] = self.k
        return out

    def kernel_params(self) -> tuple[int, np.ndarray]:
        """(model code, parameter array [fx, fy, cx, cy, max_theta, k1..kn]) for
        `vision._kernels.project1`."""
        return FISHEYE, self._prm


@dataclass(frozen=True)
class EquidistantCamera(FisheyeCamera):
    """Equidistant fisheye r = f theta: the `FisheyeCamera` with k = [1] (no distortion
    coefficients). Construct without ``k``; any other k raises ValueError."""

    model: ClassVar[str] = "equidistant"

    def __post_init__(self) -> None:
        if tuple(np.atleast_1d(np.asarray(self.k, dtype=float)).tolist()) != (1.0,):
            raise ValueError(f"camera {self.name!r}: the equidistant model has k = [1.0], got k = "
                             f"{list(np.atleast_1d(self.k))}; use model 'fisheye' for distortion")
        super().__post_init__()


Camera = Union[FisheyeCamera, PinholeCamera]
CAMERA_TYPES = (FisheyeCamera, PinholeCamera)




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
def _project_kernel(p, model, prm):  # pragma: no cover - numba
    """Pixels (n, 2) of rays p (n, 3) through the camera model (`vision._kernels.project1`: NaN
    outside the model's valid range and for zero-length or straight-backward rays)."""
    n = p.shape[0]
    uv = np.empty((n, 2))
    for i in range(n):
        uv[i, 0], uv[i, 1] = project1(p[i, 0], p[i, 1], p[i, 2], model, prm)
    return uv


# ----------------------------------------------------------------------------------------------
# projection


def project(camera: Camera, rays_c: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) [u, v] of camera-frame rays (..., 3) of any length, through any camera model
    (fisheye: 003 eqs. (13)-(14); pinhole: `vision.pinhole`).

    For a fisheye theta may exceed 90 deg (rays with z <= 0) up to ``camera.max_theta``; rays
    beyond the model's valid range and zero-length rays give NaN.
    """
    p = np.asarray(rays_c, dtype=float)
    if p.shape[-1] != 3:
        raise ValueError(f"project: rays_c must have shape (..., 3), got {p.shape}")
    model, prm = camera.kernel_params()
    uv = _project_kernel(np.ascontiguousarray(p.reshape(-1, 3)), model, prm)
    return uv.reshape(p.shape[:-1] + (2,))


def _pixels(uv: np.ndarray) -> np.ndarray:
    uv = np.asarray(uv, dtype=float)
    if uv.shape[-1] != 2:
        raise ValueError(f"unproject: uv must have shape (..., 2), got {uv.shape}")
    return uv


def _unproject(camera: Camera, uv: np.ndarray, jac: bool):
    uv = _pixels(uv)
    if isinstance(camera, PinholeCamera):
        rays, J = pinhole_unproject(np.ascontiguousarray(uv.reshape(-1, 2)), camera.kernel_params()[1], jac)
    else:
        inv_dr, th_tab, sl_tab = _rtable(camera)
        rays, J = _unproject_kernel(np.ascontiguousarray(uv.reshape(-1, 2)), camera.fx, camera.fy, camera.cx,
                                    camera.cy, np.asarray(camera.k), inv_dr, th_tab, sl_tab, camera.max_radius,
                                    jac)
    lead = uv.shape[:-1]
    return rays.reshape(lead + (3,)), (J.reshape(lead + (3, 2)) if jac else None)


def unproject(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """Unit rays (..., 3) in the camera frame for pixels (..., 2); exact inverse of `project`.

    Pinhole: the undistortion iterated to convergence (`vision.pinhole`). Fisheye:

    003 eqs. (14)-(16) on the unit sphere (000, eq. (3)) instead of the z = f plane, so
    theta >= 90 deg is representable. Pixels outside the valid radius give NaN. With
    q = [(u - cx)/fx, (v - cy)/fy], r_d = |q|, theta = r_d^-1(r_d) (`inverse_radial`):
    ray = [sin(theta) q / r_d, cos(theta)] (one numba pass, `_unproject_kernel`).
    """
    return _unproject(camera, uv, False)[0]


def unproject_jacobian(camera: Camera, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (..., 3) and their Jacobian d ray / d [u, v] (..., 3, 2) [1/px].

    Pinhole: `vision.pinhole.pinhole_unproject`. Fisheye: with q = [(u - cx)/fx, (v - cy)/fy], r_d = |q|, theta = r_d^-1(r_d) and s = sin(theta)/r_d:
    ray = [s q, cos theta], d(s q)/dq = s I + (s'(r_d)/r_d) q q^T,
    d cos(theta)/dq = -sin(theta) theta'(r_d) q^T / r_d, theta' = 1 / (dr_d/dtheta).
    Near the axis (theta < 1e-3) the two ratios use their series limits. Used to carry the pixel
    noise of 003 eq. (34) (which lives in distorted pixels) onto the unit rays. One numba pass
    (`_unproject_kernel`).
    """
    return _unproject(camera, uv, True)


def pixel_rays(camera: Camera) -> np.ndarray:
    """Unit ray of every pixel centre, shape (height, width, 3), float64 (for the renderer)."""
    v, u = np.mgrid[0: camera.height, 0: camera.width].astype(float)
    return unproject(camera, np.stack([u, v], axis=-1))


# ----------------------------------------------------------------------------------------------
# converters


def from_opencv(K: np.ndarray, D: Sequence[float], width: int, height: int, name: str = "",
                model: str = "fisheye") -> Camera:
    """Camera from OpenCV intrinsics: K (3x3, zero skew) and D.

    ``model = "fisheye"`` (``cv2.fisheye``): D = [d1..d4]; theta_d = theta (1 + d1 theta^2 + ... +
    d4 theta^8) is 003 eq. (13) with k = [1, d1, .., d4]. ``model = "pinhole"`` (``cv2.projectPoints``):
    D = [k1, k2, p1, p2[, k3[, k4, k5, k6]]] (0, 4, 5 or 8 numbers), a `PinholeCamera`.
    """
    K = np.asarray(K, dtype=float)
    D = np.asarray(D, dtype=float).ravel()
    if K.shape != (3, 3):
        raise ValueError(f"from_opencv: K must be 3x3, got shape {K.shape}")
    if K[0, 1] != 0.0:
        raise ValueError(f"from_opencv: K[0,1] (skew) = {K[0, 1]} is not supported; expected 0")
    if model == "pinhole":
        if D.size not in (0, 4, 5, 8):
            raise ValueError(f"from_opencv: the OpenCV pinhole model has 4, 5 or 8 distortion coefficients "
                             f"[k1, k2, p1, p2[, k3[, k4, k5, k6]]], got {D.size} ({D.tolist()})")
        return PinholeCamera(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], tuple(D.tolist()), name=name)
    if model != "fisheye":
        raise ValueError(f"from_opencv: model {model!r}; expected 'fisheye' or 'pinhole'")
    if D.size != 4:
        raise ValueError(f"from_opencv: the OpenCV fisheye model has 4 distortion coefficients "
                         f"D = [d1, d2, d3, d4], got {D.size} ({D.tolist()}); a 5-coefficient D is "
                         f"OpenCV's pinhole (k1, k2, p1, p2, k3) model (model='pinhole')")
    return FisheyeCamera(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                         (1.0, *D.tolist()), name=name)


def to_opencv(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(K, D): for a fisheye, for ``cv2.fisheye`` with k1 folded into fx, fy (fx' = k1 fx,
    d_i = k_{i+1}/k1; every model of the class is representable, k1 > 0 being enforced); for a
    pinhole, for ``cv2.projectPoints`` (D as given, 5 zeros when none). Projects identically."""
    if isinstance(camera, PinholeCamera):
        return camera.K, (np.asarray(camera.dist, dtype=float) if camera.dist else np.zeros(5))
    c = camera.coefficients
    k1 = c[0]
    if not k1 > 0:
        raise ValueError(f"to_opencv: k1 = {k1} must be > 0 to fold into the focal length")
    K = np.array([[camera.fx * k1, 0.0, camera.cx], [0.0, camera.fy * k1, camera.cy], [0, 0, 1.0]])
    return K, c[1:] / k1


#: ROS ``CameraInfo.distortion_model`` -> (model of `from_opencv`, accepted numbers of coefficients).
#: ROS's "equidistant" is OpenCV's fisheye (Kannala-Brandt) model, not the `EquidistantCamera`.
ROS_MODELS = {"plumb_bob": ("pinhole", (0, 4, 5)), "rational_polynomial": ("pinhole", (8,)),
              "equidistant": ("fisheye", (4,))}


def from_camera_info(info: Mapping[str, Any] | Any, name: str = "") -> Camera:
    """Camera from ROS ``sensor_msgs/CameraInfo`` fields (a mapping or an object with attributes).

    ``distortion_model``: "plumb_bob" (D = [k1, k2, p1, p2, k3]) or "rational_polynomial" (8
    coefficients) -> `PinholeCamera`; "equidistant" (ROS's name of the OpenCV fisheye model,
    D = [d1..d4]) -> `FisheyeCamera`. ``K`` (9, row-major), ``width``, ``height``. ``R`` must be
    identity and ``P`` (12) is ignored on input (it describes the rectified image).
    """
    get = (lambda n: info[n]) if isinstance(info, Mapping) else (lambda n: getattr(info, n))
    try:
        model = str(get("distortion_model"))
        D = np.asarray(get("D") if _has(info, "D") else get("d"), dtype=float).ravel()
        K = np.asarray(get("K") if _has(info, "K") else get("k"), dtype=float).reshape(3, 3)
        width, height = int(get("width")), int(get("height"))
    except (KeyError, AttributeError) as exc:
        raise ValueError(f"from_camera_info: missing CameraInfo field {exc}") from None
    if model not in ROS_MODELS:
        raise ValueError(f"from_camera_info: distortion_model {model!r} is not supported; "
                         f"expected one of {sorted(ROS_MODELS)}")
    kind, sizes = ROS_MODELS[model]
    if D.size not in sizes:
        raise ValueError(f"from_camera_info: distortion_model {model!r} takes {' or '.join(map(str, sizes))} "
                         f"distortion coefficients D, got {D.size}")
    if _has(info, "R") or _has(info, "r"):
        R = np.asarray(get("R") if _has(info, "R") else get("r"), dtype=float)
        if R.size == 9 and np.any(R) and not np.allclose(R.reshape(3, 3), np.eye(3)):
            raise ValueError("from_camera_info: R must be identity (monocular camera)")
    return from_opencv(K, D, width, height, name=name, model=kind)


def _has(info: Any, name: str) -> bool:
    return name in info if isinstance(info, Mapping) else hasattr(info, name)


def to_camera_info(camera: Camera) -> dict[str, Any]:
    """ROS ``sensor_msgs/CameraInfo`` fields: width, height, distortion_model ("equidistant" for a
    fisheye, "plumb_bob" or "rational_polynomial" for a pinhole), D, K (9), R = identity (9),
    P = [K | 0] (12), as plain lists."""
    K, D = to_opencv(camera)
    if isinstance(camera, PinholeCamera):
        model = "rational_polynomial" if D.size == 8 else "plumb_bob"
        D = np.concatenate([D, np.zeros(5 - D.size)]) if D.size < 5 else D
    else:
        model = "equidistant"
    P = np.hstack([K, np.zeros((3, 1))])
    return {"width": camera.width, "height": camera.height, "distortion_model": model,
            "D": D.tolist(), "K": K.ravel().tolist(), "R": np.eye(3).ravel().tolist(),
            "P": P.ravel().tolist()}


def fov_deg(camera: Camera) -> tuple[float, float, float]:
    """(horizontal, vertical, diagonal) field of view [deg]: the sum of the angles off the optical
    axis of the rays through two opposite image edges (pixel edges) on the principal point's row
    (horizontal) and column (vertical), and through opposite corners (diagonal: the larger of the
    two diagonals). For a centred camera this is the FOV of `from_fov`."""
    w, h, cx, cy = camera.width - 0.5, camera.height - 0.5, camera.cx, camera.cy
    uv = np.array([[-0.5, cy], [w, cy], [cx, -0.5], [cx, h], [-0.5, -0.5], [w, h], [w, -0.5], [-0.5, h]])
    th = np.degrees(np.arccos(np.clip(unproject(camera, uv)[:, 2], -1.0, 1.0)))
    return float(th[0] + th[1]), float(th[2] + th[3]), float(max(th[4] + th[5], th[6] + th[7]))


def describe(camera: Camera) -> str:
    """One line: model, size, focal lengths and field of view (printed where the CLI loads a camera)."""
    hf, vf, df = fov_deg(camera)
    label = f"{camera.name} " if camera.name else ""
    return (f"camera {label}({camera.model}, {camera.width}x{camera.height} px, fx {camera.fx:.2f} px): "
            f"FOV {hf:.2f} deg horizontal, {vf:.2f} deg vertical, {df:.2f} deg diagonal")


def check_camera(camera: Any, where: str = "camera") -> None:
    """ValueError unless ``camera`` is one of the camera models (`CAMERA_TYPES`)."""
    if not isinstance(camera, CAMERA_TYPES):
        raise ValueError(f"{where}: {type(camera).__name__}, expected a vision.camera model "
                         f"(FisheyeCamera, EquidistantCamera or PinholeCamera)")


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
#: TOML ``model`` values -> class; "fisheye-odd-poly" is an older name of "fisheye".
MODELS = {"fisheye": "FisheyeCamera", MODEL_NAME_LEGACY: "FisheyeCamera", "pinhole": "PinholeCamera",
          "equidistant": "EquidistantCamera"}


def _dict_number(d: Mapping[str, Any], key: str, where: str, integer: bool = False):
    if key not in d:
        raise ValueError(f"{where}: missing key {key!r} ({'positive integer' if integer else 'number'}, pixels)")
    v = d[key]
    if integer:
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise ValueError(f"{where}: key {key!r} = {v!r}; expected a positive integer")
        return v
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{where}: key {key!r} = {v!r}; expected a finite number")
    return float(v)


def _dict_coefficients(d: Mapping[str, Any], model: str, where: str) -> tuple[float, ...]:
    """The distortion coefficients of a [camera] table, as the model's constructor takes them."""
    allowed = {"fisheye": ("k", "opencv_D"), "pinhole": ("opencv_D",), "equidistant": ()}[model]
    for key in ("k", "opencv_D"):
        if key in d and key not in allowed:
            raise ValueError(f"{where}: key {key!r} does not apply to model {model!r}; expected "
                             f"{' or '.join(repr(a) for a in allowed) or 'no distortion coefficients'}")
    given = [key for key in allowed if key in d]
    if model == "equidistant":
        return (1.0,)
    if model == "fisheye" and len(given) != 1:
        raise ValueError(f"{where}: give exactly one of 'k' = [k1..k5] or 'opencv_D' = [d1..d4]")
    if not given:
        return ()
    key = given[0]
    seq = d[key]
    if (not isinstance(seq, (list, tuple)) or
            not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in seq)):
        raise ValueError(f"{where}: key {key!r} = {seq!r}; expected a list of numbers")
    sizes = {"k": range(1, 6), "opencv_D": (4,) if model == "fisheye" else (4, 5, 8)}[key]
    if len(seq) not in sizes:
        what = {"k": "1 to 5 [k1..k5]", "opencv_D": "4 [d1..d4]" if model == "fisheye" else
                "4, 5 or 8 [k1, k2, p1, p2[, k3[, k4, k5, k6]]]"}[key]
        raise ValueError(f"{where}: key {key!r} has {len(seq)} entries; expected {what}")
    c = tuple(float(x) for x in seq)
    return (1.0, *c) if (model == "fisheye" and key == "opencv_D") else c


def camera_from_dict(d: Mapping[str, Any], where: str = "camera") -> Camera:
    """Camera from the [camera] table of a camera file.

    Keys: width, height, fx, fy, cx, cy (numbers); ``model`` = "fisheye" (default when absent;
    "fisheye-odd-poly" is accepted), "pinhole" or "equidistant"; for the fisheye exactly one of
    k = [k1..k5] (003 eq. (13)) or opencv_D = [d1..d4] (OpenCV fisheye, meaning k = [1, d1..d4]);
    for the pinhole optionally opencv_D = [k1, k2, p1, p2[, k3[, k4, k5, k6]]]; for the
    equidistant model (r = f theta, the fisheye with k = [1]) none; optional name. ``where``
    prefixes error messages (e.g. the file name): errors name the key and the expected value.
    """
    if not isinstance(d, Mapping):
        raise ValueError(f"{where}: expected a table of camera parameters, got {type(d).__name__}")
    unknown = set(d) - _DICT_KEYS
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {sorted(unknown)}; expected {sorted(_DICT_KEYS)}")
    model = d.get("model", "fisheye")
    if model not in MODELS:
        raise ValueError(f"{where}: key 'model' = {model!r}; expected 'pinhole', 'fisheye' or 'equidistant'")
    model = "fisheye" if model == MODEL_NAME_LEGACY else model
    vals = {key: _dict_number(d, key, where, key in ("width", "height"))
            for key in ("width", "height", "fx", "fy", "cx", "cy")}
    coeffs = _dict_coefficients(d, model, where)
    name = d.get("name", "")
    if not isinstance(name, str):
        raise ValueError(f"{where}: key 'name' = {name!r}; expected a string")
    cls = {"fisheye": FisheyeCamera, "pinhole": PinholeCamera, "equidistant": EquidistantCamera}[model]
    try:
        return cls(vals["width"], vals["height"], vals["fx"], vals["fy"], vals["cx"], vals["cy"], coeffs,
                   name=name)
    except ValueError as exc:
        msg = str(exc)
        if "dist =" in msg or "k =" in msg or "polynomial" in msg:
            msg = f"key {'opencv_D' if model == 'pinhole' else 'k'}: {msg}"
        raise ValueError(f"{where}: {msg}") from None


def camera_to_dict(camera: Camera) -> dict[str, Any]:
    """The [camera] table for `camera_from_dict` (coefficients written as given, with the model)."""
    out: dict[str, Any] = {}
    if camera.name:
        out["name"] = camera.name
    out.update({"model": camera.model, "width": camera.width, "height": camera.height,
                "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy})
    if isinstance(camera, PinholeCamera):
        if camera.dist:
            out["opencv_D"] = list(camera.dist)
    elif camera.model == "fisheye":
        out["k"] = list(camera.k)
    return out
