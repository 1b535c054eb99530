"""Cone fits of the front end on top of `vision.nadir`: the fit with known or free alpha, its local
refinement from a start direction, the inlier re-selection, the sensitivity of the direction to
alpha, the curvature pre-filter's circle radii, and the edge subsampling they share."""
from __future__ import annotations

import functools
import math

import numba
import numpy as np

from nav._kernels import tangent_basis as nb_tangent_basis
from vision.covariance import tangent_basis
from vision.nadir import ConeFit, angle_residual, conic_type, direction_and_radius, nadir_from_horizon, within_cone

__all__ = ["subsample", "median", "triple_radii", "refine_local", "fit_cone", "alpha_sensitivity",
           "reselect_inliers"]


@functools.lru_cache(maxsize=512)
def subsample(m: int, k: int) -> np.ndarray:
    """At most k indices spread evenly over 0..m-1 (edge order kept). Cached per (m, k) (the
    same edge lengths recur from frame to frame); the returned array is read-only."""
    idx = np.arange(m) if m <= k else (_spread_indices(m, k) if k > 1 else np.zeros(max(k, 0), np.int64))
    idx.flags.writeable = False
    return idx


@numba.njit(cache=True)
def _spread_indices(m, k):  # pragma: no cover - numba
    """``np.unique(np.linspace(0, m - 1, k).round().astype(np.int64))`` for m > k > 1 (the same
    arithmetic: i * step, the last value exactly m - 1, round half to even; the step exceeds 1,
    so the rounded values are distinct and no sort is needed, but repeats are skipped anyway);
    np.unique and np.linspace have a per-call overhead, and edge lengths change from frame to
    frame."""
    step = (m - 1) / (k - 1)
    out = np.empty(k, np.int64)
    n = 0
    for i in range(k):
        x = np.rint(i * step) if i < k - 1 else np.float64(m - 1)
        j = np.int64(x)
        if n == 0 or j > out[n - 1]:
            out[n] = j
            n += 1
    return out[:n]


def median(x: np.ndarray) -> float:
    """``float(np.median(x))`` for a finite 1-D array, without np.median's per-call overhead
    (same arithmetic: the middle element, or the mean of the two middle ones)."""
    n = x.shape[0]
    if n == 0:
        return math.nan
    s = np.sort(x)
    if np.isnan(s[-1]):   # NaNs sort last; np.median gives NaN
        return math.nan
    h = n // 2
    return float(s[h]) if n % 2 else float((s[h - 1] + s[h]) / 2.0)



def triple_radii(H: np.ndarray, n_triples: int = 6) -> np.ndarray:
    """Angular radii [rad] (<= pi/2) of the circles on the unit sphere through triples of rays
    spread along an ordered edge: the full span (first, middle, last) and ``n_triples - 1`` triples
    spanning a third of it. A plane through three unit rays cuts the sphere in a circle of angular
    radius rho with cos(rho) = distance of the plane from the origin."""
    m = H.shape[0]
    if m < 9:
        return np.zeros(0)
    return _triple_radii_kernel(np.ascontiguousarray(H, dtype=float), _triple_index(m, n_triples))


