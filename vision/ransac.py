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
the angular distance |acos(p^T e) - alpha|, in one numba kernel per batch (`_score_hypotheses`,
the draws stay with ``rng.integers``). The number of hypotheses adapts to the best inlier ratio w
found so far: k = log(1 - confidence) / log(1 - w^(3 + d)), d = ``n_preverify`` (a good minimal
sample is kept only when its d pre-verification rays are inliers as well, probability w^d; with
w^3 alone the stop came ~9x too early at w = 0.6, d = 4). The largest consensus set is refitted with
`vision.nadir.nadir_from_horizon` (or `direction_and_radius`) and the inliers are re-selected
once against the refit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from vision.camera import Camera, FisheyeCamera, inverse_radial, radial_derivative, radial_distance, unproject_jacobian
from vision.nadir import ConeFit, check_rays, direction_and_radius, nadir_from_horizon, per_ray, within_cone

__all__ = ["RansacResult", "ransac_cone", "pixel_angle"]


@dataclass(frozen=True)
class RansacResult:
    """fit: refit on the inliers; inliers: (m,) bool; n_hypotheses: generated;
    n_scored: that passed pre-verification and were scored on all rays."""

    fit: ConeFit
    inliers: np.ndarray
    n_hypotheses: int
    n_scored: int


def pixel_angle(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """Largest angle one pixel subtends at each pixel [rad]. Converts a pixel threshold into a
    per-ray angle threshold.

    Fisheye (closed form): the larger of the radial 1/(f dr_d/dtheta) and the tangential
    sin(theta)/(f r_d), with f = min(fx, fy). Other models: the largest singular value of the
    unproject Jacobian J = d ray / d(u, v), sqrt of the larger eigenvalue of J^T J (for the fisheye
    with fx = fy the two agree)."""
    uv = np.asarray(uv, dtype=float)
    if not isinstance(camera, FisheyeCamera):
        _, J = unproject_jacobian(camera, uv)
        a = np.sum(J[..., 0] ** 2, axis=-1)
        c = np.sum(J[..., 1] ** 2, axis=-1)
        b = np.sum(J[..., 0] * J[..., 1], axis=-1)
        return np.sqrt(0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b))
    q = np.hypot((uv[..., 0] - camera.cx) / camera.fx, (uv[..., 1] - camera.cy) / camera.fy)
    th = inverse_radial(camera, q)
    f = min(camera.fx, camera.fy)
    radial = 1.0 / (f * radial_derivative(camera, th))
    with np.errstate(divide="ignore", invalid="ignore"):
        tang = np.where(q > 0, np.sin(th) / (f * radial_distance(camera, th)), radial)
    return np.maximum(radial, tang)


@numba.njit(cache=True)
def _clip1(x):
    return -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)


