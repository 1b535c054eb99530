"""A wrong Earth edge detected from the frame itself: two arcs of one edge that give two nadirs.

Why
---
The Earth's threshold edge is the boundary of the pixels brighter than the threshold. Near the
terminator the ground close to the horizon is dimly lit, and the boundary can leave the limb and
follow the place where the ground's own brightness falls through the threshold, below the true
horizon, while another part of the same boundary still runs along the limb. Each part is a
smooth arc that a cone fits to a pixel or two, with a nadir tilted by degrees from the other's;
the covariance of the arc the fit keeps (003 eq. (33), the edge height's prior) knows nothing of
that. A wrong height tilts the nadir by tenths of a degree (`vision.edge_height`); a wrong edge
moves it by degrees.

Test
----
After the winner's refit (inliers within ``ransac.threshold_px`` of the cone fitted with its edge
height), the rays left out are, when they are a sizeable part of the edge
(``EdgeHeightOptions.arc_min_fraction``), fitted by themselves with the winner's cone angle
(`vision.nadir.nadir_from_horizon`, inliers re-selected among those rays). When that second arc is
a horizon by the front end's own acceptance (at least ``arc_min_fraction`` of the edge as inliers,
residual below ``max_residual``), the hypothesis "both arcs are the same horizon" is tested: the
two nadirs at one common edge height differ by pixel noise (003 eqs. (33)-(36), each arc's
``P_k``), by the common height's error, which tilts each arc towards its own middle
(``g_k = d e_k / d h``, `vision.fitting.alpha_sensitivity`), and by the height's variation along
the limb between the arcs (``EdgeHeightOptions.along_sigma_m``, independent per arc)::

    d = e_1 - e_2,   S = P_1 + P_2 + sigma_h^2 (g_1 - g_2)(g_1 - g_2)^T + sigma_a^2 (g_1 g_1^T + g_2 g_2^T)
    m^2 = d^T S^+ d

with ``sigma_h`` the threshold edge's prior sigma (``atmosphere_sigma_m``). ``m >
EdgeHeightOptions.arc_gate`` says that the two arcs are not one horizon. Which one is the wrong
edge follows from the illumination: a brightness edge on the ground is where the ground's light
fades, under a low or set Sun, while the limb above it is still lit. So the winner is rejected
(the frame has no Earth vector, with a reason; the filter is better without it than with a vector
degrees off under a tenth-of-a-degree covariance) when, in addition, the Sun is below the local
horizon at its arc's tangent points (median elevation below ``EdgeHeightOptions.arc_shadow_el_deg``,
from the prior's position, attitude and Sun direction, `sun_elevation_deg`); a disagreeing arc in
the shadow while the winner is sunlit is the wrong one, and the winner stands. Without a Sun prior
there is no rejection. Measured on the rendered ATEK coast (`scenarios.study.edge_mismatch`, 48
frames x 10 renderings, and the vision bench's clean and disturbed frames): every disagreeing pair
whose winner was the wrong edge had its winner at a Sun elevation of -5.3 to -2.2 deg, every one
whose winner was the horizon at +4 to +22 deg. An edge whose left-out rays are scattered (glints,
the payload mask's boundary, a few noisy pixels) has no second arc and is not tested.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vision.covariance import direction_covariance
from vision.fitting import alpha_sensitivity, median
from vision.limb import tangent_height_sun
from vision.nadir import angle_residual, nadir_from_horizon, within_cone
from vision.oblate import LimbModel

__all__ = ["SecondArc", "arc_rays_needed", "second_arc", "sun_elevation_deg"]


@dataclass(frozen=True)
class SecondArc:
    """Two arcs of one edge compared (`second_arc`): the angle between their nadirs [rad], the
    Mahalanobis distance of their difference (``m`` above) and the second arc's ray count."""

    angle: float
    sigmas: float
    rays: int


def _arc_terms(model: LimbModel, rays_c, J, H, e_fit, alpha: float, R_px2: float, L_eff: float):
    """(e_c, pixel-noise P_c, g = d e_c / d h) of the fixed-height cone fit ``e_fit`` of one arc."""
    e_c = model.to_camera(e_fit)
    P = direction_covariance(rays_c, J, e_c, R_px2, L_eff, method="constrained").P_c
    g_fit = alpha_sensitivity(H, e_fit, alpha) * model.alpha_rate
    g = (model.to_camera(e_fit + 1e-3 * g_fit) - e_c) / 1e-3
    return e_c, P, g


