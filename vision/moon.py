"""The Moon as cameras see it: a search spaced for its expected size, edge thresholds relative to
each candidate, and a phase-aware fit of its lit limb with the covariance of 003 eqs. (33)-(36).

Geometry of the phase
---------------------
Seen from the camera the Moon's outline is its limb, the circle of angular radius
alpha = asin(R_moon / distance) about the direction e to its centre: the cone of 003 eq. (3),
which 003 §5 fits to the Sun with alpha free. The boundary between the lit and the dark
hemisphere is the terminator, the Moon's great circle perpendicular to the Sun's direction s; it
projects to half an ellipse with the limb's centre, its major axis alpha on the limb's diameter
perpendicular to s_t (the component of s in the tangent plane at e, the Sun's direction projected
in the image) and its minor axis alpha |cos g| along s_t (g the phase angle, Sun - Moon -
camera). The lit region is bounded by the half of the limb on the side of s_t (a half circle at
every phase: the cusps lie on the diameter perpendicular to s_t) and by the terminator. Along the
lit limb the region's outward normal is the radial direction, within 90 deg of s_t; along the
terminator it points away from s_t (a crescent's terminator is concave towards the Sun, a gibbous
one bulges away from it). The sign of ``n_out . s_t`` therefore separates the two, and only the
lit limb lies on the cone: a fit of the whole outline, as 003 §5 fits the saturated Sun, is pulled
towards the Sun by the terminator.

Steps (`process_moon`)
----------------------
1. Search: rows ``spacing_radii`` expected radii apart at the camera's coarsest pixel scale (the
   lit part of a Moon lit at the fraction k is 2 k radii thick along s_t), a seed threshold
   ``seed_above`` over the frame's dark level (`seed_threshold`, the first of
   ``seed_percentiles``); when no candidate is accepted but one was larger than the Moon, again
   over the next percentile (a Moon in the glow above the Earth's limb joins the glow at the
   sky's level; a higher seed only splits regions); with a predicted
   direction only the rows its gate reaches (`vision.image_geometry.gate_search_rows`).
2. Per candidate: size gates from the expected radius in pixels where the candidate lies
   (`size_gate`, `fast_pixel_angle`, any lens model; of those passing, the
   ``scoring.max_candidates`` with the brightest border pixels go on), then (`trace_candidate`) a window of the frame around it, its peak
   (95th percentile of its seeded pixels) and its local background (median of the window's rim),
   and the edge re-traced at ``bg + edge_fraction (peak - bg)`` (`vision.borders.find_borders`
   on the window): a dim Moon's edge is where its own brightness steps.
3. Lit limb (`lit_limb_starts`): the edge's outward normals in the image against s_t's image
   direction (from the camera's `project`). Without the Sun's direction, a RANSAC cone fit of
   the whole edge (000 §2.3; the limb is the longest circular arc) gives a centre, and s_t is
   the direction of the edge points whose inside is brightest (`lit_direction`: the lit limb is
   a step up to the disc's brightest values, the terminator a slope from the dark side); the
   points whose outward normals face it are fitted first. When that fit fails, or the disc is
   about as bright inside all round (a nearly full Moon), s_t is the mean radial direction of
   the RANSAC inliers, the middle of the lit limb (when they lie all round, s_t points away from
   those inside the cone by a pixel or more: its terminator), and a fit facing away from the
   bright side is refused. Points within ``limb_margin_deg`` of perpendicular (the cusps) are
   dropped.
4. Fit (`fit_lit_limb`): the constrained fit of 003 eq. (24) with alpha known (less the edge
   offset): the prior's apparent radius (the ephemeris distance), else the mean radius
   ``radius_deg`` with its uncertainty ``radius_sigma`` in the covariance; or, with
   ``free_radius``, the free-radius fit ``H n = 1`` (003 §5, the way 003 fits the Sun's angular
   radius), which the fading horns of a crescent pull inwards (measured in docs/vision.md); inliers re-selected by their cone distance and by their
   position about the fitted centre (within 90 deg - margin of s_t), refitted until stable.
5. Acceptance: enough inliers, the residual, the fitted radius within ``radius_tol`` of the
   expected one (free radius), the gate, dark just outside the fitted limb.
6. Covariance (`moon_covariance`): 003 eq. (33) with the correlated pixel noise of eqs.
   (34)-(36) on the inlier rays (a short arc gives a large covariance by itself), plus, with the
   known radius, ``edge_sigma_px`` of radial edge bias and the radius's uncertainty through
   de/dalpha (`vision.fitting.alpha_sensitivity`): with alpha fixed, a radial bias moves the
   centre; a disc fitted all round without a known lit side gets ``full_sigma_px`` for a
   terminator that may run within a pixel of its limb.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from vision.binarize import BinarizeConfig, as_frame, brightness_histogram
from vision.borders import SearchConfig, find_borders
from vision.camera import project, unproject, unproject_jacobian
from vision.candidates import Candidate, detect, split_borders
from vision.config import FramePrior, TargetConfig
from vision.covariance import direction_covariance, largest_eigenvalue
from vision.fitting import alpha_sensitivity, fit_cone, median
from vision.image_geometry import fast_pixel_angle, gate_search_rows, max_pixel_angle
from vision.nadir import ConeFit, conic_type, within_cone
from vision.occultation import occultation_reason, refraction_covariance
from vision.ransac import ransac_cone
from vision.results import CandidateResult, TargetResult, VectorRecord
from vision.scoring import candidate_rng, gate_reason

__all__ = ["expected_alpha", "seed_threshold", "moon_detection", "outward_normals", "size_gate", "trace_candidate",
           "sun_image_direction", "lit_side", "inner_brightness", "lit_direction", "lit_limb_starts", "fit_lit_limb",
           "moon_covariance", "process_moon"]


def expected_alpha(tc: TargetConfig, prior: FramePrior | None) -> tuple[float, float, bool]:
    """(apparent radius [rad], its 1-sigma [rad], fitted with it): ``prior.moon_alpha`` (the
    ephemeris distance), sigma 0; else ``phase.radius_deg`` with ``phase.radius_sigma``, or a
    free-radius fit with ``phase.free_radius``."""
    a = None if prior is None else prior.moon_alpha
    if a is None:
        a = math.radians(tc.phase.radius_deg)
        return a, tc.phase.radius_sigma * a, not tc.phase.free_radius
    a = float(a)
    if not (math.isfinite(a) and 0.0 < a < 0.2):
        raise ValueError(f"prior.moon_alpha = {a!r}; expected the Moon's apparent radius in (0, 0.2) rad")
    return a, 0.0, True


def seed_threshold(hist: np.ndarray, channels: int, percentile: float, above: float) -> float:
    """Seed threshold [0-255]: the frame's ``percentile`` percentile of brightness (from the
    channel-sum histogram of its sampled pixels) plus ``above``."""
    c = np.cumsum(hist)
    k = int(np.searchsorted(c, percentile / 100.0 * c[-1]))
    return min(254.0, k / channels + above)


def moon_detection(tc: TargetConfig, camera, alpha: float, threshold: float):
    """The Moon's `DetectionConfig`: ``threshold``, search lines ``spacing_radii`` expected radii
    apart at the camera's coarsest pixel scale, candidates of at least half a quarter of the
    smallest limb's length."""
    r_min = alpha * (1.0 - tc.phase.radius_tol) / max_pixel_angle(camera)
    spacing = max(1.0, tc.phase.spacing_radii * r_min)
    search = SearchConfig(line_spacing_px=spacing, max_points=tc.detection.search.max_points)
    binar = BinarizeConfig(threshold=threshold, sample_step=tc.detection.binarize.sample_step)
    return dataclasses.replace(tc.detection, binarize=binar, search=search,
                               min_length=max(4, int(0.25 * math.pi * r_min)))


