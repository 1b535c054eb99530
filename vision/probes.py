"""Image probes around a fitted cone: the mirrored-nadir test (002 §3) and the Sun/Moon disc test.
Each probe is a ray turned off the edge or the disc centre, projected through the distorted camera
(`vision._kernels.project1`) and looked up in the frame; one numba pass per test."""
from __future__ import annotations

import math

import numba
import numpy as np

from vision._kernels import project1
from vision.covariance import tangent_basis
from vision.camera import project
from vision.fitting import subsample
from vision.image_geometry import fast_pixel_angle, unit_circle
from vision.nadir import norm3

__all__ = ["side_score", "inward_kept", "disc_check"]


def _edge_probes(image, camera, mask, rays_c, uv, e_c, step_px, n_probe):
    """The kernels' inputs for ``n_probe`` edge rays spread along the edge: (frame (H, W, C), mask
    or an empty one, rays (n, 3), unit e, the angle of ``step_px`` pixels at each ray)."""
    sel = subsample(rays_c.shape[0], n_probe)
    img = image if image.ndim == 3 else image[:, :, None]
    m = mask.mask if (mask is not None and mask.has_mask) else _NO_MASK
    return (img, m, np.ascontiguousarray(rays_c[sel]), e_c / norm3(e_c),
            step_px * fast_pixel_angle(camera, uv[sel]))


def side_score(image, camera, mask, threshold, rays_c, uv, e_c, alpha_c_space, step_px, n_probe):
    """Mirrored-nadir test (002 §3): step ``n_probe`` edge rays towards / away from e by
    ``step_px`` pixels, look at the image there, and check (as `vision.nadir.earth_side_check`)
    that the bright pixels are inside the cone (body) and the dark ones outside (space). Returns
    the agreeing fraction (NaN if no usable pixel). The per-probe work is one numba pass
    (`_side_kernel`: ~25 small numpy calls per candidate otherwise)."""
    img, m, rays, e, ang = _edge_probes(image, camera, mask, rays_c, uv, e_c, step_px, n_probe)
    good, total = _side_kernel(img, m, float(threshold), rays, e, ang, float(alpha_c_space), *camera.kernel_params())
    return good / total if total else math.nan


def inward_kept(image, camera, mask, level, rays_c, uv, e_c, depth_rad, step_px, n_probe):
    """Fraction of ``n_probe`` edge rays whose path towards e, sampled every ``step_px`` pixels
    from the second step out to ``depth_rad``, stays at or above the brightness ``level`` on
    every sample inside the image (NaN when no path has a sample in the image beyond the first
    step). Below it the path has left the body for the sky's darkness: the bright side of the
    edge was a band, not the body's disc."""
    img, m, rays, e, ang = _edge_probes(image, camera, mask, rays_c, uv, e_c, step_px, n_probe)
    kept, usable = _inward_kernel(img, m, float(level), rays, e, ang, float(depth_rad), *camera.kernel_params())
    return kept / usable if usable else math.nan


_NO_MASK = np.zeros((0, 0), dtype=bool)


@numba.njit(cache=True)
def _probe_brightness(img, mask, u, v):
    """Mean-channel brightness at the nearest pixel of (u, v) (``np.rint``, clipped), or -1 when (u, v)
    is outside the image (`in_image`) or on the payload mask (an empty mask: none)."""
    h, w = img.shape[0], img.shape[1]
    if not (math.isfinite(u) and math.isfinite(v) and u >= -0.5 and u <= w - 0.5 and v >= -0.5
            and v <= h - 0.5):
        return -1.0
    iu = min(max(int(np.rint(u)), 0), w - 1)
    iv = min(max(int(np.rint(v)), 0), h - 1)
    if mask.shape[0] and mask[iv, iu]:
        return -1.0
    nc = img.shape[2]
    acc = 0.0
    for c in range(nc):
        acc += float(img[iv, iu, c])
    return acc / nc


@numba.njit(cache=True, inline="always")
def _towards(px, py, pz, e):
    """Unit tangent ``t = (e - (p.e) p) / |...|`` at the ray p towards e, and its norm before
    normalising (0 when p is along e)."""
    d = px * e[0] + py * e[1] + pz * e[2]
    tx, ty, tz = e[0] - d * px, e[1] - d * py, e[2] - d * pz
    tn = math.sqrt(tx * tx + ty * ty + tz * tz)
    if not tn > 0.0:
        return 0.0, 0.0, 0.0, 0.0
    return tx / tn, ty / tn, tz / tn, tn


