"""The Earth's edge height estimated with the nadir: the cone half-angle of 003 eq. (5) as a free
parameter of the fit, combined with a prior where the visible arc does not constrain it.

Why
---
The apparent horizon is where the limb's brightness crosses the detector's edge criterion, at an
effective tangent height ``h_e`` (``d`` of 003 eq. (5)) that depends on the camera, its exposure
and the atmosphere (003 §4, 004 §3.4.3): near 45 km for a threshold on our renderer's limb, near
0-10 km on real orbital photographs where the Earth's disc is far brighter than the thin limb.
With the unit-norm cone fit a wrong ``h_e`` is a wrong alpha, and on a partial arc a wrong alpha
tilts the nadir towards the arc (about 0.02 deg per km from 500 km with a 25 deg camera). So
``h_e`` is fitted with the direction, as 003 §5 fits the Sun's angular radius, and its
uncertainty is marginalised into the direction covariance.

Estimator
---------
In the fit frame of the limb model (`vision.oblate`) the residual of ray ``h_j`` is
``r_j = h_j^T e - cos(alpha(d))``, ``sin alpha(d) = sin alpha_0 + (d - d_0) rate cos alpha_0``
(`LimbModel.cone_angle_change`). Linearised at ``(e_k, d_k)`` with ``e = e_k + T x`` (T the
tangent basis at e_k) and ``u = (d - d_k) / sigma_p``::

    F z = -r,   F_j = [h_j^T T, s sigma_p],   s = d cos(alpha)/d d = sin(alpha) dalpha/dd

The data-only estimate is the least-squares ``z_f = (F^T F)^-1 F^T (-r)`` (the same unweighted fit
the direction has with a known alpha), and its covariance under the correlated pixel noise of 003
eqs. (34)-(36) is the sandwich ``C_f = R (F^T F)^-1 F^T Sigma F (F^T F)^-1`` with
``Sigma = D_u T D_u + D_v T D_v``, ``D = diag(e^T J_j)`` and ``T_jk = rho^|j-k|``, computed in
O(m) with the AR(1) recursions of `vision.covariance`. The prior ``d ~ N(d_p, sigma_p^2)`` is a
pseudo-measurement of ``u``; the estimate is the Gaussian conditioning of ``(z_f, C_f)`` on it
(the maximum a posteriori estimate of the linear model)::

    k = C_f[:, 2] / (C_f[2, 2] + 1),   z = z_f + k ((d_p - d_k)/sigma_p - z_f[2]),
    C = C_f - k C_f[2, :]

iterated (Gauss-Newton, the prior held fixed) until the step is below 1e-9 rad and 1e-6 sigma_p
(3-4 iterations from a start 35 km off). ``C`` is the joint
covariance of (direction, height): its direction block is the marginal direction covariance
(it contains the height's uncertainty), its last row the correlation of the two. A long arc
constrains ``d`` (``C[2, 2]`` well below 1: the prior has little weight); a short arc leaves
``C[2, 2] ~ 1`` and the prior's sigma goes into the direction covariance through the tilt, as the
fixed-height fit's ``sigma_d^2 g g^T`` term does (`vision.fitting.alpha_sensitivity`).

The prior is not a measurement: its mean is the height the edge detector's model assumes
(``TargetConfig.atmosphere_m`` for the threshold edge, ``LimbOptions.height_m`` for the limb
edge), its sigma (``EdgeHeightOptions.prior_sigma_m``) is wide enough to hold the edges of
cameras the defaults were not tuned on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from nav._kernels import tangent_basis as nb_tangent_basis
from vision.nadir import _mean_sq_residual
from vision.oblate import LimbModel

__all__ = ["EdgeHeightFit", "fit_edge_height", "conditional_on_height"]


@dataclass(frozen=True)
class EdgeHeightFit:
    """Direction and edge height fitted together (module docstring).

    Attributes
    ----------
    e_fit : (3,) unit direction in the fit frame of the limb model.
    alpha : cone half-angle at the estimated height, fit frame [rad].
    height_m : estimated edge height [m]; sigma_m : its posterior 1-sigma [m].
    data_height_m, data_sigma_m : the arc's own (prior-free) estimate of the height [m] and its
        1-sigma [m]; sigma inf when the arc alone cannot separate the height from the tilt.
    P_c : (3, 3) marginal covariance of the camera-frame direction [rad^2].
    cov_c : (3,) covariance of the camera-frame direction with the height [rad m].
    from_arc : the arc constrains the height: posterior variance below ``constrained_ratio`` of
        the prior's.
    residual : mean squared angular residual of the rays from the fitted cone [rad^2].
    """

    e_fit: np.ndarray
    alpha: float
    height_m: float
    sigma_m: float
    data_height_m: float
    data_sigma_m: float
    P_c: np.ndarray
    cov_c: np.ndarray
    from_arc: bool
    residual: float


@numba.njit(cache=True)
def _normal_3(H, J, e_fit, e_c, c, s, rho, rho_v):  # pragma: no cover - numba
    """F^T F, F^T (-r), F^T Sigma_0 F (unit pixel variance) and F^T T_v F (the along-edge
    height variation's correlation, rho_v) for F_j = [h_j^T T, s], r_j = h_j^T e - c, T the
    tangent basis at e_fit; the pixel-noise weights g_j = e_c^T J_j (camera frame: the limb
    model's map differs from a rotation by the flattening only).

    Both correlated forms in one pass without storing the rows: with the AR(1) correlation
    T_jk = rho^|j-k| = (L + L^T - I)_jk, L_jk = rho^(j-k) for k <= j, X^T T X = W + W^T - X^T X
    where W = sum_j x_j f_j^T and f_j = x_j + rho f_(j-1) (the forward recursion of
    `vision.covariance._ar1_apply_2d`; its backward one gives W^T)."""
    m = H.shape[0]
    T = nb_tangent_basis(e_fit)
    M = np.zeros((3, 3))
    b = np.zeros(3)
    S = np.zeros((3, 3))
    V = np.zeros((3, 3))
    P = np.zeros((3, 3))   # sum (gu^2 + gv^2) F_j F_j^T
    Fj = np.empty(3)
    fu = np.zeros(3)       # forward recursions of gu F_j, gv F_j (rho) and F_j (rho_v)
    fv = np.zeros(3)
    ff = np.zeros(3)
    for j in range(m):
        Fj[0] = H[j, 0] * T[0, 0] + H[j, 1] * T[1, 0] + H[j, 2] * T[2, 0]
        Fj[1] = H[j, 0] * T[0, 1] + H[j, 1] * T[1, 1] + H[j, 2] * T[2, 1]
        Fj[2] = s
        r = H[j, 0] * e_fit[0] + H[j, 1] * e_fit[1] + H[j, 2] * e_fit[2] - c
        gu = e_c[0] * J[j, 0, 0] + e_c[1] * J[j, 1, 0] + e_c[2] * J[j, 2, 0]
        gv = e_c[0] * J[j, 0, 1] + e_c[1] * J[j, 1, 1] + e_c[2] * J[j, 2, 1]
        g2 = gu * gu + gv * gv
        for a in range(3):
            b[a] -= Fj[a] * r
            fu[a] = rho * fu[a] + gu * Fj[a]
            fv[a] = rho * fv[a] + gv * Fj[a]
            ff[a] = rho_v * ff[a] + Fj[a]
        for a in range(3):
            for q in range(3):
                M[a, q] += Fj[a] * Fj[q]
                P[a, q] += g2 * Fj[a] * Fj[q]
                S[a, q] += gu * Fj[a] * fu[q] + gv * Fj[a] * fv[q]
                V[a, q] += Fj[a] * ff[q]
    return M, b, S + S.T - P, V + V.T - M, T


@numba.njit(cache=True)
def _inv3(A):  # pragma: no cover - numba
    """Inverse of a 3x3 matrix by cofactors; (inverse, ok) with ok False when singular."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    out = np.empty((3, 3))
    scale = max(abs(A[0, 0]), abs(A[1, 1]), abs(A[2, 2]), 1e-300)
    if not (math.isfinite(det) and abs(det) > 1e-14 * scale**3):
        return out, False
    out[0, 0], out[1, 0], out[2, 0] = c00 / det, c01 / det, c02 / det
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) / det
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) / det
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) / det
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) / det
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) / det
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) / det
    return out, True


