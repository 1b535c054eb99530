"""Compiled (numba) helpers shared by the vision modules: the lens models and the projection of one
ray through any camera model (003 eqs. (13)-(14) for the fisheye; OpenCV's pinhole distortion for
the pinhole). The rotation helpers (tangent-plane basis, skew matrix, quaternions) are nav's:
:mod:`nav._kernels`.

A camera hands the kernels a model code and one float64 parameter array
(``camera.kernel_params()``), so that one compiled kernel serves every model:

- ``FISHEYE`` (0): ``[fx, fy, cx, cy, max_theta, k1, .., kn]`` (odd polynomial r_d(theta),
  003 eq. (13); the equidistant model is k = [1]);
- ``PINHOLE`` (1): ``[fx, fy, cx, cy, max_r, k1, k2, p1, p2, k3, k4, k5, k6]`` (OpenCV's
  rational / plumb_bob distortion; max_r bounds the undistorted radius x/z of the valid region).

Each is the scalar form of a numpy function elsewhere, with the same arithmetic, so that kernels
which call them give the same numbers as the numpy code: `poly1` of `vision.camera`'s r_d(theta),
`project1` of `vision.camera.project`.
"""
from __future__ import annotations

import math

import numba

__all__ = ["FISHEYE", "PINHOLE", "poly1", "project1", "distort1", "undistort1"]

FISHEYE = 0
PINHOLE = 1
_P0 = 5  # index of the first distortion coefficient in the parameter array


@numba.njit(cache=True, nogil=True)
def poly1(k, t):  # pragma: no cover - numba
    """r_d(theta) = theta (k0 + k1 theta^2 + ...) for one theta (003 eq. (14)), Horner's scheme."""
    t2 = t * t
    n = k.shape[0]
    acc = k[n - 1]
    for i in range(n - 2, -1, -1):
        acc = acc * t2 + k[i]
    return acc * t


@numba.njit(cache=True, nogil=True)
def _poly_prm(prm, t):  # pragma: no cover - numba
    """`poly1` on the coefficients prm[5:] (same arithmetic, no slice)."""
    t2 = t * t
    n = prm.shape[0]
    acc = prm[n - 1]
    for i in range(n - 2, _P0 - 1, -1):
        acc = acc * t2 + prm[i]
    return acc * t


@numba.njit(cache=True, nogil=True)
def distort1(prm, x, y):  # pragma: no cover - numba
    """OpenCV pinhole distortion of one undistorted normalised point (x, y) = (X/Z, Y/Z):
    x_d = x R + 2 p1 x y + p2 (r^2 + 2 x^2), y_d = y R + p1 (r^2 + 2 y^2) + 2 p2 x y,
    R = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6). Returns (x_d, y_d) and the
    Jacobian d(x_d, y_d)/d(x, y) as (a, b, c, d) = [[a, b], [c, d]]."""
    k1, k2, p1, p2, k3, k4, k5, k6 = prm[5], prm[6], prm[7], prm[8], prm[9], prm[10], prm[11], prm[12]
    r2 = x * x + y * y
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    rad = num / den
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)
    dden = k4 + r2 * (2.0 * k5 + 3.0 * r2 * k6)
    drad = (dnum * den - num * dden) / (den * den)       # d R / d r^2
    xy = x * y
    xd = x * rad + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    a = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
    b = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y
    d = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, a, b, b, d


@numba.njit(cache=True, nogil=True)
def undistort1(prm, xd, yd):  # pragma: no cover - numba
    """Undistorted normalised point (x, y) of one distorted point (x_d, y_d): Newton's method on the
    2-D map of `distort1` from (x_d, y_d), each step halved until the residual decreases, to a
    step below 1e-15 (1 + |x|) (at most 60 steps). NaN when it does not converge or lands outside
    the valid radius prm[4]."""
    x, y = xd, yd
    fx_, fy_, a, b, c, d = distort1(prm, x, y)
    ex, ey = fx_ - xd, fy_ - yd
    res = math.hypot(ex, ey)
    for _ in range(60):
        det = a * d - b * c
        if not det > 0.0:
            return math.nan, math.nan
        sx = (d * ex - b * ey) / det
        sy = (a * ey - c * ex) / det
        lam = 1.0
        for _h in range(30):
            nx, ny = x - lam * sx, y - lam * sy
            gx, gy, na, nb, nc, nd = distort1(prm, nx, ny)
            nres = math.hypot(gx - xd, gy - yd)
            if nres <= res or nres == 0.0:
                break
            lam *= 0.5
        step = lam * math.hypot(sx, sy)
        x, y, a, b, c, d = nx, ny, na, nb, nc, nd
        ex, ey, res = gx - xd, gy - yd, nres
        if step <= 1e-15 * (1.0 + math.hypot(x, y)) or res == 0.0:
            break
    if not res <= 1e-12 * (1.0 + math.hypot(xd, yd)) or not math.hypot(x, y) <= prm[4]:
        return math.nan, math.nan
    return x, y


@numba.njit(cache=True, nogil=True)
def project1(x, y, z, model, prm):  # pragma: no cover - numba
    """Pixel (u, v) of one camera-frame ray (x, y, z) of any length through the camera model
    (``model``, ``prm``: the module docstring); (NaN, NaN) outside the model's valid range (beyond
    max_theta for the fisheye, beyond max_r or at z <= 0 for the pinhole) and for zero-length or
    straight-backward rays."""
    fx, fy, cx, cy = prm[0], prm[1], prm[2], prm[3]
    if model == FISHEYE:
        rho = math.hypot(x, y)
        theta = math.atan2(rho, z)
        if theta > prm[4] or (rho == 0.0 and z <= 0.0):
            return math.nan, math.nan
        r_d = _poly_prm(prm, theta)
        scale = r_d / rho if rho > 0.0 else 0.0
        return cx + fx * scale * x, cy + fy * scale * y
    if not z > 0.0:
        return math.nan, math.nan
    xn, yn = x / z, y / z
    if not math.hypot(xn, yn) <= prm[4]:
        return math.nan, math.nan
    xd, yd, _a, _b, _c, _d = distort1(prm, xn, yn)
    return cx + fx * xd, cy + fy * yd