@functools.lru_cache(maxsize=512)
def _triple_index(m: int, n_triples: int) -> np.ndarray:
    """(n_triples, 3) indices of the triples of `triple_radii` for an edge of m >= 9 rays."""
    s = m // 3
    starts = np.linspace(0, m - 1 - 2 * s, n_triples - 1).round().astype(np.int64)
    i = np.concatenate([[0], starts])
    j = np.concatenate([[m // 2], starts + s])
    k = np.concatenate([[m - 1], starts + 2 * s])
    idx = np.ascontiguousarray(np.stack([i, j, k], axis=1))
    idx.flags.writeable = False
    return idx


@numba.njit(cache=True)
def _triple_radii_kernel(H, idx):
    """arccos(|w . p1| / |w|), w = (p2 - p1) x (p3 - p1), for each index triple (p1, p2, p3);
    triples with |w| <= 1e-15 (collinear) are left out."""
    out = np.empty(idx.shape[0])
    n = 0
    for t in range(idx.shape[0]):
        i, j, k = idx[t, 0], idx[t, 1], idx[t, 2]
        ax, ay, az = H[j, 0] - H[i, 0], H[j, 1] - H[i, 1], H[j, 2] - H[i, 2]
        bx, by, bz = H[k, 0] - H[i, 0], H[k, 1] - H[i, 1], H[k, 2] - H[i, 2]
        wx, wy, wz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        wn = math.sqrt(wx * wx + wy * wy + wz * wz)
        if wn > 1e-15:
            c = abs(wx * H[i, 0] + wy * H[i, 1] + wz * H[i, 2]) / wn
            out[n] = math.acos(min(max(c, 0.0), 1.0))
            n += 1
    return out[:n]



def refine_local(H: np.ndarray, e0: np.ndarray, c: float, iters: int = 8) -> np.ndarray:
    """Local minimum of |H e - c 1|^2 on |e| = 1 near e0 (Gauss-Newton in the tangent plane), for
    the mirrored-nadir alternative and the limb refits (the global minimum is
    `constrained_cone_fit`). One numba call (`_refine_kernel`) instead of ~10 small numpy calls
    per iteration, up to 8 iterations, 2-4 times per frame."""
    e0 = np.asarray(e0, dtype=float)
    return _refine_kernel(np.ascontiguousarray(H, dtype=float), e0 / np.linalg.norm(e0), float(c), iters)




@numba.njit(cache=True)
def _refine_kernel(H, e, c, iters):
    """Gauss-Newton of `refine_local`: step ``dx = -lstsq(H T, H e - c)``, ``e <- (e + T dx) /
    |.|``, stop when |dx| < 1e-13. The two-column step from its 2x2 normal equations (Cholesky,
    one pass over the sums, instead of a LAPACK gelsd call per iteration, 5-10 per frame): their
    squared condition only slows the convergence, the fixed point ``(H T)^T (H e - c) = 0`` is the
    least-squares one whatever the step's rounding. A second column within rcond = eps max(m, 2)
    of the first's span (a degenerate edge) is dropped, as gelsd's minimum-norm step to first
    order."""
    m = H.shape[0]
    rcond = np.finfo(np.float64).eps * max(m, 2)
    e = e.copy()
    for _ in range(iters):
        T = nb_tangent_basis(e)
        s11 = s12 = s22 = s1r = s2r = 0.0
        for j in range(m):
            a0 = H[j, 0] * T[0, 0] + H[j, 1] * T[1, 0] + H[j, 2] * T[2, 0]
            a1 = H[j, 0] * T[0, 1] + H[j, 1] * T[1, 1] + H[j, 2] * T[2, 1]
            rj = H[j, 0] * e[0] + H[j, 1] * e[1] + H[j, 2] * e[2] - c
            s11 += a0 * a0
            s12 += a0 * a1
            s22 += a1 * a1
            s1r += a0 * rj
            s2r += a1 * rj
        if not s11 > 0.0:
            break
        # R = [[r11, r12], [0, r22]] of A = QR, Q^T r = (q1r, q2r), from the sums
        r11 = math.sqrt(s11)
        r12 = s12 / r11
        r22sq = s22 - r12 * r12
        q1r = s1r / r11
        if r22sq > (rcond * r11) ** 2:
            r22 = math.sqrt(r22sq)
            q2r = (s2r - r12 * q1r) / r22
            x1 = q2r / r22
            x0 = (q1r - r12 * x1) / r11
        else:
            x1 = 0.0
            x0 = q1r / r11
        d0, d1 = -x0, -x1
        e0 = e[0] + T[0, 0] * d0 + T[0, 1] * d1
        e1 = e[1] + T[1, 0] * d0 + T[1, 1] * d1
        e2 = e[2] + T[2, 0] * d0 + T[2, 1] * d1
        en = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        e[0], e[1], e[2] = e0 / en, e1 / en, e2 / en
        if math.sqrt(d0 * d0 + d1 * d1) < 1e-13:
            break
    return e


def fit_cone(H: np.ndarray, alpha: float | None, e_start: np.ndarray | None = None) -> ConeFit:
    if alpha is None:
        return direction_and_radius(H)
    if e_start is None:
        return nadir_from_horizon(H, alpha)
    e = refine_local(H, e_start, math.cos(alpha))
    delta, kind = conic_type(e, alpha)
    return ConeFit(e_c=e, alpha=alpha, n=e, rhs=math.cos(alpha), discriminant=delta, conic=kind,
                   residual=angle_residual(H, e, alpha), m=H.shape[0], method="constrained")


def alpha_sensitivity(H: np.ndarray, e: np.ndarray, alpha: float) -> np.ndarray:
    """d e / d alpha of the constrained fit (linearised normal equations in the tangent plane at
    e: x = (T^T N T)^-1 T^T H^T (c 1 - H e), c = cos(alpha), so de/dc = T (T^T N T)^-1 T^T H^T 1)."""
    T = tangent_basis(e)
    return _alpha_sensitivity_kernel(np.ascontiguousarray(H, dtype=float), T, math.sin(alpha))


@numba.njit(cache=True)
def _alpha_sensitivity_kernel(H, T, sin_alpha):  # pragma: no cover - numba
    """`alpha_sensitivity`: A = H T, the 2x2 normal equations A^T A x = A^T 1 by Cramer's rule."""
    a00 = a01 = a11 = b0 = b1 = 0.0
    for j in range(H.shape[0]):
        x = H[j, 0] * T[0, 0] + H[j, 1] * T[1, 0] + H[j, 2] * T[2, 0]
        y = H[j, 0] * T[0, 1] + H[j, 1] * T[1, 1] + H[j, 2] * T[2, 1]
        a00 += x * x
        a01 += x * y
        a11 += y * y
        b0 += x
        b1 += y
    det = a00 * a11 - a01 * a01
    x0 = (a11 * b0 - a01 * b1) / det
    x1 = (a00 * b1 - a01 * b0) / det
    out = np.empty(3)
    for c in range(3):
        out[c] = (T[c, 0] * x0 + T[c, 1] * x1) * (-sin_alpha)
    return out



def reselect_inliers(H, fit, inliers, thr, refit, n_iter: int, min_inliers: int):
    """Local optimisation of a cone fit: the rays within ``thr`` [rad] of its cone, the fit
    ``refit(H[sel], fit)`` on them, repeated until the selection repeats (the fit on it is the one
    at hand) or ``n_iter`` times. Returns (fit, inliers, ok); ok is False when a selection had
    fewer than ``min_inliers`` rays (fit and inliers are then the last ones before it)."""
    for _ in range(n_iter):
        new = within_cone(H, fit.e_c, fit.alpha, thr)
        if new.sum() < min_inliers:
            return fit, inliers, False
        if (new == inliers).all():
            break
        inliers = new
        fit = refit(H[inliers], fit)
    return fit, inliers, True
