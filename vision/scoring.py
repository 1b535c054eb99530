"""Scoring of one edge candidate (step 2-3 of the pipeline in `vision.frontend`): pre-filters
(gate, curvature), the direct fit or RANSAC (000 §2.3), and the acceptance tests, each failure
giving a reason."""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from vision.camera import unproject
from vision.candidates import Candidate
from vision.config import TargetConfig
from vision.fitting import fit_cone, median, subsample, triple_radii
from vision.image_geometry import conic_passes_image, fast_pixel_angle, max_pixel_angle
from vision.nadir import ConeFit, angle_residuals, mirrored_direction, within_cone
from vision.oblate import LimbModel
from vision.probes import disc_check, inward_kept, side_score
from vision.ransac import ransac_cone
from vision.results import CandidateResult

__all__ = ["candidate_rng", "gate_reason", "score_candidate"]


@dataclass(frozen=True)
class _Consensus:
    """Direct-fit stand-in for `vision.ransac.RansacResult` (fit, inliers)."""

    fit: ConeFit
    inliers: np.ndarray


_RNG = threading.local()


def candidate_rng(frame_seed: int, cand: Candidate) -> np.random.Generator:
    """RANSAC generator of one candidate, seeded by the frame's seed and the candidate itself
    (length, first pixel): its draws do not depend on which other candidates of the frame were
    scored before it (a change of the candidate order, or a candidate skipped by a cheaper test,
    leaves every other fit as it was).

    One PCG64 generator per thread, its 128-bit state set from a hash of those numbers (Python's
    tuple-of-int hash: the same in every process), an order of magnitude cheaper than seeding a
    new generator through numpy's SeedSequence for each candidate."""
    g = getattr(_RNG, "generator", None)
    if g is None:
        g = _RNG.generator = np.random.Generator(np.random.PCG64(0))
    u0, v0 = cand.points[0].tolist()
    h = hash((frame_seed, cand.n_pixels, int(u0), int(v0))) & 0xFFFFFFFFFFFFFFFF
    g.bit_generator.state = {"bit_generator": "PCG64",
                             "state": {"state": (h * 0x9E3779B97F4A7C15F39CC0605CEDC835) & (2**128 - 1),
                                       "inc": 0xDA3E39CB94B95BDB},
                             "has_uint32": 0, "uinteger": 0}
    return g


def _gate_reachable(H: np.ndarray, predicted: np.ndarray, alpha: float | None, reach: float, need: int) -> bool:
    """Can a fit of these rays pass the gate? At least ``need`` rays (the fewest inliers of an
    accepted fit) must lie within ``reach`` [rad] of a cone of half-angle ``alpha`` about the unit
    direction ``predicted`` (Earth: | angle - alpha | <= reach), or within ``reach`` of ``predicted``
    itself (Sun/Moon, ``alpha`` None; their inliers lie within gate + alpha_max + threshold)."""
    return int(np.count_nonzero(within_cone(H, predicted, 0.0 if alpha is None else alpha, reach))) >= need