@numba.njit(cache=True)
def _gauss_newton(H, J, e0, M_inv, geo, prior, R, rho, rho_v, var_v, iters):  # pragma: no cover - numba
    """The iterations of `fit_edge_height` in one call (module docstring). ``geo`` = (sin alpha_0,
    cos alpha_0, dalpha/dd at d_0, d_0), ``prior`` = (mean, sigma). Returns (e, d, C, var_data,
    h_data, ok): the direction (fit frame), the height, the joint covariance of (tilt, height /
    sigma), the arc's own variance of height / sigma and its own height estimate."""
    sa0, ca0, rate0, d0 = geo[0], geo[1], geo[2], geo[3]
    pm, ps = prior[0], prior[1]
    e = e0 / math.sqrt(e0[0] ** 2 + e0[1] ** 2 + e0[2] ** 2)
    d = d0
    C = np.zeros((3, 3))
    var_data, h_data = 0.0, d0
    for _ in range(iters):
        sa = sa0 + (d - d0) * rate0 * ca0      # sin alpha(d), 003 eq. (5) linear in d
        if not 0.0 < sa < 1.0:
            return e, d, C, var_data, h_data, False
        ca = math.sqrt(1.0 - sa * sa)
        s = sa * rate0 * ca0 / ca              # d(-cos alpha)/dd: the residual's height column
        v = M_inv @ e
        e_c = v / math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
        M, b, S, V, T = _normal_3(H, J, e, e_c, ca, s * ps, rho, rho_v)
        Mi, ok = _inv3(M)
        if not ok:
            return e, d, C, var_data, h_data, False
        z_f = Mi @ b
        C_f = Mi @ (R * S + (s * s * var_v) * V) @ Mi
        C_f = 0.5 * (C_f + C_f.T)
        if not (np.all(np.isfinite(C_f)) and C_f[2, 2] >= 0.0):
            return e, d, C, var_data, h_data, False
        var_data, h_data = C_f[2, 2], d + ps * z_f[2]
        k = C_f[:, 2] / (C_f[2, 2] + 1.0)
        z = z_f + k * ((pm - d) / ps - z_f[2])
        C = C_f - np.outer(k, C_f[2, :])
        C = 0.5 * (C + C.T)
        e = e + T[:, 0] * z[0] + T[:, 1] * z[1]
        e = e / math.sqrt(e[0] ** 2 + e[1] ** 2 + e[2] ** 2)
        d = d + ps * z[2]
        if math.sqrt(z[0] ** 2 + z[1] ** 2) < 1e-9 and abs(z[2]) < 1e-6:   # 0.2 mdeg, 2 cm per 20 km
            break
    return e, d, C, var_data, h_data, True


