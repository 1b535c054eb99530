"""Per-pixel shading kernels of the synthetic camera (numba); the physics is documented in
:mod:`scenarios.sim.render`, which is the only caller.

One pixel: rotate its camera-frame ray into e (float64), intersect it with the WGS-84 ellipsoid in
the scaled-sphere form, shade the Earth (surface + clouds + airlight) or the atmosphere limb (by
tangent height) or space, add the Sun disc, Moon, payload and lens glare, then (fused kernel) apply
exposure, vignetting, photon and read noise, saturation and the tone curve, and write uint8 RGB.
Randomness is a counter-based hash of (seed, pixel, channel), so a frame is reproducible and the
row loop can run in parallel in any order.

The scalar inputs travel in one float64 array ``P`` indexed by the constants below.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# --- indices into the parameter vector P --------------------------------------------------------
R0 = 0            # R_ec row-major, 9 values
O0 = 9            # camera position in scaled-sphere coordinates (x/a, y/a, z/b)
S0 = 12           # Sun unit vector in e (from the camera)
M0 = 15           # Moon unit vector in e
COS_SUN = 18      # cos(Sun angular radius)
COS_MOON = 19     # cos(Moon angular radius); > 1 turns the Moon off
SUN_L = 20        # Sun disc radiance (0 turns the disc off)
BLOOM_A = 21      # bloom amplitude (already times visible fraction and extinction)
BLOOM_G2 = 22     # bloom width^2 [rad^2]
GLARE_A = 23
GLARE_G2 = 24
MOON_ALB = 25
H_CAM = 26        # camera height above the ellipsoid [m]
ATM = 27          # 1: atmosphere on
H_SCALE = 28      # atmosphere scale height [m]
TAU0 = 29         # vertical optical depth R, G, B (3 values)
CH_MAX = 32       # grazing-incidence air-mass of one side of the atmosphere, sqrt(pi R / 2H)
ATM_GAIN = 33
MIE_W = 34
MIE_G = 35
TERMINATOR = 36   # 1: Lambertian Sun illumination; 0: uniformly lit Earth (clean mode)
CLOUDS = 37
CLOUD_COVER = 38
DETAIL_AMP = 39
DETAIL_SCALE = 40
AXIS_A = 41
AXIS_B = 42
EXPOSURE = 43     # radiance -> full-scale signal
FULL_WELL = 44    # electrons at saturation
READ_NOISE = 45   # electrons rms
NOISE = 46        # 1: noise on
FLAT_EARTH = 47   # 1: Earth radiance 1 everywhere (clean geometric mode)
R_MEAN = 48
WB0 = 49          # white-balance gains R, G, B (3 values)
TT_INV_DM = 52    # 1 / air-mass step of the transmission table
LIMB_SHIFT = 53   # the limb's air lifted by this height [m] (RenderOptions.limb_shift_m)
N_PARAMS = 54

#: slope [1/rad] of the Moon's surface phase function exp(-k g): with Lommel-Seeliger it gives the
#: disc-integrated quarter Moon (g = 90 deg) ~2.6 mag below the full Moon, as observed
_MOON_PHASE_K = 0.85

# surface reflectances (R, G, B)
_OCEAN = (0.025, 0.045, 0.075)
_LAND = (0.075, 0.085, 0.055)
_SNOW = (0.45, 0.47, 0.5)
_CLOUD = (0.72, 0.73, 0.75)


@njit(cache=True, inline="always")
def _smoothstep(e0, e1, x):
    t = (x - e0) / (e1 - e0)
    if t < 0.0:
        return 0.0
    if t > 1.0:
        return 1.0
    return t * t * (3.0 - 2.0 * t)


@njit(cache=True, inline="always")
def _airmass(mu, chmax):
    """Air mass of a path leaving the atmosphere at elevation sine ``mu`` (Chapman function
    stand-in 1/sqrt(mu^2 + 1/chmax^2): 1/mu overhead, chmax at grazing incidence)."""
    return 1.0 / np.sqrt(mu * mu + 1.0 / (chmax * chmax))


@njit(cache=True, inline="always")
def _sun_transmission_m(mu_s, h, P):
    """Air mass of the sunlight reaching height ``h`` with solar elevation sine ``mu_s``;
    negative when the point is in the Earth's shadow.

    Sun below the horizon (twilight): the sunray passed its lowest point, at ``hs = h - R mu^2/2``,
    a distance ``x_P = R |mu|`` before the point; along it the height is ``hs + x^2 / 2R``, so
    its air mass is ``C exp(-hs/H) (1 + erf(x_P / sqrt(2 R H)))`` with ``C = sqrt(pi R / 2H)``:
    the grazing path's Sun-side half plus the part up to the point (continuous at mu = 0 with the
    Chapman stand-in above, 2C exp(-hs/H) deep in twilight)."""
    H = P[H_SCALE]
    if mu_s >= 0.0:
        return _airmass(mu_s, P[CH_MAX]) * np.exp(-h / H)
    hs = h - 0.5 * P[R_MEAN] * mu_s * mu_s  # height of the grazing sunray's tangent point
    if hs < 0.0:
        return -1.0
    return P[CH_MAX] * np.exp(-hs / H) * (1.0 + math.erf(-mu_s * P[CH_MAX] / math.sqrt(math.pi)))


@njit(cache=True, inline="always")
def _trans(ttab, m, inv_dm, k):
    """exp(-tau_k m) from the table ``ttab[i, k] = exp(-tau_k i dm)`` (linear interpolation;
    the step dm = 0.02 keeps the relative error below 1e-4 for tau <= 0.5)."""
    x = m * inv_dm
    n = ttab.shape[0]
    if x >= n - 1.0:
        return ttab[n - 1, k]
    i = int(x)
    f = x - i
    return ttab[i, k] + f * (ttab[i + 1, k] - ttab[i, k])


@njit(cache=True, inline="always")
def _cube_sample(cmap, detail, px, py, pz, P):
    """Bilinear cube-map sample at the scaled-sphere unit vector p: (cloud, ground) in [0, 1],
    plus the detail-tile value at the face coordinates."""
    ax, ay, az = abs(px), abs(py), abs(pz)
    if ax >= ay and ax >= az:
        if px >= 0.0:
            f, s, t = 0, py / ax, pz / ax
        else:
            f, s, t = 1, -py / ax, pz / ax
    elif ay >= az:
        if py >= 0.0:
            f, s, t = 2, -px / ay, pz / ay
        else:
            f, s, t = 3, px / ay, pz / ay
    else:
        if pz >= 0.0:
            f, s, t = 4, py / az, -px / az
        else:
            f, s, t = 5, py / az, px / az
    n = cmap.shape[1]
    x = (s + 1.0) * 0.5 * n - 0.5
    y = (t + 1.0) * 0.5 * n - 0.5
    if x < 0.0:
        x = 0.0
    if y < 0.0:
        y = 0.0
    if x > n - 1.001:
        x = n - 1.001
    if y > n - 1.001:
        y = n - 1.001
    j0 = int(x)
    i0 = int(y)
    fx = x - j0
    fy = y - i0
    c = ((1.0 - fy) * ((1.0 - fx) * cmap[f, i0, j0, 0] + fx * cmap[f, i0, j0 + 1, 0])
         + fy * ((1.0 - fx) * cmap[f, i0 + 1, j0, 0] + fx * cmap[f, i0 + 1, j0 + 1, 0])) * (1.0 / 255.0)
    g = ((1.0 - fy) * ((1.0 - fx) * cmap[f, i0, j0, 1] + fx * cmap[f, i0, j0 + 1, 1])
         + fy * ((1.0 - fx) * cmap[f, i0 + 1, j0, 1] + fx * cmap[f, i0 + 1, j0 + 1, 1])) * (1.0 / 255.0)
    nd = detail.shape[0]
    dx = (s + 1.0) * P[DETAIL_SCALE] * nd
    dy = (t + 1.0) * P[DETAIL_SCALE] * nd
    jd = int(dx)
    id_ = int(dy)
    gx = dx - jd
    gy = dy - id_
    msk = nd - 1  # nd is a power of two
    j0d = jd & msk
    i0d = id_ & msk
    j1d = (j0d + 1) & msk
    i1d = (i0d + 1) & msk
    d = ((1.0 - gy) * ((1.0 - gx) * detail[i0d, j0d] + gx * detail[i0d, j1d])
         + gy * ((1.0 - gx) * detail[i1d, j0d] + gx * detail[i1d, j1d]))
    return c, g, d


@njit(cache=True, inline="always")
def _scene(rx, ry, rz, P, cmap, detail, ttab):
    """Radiance (R, G, B) of the scene along one camera-frame ray, and the pixel class
    (0 space, 1 Earth, 3 Sun disc, 4 Moon). Units: 1 = white Lambertian surface under the
    overhead Sun."""
    # ray into e (float64: the horizon position depends on it)
    dx = P[R0] * rx + P[R0 + 1] * ry + P[R0 + 2] * rz
    dy = P[R0 + 3] * rx + P[R0 + 4] * ry + P[R0 + 5] * rz
    dz = P[R0 + 6] * rx + P[R0 + 7] * ry + P[R0 + 8] * rz
    A = P[AXIS_A]
    B = P[AXIS_B]
    ox, oy, oz = P[O0], P[O0 + 1], P[O0 + 2]
    # scaled-sphere form: |o' + t d'| = 1 with o' = diag(1/a,1/a,1/b) x, d' likewise
    qx, qy, qz = dx / A, dy / A, dz / B
    a = qx * qx + qy * qy + qz * qz
    b = ox * qx + oy * qy + oz * qz
    c = ox * ox + oy * oy + oz * oz - 1.0
    disc = b * b - a * c
    sx, sy, sz = P[S0], P[S0 + 1], P[S0 + 2]
    cos_g = dx * sx + dy * sy + dz * sz  # cosine of the angle to the Sun
    lr = 0.0
    lg = 0.0
    lb = 0.0
    cls = 0
    hit = disc >= 0.0 and b < 0.0
    atm = P[ATM] > 0.5
    # phase function of the in-scattered sunlight (Rayleigh + Henyey-Greenstein aerosol)
    phase = 0.0
    if atm:
        g = P[MIE_G]
        den = 1.0 + g * g - 2.0 * g * cos_g
        phase = ((1.0 - P[MIE_W]) * 0.75 * (1.0 + cos_g * cos_g)
                 + P[MIE_W] * (1.0 - g * g) / (den * np.sqrt(den))) * 0.25 * P[ATM_GAIN]
    H = P[H_SCALE]
    chmax = P[CH_MAX]
    if hit:
        cls = 1
        if P[FLAT_EARTH] > 0.5:
            return 1.0, 1.0, 1.0, cls
        t = (-b - np.sqrt(disc)) / a
        px, py, pz = ox + t * qx, oy + t * qy, oz + t * qz
        # geodetic normal: gradient of the ellipsoid, (x/a^2, y/a^2, z/b^2) = (p'x/a, p'y/a, p'z/b)
        nx, ny, nz = px / A, py / A, pz / B
        inv = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
        nx *= inv
        ny *= inv
        nz *= inv
        mu_v = -(nx * dx + ny * dy + nz * dz)
        if P[TERMINATOR] > 0.5:
            mu_s = nx * sx + ny * sy + nz * sz
        else:
            mu_s = 0.7
        # surface reflectance: ground type and clouds
        cov, grd, det = _cube_sample(cmap, detail, px, py, pz, P)
        if grd < 0.42:
            ar, ag, ab = _OCEAN
        elif grd > 0.93:
            ar, ag, ab = _SNOW
        else:
            sh = 0.6 + 1.6 * (grd - 0.42) + 0.5 * (det - 0.5)
            ar, ag, ab = _LAND[0] * sh, _LAND[1] * sh, _LAND[2] * sh
        if P[CLOUDS] > 0.5:
            dens = cov + P[DETAIL_AMP] * (det - 0.5)
            thr = 1.0 - P[CLOUD_COVER]
            w = _smoothstep(thr - 0.02, thr + 0.10, dens)
            thick = 0.75 + 0.5 * det
            ar = ar + w * (_CLOUD[0] * thick - ar)
            ag = ag + w * (_CLOUD[1] * thick - ag)
            ab = ab + w * (_CLOUD[2] * thick - ab)
        lit = mu_s if mu_s > 0.0 else 0.0
        if atm:
            mv = _airmass(mu_v, chmax)
            ms = _sun_transmission_m(mu_s, 0.0, P)
            sun_ok = ms >= 0.0
            idm = P[TT_INV_DM]
            if sun_ok:
                tsr = _trans(ttab, ms, idm, 0)
                tsg = _trans(ttab, ms, idm, 1)
                tsb = _trans(ttab, ms, idm, 2)
            else:
                tsr = tsg = tsb = 0.0
            tvr = _trans(ttab, mv, idm, 0)
            tvg = _trans(ttab, mv, idm, 1)
            tvb = _trans(ttab, mv, idm, 2)
            lr = (ar * lit * tvr + phase * (1.0 - tvr)) * tsr
            lg = (ag * lit * tvg + phase * (1.0 - tvg)) * tsg
            lb = (ab * lit * tvb + phase * (1.0 - tvb)) * tsb
        else:
            lr, lg, lb = ar * lit, ag * lit, ab * lit
        return lr, lg, lb, cls
    # miss: atmosphere limb by tangent height
    tr = 1.0
    tg = 1.0
    tb = 1.0
    if atm:
        tc = -b / a
        if tc > 0.0:
            px, py, pz = ox + tc * qx, oy + tc * qy, oz + tc * qz
            rho = np.sqrt(px * px + py * py + pz * pz)
            rloc = np.sqrt((A * px) ** 2 + (A * py) ** 2 + (B * pz) ** 2) / rho
            h_t = (rho - 1.0) * rloc - P[LIMB_SHIFT]
            mt = 2.0 * chmax * np.exp(-h_t / H)
            nx, ny, nz = px / A, py / A, pz / B
            inv = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
            mu_s = (nx * sx + ny * sy + nz * sz) * inv
        else:  # looking up and away: the column above the camera
            h_t = P[H_CAM] - P[LIMB_SHIFT]
            nx, ny, nz = ox / A, oy / A, oz / B
            inv = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
            mu_up = (nx * dx + ny * dy + nz * dz) * inv
            mt = _airmass(mu_up, chmax) * np.exp(-h_t / H)
            mu_s = (nx * sx + ny * sy + nz * sz) * inv
        if P[TERMINATOR] <= 0.5:
            mu_s = 0.7
        ms = _sun_transmission_m(mu_s, h_t, P)
        idm = P[TT_INV_DM]
        tr = _trans(ttab, mt, idm, 0)
        tg = _trans(ttab, mt, idm, 1)
        tb = _trans(ttab, mt, idm, 2)
        if ms >= 0.0:
            lr = phase * (1.0 - tr) * _trans(ttab, ms, idm, 0)
            lg = phase * (1.0 - tg) * _trans(ttab, ms, idm, 1)
            lb = phase * (1.0 - tb) * _trans(ttab, ms, idm, 2)
    # Sun disc and Moon (only where the Earth does not hide them)
    if P[SUN_L] > 0.0 and cos_g > P[COS_SUN]:
        sl = P[SUN_L]
        lr += sl * tr
        lg += sl * tg
        lb += sl * tb
        cls = 3
    elif cos_g < P[COS_SUN]:
        mx, my, mz = P[M0], P[M0 + 1], P[M0 + 2]
        cos_m = dx * mx + dy * my + dz * mz
        if cos_m > P[COS_MOON]:
            # point on the Moon's sphere facing the camera: w = d - (d.m) m, |w| = sin(gamma)
            sin_r = np.sqrt(1.0 - P[COS_MOON] * P[COS_MOON])
            wx, wy, wz = (dx - cos_m * mx) / sin_r, (dy - cos_m * my) / sin_r, (dz - cos_m * mz) / sin_r
            w2 = wx * wx + wy * wy + wz * wz
            zc = np.sqrt(max(0.0, 1.0 - w2))
            nmx, nmy, nmz = wx - zc * mx, wy - zc * my, wz - zc * mz
            mu = nmx * sx + nmy * sy + nmz * sz
            if mu > 0.0:
                # Lommel-Seeliger: radiance factor 2 p mu0 / (mu0 + mu) f(g), p the geometric
                # albedo, mu0 = mu the incidence and zc the emission cosine, g the phase angle
                g_ph = math.acos(min(1.0, max(-1.0, -(mx * sx + my * sy + mz * sz))))
                v = 2.0 * P[MOON_ALB] * mu / (mu + zc) * math.exp(-_MOON_PHASE_K * g_ph)
                lr += v * tr
                lg += v * tg
                lb += v * tb
            cls = 4
    return lr, lg, lb, cls


@njit(cache=True, inline="always")
def _glare(rx, ry, rz, P):
    """Lens bloom + veiling glare around the Sun, g^2 = |d - s|^2 = 2 (1 - cos gamma)."""
    dx = P[R0] * rx + P[R0 + 1] * ry + P[R0 + 2] * rz
    dy = P[R0 + 3] * rx + P[R0 + 4] * ry + P[R0 + 5] * rz
    dz = P[R0 + 6] * rx + P[R0 + 7] * ry + P[R0 + 8] * rz
    g2 = 2.0 * (1.0 - (dx * P[S0] + dy * P[S0 + 1] + dz * P[S0 + 2]))
    return (P[BLOOM_A] * P[BLOOM_G2] / (P[BLOOM_G2] + g2)
            + P[GLARE_A] * P[GLARE_G2] / (P[GLARE_G2] + g2))


@njit(cache=True, inline="always")
def _bilinear_lr(buf, i, j, fac, k):
    """Sample a low-resolution (factor ``fac``) buffer at full-resolution pixel (i, j)."""
    h, w = buf.shape[0], buf.shape[1]
    y = (i + 0.5) / fac - 0.5
    x = (j + 0.5) / fac - 0.5
    if y < 0.0:
        y = 0.0
    if x < 0.0:
        x = 0.0
    if y > h - 1.0:
        y = h - 1.0
    if x > w - 1.0:
        x = w - 1.0
    i0 = int(y)
    j0 = int(x)
    i1 = min(i0 + 1, h - 1)
    j1 = min(j0 + 1, w - 1)
    fy = y - i0
    fx = x - j0
    return ((1.0 - fy) * ((1.0 - fx) * buf[i0, j0, k] + fx * buf[i0, j1, k])
            + fy * ((1.0 - fx) * buf[i1, j0, k] + fx * buf[i1, j1, k]))


@njit(cache=True, inline="always")
def _pixel(i, j, rays, mask, payload, add, fac, P, cmap, detail, ttab, has_mask, has_add, has_glare):
    rx = np.float64(rays[i, j, 0])
    ry = np.float64(rays[i, j, 1])
    rz = np.float64(rays[i, j, 2])
    if has_mask and mask[i, j]:
        lr = _bilinear_lr(payload, i, j, fac, 0)
        lg = _bilinear_lr(payload, i, j, fac, 1)
        lb = _bilinear_lr(payload, i, j, fac, 2)
        cls = 2
    else:
        lr, lg, lb, cls = _scene(rx, ry, rz, P, cmap, detail, ttab)
    if has_glare:
        gl = _glare(rx, ry, rz, P)
        lr += gl
        lg += gl
        lb += gl * 0.95
    if has_add:
        lr += _bilinear_lr(add, i, j, fac, 0)
        lg += _bilinear_lr(add, i, j, fac, 1)
        lb += _bilinear_lr(add, i, j, fac, 2)
    return lr, lg, lb, cls


@njit(cache=True, inline="always")
def _mix(seed, idx):
    """SplitMix64 of (seed, counter)."""
    h = np.uint64(seed) + np.uint64(idx) * np.uint64(0x9E3779B97F4A7C15)
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return h


@njit(cache=True, inline="always")
def _gauss3(seed, idx):
    """Three approximately standard normal deviates from two counter hashes: each the
    Irwin-Hall sum of four 10-bit uniforms (12 of the 2 x 6 available), centred and scaled to unit
    variance (the discreteness adds 1e-6 of variance; tails cut at 3.46 sigma)."""
    h1 = _mix(seed, 2 * idx)
    h2 = _mix(seed, 2 * idx + 1)
    m = np.uint64(0x3FF)
    sc = 1.7320508075688772 / 1024.0
    a = (np.float64(h1 & m) + np.float64((h1 >> np.uint64(10)) & m)
         + np.float64((h1 >> np.uint64(20)) & m) + np.float64((h1 >> np.uint64(30)) & m) + 2.0 - 2048.0) * sc
    b = (np.float64((h1 >> np.uint64(40)) & m) + np.float64((h1 >> np.uint64(50)) & m)
         + np.float64(h2 & m) + np.float64((h2 >> np.uint64(10)) & m) + 2.0 - 2048.0) * sc
    c = (np.float64((h2 >> np.uint64(20)) & m) + np.float64((h2 >> np.uint64(30)) & m)
         + np.float64((h2 >> np.uint64(40)) & m) + np.float64((h2 >> np.uint64(50)) & m) + 2.0 - 2048.0) * sc
    return a, b, c


@njit(cache=True, inline="always")
def _sensor(l, g, vig, P, lut, k):
    """Linear radiance -> uint8: exposure, white balance (channel k), vignetting, photon + read
    noise (``g`` a standard normal deviate), saturation, tone LUT."""
    s = l * P[EXPOSURE] * P[WB0 + k] * vig
    if P[NOISE] > 0.5:
        fw = P[FULL_WELL]
        e = s * fw
        if e < 0.0:
            e = 0.0
        sig = np.sqrt(e + P[READ_NOISE] * P[READ_NOISE])
        s = (e + sig * g) / fw
    if s <= 0.0:
        return lut[0]
    n = lut.shape[0]
    q = int(s * (n - 1) + 0.5)
    if q >= n:
        return lut[n - 1]
    return lut[q]


@njit(cache=True, parallel=True, fastmath=True)
def render_fused(rays, mask, payload, add, fac, vign, P, cmap, detail, ttab, lut, seed,
                 has_mask, has_add, has_glare, has_vign, out, cls_out, sat_rows):
    """Scene + lens + sensor in one pass; writes ``out`` (H, W, 3) uint8 RGB, ``cls_out`` and
    ``sat_rows`` (pixels per row with a channel at the top code)."""
    hgt, wid = rays.shape[0], rays.shape[1]
    top = lut[lut.shape[0] - 1]
    for i in prange(hgt):
        nsat = 0
        for j in range(wid):
            lr, lg, lb, cls = _pixel(i, j, rays, mask, payload, add, fac, P, cmap, detail, ttab,
                                     has_mask, has_add, has_glare)
            vig = vign[i, j] if has_vign else 1.0
            g0, g1, g2 = _gauss3(seed, i * wid + j)
            c0 = _sensor(lr, g0, vig, P, lut, 0)
            c1 = _sensor(lg, g1, vig, P, lut, 1)
            c2 = _sensor(lb, g2, vig, P, lut, 2)
            out[i, j, 0] = c0
            out[i, j, 1] = c1
            out[i, j, 2] = c2
            if c0 == top or c1 == top or c2 == top:
                nsat += 1
            cls_out[i, j] = cls
        sat_rows[i] = nsat


@njit(cache=True, parallel=True, fastmath=True)
def render_radiance(rays, mask, payload, add, fac, P, cmap, detail, ttab, has_mask, has_add, has_glare,
                    out, cls_out):
    """Scene + lens radiance into ``out`` (H, W, 3) float32 (for metering and motion blur)."""
    hgt, wid = rays.shape[0], rays.shape[1]
    for i in prange(hgt):
        for j in range(wid):
            lr, lg, lb, cls = _pixel(i, j, rays, mask, payload, add, fac, P, cmap, detail, ttab,
                                     has_mask, has_add, has_glare)
            out[i, j, 0] = lr
            out[i, j, 1] = lg
            out[i, j, 2] = lb
            cls_out[i, j] = cls


@njit(cache=True, parallel=True)
def sensor_pass(rad, vign, P, lut, seed, has_vign, out):
    """Exposure, vignetting, noise, saturation and tone curve of a radiance image."""
    hgt, wid = rad.shape[0], rad.shape[1]
    for i in prange(hgt):
        for j in range(wid):
            vig = vign[i, j] if has_vign else 1.0
            g0, g1, g2 = _gauss3(seed, i * wid + j)
            out[i, j, 0] = _sensor(np.float64(rad[i, j, 0]), g0, vig, P, lut, 0)
            out[i, j, 1] = _sensor(np.float64(rad[i, j, 1]), g1, vig, P, lut, 1)
            out[i, j, 2] = _sensor(np.float64(rad[i, j, 2]), g2, vig, P, lut, 2)


@njit(cache=True, parallel=True)
def motion_blur(rad, disp, step, out):
    """Average the radiance along each pixel's image motion during the exposure.

    ``disp`` (Hc, Wc, 2) is the image displacement [px] (end minus start of the exposure) on a
    coarse grid with spacing ``step`` px; taps are spread uniformly over [-1/2, 1/2] of it
    (nearest pixel), one tap per pixel of motion, at most 48.
    """
    hgt, wid = rad.shape[0], rad.shape[1]
    hc, wc = disp.shape[0], disp.shape[1]
    for i in prange(hgt):
        for j in range(wid):
            y = i / step
            x = j / step
            i0 = min(int(y), hc - 2)
            j0 = min(int(x), wc - 2)
            fy = y - i0
            fx = x - j0
            du = ((1 - fy) * ((1 - fx) * disp[i0, j0, 0] + fx * disp[i0, j0 + 1, 0])
                  + fy * ((1 - fx) * disp[i0 + 1, j0, 0] + fx * disp[i0 + 1, j0 + 1, 0]))
            dv = ((1 - fy) * ((1 - fx) * disp[i0, j0, 1] + fx * disp[i0, j0 + 1, 1])
                  + fy * ((1 - fx) * disp[i0 + 1, j0, 1] + fx * disp[i0 + 1, j0 + 1, 1]))
            n = int(np.sqrt(du * du + dv * dv)) + 1
            if n > 48:
                n = 48
            if n == 1:
                for k in range(3):
                    out[i, j, k] = rad[i, j, k]
                continue
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for t in range(n):
                f = t / (n - 1.0) - 0.5
                ii = int(i + f * dv + 0.5)
                jj = int(j + f * du + 0.5)
                if ii < 0:
                    ii = 0
                if jj < 0:
                    jj = 0
                if ii >= hgt:
                    ii = hgt - 1
                if jj >= wid:
                    jj = wid - 1
                a0 += rad[ii, jj, 0]
                a1 += rad[ii, jj, 1]
                a2 += rad[ii, jj, 2]
            out[i, j, 0] = a0 / n
            out[i, j, 1] = a1 / n
            out[i, j, 2] = a2 / n
