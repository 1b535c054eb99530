"""Compiled (numba) helpers shared by the vision modules: the lens polynomial and the projection
of one ray (003 eqs. (13)-(14)), and the tangent-plane basis of a unit vector.

Each is the scalar form of a numpy function elsewhere, with the same arithmetic, so that kernels
which call them give the same numbers as the numpy code: `poly1` of `vision.camera`'s r_d(theta),
`project1` of `vision.camera.project`, `nb_tangent_basis` of `nav.rotation.tangent_basis`.
"""
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["poly1", "project1", "nb_tangent_basis"]


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


@numba.njit(cache=True, nogil=True)
def nb_tangent_basis(e):  # pragma: no cover - numba
    """(3, 2) orthonormal basis ``[t1, t2]`` of the plane perpendicular to ``e``: the arithmetic
    of `nav.rotation.tangent_basis` (``t1 = e x a / |e x a|``, a the x axis, or the y axis when e
    is within 26 deg of x; ``t2 = e x t1``)."""
    e0, e1, e2 = e[0], e[1], e[2]
    n = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0, e1, e2 = e0 / n, e1 / n, e2 / n
    if abs(e0) < 0.9:
        t0, t1, t2 = 0.0, e2, -e1
    else:
        t0, t1, t2 = -e2, 0.0, e0
    tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    a0, a1, a2 = t0 / tn, t1 / tn, t2 / tn
    T = np.empty((3, 2))
    T[0, 0], T[1, 0], T[2, 0] = a0, a1, a2
    T[0, 1], T[1, 1], T[2, 1] = e1 * a2 - e2 * a1, e2 * a0 - e0 * a2, e0 * a1 - e1 * a0
    return T
