"""Pinhole camera with OpenCV's lens distortion (plumb_bob / rational polynomial).

Model (OpenCV ``cv2.projectPoints``; ROS ``plumb_bob`` and ``rational_polynomial``)
-------------------------------------------------------------------------------------
A camera-frame ray ``[X, Y, Z]`` (z along the optical axis, x right, y down; Z > 0) has the
undistorted normalised point ``x = X/Z, y = Y/Z``, ``r^2 = x^2 + y^2``, the distorted point::

    R   = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
    x_d = x R + 2 p1 x y + p2 (r^2 + 2 x^2)
    y_d = y R + p1 (r^2 + 2 y^2) + 2 p2 x y

and the pixel ``u = cx + fx x_d, v = cy + fy y_d`` (origin at the centre of the top-left pixel).
The distortion coefficients are given in OpenCV's order ``[k1, k2, p1, p2]``, ``[.., k3]`` or
``[.., k3, k4, k5, k6]`` (4, 5 or 8 numbers; none: no distortion).

Valid region
------------
``max_r`` is the end of the monotonic range of the radial map ``r -> r R(r^2)`` (the first radius
where its derivative or the denominator of R reaches 0; infinite if none up to r = 1e3). Rays with
``hypot(x, y) > max_r`` or ``Z <= 0`` project to NaN. The constructor checks that the image can be
undistorted uniquely: every pixel-edge point of the image border and a grid over the image must
undistort (Newton's method, `vision._kernels.undistort1`) to a point inside ``max_r`` where the
Jacobian of the distortion map has a positive determinant, else ValueError naming ``dist``.

Unprojection iterates the undistortion to convergence (Newton's method, steps below 1e-15, not
OpenCV's fixed 5 fixed-point iterations), and returns unit rays ``[x, y, 1] / |[x, y, 1]|``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numba
import numpy as np

from vision._intrinsics import Intrinsics, check_intrinsics
from vision._kernels import PINHOLE, distort1, undistort1

__all__ = ["PinholeCamera", "pinhole_unproject"]

_R_SCAN = 1.0e3     # largest undistorted radius x/z considered (89.94 deg off the axis)


def _radial_limit(c: np.ndarray) -> float:
    """First undistorted radius where d(r R(r^2))/dr <= 0 or the denominator of R <= 0 (inf if none
    up to _R_SCAN), on a grid refined by bisection."""
    k1, k2, _p1, _p2, k3, k4, k5, k6 = c

    def g(r):
        r2 = r * r
        return r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))

    def ok(r):
        r2 = r * r
        h = 1e-7 * np.maximum(r, 1e-3)
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        return (den > 0) & (g(r + h) - g(r - h) > 0)

    r = np.concatenate([np.linspace(0.0, 2.0, 20001), np.geomspace(2.0, _R_SCAN, 20001)[1:]])
    bad = np.nonzero(~ok(r))[0]
    if bad.size == 0:
        return math.inf
    i = int(bad[0])
    if i == 0:
        return 0.0
    lo, hi = float(r[i - 1]), float(r[i])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if bool(ok(np.array(mid))) else (lo, mid)
    return lo


@dataclass(frozen=True)
class PinholeCamera(Intrinsics):
    """Intrinsics of a pinhole camera with OpenCV distortion (module docstring).

    Parameters
    ----------
    width, height : int
        Image size [px].
    fx, fy : float
        Focal lengths [px].
    cx, cy : float
        Principal point [px] (OpenCV convention), inside the image.
    dist : tuple of float
        OpenCV distortion coefficients [k1, k2, p1, p2[, k3[, k4, k5, k6]]]: 0, 4, 5 or 8 numbers.
    name : str
        Free label.

    Derived: ``max_r`` (valid undistorted radius), ``max_theta = atan(max_r)`` [rad],
    ``fov_theta`` [rad] (largest angle off the axis seen in the image).
    """

    dist: tuple[float, ...] = ()
    name: str = ""
    model: ClassVar[str] = "pinhole"
    max_r: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        label = check_intrinsics(self)
        dist = tuple(float(c) for c in np.atleast_1d(np.asarray(self.dist, dtype=float)))
        object.__setattr__(self, "dist", dist)
        if len(dist) not in (0, 4, 5, 8) or not all(math.isfinite(c) for c in dist):
            raise ValueError(f"{label}: dist = {list(dist)}; expected 0, 4, 5 or 8 finite OpenCV "
                             f"coefficients [k1, k2, p1, p2[, k3[, k4, k5, k6]]]")
        c = self.coefficients
        max_r = _radial_limit(c)
        prm = np.array([self.fx, self.fy, self.cx, self.cy, max_r, *c])
        object.__setattr__(self, "_prm", prm)
        object.__setattr__(self, "max_r", max_r)
        object.__setattr__(self, "max_theta", math.atan(max_r))
        object.__setattr__(self, "max_radius", float(np.hypot(*distort1(prm, max_r, 0.0)[:2]))
                           if math.isfinite(max_r) else math.inf)
        object.__setattr__(self, "fov_theta", self._check_invertible(label))

    def _check_invertible(self, label: str) -> float:
        """Undistort the image border (every 2 px of the pixel edges) and a 33x33 grid; ValueError
        naming ``dist`` if any fails (not invertible over the image). Returns the largest angle."""
        w, h = self.width, self.height
        su = np.linspace(-0.5, w - 0.5, max(2, w // 2 + 1))
        sv = np.linspace(-0.5, h - 0.5, max(2, h // 2 + 1))
        border = np.concatenate([np.stack([su, np.full_like(su, -0.5)], 1),
                                 np.stack([su, np.full_like(su, h - 0.5)], 1),
                                 np.stack([np.full_like(sv, -0.5), sv], 1),
                                 np.stack([np.full_like(sv, w - 0.5), sv], 1)])
        gv, gu = np.meshgrid(np.linspace(-0.5, h - 0.5, 33), np.linspace(-0.5, w - 0.5, 33))
        uv = np.concatenate([border, np.stack([gu.ravel(), gv.ravel()], 1)])
        xy, det = _undistort_with_det(np.ascontiguousarray(uv), self._prm)
        bad = ~(np.isfinite(xy).all(axis=1) & (det > 0))
        if bad.any():
            u, v = uv[np.argmax(bad)]
            raise ValueError(f"{label}: distortion dist = {list(self.dist)} cannot be inverted over the "
                             f"image (pixel ({u:.1f}, {v:.1f}) has no unique undistorted point; the "
                             f"radial map r R(r^2) stops increasing at r = {self.max_r:.4g}); expected a "
                             f"distortion that is monotonic over the image")
        return float(np.max(np.arctan(np.hypot(xy[:, 0], xy[:, 1]))))

    @property
    def coefficients(self) -> np.ndarray:
        """[k1, k2, p1, p2, k3, k4, k5, k6], zero-padded."""
        out = np.zeros(8)
        out[: len(self.dist)] = self.dist
        return out

    def kernel_params(self) -> tuple[int, np.ndarray]:
        """(model code, parameter array) for `vision._kernels.project1`."""
        return PINHOLE, self._prm


@numba.njit(cache=True, nogil=True)
def _undistort_with_det(uv, prm):  # pragma: no cover - numba
    """Undistorted normalised points (n, 2) of pixels uv and the Jacobian determinant of the
    distortion map there (NaN where the undistortion fails)."""
    n = uv.shape[0]
    out = np.empty((n, 2))
    det = np.empty(n)
    for i in range(n):
        x, y = undistort1(prm, (uv[i, 0] - prm[2]) / prm[0], (uv[i, 1] - prm[3]) / prm[1])
        out[i, 0], out[i, 1] = x, y
        if x == x:
            _xd, _yd, a, b, c, d = distort1(prm, x, y)
            det[i] = a * d - b * c
        else:
            det[i] = math.nan
    return out, det


@numba.njit(cache=True, nogil=True)
def pinhole_unproject(uv, prm, jac):  # pragma: no cover - numba
    """Unit rays (n, 3) of pixels uv (n, 2) and with ``jac`` d ray / d(u, v) (n, 3, 2) (else an
    empty array): x = undistort((u - cx)/fx, (v - cy)/fy), ray = [x, y, 1]/N, N = |[x, y, 1]|;
    d ray/d(x, y) = the first two columns of d(a/|a|)/da = (I - ray ray^T)/N at a = [x, y, 1],
    d(x, y)/d(u, v) = J_dist^-1 diag(1/fx, 1/fy) (`distort1`'s Jacobian)."""
    n = uv.shape[0]
    rays = np.empty((n, 3))
    J = np.empty((n if jac else 0, 3, 2))
    fx, fy = prm[0], prm[1]
    for i in range(n):
        x, y = undistort1(prm, (uv[i, 0] - prm[2]) / fx, (uv[i, 1] - prm[3]) / fy)
        nn = math.sqrt(x * x + y * y + 1.0)
        rx, ry, rz = x / nn, y / nn, 1.0 / nn
        rays[i, 0], rays[i, 1], rays[i, 2] = rx, ry, rz
        if not jac:
            continue
        _xd, _yd, a, b, c, d = distort1(prm, x, y)
        det = a * d - b * c
        ia, ib, ic, id_ = d / det / fx, -b / det / fy, -c / det / fx, a / det / fy   # J_dist^-1 diag(1/f)
        # d ray / d(x, y)
        g00, g01 = (1.0 - rx * rx) / nn, -rx * ry / nn
        g10, g11 = -ry * rx / nn, (1.0 - ry * ry) / nn
        g20, g21 = -rz * rx / nn, -rz * ry / nn
        J[i, 0, 0] = g00 * ia + g01 * ic
        J[i, 0, 1] = g00 * ib + g01 * id_
        J[i, 1, 0] = g10 * ia + g11 * ic
        J[i, 1, 1] = g10 * ib + g11 * id_
        J[i, 2, 0] = g20 * ia + g21 * ic
        J[i, 2, 1] = g20 * ib + g21 * id_
    return rays, J
