"""Numpy and OpenCV twins of vision's compiled kernels, the references the tests (and the detection
benchmark) check the kernels against: the same formulas as array operations on all elements."""
from __future__ import annotations

import cv2
import numpy as np

from vision.borders import Borders
from vision.camera import FisheyeCamera, _inverse_radial_bracketed, radial_distance
from vision.limb import LimbEdgeConfig, _bilinear
from vision.mask import PayloadMask


def project_reference(camera: FisheyeCamera, rays_c: np.ndarray) -> np.ndarray:
    """`vision.camera.project` in numpy array operations (the reference its kernel is tested against)."""
    p = np.asarray(rays_c, dtype=float)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    rho = np.hypot(x, y)
    theta = np.arctan2(rho, z)
    r_d = radial_distance(camera, theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(rho > 0.0, r_d / rho, 0.0)
    u = camera.cx + camera.fx * scale * x
    v = camera.cy + camera.fy * scale * y
    bad = (theta > camera.max_theta) | ((rho == 0.0) & (z <= 0.0))
    uv = np.stack([u, v], axis=-1)
    uv[bad] = np.nan
    return uv


def unproject_reference(camera: FisheyeCamera, uv: np.ndarray) -> np.ndarray:
    """`vision.camera.unproject` in numpy array operations with the bracketed Newton inverse."""
    uv = np.asarray(uv, dtype=float)
    xd, yd = (uv[..., 0] - camera.cx) / camera.fx, (uv[..., 1] - camera.cy) / camera.fy
    r_d = np.hypot(xd, yd)
    theta = _inverse_radial_bracketed(camera, r_d)
    st = np.sin(theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(r_d > 0.0, st / r_d, 0.0)
    return np.stack([s * xd, s * yd, np.cos(theta)], axis=-1)


def profile_crossings_reference(image, uv, n, s, config: LimbEdgeConfig):
    """`vision.limb._limb_profiles` as numpy array operations on all samples (the reference
    tests/test_limb.py checks the kernel against). Returns (sc, ok)."""
    m = uv.shape[0]
    Q = uv[:, None, :] + s[None, :, None] * n[:, None, :]
    Q = np.nan_to_num(Q, nan=-10.0).astype(np.float32)
    v = _bilinear(image, config.channel, Q[..., 0], Q[..., 1])
    inside = np.all(v >= 0.0, axis=1) & np.all(np.isfinite(n), axis=1)
    L = (np.clip(v, 0.0, 255.0) * (1.0 / 255.0)) ** config.gamma
    i0 = config.space_px
    Lin = L[:, i0:]
    rm = np.maximum.accumulate(Lin, axis=1)
    drop = Lin < (1.0 - config.min_drop) * rm
    has_drop = drop.any(axis=1)
    stop = np.where(has_drop, drop.argmax(axis=1), Lin.shape[1] - 1)
    rows = np.arange(m)
    peak = rm[rows, stop]
    reach = (Lin >= peak[:, None]) & (np.arange(Lin.shape[1])[None, :] <= stop[:, None])
    jpk = reach.argmax(axis=1) + i0
    bg = np.min(L[:, :i0 + 1], axis=1)
    clip = (config.clip_level / 255.0) ** config.gamma
    tgt = bg + config.fraction * (peak - bg)
    idx = np.arange(L.shape[1])[None, :]
    below = (L < tgt[:, None]) & (idx < jpk[:, None])
    found = below.any(axis=1)
    a = L.shape[1] - 1 - below[:, ::-1].argmax(axis=1)
    a = np.minimum(a, L.shape[1] - 2)
    La, Lb = L[rows, a], L[rows, a + 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.clip((tgt - La) / (Lb - La), 0.0, 1.0)
    sc = s[a] + frac
    ok = inside & has_drop & found & (peak < clip) & (peak > bg + 1e-6) & (a + 1 <= jpk)
    return sc, ok


def find_borders_reference(binary, mask: PayloadMask | None = None, rows=None) -> Borders:
    """The same borders from OpenCV's ``findContours(RETR_EXTERNAL, CHAIN_APPROX_NONE)`` on the
    whole binary image (Suzuki & Abe, every pixel examined), kept if they touch the image border,
    lie next to the mask or have a pixel on a search row: the reference of
    `vision.borders.find_borders` and the baseline of its benchmark.

    ``binary``: (H, W) uint8, nonzero = white; masked pixels are set to black first.
    """
    b = np.asarray(binary)
    if b.ndim != 2 or b.dtype != np.uint8:
        raise ValueError(f"binary: shape {b.shape} dtype {b.dtype}, expected (H, W) uint8")
    h, w = b.shape
    rows = np.zeros(0, np.int64) if rows is None else np.asarray(rows, np.int64).ravel()
    if mask is not None:
        mask.check(b.shape)
        b = np.where(mask.mask, 0, b).astype(np.uint8)
        near_mask = np.zeros((h, w), np.bool_)
        near_mask[mask.seed_v, mask.seed_u] = True
    contours, _ = cv2.findContours(b, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    on_row = np.zeros(h, np.bool_)
    on_row[rows] = True
    keep = []
    for c in contours:
        p = c.reshape(-1, 2)
        u, v = p[:, 0], p[:, 1]
        hit = (u.min() == 0 or v.min() == 0 or u.max() == w - 1 or v.max() == h - 1
               or on_row[v].any() or (mask is not None and near_mask[v, u].any()))
        if hit:
            keep.append(p.astype(np.int32))
    lens = np.array([len(p) for p in keep], np.int64)
    offs = np.concatenate(([0], np.cumsum(lens))).astype(np.int64)
    pts = np.concatenate(keep) if keep else np.zeros((0, 2), np.int32)
    return Borders(pts, offs, np.full(len(keep), -1, np.int8), rows, (h, w))
