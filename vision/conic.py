"""General conic-section fit baseline and conic geometry, 003 §2.5, eqs. (6)-(7), (17)-(18).

This is the approach 003 §3.3 describes first and then sets aside (a general conic fit ignores
the constraints (19)-(21) that tie A..F to e); it is kept as a benchmark baseline for
`vision.nadir`. It works on the undistorted plane z = f (here f = 1: x = X/Z, y = Y/Z), so only
rays with z > 0 can take part (000 §2.2 explains why this fails near and beyond 90 deg).

Conic matrix: with q = [x, y, f], eq. (6) reads q^T M q = 0,
M = [[A, B/2, D/(2f)], [B/2, C, E/(2f)], [D/(2f), E/(2f), F/f^2]] (rows/cols scaled by f), and
eq. (7) says M = s (e e^T - cos^2(alpha) I) for a scale s != 0. Hence M has one simple
eigenvalue s (1 - cos^2 alpha) with eigenvector e and a double eigenvalue -s cos^2(alpha).
`nadir_from_conic` fixes the unknown scale s from the eigenvalues (simple - double = s) and
returns the simple eigenvector as e. 003 eq. (18), |e_i| = sqrt(M_ii/s + cos^2 alpha), gives the
same magnitudes for an exact conic but loses the signs and, through the square root, accuracy
of components near zero (an error eps in M_ii becomes sqrt(eps)); it is available with
``use_eq18=True`` (signs then taken from the eigenvector). The overall sign is chosen so that the
fitted points lie on the nappe around e (p^T e = +cos(alpha) |p|, 003 eq. (3)).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["conic_from_nadir", "fit_conic", "conic_matrix", "nadir_from_conic", "conic_nadir_fit"]


def conic_from_nadir(e_c: np.ndarray, alpha: float, f: float = 1.0) -> np.ndarray:
    """Coefficients z = [A, B, C, D, E, F] of the projected horizon, 003 eq. (7)."""
    ex, ey, ez = (float(v) for v in e_c)
    c2 = math.cos(alpha) ** 2
    return np.array([ex * ex - c2, 2 * ex * ey, ey * ey - c2, 2 * ex * ez * f, 2 * ey * ez * f,
                     f * f * (ez * ez - c2)])


def conic_matrix(z: np.ndarray, f: float = 1.0) -> np.ndarray:
    """Symmetric 3x3 M with [x, y, f] M [x, y, f]^T = eq. (6)."""
    A, B, C, D, E, F = (float(v) for v in z)
    return np.array([[A, B / 2, D / (2 * f)], [B / 2, C, E / (2 * f)],
                     [D / (2 * f), E / (2 * f), F / (f * f)]])


def fit_conic(xy: np.ndarray) -> np.ndarray:
    """Algebraic least-squares conic through points (m, 2), 003 eq. (17): unit-norm z minimising
    |Z z| (Z rows [x^2, xy, y^2, x, y, 1]), by SVD on Hartley-normalised points (centred, mean
    distance sqrt(2)) and mapped back. No ellipse/hyperbola constraint. Returns z (6,), |z| = 1."""
    P = np.asarray(xy, dtype=float)
    if P.ndim != 2 or P.shape[1] != 2 or P.shape[0] < 5:
        raise ValueError(f"fit_conic: need (m >= 5, 2) points, got {P.shape}")
    mu = P.mean(axis=0)
    d = np.mean(np.linalg.norm(P - mu, axis=1))
    k = math.sqrt(2.0) / d if d > 0 else 1.0
    x, y = ((P - mu) * k).T
    Z = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=1)
    zn = np.linalg.svd(Z, full_matrices=False)[2][-1]
    # back to original coordinates: x_n = k (x - mx), y_n = k (y - my); M_orig = T^T M_n T
    Mn = np.array([[zn[0], zn[1] / 2, zn[3] / 2], [zn[1] / 2, zn[2], zn[4] / 2],
                   [zn[3] / 2, zn[4] / 2, zn[5]]])
    T = np.array([[k, 0, -k * mu[0]], [0, k, -k * mu[1]], [0, 0, 1.0]])
    M = T.T @ Mn @ T
    z = np.array([M[0, 0], 2 * M[0, 1], M[1, 1], 2 * M[0, 2], 2 * M[1, 2], M[2, 2]])
    return z / np.linalg.norm(z)


def nadir_from_conic(z: np.ndarray, f: float = 1.0, points: np.ndarray | None = None,
                     use_eq18: bool = False) -> tuple[np.ndarray, float]:
    """Nadir e_c and cone half-angle alpha from conic coefficients, 003 eq. (18) with signs.

    ``points`` (m, 2) on the plane z = f (optional) choose the nappe; without them the sign
    that gives e_z > 0 is returned.
    """
    M = conic_matrix(z, f)
    w, V = np.linalg.eigh(M)
    # the double eigenvalue is the closest pair; the remaining one is the simple eigenvalue
    gaps = [abs(w[1] - w[0]), abs(w[2] - w[1])]
    if gaps[0] <= gaps[1]:
        single, dbl, v = w[2], 0.5 * (w[0] + w[1]), V[:, 2]
    else:
        single, dbl, v = w[0], 0.5 * (w[1] + w[2]), V[:, 0]
    s = single - dbl  # = s (1 - c^2) - (-s c^2)
    c2 = -dbl / s
    if not 0.0 < c2 < 1.0:
        raise ValueError(f"nadir_from_conic: conic is not the projection of a cone "
                         f"(cos^2 alpha = {c2:.6g})")
    if use_eq18:
        mag = np.sqrt(np.maximum(np.diag(M / s) + c2, 0.0))  # 003 eq. (18)
        e = np.sign(v) * mag
        e /= np.linalg.norm(e)
    else:
        e = v / np.linalg.norm(v)
    if points is not None:
        P = np.asarray(points, dtype=float)
        q = np.column_stack([P, np.full(P.shape[0], f)])
        if np.mean(q @ e) < 0:
            e = -e
    elif e[2] < 0:
        e = -e
    return e, math.acos(math.sqrt(c2))


def conic_nadir_fit(rays_c: np.ndarray) -> tuple[np.ndarray, float]:
    """Baseline: rays (z > 0 only) -> plane z = 1 -> `fit_conic` -> `nadir_from_conic`."""
    P = np.asarray(rays_c, dtype=float)
    P = P[P[:, 2] > 0]
    xy = P[:, :2] / P[:, 2:3]
    return nadir_from_conic(fit_conic(xy), 1.0, points=xy)
