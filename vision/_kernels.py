"""Compiled (numba) helpers shared by the vision modules: the lens polynomial and the projection
of one ray (003 eqs. (13)-(14)). The rotation helpers (tangent-plane basis, skew matrix,
quaternions) are nav's: :mod:`nav._kernels`.

Each is the scalar form of a numpy function elsewhere, with the same arithmetic, so that kernels
which call them give the same numbers as the numpy code: `poly1` of `vision.camera`'s r_d(theta),
`project1` of `vision.camera.project`.
"""
from __future__ import annotations

import math

import numba

__all__ = ["poly1", "project1"]


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
def project1(x, y, z, fx, fy, cx, cy, k, max_theta):  # pragma: no cover - numba
    """Pixel (u, v) of one camera-frame ray (x, y, z) of any length through the lens polynomial k
    (003 eqs. (13)-(14)); (NaN, NaN) beyond ``max_theta`` and for zero-length or straight-backward
    rays."""
    rho = math.hypot(x, y)
    theta = math.atan2(rho, z)
    if theta > max_theta or (rho == 0.0 and z <= 0.0):
        return math.nan, math.nan
    r_d = poly1(k, theta)
    scale = r_d / rho if rho > 0.0 else 0.0
    return cx + fx * scale * x, cy + fy * scale * y

