"""Compiled (numba) helpers of the navigation package: skew matrix, quaternion and rotation-vector
conversions, the tangent-plane basis of a unit vector and the J2 gravity, allocation-light forms
for the kernels of :mod:`nav.ins`, :mod:`nav.error_state` and the filter loop
(:mod:`nav.filter_state`, :mod:`nav.updates`).

Conventions as :mod:`nav.rotation` (docs/conventions.md "Rotations"): quaternions scalar-last, ``R_ab``
maps b into a. ``tests/test_ins.py`` checks them against scipy and :func:`nav.earth.gravity_e`.
Other packages' kernels (the truth simulator) import them from here.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from nav import earth

_A, _GM, _J2, _W = earth.A, earth.GM, earth.J2, earth.OMEGA_E


@nb.njit(cache=True)
def skew(v):
    """Skew-symmetric matrix ``[v x]`` (3, 3), ``skew(a) @ b == cross(a, b)`` (003 eq. (48))."""
    K = np.zeros((3, 3))
    K[0, 1] = -v[2]; K[0, 2] = v[1]; K[1, 0] = v[2]
    K[1, 2] = -v[0]; K[2, 0] = -v[1]; K[2, 1] = v[0]
    return K


@nb.njit(cache=True)
def inverse3_into(M, out):
    """``out = M^-1`` for a (3, 3) ``M``: the adjugate over the determinant (Cramer's rule), exact
    to rounding for the well-conditioned matrices it serves (IMU calibrations within a few % of
    I). Returns the determinant; a zero one leaves ``out`` non-finite."""
    c00 = M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]
    c01 = M[1, 2] * M[2, 0] - M[1, 0] * M[2, 2]
    c02 = M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]
    det = M[0, 0] * c00 + M[0, 1] * c01 + M[0, 2] * c02
    r = 1.0 / det if det != 0.0 else np.nan
    out[0, 0] = c00 * r
    out[1, 0] = c01 * r
    out[2, 0] = c02 * r
    out[0, 1] = (M[0, 2] * M[2, 1] - M[0, 1] * M[2, 2]) * r
    out[1, 1] = (M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0]) * r
    out[2, 1] = (M[0, 1] * M[2, 0] - M[0, 0] * M[2, 1]) * r
    out[0, 2] = (M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1]) * r
    out[1, 2] = (M[0, 2] * M[1, 0] - M[0, 0] * M[1, 2]) * r
    out[2, 2] = (M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]) * r
    return det


@nb.njit(cache=True, fastmath=False)
def gravity(x0, x1, x2):
    """J2 gravitation + centrifugal acceleration in e at (x0, x1, x2) [m/s^2] as a tuple; the
    formula of :func:`nav.earth.gravity_e`."""
    r2 = x0 * x0 + x1 * x1 + x2 * x2
    r = math.sqrt(r2)
    zr2 = x2 * x2 / r2
    k = 1.5 * _J2 * (_A * _A / r2)
    fxy = 1.0 + k * (1.0 - 5.0 * zr2)
    fz = 1.0 + k * (3.0 - 5.0 * zr2)
    s = -_GM / (r2 * r)
    w2 = _W * _W
    return s * fxy * x0 + w2 * x0, s * fxy * x1 + w2 * x1, s * fz * x2


@nb.njit(cache=True)
def quat_to_R_into(q, R, normalise):
    """Scalar-last quaternion -> rotation matrix, written into ``R`` (3, 3). ``normalise``: divide
    by |q|^2 (any non-zero quaternion); otherwise q is taken as a unit quaternion."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    s = 2.0
    if normalise:
        s = 2.0 / (x * x + y * y + z * z + w * w)
    R[0, 0] = 1 - s * (y * y + z * z); R[0, 1] = s * (x * y - z * w); R[0, 2] = s * (x * z + y * w)
    R[1, 0] = s * (x * y + z * w); R[1, 1] = 1 - s * (x * x + z * z); R[1, 2] = s * (y * z - x * w)
    R[2, 0] = s * (x * z - y * w); R[2, 1] = s * (y * z + x * w); R[2, 2] = 1 - s * (x * x + y * y)


@nb.njit(cache=True)
def quat_to_R(q):
    """Scalar-last quaternion -> rotation matrix (normalising)."""
    R = np.empty((3, 3))
    quat_to_R_into(q, R, True)
    return R


@nb.njit(cache=True)
def R_to_quat(R):
    """Rotation matrix -> scalar-last unit quaternion with w >= 0 (Shepperd)."""
    q = np.empty(4)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr >= R[0, 0] and tr >= R[1, 1] and tr >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + tr)
        q[3] = 0.25 * s
        q[0] = (R[2, 1] - R[1, 2]) / s
        q[1] = (R[0, 2] - R[2, 0]) / s
        q[2] = (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] >= R[1, 1] and R[0, 0] >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q[0] = 0.25 * s
        q[1] = (R[0, 1] + R[1, 0]) / s
        q[2] = (R[0, 2] + R[2, 0]) / s
        q[3] = (R[2, 1] - R[1, 2]) / s
    elif R[1, 1] >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q[1] = 0.25 * s
        q[0] = (R[0, 1] + R[1, 0]) / s
        q[2] = (R[1, 2] + R[2, 1]) / s
        q[3] = (R[0, 2] - R[2, 0]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q[2] = 0.25 * s
        q[0] = (R[0, 2] + R[2, 0]) / s
        q[1] = (R[1, 2] + R[2, 1]) / s
        q[3] = (R[1, 0] - R[0, 1]) / s
    n = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    sg = 1.0 if q[3] >= 0 else -1.0
    for i in range(4):
        q[i] *= sg / n
    return q


@nb.njit(cache=True)
def rotvec_to_R(phi):
    """Rotation vector -> matrix, exp([phi x]) (Rodrigues with series near zero)."""
    a = math.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    if a < 1e-4:
        s = 1.0 - a * a / 6.0
        c = 0.5 - a * a / 24.0
    else:
        s = math.sin(a) / a
        c = (1.0 - math.cos(a)) / (a * a)
    K = skew(phi)
    return np.eye(3) + s * K + c * (K @ K)


@nb.njit(cache=True)
def tangent_basis(e):
    """(3, 2) orthonormal basis ``[t1, t2]`` of the plane perpendicular to ``e`` (non-zero, finite;
    normalised first): ``t1 = e x a / |e x a|`` with ``a`` the x axis (the y axis when e is within
    26 deg of x), ``t2 = e x t1``. :func:`nav.rotation.tangent_basis` checks its argument and
    calls this."""
    e0, e1, e2 = e[0], e[1], e[2]
    n = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0, e1, e2 = e0 / n, e1 / n, e2 / n
    if abs(e0) < 0.9:
        t0, t1, t2 = 0.0, e2, -e1     # e x x_hat
    else:
        t0, t1, t2 = -e2, 0.0, e0     # e x y_hat
    tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    a0, a1, a2 = t0 / tn, t1 / tn, t2 / tn
    T = np.empty((3, 2))
    T[0, 0], T[1, 0], T[2, 0] = a0, a1, a2
    T[0, 1], T[1, 1], T[2, 1] = e1 * a2 - e2 * a1, e2 * a0 - e0 * a2, e0 * a1 - e1 * a0
    return T


@nb.njit(cache=True)
def quadratic_form_covariance(P, v, W):
    """Covariance (2, 2) of ``w_k . q(y)``, ``k = 0, 1`` (``w_k`` the columns of ``W`` (3, 2)), for
    ``y = [psi_b; psi_c] ~ N(0, P)`` (``P`` (6, 6); (3, 3): ``psi_b`` alone) and the second-order
    vector term ``q = 1/2 phi x (phi x v) + 1/2 (psi_c x psi_b) x v``, ``phi = psi_b + psi_c``
    (:func:`nav.measurements.second_order_noise`). ``w . q = y^T A y`` with, for
    ``S = (w v^T + v w^T)/2 - (w . v) I`` and ``N = [(v x w) x]``: ``1/2 S`` in every 3 x 3 block,
    plus ``-N/4`` in the (psi_c, psi_b) block and ``N/4`` in the (psi_b, psi_c) block (from
    ``1/2 (psi_c x psi_b) . (v x w) = -1/2 psi_c^T N psi_b``); ``Cov_kl = 2 tr(A_k P A_l P)``."""
    m = P.shape[0]
    AP = np.zeros((2, m, m))
    for k in range(2):
        w = W[:, k]
        wv = w[0] * v[0] + w[1] * v[1] + w[2] * v[2]
        S = 0.25 * (np.outer(w, v) + np.outer(v, w))
        for i in range(3):
            S[i, i] -= 0.5 * wv
        A = np.zeros((m, m))
        for bi in range(0, m, 3):
            for bj in range(0, m, 3):
                A[bi:bi + 3, bj:bj + 3] = S
        if m == 6:
            N = skew(np.cross(v, w))
            A[3:6, 0:3] -= 0.25 * N
            A[0:3, 3:6] += 0.25 * N
        AP[k] = A @ P
    C = np.empty((2, 2))
    for k in range(2):
        for l in range(2):
            C[k, l] = 2.0 * np.sum(AP[k] * AP[l].T)
    return C