def _select(H2: np.ndarray, alpha: float, thr: np.ndarray, n_iter: int = 5):
    """Fixed-alpha cone fit of the rays ``H2`` with its inliers re-selected until they repeat."""
    fit = nadir_from_horizon(H2, alpha)
    sel = within_cone(H2, fit.e_c, alpha, thr)
    for _ in range(n_iter):
        if sel.sum() < 3:
            break
        fit = nadir_from_horizon(H2[sel], alpha)
        new = within_cone(H2, fit.e_c, alpha, thr)
        if (new == sel).all():
            break
        sel = new
    return fit, sel


def arc_rays_needed(n_rays: int, min_fraction: float) -> int:
    """Fewest rays of an edge of ``n_rays`` that make a second arc: ``min_fraction`` of them, at
    least 20."""
    return max(20, int(math.ceil(min_fraction * n_rays)))


def second_arc(model: LimbModel, rays_c: np.ndarray, J: np.ndarray, H: np.ndarray, inliers: np.ndarray,
               e_fit: np.ndarray, alpha: float, sigma_h_m: float, along_sigma_m: float, R_px2: float, L_eff: float,
               threshold, min_fraction: float, max_residual: float) -> SecondArc | None:
    """The arc of the rays left out of the winner's fit, compared with the winner's (module docstring).

    Parameters
    ----------
    model : the limb model (`vision.oblate`) of the fit.
    rays_c, J, H : (m, 3) camera-frame unit rays of the whole edge in edge order, (m, 3, 2) their
        Jacobians [1/px], (m, 3) the same rays in the model's fit frame.
    inliers : (m,) bool, the winner's inliers; e_fit, alpha : its fit-frame direction and cone
        half-angle [rad] (the second arc is fitted with the same angle: one edge height).
    sigma_h_m, along_sigma_m : the common edge height's sigma and its variation along the limb [m].
    R_px2, L_eff : pixel-noise variance [px^2] and correlation length [steps of the edge] (003
        eqs. (34)-(36)).
    threshold : inlier distance from the cone [rad], scalar or per ray.
    min_fraction : a second arc needs at least this fraction of the edge's rays as its inliers.
    max_residual : its mean squared angular residual must be below this [rad^2].

    Returns
    -------
    `SecondArc`, or None when the left-out rays hold no second horizon arc.
    """
    inl = np.asarray(inliers, dtype=bool)
    out = ~inl
    n_min = arc_rays_needed(inl.size, min_fraction)
    if out.sum() < n_min or inl.sum() < n_min:
        return None
    thr = np.broadcast_to(np.asarray(threshold, dtype=float), (inl.size,))
    H2 = np.ascontiguousarray(H[out])
    fit2, sel = _select(H2, alpha, thr[out])
    if sel.sum() < n_min or not angle_residual(H2[sel], fit2.e_c, alpha) <= max_residual:
        return None
    e1, P1, g1 = _arc_terms(model, rays_c[inl], J[inl], H[inl], np.asarray(e_fit, dtype=float), alpha, R_px2, L_eff)
    e2, P2, g2 = _arc_terms(model, rays_c[out][sel], J[out][sel], H2[sel], fit2.e_c, alpha, R_px2, L_eff)
    dg = g1 - g2
    S = P1 + P2 + sigma_h_m**2 * np.outer(dg, dg) + along_sigma_m**2 * (np.outer(g1, g1) + np.outer(g2, g2))
    d = e1 - e2
    m2 = float(d @ np.linalg.pinv(S, rcond=1e-10, hermitian=True) @ d)
    ang = math.acos(max(-1.0, min(1.0, float(e1 @ e2))))
    return SecondArc(ang, math.sqrt(max(m2, 0.0)), int(sel.sum()))


def sun_elevation_deg(rays_c: np.ndarray, R_ec: np.ndarray, x_e: np.ndarray, sun_e: np.ndarray) -> float:
    """Median elevation [deg] of the Sun above the local horizon at the tangent points of the
    camera-frame rays ``rays_c`` (attitude ``R_ec``, position ``x_e``, Sun direction ``sun_e`` in e;
    `vision.limb.tangent_height_sun`)."""
    rays_e = np.asarray(rays_c, dtype=float) @ np.asarray(R_ec, dtype=float).T
    _, mu = tangent_height_sun(rays_e, x_e, sun_e)
    return math.degrees(math.asin(max(-1.0, min(1.0, median(mu)))))