def outward_normals(points: np.ndarray, closed: bool, k: int = 2) -> np.ndarray:
    """Unit outward normals (m, 2) of a followed border (`vision.borders`: white on the left when
    walking along the chain with v down), from the chord ``p[i+k] - p[i-k]`` (cyclic when
    closed, clipped at the ends otherwise) turned to the right."""
    m = points.shape[0]
    idx = np.arange(m)
    if closed:
        ip, im = (idx + k) % m, (idx - k) % m
    else:
        ip, im = np.minimum(idx + k, m - 1), np.maximum(idx - k, 0)
    t = points[ip] - points[im]
    n = np.stack([-t[:, 1], t[:, 0]], axis=1)
    nn = np.linalg.norm(n, axis=1)
    nn[nn == 0] = 1.0
    return n / nn[:, None]


def size_gate(cand: Candidate, r_px: float, tc: TargetConfig) -> str:
    """"" when the candidate's larger extent lies between the Moon's expected radius and diameter
    ``r_px`` [px] (+- ``phase.radius_tol``, +3 px of blur), else the reason."""
    ph = tc.phase
    ext = float((cand.points.max(axis=0) - cand.points.min(axis=0)).max()) + 1.0
    if ext > 2.0 * r_px * (1.0 + ph.radius_tol) + 3.0:
        return f"{ext:.0f} px across > the Moon's {2 * r_px:.1f} px (+{ph.radius_tol:g})"
    if ext < r_px * (1.0 - ph.radius_tol) - 1.0:
        return f"{ext:.0f} px across < the Moon's radius {r_px:.1f} px (-{ph.radius_tol:g})"
    return ""


