"""Schmidt-Kalman filter core (003 §6.1, ref. [14]): covariance propagation and the update.

Considered states (Schmidt) are never estimated: the rows of the Kalman gain that belong to them
are zero (003 §6.3, "the entries of the Kalman gain ... are set to zero"). With that suboptimal
gain the covariance must be updated in Joseph form,
``P+ = (I - K H) P (I - K H)^T + K R K^T``, which is valid for any gain and keeps P symmetric
positive (semi-)definite; it is evaluated as ``P - K H P - P H^T K^T + K S K^T`` (algebraically
identical, fewer products) and symmetrised.

The arithmetic is one numba kernel, :func:`update_kernel`, shared by :func:`schmidt_update` (one
measurement, the reference API) and :mod:`nav.navigator` (every measurement of an epoch at once:
each gated on its own with its diagonal block of S, then the accepted ones applied together). It
exploits the sparsity of H (only the columns where H is non-zero enter ``P H^T`` and ``H P H^T``;
GPS touches 9 states, a camera vector dx, psi, psi_c, dt_c and its zeta), skips the zero gain rows
of the considered states and updates P in place (no n x n temporaries).
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.special import gammaincinv

#: status / per-block codes of :func:`update_kernel`
OK, GATED, NOT_PD, NONFINITE = 0, 1, 2, 3
REASONS = {GATED: "chi-square gate", NOT_PD: "innovation covariance not positive definite",
           NONFINITE: "non-finite innovation or Jacobian"}


@dataclass
class UpdateResult:
    dx: np.ndarray        #: state correction (zero in considered rows)
    P: np.ndarray         #: updated covariance
    innovation: np.ndarray
    S: np.ndarray         #: innovation covariance, 003 eq. (49)
    nis: float            #: normalised innovation squared s^T S^-1 s
    accepted: bool
    reason: str | None


def chi2_gate(dof: int, probability: float) -> float:
    """NIS threshold: the chi-square quantile of ``probability`` with ``dof`` degrees of freedom,
    ``2 P^-1(dof/2, probability)`` with P the regularised lower incomplete gamma function (what
    ``scipy.stats.chi2.ppf`` computes, to the bit; scipy.stats is not imported for it: ~0.3 s)."""
    return float(2.0 * gammaincinv(0.5 * dof, probability))


def symmetrize(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


@nb.njit(cache=True)
def _cholesky(S, L):
    """Lower Cholesky factor of the small SPD ``S`` into ``L``; False if a pivot is not > 0
    (not positive definite, or NaN)."""
    m = S.shape[0]
    for j in range(m):
        acc = S[j, j]
        for p in range(j):
            acc -= L[j, p] * L[j, p]
        if not acc > 0.0:
            return False
        ljj = np.sqrt(acc)
        L[j, j] = ljj
        for i in range(j + 1, m):
            a = S[i, j]
            for p in range(j):
                a -= L[i, p] * L[j, p]
            L[i, j] = a / ljj
        for i in range(j):
            L[i, j] = 0.0
    return True


@nb.njit(cache=True)
def _forward(L, b, y):
    """Solve ``L y = b`` (L lower triangular)."""
    m = L.shape[0]
    for i in range(m):
        a = b[i]
        for p in range(i):
            a -= L[i, p] * y[p]
        y[i] = a / L[i, i]


@nb.njit(cache=True)
def _bad_blocks(H, R, s, offs):
    """Per block: a non-finite row of H, s or R (such blocks are rejected on their own)."""
    n = H.shape[1]
    nblk = offs.size - 1
    bad = np.zeros(nblk, np.bool_)
    for b in range(nblk):
        for r in range(offs[b], offs[b + 1]):
            if not np.isfinite(s[r]):
                bad[b] = True
            for j in range(n):
                if not np.isfinite(H[r, j]):
                    bad[b] = True
            for c in range(offs[b], offs[b + 1]):
                if not np.isfinite(R[r, c]):
                    bad[b] = True
    return bad


@nb.njit(cache=True)
def _innovation_covariance(P, H, R, S):
    """``P H^T`` (n, m), returned, and ``S = H P H^T + R`` (symmetrised) into ``S``, over the
    columns where H is non-zero (the only ones that enter either product)."""
    n = P.shape[0]
    m = H.shape[0]
    cols = np.empty(n, np.int64)
    nc = 0
    for j in range(n):
        for r in range(m):
            if H[r, j] != 0.0:
                cols[nc] = j
                nc += 1
                break
    PHt = np.zeros((n, m))
    for i in range(n):
        for r in range(m):
            a = 0.0
            for q in range(nc):
                j = cols[q]
                a += P[i, j] * H[r, j]
            PHt[i, r] = a
    for r in range(m):
        for c in range(m):
            a = R[r, c]
            for q in range(nc):
                j = cols[q]
                a += H[r, j] * PHt[j, c]
            S[r, c] = a
    for r in range(m):
        for c in range(r + 1, m):
            v = 0.5 * (S[r, c] + S[c, r])
            S[r, c] = v
            S[c, r] = v
    return PHt


@nb.njit(cache=True)
def _gate_blocks(S, s, offs, gates, bad, nis, code):
    """Each block's NIS with the prior and its code (module docstring of :func:`update_kernel`);
    returns the rows of the accepted blocks and their count."""
    nblk = offs.size - 1
    acc = np.zeros(s.size, np.int64)
    ma = 0
    for b in range(nblk):
        o0, o1 = offs[b], offs[b + 1]
        d = o1 - o0
        if bad[b]:
            code[b] = NONFINITE
            nis[b] = np.nan
            continue
        Lb = np.zeros((d, d))
        if not _cholesky(S[o0:o1, o0:o1], Lb):
            code[b] = NOT_PD
            nis[b] = np.nan
            continue
        y = np.empty(d)
        _forward(Lb, s[o0:o1], y)
        v = 0.0
        for i in range(d):
            v += y[i] * y[i]
        nis[b] = v
        if gates[b] > 0.0 and v > gates[b]:
            code[b] = GATED
            continue
        code[b] = OK
        for r in range(o0, o1):
            acc[ma] = r
            ma += 1
    return acc, ma


@nb.njit(cache=True)
def _gain(PHt, La, acc, ma, est):
    """``K^T`` (ma, n) = ``S_a^-1 (P H_a^T)^T`` via the Cholesky factor ``La`` of S_a: L Z = PHt_a^T,
    L^T K^T = Z; the considered rows of K (columns of K^T) are zero."""
    n = PHt.shape[0]
    Kt = np.zeros((ma, n))
    z = np.empty(ma)
    col = np.empty(ma)
    for i in range(n):
        if not est[i]:
            continue
        for r in range(ma):
            col[r] = PHt[i, acc[r]]
        _forward(La, col, z)
        for r in range(ma - 1, -1, -1):
            a = z[r]
            for p in range(r + 1, ma):
                a -= La[p, r] * Kt[p, i]
            Kt[r, i] = a / La[r, r]
    return Kt


@nb.njit(cache=True)
def _joseph(P, PHt, Kt, Sa, acc, est):
    """In place ``P+ = P - K H P - P H^T K^T + K S K^T`` with ``K H P = K PHt_a^T``, symmetrised;
    only the upper triangle is computed and mirrored."""
    n = P.shape[0]
    ma = Kt.shape[0]
    KSt = np.zeros((ma, n))   # (K S_a)^T, zero in considered rows of K
    for i in range(n):
        if not est[i]:
            continue
        for c in range(ma):
            a = 0.0
            for r in range(ma):
                a += Kt[r, i] * Sa[r, c]
            KSt[c, i] = a
    for i in range(n):
        ei = est[i]
        for j in range(i, n):
            if not (ei or est[j]):
                # considered x considered: the K rows are zero, the block is only symmetrised
                v = 0.5 * (P[i, j] + P[j, i])
                P[i, j] = v
                P[j, i] = v
                continue
            khp_ij = 0.0
            khp_ji = 0.0
            ksk = 0.0
            for r in range(ma):
                khp_ij += Kt[r, i] * PHt[j, acc[r]]
                khp_ji += Kt[r, j] * PHt[i, acc[r]]
                ksk += KSt[r, i] * Kt[r, j]
            # (Pn + Pn^T)/2 with Pn = P - KHP - KHP^T + KSK; KSK is symmetric in exact arithmetic
            ksk_t = 0.0
            for r in range(ma):
                ksk_t += KSt[r, j] * Kt[r, i]
            pij = P[i, j] - khp_ij - khp_ji + ksk
            pji = P[j, i] - khp_ji - khp_ij + ksk_t
            v = 0.5 * (pij + pji)
            P[i, j] = v
            P[j, i] = v


@nb.njit(cache=True)
def update_kernel(P, H, R, s, est, offs, gates, S, nis, code, dx):
    """Gate and apply the Schmidt-Kalman update of a stack of measurement blocks, in place.

    Parameters
    ----------
    P : (n, n) prior covariance, overwritten with the posterior when an update is applied.
    H : (m, n) stacked Jacobians; R : (m, m) noise (block diagonal over the blocks);
    s : (m,) stacked innovations; est : (n,) bool, False for considered states.
    offs : (nb + 1,) int64 row offsets of the blocks; gates : (nb,) NIS thresholds (<= 0: no gate).
    S : (m, m) out, ``H P H^T + R`` (symmetrised; its diagonal blocks are each block's S).
    nis : (nb,) out, each block's NIS ``s_b^T S_bb^-1 s_b`` with the prior P.
    code : (nb,) out, OK, GATED, NOT_PD (S_bb not positive definite) or NONFINITE.
    dx : (n,) out, the correction ``K s`` (zero in considered rows and when nothing is applied).

    Returns
    -------
    int
        OK if the accepted blocks were applied (P updated), NOT_PD if the batch of the accepted
        blocks could not be (P unchanged), GATED if no block was accepted.
    """
    n = P.shape[0]
    for i in range(n):
        dx[i] = 0.0
    bad = _bad_blocks(H, R, s, offs)
    PHt = _innovation_covariance(P, H, R, S)
    acc, ma = _gate_blocks(S, s, offs, gates, bad, nis, code)
    if ma == 0:
        return GATED
    # the accepted blocks together: S_a is the sub-matrix of S (R is block diagonal)
    Sa = np.empty((ma, ma))
    for r in range(ma):
        for c in range(ma):
            Sa[r, c] = S[acc[r], acc[c]]
    La = np.zeros((ma, ma))
    if not _cholesky(Sa, La):
        return NOT_PD
    Kt = _gain(PHt, La, acc, ma, est)
    for i in range(n):
        a = 0.0
        for r in range(ma):
            a += Kt[r, i] * s[acc[r]]
        dx[i] = a
    _joseph(P, PHt, Kt, Sa, acc, est)
    return OK


def schmidt_update(P: np.ndarray, H: np.ndarray, R: np.ndarray, s: np.ndarray, estimated: np.ndarray,
                   gate: float | None = None) -> UpdateResult:
    """One Schmidt-Kalman measurement update (:func:`update_kernel` with one block).

    Parameters
    ----------
    P : (n, n) prior covariance of the error state (not modified).
    H : (m, n) measurement Jacobian; R : (m, m) measurement noise; s : (m,) innovation.
    estimated : (n,) bool, False for considered states (their gain rows are zeroed).
    gate : float, optional
        Reject if the NIS exceeds it (e.g. :func:`chi2_gate`); rejected updates return P unchanged.
    """
    s = np.asarray(s, float)
    n = P.shape[0]
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(H)) and np.all(np.isfinite(R))):
        return UpdateResult(np.zeros(n), P, s, np.full((s.size, s.size), np.nan), np.nan, False,
                            "non-finite innovation or Jacobian")
    m = s.size
    Pn = np.array(P, dtype=float, order="C")
    S = np.empty((m, m))
    nis = np.empty(1)
    code = np.empty(1, np.int64)
    dx = np.empty(n)
    st = update_kernel(Pn, np.ascontiguousarray(H, dtype=float), np.ascontiguousarray(R, dtype=float),
                       np.ascontiguousarray(s), np.ascontiguousarray(estimated, dtype=np.bool_),
                       np.array([0, m], np.int64), np.array([-1.0 if gate is None else float(gate)]),
                       S, nis, code, dx)
    if st != OK:
        return UpdateResult(np.zeros(n), P, s, S, float(nis[0]), False, REASONS[int(code[0])])
    return UpdateResult(dx, Pn, s, S, float(nis[0]), True, None)
