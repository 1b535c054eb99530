"""Error covariance of a cone-fit direction with spatially correlated pixel noise, 003 §3.5,
eqs. (29)-(37), in O(m).

Linearisation on the unit sphere
--------------------------------
003 linearises the cone equation for points on the z = f plane (eq. (29)-(32)). Here the rows of
H are unit rays ``h_j = ray(u_j, v_j)`` and the right-hand side is the constant y (cos(alpha), or
1 for the free-alpha Sun fit), so a pixel error ``du_j`` (2-vector, distorted pixels) changes only
the row: ``h_j -> h_j + J_j du_j`` with ``J_j = d ray / d(u, v)`` (3x2,
`vision.camera.unproject_jacobian`, which carries the undistortion). With ``n`` the fitted
vector, eq. (30) becomes ``h_j^T dn = -n^T J_j du_j``, i.e. 003's row vector (eq. (32)) is

    g_j^T = -n^T J_j        (1x2)

and the linear estimate (003 eq. (24)) has, with ``N = H^T H`` (eq. (33)):

    P_n = N^-1 H^T G R_i G^T H N^-1,    H^T G du = sum_j h_j g_j^T du_j

003 eq. (34)-(35): R_i = R [C^|j-k|], C = (1 - 1/L) I_2: the u and v errors are independent
first-order Gauss-Markov sequences along the *ordered* edge (index j, as 003 does), each with the
Toeplitz correlation rho^|j-k|, rho = 1 - 1/L. With a_j = g_j,u h_j and b_j = g_j,v h_j (rows of
A, B, m x 3):

    H^T G R_i G^T H = R (A^T T A + B^T T B),   T_jk = rho^|j-k|

and ``T X`` costs O(m) because T = F + F^T - I with F the lower-triangular AR(1) filter
(``x_j = X_j + rho x_{j-1}``): one forward and one backward ``scipy.signal.lfilter`` pass. The
2m x 2m R_i is never formed.

Direction covariances returned
------------------------------
- ``P_n``: 003 eq. (33) as written, the covariance of the raw least-squares vector n.
- ``P_c``: covariance of the unit vector e = n/|n|: ``P_c = Pi P_n Pi / |n|^2``,
  Pi = I - e e^T (rank 2; the radial part of n is a scale/alpha error, not a direction error).
  For ``method="constrained"`` (|e| = 1 enforced, `vision.nadir.constrained_cone_fit`) the
  estimator is different: with T_e a 3x2 basis of the tangent plane at e and the same S,
  ``P_c = T_e (T_e^T N T_e)^-1 T_e^T S T_e (T_e^T N T_e)^-1 T_e^T`` (Gauss-Newton on the sphere),
  and P_n is set equal to it.
- ``P_sphere``: 003 eq. (37), ``lambda_max(P_c) I_3``, the spherical overbound used by the filter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from nav.rotation import tangent_basis

__all__ = ["DirectionCovariance", "ar1_toeplitz_apply", "ar1_quadratic_form",
           "direction_covariance", "tangent_basis"]


@dataclass(frozen=True)
class DirectionCovariance:
    """P_n (003 eq. (33)), P_c (unit-vector direction), P_sphere (eq. (37)), lambda_max."""

    P_n: np.ndarray
    P_c: np.ndarray
    P_sphere: np.ndarray
    lambda_max: float


def ar1_toeplitz_apply(X: np.ndarray, rho: float) -> np.ndarray:
    """T X with T_jk = rho^|j-k| (m x m, never formed), X (m, ...), O(m).

    T = F + B - I, F X: forward recursion f_j = X_j + rho f_{j-1}; B X: the same run backwards.
    """
    X = np.asarray(X, dtype=float)
    if not 0.0 <= rho < 1.0:
        raise ValueError(f"ar1_toeplitz_apply: rho = {rho}; expected 0 <= rho < 1 (L >= 1 px)")
    if rho == 0.0:
        return X.copy()
    if X.ndim == 2 and X.shape[0] > 0:
        return _ar1_apply_2d(np.ascontiguousarray(X), float(rho))
    from scipy.signal import lfilter   # this branch only (importing scipy.signal takes ~0.1 s)
    a = [1.0, -rho]
    fwd = lfilter([1.0], a, X, axis=0)
    bwd = lfilter([1.0], a, X[::-1], axis=0)[::-1]
    return fwd + bwd - X


@numba.njit(cache=True)
def _ar1_apply_2d(X, rho):
    """`ar1_toeplitz_apply` for a 2-D X: the recursions f_j = X_j + rho f_{j-1} forwards and
    backwards (the arithmetic of ``lfilter([1], [1, -rho])``), then F X + B X - X."""
    m, p = X.shape
    out = np.empty((m, p))
    for c in range(p):
        f = 0.0
        for j in range(m):
            f = rho * f + X[j, c] if j else X[j, c]
            out[j, c] = f
        b = 0.0
        for j in range(m - 1, -1, -1):
            b = rho * b + X[j, c] if j < m - 1 else X[j, c]
            out[j, c] = out[j, c] + b - X[j, c]
    return out


@numba.njit(cache=True)
def _normal_matrices(H, J, n, rho):
    """(A^T T A + B^T T B, H^T H) for `direction_covariance` in one pass over the m rows: with
    g_j = -n^T J_j (003 eq. (32) on the unit sphere), a_j = g_j,u h_j, b_j = g_j,v h_j (rows of
    A, B) and T_jk = rho^|j-k| applied by the forward and backward AR(1) recursions of
    `_ar1_apply_2d` (T X = F X + B X - X): one pass instead of an einsum, a concatenation, the
    recursions and three small matrix products (~10 numpy calls on (m, 6) arrays, m <= 512, per
    target and frame)."""
    m = H.shape[0]
    AB = np.empty((m, 6))
    N = np.zeros((3, 3))
    for j in range(m):
        gu = -(n[0] * J[j, 0, 0] + n[1] * J[j, 1, 0] + n[2] * J[j, 2, 0])
        gv = -(n[0] * J[j, 0, 1] + n[1] * J[j, 1, 1] + n[2] * J[j, 2, 1])
        for c in range(3):
            AB[j, c] = gu * H[j, c]
            AB[j, 3 + c] = gv * H[j, c]
            for d in range(3):
                N[c, d] += H[j, c] * H[j, d]
    TAB = _ar1_apply_2d(AB, rho) if rho > 0.0 else AB.copy()
    S = np.zeros((3, 3))
    for j in range(m):
        for c in range(3):
            for d in range(3):
                S[c, d] += AB[j, c] * TAB[j, d] + AB[j, 3 + c] * TAB[j, 3 + d]
    return S, N


def ar1_quadratic_form(X: np.ndarray, Y: np.ndarray, rho: float) -> np.ndarray:
    """X^T T Y for T_jk = rho^|j-k| in O(m) (X: (m, p), Y: (m, q))."""
    return np.asarray(X).T @ ar1_toeplitz_apply(Y, rho)


def direction_covariance(rays_c: np.ndarray, jac: np.ndarray, n: np.ndarray, R: float,
                         L: float, method: str = "linear") -> DirectionCovariance:
    """Covariance of a cone-fit direction, 003 eqs. (29)-(37), O(m).

    Parameters
    ----------
    rays_c : (m, 3) unit rays of the edge pixels, ordered along the edge (the order defines the
        correlation distance |j - k| of eq. (34)).
    jac : (m, 3, 2) d ray / d(u, v) at those pixels [1/px] (`vision.camera.unproject_jacobian`).
    n : (3,) the fitted vector (`ConeFit.n`): e for the known-alpha fit, e/cos(alpha) for the
        free-alpha fit.
    R : pixel error variance [px^2] (003 eq. (36): 1 px^2 horizon, eq. (38): 9 px^2 Sun).
    L : characteristic length of the pixel-error Gauss-Markov process [px] (300 in 003), >= 1.
    method : "linear" (003 eq. (33)) or "constrained" (unit-norm fit; see module docstring).
    """
    H = np.asarray(rays_c, dtype=float)
    J = np.asarray(jac, dtype=float)
    n = np.asarray(n, dtype=float)
    m = H.shape[0]
    if H.shape != (m, 3) or J.shape != (m, 3, 2) or n.shape != (3,):
        raise ValueError(f"direction_covariance: shapes rays {H.shape}, jac {J.shape}, n {n.shape}; "
                         f"expected (m, 3), (m, 3, 2), (3,)")
    if not (R >= 0 and math.isfinite(R)):
        raise ValueError(f"direction_covariance: R = {R}; expected a finite variance >= 0 [px^2]")
    if not L >= 1.0:
        raise ValueError(f"direction_covariance: L = {L} px; expected >= 1 (003 eq. (35))")
    if method not in ("linear", "constrained"):
        raise ValueError(f"direction_covariance: method {method!r}; expected 'linear' or 'constrained'")
    rho = 1.0 - 1.0 / L
    S0, N = _normal_matrices(np.ascontiguousarray(H), np.ascontiguousarray(J), n, rho)
    Tb = tangent_basis(n) if method == "constrained" else np.zeros((3, 2))
    P_n, P_c, lam = _covariance_from_normal(S0, N, n, float(R), method == "constrained", Tb)
    return DirectionCovariance(P_n=P_n, P_c=P_c, P_sphere=lam * np.eye(3), lambda_max=lam)


@numba.njit(cache=True)
def _covariance_from_normal(S0, N, n, R, constrained, Tb):  # pragma: no cover - numba
    """P_n, P_c and the largest eigenvalue of P_c from the sums of `_normal_matrices` (the
    3x3 algebra of `direction_covariance`: eq. (33) with the projector onto the tangent plane, or
    the constrained form in the tangent basis Tb of e = n/|n|; ~12 small numpy calls otherwise)."""
    S = R * S0
    S = 0.5 * (S + S.T)
    nn = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    e = n / nn
    if constrained:
        TbT = np.ascontiguousarray(Tb.T)
        Mi = np.linalg.inv(TbT @ N @ Tb)
        P_c = Tb @ Mi @ (TbT @ S @ Tb) @ Mi @ TbT
        P_n = P_c.copy()
    else:
        Ninv = np.linalg.inv(N)
        P_n = Ninv @ S @ Ninv
        Pi = np.eye(3) - np.outer(e, e)
        P_c = Pi @ P_n @ Pi / (nn * nn)
    P_n = 0.5 * (P_n + P_n.T)
    P_c = 0.5 * (P_c + P_c.T)
    return P_n, P_c, largest_eigenvalue(P_c)


@numba.njit(cache=True)
def largest_eigenvalue(P):  # pragma: no cover - numba
    """Largest eigenvalue of a symmetric matrix (``np.linalg.eigvalsh(P)[-1]`` without numpy's
    per-call overhead; the radius of the spherical overbound, 003 eq. (37))."""
    return np.linalg.eigvalsh(P)[-1]