def trace_candidate(a: np.ndarray, cand: Candidate, t_seed: float, r_px: float, tc: TargetConfig):
    """Step 2 of the module docstring: (edge Candidate in frame pixels, threshold) or a reason."""
    ph = tc.phase
    why = size_gate(cand, r_px, tc)
    if why:
        return why
    lo, hi = cand.points.min(axis=0), cand.points.max(axis=0)
    h, w = a.shape[:2]
    mg = int(math.ceil(r_px)) + 3
    u0, v0 = max(0, int(lo[0]) - mg), max(0, int(lo[1]) - mg)
    u1, v1 = min(w, int(hi[0]) + mg + 1), min(h, int(hi[1]) + mg + 1)
    win = np.ascontiguousarray(a[v0:v1, u0:u1])
    b = win.mean(axis=2)
    seeded = b[b >= t_seed]
    rim = np.concatenate([b[0], b[-1], b[1:-1, 0], b[1:-1, -1]])
    bg = float(np.median(rim))
    peak = float(np.percentile(seeded, 95)) if seeded.size else bg
    if peak - bg < ph.min_contrast:
        return f"peak {peak:.0f} over background {bg:.0f}: contrast < min_contrast {ph.min_contrast:g}"
    t = bg + ph.edge_fraction * (peak - bg)
    cands = split_borders(find_borders(win, t, None, SearchConfig(line_spacing_px=1.0)), None, 4)
    if not cands:
        return f"no edge at the relative threshold {t:.0f}"
    c = max(cands, key=lambda q: q.n_pixels)
    p = c.points + np.array([u0, v0], dtype=float)
    return Candidate(p, cand.border, c.closed, c.start_edge, c.end_edge, c.arc_length), t


