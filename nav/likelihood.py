"""The likelihood of a filter run's innovations and its information matrix (pure computation).

For a linear Gaussian state-space model the innovations ``nu_k`` of a Kalman filter are
independent with covariance ``S_k``, so the log-likelihood of the measurements is the
prediction-error decomposition (Schweppe 1965; Harvey, *Forecasting, structural time series
models and the Kalman filter*, §3.4)::

    -log L(theta) = sum_k 0.5 (d_k log(2 pi) + log det S_k + nu_k^T S_k^-1 nu_k)

over the measurement blocks k the filter applied (003 eq. (49)'s innovation and its covariance,
:class:`nav.updates.Innovation`). Its expected Hessian, the Fisher information, needs only the
first derivatives of ``nu_k`` and ``S_k`` (Harvey eq. (3.4.69))::

    I_ij = sum_k 0.5 tr(S^-1 dS/dtheta_i S^-1 dS/dtheta_j) + dnu/dtheta_i^T S^-1 dnu/dtheta_j

which :func:`fisher_information` evaluates from derivatives the caller obtains (e.g. by finite
differences of filter runs). The same derivatives give the gradient, the score (Harvey eq. (3.4.66))::

    d(-log L)/dtheta_i = sum_k 0.5 tr(S^-1 dS_i) - 0.5 nu^T S^-1 dS_i S^-1 nu + nu^T S^-1 dnu_i

which :func:`score` evaluates. Where S is a sum of terms each scaled by one parameter (a noise
variance), a forward difference in log-parameters scales every ``dS_i`` by the same
``(e^h - 1) / h``, so the score's zero, the estimate, does not move with the step ``h``; the
forward difference of -log L itself is off by ``h/2`` times its curvature, many standard errors
for a well-identified parameter.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["InnovationSet", "innovation_set", "negative_log_likelihood", "fisher_information", "score"]

LOG_2PI = math.log(2.0 * math.pi)


class InnovationSet:
    """The applied innovations of a run grouped by block dimension: ``keys`` (t_ns, kind, camera)
    per block, and per dimension d the stacked ``nu`` (m, d) and ``S`` (m, d, d) with the index
    of each block in ``keys``."""

    def __init__(self, keys: list, by_dim: dict):
        self.keys = keys
        self.by_dim = by_dim   #: d -> (indices (m,), nu (m, d), S (m, d, d))

    def __len__(self) -> int:
        return len(self.keys)

    def kinds(self) -> set:
        return {k[1] for k in self.keys}


def innovation_set(innovations, *, kinds=None) -> InnovationSet:
    """The accepted innovations (:class:`nav.updates.Innovation` list of a
    :class:`nav.navigator.NavResult`) of ``kinds`` (default all), grouped by dimension."""
    keys, groups = [], {}
    for inn in innovations:
        if not inn.accepted or (kinds is not None and inn.kind not in kinds):
            continue
        d = int(np.size(inn.s))
        g = groups.setdefault(d, ([], [], []))
        g[0].append(len(keys))
        g[1].append(np.asarray(inn.s, float).reshape(d))
        g[2].append(np.asarray(inn.S, float).reshape(d, d))
        keys.append((int(inn.t_ns), inn.kind, int(inn.camera)))
    by_dim = {d: (np.array(g[0], np.int64), np.array(g[1]), np.array(g[2])) for d, g in groups.items()}
    return InnovationSet(keys, by_dim)


def negative_log_likelihood(iset: InnovationSet) -> tuple[float, np.ndarray]:
    """``(-log L, per-block terms (len(iset),))`` of the prediction-error decomposition (module
    docstring). A block whose S is not positive definite makes the total ``inf``."""
    terms = np.zeros(len(iset))
    for d, (idx, nu, S) in iset.by_dim.items():
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            terms[idx] = np.inf
            continue
        z = np.linalg.solve(L, nu[..., None])[..., 0]
        logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), axis=1)
        terms[idx] = 0.5 * (d * LOG_2PI + logdet + np.sum(z * z, axis=1))
    return float(terms.sum()), terms


def fisher_information(S: np.ndarray, dS: np.ndarray, dnu: np.ndarray) -> np.ndarray:
    """Fisher information (p, p) of the parameters from blocks of one dimension d (module
    docstring): ``S`` (m, d, d) at the estimate, ``dS`` (p, m, d, d) and ``dnu`` (p, m, d) the
    derivatives of S and of the innovations with respect to each parameter. Sum the results of
    the dimensions present."""
    Si = np.linalg.inv(S)
    A = np.einsum("mab,pmbc->pmac", Si, dS)             # S^-1 dS_i
    tr = 0.5 * np.einsum("imab,jmba->ij", A, A)         # 0.5 tr(S^-1 dS_i S^-1 dS_j)
    W = np.einsum("mab,pmb->pma", Si, dnu)
    return tr + np.einsum("ima,jma->ij", dnu, W)


def score(nu: np.ndarray, S: np.ndarray, dS: np.ndarray, dnu: np.ndarray) -> np.ndarray:
    """Gradient (p,) of -log L with respect to the parameters from blocks of one dimension d
    (module docstring): ``nu`` (m, d) and ``S`` (m, d, d) at the point, ``dS`` (p, m, d, d) and
    ``dnu`` (p, m, d) their derivatives. Sum the results of the dimensions present.

    Examples
    --------
    One scalar block nu = 1, S = 2 with dS = 1 and dnu = 0: 0.5 (1/2) - 0.5 (1/2)(1)(1/2) = 0.125.

    >>> float(score(np.ones((1, 1)), np.full((1, 1, 1), 2.0), np.ones((1, 1, 1, 1)), np.zeros((1, 1, 1)))[0])
    0.125
    """
    Si = np.linalg.inv(S)
    w = np.einsum("mab,mb->ma", Si, nu)                   # S^-1 nu
    A = np.einsum("mab,pmbc->pmac", Si, dS)               # S^-1 dS_i
    return (0.5 * np.einsum("pmaa->p", A) - 0.5 * np.einsum("ma,pmab,mb->p", w, dS, w)
            + np.einsum("ma,pma->p", w, dnu))
