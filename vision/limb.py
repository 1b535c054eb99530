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

A profile cannot be used when (a) its maximum is clipped (sensor saturation hides the peak; the
height then comes from the shape of its unsaturated flank instead, `flank_heights`), (b) the
Earth's surface merges with the limb without a dip, or (c) the
Sun is low at the tangent point: the sunlight reaching the lower limb is then dimmed by the lower
atmosphere, more so the lower it goes, and the maximum moves up (below the terminator it is the
shadow edge, not the optical knee). (a), (b) are detected on the profile; (c) needs the Sun direction: `sun_elevation`
gives the Sun elevation at each limb tangent point (geodetic vertical).

Sun path (c) as a model rather than a cut-off
---------------------------------------------
The maximum of the profile exists *because* the sunlight reaching height h has itself crossed
the air mass ``m_s(h) = Ch(mu_s) exp(-h/H)`` (mu_s = sine of the Sun elevation at the tangent
point, Ch the Chapman function), so (1) is really

    B(h) = E P T_0 (1 - exp(-u)) exp(-c u),   u = tau m(h),   c = m_s / m                 (4)

with c independent of h (`sun_path_ratio`; twilight: ``m_s = C exp(-hs/H) (1 + erf(|mu_s|
sqrt(R/2H)))``, hs = h - R mu_s^2/2 the height of the sunray's lowest point).
The crossing of ``f max B`` on the space side of the maximum ``u* = ln((1 + c)/c)`` is a number
``u_f(c)`` that depends on f and c only, hence

    h_f(mu_s) = H ln(tau 2C) - H ln u_f(c(mu_s)) = h_f(1) - H ln(u_f(c(mu_s)) / u_f(c(1)))     (5)

(`fraction_height_shift`): exposure, phase function and tau still drop out of the *shift*; only
H enters. It agrees with the renderer's 1-D limb radiance to < 50 m (tests/test_limb_sun_path.py)
and with the tangent heights of the fraction-of-peak edge on rendered frames to 0.2-0.7 km for
Sun elevations of 3..30 deg; below ~3 deg it lies 1..7 km low.

Sun elevation down the profile (twilight)
-----------------------------------------
c is not constant along a profile: the profile of one edge pixel runs down through tangent
points that move along the line of sight (~3 km of ground per km of tangent height), so the Sun
elevation at the tangent point changes down the profile, ``mu(h) = mu_s + (dmu/dh) (h - h_f)``.
Near the terminator c changes by ``exp(R mu dmu / H)`` over the profile, which moves its maximum
and the crossing by kilometres. `profile_height_shift` finds the crossing on (4) with that mu(h)
and the Earth's shadow by the detector's rules; tau, which then no longer cancels, follows from
the overhead-Sun height h_f(1) by (5). On rendered twilight frames the tangent heights of the
crossings then agree with it to 0.1-0.3 km per frame (eq. (5) alone: 1-3.5 km; docs/vision.md).
With it no measured twilight correction is needed (`vision.config.LimbOptions.twilight_el_deg`
and ``twilight_dh_m`` hold one when wanted; empty by default).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

from nav import earth as _earth
from vision.camera import Camera, project, unproject, unproject_jacobian
from vision.nadir import per_ray

_EARTH_A, _EARTH_B = _earth.A, _earth.B

__all__ = ["LimbEdgeConfig", "limb_edge_points", "sun_elevation", "sun_path_ratio", "fraction_height_shift",
           "profile_height_shift", "flank_rise_height", "surface_ratio", "resolved_sun_sine", "tangent_height_sun", "flank_heights", "phase_function", "phase_slope",
           "turn_towards"]


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


def _bilinear(image: np.ndarray, channel: int, qx: np.ndarray, qy: np.ndarray) -> np.ndarray:
    """Bilinear samples (float32) of one channel (-1: mean of the channels) of a uint8 frame at
    the points (qx, qy): the arithmetic of ``cv2.remap(plane, qx, qy, INTER_LINEAR,
    BORDER_CONSTANT, -1)`` on the float32 plane (exact bilinear weights; neighbours outside the
    image count as -1; equal to it to float32 round-off, tests/test_limb.py), gathered from the
    four neighbours of each sample only instead of converting the whole frame to float32 first
    (a limb has ~3e4 samples, a 1920 x 1080 frame 2e6 pixels)."""
    img = image if image.ndim == 3 else image[:, :, None]
    ch = -1 if (channel < 0 and img.shape[2] > 1) else (0 if img.shape[2] == 1 else channel)
    out = np.empty(qx.shape, dtype=np.float32)
    _bilinear_kernel(img, ch, np.ascontiguousarray(qx, dtype=np.float32).reshape(-1),
                     np.ascontiguousarray(qy, dtype=np.float32).reshape(-1), out.reshape(-1))
    return out


@numba.njit(cache=True)
def _bilinear1(img, ch, x, y):
    """One bilinear sample at (x, y) (float32 coordinates) of `_bilinear`: the four neighbours'
    weights in float64, neighbours outside the image count as -1, -1 far outside."""
    h, w, nc = img.shape
    if not (x > -2.0 and y > -2.0 and x < w + 1.0 and y < h + 1.0):
        return -1.0
    x0 = int(math.floor(x))
    y0 = int(math.floor(y))
    fx = x - x0
    fy = y - y0
    acc = 0.0
    for dy in range(2):
        wy = fy if dy else 1.0 - fy
        yy = y0 + dy
        for dx in range(2):
            wx = fx if dx else 1.0 - fx
            xx = x0 + dx
            if yy < 0 or yy >= h or xx < 0 or xx >= w:
                p = -1.0
            elif ch >= 0:
                p = float(img[yy, xx, ch])
            else:
                p = 0.0
                for c in range(nc):
                    p += float(img[yy, xx, c])
                p /= nc
            acc += wy * wx * p
    return acc


@numba.njit(cache=True)
def _bilinear_inside(img, ch, x, y):
    """`_bilinear1` for a point whose four neighbours are inside the image and a channel ch >= 0:
    the same products in the same order, without the bounds and channel branches, and int() for
    floor() (x, y >= 0 here), which is cheaper."""
    x0 = int(x)
    y0 = int(y)
    fx = x - x0
    fy = y - y0
    wx0 = 1.0 - fx
    wy0 = 1.0 - fy
    acc = 0.0
    acc += wy0 * wx0 * float(img[y0, x0, ch])
    acc += wy0 * fx * float(img[y0, x0 + 1, ch])
    acc += fy * wx0 * float(img[y0 + 1, x0, ch])
    acc += fy * fx * float(img[y0 + 1, x0 + 1, ch])
    return acc


@numba.njit(cache=True)
def _sample_inside(img, ch, u, v, s, nx, ny):
    """Clipped profile sample at ``(u, v) + s (nx, ny)`` whose neighbours are inside the image
    (`_bilinear_inside`; finite n, so no NaN coordinate)."""
    val = np.float32(_bilinear_inside(img, ch, np.float32(u + s * nx), np.float32(v + s * ny)))
    return min(max(val, np.float32(0.0)), np.float32(255.0))


@numba.njit(cache=True)
def _bilinear_kernel(img, ch, qx, qy, out):
    for i in range(qx.size):
        out[i] = _bilinear1(img, ch, qx[i], qy[i])


@numba.njit(cache=True, error_model="numpy")
def _tone(c, gamma):
    """Tone curve of a clipped float32 sample: ``(c / 255)^gamma`` in float32 arithmetic (as the
    numpy expression ``(np.clip(v, 0, 255) * (1 / 255)) ** gamma`` on a float32 array)."""
    return (c * np.float32(1.0 / 255.0)) ** gamma


@numba.njit(cache=True)
def _q32(u, s, n):
    """Profile coordinate ``float32(u + s n)`` (NaN -> -10: outside, as np.nan_to_num(nan=-10))."""
    q = u + s * n
    return np.float32(-10.0) if math.isnan(q) else np.float32(q)


@numba.njit(cache=True, error_model="numpy")
def _limb_profiles(img, ch, uv, nrm, s, i0, gamma, fraction, keep, clip, root_keep, slope, upper):
    """Fraction-of-peak crossing of every limb profile (`limb_edge_points`), one pass per profile.

    The profile of edge pixel i is sampled (`_bilinear1`) at ``uv_i + s_k n_i``. The steps are
    those of the array version (module docstring): background ``bg`` = min of the space samples
    (k <= i0), scan inwards from i0 to the first sample below ``keep`` (= 1 - min_drop) times the
    running maximum (the stop; none: unusable), ``peak`` = the maximum before it, ``jpk`` its first
    index, the last sample before jpk below ``tgt = bg + fraction (peak - bg)``, and the linear
    crossing between it and the next one. Why a kernel: the array version evaluates the tone curve
    (a float32 power) on all ~34 000 samples of a 512-pixel limb in ~30 array passes; here samples
    are taken only up to the stop (all of them only when the profile's end points are not
    safely inside the image, where the "inside" test needs every sample) and, the tone curve
    being monotone, the running maximum, the background and most of the drop tests use the
    clipped 8-bit-scale values: the power is evaluated at the background, the peak, the crossing
    samples and a drop test within 0.1 % of its bound only (float32 power: results equal to the
    array version to its 1-ulp rounding). Returns the crossing offset sc (m,) [px along n_i],
    ok (m,): inside the image, a drop after the peak, a crossing found, peak below ``clip``,
    peak above bg + 1e-6 (all in float32 as the array version), and rise (m,) [px]: from the
    crossing to the first crossing of ``bg + upper (peak - bg)`` towards the peak (the rise of
    the profile's flank, `limb_edge_points`; NaN where not ok). ``s`` is uniformly spaced
    (``np.arange``). ``slope`` (m,): d ln P / ds of
    the phase function along each profile [1/px] (`phase_slope`): the samples are divided by
    ``exp(slope s)`` (``exp(slope s / gamma)`` on the 8-bit scale) before the scan, the clip test
    stays on the raw samples; 0: the samples as they are."""
    m = uv.shape[0]
    S = s.shape[0]
    sc = np.zeros(m)
    ok = np.zeros(m, np.bool_)
    rise = np.full(m, np.nan)
    c = np.empty(S, np.float32)          # clipped samples, 0..taken-1 (phase-corrected)
    f = np.empty(S, np.float32)          # their phase factors
    for i in range(m):
        u, v, nx, ny = uv[i, 0], uv[i, 1], nrm[i, 0], nrm[i, 1]
        if not (math.isfinite(nx) and math.isfinite(ny)):
            continue
        b = slope[i] / gamma
        # exp(-b s_k) by its recurrence over the uniform steps of s (one exp per profile: ~40 %
        # of the kernel's time with an exp per sample; 67 products keep float64 to ~1e-14); f[k]
        # is set as sample k is taken (in order of k; most profiles stop well before the end)
        fk = math.exp(-b * s[0])
        rk = math.exp(-b * (s[1] - s[0])) if S > 1 else 1.0
        taken, fk = _take_space_samples(img, ch, u, v, nx, ny, s, i0, c, f, fk, rk)
        if taken < 0:
            continue
        stop, vmax, cmin = _scan_to_drop(img, ch, u, v, nx, ny, s, i0, c, f, fk, rk, taken, gamma, keep,
                                         root_keep)
        if stop < 0:
            continue                      # no drop after the maximum: surface merges with the limb
        sc[i], ok[i], rise[i] = _crossing(c, f, s, i0, stop, vmax, cmin, gamma, fraction, clip, upper)
    return sc, ok, rise


@numba.njit(cache=True, error_model="numpy")
def _take_space_samples(img, ch, u, v, nx, ny, s, i0, c, f, fk, rk):
    """Samples 0..i0 (space) of one profile of `_limb_profiles` into c (phase-corrected, clipped
    to 255) and their phase factors into f, fk the running factor (times rk per step). Profiles
    whose end points are not safely inside the image, or the channel mean (ch < 0), take all
    samples with the general `_bilinear1` (every sample decides "inside"). Returns (samples
    taken, fk), taken = -1 when a sample is outside the image."""
    S = s.shape[0]
    h, w, _ = img.shape
    xa, ya = _q32(u, s[0], nx), _q32(v, s[0], ny)
    xb, yb = _q32(u, s[S - 1], nx), _q32(v, s[S - 1], ny)
    safe = (0.5 <= xa <= w - 1.5 and 0.5 <= xb <= w - 1.5 and 0.5 <= ya <= h - 1.5
            and 0.5 <= yb <= h - 1.5)
    taken = 0
    if not (safe and ch >= 0):
        for k in range(S):
            val = np.float32(_bilinear1(img, ch, _q32(u, s[k], nx), _q32(v, s[k], ny)))
            if not val >= 0.0:
                return -1, fk
            f[k] = np.float32(fk)
            fk *= rk
            c[k] = min(val, np.float32(255.0)) * f[k]
        taken = S
    for k in range(taken, i0 + 1):
        f[k] = np.float32(fk)
        fk *= rk
        c[k] = _sample_inside(img, ch, u, v, s[k], nx, ny) * f[k]
    return max(taken, i0 + 1), fk


@numba.njit(cache=True, error_model="numpy")
def _scan_to_drop(img, ch, u, v, nx, ny, s, i0, c, f, fk, rk, taken, gamma, keep, root_keep):
    """Inward scan of one profile of `_limb_profiles` from i0: running maximum (clipped samples),
    first sample below ``keep`` times it in tone-curve units (the tone evaluated only within 0.1 %
    of the bound ``root_keep`` times the maximum), samples taken as needed. Returns (stop index or
    -1, maximum, background = min of the space samples 0..i0)."""
    S = s.shape[0]
    lo_m, hi_m = 1.0 - 1e-3, 1.0 + 1e-3
    cmin = c[0]
    for k in range(1, i0 + 1):
        cmin = min(cmin, c[k])
    vmax = c[i0]
    L_max = np.float32(-1.0)   # tone of vmax, when evaluated
    bound = vmax * root_keep
    for k in range(i0, S):
        if k >= taken:
            f[k] = np.float32(fk)
            fk *= rk
            c[k] = _sample_inside(img, ch, u, v, s[k], nx, ny) * f[k]
            taken = k + 1
        ck = c[k]
        if ck > vmax:
            vmax = ck
            L_max = np.float32(-1.0)
            bound = vmax * root_keep
            continue
        if ck < bound * lo_m:
            return k, vmax, cmin
        if ck > bound * hi_m:
            continue
        if L_max < 0.0:
            L_max = _tone(vmax, gamma)
        if _tone(ck, gamma) < keep * L_max:
            return k, vmax, cmin
    return -1, vmax, cmin


@numba.njit(cache=True, error_model="numpy")
def _crossing(c, f, s, i0, stop, vmax, cmin, gamma, fraction, clip, upper):
    """Fraction-of-peak crossing of one scanned profile of `_limb_profiles`: (offset sc [px along
    the normal], ok, rise [px] from it to the ``upper``-of-peak level). Not ok when the raw peak
    is clipped, the peak is not above the background, or no sample before the peak lies below
    the target level."""
    S = s.shape[0]
    eps = np.float32(1e-6)
    lo_m, hi_m = 1.0 - 1e-3, 1.0 + 1e-3
    peak = _tone(vmax, gamma)
    bg = _tone(cmin, gamma)
    raw = np.float32(0.0)              # the clip test on the raw samples
    for k in range(i0, stop + 1):
        raw = max(raw, c[k] / f[k])
    if not (_tone(raw, gamma) < clip and peak > bg + eps):
        return 0.0, False, np.nan
    jpk = -1
    for k in range(i0, stop + 1):
        if c[k] >= vmax * lo_m and _tone(c[k], gamma) >= peak:
            jpk = k
            break
    tgt = bg + fraction * (peak - bg)
    a = -1
    t_raw = 255.0 * float(tgt) ** (1.0 / float(gamma))    # tgt on the clipped-sample scale
    for k in range(jpk - 1, -1, -1):
        if c[k] > t_raw * hi_m:
            continue
        if c[k] < t_raw * lo_m or _tone(c[k], gamma) < tgt:
            a = k
            break
    if a < 0:
        return 0.0, False, np.nan
    a = min(a, S - 2)
    if not a + 1 <= jpk:
        return 0.0, False, np.nan
    La, Lb = _tone(c[a], gamma), _tone(c[a + 1], gamma)
    frac = (tgt - La) / (Lb - La)
    frac = min(max(frac, np.float32(0.0)), np.float32(1.0))
    sc = s[a] + frac
    return sc, True, _level_after(c, s, a + 1, jpk, gamma, bg + upper * (peak - bg)) - sc


@numba.njit(cache=True, error_model="numpy")
def _level_after(c, s, k0, jpk, gamma, level):
    """Offset [px] of the first crossing of ``level`` (tone-curve units) by the samples k0..jpk of a
    scanned profile, linear between samples (the peak's offset when none before it)."""
    prev = _tone(c[k0 - 1], gamma)
    for k in range(k0, jpk + 1):
        cur = _tone(c[k], gamma)
        if cur >= level:
            fr = (level - prev) / (cur - prev) if cur > prev else 1.0
            return s[k - 1] + min(max(fr, 0.0), 1.0)
        prev = cur
    return s[jpk]


def _profile_crossings(image, uv, n, s, config: LimbEdgeConfig, slope=None, upper: float = 0.8):
    """(sc, ok, rise) of every profile: `_limb_profiles` with the configuration's constants."""
    img = image if image.ndim == 3 else image[:, :, None]
    ch = -1 if (config.channel < 0 and img.shape[2] > 1) else (0 if img.shape[2] == 1 else config.channel)
    return _limb_profiles(img, ch, np.ascontiguousarray(uv, dtype=float), np.ascontiguousarray(n, dtype=float),
                          s, config.space_px, np.float32(config.gamma), np.float32(config.fraction),
                          np.float32(1.0 - config.min_drop), np.float32((config.clip_level / 255.0) ** config.gamma),
                          float((1.0 - config.min_drop) ** (1.0 / config.gamma)),
                          np.zeros(len(uv)) if slope is None else np.ascontiguousarray(slope, dtype=float),
                          np.float32(upper))


def phase_function(cos_g, aerosol_weight: float = 0.0, aerosol_g: float = 0.75) -> np.ndarray:
    """Scattering phase function of the limb (up to a constant): Rayleigh ``3/4 (1 + cos^2 g)``
    and a Henyey-Greenstein aerosol lobe ``(1 - g^2) / (1 + g^2 - 2 g cos)^(3/2)`` weighted by
    ``aerosol_weight`` (the renderer's atmosphere, `scenarios.sim.render`)."""
    c = np.asarray(cos_g, dtype=float)
    return _phase(c, float(aerosol_weight), float(aerosol_g))


def phase_slope(rays_c: np.ndarray, e_c: np.ndarray, pixel_angle: np.ndarray, sun_c: np.ndarray,
                aerosol_weight: float = 0.0, aerosol_g: float = 0.75) -> np.ndarray:
    """d ln P / ds [1/px] along each limb profile (towards the body e_c, one pixel angle per px):
    the phase function P of eq. (1) at the scattering angle to the Sun ``sun_c`` (camera frame)
    changes down the profile, most near the Sun (the aerosol lobe: ~9 % per degree at 20 deg),
    which shifts the profile's maximum against its crossing (eq. (3) holds for a factor that is
    constant along the profile only). Measured on rendered frames near the Sun: 0.04-0.06 deg of
    nadir (docs/vision.md)."""
    s = np.asarray(sun_c, dtype=float)
    s = s / np.linalg.norm(s)
    r = np.ascontiguousarray(rays_c, dtype=float).reshape(-1, 3)
    pa = per_ray(pixel_angle, r.shape[0])
    out = np.empty(r.shape[0])
    _phase_slope_kernel(r, np.asarray(e_c, dtype=float), pa, s, float(aerosol_weight),
                        float(aerosol_g), out)
    return out


@numba.njit(cache=True)
def _phase(c, w, g):
    """`phase_function` (a cosine or an array of them)."""
    return (1.0 - w) * 0.75 * (1.0 + c * c) + w * (1.0 - g * g) / (1.0 + g * g - 2.0 * g * c) ** 1.5


@numba.njit(cache=True)
def _phase_slope_kernel(rays, e, pa, s, w, g, out):
    """`phase_slope` per ray: the ray turned by 10 pixel angles towards e (`_turn1`; 10 px:
    crossing to peak), ln P there minus ln P at the ray, per pixel."""
    for i in range(rays.shape[0]):
        r0, r1, r2 = rays[i, 0], rays[i, 1], rays[i, 2]
        q0, q1, q2 = _turn1(r0, r1, r2, e, 10.0 * pa[i])
        c_t = q0 * s[0] + q1 * s[1] + q2 * s[2]
        c_r = r0 * s[0] + r1 * s[1] + r2 * s[2]
        out[i] = (math.log(_phase(c_t, w, g)) - math.log(_phase(c_r, w, g))) / 10.0


def turn_towards(rays: np.ndarray, e: np.ndarray, angle) -> np.ndarray:
    """Unit rays (m, 3) turned by ``angle`` [rad] (scalar or (m,)) towards the direction e, each
    along its great circle through e."""
    r = np.ascontiguousarray(rays, dtype=float).reshape(-1, 3)
    a = per_ray(angle, r.shape[0])
    out = np.empty_like(r)
    _turn_kernel(r, np.asarray(e, dtype=float), a, out)
    return out


@numba.njit(cache=True)
def _turn1(r0, r1, r2, e, a):
    """One unit ray turned by ``a`` towards e (`turn_towards`): ``cos a r + sin a t``, t the unit
    tangent towards e."""
    d = r0 * e[0] + r1 * e[1] + r2 * e[2]
    t0, t1, t2 = e[0] - d * r0, e[1] - d * r1, e[2] - d * r2
    tn = max(math.sqrt(t0 * t0 + t1 * t1 + t2 * t2), 1e-300)
    ca, sa = math.cos(a), math.sin(a)
    return ca * r0 + sa * (t0 / tn), ca * r1 + sa * (t1 / tn), ca * r2 + sa * (t2 / tn)


@numba.njit(cache=True)
def _turn_kernel(rays, e, a, out):
    for i in range(rays.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _turn1(rays[i, 0], rays[i, 1], rays[i, 2], e, a[i])


def _profile_normals(camera: Camera, uv: np.ndarray, rays_c: np.ndarray, e_c: np.ndarray,
                     pixel_angle: np.ndarray) -> np.ndarray:
    """(m, 2) unit image directions of the limb profiles: from each edge pixel towards the body
    e_c (the image of the ray turned by one pixel angle towards it)."""
    q1 = project(camera, turn_towards(rays_c, e_c, pixel_angle))
    return _unit_differences(q1, np.ascontiguousarray(uv, dtype=float))


@numba.njit(cache=True)
def _unit_differences(q, p):  # pragma: no cover - numba
    """Rows (q - p) / max(|q - p|, 1e-300) of (m, 2) arrays (NaN rows stay NaN)."""
    out = np.empty_like(q)
    for i in range(q.shape[0]):
        dx, dy = q[i, 0] - p[i, 0], q[i, 1] - p[i, 1]
        nn = max(math.sqrt(dx * dx + dy * dy), 1e-300)
        out[i, 0], out[i, 1] = dx / nn, dy / nn
    return out


def limb_edge_points(image: np.ndarray, camera: Camera, uv: np.ndarray, rays_c: np.ndarray,
                     e_c: np.ndarray, pixel_angle: np.ndarray, config: LimbEdgeConfig,
                     jacobian: bool = False, phase_slope: np.ndarray | None = None, rise_level: float = 0.0):
    """Move threshold-edge pixels to the fraction-of-peak crossing of the limb profile.

    Parameters
    ----------
    image : decoded frame (H, W, 3) or (H, W), uint8.
    uv : (m, 2) edge pixels; rays_c : (m, 3) their unit rays; e_c : (3,) the body direction of a
        first fit (only the direction *towards* the body matters); pixel_angle : (m,) [rad/px].

    jacobian : also return the (m, 3, 2) Jacobian d ray / d uv of the moved pixels
        (`vision.camera.unproject_jacobian`, computed with the rays in one call; NaN where not ok).
    phase_slope : (m,) d ln P / ds [1/px] of the scattering phase function along each profile
        (`phase_slope`); the profile is divided by it before the peak and the crossing are taken.
    rise_level : in (fraction, 1): also return the (m,) rise [px] of each profile from its crossing
        to the crossing of ``bg + rise_level (peak - bg)`` towards the peak (NaN where not ok):
        the width of the flank, which eq. (4) predicts (`flank_rise_height`).

    Returns
    -------
    uv_new (m, 2), rays_new (m, 3) and ok (m,) bool: profiles that were usable (not clipped, with a
    drop after the maximum, inside the image, a crossing found); with ``jacobian`` also J_new, with
    ``rise_level`` also the rise.
    """
    if rise_level and not config.fraction < rise_level < 1.0:
        raise ValueError(f"limb_edge_points: rise_level = {rise_level}; expected 0 (none) or a level in "
                         f"(fraction = {config.fraction}, 1)")
    uv = np.asarray(uv, dtype=float)
    m = uv.shape[0]
    n = _profile_normals(camera, uv, rays_c, e_c, pixel_angle)
    s = np.arange(-config.space_px, config.search_px + 1, dtype=float)
    sc, ok, rise = _profile_crossings(image, uv, n, s, config, phase_slope, rise_level or 0.8)
    uv_new = uv + np.where(ok, sc, 0.0)[:, None] * n
    rays_new = rays_c.copy()
    J_new = np.full((m, 3, 2), np.nan) if jacobian else None
    if ok.any():
        if jacobian:
            rays_new[ok], J_new[ok] = unproject_jacobian(camera, uv_new[ok])
        else:
            rays_new[ok] = unproject(camera, uv_new[ok])
        ok &= np.isfinite(rays_new).all(axis=1)
    out = (uv_new, rays_new, ok, J_new) if jacobian else (uv_new, rays_new, ok)
    return out + (rise,) if rise_level else out


@numba.njit(cache=True)
def _tangent_kernel(rays, x, s, a, b, h_out, mu_out):
    """Per ray: the tangent point in the scaled space ``diag(1, 1, a/b)`` (where the ellipsoid is
    the sphere of radius a), its height ``(|T'| - a) |T| / |T'|`` (`scenarios.sim.render.ray_ellipsoid`'s
    h_t: the scaled-sphere height times the local radius over a), and the sine of the Sun elevation
    above the geodetic horizon there (normal ``(x/a^2, y/a^2, z/b^2)``)."""
    q = a / b
    xs0, xs1, xs2 = x[0], x[1], x[2] * q
    for i in range(rays.shape[0]):
        r0, r1, r2 = rays[i, 0], rays[i, 1], rays[i, 2] * q
        rn = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        r0 /= rn
        r1 /= rn
        r2 /= rn
        tc = -(r0 * xs0 + r1 * xs1 + r2 * xs2)
        p0, p1, p2 = xs0 + tc * r0, xs1 + tc * r1, xs2 + tc * r2      # tangent point, scaled
        rho = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        T2 = p2 / q                                                # tangent point in e
        rloc = math.sqrt(p0 * p0 + p1 * p1 + T2 * T2)
        h_out[i] = (rho - a) * rloc / rho
        n0, n1, n2 = p0, p1, T2 * q * q                            # (x, y, z a^2/b^2) ~ normal
        nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        mu_out[i] = min(1.0, max(-1.0, (n0 * s[0] + n1 * s[1] + n2 * s[2]) / nn))


def tangent_height_sun(rays_e: np.ndarray, x_e: np.ndarray, sun_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent height [m] above the WGS-84 ellipsoid of each ray and the sine ``mu_s`` of the Sun
    elevation above the local (geodetic) horizon at its tangent point (rays_e (m, 3) unit rays from
    x_e, e frame; sun_e: the Sun's direction or position in e).

    The tangent point is the ray's closest approach to the ellipsoid, found in the scaled space
    ``S = diag(1, 1, a/b)`` where the ellipsoid is the sphere of radius a (`vision.oblate`); the
    vertical there is the ellipsoid normal ``(x/a^2, y/a^2, z/b^2)``. The geocentric vertical
    differs by up to 0.19 deg, which matters near the terminator: the Sun-path factor of
    `fraction_height_shift` changes by ~R mu / H ~ 800 per unit of mu there (module docstring)."""
    r = np.ascontiguousarray(rays_e, dtype=float).reshape(-1, 3)
    s = np.asarray(sun_e, dtype=float)
    s = s / np.linalg.norm(s)
    h = np.empty(r.shape[0])
    mu = np.empty(r.shape[0])
    _tangent_kernel(r, np.asarray(x_e, dtype=float), s, _EARTH_A, _EARTH_B, h, mu)
    return h, mu


def sun_elevation(rays_e: np.ndarray, x_e: np.ndarray, sun_e: np.ndarray) -> np.ndarray:
    """Elevation [rad] of the Sun above the local horizontal at the tangent point of each ray
    (rays_e (m, 3) unit rays from x_e, e frame; geodetic vertical of the WGS-84 ellipsoid):
    `tangent_height_sun`.

    Where the Sun is low the sunlight that reaches the lower limb has crossed the lower
    atmosphere itself: it is attenuated by ``exp(-tau m_s(h))`` (module docstring, eq. (4))."""
    return np.arcsin(tangent_height_sun(rays_e, x_e, sun_e)[1])


def sun_path_ratio(mu_s: np.ndarray, scale_height_m: float = 8000.0,
                   radius_m: float = 6371e3) -> np.ndarray:
    """c = m_s / m of eq. (4): air mass of the sunlight reaching the limb at height h over the
    air mass of the line of sight at tangent height h; constant along a profile.

    ``m(h) = 2 C exp(-h/H)`` with ``C = sqrt(pi R / 2H)`` (the grazing Chapman air mass of one
    half of the path). Sun above the local horizon (mu_s = sin(elevation) >= 0): the Chapman
    function is approximated by ``Ch(mu) = 1 / sqrt(mu^2 + 1/C^2)`` (1/mu overhead, C at grazing
    incidence), ``m_s = Ch(mu_s) exp(-h/H)``. Sun below it (twilight): the sunray through the
    point passed its lowest point, at ``hs = h - R mu_s^2 / 2``, a distance ``R |mu_s|`` before
    it; along the ray the height is ``hs + x^2 / 2R``, so ``m_s = C exp(-hs/H) (1 + erf(|mu_s|
    sqrt(R / 2H)))``: the Sun-side half of the grazing path plus the part up to the point
    (continuous at mu_s = 0; 2C exp(-hs/H) deep in twilight; below ``h = R mu_s^2/2`` the point is
    in the Earth's shadow)."""
    mu = np.asarray(mu_s, dtype=float)
    out = np.empty(mu.shape)
    _sun_path_ratio_kernel(np.ascontiguousarray(mu.reshape(-1)), float(scale_height_m), float(radius_m),
                           out.reshape(-1))
    return out


@numba.njit(cache=True)
def _sun_path_ratio1(m, H, R):
    """`sun_path_ratio` of one mu_s (the expressions of its docstring)."""
    C = math.sqrt(math.pi * R / (2.0 * H))
    if m >= 0.0:
        ch = 1.0 / math.sqrt(m * m + 1.0 / (C * C))
    else:
        ch = C * math.exp(min(R * m * m / (2.0 * H), 50.0)) * (1.0 + math.erf(abs(m) * C / math.sqrt(math.pi)))
    return ch / (2.0 * C)


@numba.njit(cache=True)
def _sun_path_ratio_kernel(mu, H, R, out):
    for i in range(mu.shape[0]):
        out[i] = _sun_path_ratio1(mu[i], H, R)


@functools.lru_cache(maxsize=16)
def _uf_table(fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """ln u_f over ln c on a grid (eq. (5)): the crossing of ``g(u) = (1 - e^-u) e^(-c u)`` with
    ``fraction * max g`` on the small-u (space) side of the maximum ``u* = ln((1 + c)/c)``,
    by bisection in ln u (60 halvings: exact to 1e-15 relative, far below the table step)."""
    lnc = np.linspace(-12.0, 8.0, 801)
    c = np.exp(lnc)
    us = np.log1p(1.0 / c)
    gmax = np.exp(-np.log1p(c) + c * (np.log(c) - np.log1p(c)))
    lo = np.full_like(c, math.log(1e-9))
    hi = np.log(us)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        u = np.exp(mid)
        big = -np.expm1(-u) * np.exp(-c * u) > fraction * gmax
        hi = np.where(big, mid, hi)
        lo = np.where(big, lo, mid)
    return lnc, 0.5 * (lo + hi)


def flank_rise_height(mu_s: np.ndarray, fraction: float = 0.5, upper: float = 0.8,
                      scale_height_m: float = 8000.0, radius_m: float = 6371e3) -> np.ndarray:
    """Height [m] from the fraction-of-peak crossing down to the ``upper``-of-peak level on the
    space side of the maximum of eq. (4), with the Sun-elevation sine ``mu_s`` at the tangent
    point: ``H ln(u_upper(c) / u_f(c))`` (the table of eq. (5) for both levels). Like the shift
    of eq. (5) it depends neither on the exposure, the phase function nor tau: the flank of a
    limb maximum has this width in tangent height on any camera (6.5 km with the Sun overhead,
    5.8 km at the horizon, for f = 0.5, upper = 0.8). A profile whose maximum is not the
    limb's (a surface brighter than the limb's flat top, beyond the horizon) has a wider one."""
    lnc, lnu_f = _uf_table(float(fraction))
    _, lnu_q = _uf_table(float(upper))
    c = sun_path_ratio(mu_s, scale_height_m, radius_m)
    x = np.log(np.maximum(c, 1e-300))
    return scale_height_m * (np.interp(x, lnc, lnu_q) - np.interp(x, lnc, lnu_f))


def fraction_height_shift(mu_s: np.ndarray, fraction: float = 0.5, scale_height_m: float = 8000.0,
                          radius_m: float = 6371e3) -> np.ndarray:
    """Height [m] of the fraction-of-peak crossing relative to the Sun overhead (mu_s = 1), eq. (5):
    ``h_f(mu) - h_f(1) = -H ln(u_f(c(mu)) / u_f(c(1)))``. It depends on the Sun elevation at the
    tangent point and on H (through c, `sun_path_ratio`), not on the exposure, the phase function
    or the optical depth tau (which only sets h_f(1), the configured ``limb.height_m``).
    Measured on rendered frames (docs/vision.md): +0.6 km at 20 deg, +1.5 km at 8 deg, +4 km at
    2 deg elevation."""
    lnc, lnu = _uf_table(float(fraction))
    mu = np.asarray(mu_s, dtype=float)
    out = np.empty(mu.shape)
    # one kernel for sun_path_ratio and the table look-up (np.interp on its uniform ln c grid),
    # instead of ~15 numpy calls per limb
    _fraction_shift_kernel(np.ascontiguousarray(mu.reshape(-1)), float(lnc[0]), float(lnc[1] - lnc[0]), lnu,
                           float(scale_height_m), float(radius_m), out.reshape(-1))
    return out


@numba.njit(cache=True)
def _ln_uf(lnc, lnc0, dlnc, lnu):
    """np.interp(lnc, grid, lnu) on the uniform grid ``lnc0 + k dlnc`` (ends held)."""
    n = lnu.shape[0]
    x = (lnc - lnc0) / dlnc
    if not x > 0.0:
        return lnu[0]
    if x >= n - 1:
        return lnu[n - 1]
    k = int(x)
    f = x - k
    return lnu[k] + f * (lnu[k + 1] - lnu[k])


@numba.njit(cache=True)
def _fraction_shift_kernel(mu, lnc0, dlnc, lnu, H, R, out):
    """`fraction_height_shift` per point: c of `sun_path_ratio`, ln u_f from the table, minus its
    value with the Sun overhead."""
    ln1 = _ln_uf(math.log(_sun_path_ratio1(1.0, H, R)), lnc0, dlnc, lnu)
    for i in range(mu.shape[0]):
        c = _sun_path_ratio1(mu[i], H, R)
        out[i] = -H * (_ln_uf(math.log(max(c, 1e-300)), lnc0, dlnc, lnu) - ln1)


@functools.lru_cache(maxsize=64)
def _tau_2c(fraction: float, scale_height_m: float, height_m: float, radius_m: float) -> float:
    """``tau 2C`` (u at h = 0) from the overhead-Sun crossing height by eq. (5):
    ``h_f(1) = H ln(tau 2C / u_f(c(1)))``."""
    lnc, lnu = _uf_table(float(fraction))
    c1 = sun_path_ratio(np.array([1.0]), scale_height_m, radius_m)
    return math.exp(float(np.interp(np.log(c1), lnc, lnu)[0]) + height_m / scale_height_m)


@numba.njit(cache=True)
def _limb_radiance(h, mu_c, k, h_c, A, H, C, R):
    """Limb radiance over ``E P T_0`` at tangent height h (eq. (4) with ``u = A e^(-h/H)``,
    ``A = tau 2C``), the Sun-elevation sine at the tangent point changing down the profile as
    ``mu(h) = mu_c + k (h - h_c)``; 0 in the Earth's shadow (twilight: the sunray's own lowest
    point below the surface)."""
    q, h_shadow = _sun_path_term(mu_c + k * (h - h_c), A, H, C, R)
    if h < h_shadow:
        return 0.0
    e = math.exp(-h / H)
    return -math.expm1(-A * e) * math.exp(-q * e)


@numba.njit(cache=True)
def _sun_path_term(mu, A, H, C, R):
    """``(q, h_shadow)`` of the sunlight's path to a tangent point with Sun-elevation sine mu
    (clipped to [-1, 1]): its optical depth is ``q exp(-h / H)`` at tangent height h (``A / (2C) /
    sqrt(mu^2 + 1/C^2)``; twilight, `sun_path_ratio`: ``A/2 exp(R mu^2 / (2H)) (1 + erf(-mu C /
    sqrt(pi)))``), and below ``h_shadow`` (``R mu^2 / 2``; -inf in daylight) the point lies in the
    Earth's shadow. Shared by `_limb_radiance` and the flank fit's per-sample terms."""
    m = min(1.0, max(-1.0, mu))
    if m >= 0.0:
        return A / (2.0 * C) / math.sqrt(m * m + 1.0 / (C * C)), -math.inf
    sh = 0.5 * R * m * m
    return 0.5 * A * math.exp(sh / H) * (1.0 + math.erf(-m * C / math.sqrt(math.pi))), sh


@numba.njit(cache=True)
def _profile_crossing(mu_c, k, h_c, A, H, C, R, fraction, keep):
    """Fraction-of-peak crossing height [m] of `_limb_radiance` with the detector's rules
    (`_limb_profiles`): scanning down from space, the first maximum followed by a drop below
    ``keep`` times it (or the surface, h = 0, where the detector's profile runs into the Earth's
    disc), then the crossing of ``fraction`` times that peak above it. 1 km scan, the peak
    refined by golden section to ~10 m (at the shadow edge the maximum is the edge itself), the
    crossing by bisection to ~1 m."""
    step = 1000.0
    top = max(h_c, 0.0) + 8e3              # ~e^-1 of the crossing's radiance: raised when not below it
    hs = np.empty(160)
    gs = np.empty(160)
    for _ in range(4):                       # the top must lie above the crossing
        h = top
        g = _limb_radiance(h, mu_c, k, h_c, A, H, C, R)
        hs[0], gs[0] = h, g
        n = 1
        jmax = 0
        while n < 160 and h > 0.0:
            h = max(h - step, 0.0)
            g = _limb_radiance(h, mu_c, k, h_c, A, H, C, R)
            hs[n], gs[n] = h, g
            n += 1
            if g > gs[jmax]:
                jmax = n - 1
            elif g < keep * gs[jmax]:
                break
        if gs[jmax] <= 0.0:
            return np.nan                    # all in the Earth's shadow
        # golden-section maximum on [h_jmax - step, h_jmax + step] (not below the surface)
        lo, hi = max(hs[jmax] - step, 0.0), hs[jmax] + step
        gr = 0.6180339887498949
        x1, x2 = hi - gr * (hi - lo), lo + gr * (hi - lo)
        f1 = _limb_radiance(x1, mu_c, k, h_c, A, H, C, R)
        f2 = _limb_radiance(x2, mu_c, k, h_c, A, H, C, R)
        for _ in range(11):
            if f1 > f2:
                hi, x2, f2 = x2, x1, f1
                x1 = hi - gr * (hi - lo)
                f1 = _limb_radiance(x1, mu_c, k, h_c, A, H, C, R)
            else:
                lo, x1, f1 = x1, x2, f2
                x2 = lo + gr * (hi - lo)
                f2 = _limb_radiance(x2, mu_c, k, h_c, A, H, C, R)
        peak = max(gs[jmax], f1, f2)
        tgt = fraction * peak
        if gs[0] >= tgt:
            top += 20e3
            continue
        j = 1
        while gs[j] < tgt:
            j += 1
        a, b = hs[j], hs[j - 1]              # g(a) >= tgt > g(b), a < b
        for _ in range(10):
            m = 0.5 * (a + b)
            if _limb_radiance(m, mu_c, k, h_c, A, H, C, R) >= tgt:
                a = m
            else:
                b = m
        return 0.5 * (a + b)
    return np.nan


def surface_ratio(mu_s, fraction: float = 0.5, scale_height_m: float = 8000.0, height_m: float = 18300.0,
                  radius_m: float = 6371e3) -> np.ndarray:
    """Radiance of the limb at the surface (tangent height 0) over its maximum above it, eq. (4)
    with the Sun-elevation sine ``mu_s`` at the tangent point (tau from the overhead-Sun crossing
    height ``height_m`` by eq. (5), as in `profile_height_shift`).

    With the Sun high the path ratio c of eq. (4) is small, the maximum ``u* = ln((1 + c)/c)``
    lies within a few km of the surface and the radiance barely falls below it (2 % with the Sun
    overhead, 19 % at 10 deg, 71 % at 2 deg with the defaults): where this ratio exceeds
    ``1 - min_drop`` of the detector the limb has no drop of its own above the surface, so the
    drop the detector finds lies on the Earth's disc, and the maximum before it can be a surface
    brighter than the limb's flat top (case (b) of the module docstring). The maximum is taken
    on a 50 m grid over 0..80 km (the top of eq. (4) is flat: < 1e-4 off)."""
    mu = np.ascontiguousarray(mu_s, dtype=float).reshape(-1)
    H = float(scale_height_m)
    C = math.sqrt(math.pi * radius_m / (2.0 * H))
    A = _tau_2c(float(fraction), H, float(height_m), float(radius_m))
    out = np.empty(mu.size)
    _surface_ratio_kernel(mu, A, H, C, float(radius_m), out)
    return out.reshape(np.shape(mu_s))


@functools.lru_cache(maxsize=16)
def resolved_sun_sine(fraction: float = 0.5, scale_height_m: float = 8000.0, height_m: float = 18300.0,
                      min_drop: float = 0.15, radius_m: float = 6371e3) -> float:
    """Sine of the Sun elevation at the tangent point above which the limb's maximum is not
    resolved from the surface: `surface_ratio` > ``1 - min_drop`` (it rises with the Sun in
    daylight); 1 when it never exceeds it. Bisection to 1e-9 in the sine (12.4 deg with the
    defaults)."""
    keep = 1.0 - float(min_drop)
    if surface_ratio(np.array([1.0]), fraction, scale_height_m, height_m, radius_m)[0] <= keep:
        return 1.0
    lo, hi = 0.0, 1.0
    while hi - lo > 1e-9:
        mid = 0.5 * (lo + hi)
        if surface_ratio(np.array([mid]), fraction, scale_height_m, height_m, radius_m)[0] > keep:
            hi = mid
        else:
            lo = mid
    return lo


@numba.njit(cache=True)
def _surface_ratio_kernel(mu, A, H, C, R, out):
    """`surface_ratio` per Sun-elevation sine (0 when the whole profile is in the Earth's shadow)."""
    for i in range(mu.size):
        g0 = _limb_radiance(0.0, mu[i], 0.0, 0.0, A, H, C, R)
        gmax = g0
        for j in range(1, 1601):
            gmax = max(gmax, _limb_radiance(50.0 * j, mu[i], 0.0, 0.0, A, H, C, R))
        out[i] = g0 / gmax if gmax > 0.0 else 0.0


@numba.njit(cache=True)
def _profile_heights(mu, k, h0, A, H, C, R, fraction, keep, out):
    for i in range(mu.size):
        h = h0[i]
        for _ in range(2):                   # h_c = crossing(mu(h) anchored at h_c): contracts by ~k dh/dmu
            h1 = _profile_crossing(mu[i], k[i], h, A, H, C, R, fraction, keep)
            if not math.isfinite(h1):
                break
            h = h1
        out[i] = h1


def profile_height_shift(mu_s: np.ndarray, dmu_dh: np.ndarray, fraction: float = 0.5,
                         scale_height_m: float = 8000.0, height_m: float = 18300.0,
                         min_drop: float = 0.15, radius_m: float = 6371e3) -> np.ndarray:
    """Height [m] of the fraction-of-peak crossing relative to the Sun overhead, with the Sun
    elevation changing down the profile: eq. (5) generalised.

    Eq. (5) takes the Sun-path ratio c of eq. (4) constant along a profile. The profile of one
    edge pixel, though, runs down through tangent points that move along the line of sight
    (~3 km of ground per km of tangent height from a few hundred km up), so the Sun elevation
    at the tangent point changes down the profile, ``mu(h) = mu_s + dmu_dh (h - h_f)`` (mu_s at
    the crossing itself). Near the terminator c changes by a factor ``exp(R mu dmu / H)``, which
    moves the maximum, and with it the crossing, by kilometres (eq. (5) alone is 1..7 km low
    there on rendered frames, docs/vision.md). Here the crossing is found on eq. (4) with that
    ``mu(h)`` and the Earth's shadow, by the detector's rules (`_profile_crossing`), and made
    self-consistent in h_f (two fixed-point steps; they contract by ``dmu_dh dh_f/dmu``, ~0.05).

    Unlike eq. (5), the optical depth tau no longer cancels: it follows from the overhead-Sun
    height ``height_m`` by eq. (5) itself, ``tau 2C = u_f(c(1)) exp(h_f(1) / H)``. With
    ``dmu_dh = 0`` this is `fraction_height_shift` (tests/test_limb_sun_path.py).

    mu_s, dmu_dh : (m,) Sun-elevation sine at each crossing's tangent point and its derivative
        down the profile [1/m] (`tangent_height_sun` of the pixel's ray and of a ray turned
        towards the body).
    Returns (m,) shifts [m]; NaN where the profile has no maximum above the surface.
    """
    mu = np.ascontiguousarray(mu_s, dtype=float).reshape(-1)
    k = np.broadcast_to(np.asarray(dmu_dh, dtype=float), mu.shape).copy()
    H = float(scale_height_m)
    C = math.sqrt(math.pi * radius_m / (2.0 * H))
    A = _tau_2c(fraction, H, height_m, radius_m)
    keep = 1.0 - float(min_drop)
    ref = _profile_crossing(1.0, 0.0, height_m, A, H, C, radius_m, fraction, keep)
    h0 = ref + fraction_height_shift(mu, fraction, H, radius_m)
    out = np.empty(mu.size)
    _profile_heights(mu, k, h0, A, H, C, float(radius_m), float(fraction), keep, out)
    return out - ref


@numba.njit(cache=True)
def _flank_terms(dh, mu, n, A, H, C, R, E, Q, hmin):
    """The parts of ``_limb_radiance(h0 + dh_k, mu_k, 0, 0, ...)`` that do not depend on h0, for
    the n samples of one profile: ``E_k = exp(-dh_k / H)``, ``Q_k`` with ``tms = Q_k e`` (``e =
    exp(-h0 / H) E_k``, `_sun_path_term`) and ``hmin_k``, the h0 below which the sample lies in
    the Earth's shadow (-inf in daylight). The flank fit evaluates the profile at ~55 heights h0: with
    these, two transcendental functions per sample and height instead of four or five."""
    for k in range(n):
        E[k] = math.exp(-dh[k] / H)
        Q[k], h_shadow = _sun_path_term(mu[k], A, H, C, R)
        hmin[k] = h_shadow - dh[k]


@numba.njit(cache=True)
def _flank_residual(h0, L, w, E, Q, hmin, ph, n, A, H, sw, sl, sll):
    """Weighted least-squares misfit of ``L = K ph_k g(h0 + dh_k; mu_k) + b`` (K, b solved in
    closed form, the misfit from the same sums) over n samples; ph the phase function relative to
    the edge pixel's, g `_limb_radiance` through the terms of `_flank_terms`; sw, sl, sll the sums
    of w, w L and w L^2 (independent of h0). Returns (misfit, K, b)."""
    e0 = math.exp(-h0 / H)
    sgg = sg = sgl = 0.0
    for k in range(n):
        if h0 < hmin[k]:
            continue                      # g = 0: in the Earth's shadow
        e = e0 * E[k]
        g = ph[k] * (-math.expm1(-A * e) * math.exp(-Q[k] * e))
        wk = w[k]
        sgg += wk * g * g
        sg += wk * g
        sgl += wk * g * L[k]
    det = sgg * sw - sg * sg
    if not det > 0.0:
        return np.inf, 0.0, 0.0
    K = (sgl * sw - sl * sg) / det
    b = (sgg * sl - sg * sgl) / det
    ss = sll - 2.0 * K * sgl - 2.0 * b * sl + K * K * sgg + 2.0 * K * b * sg + b * b * sw
    return max(ss, 0.0), K, b


#: grid step [m] of the flank fit's height search (refined by golden section around the best node)
_FLANK_GRID = 3000.0
#: 8-bit levels below which flank samples are not fitted (floored by the black level), and the
#: level below which their weight stops growing (8-bit noise is not smaller there)
_FLANK_MIN_LEVEL = 5.0
_FLANK_WEIGHT_FLOOR = 20.0


@numba.njit(cache=True)
def _flank_kernel(c, dh, mu, phase, A, H, C, R, gamma, clip, keep, min_samples, min_top, out_h, out_rms):
    """Per profile (rows of c, dh, mu): the samples from space down to the first clipped one or
    the first maximum (at least ``min_top``) followed by a drop below ``keep`` times it (the
    ground side is not in the model), without those below ``_FLANK_MIN_LEVEL`` (the tone curve's
    black level floors them at 0, which the model does not follow: with them the fit runs off to
    the pure exponential tail, K -> infinity); at least ``min_samples`` of them, the brightest >=
    ``min_top`` (the knee, where the profile bends away from the exponential tail, must be in
    view: it fixes the height). Linearised ``L = (c/255)^gamma``, weights ``1 / max(c, 20)^(2
    (gamma - 1))`` (a constant 8-bit noise seen through the tone curve). Then the height h0 of the
    edge pixel (sample dh = 0) that fits best: a `_FLANK_GRID` grid over 6..100 km and a
    golden-section search around the best node (~10 m). NaN where not fitted."""
    m, S = c.shape
    L = np.empty(S)
    w = np.empty(S)
    d = np.empty(S)
    u = np.empty(S)
    ph = np.empty(S)
    E = np.empty(S)
    Q = np.empty(S)
    hmin = np.empty(S)
    ex = 2.0 * (gamma - 1.0)
    for i in range(m):
        out_h[i] = np.nan
        out_rms[i] = np.nan
        n, top, inside = _flank_samples(c[i], dh[i], mu[i], phase[i], gamma, clip, keep, min_top, ex,
                                        L, w, d, u, ph)
        if not inside or n < min_samples or top < min_top:
            continue
        _flank_terms(d, u, n, A, H, C, R, E, Q, hmin)
        h0, f, K = _flank_search(L, w, E, Q, hmin, ph, n, A, H)
        if K > 0.0:
            out_h[i] = h0
            out_rms[i] = math.sqrt(f / n)


@numba.njit(cache=True)
def _flank_samples(c, dh, mu, phase, gamma, clip, keep, min_top, ex, L, w, d, u, ph):
    """The fitted samples of one profile of `_flank_kernel` into L (linearised), w (weights), d,
    u, ph (height offsets, Sun cosines, phase factors). Returns (count, brightest sample, inside
    the image)."""
    n = 0
    top = -1.0
    run = -1.0
    for k in range(c.shape[0]):
        ck = c[k]
        if ck < 0.0 or not math.isfinite(dh[k]):
            return n, top, False             # outside the image
        if ck >= clip:
            break
        if ck > run:
            run = ck
        elif run >= min_top and (ck / 255.0) ** gamma < keep * (run / 255.0) ** gamma:
            break                            # the ground side (a drop in the faint tail is noise)
        if ck < _FLANK_MIN_LEVEL:
            continue
        L[n] = (ck / 255.0) ** gamma
        w[n] = 1.0 / max(ck, _FLANK_WEIGHT_FLOOR) ** ex
        d[n] = dh[k]
        u[n] = mu[k]
        ph[n] = phase[k]
        n += 1
        top = max(top, ck)
    return n, top, True


@numba.njit(cache=True)
def _flank_search(L, w, E, Q, hmin, ph, n, A, H):
    """Height h0 [m] of the best fit of `_flank_residual` over n samples: the `_FLANK_GRID` grid
    over 6..100 km, then a golden-section search around the best node. Returns (h0, residual, K);
    (NaN, NaN, NaN) when no node gives a finite residual."""
    sw = sl = sll = 0.0
    for k in range(n):
        sw += w[k]
        sl += w[k] * L[k]
        sll += w[k] * L[k] * L[k]
    best, hb = np.inf, np.nan
    h = 6e3
    while h <= 100e3:
        f = _flank_residual(h, L, w, E, Q, hmin, ph, n, A, H, sw, sl, sll)[0]
        if f < best:
            best, hb = f, h
        h += _FLANK_GRID
    if not math.isfinite(hb):
        return np.nan, np.nan, np.nan
    gr = 0.6180339887498949
    lo, hi = hb - _FLANK_GRID, hb + _FLANK_GRID
    x1, x2 = hi - gr * (hi - lo), lo + gr * (hi - lo)
    f1 = _flank_residual(x1, L, w, E, Q, hmin, ph, n, A, H, sw, sl, sll)[0]
    f2 = _flank_residual(x2, L, w, E, Q, hmin, ph, n, A, H, sw, sl, sll)[0]
    for _ in range(20):
        if f1 < f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - gr * (hi - lo)
            f1 = _flank_residual(x1, L, w, E, Q, hmin, ph, n, A, H, sw, sl, sll)[0]
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + gr * (hi - lo)
            f2 = _flank_residual(x2, L, w, E, Q, hmin, ph, n, A, H, sw, sl, sll)[0]
    h0 = 0.5 * (lo + hi)
    f, K, _ = _flank_residual(h0, L, w, E, Q, hmin, ph, n, A, H, sw, sl, sll)
    return h0, f, K


def flank_heights(image: np.ndarray, camera: Camera, uv: np.ndarray, rays_c: np.ndarray,
                  e_c: np.ndarray, pixel_angle: np.ndarray, R_ec: np.ndarray, x_e: np.ndarray,
                  sun_e: np.ndarray, config: LimbEdgeConfig, *, height_m: float = 18300.0,
                  scale_height_m: float = 8000.0, space_px: int = 15, min_samples: int = 15,
                  min_top: float = 100.0, clip: float = 245.0, radius_m: float = 6371e3,
                  aerosol_weight: float = 0.0, aerosol_g: float = 0.75) -> np.ndarray:
    """Tangent height [m] of each edge pixel fitted on the *unsaturated* flank of its limb profile
    (a limb whose maximum the exposure clips: module docstring, case (a)).

    Where the maximum is clipped no fraction of it can be taken, but eq. (4) still fixes the
    profile's shape: ``B(h) = K g(h)``, ``g = (1 - e^-u) e^(-c u)``. The exponential tail alone
    (u << 1) is translation-invariant (only K e^(-h/H) is seen), but towards the knee (u ~ 0.3-1,
    still below saturation when K is a few times the clip level) ``1 - e^-u`` bends away from u,
    and that bend fixes the height. So each profile, sampled from ``space_px`` outside the pixel
    to ``config.search_px`` inside it down to its first clipped sample, is fitted with
    ``L = K g(h0 + dh) + b``: dh the samples' tangent heights relative to the pixel's
    (`tangent_height_sun` of their rays with the attitude R_ec, camera -> e; differences of
    heights, insensitive to its error), g with the Sun elevation at each sample's tangent point
    (the twilight path of `profile_height_shift`) and the phase function's change along the
    profile (`phase_function` of each sample's scattering angle, ``aerosol_*``), tau from
    ``height_m`` as there, K (exposure and phase) and b (the tone curve's black level) linear.
    Measured on rendered frames whose red limb maximum is clipped: median signed error 0.08 /
    -0.02 / 0.21 km at 1 / 1.5 / 2x the auto exposure (tests/test_limb.py, docs/vision.md).

    Returns (m,) heights h0 [m] of the edge pixels; NaN where the profile leaves the image, has
    fewer than ``min_samples`` samples below ``clip`` (8-bit; JPEG rings a few levels below a
    saturated run) before its maximum, or none as bright as ``min_top`` (the knee not in view).
    """
    uv = np.asarray(uv, dtype=float)
    m = uv.shape[0]
    if m == 0:
        return np.zeros(0)
    nrm = _profile_normals(camera, uv, rays_c, e_c, pixel_angle)
    s = np.arange(-space_px, config.search_px + 1, dtype=float)
    Q = uv[:, None, :] + s[None, :, None] * nrm[:, None, :]
    with np.errstate(invalid="ignore"):
        rays = unproject(camera, Q.reshape(-1, 2))
    ok = np.all(np.isfinite(rays), axis=1)
    rays = np.where(ok[:, None], rays, np.array([0.0, 0.0, 1.0]))
    h, mu = tangent_height_sun(rays @ np.asarray(R_ec, dtype=float).T, x_e, sun_e)
    h = np.where(ok, h, np.nan).reshape(m, s.size)
    mu = mu.reshape(m, s.size)
    sun_c = np.asarray(R_ec, dtype=float).T @ (np.asarray(sun_e, dtype=float) / np.linalg.norm(sun_e))
    P = phase_function(rays @ sun_c, aerosol_weight, aerosol_g).reshape(m, s.size)
    phase = P / P[:, space_px:space_px + 1]            # the phase function along each profile
    dh = h - h[:, space_px:space_px + 1]
    Qf = np.nan_to_num(Q, nan=-10.0).astype(np.float32)
    c = _bilinear(image, config.channel, Qf[..., 0], Qf[..., 1]).astype(float)
    H = float(scale_height_m)
    C = math.sqrt(math.pi * radius_m / (2.0 * H))
    A = _tau_2c(config.fraction, H, height_m, radius_m)
    out_h = np.empty(m)
    out_rms = np.empty(m)
    _flank_kernel(np.ascontiguousarray(c), np.ascontiguousarray(dh), np.ascontiguousarray(mu), phase, A, H, C,
                  float(radius_m), float(config.gamma), float(clip), 1.0 - config.min_drop,
                  int(min_samples), float(min_top), out_h, out_rms)
    return out_h
