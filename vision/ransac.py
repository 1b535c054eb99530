"""RANSAC for cone fits on the unit sphere (003 §3.6) with the pre-verification of 000 §2.3.

Minimal models (3 rays each, batched over hypotheses):

- known alpha (Earth): two rays p1, p2 fix e up to the mirror pair (e . (p1 - p2) = 0,
  e . (p1 + p2) = 2 cos(alpha), |e| = 1): e = a s^ +- b w^ with s = p1 + p2, w = p1 x p2,
  a = 2 cos(alpha)/|s|, b = sqrt(1 - a^2). The third ray picks the sign whose cone it is closer
  to (this is the mirrored-nadir choice of 002 at the level of a sample). Pairs further apart
  than 2 alpha have no solution and are dropped.
- unknown alpha (Sun/Moon): n = P^-1 1 with P the 3x3 matrix of the rays (exactly determined,
  003 §5); alpha = arccos(1/|n|); hypotheses with |n| <= 1 are dropped.

Pre-verification (000 §2.3 step 3): each hypothesis is first scored on ``n_preverify`` further
random rays; only those with all of them within the threshold are scored on all m rays. Scoring is
the angular distance |acos(p^T e) - alpha|, vectorised as one (hypotheses x m) matrix product per
batch. The number of hypotheses adapts to the best inlier ratio w found so far:
k = log(1 - confidence) / log(1 - w^3). The largest consensus set is refitted with
`vision.nadir.nadir_from_horizon` (or `direction_and_radius`) and the inliers are re-selected
once against the refit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vision.camera import FisheyeCamera, inverse_radial, radial_derivative, radial_distance
from vision.nadir import ConeFit, _check_rays, angle_residuals, direction_and_radius, nadir_from_horizon

__all__ = ["RansacResult", "ransac_cone", "pixel_angle"]


@dataclass(frozen=True)
class RansacResult:
    """fit: refit on the inliers; inliers: (m,) bool; n_hypotheses: generated;
    n_scored: that passed pre-verification and were scored on all rays."""

    fit: ConeFit
    inliers: np.ndarray
    n_hypotheses: int
    n_scored: int


def pixel_angle(camera: FisheyeCamera, uv: np.ndarray) -> np.ndarray:
    """Largest angle one pixel subtends at each pixel [rad]: the larger of the radial
    1/(f dr_d/dtheta) and the tangential sin(theta)/(f r_d), with f = min(fx, fy).
    Converts a pixel threshold into a per-ray angle threshold."""
    uv = np.asarray(uv, dtype=float)
    q = np.hypot((uv[..., 0] - camera.cx) / camera.fx, (uv[..., 1] - camera.cy) / camera.fy)
    th = inverse_radial(camera, q)
    f = min(camera.fx, camera.fy)
    radial = 1.0 / (f * radial_derivative(camera, th))
    with np.errstate(divide="ignore", invalid="ignore"):
        tang = np.where(q > 0, np.sin(th) / (f * radial_distance(camera, th)), radial)
    return np.maximum(radial, tang)


def _hyp_known(P: np.ndarray, c: float) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3, 3) sample rays -> (B, 3) directions, (B,) valid."""
    p1, p2, p3 = P[:, 0], P[:, 1], P[:, 2]
    s = p1 + p2
    w = np.cross(p1, p2)
    sn = np.linalg.norm(s, axis=1)
    wn = np.linalg.norm(w, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = 2.0 * c / sn
        b = np.sqrt(np.maximum(1.0 - a * a, 0.0))
        sh = s / sn[:, None]
        wh = w / wn[:, None]
    valid = (a <= 1.0) & (wn > 1e-12) & (sn > 1e-12)
    e_plus = a[:, None] * sh + b[:, None] * wh
    e_minus = a[:, None] * sh - b[:, None] * wh
    r_plus = np.abs(np.einsum("bi,bi->b", p3, e_plus) - c)
    r_minus = np.abs(np.einsum("bi,bi->b", p3, e_minus) - c)
    e = np.where((r_plus <= r_minus)[:, None], e_plus, e_minus)
    return e, valid & np.all(np.isfinite(e), axis=1)


def _hyp_free(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(B, 3, 3) -> directions (B, 3), alphas (B,), valid (B,)."""
    det = np.linalg.det(P)
    ok = np.abs(det) > 1e-12
    Ps = np.where(ok[:, None, None], P, np.eye(3))
    n = np.linalg.solve(Ps, np.ones((P.shape[0], 3, 1)))[..., 0]
    nn = np.linalg.norm(n, axis=1)
    valid = ok & (nn > 1.0) & np.isfinite(nn)
    with np.errstate(divide="ignore", invalid="ignore"):
        alpha = np.arccos(np.clip(1.0 / nn, -1.0, 1.0))
        e = n / nn[:, None]
    return e, alpha, valid


def ransac_cone(rays_c: np.ndarray, rng: np.random.Generator, alpha: float | None = None,
                threshold: float | np.ndarray = 1e-3, confidence: float = 0.999,
                max_hypotheses: int = 2000, n_preverify: int = 5, batch: int = 128,
                method: str = "constrained", min_inliers: int = 3) -> RansacResult:
    """Robust cone fit: 3-ray minimal models, pre-verification, vectorised scoring, refit.

    Parameters
    ----------
    rays_c : (m, 3) edge rays (unit or not), in edge order.
    rng : seeded ``numpy.random.Generator`` (the result is reproducible for a given seed).
    alpha : known cone half-angle [rad] (Earth), or None to estimate it (Sun/Moon).
    threshold : inlier threshold on the angular distance to the cone [rad]; scalar or (m,) per
        ray (e.g. ``k_px * pixel_angle(camera, uv)`` for a threshold in pixels).
    confidence : probability of drawing at least one all-inlier sample (adaptive stop).
    max_hypotheses : cap on the number of minimal samples.
    n_preverify : rays used to pre-verify a hypothesis before full scoring (000 §2.3); 0 disables.
    batch : hypotheses generated and scored together.
    method : refit method for known alpha (see `nadir_from_horizon`).
    min_inliers : fewer inliers than this raises ValueError.
    """
    H = _check_rays(rays_c)
    m = H.shape[0]
    thr = np.broadcast_to(np.asarray(threshold, dtype=float), (m,))
    if not np.all(thr > 0):
        raise ValueError("ransac_cone: threshold must be > 0 [rad]")
    if not 0 < confidence < 1:
        raise ValueError(f"ransac_cone: confidence = {confidence}; expected in (0, 1)")
    c = None if alpha is None else math.cos(alpha)
    best_count, best_mask = -1, None
    n_hyp = n_scored = 0
    needed = max_hypotheses
    while n_hyp < min(needed, max_hypotheses):
        B = min(batch, max_hypotheses - n_hyp)
        idx = rng.integers(0, m, size=(B, 3 + n_preverify))
        distinct = ((idx[:, 0] != idx[:, 1]) & (idx[:, 0] != idx[:, 2]) & (idx[:, 1] != idx[:, 2]))
        P = H[idx[:, :3]]
        if c is None:
            e, al, valid = _hyp_free(P)
        else:
            e, valid = _hyp_known(P, c)
            al = np.full(B, alpha)
        valid &= distinct
        n_hyp += B
        if n_preverify > 0 and np.any(valid):
            pre = H[idx[:, 3:]]  # (B, k, 3)
            cosang = np.clip(np.einsum("bki,bi->bk", pre, np.nan_to_num(e)), -1, 1)
            r = np.abs(np.arccos(cosang) - al[:, None])
            valid &= np.all(r <= thr[idx[:, 3:]], axis=1)
        if not np.any(valid):
            continue
        ev, av = e[valid], al[valid]
        n_scored += ev.shape[0]
        ang = np.arccos(np.clip(ev @ H.T, -1.0, 1.0))  # (b, m)
        inl = np.abs(ang - av[:, None]) <= thr[None, :]
        counts = inl.sum(axis=1)
        j = int(np.argmax(counts))
        if counts[j] > best_count:
            best_count, best_mask = int(counts[j]), inl[j].copy()
            w = best_count / m
            if w >= 1.0:
                needed = n_hyp
            else:
                denom = math.log(max(1.0 - w**3, 1e-300))
                needed = int(math.ceil(math.log(1.0 - confidence) / denom)) if denom < 0 else max_hypotheses
    if best_mask is None or best_count < max(min_inliers, 3):
        raise ValueError(f"ransac_cone: no consensus set of at least {max(min_inliers, 3)} rays "
                         f"among {m} after {n_hyp} hypotheses (threshold too small, or no cone)")

    def refit(mask: np.ndarray) -> ConeFit:
        if c is None:
            return direction_and_radius(H[mask])
        return nadir_from_horizon(H[mask], alpha, method=method)

    fit = refit(best_mask)
    mask = np.abs(angle_residuals(H, fit.e_c, fit.alpha)) <= thr
    if mask.sum() >= max(min_inliers, 3) and not np.array_equal(mask, best_mask):
        fit = refit(mask)
    else:
        mask = best_mask
    return RansacResult(fit=fit, inliers=mask, n_hypotheses=n_hyp, n_scored=n_scored)