def sun_image_direction(camera, e0: np.ndarray, sun_c: np.ndarray) -> np.ndarray | None:
    """Unit image direction (2,) of the Sun's projected direction s_t at the Moon's direction e0
    (`project` of e0 and of e0 turned 1 mrad towards s_t), or None at full/new Moon (s_t = 0)
    or beyond the lens's range."""
    s = sun_c / np.linalg.norm(sun_c)
    st = s - float(s @ e0) * e0
    ns = float(np.linalg.norm(st))
    if ns < 1e-3:
        return None
    e1 = e0 + 1e-3 * st / ns
    with np.errstate(invalid="ignore"):
        uv = project(camera, np.stack([e0, e1 / np.linalg.norm(e1)]))
    d = uv[1] - uv[0]
    nd = float(np.linalg.norm(d))
    return d / nd if math.isfinite(nd) and nd > 0 else None


def lit_side(H: np.ndarray, e: np.ndarray, s: np.ndarray | None, margin: float) -> np.ndarray:
    """Rays whose position about e lies within 90 deg - margin of s's tangent direction at e (the
    lit half of the limb without its cusps); all when s is None or along e (full Moon)."""
    if s is None:
        return np.ones(H.shape[0], bool)
    st = s - float(s @ e) * e
    ns = float(np.linalg.norm(st))
    if ns < 1e-3:
        return np.ones(H.shape[0], bool)
    tp = H - np.outer(H @ e, e)
    c = (tp @ st) / (np.linalg.norm(tp, axis=1) * ns + 1e-300)
    return c > math.sin(margin)