@numba.njit(cache=True)
def _score_hypotheses(H, idx, thr, c, alpha, free):
    """Minimal models of all B samples ``idx`` (B, 3 + k) (the formulas of the module docstring;
    samples with repeated indices are invalid), pre-verification on the k further rays (000 §2.3),
    and the inlier count on all m rays of the survivors. Returns counts (B,) (-1: invalid or
    failed the pre-verification), directions (B, 3), half-angles (B,)."""
    B = idx.shape[0]
    k = idx.shape[1] - 3
    m = H.shape[0]
    counts = np.full(B, -1, np.int64)
    E = np.zeros((B, 3))
    AL = np.zeros(B)
    for h in range(B):
        i0, i1, i2 = idx[h, 0], idx[h, 1], idx[h, 2]
        if i0 == i1 or i0 == i2 or i1 == i2:
            continue
        p1x, p1y, p1z = H[i0, 0], H[i0, 1], H[i0, 2]
        p2x, p2y, p2z = H[i1, 0], H[i1, 1], H[i1, 2]
        p3x, p3y, p3z = H[i2, 0], H[i2, 1], H[i2, 2]
        if free:
            # n = P^-1 1 (Cramer: (p2 x p3 + p3 x p1 + p1 x p2) / det)
            c23x, c23y, c23z = p2y * p3z - p2z * p3y, p2z * p3x - p2x * p3z, p2x * p3y - p2y * p3x
            c31x, c31y, c31z = p3y * p1z - p3z * p1y, p3z * p1x - p3x * p1z, p3x * p1y - p3y * p1x
            c12x, c12y, c12z = p1y * p2z - p1z * p2y, p1z * p2x - p1x * p2z, p1x * p2y - p1y * p2x
            det = p1x * c23x + p1y * c23y + p1z * c23z
            if not abs(det) > 1e-12:
                continue
            nx = (c23x + c31x + c12x) / det
            ny = (c23y + c31y + c12y) / det
            nz = (c23z + c31z + c12z) / det
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
            if not (nn > 1.0 and math.isfinite(nn)):
                continue
            al = math.acos(_clip1(1.0 / nn))
            ex, ey, ez = nx / nn, ny / nn, nz / nn
        else:
            sx, sy, sz = p1x + p2x, p1y + p2y, p1z + p2z
            wx, wy, wz = p1y * p2z - p1z * p2y, p1z * p2x - p1x * p2z, p1x * p2y - p1y * p2x
            sn = math.sqrt(sx * sx + sy * sy + sz * sz)
            wn = math.sqrt(wx * wx + wy * wy + wz * wz)
            if not (wn > 1e-12 and sn > 1e-12):
                continue
            a = 2.0 * c / sn
            if not a <= 1.0:
                continue
            b = math.sqrt(max(1.0 - a * a, 0.0))
            shx, shy, shz = sx / sn, sy / sn, sz / sn
            whx, why, whz = wx / wn, wy / wn, wz / wn
            epx, epy, epz = a * shx + b * whx, a * shy + b * why, a * shz + b * whz
            emx, emy, emz = a * shx - b * whx, a * shy - b * why, a * shz - b * whz
            rp = abs(p3x * epx + p3y * epy + p3z * epz - c)
            rm = abs(p3x * emx + p3y * emy + p3z * emz - c)
            if rp <= rm:
                ex, ey, ez = epx, epy, epz
            else:
                ex, ey, ez = emx, emy, emz
            if not (math.isfinite(ex) and math.isfinite(ey) and math.isfinite(ez)):
                continue
            al = alpha
        ok = True
        for q in range(k):
            j = idx[h, 3 + q]
            r = abs(math.acos(_clip1(H[j, 0] * ex + H[j, 1] * ey + H[j, 2] * ez)) - al)
            if not r <= thr[j]:
                ok = False
                break
        if not ok:
            continue
        n_in = 0
        for j in range(m):
            r = abs(math.acos(_clip1(H[j, 0] * ex + H[j, 1] * ey + H[j, 2] * ez)) - al)
            if r <= thr[j]:
                n_in += 1
        counts[h] = n_in
        E[h, 0], E[h, 1], E[h, 2] = ex, ey, ez
        AL[h] = al
    return counts, E, AL


@numba.njit(cache=True)
def _count_best(counts):
    """(number of counts >= 0, index of the first largest count): ``(counts >= 0).sum()`` and
    ``argmax(counts)`` in one pass (three numpy calls on a 100-element array otherwise)."""
    n_valid = 0
    j = 0
    for h in range(counts.shape[0]):
        if counts[h] >= 0:
            n_valid += 1
        if counts[h] > counts[j]:
            j = h
    return n_valid, j


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
    H = check_rays(rays_c)
    m = H.shape[0]
    thr = per_ray(threshold, m)
    if not thr.min() > 0:
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
        counts, E, AL = _score_hypotheses(H, idx, thr, -1.0 if c is None else c,
                                          0.0 if alpha is None else alpha, c is None)
        n_hyp += B
        n_valid, j = _count_best(counts)
        if n_valid == 0:
            continue
        n_scored += n_valid
        if counts[j] > best_count:
            best_count, best_mask = int(counts[j]), within_cone(H, E[j], AL[j], thr)
            w = best_count / m
            if w >= 1.0:
                needed = n_hyp
            else:
                # a good sample survives only if its n_preverify further rays are inliers too
                denom = math.log(max(1.0 - w ** (3 + n_preverify), 1e-300))
                needed = int(math.ceil(math.log(1.0 - confidence) / denom)) if denom < 0 else max_hypotheses
    if best_mask is None or best_count < max(min_inliers, 3):
        raise ValueError(f"ransac_cone: no consensus set of at least {max(min_inliers, 3)} rays "
                         f"among {m} after {n_hyp} hypotheses (threshold too small, or no cone)")

    def refit(mask: np.ndarray) -> ConeFit:
        if c is None:
            return direction_and_radius(H[mask])
        return nadir_from_horizon(H[mask], alpha, method=method)

    fit = refit(best_mask)
    mask = within_cone(H, fit.e_c, fit.alpha, thr)
    if mask.sum() >= max(min_inliers, 3) and not (mask == best_mask).all():
        fit = refit(mask)
    else:
        mask = best_mask
    return RansacResult(fit=fit, inliers=mask, n_hypotheses=n_hyp, n_scored=n_scored)
