"""Schmidt-Kalman filter core (003 §6.1, ref. [14]): covariance propagation and the update.

Considered states (Schmidt) are never estimated: the rows of the Kalman gain that belong to them
are zero (003 §6.3, "the entries of the Kalman gain ... are set to zero"). With that suboptimal
gain the covariance must be updated in Joseph form,
``P+ = (I - K H) P (I - K H)^T + K R K^T``, which is valid for any gain and keeps P symmetric
positive (semi-)definite; it is evaluated as ``P - K H P - P H^T K^T + K S K^T`` (algebraically
identical, fewer products) and symmetrised.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2


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
    """NIS threshold: the chi-square quantile of ``probability`` with ``dof`` degrees of freedom."""
    return float(chi2.ppf(probability, dof))


def symmetrize(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


def propagate(P: np.ndarray, Phi: np.ndarray, Qd: np.ndarray) -> np.ndarray:
    """``Phi P Phi^T + Qd``, symmetrised."""
    return symmetrize(Phi @ P @ Phi.T + Qd)


def schmidt_update(P: np.ndarray, H: np.ndarray, R: np.ndarray, s: np.ndarray, estimated: np.ndarray,
                   gate: float | None = None) -> UpdateResult:
    """One Schmidt-Kalman measurement update.

    Parameters
    ----------
    P : (n, n) prior covariance of the error state.
    H : (m, n) measurement Jacobian; R : (m, m) measurement noise; s : (m,) innovation.
    estimated : (n,) bool, False for considered states (their gain rows are zeroed).
    gate : float, optional
        Reject if the NIS exceeds it (e.g. :func:`chi2_gate`); rejected updates return P unchanged.
    """
    s = np.asarray(s, float)
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(H)) and np.all(np.isfinite(R))):
        return UpdateResult(np.zeros(P.shape[0]), P, s, np.full((s.size, s.size), np.nan), np.nan, False,
                            "non-finite innovation or Jacobian")
    PHt = P @ H.T
    S = symmetrize(H @ PHt + R)
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return UpdateResult(np.zeros(P.shape[0]), P, s, S, np.nan, False, "innovation covariance not positive definite")
    y = np.linalg.solve(L, s)
    nis = float(y @ y)
    if gate is not None and nis > gate:
        return UpdateResult(np.zeros(P.shape[0]), P, s, S, nis, False, "chi-square gate")
    # K = P H^T S^-1 via the Cholesky factor
    K = np.linalg.solve(L.T, np.linalg.solve(L, PHt.T)).T
    K[~estimated, :] = 0.0
    KHP = K @ PHt.T
    Pn = P - KHP - KHP.T + K @ S @ K.T
    return UpdateResult(K @ s, symmetrize(Pn), s, S, nis, True, None)