def _scored_rays(cand: Candidate, camera, tc: TargetConfig):
    """(uv, rays_c) of at most ``scoring.score_rays`` pixels spread along the candidate, those
    beyond the lens's range dropped; or a reason."""
    idx = subsample(cand.n_pixels, tc.scoring.score_rays)
    uv = cand.points[idx]
    rays_c = unproject(camera, uv)
    ok = np.isfinite(rays_c[:, 2])     # unproject: all three NaN beyond the lens's range
    n_ok = int(np.count_nonzero(ok))
    if n_ok < max(8, min(tc.min_pixels, idx.size) // 2):
        return "edge pixels outside the lens's valid range"
    if n_ok < ok.size:
        uv, rays_c = uv[ok], rays_c[ok]
    return uv, rays_c


def _prefilter(H, camera, tc: TargetConfig, model: LimbModel | None, predicted, min_inliers: int) -> str:
    """Cheap tests before any fit; "" or the reason.

    Gate: an accepted fit lies within ``gate_deg`` of the prediction and has at least
    ``min_inliers`` rays within the threshold of its cone (the direct fit: 95 %). Earth: in the fit
    frame, +1 deg for its mapping (< 0.2 deg) and a mirrored refit's spread. The threshold and the
    edge offset are taken with the camera's largest pixel angle (before the per-pixel angles: most
    candidates that fail here are not worth computing them for).

    Curvature: no triple of pixels spread along the edge lies on a circle of the expected angular
    radius -> not this body's limb (saves the RANSAC on glare/cloud edges). Earth: about the cone
    of the model, widened by the edge offset's largest angle."""
    if predicted is not None:
        p = predicted if model is None else model.to_fit(predicted)
        pa_max = max_pixel_angle(camera)
        reach = (math.radians(tc.gate_deg + (tc.alpha_max_deg if model is None else 1.0))
                 + (tc.ransac.threshold_px + (0.0 if model is None else abs(tc.edge_offset_px))) * pa_max)
        if not _gate_reachable(H, p, None if model is None else model.alpha, reach, min_inliers):
            return (f"gate: fewer than {min_inliers} of {H.shape[0]} pixels can lie on a "
                    f"{'disc' if model is None else 'limb'} within gate_deg {tc.gate_deg:g} "
                    f"of the predicted direction")
    rho = triple_radii(H)
    if model is not None:
        ok_rho = np.abs(rho - model.alpha) <= (math.radians(tc.scoring.curvature_tol_deg)
                                               + abs(tc.edge_offset_px) * max_pixel_angle(camera))
    else:
        ok_rho = rho <= math.radians(tc.alpha_max_deg + tc.scoring.curvature_tol_deg)
    if rho.size and not ok_rho.any():
        want = (f"{math.degrees(model.alpha):.1f}" if model is not None else f"<= {tc.alpha_max_deg:g}")
        return (f"curvature: circles through pixel triples have radii "
                f"{math.degrees(rho.min()):.1f}-{math.degrees(rho.max()):.1f} deg, expected {want} "
                f"+- {tc.scoring.curvature_tol_deg:g} deg")
    return ""


def _consensus(H, alpha, thr, tc: TargetConfig, frame_seed: int, cand: Candidate, min_inliers: int):
    """Fit and inliers: a clean edge is fitted directly (refitted on its inliers); RANSAC (000
    §2.3) only when that fit leaves more than ``scoring.direct_outlier_fraction`` of the pixels
    outside the threshold. ValueError when RANSAC finds no consensus."""
    rr = None
    try:
        f0 = fit_cone(H, alpha)
        in0 = within_cone(H, f0.e_c, f0.alpha, thr)
        if np.count_nonzero(in0) >= (1.0 - tc.scoring.direct_outlier_fraction) * in0.size:
            f1 = fit_cone(H[in0], alpha)
            rr = _Consensus(f1, within_cone(H, f1.e_c, f1.alpha, thr))
    except ValueError:
        rr = None
    if rr is None or rr.inliers.sum() < 3:
        rr = ransac_cone(H, candidate_rng(frame_seed, cand), alpha=alpha, threshold=thr,
                         confidence=tc.ransac.confidence, max_hypotheses=tc.ransac.max_hypotheses,
                         n_preverify=4, batch=tc.ransac.max_hypotheses, min_inliers=min_inliers)
    return rr


def gate_reason(e_c, predicted, gate_deg: float, what: str = "the predicted direction") -> str:
    """"" when ``predicted`` is None or the unit vector ``e_c`` lies within ``gate_deg`` of it,
    else the reason, naming ``predicted`` as ``what``."""
    if predicted is None:
        return ""
    off = math.degrees(math.acos(max(-1.0, min(1.0, float(e_c @ predicted)))))
    return f"{off:.1f} deg from {what} > gate_deg {gate_deg:g}" if off > gate_deg else ""


def _disc_reason(fit: ConeFit, image, camera, mask, det, tc: TargetConfig, predicted) -> str:
    """Sun/Moon acceptance: apparent radius in [alpha_min_deg, alpha_max_deg], within
    ``gate_deg`` of the predicted direction, a disc bright inside and dark around
    (`vision.probes.disc_check`); "" or the reason."""
    if not (math.radians(tc.alpha_min_deg) <= fit.alpha <= math.radians(tc.alpha_max_deg)):
        return (f"apparent radius {math.degrees(fit.alpha):.3g} deg outside "
                f"[{tc.alpha_min_deg:g}, {tc.alpha_max_deg:g}] deg")
    gate = gate_reason(fit.e_c, predicted, tc.gate_deg)
    if gate:
        return gate + " (flare ghost?)"
    return disc_check(image, camera, mask, det.threshold, fit.e_c, fit.alpha, tc.side_check.step_px)


def _side_test(res: CandidateResult, fit: ConeFit, inl, H, rays_c, uv, alpha, image, camera, mask, det,
               tc: TargetConfig, model: LimbModel | None):
    """Mirrored-nadir test (002 §3): the body must be bright on its side of the edge. An Earth fit
    that fails it is refitted from its mirror image (`vision.nadir.mirrored_direction`), which
    replaces it in ``res`` when it passes with an acceptable residual. Returns (fit, agreeing
    fraction of the probes)."""
    e_c = fit.e_c if model is None else model.to_camera(fit.e_c)
    alpha_c = fit.alpha if model is None else median(angle_residuals(rays_c[inl], e_c, 0.0))
    side = side_score(image, camera, mask, det.threshold, rays_c[inl], uv[inl], e_c, alpha_c,
                      tc.side_check.step_px, tc.side_check.rays)
    if not side >= tc.side_check.min_agree and model is not None:
        alt = fit_cone(H[inl], alpha, mirrored_direction(fit.e_c, H[inl]))
        e_alt = model.to_camera(alt.e_c)
        side_alt = side_score(image, camera, mask, det.threshold, rays_c[inl], uv[inl], e_alt, alpha_c,
                              tc.side_check.step_px, tc.side_check.rays)
        if side_alt >= tc.side_check.min_agree and alt.residual <= tc.max_residual:
            fit, side, res.mirrored = alt, side_alt, True
            res.fit, res.residual = alt, alt.residual
    return fit, side


def _band_reason(fit: ConeFit, inl, H, rays_c, uv, alpha, image, camera, mask, det, tc: TargetConfig,
                 model: LimbModel) -> str:
    """Earth: "" unless the mirrored cone fits the arc as well as the fit (residual within
    ``max_residual``: a short, nearly straight arc, where only the brightness tells the sides
    apart) and the Earth's side falls back to the sky's darkness within
    ``side_check.band_depth_deg`` (`vision.probes.inward_kept`): then the bright side is a lit
    band of air over a dark Earth, whose lower edge has the Earth's brightness on the wrong side."""
    sc = tc.side_check
    if not sc.band_depth_deg > 0.0:
        return ""
    alt = fit_cone(H[inl], alpha, mirrored_direction(fit.e_c, H[inl]))
    if not alt.residual <= tc.max_residual:
        return ""
    kept = inward_kept(image, camera, mask, sc.band_level * det.threshold, rays_c[inl], uv[inl],
                       model.to_camera(fit.e_c), math.radians(sc.band_depth_deg), sc.step_px, sc.rays)
    if not kept < sc.band_min_kept:
        return ""
    return (f"a lit band over a dark Earth? {kept:.2f} of the paths towards the nadir stay above "
            f"{sc.band_level:g} of the threshold for {sc.band_depth_deg:g} deg (< {sc.band_min_kept:g}), and "
            f"the mirrored cone fits the arc as well (002 mirrored nadir)")


def score_candidate(k: int, cand: Candidate, image, camera, mask, det, tc: TargetConfig,
                    model: LimbModel | None, frame_seed: int, predicted: np.ndarray | None = None) -> CandidateResult:
    """Fit and acceptance tests of candidate ``k`` (steps 2-3 of `vision.frontend`'s pipeline) on
    at most ``scoring.score_rays`` of its pixels. ``model``: the Earth's limb model (known alpha
    in its fit frame), None for the Sun/Moon (alpha estimated); ``predicted``: the target's
    predicted unit direction in the camera frame, or None. ``reason`` is "" when accepted."""
    res = CandidateResult(index=k, n_pixels=cand.n_pixels)
    if cand.n_pixels < tc.min_pixels:
        res.reason = f"{cand.n_pixels} pixels < min_pixels {tc.min_pixels}"
        return res
    sr = _scored_rays(cand, camera, tc)
    if isinstance(sr, str):
        res.reason = sr
        return res
    uv, rays_c = sr
    H = rays_c if model is None else model.to_fit(rays_c)
    min_inliers = max(3, int(math.ceil(tc.ransac.min_inlier_fraction * H.shape[0])))
    res.reason = _prefilter(H, camera, tc, model, predicted, min_inliers)
    if res.reason:
        return res
    pa = fast_pixel_angle(camera, uv)
    thr = tc.ransac.threshold_px * pa
    alpha = None if model is None else model.alpha - tc.edge_offset_px * median(pa)
    try:
        rr = _consensus(H, alpha, thr, tc, frame_seed, cand, min_inliers)
    except ValueError as exc:
        res.reason = f"no cone: {exc}"
        return res
    fit = rr.fit
    res.inliers = int(rr.inliers.sum())
    res.fit = fit
    res.residual = fit.residual
    if model is None:
        res.reason = _disc_reason(fit, image, camera, mask, det, tc, predicted)
        if res.reason:
            return res
    inl = rr.inliers
    fit, side = _side_test(res, fit, inl, H, rays_c, uv, alpha, image, camera, mask, det, tc, model)
    if not side >= tc.side_check.min_agree:
        res.reason = (f"wrong side (002 mirrored nadir): {side:.2f} of the pixels beside the edge "
                      f"agree < {tc.side_check.min_agree:g}")
        return res
    if model is not None:
        res.reason = _band_reason(fit, inl, H, rays_c, uv, alpha, image, camera, mask, det, tc, model)
        if res.reason:
            return res
    if model is not None and predicted is not None:
        # Earth gate: the geocentric nadir predicted by the prior (x_e, R_ec); a glare or cloud
        # edge that happens to fit a cone of the right radius points elsewhere
        gate = gate_reason(model.to_camera(fit.e_c), predicted, tc.gate_deg, "the predicted nadir")
        if gate:
            res.reason = f"{gate} (glare or cloud edge?)"
            return res
    if res.residual > tc.max_residual:
        res.reason = f"residual {res.residual:.3g} rad^2 > max_residual {tc.max_residual:.3g}"
        return res
    if not conic_passes_image(camera, fit.e_c, fit.alpha, model, H[inl]):   # 003 §3.3 sanity check
        res.reason = "the fitted conic does not pass through the image (003 §3.3)"
    return res
