"""The vision front end, assembled: from a raw, distorted camera frame to Earth-nadir, Sun and Moon
direction vectors with covariances (003 §3, §5; 000 §2.3-2.4; 002 §3; 004 §2.2).

Pipeline per target (`process_frame`; options: `vision.config`)
---------------------------------------------------------------
1. Detection (`vision.candidates.detect`): brightness gate, threshold, border-following edge
   search (one brightness histogram per frame, shared by the targets). Earth: image border and
   payload-mask boundary only (003 §3.1); Sun/Moon: plus search lines ``2 f tan(alpha_min)``
   apart (003 §5).
2. Candidate scoring, cheap (`vision.scoring`): each candidate (longest first, at most
   ``scoring.max_candidates``; after one is accepted, only those at least
   ``scoring.compete_fraction`` as long) is subsampled to at most ``scoring.score_rays`` pixels
   spread along it, only those pixels are unprojected (`vision.camera.unproject`), and fitted
   directly; when more than ``scoring.direct_outlier_fraction`` of them miss the cone by
   ``ransac.threshold_px`` (converted per ray to an angle, `vision.ransac.pixel_angle`), the
   pre-verified RANSAC cone fit (`vision.ransac.ransac_cone`, 000 §2.3) runs instead. Earth:
   known alpha from the height (prior) and the effective atmosphere thickness d (003 eq. (5);
   ``edge.start_m`` when the edge height is estimated, `model_height_m`), in the fit frame of
   the limb model (`vision.oblate`). Sun/Moon: alpha estimated (003 §5).
3. Acceptance per candidate, each failure giving a reason: enough pixels and inliers, residual
   (mean squared angular distance of the inliers from the cone, `vision.nadir.angle_residual`)
   below ``max_residual`` (003 §7.3, re-derived in `vision.config`), Sun/Moon apparent radius
   inside ``[alpha_min_deg, alpha_max_deg]``, within ``gate_deg`` of a predicted direction when
   the prior gives one (Sun/Moon: ephemeris + attitude; Earth: the geocentric nadir from x_e and
   R_ec), a disc that is bright inside and dark around (`vision.probes.disc_check`), the implied
   conic passes through the image (003 §3.3 sanity check), and the mirrored-nadir test (002 §3):
   pixels a few pixels on the body side of the edge must be bright and those on the space side
   dark (`vision.probes.side_score`); a fit that fails it is retried from its mirror image
   (`vision.nadir.mirrored_direction`, refined locally).
4. The accepted candidate with the smallest residual wins (003 §3.4); for the Earth, when the
   winner's limb profiles are the ground's, an accepted candidate beyond its edge is processed
   instead (`_outer_candidate`: the air lies above the ground). Only the winner is
   processed fully: at most ``fit.rays`` of its pixels are unprojected with the Jacobian
   (`vision.camera.unproject_jacobian`), inliers re-selected, refitted, and the O(m) covariance of
   003 eq. (33) with the correlated pixel noise (R, L) of eqs. (34)-(36), (38) is computed
   (`vision.covariance.direction_covariance`), plus, for the Earth, the term of the uncertain
   effective atmosphere thickness (sigma_d, below), and the spherical overbound of eq. (37).
   Earth with a prior giving x_e, R_ec and the Sun direction: before the covariance the winner's
   inlier pixels are moved to the fraction-of-peak crossing of the limb profile
   (`vision.limb.limb_edge_points`, exposure-invariant) and refitted with d = ``limb.height_m``
   (sigma ``limb.height_sigma_m``) when enough profiles are usable (`vision.limb_refit`).

Covariance terms
----------------
- Pixel noise, 003 eqs. (33)-(36) (Earth R = 1 px^2, L = 300 px) and (38) (Sun R = 9 px^2).
- Effective atmosphere thickness (Earth): the apparent horizon is where the limb's brightness
  crosses the threshold, at a tangent height d that varies with exposure and illumination
  (003 §4, 004 §3.4.3). With the *constrained* unit-norm fit a wrong d is a wrong alpha, and on
  a partial arc a wrong alpha tilts e towards the arc (nearly 1:1 for a short arc), so
  ``P_c += sigma_d^2 g g^T`` with ``g = de/dd`` (`vision.fitting.alpha_sensitivity` times
  dalpha/dd, mapped into the camera frame). 003 §4 found the
  estimate insensitive to d because its linear fit (eq. (24)) does not use alpha at all (the
  direction of lstsq(H, cos(alpha) 1) is independent of alpha; see `vision.nadir`); that
  estimator is ill-conditioned on partial arcs, which is why the constrained fit is used.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from nav.ephemeris import AU, SUN_RADIUS
from vision.binarize import as_frame, brightness_histogram
from vision.camera import Camera, check_camera, unproject, unproject_jacobian
from vision.candidates import detect
from vision.config import (TARGETS, FramePrior, TargetConfig, VisionConfig, default_config,
                           resolve_search_lines)
from vision.covariance import direction_covariance, largest_eigenvalue
from vision.edge_check import arc_rays_needed, second_arc, sun_elevation_deg
from vision.edge_height import conditional_on_height, fit_edge_reselect
from vision.fitting import alpha_sensitivity, fit_cone, median, reselect_inliers, subsample
from vision.image_geometry import conic_polyline, fast_pixel_angle, gate_search_rows
from vision.limb_refit import limb_refit, tilt_corrected_attitude
from vision.mask import PayloadMask
from vision.nadir import angle_residuals, conic_type, direction_and_radius, within_cone
from vision.oblate import ellipsoid_model, is_above, sphere_model
from vision.occultation import REFRACTION_CEILING_M, EarthEdge, occultation_reason, refraction_covariance, tangent_height
from vision.results import CandidateResult, FrameResult, TargetResult, VectorRecord
from vision.scoring import gate_reason, score_candidate

__all__ = ["TargetConfig", "VisionConfig", "FramePrior", "VectorRecord", "CandidateResult",
           "TargetResult", "FrameResult", "process_frame", "conic_polyline", "default_config",
           "tilt_corrected_attitude", "TARGETS"]


def _detect(name, image, camera, mask, tc: TargetConfig, predicted, hists: dict):
    """Detection of one target (`vision.candidates.detect`) with the frame's brightness histogram
    (one per sample step, shared by the targets) and, for the Sun/Moon with a predicted
    direction, only the search rows its gate can reach (`gate_search_rows`)."""
    step = tc.detection.binarize.sample_step
    hist = hists.get(step)
    if hist is None:
        hist = hists[step] = brightness_histogram(as_frame(image, (camera.height, camera.width)), step)
    rows = None
    if name != "earth" and predicted is not None:
        rows = gate_search_rows(camera, predicted, math.radians(tc.gate_deg + tc.alpha_max_deg), tc.detection.search)
    return detect(image, tc.detection, mask, expected_shape=(camera.height, camera.width), hist=hist, rows=rows)


def _score_candidates(det, image, camera, mask, tc: TargetConfig, model, frame_seed: int, predicted):
    """`score_candidate` on the candidates, longest first (at most ``scoring.max_candidates``);
    once one is accepted, candidates shorter than ``scoring.compete_fraction`` of it are not
    scored (not the same body's limb)."""
    order = sorted(range(len(det.candidates)), key=lambda i: -det.candidates[i].n_pixels)
    results = []
    accepted_len = 0
    for i in order[:tc.scoring.max_candidates]:
        n_i = det.candidates[i].n_pixels
        if accepted_len and n_i < tc.scoring.compete_fraction * accepted_len:
            break
        r_i = score_candidate(i, det.candidates[i], image, camera, mask, det, tc, model, frame_seed, predicted)
        results.append(r_i)
        if not r_i.reason:
            accepted_len = max(accepted_len, n_i)
    return results


def _refit_winner(out: TargetResult, win, cand, camera, tc: TargetConfig, model):
    """Full processing of the winner: at most ``fit.rays`` pixels spread along the whole edge,
    unprojected with the Jacobian, inliers re-selected and refitted (Earth: the constrained fit,
    from the mirrored direction when the scoring took it; Sun/Moon: iterated to a stable inlier
    set, so that the result depends less on the RANSAC's draw than one re-selection would).
    Returns (uv, rays_c, J, pa, H, fit, inliers, step), or None with ``out.reason`` set."""
    step = max(1.0, cand.n_pixels / tc.fit.rays)
    uv = cand.points[subsample(cand.n_pixels, tc.fit.rays)]
    rays_c, J = unproject_jacobian(camera, uv)
    ok = np.isfinite(rays_c[:, 2])     # all three NaN beyond the lens's range
    if not ok.all():
        uv, rays_c, J = uv[ok], rays_c[ok], J[ok]
    pa = fast_pixel_angle(camera, uv)
    H = model.to_fit(rays_c) if model is not None else rays_c
    fit = win.fit
    thr = tc.ransac.threshold_px * pa
    inl = within_cone(H, fit.e_c, fit.alpha, thr)
    min_used = min(tc.min_pixels, int(math.ceil(tc.min_pixels / step)))
    if inl.sum() < max(min_used, 3):
        out.reason = f"candidate {win.index}: {int(inl.sum())} inliers on the full edge (min_pixels {tc.min_pixels})"
        return None
    if model is not None:
        fit = fit_cone(H[inl], fit.alpha, fit.e_c if win.mirrored else None)
        if tc.edge.estimate and tc.atmosphere_sigma_m > 0:
            fit, inl = _edge_inliers(model, fit, H, J, inl, tc, step, thr, max(min_used, 20))
    else:
        fit, inl, _ = reselect_inliers(H, direction_and_radius(H[inl]), inl, thr,
                                       lambda Hi, f: direction_and_radius(Hi), 10, max(min_used, 3))
    if fit.residual > tc.max_residual:
        out.reason = (f"candidate {win.index}: residual {fit.residual:.3g} rad^2 on the full edge > "
                      f"max_residual {tc.max_residual:.3g}")
        return None
    return uv, rays_c, J, pa, H, fit, inl, step


def _edge_inliers(model, fit, H, J, inl, tc: TargetConfig, step: float, thr, min_inliers: int):
    """The threshold edge's inliers re-selected on the cone of the joint direction and edge-height
    fit (`vision.edge_height.fit_edge_reselect`) with the prior centred on the height the
    candidates were scored at (`model_height_m`, sigma ``atmosphere_sigma_m``): the fixed-height
    cone keeps only part of a long arc when the edge sits elsewhere. This selection feeds the limb
    edge (`limb_refit`), whose height has its own prior; the threshold edge's final fit
    (`_earth_covariance`) takes the prior N(atmosphere_m, atmosphere_sigma_m^2). (fit, inliers);
    the fit's direction and alpha those of the joint fit."""
    d0 = model_height_m(tc)
    ef, inl2 = fit_edge_reselect(model, d0, H, J, inl, fit.e_c, d0,
                                 tc.atmosphere_sigma_m, tc.fit.R_px2, max(1.0, tc.fit.L_px / step), thr,
                                 min_inliers, tc.edge.constrained_ratio, along_sigma_m=tc.edge.along_sigma_m,
                                 along_L=max(1.0, tc.edge.along_L_px / step))
    if ef is None:
        return fit, inl
    return dataclasses.replace(fit, e_c=ef.e_fit, n=ef.e_fit, alpha=ef.alpha, rhs=math.cos(ef.alpha),
                               residual=ef.residual), inl2


def _earth_covariance(model, fit, H, rays_c, J, inl, tc: TargetConfig, L_eff: float, sig_p: float, d0: float,
                      thr: float, along_m: float, prior_m: float, state: bool = False):
    """Earth: (e_c, P_c, cone alpha, fit alpha, edge, inliers) of the final fit at edge height
    ``d0`` [m] (the height ``model`` is built at). With ``edge.estimate`` the height is fitted
    with the direction, the prior N(d0, sig_p^2) as a pseudo-measurement, the inliers re-selected
    on the fitted cone (``thr`` [rad]; `vision.edge_height.fit_edge_reselect`), and P_c is its
    marginal direction covariance; else (or when that fit is singular) 003 eq. (33) with the
    pixel noise plus ``sig_p^2 g g^T``, ``g = de/dd`` = de/dalpha * dalpha/dd
    (`alpha_sensitivity`, `LimbModel.alpha_rate`) mapped into the camera. ``edge`` = (height
    [m], sigma [m], (3,) covariance with e_c [rad m], from the arc, the arc's own height [m] and its
    sigma [m], and with ``state`` (the filter estimates this edge's height) the pair (``d e_c /
    d h_e``, covariance of e_c given the height) (`vision.edge_height.conditional_on_height`; the
    fixed-height fit: (-g, the pixel-noise covariance)), else None); ``along_m``: the edge's height variation along the limb
    [m]; ``prior_m``: the prior's mean [m] (``d0`` when the height is not estimated). The cone
    alpha is the median angle of the inlier rays about e_c (the visible horizon's cone, for its
    conic type)."""
    if tc.edge.estimate and sig_p > 0:
        ef, inl2 = fit_edge_reselect(model, d0, H, J, inl, fit.e_c, prior_m, sig_p, tc.fit.R_px2, L_eff, thr,
                                     max(20, int(inl.sum()) // 2), tc.edge.constrained_ratio,
                                     along_sigma_m=along_m, along_L=L_eff * tc.edge.along_L_px / tc.fit.L_px)
        if ef is not None:
            e_c = model.to_camera(ef.e_fit)
            given_h = conditional_on_height(ef.P_c, ef.cov_c, ef.sigma_m)[::-1] if state else None
            edge = (ef.height_m, ef.sigma_m, ef.cov_c, ef.from_arc, ef.data_height_m, ef.data_sigma_m, given_h)
            return e_c, ef.P_c, median(angle_residuals(rays_c[inl2], e_c, 0.0)), ef.alpha, edge, inl2
    e_c = model.to_camera(fit.e_c)
    P_px = direction_covariance(rays_c[inl], J[inl], e_c, tc.fit.R_px2, L_eff, method="constrained").P_c
    g = np.zeros(3)
    if sig_p > 0 or state:
        g_fit = alpha_sensitivity(H[inl], fit.e_c, fit.alpha) * model.alpha_rate
        g = model.to_camera(fit.e_c + 1e-3 * g_fit) - e_c
        g /= 1e-3
    edge = (d0, sig_p, sig_p**2 * g, False, math.nan, math.inf, (-g, P_px) if state else None)
    return e_c, P_px + sig_p**2 * np.outer(g, g), median(angle_residuals(rays_c[inl], e_c, 0.0)), fit.alpha, edge, inl


def _limb_consistent(ef, sigma_l: float, tc: TargetConfig) -> bool:
    """The limb edge's arc agrees with the limb model's height (``edge.limb_gate``, `vision.config`):
    its own height estimate within limb_gate combined sigmas of ``limb.height_m``, or the arc
    too short to tell."""
    h, s = ef[4], ef[5]
    if tc.edge.limb_gate <= 0 or not (math.isfinite(h) and math.isfinite(s)):
        return True
    return abs(h - tc.limb.height_m) <= tc.edge.limb_gate * math.hypot(s, sigma_l)


def _earth_final(out: TargetResult, image, camera, tc: TargetConfig, model, limb, w, L_eff: float, timings):
    """Earth after the refit ``w`` (`_refit_winner`): the limb edge (`limb_refit`) when the prior
    allows it and its arc agrees with the limb model (`_limb_consistent`), else the threshold
    edge (the threshold edge alone where the filter's state describes it, `_threshold_state`);
    each with its edge height fitted and the covariance (`_earth_covariance`). Returns
    (e_c, P_c, alpha, (height, sigma), uv, inliers, fit) and fills ``out``'s limb and edge fields."""
    uv, rays_c, J, pa, H, fit, inl, step = w
    t0 = time.perf_counter()
    pa_med = median(pa)
    if limb is not None and tc.limb.fraction > 0:
        info: dict = {}
        lr = limb_refit(image, camera, tc, limb, uv[inl], rays_c[inl], pa[inl], model.to_camera(fit.e_c), J[inl],
                        info=info)
        timings["earth.limb"] = time.perf_counter() - t0
        out.limb_width_ratio = info.get("width_ratio", math.nan)
        if lr is not None and not _threshold_state(tc):
            model_l, fit_l, uv_l, rays_l, J_l, inl_l, sigma_l = lr[:7]
            res = _earth_covariance(model_l, fit_l, model_l.to_fit(rays_l), rays_l, J_l, inl_l, tc, L_eff,
                                    max(sigma_l, tc.edge.limb_prior_sigma_m), tc.limb.height_m,
                                    tc.limb.refit_threshold_px * pa_med, tc.edge.along_sigma_m, tc.limb.height_m,
                                    tc.edge.filter_state and lr[9] in ("limb", "flank"))
            res_t = None
            if _limb_consistent(res[4], sigma_l, tc) and _limb_checked(res[4], max(sigma_l, tc.edge.limb_prior_sigma_m), tc):
                res_t = _threshold_covariance(model, fit, w, tc, L_eff, pa_med)
            if _limb_consistent(res[4], sigma_l, tc) and _edges_agree(res, res_t, tc):
                out.limb_used, out.limb_shift_m, out.limb_path, out.limb_d_m = lr[7:]
                out.limb_edge = True
                out.limb_prior_m, out.limb_prior_sigma_m = tc.limb.height_m, max(sigma_l, tc.edge.limb_prior_sigma_m)
                out.limb_sigma_m = sigma_l
                return _earth_out(out, res, uv_l, fit_l)
            out.limb_rejected_m = float(res[4][4])
            if res_t is not None:
                return _earth_out(out, res_t, uv, fit)
    return _earth_out(out, _threshold_covariance(model, fit, w, tc, L_eff, pa_med), uv, fit)


def _threshold_covariance(model, fit, w, tc: TargetConfig, L_eff: float, pa_med: float):
    """`_earth_covariance` of the threshold edge (the refit ``w``), prior N(atmosphere_m, atmosphere_sigma_m^2)."""
    _, rays_c, J, _, H, _, inl, _ = w
    return _earth_covariance(model, fit, H, rays_c, J, inl, tc, L_eff, tc.atmosphere_sigma_m, model_height_m(tc),
                             tc.ransac.threshold_px * pa_med, tc.edge.along_sigma_m, tc.atmosphere_m,
                             tc.edge.filter_state and (_threshold_state(tc) or not tc.limb.fraction > 0))


def _threshold_state(tc: TargetConfig) -> bool:
    """The filter's edge-height state describes the threshold edge on every frame
    (``edge.state_edge`` "threshold" with ``edge.filter_state``): the limb edge is not used for
    the vector (its profiles still judge whether the winner's edge is a limb, `_outer_candidate`)."""
    return tc.edge.filter_state and tc.edge.state_edge == "threshold"


def _limb_checked(ef, sigma_p: float, tc: TargetConfig) -> bool:
    """The arc cannot check the limb model's height (`_limb_consistent` is inconclusive): its own
    height sigma exceeds ``edge.cross_check_ratio`` times the limb prior's ``sigma_p`` [m] (a
    narrow field of view), so the limb edge is checked against the threshold edge instead
    (`_edges_agree`). An arc that was not fitted for its height (``edge.estimate`` false: sigma
    inf) is not checked."""
    s = ef[5]
    return tc.edge.limb_gate > 0 and tc.edge.cross_check_ratio > 0 and tc.edge.cross_check_ratio * sigma_p < s < math.inf


def _edges_agree(res_l, res_t, tc: TargetConfig) -> bool:
    """The limb edge's nadir and the threshold edge's (``res_*`` from `_earth_covariance`; None:
    not compared) within ``edge.limb_gate`` sigmas of their difference, covariance the sum of
    theirs (independent height priors: the limb model's and the threshold edge's). The limb edge's
    per-pixel heights (flank, calibration) come from a limb profile model that an unseen
    atmosphere or camera may not follow; where the arc cannot check them, the threshold edge can."""
    if res_t is None:
        return True
    d = res_l[0] - res_t[0]
    m2 = float(d @ np.linalg.pinv(res_l[1] + res_t[1], rcond=1e-10, hermitian=True) @ d)
    return m2 <= tc.edge.limb_gate**2


def _earth_out(out: TargetResult, res, uv, fit):
    """`_earth_final`'s return value from `_earth_covariance`'s ``res``; fills ``out``."""
    e_c, P, out.cone_alpha, alpha, ef, inl = res
    out.edge_cov_c, out.edge_from_arc = ef[2], ef[3]
    if ef[6] is not None:    # the filter estimates the height: the direction given it
        out.edge_dedge_c, P = ef[6]
    out.edge_data_m, out.edge_data_sigma_m = float(ef[4]), float(ef[5])
    return e_c, P, alpha, ef[:2], uv, inl, fit


def _wrong_edge(out: TargetResult, index: int, w, tc: TargetConfig, model, L_eff: float, limb) -> bool:
    """The wrong-edge test (`vision.edge_check`) on the refit ``w``: True, with ``out.reason``
    set, when the rays the fit leaves out form a second horizon arc whose nadir disagrees with the
    fit's by more than ``edge.arc_gate`` sigmas (one common edge height of sigma
    ``atmosphere_sigma_m``) and the fit's own arc lies where the Sun is below
    ``edge.arc_shadow_el_deg`` (``limb`` = (limb model, R_ec, x_e, Sun direction in e) of
    `_limb_prior`; None: no rejection). The Sun's elevation is checked first: on a sunlit arc the
    second arc is not looked for (``out.second_arc`` stays None)."""
    if not (tc.edge.arc_gate > 0 and tc.atmosphere_sigma_m > 0 and limb is not None):
        return False
    _, rays_c, J, pa, H, fit, inl, _ = w
    if int(inl.size - inl.sum()) < arc_rays_needed(inl.size, tc.edge.arc_min_fraction):
        return False
    el = sun_elevation_deg(rays_c[inl], limb[1], limb[2], limb[3])
    if el >= tc.edge.arc_shadow_el_deg:     # a sunlit arc stands whatever a second arc says
        return False
    arc = second_arc(model, rays_c, J, H, inl, fit.e_c, fit.alpha, tc.atmosphere_sigma_m, tc.edge.along_sigma_m,
                     tc.fit.R_px2, L_eff, tc.ransac.threshold_px * pa, tc.edge.arc_min_fraction, tc.max_residual)
    out.second_arc = arc
    if arc is None or arc.sigmas <= tc.edge.arc_gate:
        return False
    out.reason = (f"candidate {index}: two arcs of the edge give nadirs {math.degrees(arc.angle):.2f} deg apart "
                  f"({arc.sigmas:.1f} sigma > edge.arc_gate {tc.edge.arc_gate:g}) and the fitted one lies where the "
                  f"Sun is {el:.1f} deg high (< edge.arc_shadow_el_deg {tc.edge.arc_shadow_el_deg:g}): a brightness "
                  f"edge on the dim ground, not the horizon")
    return True


def _baseline_fit(out: TargetResult, camera, cand, timings, name):
    """The general conic fit (`vision.conic.conic_nadir_fit`) on all pixels of the winner."""
    from vision.conic import conic_nadir_fit
    tb = time.perf_counter()
    try:
        allr = unproject(camera, cand.points)
        allr = allr[np.all(np.isfinite(allr), axis=1)]
        e_b, _ = conic_nadir_fit(allr)
        out.baseline_e_c = e_b
    except (ValueError, np.linalg.LinAlgError) as exc:
        out.baseline_reason = str(exc)
    timings[f"{name}.baseline_conic_fit"] = time.perf_counter() - tb


def _process_target(name, image, camera, mask, tc: TargetConfig, model, frame_seed: int, timings,
                    baseline: bool, predicted: np.ndarray | None, limb, hists: dict, ids,
                    earth: _EarthBeside | None = None) -> TargetResult:
    """Steps 1-4 of the module docstring for one target (``model``: the Earth's limb model, None
    for the Sun/Moon); ``ids`` = (t_ns, camera_id) of the record; ``earth``: the frame's Earth
    for the Sun, whose accepted candidates must be clear of it before the winner is chosen (a
    glint on the sea does not hide the Sun elsewhere in the frame)."""
    t0 = time.perf_counter()
    det = _detect(name, image, camera, mask, tc, predicted, hists)
    t1 = time.perf_counter()
    timings[f"{name}.detect"] = t1 - t0
    out = TargetResult(name, det)
    if not det.candidates:
        out.reason = f"no candidate: {det.reason}"
        return out
    out.candidates = results = _score_candidates(det, image, camera, mask, tc, model, frame_seed, predicted)
    t2 = time.perf_counter()
    timings[f"{name}.score"] = t2 - t1
    good = [r for r in results if not r.reason]
    if earth is not None:
        for r in good:
            r.reason = _sun_reason(earth, r.fit.e_c, tc)
        good = [r for r in good if not r.reason]
    if not good:
        best = min(results, key=lambda r: r.residual)
        out.reason = (f"no accepted candidate among {len(det.candidates)} "
                      f"(best: candidate {best.index}, {best.reason})")
        return out
    win = min(good, key=lambda r: r.residual)
    res = _winner_record(out, win, image, camera, tc, model, limb, timings, baseline, ids, t2)
    alt = _outer_candidate(res, good, win, camera, tc) if model is not None and res.record is not None else None
    if alt is not None:
        out2 = TargetResult(name, det, candidates=results, inner_candidate=win.index,
                            inner_width_ratio=res.limb_width_ratio)
        res2 = _winner_record(out2, alt, image, camera, tc, model, limb, timings, baseline, ids, t2)
        if res2.record is not None:
            return res2
    return res


def _winner_record(out: TargetResult, win, image, camera, tc: TargetConfig, model, limb, timings, baseline: bool,
                   ids, t2: float) -> TargetResult:
    """Step 4 of the module docstring on the accepted candidate ``win`` of ``out.detection``: the
    refit, the wrong-edge test (Earth), the final fit and covariance, the record; ``out`` with the
    record or with its reason."""
    name = out.target
    cand = out.detection.candidates[win.index]
    out.winner = win.index
    w = _refit_winner(out, win, cand, camera, tc, model)
    if w is None:
        return out
    uv, rays_c, J, pa, H, fit, inl, step = w
    L_eff = max(1.0, tc.fit.L_px / step)   # correlation length in steps of the subsampled edge
    if model is not None and _wrong_edge(out, win.index, w, tc, model, L_eff, limb):
        return out
    t3 = time.perf_counter()
    timings[f"{name}.refit"] = t3 - t2
    alpha = float(fit.alpha)
    edge = (math.nan, math.nan)
    if model is not None:
        e_c, P, alpha, edge, uv, inl, fit = _earth_final(out, image, camera, tc, model, limb, w, L_eff, timings)
        out.reason = _moved_reason(e_c, model.to_camera(win.fit.e_c), tc)
        if out.reason:
            return out
        conic = conic_type(e_c, out.cone_alpha)[1]
        t3 += timings.get("earth.limb", 0.0)
    else:
        e_c, conic = fit.e_c, fit.conic
        P = direction_covariance(rays_c[inl], J[inl], fit.n, tc.fit.R_px2, L_eff, method="linear").P_c
    P = 0.5 * (P + P.T)
    lam = float(largest_eigenvalue(P))
    timings[f"{name}.covariance"] = time.perf_counter() - t3
    n_inl = int(round(int(inl.sum()) * cand.n_pixels / max(uv.shape[0], 1)))
    out.points = uv
    out.inlier_mask = inl
    out.record = VectorRecord(int(ids[0]), int(ids[1]), name, e_c, P, lam * np.eye(3), float(fit.residual),
                              int(cand.n_pixels), min(n_inl, cand.n_pixels), conic, alpha,
                              model.kind if model is not None else "", float(edge[0]), float(edge[1]),
                              out.edge_dedge_c if model is not None else None,
                              *_edge_data(out, model, tc))
    if baseline:
        _baseline_fit(out, camera, cand, timings, name)
    return out


def _moved_reason(e_c, e_scored, tc: TargetConfig) -> str:
    """"" when the final Earth direction ``e_c`` (edge height fitted, limb edge) lies within
    ``gate_deg`` of the direction ``e_scored`` whose side and gate the scoring checked, else the
    reason. On a short arc the cone that curves the other way fits nearly as well (the mirrored
    nadir, ~2 alpha away: 162 deg at 76 km); the refits start from the scored cone but their
    edge height is free, and one that lands on the mirror has passed no side test."""
    gate = gate_reason(e_c, e_scored, tc.gate_deg, "the scored cone")
    return f"the edge-height fit moved the nadir {gate} (a mirrored cone on a short arc?)" if gate else ""


def _outer_candidate(res: TargetResult, good: list, win, camera, tc: TargetConfig):
    """The accepted Earth candidate that lies beyond the winner's edge, or None.

    Looked for only when the winner's limb profiles are not a limb's (median flank width above
    ``limb.edge_width_max``, `vision.limb_refit`): the brightness inside its edge is the ground's.
    The air lies above the ground, so the Earth's edge is the outermost of its edges about one
    nadir. With the Sun below the horizon at the tangent points the Earth's shadow darkens the
    lower atmosphere, and a sunlit limb above it is a bright arc of its own, separated from the
    ground by a dark band: two accepted candidates, and the ground's may fit its cone a little
    better. The candidate returned is the best-fitting (smallest residual) of those whose pixels
    (a subsample of `_OUTER_RAYS`) lie on average more than ``ransac.threshold_px`` beyond the
    winner's cone (``res.cone_alpha`` about its vector)."""
    r_w = tc.limb.edge_width_max
    if not (r_w > 0 and res.limb_width_ratio > r_w) or len(good) < 2:
        return None
    e_c = res.record.e_c
    best = None
    for r in good:
        if r.index == win.index or (best is not None and r.residual >= best.residual):
            continue
        pts = res.detection.candidates[r.index].points
        pts = pts[subsample(pts.shape[0], _OUTER_RAYS)]
        rays = unproject(camera, pts)
        ok = np.isfinite(rays[:, 2])
        if ok.sum() < 3:
            continue
        beyond = median(angle_residuals(rays[ok], e_c, 0.0)) - res.cone_alpha
        if beyond > tc.ransac.threshold_px * median(fast_pixel_angle(camera, pts[ok])):
            best = r
    return best


#: pixels of a candidate whose angle from the winner's vector `_outer_candidate` measures
_OUTER_RAYS = 64


def _edge_data(out: TargetResult, model, tc: TargetConfig) -> tuple:
    """(edge_data_m, edge_data_sigma_m) of the record: the arc's own edge height and its sigma
    where the filter estimates the height (``dedge_c`` set), else NaN; (NaN, inf) where the state
    describes the threshold edge (`_threshold_state`): there the arc's own height is no
    measurement of it. Its error is the bend of the edge's height variation along the limb
    (the Sun's elevation and the scattering angle change along it), which a camera that keeps
    its arc in one place sees alike in every frame: a common error that independent per-frame
    measurements would add up (docs/vision.md)."""
    if model is None or out.edge_dedge_c is None:
        return math.nan, math.nan
    if _threshold_state(tc):
        return math.nan, math.inf
    return float(out.edge_data_m), float(out.edge_data_sigma_m)


def model_height_m(tc: TargetConfig) -> float:
    """Edge height [m] the Earth's limb model is built at: the candidates are scored with its
    cone and the joint fit of the height starts there (``edge.start_m`` when the height is
    estimated and set, else ``atmosphere_m``, the prior's mean, which a fixed height is)."""
    if tc.edge.estimate and tc.atmosphere_sigma_m > 0 and not math.isnan(tc.edge.start_m):
        return tc.edge.start_m
    return tc.atmosphere_m


def _earth_model(config: VisionConfig, prior: FramePrior | None, height_m: float | None):
    """The Earth's limb model (`vision.oblate`, d = `model_height_m`): the ellipsoid with a
    prior giving x_e and R_ec, else the sphere at ``height_m`` of radius ``sphere_radius_m``,
    the Gaussian radius at ``prior.lat``, or ``nav.earth.R_MEAN`` (003 §2.8). Returns
    (config, model, reason): for a camera not above d (a balloon, a rocket's ascent) with the
    height estimated, the model and config's ``edge.start_m`` at the first of ``atmosphere_m``
    (the prior's mean) and 0 m below it; with no such height, model None and the reason."""
    tc = config.earth
    d = model_height_m(tc)
    ellipsoid = prior is not None and prior.x_e is not None and prior.R_ec is not None
    if not ellipsoid:
        if height_m is None:
            raise ValueError("height_m: required for the Earth (003 eq. (5)) without a position prior")
        if not (math.isfinite(height_m) and height_m > 0):
            raise ValueError(f"height_m = {height_m}; expected a finite height above the ellipsoid [m]")
    above = (lambda h: is_above(prior.x_e, h)) if ellipsoid else (lambda h: height_m > h)
    if not above(d):
        lower = [h for h in (tc.atmosphere_m, 0.0) if h < d and above(h)]
        if not (tc.edge.estimate and tc.atmosphere_sigma_m > 0 and lower):
            return config, None, (f"the camera is not above the Earth's edge height {d / 1e3:.0f} km that its "
                                  f"cone is built at (003 eq. (5)): no Earth cone")
        d = lower[0]
        config = dataclasses.replace(config, earth=dataclasses.replace(
            tc, edge=dataclasses.replace(tc.edge, start_m=d)))
    if ellipsoid:
        return config, ellipsoid_model(prior.x_e, prior.R_ec, d), ""
    if config.sphere_radius_m is not None:
        r = config.sphere_radius_m
    elif prior is not None and prior.lat is not None:
        from vision.oblate import gaussian_radius
        r = gaussian_radius(prior.lat)
    else:
        from nav.earth import R_MEAN as r
    return config, sphere_model(height_m, r, d), ""


def _limb_prior(config: VisionConfig, prior: FramePrior | None, image):
    """(limb model at d = ``limb.height_m``, R_ec, x_e, Sun direction in e) for `limb_refit`, or
    None when the limb edge is off or the prior lacks x_e, R_ec or sun_c, or the frame is grey."""
    if not (config.earth.enabled and config.earth.limb.fraction > 0 and prior is not None and prior.x_e is not None
            and prior.R_ec is not None and prior.sun_c is not None and image.ndim == 3
            and is_above(prior.x_e, config.earth.limb.height_m)):
        return None
    R_ec = np.asarray(prior.R_ec, dtype=float)
    return (ellipsoid_model(prior.x_e, R_ec, config.earth.limb.height_m), R_ec,
            np.asarray(prior.x_e, dtype=float), R_ec @ np.asarray(prior.sun_c, dtype=float))


#: the Sun's mean apparent radius [rad]
SUN_ALPHA = math.asin(SUN_RADIUS / AU)


#: most edge rays `vision.occultation` takes of the Earth (spread along it; the edge angle is a
#: median over the 16 nearest the body's azimuth)
EDGE_RAYS = 512


def _inlier_rays(tr: TargetResult, camera: Camera, most: int | None = None) -> np.ndarray:
    """Unit camera rays (n, 3) of a target's final inlier pixels (at most ``most``, spread
    along the edge)."""
    uv = np.asarray(tr.points, dtype=float)[np.asarray(tr.inlier_mask, dtype=bool)]
    if most is not None:
        uv = uv[subsample(uv.shape[0], most)]
    rays = unproject(camera, uv)
    return rays[np.isfinite(rays).all(axis=1)]


class _EarthBeside:
    """The frame's Earth for the Sun's checks against it (`vision.occultation`): the edge's rays
    are unprojected (`EarthEdge`) only for a disc that comes near the edge (`far`)."""

    def __init__(self, tr: TargetResult, camera: Camera, prior: FramePrior | None, height_m, model):
        self.tr, self.camera = tr, camera
        if prior is not None and prior.x_e is not None:
            self.r = float(np.linalg.norm(prior.x_e))
        else:
            self.r = model.radius + float(height_m)
        self._edge = None

    def far(self, b_c: np.ndarray, alpha_b: float) -> bool:
        """Whether the disc of centre ``b_c`` and radius ``alpha_b`` [rad] stands so far above the
        edge that it cannot touch it and no air bends its light: its lowest point more than a
        degree beyond the Earth's cone (`TargetResult.cone_alpha`) and at a tangent height above
        `REFRACTION_CEILING_M` even over an edge at the ground."""
        a = self.tr.cone_alpha
        theta = float(np.arccos(np.clip(np.asarray(b_c) @ self.tr.record.e_c, -1.0, 1.0))) - alpha_b
        return (math.isfinite(a) and theta > a + math.radians(1.0)
                and tangent_height(self.r, 0.0, theta, a) > REFRACTION_CEILING_M)

    @property
    def edge(self) -> EarthEdge:
        if self._edge is None:
            rec = self.tr.record
            self._edge = EarthEdge(rec.e_c, _inlier_rays(self.tr, self.camera, EDGE_RAYS), rec.edge_height_m,
                                   rec.edge_height_sigma_m, self.r)
        return self._edge


def _earth_beside(tr: TargetResult, camera: Camera, prior: FramePrior | None, height_m, model) -> _EarthBeside | None:
    """The Earth's result ``tr`` for `vision.occultation`, or None without an Earth vector."""
    if tr.record is None or tr.points is None or not np.any(tr.inlier_mask):
        return None
    return _EarthBeside(tr, camera, prior, height_m, model)


def _sun_reason(earth: _EarthBeside, b_c: np.ndarray, tc: TargetConfig) -> str:
    """`vision.occultation.occultation_reason` of a Sun disc at ``b_c`` ("" when far above)."""
    if earth.far(b_c, SUN_ALPHA):
        return ""
    return occultation_reason(earth.edge, b_c, SUN_ALPHA, math.radians(tc.occultation.min_clearance_deg), "Sun")


def _sun_beside_earth(tr: TargetResult, camera: Camera, tc: TargetConfig, earth: _EarthBeside) -> None:
    """The Sun's record against the frame's Earth (`vision.occultation`): dropped with the reason
    when its disc is not clear of the Earth's edge, else its covariance with the refraction
    term (none far above the edge, where it is below 0.0003 deg). The Sun's own radius is the
    ephemeris's mean (the fitted one includes the bloom)."""
    rec = tr.record
    why = _sun_reason(earth, rec.e_c, tc)
    if why:
        tr.record, tr.reason = None, why
        return
    if earth.far(rec.e_c, rec.alpha):
        return
    P = rec.P_c + refraction_covariance(earth.edge, rec.e_c, _inlier_rays(tr, camera), tc.occultation.edge_sigmas)
    tr.record = dataclasses.replace(rec, P_c=P, P_overbound=float(largest_eigenvalue(P)) * np.eye(3))


def _predicted(name: str, prior: FramePrior | None):
    """Predicted unit direction of a target in the camera frame, or None: the Earth's geocentric
    nadir ``R_ec.T @ (-x_e / |x_e|)``, the Sun's/Moon's ``prior.sun_c``/``moon_c``."""
    if prior is None:
        return None
    if name == "earth":
        if prior.x_e is None or prior.R_ec is None:
            return None
        x = np.asarray(prior.x_e, dtype=float)
        return np.asarray(prior.R_ec, dtype=float).T @ (-x / np.linalg.norm(x))
    pred = prior.sun_c if name == "sun" else prior.moon_c
    if pred is None:
        return None
    pred = np.asarray(pred, dtype=float)
    if pred.shape != (3,) or not np.all(np.isfinite(pred)) or np.linalg.norm(pred) == 0:
        raise ValueError(f"prior.{name}_c = {pred!r}; expected a finite 3-vector")
    return pred / np.linalg.norm(pred)


def process_frame(image, camera: Camera, config: VisionConfig, *, height_m: float | None = None,
                  mask: PayloadMask | None = None, prior: FramePrior | None = None,
                  rng: np.random.Generator | None = None, t_ns: int = 0, camera_id: int = 0,
                  baseline: bool = False) -> FrameResult:
    """Earth-nadir, Sun and Moon vectors of one decoded frame (see the module docstring).

    Parameters
    ----------
    image : (H, W, 3) or (H, W) uint8 frame as decoded (distorted); its size must be the camera's.
    camera : intrinsics, any `vision.camera` model (fisheye, equidistant, pinhole).
    config : `VisionConfig`; search lines given by ``alpha_min_deg`` only are spaced for this
        camera (`vision.config.resolve_search_lines`).
    height_m : height above the ellipsoid [m] (the height prior of 003 eq. (5)); needed for the
        Earth unless ``prior.x_e`` is given.
    mask : payload mask of the camera, or None.
    prior : `FramePrior`; with x_e and R_ec the ellipsoid model is used (`vision.oblate`), else the
        spherical model with the local radius of curvature.
    rng : seeded generator for RANSAC (default: seed 0, reproducible).
    t_ns, camera_id : copied into the records.
    baseline : also run the general conic fit (`vision.conic.conic_nadir_fit`) on the Earth winner.

    Returns
    -------
    FrameResult; ``reasons[target]`` says why a target has no vector. Bad input (not a uint8
    frame, wrong size, bad mask) raises ValueError.
    """
    check_camera(camera)
    if not isinstance(image, np.ndarray):
        raise ValueError(f"image: {type(image).__name__}, expected a decoded uint8 numpy array "
                         f"(decode bytes with cv2.imdecode first)")
    config = resolve_search_lines(config, float(min(camera.fx, camera.fy)))
    rng = np.random.default_rng(0) if rng is None else rng
    # one draw per frame: each candidate's RANSAC generator is derived from it (`candidate_rng`)
    frame_seed = int(rng.integers(2**63))
    timings: dict[str, float] = {}
    reasons: dict[str, str] = {}
    targets: dict[str, TargetResult] = {}
    model = None
    if config.earth.enabled:
        config, model, why = _earth_model(config, prior, height_m)
        if model is None:
            reasons["earth"] = why
            config = dataclasses.replace(config, earth=dataclasses.replace(config.earth, enabled=False))
    limb = _limb_prior(config, prior, image)
    hists: dict = {}
    earth = None          # the frame's Earth for the Sun's and the Moon's checks (`vision.occultation`)
    for name in TARGETS:
        tc = config.target(name)
        if not tc.enabled:
            continue
        is_earth = name == "earth"
        if name == "moon" and tc.phase.aware:
            from vision.moon import process_moon
            sun = targets.get("sun")
            sun_c = prior.sun_c if prior is not None and prior.sun_c is not None else (
                sun.record.e_c if sun is not None and sun.record is not None else None)
            tr = process_moon(image, camera, mask, tc, prior, _predicted(name, prior), sun_c, frame_seed, timings,
                              hists, (t_ns, camera_id),
                              earth.edge if earth is not None and tc.occultation.enabled else None)
            targets[name] = tr
            if tr.record is None:
                reasons[name] = tr.reason
            continue
        beside = earth if name == "sun" and tc.occultation.enabled else None
        tr = _process_target(name, image, camera, mask, tc, model if is_earth else None, frame_seed, timings,
                             baseline and is_earth, _predicted(name, prior), limb if is_earth else None, hists,
                             (t_ns, camera_id), beside)
        if beside is not None and tr.record is not None:
            _sun_beside_earth(tr, camera, tc, beside)
        targets[name] = tr
        if is_earth:
            earth = _earth_beside(tr, camera, prior, height_m, model)
        if tr.record is None:
            reasons[name] = tr.reason
    records = [tr.record for tr in targets.values() if tr.record is not None]
    timings["total"] = sum(v for k, v in timings.items() if not k.endswith("baseline_conic_fit"))
    return FrameResult(records, reasons, targets, timings, model.kind if model is not None else "")
