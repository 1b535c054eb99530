"""Procedural Earth surface and cloud cover for the synthetic camera images, deterministic from a seed.

Two maps, made once per seed and cached in memory:

* a **cube map** of the (scaled) unit sphere, ``(6, N, N, 2)`` uint8: channel 0 is cloud coverage,
  channel 1 the ground type (ocean below 128, land above, its value the land shade). Each texel is
  the 3-D fractional Brownian motion (fBm) of value noise evaluated at the texel's direction on the
  unit sphere, so neighbouring faces join without seams and the clouds stay fixed in the Earth-fixed
  frame e: both cameras and every frame of a flight see the same weather. Both channels are
  equalised to a uniform distribution (histogram lookup), so a threshold ``1 - cover`` on channel 0
  gives a cloud fraction of ``cover``. Face order +X, -X, +Y, -Y, +Z, -Z; on face ``f`` the texel
  ``(i, j)`` (row, column) is the direction ``axis_f + s * right_f + t * up_f`` with
  ``s = (2 j + 1) / N - 1``, ``t = (2 i + 1) / N - 1`` (see :data:`FACE_BASES`).
* a **detail tile**, ``(D, D)`` float32 in [0, 1], periodic (band-limited noise made by filtering
  white noise in the Fourier domain, hence seamless when tiled), which the shader adds at a much
  finer scale to break up the cube-map texels into ragged cloud edges.

With N = 1024 a texel is about 10 km on the ground; the detail tile repeats every
``detail_period_m`` (default 120 km) with 0.5 km texels. Seen from 230 km (003 fig. 9) a pixel of
the ATEK camera covers 0.3 km (straight down) to several km (near the horizon).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit, prange

__all__ = ["FACE_BASES", "cube_map", "detail_tile"]

#: (axis, right, up) of the six cube faces, in the Earth-fixed frame (scaled sphere).
FACE_BASES = np.array([
    [[1, 0, 0], [0, 1, 0], [0, 0, 1]],     # +X
    [[-1, 0, 0], [0, -1, 0], [0, 0, 1]],   # -X
    [[0, 1, 0], [-1, 0, 0], [0, 0, 1]],    # +Y
    [[0, -1, 0], [1, 0, 0], [0, 0, 1]],    # -Y
    [[0, 0, 1], [0, 1, 0], [-1, 0, 0]],    # +Z
    [[0, 0, -1], [0, 1, 0], [1, 0, 0]],    # -Z
], dtype=np.float64)


@njit(cache=True, inline="always")
def _hash3(ix, iy, iz, seed):
    """Integer lattice hash -> [0, 1) (SplitMix64 finaliser)."""
    h = np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15)
    h ^= np.uint64(ix & 0xFFFFFFFF) * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= np.uint64(iy & 0xFFFFFFFF) * np.uint64(0x165667B19E3779F9)
    h ^= np.uint64(iz & 0xFFFFFFFF) * np.uint64(0x27D4EB2F165667C5)
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return (h >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True)
def _value_noise3(x, y, z, seed):
    """Trilinear value noise with smoothstep weights, in [0, 1)."""
    fx, fy, fz = np.floor(x), np.floor(y), np.floor(z)
    ix, iy, iz = np.int64(fx), np.int64(fy), np.int64(fz)
    tx, ty, tz = x - fx, y - fy, z - fz
    tx = tx * tx * (3.0 - 2.0 * tx)
    ty = ty * ty * (3.0 - 2.0 * ty)
    tz = tz * tz * (3.0 - 2.0 * tz)
    acc = 0.0
    for dz in range(2):
        wz = tz if dz else 1.0 - tz
        for dy in range(2):
            wy = ty if dy else 1.0 - ty
            for dx in range(2):
                wx = tx if dx else 1.0 - tx
                acc += wx * wy * wz * _hash3(ix + dx, iy + dy, iz + dz, seed)
    return acc


@njit(cache=True, parallel=True)
def _fbm_cube(n, seed, base_freq, octaves, gain, bases, out, channel):
    for f in range(6):
        ax0, ax1, ax2 = bases[f, 0, 0], bases[f, 0, 1], bases[f, 0, 2]
        r0, r1, r2 = bases[f, 1, 0], bases[f, 1, 1], bases[f, 1, 2]
        u0, u1, u2 = bases[f, 2, 0], bases[f, 2, 1], bases[f, 2, 2]
        for i in prange(n):
            t = (2.0 * i + 1.0) / n - 1.0
            for j in range(n):
                s = (2.0 * j + 1.0) / n - 1.0
                x = ax0 + s * r0 + t * u0
                y = ax1 + s * r1 + t * u1
                z = ax2 + s * r2 + t * u2
                inv = 1.0 / np.sqrt(x * x + y * y + z * z)
                x *= inv
                y *= inv
                z *= inv
                freq = base_freq
                amp = 1.0
                acc = 0.0
                norm = 0.0
                for o in range(octaves):
                    # offset per octave so the lattices do not align
                    acc += amp * _value_noise3(x * freq + 17.3 * o, y * freq - 9.1 * o,
                                               z * freq + 3.7 * o, seed + 7919 * o)
                    norm += amp
                    freq *= 2.0
                    amp *= gain
                out[f, i, j, channel] = acc / norm


def _equalise_to_uint8(v: np.ndarray) -> np.ndarray:
    """Map values to a uniform distribution on 0..255 (histogram equalisation, 4096 bins)."""
    lo, hi = float(v.min()), float(v.max())
    nb = 4096
    idx = np.minimum(((v - lo) / max(hi - lo, 1e-12) * nb).astype(np.int32), nb - 1)
    hist = np.bincount(idx.ravel(), minlength=nb).astype(np.float64)
    cdf = np.cumsum(hist) / hist.sum()
    lut = np.clip(np.round((cdf - 0.5 * hist / hist.sum()) * 255.0), 0, 255).astype(np.uint8)
    return lut[idx]


@lru_cache(maxsize=4)
def cube_map(seed: int, size: int = 1024) -> np.ndarray:
    """Cloud and ground cube map, ``(6, size, size, 2)`` uint8, deterministic from ``seed``.

    Cloud channel: fBm of 8 octaves from base frequency 2.5 per Earth radius (features of ~2500 km
    down to ~20 km), gain 0.55. Ground channel: 7 octaves from 1.5 per Earth radius, gain 0.5.
    """
    if int(size) != size or not 16 <= size <= 4096:
        raise ValueError(f"cube_map: size = {size!r} must be an integer in [16, 4096] texels per face")
    size = int(size)
    raw = np.empty((6, size, size, 2), dtype=np.float32)
    s = int(seed) & 0x7FFFFFFF
    _fbm_cube(size, s * 2 + 1, 2.5, 8, 0.55, FACE_BASES, raw, 0)
    _fbm_cube(size, s * 2 + 2, 1.5, 7, 0.5, FACE_BASES, raw, 1)
    out = np.empty((6, size, size, 2), dtype=np.uint8)
    out[..., 0] = _equalise_to_uint8(raw[..., 0])
    out[..., 1] = _equalise_to_uint8(raw[..., 1])
    out.setflags(write=False)
    return out


@lru_cache(maxsize=4)
def detail_tile(seed: int, size: int = 256, slope: float = 1.6) -> np.ndarray:
    """Periodic detail noise ``(size, size)`` float32 in [0, 1]: white noise shaped by a
    power-law spectrum ``|k|^-slope`` (wavelengths from the tile size down to 2 texels),
    hence seamless when tiled."""
    rng = np.random.default_rng([int(seed) & 0x7FFFFFFF, 0xC10D])
    w = rng.standard_normal((size, size))
    k = np.fft.fftfreq(size) * size
    kk = np.hypot(k[:, None], k[None, :])
    kk[0, 0] = 1.0
    spec = np.fft.fft2(w) / kk**slope
    spec[0, 0] = 0.0
    d = np.real(np.fft.ifft2(spec))
    d = (d - d.min()) / (d.max() - d.min())
    out = d.astype(np.float32)
    out.setflags(write=False)
    return out