def _camera_jacobian(model: LimbModel, e_fit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e_c, d e_c / d e_fit) of `LimbModel.to_camera` (3x3, for tangent-plane perturbations)."""
    if model.kind == "sphere":
        return e_fit, np.eye(3) - np.outer(e_fit, e_fit)
    v = model.M_inv @ e_fit
    nv = float(np.linalg.norm(v))
    e_c = v / nv
    return e_c, (np.eye(3) - np.outer(e_c, e_c)) @ model.M_inv / nv


def fit_edge_height(model: LimbModel, d0: float, H: np.ndarray, J: np.ndarray, e_fit: np.ndarray,
                    prior_m: float, prior_sigma_m: float, R_px2: float, L_eff: float,
                    constrained_ratio: float = 0.5, iters: int = 6, along_sigma_m: float = 0.0,
                    along_L: float = 1.0) -> EdgeHeightFit | None:
    """Direction and edge height of a limb arc, the height's prior as a pseudo-measurement.

    Parameters
    ----------
    model : the limb model (`vision.oblate`) built at edge height ``d0`` [m]; ``H`` its fit-frame
        unit rays (m, 3) of the inliers, ordered along the edge.
    J : (m, 3, 2) d ray / d(u, v) of the rays in the camera frame [1/px].
    e_fit : start direction in the fit frame (the fit at ``d0``).
    prior_m, prior_sigma_m : the prior N(prior_m, prior_sigma_m^2) of the height [m]; sigma > 0.
    R_px2, L_eff : pixel-noise variance [px^2] and correlation length in steps of the subsampled
        edge (003 eqs. (34)-(36)).
    constrained_ratio : ``from_arc`` when the posterior variance is below this fraction of the prior's.
    along_sigma_m, along_L : the edge's height variation along the limb [m] (illumination,
        exposure) as a Gauss-Markov sequence of this sigma and correlation length [steps of the
        edge]: a residual ``s dh_j`` per ray whose correlated part mimics a change of curvature,
        so it limits what the arc can say about the height (0: none).

    Returns
    -------
    `EdgeHeightFit`, or None when the linearised problem is singular or the height leaves the
    range where the cone exists (the caller keeps the fixed-height fit).
    """
    if not (prior_sigma_m > 0.0 and math.isfinite(prior_sigma_m)):
        raise ValueError(f"prior_sigma_m = {prior_sigma_m}; expected a finite sigma > 0 [m]")
    geo = np.array([math.sin(model.alpha), math.cos(model.alpha), model.alpha_rate, float(d0)])
    Hc = np.ascontiguousarray(H, dtype=float)
    e, d, C, var_data, h_data, ok = _gauss_newton(
        Hc, np.ascontiguousarray(J, dtype=float), np.asarray(e_fit, dtype=float),
        np.ascontiguousarray(model.M_inv, dtype=float), geo, np.array([float(prior_m), float(prior_sigma_m)]),
        float(R_px2), 1.0 - 1.0 / max(L_eff, 1.0), 1.0 - 1.0 / max(along_L, 1.0), float(along_sigma_m) ** 2, iters)
    sa = geo[0] + (d - d0) * geo[2] * geo[1]
    if not (ok and 0.0 < sa < 1.0):
        return None
    alpha = math.asin(sa)
    _, Jm = _camera_jacobian(model, e)
    A = Jm @ nb_tangent_basis(e)
    P_c = A @ C[:2, :2] @ A.T
    var_h = float(C[2, 2]) * prior_sigma_m**2
    return EdgeHeightFit(e_fit=e, alpha=alpha, height_m=float(d), sigma_m=math.sqrt(max(var_h, 0.0)),
                         data_height_m=float(h_data),
                         data_sigma_m=math.sqrt(var_data) * prior_sigma_m if var_data < 1e12 else math.inf,
                         P_c=0.5 * (P_c + P_c.T), cov_c=A @ C[:2, 2] * prior_sigma_m,
                         from_arc=var_h < constrained_ratio * prior_sigma_m**2,
                         residual=float(_mean_sq_residual(Hc, e, alpha)))


def conditional_on_height(P_c: np.ndarray, cov_c: np.ndarray, sigma_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The direction given the edge height, from the joint (direction, height) fit: the regression
    of ``e_c`` on ``h``, ``e_c(h) = e_c + b (h - h_fit)`` with ``b = cov(e_c, h) / sigma_h^2``
    [rad/m] (the fitted direction's move when the fit assumes a height ``h``), and its covariance
    ``P_c - cov cov^T / sigma_h^2`` [rad^2].

    The prior on the height enters the posterior through ``h`` alone, so this conditional is the
    arc's own (prior-free) one. A true edge at ``h`` puts the true direction at ``e_c + b (h -
    h_fit)``, so the fitted ``e_c`` measures ``e_true - b (h - h_fit)``: the sensitivity ``d e_c /
    d h_e`` a filter that estimates the height uses is ``g = -b``, with this covariance (the
    height's uncertainty not counted again), and the arc's own height
    (``EdgeHeightFit.data_height_m``, independent of this conditional) measures the height.
    Returns ``(P, g)``."""
    cov = np.asarray(cov_c, dtype=float)
    if not (math.isfinite(sigma_m) and sigma_m > 0.0):
        raise ValueError(f"sigma_m = {sigma_m}; expected the height's finite 1-sigma > 0 [m]")
    b = cov / sigma_m**2
    P = np.asarray(P_c, dtype=float) - np.outer(cov, b)
    return 0.5 * (P + P.T), -b


