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
smoother either: their components of ``d_k`` are held at zero (so they do not feed back into the
estimated states through the next step's recursion). The covariance recursion is the standard one
applied to the full state; with Schmidt gains it is an approximation (the Schmidt covariance is
not the optimal one RTS assumes), documented here and checked in tests/test_smoother.py by the
smoothed errors' consistency on a simulated coast.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav import ins
from nav.navigator import NavResult


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


def rts_smooth(res: NavResult, *, keep_full: bool = False) -> SmoothResult:
    """Smooth a forward run made with ``store_for_smoother=True`` (see module docstring)."""
    st = res.store
    if st is None:
        raise ValueError("res: the forward run was made with store_for_smoother=False; nothing to smooth")
    K = len(st.idx)
    n = res.layout.n
    est = res.layout.estimated_mask
    d = np.zeros((K, n))
    Pd = np.zeros((K, n))
    Ps_next = st.P_post[-1] if st.P_post[-1] is not None else st.P_prior[-1]
    Pd[-1] = np.diag(Ps_next)
    for k in range(K - 2, -1, -1):
        P_post = st.P_post[k] if st.P_post[k] is not None else st.P_prior[k]
        trans = st.Phi[k + 1]
        Pp = st.P_prior[k + 1]
        # C = P_post Phi^T Pp^-1  (Pp symmetric): solve Pp C^T = Phi P_post
        PhiP = trans.A @ P_post  # rows 0..8 of Phi P_post
        full = (P_post * trans.d[:, None])
        full[:9] = PhiP
        try:
            L = np.linalg.cholesky(Pp)
            Ct = np.linalg.solve(L.T, np.linalg.solve(L, full))
        except np.linalg.LinAlgError:
            Ct = np.linalg.lstsq(Pp, full, rcond=None)[0]
        C = Ct.T
        delta = st.dx[k + 1] if st.dx[k + 1] is not None else 0.0
        dk = C @ (d[k + 1] + delta)
        dk[~est] = 0.0
        d[k] = dk
        Ps = P_post + C @ (Ps_next - Pp) @ C.T
        Ps = 0.5 * (Ps + Ps.T)
        Pd[k] = np.diag(Ps)
        Ps_next = Ps
    idx = np.asarray(st.idx)
    lay = res.layout
    x = res.x_e[idx] + d[:, lay["dx"]]
    v = res.v_e[idx] + d[:, lay["dv"]]
    q = np.array([ins.R_to_quat(ins.rotvec_to_R(np.ascontiguousarray(d[i, lay["psi"]])) @ ins.quat_to_R(res.q_eb[j]))
                  for i, j in enumerate(idx)])
    return SmoothResult(res.t_ns[idx], idx, d, Pd, x, v, q)