def _radial(H: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Unit directions (m, 3) of the rays ``H`` about ``e`` in the tangent plane at e."""
    tp = H - np.outer(H @ e, e)
    return tp / np.linalg.norm(tp, axis=1)[:, None]


def _brightness_at(a: np.ndarray, uv: np.ndarray, mask=None) -> np.ndarray:
    """Mean-channel brightness (m,) of the frame ``a`` at the nearest pixels of ``uv`` (m, 2);
    NaN outside the frame or on the payload ``mask``."""
    iu, iv = np.rint(uv[:, 0]), np.rint(uv[:, 1])
    idx = np.flatnonzero(np.isfinite(iu) & np.isfinite(iv) & (iu >= 0) & (iv >= 0)
                         & (iu < a.shape[1]) & (iv < a.shape[0]))
    iu, iv = iu[idx].astype(np.int64), iv[idx].astype(np.int64)
    if mask is not None and mask.has_mask:
        keep = ~mask.mask[iv, iu]
        idx, iu, iv = idx[keep], iu[keep], iv[keep]
    b = np.full(uv.shape[0], np.nan)
    b[idx] = a[iv, iu].reshape(iu.size, -1).mean(axis=1)
    return b


def inner_brightness(a: np.ndarray, edge: Candidate, step_px: float) -> np.ndarray:
    """Brightness (m,) of the frame ``a`` (H, W, C) ``step_px`` pixels inside each edge point,
    along its inward normal (`outward_normals`), at the nearest pixel (NaN outside the frame)."""
    return _brightness_at(a, edge.points - step_px * outward_normals(edge.points, edge.closed))


def lit_direction(H: np.ndarray, e: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """(unit tangent direction (3,) at ``e`` towards the Moon's lit side, its strength in
    [0, 1]) from the brightness ``b`` just inside each edge ray ``H`` (`inner_brightness`).

    The lit limb is a step up to the disc's brightest values, the terminator a slope from the
    dark side (Lommel-Seeliger: the brightness falls to zero at the terminator), so the inside
    of the lit limb is brighter than the outline's mean and that of the terminator darker:
    ``v = sum w t``, ``w`` the brightness about its mean and ``t`` the rays' radial directions
    about e, points to the lit side. Strength ``|v| / sum |w|``: 0 for a disc of even
    brightness all round (a full Moon), 1 when the bright and dark halves face each other."""
    ok = np.isfinite(b)
    tp = _radial(H[ok], e)
    w = b[ok] - b[ok].mean()
    v = w @ tp
    n, den = float(np.linalg.norm(v)), float(np.abs(w).sum())
    if n == 0.0 or den == 0.0:
        return np.zeros(3), 0.0
    return v / n, n / den


def lit_limb_starts(edge: Candidate, H, thr, alpha_fit, sun_c, e0, camera, tc: TargetConfig, rng, a):
    """Step 3: the first selections of the lit limb to fit, in the order to try them, each
    ((m,) bool, Sun direction s for `lit_side` or None, the lit side the fit must face or None),
    or a reason. With ``sun_c``: the outward normals against s_t's image direction at e0.
    Without it, a RANSAC cone fit of the whole edge gives a centre, and where the brightness
    inside the edge points to a side (`lit_direction`, strength at least
    ``phase.min_lit_strength``) the edge points whose outward normals face that side come first
    (they need no exact centre: a RANSAC draw on a small half Moon can take its flat terminator
    for the limb); then the RANSAC inliers on the side of their mean radial direction, whose fit
    must face the bright side when there is one (`_facing`). ``a``: the frame (H, W, C)."""
    margin = math.radians(tc.phase.limb_margin_deg)
    if sun_c is not None:
        s = np.asarray(sun_c, float) / np.linalg.norm(sun_c)
        d = sun_image_direction(camera, e0, s)
        if d is None:
            return [(np.ones(H.shape[0], bool), None, None)]
        return [(outward_normals(edge.points, edge.closed) @ d > math.sin(margin), s, None)]
    need = max(5, int(0.25 * H.shape[0]))
    try:
        rr = ransac_cone(H, rng, alpha=alpha_fit, threshold=thr, confidence=tc.ransac.confidence,
                         max_hypotheses=tc.ransac.max_hypotheses, n_preverify=4,
                         batch=tc.ransac.max_hypotheses, min_inliers=need)
    except ValueError as exc:
        return f"no cone on the whole edge: {exc}"
    e = rr.fit.e_c
    starts = []
    d, strength = lit_direction(H, e, inner_brightness(a, edge, tc.phase.inner_step_px))
    d_img = sun_image_direction(camera, e, d) if strength >= tc.phase.min_lit_strength else None
    if d_img is not None:
        starts.append((outward_normals(edge.points, edge.closed) @ d_img > 0.0, d, None))
    else:
        d = None
    tp = _radial(H, e)
    st = tp[rr.inliers].mean(axis=0)
    if np.linalg.norm(st) < 0.3:
        # inliers all round: a full or nearly full disc, whose terminator runs just inside the
        # limb on the side away from the Sun
        inside = rr.inliers & (np.arccos(np.clip(H @ e, -1.0, 1.0)) - rr.fit.alpha
                               < -1.0 * thr / tc.ransac.threshold_px)
        if inside.sum() < 0.15 * rr.inliers.sum():
            return starts + [(rr.inliers, None, d)]
        st = -tp[inside].mean(axis=0)
    return starts + [(rr.inliers & lit_side(H, e, st, margin), st / np.linalg.norm(st), d)]


def fit_lit_limb(H, sel, s, alpha_fit, thr, margin, need, n_iter: int = 8):
    """Step 4: (ConeFit, inliers) of the lit limb from the first selection ``sel``, or a reason."""
    if int(sel.sum()) < need:
        return f"{int(sel.sum())} lit-limb points < {need}"
    try:
        fit = fit_cone(H[sel], alpha_fit)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return f"no cone on the lit limb: {exc}"
    inl = sel
    for _ in range(n_iter):
        new = within_cone(H, fit.e_c, fit.alpha, thr) & lit_side(H, fit.e_c, s, margin)
        if int(new.sum()) < need:
            return f"{int(new.sum())} lit-limb inliers < {need}"
        if (new == inl).all():
            break
        inl = new
        fit = fit_cone(H[inl], alpha_fit)
    return fit, inl


def moon_covariance(rays, J, fit: ConeFit, H_inl, known: bool, pa: float, sigma_alpha: float,
                    tc: TargetConfig, full: bool = False) -> np.ndarray:
    """Step 6: 003 eq. (33) with eqs. (34)-(36) on the inliers (constrained with the known
    radius, linear with the free one), plus, with the known radius,
    ``((edge_sigma_px pa)^2 + sigma_alpha^2) g g^T``, g = de/dalpha: the edge's radial bias and
    the radius's own uncertainty both act as an error of alpha; ``full`` (fitted all round, no
    lit side known): ``(full_sigma_px pa)^2`` per axis of the tangent plane."""
    if known:
        P = direction_covariance(rays, J, fit.e_c, tc.fit.R_px2, tc.fit.L_px, method="constrained").P_c
        g = alpha_sensitivity(H_inl, fit.e_c, fit.alpha) * math.hypot(tc.phase.edge_sigma_px * pa, sigma_alpha)
        P = P + np.outer(g, g)
    else:
        P = direction_covariance(rays, J, fit.n, tc.fit.R_px2, tc.fit.L_px, method="linear").P_c
    if full:
        P = P + (tc.phase.full_sigma_px * pa) ** 2 * (np.eye(3) - np.outer(fit.e_c, fit.e_c))
    return 0.5 * (P + P.T)


def _dark_outside(image, camera, mask, threshold, rays, e, alpha, step):
    """Fraction of the inlier rays that, turned ``step`` [rad] away from e, land on a pixel below
    ``threshold`` (NaN when none lands in the image outside the mask)."""
    c, s = math.cos(alpha + step), math.sin(alpha + step)
    with np.errstate(invalid="ignore"):
        uv = project(camera, c * e[None, :] + s * _radial(rays, e))
    b = _brightness_at(image, uv, mask)
    b = b[np.isfinite(b)]
    if b.size == 0:
        return math.nan
    return float(np.mean(b < threshold))


def _score(k, cand, pa_c, a, camera, mask, tc, t_seed, alpha, known, sun_c, predicted, frame_seed, earth_edge):
    """Steps 2-5 for candidate k (``pa_c``: the pixel angle where it lies): (CandidateResult,
    payload for the covariance or None)."""
    res = CandidateResult(index=k, n_pixels=cand.n_pixels)
    r_px = alpha / pa_c
    tr = trace_candidate(a, cand, t_seed, r_px, tc)
    if isinstance(tr, str):
        res.reason = tr
        return res, None
    edge, t = tr
    H = unproject(camera, edge.points)
    ok = np.isfinite(H[:, 2])          # NaN beyond the lens's range
    if not ok.all():
        edge = Candidate(edge.points[ok], edge.border, False, edge.start_edge, edge.end_edge, edge.arc_length)
        H = H[ok]
    uv = edge.points
    pa = fast_pixel_angle(camera, uv)
    thr = tc.ransac.threshold_px * pa
    alpha_fit = alpha - tc.edge_offset_px * median(pa) if known else None
    e0 = predicted if predicted is not None else unproject(camera, uv.mean(axis=0))
    need = max(5, int(math.ceil(0.4 * math.pi * r_px)))
    starts = lit_limb_starts(edge, H, thr, alpha_fit, sun_c, e0, camera, tc, candidate_rng(frame_seed, cand), a)
    if isinstance(starts, str):
        res.reason = starts
        return res, None
    for sel, s, facing in starts:
        out = fit_lit_limb(H, sel, s, alpha_fit, thr, math.radians(tc.phase.limb_margin_deg), need)
        if not isinstance(out, str):
            out = out if facing is None else _facing(H, out, facing)
        if not isinstance(out, str):
            break
    if isinstance(out, str):
        res.reason = out
        return res, None
    fit, inl = out
    res.fit, res.residual, res.inliers = fit, fit.residual, int(inl.sum())
    res.reason = _accept(fit, known, alpha, pa_c, predicted, tc)
    if not res.reason and earth_edge is not None and tc.occultation.enabled:
        res.reason = occultation_reason(earth_edge, fit.e_c, alpha, math.radians(tc.occultation.min_clearance_deg),
                                        "Moon")
    if not res.reason:
        dark = _dark_outside(a, camera, mask, t, H[inl], fit.e_c, fit.alpha, tc.side_check.step_px * pa_c)
        if not dark >= tc.side_check.min_agree:
            res.reason = f"bright just outside the fitted limb ({dark:.2f} of the probes dark)"
    return res, (edge, H, inl, fit, pa_c, s is None)


def _facing(H: np.ndarray, out, d: np.ndarray):
    """``out`` (ConeFit, inliers) when its lit limb faces the lit side ``d`` that the brightness
    inside the edge gives (the inliers' mean radial direction about the centre within 90 deg of
    it), else the reason."""
    fit, inl = out
    if float(_radial(H[inl], fit.e_c).mean(axis=0) @ d) > 0.0:
        return out
    return "the fitted lit limb faces away from the bright side inside the edge (a terminator taken for the limb)"


def _accept(fit: ConeFit, known: bool, alpha: float, pa: float, predicted, tc: TargetConfig) -> str:
    """Step 5 (residual, radius, gate): "" or the reason."""
    if fit.residual > tc.max_residual:
        return f"residual {fit.residual:.3g} rad^2 > max_residual {tc.max_residual:.3g}"
    tol = tc.phase.radius_tol * alpha + 1.5 * pa
    if not known and abs(fit.alpha - alpha) > tol:
        return (f"fitted radius {math.degrees(fit.alpha):.3f} deg, expected {math.degrees(alpha):.3f} "
                f"+- {math.degrees(tol):.3f} deg (radius_tol)")
    return gate_reason(fit.e_c, predicted, tc.gate_deg)


def _search(a, camera, mask, tc: TargetConfig, hist, t_seed: float, alpha: float, predicted):
    """Step 1 at the seed threshold ``t_seed``: the `Detection`."""
    dc = moon_detection(tc, camera, alpha, t_seed)
    rows = None
    if predicted is not None:
        rows = gate_search_rows(camera, predicted, math.radians(tc.gate_deg) + 2.0 * alpha, dc.search)
    return detect(a, dc, mask, hist=hist, rows=rows)


def _plausible(cands, a, camera, alpha: float, tc: TargetConfig):
    """Size gate (`size_gate`'s bounds) of all candidates at once: (indices passing, brightest
    first by the largest brightness on their border, at most ``scoring.max_candidates``; pixel
    angle at each candidate's centroid; count too large; count too small). Noise and glare give
    hundreds of Moon-sized borders; the Moon's lit limb is a step, so its border pixels are as
    bright as its limb."""
    n = np.array([c.n_pixels for c in cands])
    off = np.concatenate([[0], np.cumsum(n)[:-1]])
    P = np.concatenate([c.points for c in cands])
    ext = (np.maximum.reduceat(P, off, axis=0) - np.minimum.reduceat(P, off, axis=0)).max(axis=1) + 1.0
    pa = fast_pixel_angle(camera, np.add.reduceat(P, off, axis=0) / n[:, None])
    r = alpha / pa
    big = ext > 2.0 * r * (1.0 + tc.phase.radius_tol) + 3.0
    small = ext < r * (1.0 - tc.phase.radius_tol) - 1.0
    b = np.maximum.reduceat(a[P[:, 1].astype(np.int64), P[:, 0].astype(np.int64)].mean(axis=1), off)
    idx = np.flatnonzero(~big & ~small)
    idx = idx[np.lexsort((-n[idx], -b[idx]))][:tc.scoring.max_candidates]
    return idx, pa, int(big.sum()), int(small.sum())


def _candidates(out: TargetResult, a, camera, mask, tc, t_seed, alpha, known, sun_c, predicted, frame_seed,
                earth_edge):
    """Steps 2-5 on ``out.detection``'s plausible candidates (`_plausible`): (the accepted
    (result, payload) pairs, whether a candidate was larger than the Moon); ``out.candidates``
    and ``out.reason`` set."""
    det = out.detection
    if not det.candidates:
        out.reason = f"no candidate: {det.reason}"
        return [], False
    cands = det.candidates
    idx, pa, n_big, n_small = _plausible(cands, a, camera, alpha, tc)
    scored = [_score(int(i), cands[i], float(pa[i]), a, camera, mask, tc, t_seed, alpha, known, sun_c, predicted,
                     frame_seed, earth_edge) for i in idx]
    out.candidates = [r for r, _ in scored]
    good = [(r, p) for r, p in scored if not r.reason]
    if not good:
        sizes = f"{n_big} larger than the Moon, {n_small} smaller"
        if scored:
            best = min(out.candidates, key=lambda r: r.residual)
            out.reason = (f"no accepted candidate among {len(cands)} at seed threshold {t_seed:.0f} ({sizes}; "
                          f"best: candidate {best.index}, {best.reason})")
        else:
            out.reason = f"no candidate of the Moon's size among {len(cands)} at seed threshold {t_seed:.0f} ({sizes})"
    return good, n_big > 0


def process_moon(image, camera, mask, tc: TargetConfig, prior: FramePrior | None, predicted, sun_c,
                 frame_seed: int, timings: dict, hists: dict, ids, earth_edge=None) -> TargetResult:
    """The Moon's target result for one frame (steps 1-6 of the module docstring), at each seed
    threshold of ``phase.seed_percentiles`` until a candidate is accepted. ``predicted``: the
    Moon's predicted direction or None; ``sun_c``: the Sun's direction in the camera frame (the
    prior's, or the Sun found in the same frame) or None; ``hists``: the frame's brightness
    histograms by sample step (shared with the other targets); ``earth_edge``: the frame's Earth
    (`vision.occultation.EarthEdge`) or None (step 5's occultation test and the refraction term)."""
    t0 = time.perf_counter()
    a = as_frame(image, (camera.height, camera.width))
    step = tc.detection.binarize.sample_step
    hist = hists.get(step)
    if hist is None:
        hist = hists[step] = brightness_histogram(a, step)
    alpha, sigma_alpha, known = expected_alpha(tc, prior)
    good, tried = [], []
    for q in tc.phase.seed_percentiles:
        t_seed = seed_threshold(hist, a.shape[2], q, tc.phase.seed_above)
        if tried and t_seed < tried[-1] + 0.5 * tc.phase.seed_above:
            continue
        tried.append(t_seed)
        out = TargetResult("moon", _search(a, camera, mask, tc, hist, t_seed, alpha, predicted))
        good, too_large = _candidates(out, a, camera, mask, tc, t_seed, alpha, known, sun_c, predicted, frame_seed,
                                      earth_edge)
        if good or not too_large:
            break           # a higher seed only splits regions larger than the Moon
    t1 = time.perf_counter()
    timings["moon.detect"] = t1 - t0
    if not good:
        return out
    win, (edge, H, inl, fit, pa, full) = min(good, key=lambda q: q[0].residual)
    out.winner = win.index
    rays, J = unproject_jacobian(camera, edge.points[inl])
    P = moon_covariance(rays, J, fit, H[inl], known, pa, sigma_alpha, tc, full)
    if earth_edge is not None and tc.occultation.enabled:
        P = P + refraction_covariance(earth_edge, fit.e_c, H[inl], tc.occultation.edge_sigmas)
    timings["moon.covariance"] = time.perf_counter() - t1
    out.points, out.inlier_mask = edge.points, inl
    lam = float(largest_eigenvalue(P))
    out.record = VectorRecord(int(ids[0]), int(ids[1]), "moon", fit.e_c, P, lam * np.eye(3), float(fit.residual),
                              edge.n_pixels, int(inl.sum()), conic_type(fit.e_c, fit.alpha)[1], float(fit.alpha), "")
    return out
