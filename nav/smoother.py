"""Rauch-Tung-Striebel smoother over the closed-loop forward pass of :mod:`nav.navigator`.

For a linear system the RTS recursion (Rauch, Tung & Striebel 1965) is::

    C_k   = P_k+ Phi_{k+1}^T (P_{k+1}-)^-1
    x_k^s = x_k+ + C_k (x_{k+1}^s - x_{k+1}-)
    P_k^s = P_k+ + C_k (P_{k+1}^s - P_{k+1}-) C_k^T

(:func:`rts` implements exactly this and is checked against filterpy's ``rts_smoother``).

Closed loop error state. The forward filter feeds its corrections back, so its posterior error
estimate is zero at every epoch and the prior at k+1 is zero about the propagated nominal. Written
as the smoothed error ``d_k`` about the forward posterior nominal at k, with ``delta_{k+1}`` the
correction fed back at epoch k+1 (zero where there was no update), the recursion becomes::

    d_N = 0,   d_k = C_k (d_{k+1} + delta_{k+1})

and the smoothed nominal is the forward solution corrected by ``d_k`` (position, velocity,
attitude ``exp([psi x]) R_eb``, the estimated sensor and misalignment groups).

Considered (Schmidt) states are not estimated by the forward filter and are not estimated by the
smoother either. The recursion runs over the estimated states ``e`` alone, with the considered
states marginalised into its process noise. The Schmidt covariance is not that of an optimal
filter: its update lowers the estimated block (``P+[e, e] <= P-[e, e]``) but leaves the
estimated/considered cross terms indefinite, and the considered states' share of the propagation,
``Q = P_{k+1}-[e, e] - Phi_ee P_k+[e, e] Phi_ee^T``, can be indefinite too. Used as they are, the
full-state gain (or the one with Q indefinite) feeds those cross terms back at every epoch; with
small white process noise nothing damps it, and the smoothed position drifts by hundreds of meters
while the smoothed covariance loses definiteness. The smoother therefore uses its own prior::

    Pp_k+1 = Phi_ee P_k+[e, e] Phi_ee^T + Q+,    Q+ the positive semidefinite part of Q
    C_k    = P_k+[e, e] Phi_ee^T Pp_k+1^-1
    d_k[e] = C_k (d_k+1 + delta_k+1)[e],   d_k[considered] = 0
    P_k^s  = P_k+[e, e] + C_k (P_k+1^s - Pp_k+1) C_k^T

``Pp >= P_{k+1}-[e, e] >= P_{k+1}+[e, e] >= P_{k+1}^s`` and ``Pp >= Phi_ee P_k+ Phi_ee^T``, so
``P_k^s = (P_k+ - C Pp C^T) + C P_k+1^s C^T`` is positive semidefinite and never above the forward
``P_k+[e, e]`` (by induction from ``P_N^s = P_N+``; the middle inequality is the Schmidt update's
on the estimated block, which the rotation of the misalignment covariance after a feedback,
:meth:`nav.filter_state.FilterState.reset_rotations`, keeps only to first order). Without
considered states and with the covariance as propagated, ``Q+ = Q`` and this is the textbook
recursion. The considered states' smoothed variances are the forward ones. Limitation: in the
smoother's model a considered state's effect is white, so an estimated state that it confounds
(a tilt against an accelerometer bias both driving one velocity axis) takes part of that effect,
and its smoothed variance is optimistic there. Checked in tests/test_smoother.py.

Implementation: the backward pass over the forward run's store (:class:`nav.navigator.SmootherStore`)
is one numba kernel, :func:`rts_kernel`: per epoch the smoother's prior (one symmetric
eigendecomposition of Q), a Cholesky factorisation of it, the gain from two triangular solves with
``Phi_ee P_k+[e, e]`` and the covariance recursion, all in preallocated (ne, ne) work arrays.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from nav.navigator import NavResult
from nav.rotation import matrix_to_quat, matrix_to_rotvec, quat_to_matrix, rotvec_to_matrix


def rts(xs_post, Ps_post, xs_prior, Ps_prior, Phis):
    """Plain RTS smoother for a linear filter (filterpy convention: ``Phis[k]`` maps k to k+1,
    ``xs_prior[k+1] = Phis[k] xs_post[k]``).

    Parameters
    ----------
    xs_post, Ps_post : (N, n), (N, n, n) filtered estimates.
    xs_prior, Ps_prior : (N, n), (N, n, n) predictions (index k: prediction for epoch k).
    Phis : (N, n, n) transitions.
    """
    x = np.array(xs_post, float)
    P = np.array(Ps_post, float)
    N = x.shape[0]
    for k in range(N - 2, -1, -1):
        C = np.linalg.solve(Ps_prior[k + 1].T, (Ps_post[k] @ Phis[k].T).T).T
        x[k] = xs_post[k] + C @ (x[k + 1] - xs_prior[k + 1])
        P[k] = Ps_post[k] + C @ (P[k + 1] - Ps_prior[k + 1]) @ C.T
    return x, P


@dataclass
class SmoothResult:
    t_ns: np.ndarray        #: covariance epochs
    idx: np.ndarray         #: IMU sample index of each epoch
    d: np.ndarray           #: (K, n) smoothed error about the forward posterior nominal
    P: np.ndarray           #: (K, n) smoothed covariance diagonal
    x_e: np.ndarray         #: (K, 3) smoothed position at the epochs
    v_e: np.ndarray
    q_eb: np.ndarray
    #: (K, n) smoothed estimates of the states beyond dx, dv, psi, in the coordinates of
    #: ``NavResult.estimates`` (:func:`smoothed_estimates`); None when the forward run has none
    estimates: np.ndarray | None = None
    #: (K, 9, 9) smoothed covariance of dx, dv, psi (the full navigation block)
    P_nav: np.ndarray | None = None


@nb.njit(cache=True, fastmath={"contract"})
def _cholesky_upper(S, U):
    """``U`` upper triangular with ``U^T U = S`` (right-looking, row-contiguous updates); False if
    S is not positive definite. Only the upper triangle of S is read."""
    n = S.shape[0]
    for i in range(n):
        for j in range(n):
            U[i, j] = S[i, j] if j >= i else 0.0
    for j in range(n):
        piv = U[j, j]
        if not piv > 0.0:
            return False
        inv = 1.0 / np.sqrt(piv)
        for c in range(j, n):
            U[j, c] *= inv
        for i in range(j + 1, n):
            a = U[j, i]
            if a != 0.0:
                for c in range(i, n):
                    U[i, c] -= a * U[j, c]
    return True


@nb.njit(cache=True, fastmath={"contract"})
def _chol_solve(U, B):
    """In place ``B <- (U^T U)^-1 B`` (B (n, r)), row-oriented (axpy) loops."""
    n = U.shape[0]
    r = B.shape[1]
    for i in range(n):           # U^T Y = B
        for p in range(i):
            a = U[p, i]
            if a != 0.0:
                for c in range(r):
                    B[i, c] -= a * B[p, c]
        inv = 1.0 / U[i, i]
        for c in range(r):
            B[i, c] *= inv
    for i in range(n - 1, -1, -1):   # U X = Y
        for p in range(i + 1, n):
            a = U[i, p]
            if a != 0.0:
                for c in range(r):
                    B[i, c] -= a * B[p, c]
        inv = 1.0 / U[i, i]
        for c in range(r):
            B[i, c] *= inv


@nb.njit(cache=True, nogil=True)
def _smoother_prior(Ak, dk, Pk, P_next, e, Phi, Pe, Ct, Pp):
    """The estimated states' transition ``Phi = Phi[e, e]`` (rows 0..8 from ``Ak``, the others
    diagonal ``dk``), ``Pe = P_post[e, e]``, ``Ct = Phi Pe`` and the smoother's prior
    ``Pp = Phi Pe Phi^T + Q+`` with ``Q+`` the positive semidefinite part of
    ``Q = P_{k+1}-[e, e] - Phi Pe Phi^T`` (module docstring)."""
    ne = e.size
    for a in range(ne):
        r = e[a]
        for b in range(ne):
            Pe[a, b] = Pk[r, e[b]]
            Phi[a, b] = Ak[r, e[b]] if r < 9 else (dk[r] if b == a else 0.0)
    np.dot(Phi, Pe, Ct)
    M = np.dot(Ct, Phi.T)
    Q = np.empty((ne, ne))
    for a in range(ne):
        for b in range(ne):
            Q[a, b] = 0.5 * (P_next[e[a], e[b]] + P_next[e[b], e[a]]) - 0.5 * (M[a, b] + M[b, a])
    w, V = np.linalg.eigh(Q)
    for a in range(ne):
        w[a] = max(w[a], 0.0)
    for a in range(ne):
        for b in range(a, ne):
            s = 0.0
            for c in range(ne):
                s += V[a, c] * w[c] * V[b, c]
            v = 0.5 * (M[a, b] + M[b, a]) + s
            Pp[a, b] = v
            Pp[b, a] = v


@nb.njit(cache=True, nogil=True)
def rts_kernel(P_prior, post, P_full, A, dphi, dxs, e, d, Pd, Pn, Ps, k_start):
    """Backward RTS pass of :func:`rts_smooth` over the estimated states ``e`` (module docstring)
    from epoch ``k_start`` down to 0.

    Parameters
    ----------
    P_prior : (K, n, n); post : (K,) row of ``P_full`` with the posterior (-1: the prior);
    A, dphi : (K, 9, n), (K, n) transition from k-1 to k; dxs : (K, n) fed-back corrections;
    e : (ne,) indices of the estimated states (0..8 first); d : (K, n) smoothed errors (row
    ``k_start + 1`` given, rows below written); Pd : (K, n) smoothed variances (written; the
    considered states keep the forward ones); Pn : (K, 9, 9) smoothed navigation block (written);
    Ps : (ne, ne) smoothed covariance of the estimated states at ``k_start + 1``, updated in place.

    Returns
    -------
    int
        -1 when done, or the epoch k where the smoother's prior is not positive definite (nothing
        written for it): the caller solves that epoch by least squares and continues from k - 1.
    """
    n, ne = P_prior.shape[1], e.size
    L = np.empty((ne, ne))
    Ct = np.empty((ne, ne))
    Pp = np.empty((ne, ne))
    Pe = np.empty((ne, ne))
    Phi = np.empty((ne, ne))
    Dl = np.empty((ne, ne))
    X = np.empty((ne, ne))
    w = np.empty(ne)
    for k in range(k_start, -1, -1):
        j = post[k]
        Pk = P_full[j] if j >= 0 else P_prior[k]
        _smoother_prior(A[k + 1], dphi[k + 1], Pk, P_prior[k + 1], e, Phi, Pe, Ct, Pp)
        # C^T = Pp^-1 Phi Pe (Pp symmetric)
        if not _cholesky_upper(Pp, L):
            return k
        _chol_solve(L, Ct)
        # d_k = C (d_{k+1} + delta_{k+1}) on the estimated states; the considered ones stay zero
        for a in range(ne):
            w[a] = d[k + 1, e[a]] + dxs[k + 1, e[a]]
        for a in range(n):
            d[k, a] = 0.0
        for p in range(ne):
            c = w[p]
            if c != 0.0:
                for a in range(ne):
                    d[k, e[a]] += Ct[p, a] * c
        # Ps = Pe + C (Ps_next - Pp) C^T, numpy's left-to-right order of C @ D @ C.T
        for a in range(ne):
            for b in range(ne):
                Dl[a, b] = Ps[a, b] - Pp[a, b]
        np.dot(Ct.T, Dl, X)
        np.dot(X, Ct, Dl)
        for a in range(ne):
            for b in range(ne):
                Ps[a, b] = Pe[a, b] + Dl[a, b]
        for a in range(ne):
            for b in range(a + 1, ne):
                v = 0.5 * (Ps[a, b] + Ps[b, a])
                Ps[a, b] = v
                Ps[b, a] = v
        for a in range(n):
            Pd[k, a] = Pk[a, a]
        for a in range(ne):
            Pd[k, e[a]] = Ps[a, a]
        Pn[k] = Ps[:9, :9]
    return -1


def _lstsq_epoch(st, e, post_k, d, Ps, k):
    """Epoch k of the backward pass by least squares (the smoother's prior not positive
    definite): writes ``d[k]`` and returns the smoothed covariance of the estimated states."""
    ne = e.size
    Phi, Pe, Ct, Pp = (np.empty((ne, ne)) for _ in range(4))
    _smoother_prior(st.A[k + 1], st.d[k + 1], post_k, st.P_prior[k + 1], e, Phi, Pe, Ct, Pp)
    C = np.linalg.lstsq(Pp, Ct, rcond=None)[0].T
    d[k] = 0.0
    d[k, e] = C @ (d[k + 1, e] + st.dx[k + 1, e])
    Ps = Pe + C @ (Ps - Pp) @ C.T
    return np.ascontiguousarray(0.5 * (Ps + Ps.T))


def rts_smooth(res: NavResult) -> SmoothResult:
    """Smooth a forward run made with ``store_for_smoother=True`` (see module docstring)."""
    st = res.store
    if st is None:
        raise ValueError("res: the forward run was made with store_for_smoother=False; nothing to smooth")
    K = st.idx.size
    n = res.layout.n
    e = np.flatnonzero(res.layout.estimated_mask).astype(np.int64)
    if not np.array_equal(e[:9], np.arange(9)):
        raise ValueError("res.layout: the smoother needs dx, dv, psi estimated and first")
    d = np.zeros((K, n))
    Pd = np.zeros((K, n))
    Pn = np.zeros((K, 9, 9))
    P_full = res.P_full if res.P_full.size else np.zeros((1, n, n))

    def post(k):
        return P_full[st.post[k]] if st.post[k] >= 0 else st.P_prior[k]

    Ps = np.ascontiguousarray(post(K - 1)[np.ix_(e, e)], dtype=float)
    Pd[-1] = np.diag(post(K - 1))
    Pn[-1] = Ps[:9, :9]
    k = K - 2
    while k >= 0:
        k = rts_kernel(st.P_prior, st.post, P_full, st.A, st.d, st.dx, e, d, Pd, Pn, Ps, k)
        if k < 0:
            break
        Ps = _lstsq_epoch(st, e, post(k), d, Ps, k)
        Pd[k] = np.diag(post(k))
        Pd[k, e] = np.diag(Ps)
        Pn[k] = Ps[:9, :9]
        k -= 1
    idx = np.asarray(st.idx)
    lay = res.layout
    x = res.x_e[idx] + d[:, lay["dx"]]
    v = res.v_e[idx] + d[:, lay["dv"]]
    q = matrix_to_quat(rotvec_to_matrix(d[:, lay["psi"]]) @ quat_to_matrix(res.q_eb[idx]))
    est = None if res.estimates is None else smoothed_estimates(lay, res.estimates, d)
    return SmoothResult(res.t_ns[idx], idx, d, Pd, x, v, q, est, Pn)


def smoothed_estimates(layout, estimates, d):
    """The forward estimates (K, n) corrected by the smoothed errors ``d`` (K, n) the way the
    forward filter feeds its corrections back (:func:`nav.filter_state.feedback_table`): camera
    misalignments compose as rotations, ``exp([d x]) exp([e x])`` (003 eq. (50)), every other
    estimated group adds; navigation and considered states stay 0."""
    out = np.array(estimates, dtype=float)
    for g in layout.groups:
        if not g.estimated or g.name in ("dx", "dv", "psi"):
            continue
        if g.name.startswith("psi_c_"):
            out[:, g.slice] = matrix_to_rotvec(rotvec_to_matrix(d[:, g.slice]) @ rotvec_to_matrix(out[:, g.slice]))
        else:
            out[:, g.slice] += d[:, g.slice]
    return out
