"""Exposure-invariant horizon edge: the limb located at a fixed fraction of its own peak
brightness (003 §4, 004 §3.4.3: the threshold edge moves with the exposure).

Physics
-------
A ray that misses the Earth at tangent height h_t sees single-scattered sunlight from an air mass
``m(h_t) = 2 sqrt(pi R / 2H) exp(-h_t / H)`` (scale height H ~ 8 km), i.e. a radiance

    B(h_t) = E P(gamma) (1 - exp(-tau m(h_t))) T_sun                                       (1)

with E the exposure (radiance -> full scale) and P the phase function at the scattering angle
gamma to the Sun. Above the knee (tau m << 1, h_t >~ 25 km) B falls off as exp(-h_t / H); below it
the limb saturates optically (tau m >~ 1, h_t ~ 15-20 km): B has a maximum ("the bright limb")
at a height fixed by tau and H alone. A binarisation threshold B_thr cuts the exponential part at

    h_thr = H ln(E P tau 2 sqrt(pi R / 2H) T_sun / B_thr)                                  (2)

which moves by H ln(ratio) with the exposure (8 km for a factor e) and along the limb with P:
this is the 33-55 km spread of the effective atmosphere thickness d (003 eq. (5)) measured on
rendered frames. The exposure E and the phase P *multiply* (1); the height where B crosses a fixed
*fraction* f of its local maximum, B(h_f) = f max B, therefore does not depend on either:

    h_f = fixed by (tau, H, f) alone                                                        (3)

Only the local profile is needed, so this is done on the edge pixels only: at each edge pixel the
brightness is sampled (bilinear) along the image-space normal of the fitted cone, from a few pixels
in space to ``search_px`` pixels towards the body, linearised with the tone curve (``gamma``),
the background (space side) subtracted, the first maximum scanning inwards found, and the edge
moved to the sub-pixel crossing of ``bg + f (peak - bg)`` on the space side of that maximum.

A profile cannot be used when (a) its maximum is clipped (sensor saturation hides the knee: then
only the exponential tail is seen, which is translation-invariant, and no exposure-invariant
height exists), (b) the Earth's surface merges with the limb without a dip (same), or (c) the
Sun is low at the tangent point: the sunlight reaching the lower limb is then dimmed by the lower
atmosphere, more so the lower it goes, and the maximum moves up (below the terminator it is the
shadow edge, not the optical knee). (a), (b) are detected on the profile; (c) needs the Sun direction: `sun_elevation`
gives the Sun elevation at each limb tangent point; low-Sun points are not used.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from vision.camera import FisheyeCamera, project, unproject

__all__ = ["LimbEdgeConfig", "limb_edge_points", "sun_elevation"]


@dataclass(frozen=True)
class LimbEdgeConfig:
    """Fraction-of-peak limb edge (module docstring).

    fraction : f of eq. (3), in (0, 1): the crossing of ``bg + f (peak - bg)`` (linear units).
    channel : colour channel of the decoded frame used for the profile (cv2 decodes BGR: 2 = red,
        the channel least likely to be clipped on the blue limb); -1 = mean of the channels.
    gamma : exponent of the camera tone curve (value/255)^gamma -> linear.
    search_px : profile length towards the body [px].
    space_px : profile length towards space [px] (background).
    clip_level : a maximum at or above this 8-bit value counts as clipped (a).
    min_drop : the maximum must be followed by a drop to below (1 - min_drop) of it within the
        profile (in linear units), else the surface merges with the limb (b).
    """

    fraction: float = 0.5
    channel: int = 2
    gamma: float = 2.2
    search_px: int = 60
    space_px: int = 6
    clip_level: float = 250.0
    min_drop: float = 0.15

    def __post_init__(self):
        if not 0.0 < self.fraction < 1.0:
            raise ValueError(f"LimbEdgeConfig.fraction = {self.fraction}; expected in (0, 1)")
        if self.channel not in (-1, 0, 1, 2):
            raise ValueError(f"LimbEdgeConfig.channel = {self.channel}; expected -1 (mean), 0, 1 or 2")
        if not (math.isfinite(self.gamma) and self.gamma > 0):
            raise ValueError(f"LimbEdgeConfig.gamma = {self.gamma}; expected > 0")
        if not (isinstance(self.search_px, int) and self.search_px >= 4 and isinstance(self.space_px, int)
                and self.space_px >= 2):
            raise ValueError(f"LimbEdgeConfig.search_px / space_px = {self.search_px} / {self.space_px}; "
                             f"expected integers >= 4 / >= 2")
        if not 0.0 < self.min_drop < 1.0:
            raise ValueError(f"LimbEdgeConfig.min_drop = {self.min_drop}; expected in (0, 1)")


def _plane(image: np.ndarray, channel: int) -> np.ndarray:
    if image.ndim == 2:
        return image.astype(np.float32)
    if channel < 0:
        return image.mean(axis=2, dtype=np.float32)
    return image[..., channel].astype(np.float32)


def limb_edge_points(image: np.ndarray, camera: FisheyeCamera, uv: np.ndarray, rays_c: np.ndarray,
                     e_c: np.ndarray, pixel_angle: np.ndarray, config: LimbEdgeConfig
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move threshold-edge pixels to the fraction-of-peak crossing of the limb profile.

    Parameters
    ----------
    image : decoded frame (H, W, 3) or (H, W), uint8.
    uv : (m, 2) edge pixels; rays_c : (m, 3) their unit rays; e_c : (3,) the body direction of a
        first fit (only the direction *towards* the body matters); pixel_angle : (m,) [rad/px].

    Returns
    -------
    uv_new (m, 2), rays_new (m, 3) and ok (m,) bool: profiles that were usable (not clipped, with a
    drop after the maximum, inside the image, a crossing found).
    """
    uv = np.asarray(uv, dtype=float)
    m = uv.shape[0]
    plane = _plane(image, config.channel)
    e = np.asarray(e_c, dtype=float)
    t = e[None, :] - (rays_c @ e)[:, None] * rays_c
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
    pa = np.asarray(pixel_angle, dtype=float)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        q1 = project(camera, np.cos(pa) * rays_c + np.sin(pa) * t)
    n = q1 - uv
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    s = np.arange(-config.space_px, config.search_px + 1, dtype=float)
    Q = uv[:, None, :] + s[None, :, None] * n[:, None, :]
    Q = np.nan_to_num(Q, nan=-10.0).astype(np.float32)
    v = cv2.remap(plane, Q[..., 0], Q[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                  borderValue=-1.0)
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
    # index of the maximum before the stop: the first index reaching the running max at stop
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
    uv_new = uv + np.where(ok, sc, 0.0)[:, None] * n
    rays_new = rays_c.copy()
    if np.any(ok):
        rays_new[ok] = unproject(camera, uv_new[ok])
        ok &= np.all(np.isfinite(rays_new), axis=1)
    return uv_new, rays_new, ok


def sun_elevation(rays_e: np.ndarray, x_e: np.ndarray, sun_e: np.ndarray) -> np.ndarray:
    """Elevation [rad] of the Sun above the local horizontal at the tangent point of each ray
    (e frame, geocentric vertical; the ellipsoid's ~0.2 deg deflection does not matter here).

    Where it is low the sunlight that reaches the lower limb has crossed the lower atmosphere
    itself: it is attenuated by ``exp(-tau m_s(h))`` with an air mass ``m_s ~ exp(-h/H) / sin(el)``
    that grows *downwards*, so the limb's maximum moves up and with it the fraction-of-peak
    height (below the terminator the maximum is the shadow edge). That factor is not a constant
    multiplier along the profile, so eq. (3) of the module docstring does not hold there: such
    limb points are not used."""
    x = np.asarray(x_e, dtype=float)
    r = np.asarray(rays_e, dtype=float)
    s = np.asarray(sun_e, dtype=float)
    s = s / np.linalg.norm(s)
    tc = -(r @ x)
    T = x[None, :] + tc[:, None] * r
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    return np.arcsin(np.clip(T @ s, -1.0, 1.0))