def fit_edge_reselect(model: LimbModel, d0: float, H: np.ndarray, J: np.ndarray, inliers: np.ndarray,
                      e_fit: np.ndarray, prior_m: float, prior_sigma_m: float, R_px2: float, L_eff: float,
                      threshold, min_inliers: int, constrained_ratio: float = 0.5,
                      n_iter: int = 4, along_sigma_m: float = 0.0,
                      along_L: float = 1.0) -> tuple[EdgeHeightFit | None, np.ndarray]:
    """`fit_edge_height` with the inliers re-selected on its cone: the rays of ``H`` (all of the
    edge, fit frame) within ``threshold`` [rad, scalar or per ray] of the fitted cone, refitted,
    until the selection repeats or ``n_iter`` times. A fit with a fixed, wrong height keeps only
    the part of a long arc where its tilted cone crosses the true one; the joint fit's cone
    takes the whole arc back. Returns (fit, inliers); (None, inliers) when the first fit fails;
    a selection of fewer than ``min_inliers`` rays ends the loop with the last good fit."""
    from vision.nadir import within_cone

    inl = np.asarray(inliers, dtype=bool)
    kw = dict(along_sigma_m=along_sigma_m, along_L=along_L)
    ef = fit_edge_height(model, d0, H[inl], J[inl], e_fit, prior_m, prior_sigma_m, R_px2, L_eff, constrained_ratio, **kw)
    for _ in range(n_iter):
        if ef is None:
            break
        new = within_cone(H, ef.e_fit, ef.alpha, threshold)
        if new.sum() < min_inliers or (new == inl).all():
            break
        nf = fit_edge_height(model, d0, H[new], J[new], ef.e_fit, prior_m, prior_sigma_m, R_px2, L_eff,
                             constrained_ratio, **kw)
        if nf is None:
            break
        ef, inl = nf, new
    return ef, inl