@numba.njit(cache=True)
def _side_kernel(img, mask, threshold, rays, e, ang, alpha, model, prm):
    """Probes of `side_score`: each ray turned by ang_j towards e and away from it (tangent
    ``t = e - (p.e) p`` normalised; rays with |t| <= 1e-9 skipped), projected, looked up
    (`_probe_brightness`); a bright probe (>= threshold) agrees when its angle from e is below
    alpha, a dark one when above. Returns (agreeing, usable) probe counts."""
    good = 0
    total = 0
    for sign in (1.0, -1.0):
        for j in range(rays.shape[0]):
            px, py, pz = rays[j, 0], rays[j, 1], rays[j, 2]
            tx, ty, tz, tn = _towards(px, py, pz, e)
            if not tn > 1e-9:
                continue
            ca, sa = math.cos(ang[j]), sign * math.sin(ang[j])
            qx = ca * px + sa * tx
            qy = ca * py + sa * ty
            qz = ca * pz + sa * tz
            u, v = project1(qx, qy, qz, model, prm)
            b = _probe_brightness(img, mask, u, v)
            if b < 0.0:
                continue
            qn = math.sqrt(qx * qx + qy * qy + qz * qz)
            c = (qx * e[0] + qy * e[1] + qz * e[2]) / qn
            a = math.acos(min(max(c, -1.0), 1.0))
            total += 1
            if (b >= threshold and a < alpha) or (b < threshold and a > alpha):
                good += 1
    return good, total



@numba.njit(cache=True)
def _inward_kernel(img, mask, level, rays, e, ang, depth, model, prm):
    """Paths of `inward_kept`: each ray turned towards e (tangent ``t = e - (p.e) p``) by k ang_j,
    k = 2, 3, ... while k ang_j <= depth, each sample projected and looked up
    (`_probe_brightness`; outside the image or on the mask: skipped). Returns (paths whose every
    sample is >= level, paths with a sample)."""
    kept = 0
    usable = 0
    for j in range(rays.shape[0]):
        px, py, pz = rays[j, 0], rays[j, 1], rays[j, 2]
        tx, ty, tz, tn = _towards(px, py, pz, e)
        if not (tn > 1e-9 and ang[j] > 0.0):
            continue
        n_seen = 0
        dark = False
        k = 2
        while k * ang[j] <= depth:
            ca, sa = math.cos(k * ang[j]), math.sin(k * ang[j])
            u, v = project1(ca * px + sa * tx, ca * py + sa * ty, ca * pz + sa * tz, model, prm)
            b = _probe_brightness(img, mask, u, v)
            k += 1
            if b < 0.0:
                continue
            n_seen += 1
            if b < level:
                dark = True
                break
        if n_seen:
            usable += 1
            if not dark:
                kept += 1
    return kept, usable


def disc_check(image, camera, mask, threshold, e_c, alpha, step_px, n: int = 16) -> str:
    """Sun/Moon disc test: the ring at alpha/2 about the fitted centre must lie in the image
    (at least 3/4 of its points, outside the payload mask) and be bright throughout, and at least
    3/4 of the ring at alpha + step_px pixels must be dark. Rejects short bright arcs (a saturated
    limb or glint at the image corner) that a small circle fits. Returns "" or the reason. The
    ring probes are one numba pass (`_disc_kernel`)."""
    T = tangent_basis(e_c)
    with np.errstate(invalid="ignore", divide="ignore"):
        uv_c = project(camera, e_c)
    pa = float(fast_pixel_angle(camera, uv_c[None, :])[0]) if np.isfinite(uv_c).all() else 1.0 / camera.fx
    img = image if image.ndim == 3 else image[:, :, None]
    m = mask.mask if (mask is not None and mask.has_mask) else _NO_MASK
    n_in, dark_in, n_out, dark_out = _disc_kernel(
        img, m, float(threshold), np.asarray(e_c, dtype=float), T, unit_circle(n, False),
        0.5 * alpha, alpha + step_px * pa, *camera.kernel_params())
    if n_in < 0.75 * n:
        return f"disc centre too close to the image edge or mask ({n_in}/{n} inner probes visible)"
    if dark_in:
        return f"disc not bright inside ({dark_in}/{n_in} inner probes below threshold)"
    if n_out and dark_out / n_out < 0.75:
        return f"bright around the disc ({n_out - dark_out}/{n_out} outer probes above threshold)"
    return ""


@numba.njit(cache=True)
def _disc_kernel(img, mask, threshold, e, T, cs, ang_in, ang_out, model, prm):
    """Rings of `disc_check`: ``cos(ang) e + sin(ang) (cos psi t1 + sin psi t2)`` for the inner and
    the outer angle, projected and looked up (`_probe_brightness`). Returns (inner probes usable,
    of them below threshold, outer probes usable, of them below threshold)."""
    out = np.zeros(4, np.int64)
    for q in range(2):
        ang = ang_in if q == 0 else ang_out
        ca, sa = math.cos(ang), math.sin(ang)
        for j in range(cs.shape[0]):
            c, s = cs[j, 0], cs[j, 1]
            rx = c * T[0, 0] + s * T[0, 1]
            ry = c * T[1, 0] + s * T[1, 1]
            rz = c * T[2, 0] + s * T[2, 1]
            u, v = project1(ca * e[0] + sa * rx, ca * e[1] + sa * ry, ca * e[2] + sa * rz, model, prm)
            b = _probe_brightness(img, mask, u, v)
            if b < 0.0:
                continue
            out[2 * q] += 1
            if b < threshold:
                out[2 * q + 1] += 1
    return out[0], out[1], out[2], out[3]
