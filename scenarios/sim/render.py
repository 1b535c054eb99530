"""Synthetic camera images (any `vision.camera` model) of the Earth's horizon, the Sun and the Moon, with exact truth.

What the renderer draws, per pixel, along the pixel-centre ray of the camera model
(:func:`vision.camera.pixel_rays`, 003 eqs. (13)-(16)) rotated into e with the frame's truth
attitude ``R_ec`` from the truth position ``x_e``:

* **Earth**: the WGS-84 ellipsoid, hit in the scaled-sphere form ``|o' + t d'| = 1`` with
  ``o' = diag(1/a, 1/a, 1/b) x_e``, ``d'`` likewise (exact: a pixel is "Earth" iff its centre ray
  hits the ellipsoid, the ellipsoidal version of the Earth cone of 003 eq. (4)). Reflectance from a
  procedural cube map (:mod:`scenarios.sim.clouds`: ocean, land, snow, clouds; deterministic from the
  seed and fixed in e), Lambertian illumination ``max(n . s, 0)`` by the Sun with the geodetic normal
  ``n`` (the day/night terminator).
* **Atmosphere**: single scattering in an exponential atmosphere with scale height ``H`` and
  vertical optical depths ``tau_RGB`` (Rayleigh ~ lambda^-4 plus a grey aerosol part). A ray that
  misses the Earth passes the tangent height ``h_t`` (closest approach to the ellipsoid, from the
  scaled sphere) and crosses the air mass ``m = 2 sqrt(pi R / 2H) exp(-h_t / H)``; its radiance is
  ``P(gamma)/4 (1 - exp(-tau m)) T_sun``: flat and saturated below ~15 km, then falling off by
  ``e`` every ``H`` upwards. Where a camera's binarisation threshold cuts this profile decides the
  apparent horizon height: that is the effective atmosphere thickness ``d`` of 003 eq. (5), which
  004 (§3.4.3) observed as a threshold-dependent bias and 003 §4 shows the nadir estimate to be
  insensitive to. :func:`limb_profile` gives the profile so a test can compute ``d`` for a
  threshold. Rays that hit the ground carry airlight ``P/4 (1 - exp(-tau m_v)) T_sun`` and an
  attenuated surface; the Sun light is reddened by the air mass towards the Sun ``T_sun``; the limb
  is lit only above the Earth's shadow. ``P`` is Rayleigh plus a Henyey-Greenstein forward lobe
  (the bright limb towards the Sun).
* **Sun**: a disc of 0.267 deg radius with radiance ``1 / sin^2(r_sun)`` (about 46 000 times a white
  Lambertian surface under the overhead Sun: always saturated), dimmed by the limb when low; the
  lens adds bloom and veiling glare ``A g0^2 / (g0^2 + gamma^2)`` around it (why the saturated Sun
  ellipse looks larger than the disc, 003 §5), a starburst from the aperture, and lens-flare ghosts
  on the line from the Sun's image through the principal point. 004's "image disturbances"
  (Sun in the image, flares, too bright illumination) are these.
* **Payload**: a polygon at the image edge where the vehicle's skin is in view (003 fig. 9: "the
  area on the right where the payload is visible"); the skin is a cylinder seen edge-on whose
  normal turns from the silhouette towards the camera; it is diffusely lit, and when the Sun is in
  the right place it shows an elongated specular smear near the mask edge (003 fig. 23: "the
  sunlight is strongly reflected on the surface of the sounding rocket").
* **Moon**: a sphere of geometric albedo 0.12 lit by the Sun (phases with the terminator), shaded
  with the Lommel-Seeliger law ``2 p mu0 / (mu0 + mu) exp(-0.85 g)`` (mu0, mu the incidence and
  emission cosines, g the phase angle): no limb darkening at full Moon, the lit limb the brightest
  part, as the real Moon; where in view and not behind the Earth.
* **Sensor**: automatic exposure (average metering with highlight headroom, as action cameras
  do; 004's brightness gate), optional vignetting, motion blur from the body rate during the
  exposure, photon (Poisson, Gaussian approximation) and read noise, saturation at the full-well
  capacity, gamma 2.2 tone curve, 8-bit RGB, JPEG (``cv2.imencode``).

Everything is deterministic from ``seed``. ``RenderOptions.geometric()`` switches everything but
the ellipsoid off (uniformly white Earth on black space): the clean mode for geometric tests.
Units of radiance: 1 = a white Lambertian surface under the overhead Sun outside the atmosphere.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Iterator, Mapping, Sequence

import cv2
import numpy as np

from nav import earth
from nav.rotation import rotvec_to_matrix
from scenarios.sim import _render_kernel as K
from scenarios.sim import clouds
from vision.camera import CAMERA_TYPES, Camera, pixel_rays, project

__all__ = [
    "SUN_ANGULAR_RADIUS",
    "SUN_RADIANCE",
    "DEFAULT_PAYLOAD_MASK",
    "RenderOptions",
    "RenderedFrame",
    "FrameTruth",
    "render_frame",
    "encode_jpeg",
    "render_flight_frames",
    "limb_profile",
    "ray_ellipsoid",
    "payload_mask",
]

#: Mean apparent angular radius of the Sun [rad] (0.267 deg).
SUN_ANGULAR_RADIUS = math.radians(0.267)
#: Sun disc radiance relative to a white Lambertian surface under the overhead Sun: pi / Omega_sun.
SUN_RADIANCE = 1.0 / math.sin(SUN_ANGULAR_RADIUS) ** 2
_MOON_RADIUS = 1_737_400.0
_LOWRES = 4  # factor of the low-resolution payload / flare buffers

#: Payload region (x, y) as fractions of the image width/height: a band on the right edge with a
#: bowed inner edge (the vehicle skin seen through the fisheye lens), as in 003 fig. 9.
DEFAULT_PAYLOAD_MASK = ((0.945, 0.0), (1.0, 0.0), (1.0, 1.0), (0.905, 1.0), (0.918, 0.75),
                        (0.925, 0.5), (0.932, 0.25))


@dataclass(frozen=True)
class RenderOptions:
    """Switches and parameters of :func:`render_frame` (defaults: the ATEK-like look).

    Atmosphere: ``atmosphere_scale_height_m`` H, ``atmosphere_tau`` vertical optical depth (R, G, B),
    ``atmosphere_gain`` multiplies the scattered radiance, ``aerosol_weight``/``aerosol_g`` the
    Henyey-Greenstein part of the phase function; ``limb_shift_m`` lifts the air of the limb (rays
    that miss the Earth) by this height [m] (negative: lowers it), which moves the limb's
    brightness edge by as much without changing its shape (model-mismatch renders: an edge the
    front end does not assume; the ground's airlight is unchanged). Clouds: ``cloud_cover`` fraction in [0, 1],
    ``cloud_map_size`` texels per cube face, ``cloud_detail`` amplitude of the fine noise,
    ``detail_period_m`` its repeat length. Sun: ``sun_disc``, ``sun_bloom``, ``sun_glare``,
    ``lens_flare`` (ghosts and starburst). ``payload_mask``: polygon in image fractions or None;
    ``payload_reflections`` the specular smear. Exposure: ``exposure`` = "auto" or a fixed factor
    (radiance -> full scale), ``exposure_target`` mean signal of auto exposure,
    ``exposure_limits``. Sensor: ``noise``, ``full_well_e``, ``read_noise_e``, ``vignetting``
    (relative loss at the farthest corner, 0 = off), ``motion_blur`` with ``exposure_time_s``,
    ``gamma`` of the tone curve, ``jpeg_quality`` (1..100).
    """

    atmosphere: bool = True
    atmosphere_scale_height_m: float = 8000.0
    atmosphere_tau: tuple[float, float, float] = (0.09, 0.15, 0.27)
    atmosphere_gain: float = 1.0
    aerosol_weight: float = 0.25
    aerosol_g: float = 0.75
    limb_shift_m: float = 0.0
    clouds: bool = True
    cloud_cover: float = 0.45
    cloud_map_size: int = 1024
    cloud_detail: float = 0.35
    detail_period_m: float = 150e3
    terminator: bool = True
    moon: bool = True
    sun_disc: bool = True
    sun_bloom: bool = True
    sun_glare: bool = True
    lens_flare: bool = True
    payload_mask: tuple[tuple[float, float], ...] | None = DEFAULT_PAYLOAD_MASK
    payload_reflections: bool = True
    exposure: Any = "auto"
    white_balance: bool = True
    exposure_target: float = 0.30
    exposure_limits: tuple[float, float] = (0.3, 300.0)
    noise: bool = True
    full_well_e: float = 6000.0
    read_noise_e: float = 4.0
    vignetting: float = 0.3
    motion_blur: bool = True
    exposure_time_s: float = 1.0 / 1000.0
    gamma: float = 2.2
    black_level: float = 0.01
    jpeg_quality: int = 90

    def __post_init__(self) -> None:
        def bad(name, expected):
            raise ValueError(f"RenderOptions.{name} = {getattr(self, name)!r}; expected {expected}")

        for name in ("atmosphere_scale_height_m", "full_well_e", "gamma", "detail_period_m",
                     "exposure_target"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                bad(name, "a finite number > 0")
        if not (isinstance(self.limb_shift_m, (int, float)) and abs(self.limb_shift_m) <= 100e3):
            bad("limb_shift_m", "a height shift [m] within +-100 km")
        for name in ("atmosphere_gain", "read_noise_e", "cloud_detail", "exposure_time_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                bad(name, "a finite number >= 0")
        tau = self.atmosphere_tau
        if len(tau) != 3 or not all(math.isfinite(t) and t >= 0 for t in tau):
            bad("atmosphere_tau", "three finite optical depths >= 0 (R, G, B)")
        if not 0.0 <= self.cloud_cover <= 1.0:
            bad("cloud_cover", "a fraction in [0, 1]")
        if not 0.0 <= self.aerosol_weight <= 1.0:
            bad("aerosol_weight", "a weight in [0, 1]")
        if not -0.99 < self.aerosol_g < 0.99:
            bad("aerosol_g", "an asymmetry parameter in (-0.99, 0.99)")
        if not 0.0 <= self.black_level < 0.5:
            bad("black_level", "a linear level in [0, 0.5)")
        if not 0.0 <= self.vignetting < 1.0:
            bad("vignetting", "a relative loss in [0, 1)")
        if not (isinstance(self.jpeg_quality, int) and 1 <= self.jpeg_quality <= 100):
            bad("jpeg_quality", "an integer in 1..100")
        if int(self.cloud_map_size) != self.cloud_map_size or not 16 <= self.cloud_map_size <= 4096:
            bad("cloud_map_size", "an integer in [16, 4096]")
        lo, hi = self.exposure_limits
        if not 0 < lo <= hi:
            bad("exposure_limits", "(min, max) with 0 < min <= max")
        if not (self.exposure == "auto" or (isinstance(self.exposure, (int, float))
                                            and math.isfinite(self.exposure) and self.exposure > 0)):
            bad("exposure", "'auto' or a number > 0")
        if self.payload_mask is not None:
            pts = np.asarray(self.payload_mask, dtype=float)
            if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3 or not np.all(np.isfinite(pts)):
                bad("payload_mask", "a polygon of at least 3 (x, y) image fractions, or None")

    @classmethod
    def geometric(cls, **overrides) -> "RenderOptions":
        """Clean geometric mode: uniformly white Earth (pixel value 255 where the centre ray hits
        the ellipsoid) on black space; no atmosphere, clouds, terminator, Sun, Moon, payload,
        noise, vignetting or blur; fixed exposure."""
        base = dict(atmosphere=False, clouds=False, terminator=False, moon=False, sun_disc=False,
                    sun_bloom=False, sun_glare=False, lens_flare=False, payload_mask=None,
                    payload_reflections=False, exposure=1.0, noise=False, vignetting=0.0,
                    motion_blur=False, gamma=1.0, black_level=0.0, white_balance=False)
        base.update(overrides)
        return cls(**base)


@dataclass
class RenderedFrame:
    """A rendered image and its truth.

    ``image`` (H, W, 3) uint8 RGB. ``pixel_class`` (H, W) uint8: 0 space, 1 Earth (centre ray hits
    the ellipsoid), 2 payload, 3 Sun disc, 4 Moon disc. Camera-frame unit vectors: ``e_c_earth``
    (to the Earth's centre: 003's nadir vector e_c for the spherical model), ``e_c_sun``,
    ``e_c_moon`` (None without Moon). ``sun_uv``/``moon_uv`` pixel coordinates (NaN beyond the
    lens's range), ``sun_visible`` fraction of the Sun's disc in the image and not hidden by the
    Earth or the payload, ``alpha`` the Earth-cone half angle arcsin(R_mean / |x_e|) (003 eq. (5),
    d = 0), ``height_m``, ``exposure`` (radiance -> full scale), ``saturated_fraction`` of pixels
    with a channel at 255, ``payload_mask`` (H, W) bool.
    """

    image: np.ndarray
    pixel_class: np.ndarray
    e_c_earth: np.ndarray
    e_c_sun: np.ndarray
    e_c_moon: np.ndarray | None
    sun_uv: np.ndarray
    moon_uv: np.ndarray | None
    sun_visible: float
    alpha: float
    height_m: float
    exposure: float
    saturated_fraction: float
    payload_mask: np.ndarray

    @property
    def earth_mask(self) -> np.ndarray:
        """Pixels whose centre ray hits the ellipsoid (outside the payload region)."""
        return self.pixel_class == 1


# ------------------------------------------------------------------------------------------------
# geometry helpers (numpy; also the independent reference for tests)


def ray_ellipsoid(x_e: np.ndarray, d_e: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays from ``x_e`` along ``d_e`` (..., 3) against the WGS-84 ellipsoid.

    Returns ``hit`` (bool), ``t`` (range [m] to the first intersection for unit ``d_e``, NaN on a
    miss) and ``h_t``: the tangent height [m] of a miss (height of the closest approach in the
    scaled-sphere metric, (|p'| - 1) times the local radius), 0 for hits.
    """
    x = np.asarray(x_e, dtype=float)
    d = np.asarray(d_e, dtype=float)
    s = np.array([1.0 / earth.A, 1.0 / earth.A, 1.0 / earth.B])
    o = x * s
    q = d * s
    a = np.sum(q * q, axis=-1)
    b = np.sum(o * q, axis=-1)
    c = np.sum(o * o, axis=-1) - 1.0
    disc = b * b - a * c
    hit = (disc >= 0.0) & (b < 0.0)
    with np.errstate(invalid="ignore"):
        t = np.where(hit, (-b - np.sqrt(np.where(hit, disc, 0.0))) / a, np.nan)
    tc = np.maximum(-b / a, 0.0)
    p = o + tc[..., None] * q
    rho = np.linalg.norm(p, axis=-1)
    rloc = np.linalg.norm(p / s, axis=-1) / rho
    h_t = np.where(hit, 0.0, (rho - 1.0) * rloc)
    return hit, t, h_t


def limb_profile(h_t: np.ndarray, options: RenderOptions | None = None, *,
                 sun_elevation_deg: float = 90.0, scattering_deg: float = 90.0) -> np.ndarray:
    """Radiance (..., 3) of the sunlit limb at tangent heights ``h_t`` [m] (the model above):
    ``P(gamma)/4 * gain * (1 - exp(-tau m(h_t))) * T_sun`` with ``m = 2 sqrt(pi R / 2H) e^(-h/H)``,
    ``h = h_t - limb_shift_m``.

    For a binarisation threshold ``L_thr`` on this curve, the height where it is crossed is the
    effective atmosphere thickness ``d`` of 003 eq. (5) (before exposure and noise).
    """
    o = options or RenderOptions()
    h = np.asarray(h_t, dtype=float)[..., None] - o.limb_shift_m
    H = o.atmosphere_scale_height_m
    chmax = math.sqrt(math.pi * earth.R_MEAN / (2.0 * H))
    tau = np.asarray(o.atmosphere_tau)
    c = math.cos(math.radians(scattering_deg))
    g = o.aerosol_g
    den = 1 + g * g - 2 * g * c
    phase = ((1 - o.aerosol_weight) * 0.75 * (1 + c * c)
             + o.aerosol_weight * (1 - g * g) / den**1.5) * 0.25 * o.atmosphere_gain
    mu = math.sin(math.radians(sun_elevation_deg))
    ms = np.exp(-h / H) / np.sqrt(mu * mu + 1 / chmax**2)
    m = 2 * chmax * np.exp(-h / H)
    return phase * (1 - np.exp(-tau * m)) * np.exp(-tau * ms)


# ------------------------------------------------------------------------------------------------
# per-camera precomputation (cached)


class _CameraData:
    def __init__(self, camera: Camera):
        self.camera = camera
        rays = pixel_rays(camera)
        if not np.all(np.isfinite(rays)):
            raise ValueError(f"camera {camera.name!r}: some pixel rays are undefined (beyond the "
                             f"lens's monotonic range); expected a camera valid over the image")
        self.rays = np.ascontiguousarray(rays, dtype=np.float32)
        # metering grid: every 8th pixel, offset 4 (centres of 8x8 blocks)
        self.rays_meter = np.ascontiguousarray(self.rays[4::8, 4::8])
        f = _LOWRES
        self.rays_lr = rays[f // 2::f, f // 2::f].astype(np.float64)
        self.lr_shape = self.rays_lr.shape[:2]
        # coarse grid for motion blur
        step = 16
        self.blur_step = step
        vv, uu = np.mgrid[0: camera.height + step: step, 0: camera.width + step: step].astype(float)
        self.blur_uv = np.stack([uu, vv], axis=-1)
        self.blur_rays = self._rays_at(self.blur_uv)
        self._vign: dict[float, np.ndarray] = {}
        self._masks: dict[tuple, tuple[np.ndarray, ...]] = {}

    def _rays_at(self, uv):
        from vision.camera import unproject

        return unproject(self.camera, uv)

    def vignetting(self, strength: float) -> np.ndarray:
        """cos^4-like radial falloff normalised to lose ``strength`` at the farthest corner."""
        v = self._vign.get(strength)
        if v is None:
            theta = np.arccos(np.clip(self.rays[..., 2].astype(np.float64), -1, 1))
            t_max = float(theta.max())
            v = (1.0 - strength * (np.sin(theta) / math.sin(t_max)) ** 2
                 if t_max < math.pi / 2 else 1.0 - strength * (theta / t_max) ** 2)
            v = np.ascontiguousarray(v, dtype=np.float32)
            self._vign[strength] = v
        return v

    def mask(self, polygon) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(full-res bool mask, meter-grid mask, low-res mask, low-res depth xi in [0, 1] from the
        mask edge)."""
        key = tuple(map(tuple, polygon))
        m = self._masks.get(key)
        if m is None:
            full = payload_mask(self.camera, polygon)
            dist = cv2.distanceTransform(full.astype(np.uint8), cv2.DIST_L2, 5)
            dmax = max(float(dist.max()), 1.0)
            f = _LOWRES
            lr_mask = cv2.dilate(full.astype(np.uint8), np.ones((2 * f + 1, 2 * f + 1), np.uint8))
            lr_mask = lr_mask[f // 2::f, f // 2::f].astype(bool)
            xi = (dist / dmax)[f // 2::f, f // 2::f]
            m = (full, np.ascontiguousarray(full[4::8, 4::8]), lr_mask, xi)
            self._masks[key] = m
        return m


_CAMERA_CACHE: dict[Camera, _CameraData] = {}


def _camera_data(camera: Camera) -> _CameraData:
    cd = _CAMERA_CACHE.get(camera)
    if cd is None:
        if len(_CAMERA_CACHE) >= 4:
            _CAMERA_CACHE.pop(next(iter(_CAMERA_CACHE)))
        cd = _CameraData(camera)
        _CAMERA_CACHE[camera] = cd
    return cd


def payload_mask(camera: Camera, polygon: Sequence[Sequence[float]]) -> np.ndarray:
    """Boolean (H, W) mask of the payload polygon given in image fractions (x of the width,
    y of the height): the region a detector must ignore (003 §3.1)."""
    pts = np.asarray(polygon, dtype=float) * [camera.width, camera.height]
    img = np.zeros((camera.height, camera.width), np.uint8)
    cv2.fillPoly(img, [np.round(pts * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    return img.astype(bool)


_LUTS: dict[tuple[float, float], np.ndarray] = {}


def _lut(gamma: float, black: float = 0.0) -> np.ndarray:
    """Tone curve, 4096 linear codes -> uint8: ((x - black) / (1 - black))^(1/gamma)."""
    t = _LUTS.get((gamma, black))
    if t is None:
        x = np.clip((np.linspace(0.0, 1.0, 4096) - black) / (1.0 - black), 0.0, 1.0)
        t = _LUTS[(gamma, black)] = np.round(255.0 * x ** (1.0 / gamma)).astype(np.uint8)
    return t


# ------------------------------------------------------------------------------------------------
# input checks


def _check_inputs(camera, R_ec, x_e, sun_e, moon_e):
    if not isinstance(camera, CAMERA_TYPES):
        raise ValueError(f"render_frame: camera must be a vision.camera model, got "
                         f"{type(camera).__name__}")
    R = np.asarray(R_ec, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"render_frame: R_ec must be a finite 3x3 rotation matrix, got shape {R.shape}")
    if np.max(np.abs(R @ R.T - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0:
        raise ValueError("render_frame: R_ec is not a proper rotation (R R^T != I or det < 0)")
    x = np.asarray(x_e, dtype=float)
    if x.shape != (3,) or not np.all(np.isfinite(x)):
        raise ValueError(f"render_frame: x_e must be a finite ECEF position (3,) [m], got {x_e!r}")
    s = np.asarray(sun_e, dtype=float)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.linalg.norm(s) < 1e10:
        raise ValueError("render_frame: sun_e must be the geocentric Sun position in e [m] "
                         "(nav.ephemeris.sun_position_e), |sun_e| ~ 1.5e11 m")
    m = None
    if moon_e is not None:
        m = np.asarray(moon_e, dtype=float)
        if m.shape != (3,) or not np.all(np.isfinite(m)) or np.linalg.norm(m) < 1e8:
            raise ValueError("render_frame: moon_e must be the geocentric Moon position in e [m] "
                             "(nav.ephemeris.moon_position_e) or None")
    h = float(earth.ecef_to_geodetic(x)[2])
    if not h > 1.0:
        raise ValueError(f"render_frame: the camera is {h:.1f} m above the WGS-84 ellipsoid; "
                         f"expected a camera above the surface (h > 1 m)")
    return R, x, s, m, h


# ------------------------------------------------------------------------------------------------
# lens effects and payload (low-resolution buffers)


def _sun_visibility(x, s_e, R_ec, camera, mask_full, tau_mean, H, chmax) -> tuple[float, float]:
    """Fraction of the Sun disc (61 sample rays) in the lens range, not behind the Earth or the
    payload; and the mean transmission of the limb along those rays."""
    sd = s_e / np.linalg.norm(s_e)
    a = np.cross(sd, [0.0, 0.0, 1.0] if abs(sd[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(sd, a)
    rr, ang = np.meshgrid(np.sqrt((np.arange(5) + 0.5) / 5.0), np.linspace(0, 2 * np.pi, 12, endpoint=False))
    off = SUN_ANGULAR_RADIUS * (rr.ravel()[:, None] * (np.cos(ang.ravel())[:, None] * a
                                                         + np.sin(ang.ravel())[:, None] * b))
    dirs = np.vstack([sd, sd + off])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hit, _, h_t = ray_ellipsoid(np.broadcast_to(x, dirs.shape), dirs)
    uv = project(camera, dirs @ R_ec)  # rows: R_ec^T d
    ok = ~hit & np.all(np.isfinite(uv), axis=1)
    if mask_full is not None:
        inside = ok & (uv[:, 0] > -0.5) & (uv[:, 0] < camera.width - 0.5) & \
            (uv[:, 1] > -0.5) & (uv[:, 1] < camera.height - 0.5)
        iu = np.clip(np.round(uv[inside, 0]).astype(int), 0, camera.width - 1)
        iv = np.clip(np.round(uv[inside, 1]).astype(int), 0, camera.height - 1)
        blocked = np.zeros(len(dirs), bool)
        blocked[np.nonzero(inside)[0][mask_full[iv, iu]]] = True
        ok &= ~blocked
    vis = float(np.mean(ok))
    if vis == 0.0:
        return 0.0, 0.0
    trans = float(np.mean(np.exp(-tau_mean * 2 * chmax * np.exp(-h_t[ok] / H))))
    return vis, trans


def _flare(cd: _CameraData, sun_uv, strength: float, seed: int) -> np.ndarray:
    """Low-res additive buffer: ghosts on the line Sun image -> principal point, and a
    six-ray starburst around the Sun's image. ``strength`` in radiance units."""
    cam = cd.camera
    h, w = cd.lr_shape
    f = _LOWRES
    out = np.zeros((h, w, 3), np.float32)
    if strength <= 0 or not np.all(np.isfinite(sun_uv)):
        return out
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    xx = xx * f + f // 2
    yy = yy * f + f // 2
    c = np.array([cam.cx, cam.cy])
    sv = np.asarray(sun_uv, float)
    rng = np.random.default_rng([seed & 0x7FFFFFFF, 0xF1A2E])
    ghosts = [(-0.25, 0.018, (0.5, 1.0, 0.6), 1.0), (-0.55, 0.05, (0.6, 0.5, 1.0), 0.35),
              (-0.9, 0.09, (1.0, 0.7, 0.4), 0.18), (-1.35, 0.035, (0.5, 0.9, 1.0), 0.5),
              (0.35, 0.025, (1.0, 0.6, 0.9), 0.4), (0.6, 0.06, (0.6, 1.0, 0.8), 0.15)]
    for k, rad, col, amp in ghosts:
        p = c + k * (sv - c)
        r = rad * cam.height * (0.9 + 0.2 * rng.random())
        sl = _lr_box(p, r, f, h, w)
        if sl is None:
            continue
        d = np.hypot(xx[sl] - p[0], yy[sl] - p[1]) / r
        prof = np.clip(1.0 - d, 0, None) ** 0.5 * (0.6 + 0.4 * d)  # brighter rim
        prof[d > 1] = 0
        out[sl] += (strength * amp * prof)[..., None] * np.asarray(col, np.float32)
    # starburst: six rays (three lines) from the aperture blades, within 5 decay lengths
    sl = _lr_box(sv, 700.0, f, h, w)
    if sl is not None:
        du, dv = xx[sl] - sv[0], yy[sl] - sv[1]
        dist = np.hypot(du, dv)
        for ang in (math.radians(15), math.radians(75), math.radians(135)):
            ca, sa = math.cos(ang), math.sin(ang)
            perp = np.abs(-du * sa + dv * ca)
            ray = np.exp(-0.5 * (perp / 2.5) ** 2) * np.exp(-dist / 140.0) * (30.0 / (30.0 + dist))
            out[sl] += (strength * 6.0 * ray)[..., None]
    return out


def _lr_box(p, r, f, h, w):
    """Slice of the low-res grid covering the disc of radius r [px] around p (full-res px)."""
    i0, i1 = int(max(0, (p[1] - r) // f)), int(min(h, (p[1] + r) // f + 2))
    j0, j1 = int(max(0, (p[0] - r) // f)), int(min(w, (p[0] + r) // f + 2))
    if i0 >= i1 or j0 >= j1:
        return None
    return (slice(i0, i1), slice(j0, j1))


def _payload_radiance(cd: _CameraData, polygon, R_ec, s_e, sun_unocc: float,
                      earth_fill: float, reflections: bool) -> np.ndarray:
    """Low-res radiance of the payload skin: a cylinder whose normal turns from the silhouette
    (perpendicular to the ray, towards the image centre) to facing the camera with the depth xi
    into the mask; diffuse (albedo 0.35) + earthshine + anisotropic specular lobe elongated along
    the cylinder axis (image vertical): sigma 2.5 deg across, 12 deg along."""
    h, w = cd.lr_shape
    _, _, lr_mask, xi = cd.mask(polygon)
    out = np.zeros((h, w, 3), np.float32)
    r = cd.rays_lr[lr_mask]
    xiv = np.clip(xi[lr_mask], 0, 1)
    s_c = R_ec.T @ (s_e / np.linalg.norm(s_e))
    left = np.array([-1.0, 0.0, 0.0])
    t = left - (r @ left)[:, None] * r
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    beta = np.radians(70.0) * xiv
    n = np.cos(beta)[:, None] * t - np.sin(beta)[:, None] * r
    mu = np.clip(n @ s_c, 0, None) * sun_unocc
    diffuse = 0.35 * mu + 0.04 * earth_fill
    val = np.repeat(diffuse[:, None], 3, axis=1) * np.array([1.0, 0.98, 0.95])
    if reflections and sun_unocc > 0:
        refl = r - 2.0 * np.sum(r * n, axis=1, keepdims=True) * n
        e = refl - s_c
        axis = np.array([0.0, 1.0, 0.0])
        ea = e @ axis
        ep = np.linalg.norm(e - ea[:, None] * axis, axis=1)
        sa, sp = math.radians(12.0), math.radians(2.5)
        lobe = np.exp(-0.5 * ((ea / sa) ** 2 + (ep / sp) ** 2)) / (2.0 * sa * sp)
        val += (0.4 * lobe * (mu > 0))[:, None]
    out[lr_mask] = val
    return out


# ------------------------------------------------------------------------------------------------
# main entry


def _params(cam_h, R, x, s_dir, m_dir, m_cos, o: RenderOptions, sun_on: float, bloom: float,
            glare: float, exposure: float, moon_on: bool, wb=(1.0, 1.0, 1.0)) -> np.ndarray:
    P = np.zeros(K.N_PARAMS)
    P[K.R0:K.R0 + 9] = R.ravel()
    P[K.O0:K.O0 + 3] = x / np.array([earth.A, earth.A, earth.B])
    P[K.S0:K.S0 + 3] = s_dir
    P[K.M0:K.M0 + 3] = m_dir
    P[K.COS_SUN] = math.cos(SUN_ANGULAR_RADIUS)
    P[K.COS_MOON] = m_cos if moon_on else 2.0
    P[K.SUN_L] = SUN_RADIANCE if sun_on else 0.0
    P[K.BLOOM_A] = bloom
    P[K.BLOOM_G2] = math.radians(0.5) ** 2
    P[K.GLARE_A] = glare
    P[K.GLARE_G2] = math.radians(7.0) ** 2
    P[K.MOON_ALB] = 0.12
    P[K.H_CAM] = cam_h
    P[K.ATM] = 1.0 if o.atmosphere else 0.0
    P[K.H_SCALE] = o.atmosphere_scale_height_m
    P[K.TAU0:K.TAU0 + 3] = o.atmosphere_tau
    P[K.CH_MAX] = math.sqrt(math.pi * earth.R_MEAN / (2.0 * o.atmosphere_scale_height_m))
    P[K.ATM_GAIN] = o.atmosphere_gain
    P[K.MIE_W] = o.aerosol_weight
    P[K.MIE_G] = o.aerosol_g
    P[K.TERMINATOR] = 1.0 if o.terminator else 0.0
    P[K.CLOUDS] = 1.0 if o.clouds else 0.0
    P[K.CLOUD_COVER] = o.cloud_cover
    P[K.DETAIL_AMP] = o.cloud_detail
    # one unit of face coordinate ~ pi/4 radians of arc near a face centre
    P[K.DETAIL_SCALE] = 0.25 * math.pi * earth.A / o.detail_period_m
    P[K.AXIS_A] = earth.A
    P[K.AXIS_B] = earth.B
    P[K.EXPOSURE] = exposure
    P[K.FULL_WELL] = o.full_well_e
    P[K.READ_NOISE] = o.read_noise_e
    P[K.NOISE] = 1.0 if o.noise else 0.0
    P[K.FLAT_EARTH] = 1.0 if (not o.atmosphere and not o.clouds and not o.terminator) else 0.0
    P[K.R_MEAN] = earth.R_MEAN
    P[K.WB0:K.WB0 + 3] = wb
    P[K.TT_INV_DM] = 1.0 / _TT_DM
    P[K.LIMB_SHIFT] = o.limb_shift_m
    return P


_TT_DM = 0.02
_TTABS: dict[tuple, np.ndarray] = {}


def _ttab(o: RenderOptions) -> np.ndarray:
    """Transmission table exp(-tau_k m) for air masses m = 0, dm, ... 2 * sqrt(pi R / 2H) + 1."""
    key = (o.atmosphere_tau, o.atmosphere_scale_height_m)
    t = _TTABS.get(key)
    if t is None:
        chmax = math.sqrt(math.pi * earth.R_MEAN / (2.0 * o.atmosphere_scale_height_m))
        m = np.arange(0.0, 2.0 * chmax + 1.0 + _TT_DM, _TT_DM)
        t = _TTABS[key] = np.exp(-np.outer(m, np.asarray(o.atmosphere_tau, float)))
    return t


_EMPTY3 = np.zeros((1, 1, 3), np.float32)
_EMPTY_MASK = np.zeros((1, 1), np.bool_)
_EMPTY_VIGN = np.ones((1, 1), np.float32)


def render_frame(camera: Camera, R_ec, x_e, sun_e, moon_e=None, *, seed: int = 0,
                 options: RenderOptions | None = None, omega_c=None,
                 cloud_seed: int | None = None) -> RenderedFrame:
    """Render one camera frame at a truth pose.

    Parameters
    ----------
    camera : any vision.camera model (fisheye, equidistant, pinhole)
        Intrinsics (003 eqs. (13)-(16)).
    R_ec : (3, 3)
        Camera attitude, camera frame c -> e (docs/conventions.md "Rotations").
    x_e : (3,)
        Camera position in e [m] (above the ellipsoid).
    sun_e, moon_e : (3,)
        Geocentric Sun and Moon positions in e [m] (:func:`nav.ephemeris.sun_position_e`); the
        directions from ``x_e`` include the parallax. ``moon_e`` may be None.
    seed : int
        Seed of the noise (same seeds, same image).
    options : RenderOptions
        Defaults to ``RenderOptions()``.
    omega_c : (3,), optional
        Angular rate of the camera w.r.t. inertial space, in c [rad/s], for motion blur over
        ``options.exposure_time_s``.
    cloud_seed : int, optional
        Seed of the weather (cloud and ground maps) and of the lens-flare ghost sizes; defaults to
        ``seed``. A flight uses one cloud seed for all frames and cameras.

    Returns
    -------
    RenderedFrame
        ``.image`` (H, W, 3) uint8 RGB and the truth fields.
    """
    o = options or RenderOptions()
    R, x, sun, moon, h = _check_inputs(camera, R_ec, x_e, sun_e, moon_e)
    seed = int(seed)
    cseed = seed if cloud_seed is None else int(cloud_seed)
    cd = _camera_data(camera)
    s_dir = (sun - x) / np.linalg.norm(sun - x)
    s_c = R.T @ s_dir
    sun_uv = project(camera, s_c)
    m_dir = np.zeros(3)
    m_cos = 2.0
    e_c_moon = moon_uv = None
    if moon is not None:
        m_dir = (moon - x) / np.linalg.norm(moon - x)
        m_cos = math.cos(math.asin(min(1.0, _MOON_RADIUS / np.linalg.norm(moon - x))))
        e_c_moon = R.T @ m_dir
        moon_uv = project(camera, e_c_moon)
    polygon = o.payload_mask
    if polygon is not None:
        mask_full, mask_meter, _, _ = cd.mask(polygon)
    else:
        mask_full = mask_meter = None
    H = o.atmosphere_scale_height_m
    chmax = math.sqrt(math.pi * earth.R_MEAN / (2.0 * H))
    tau_mean = float(np.mean(o.atmosphere_tau)) if o.atmosphere else 0.0
    vis, trans = _sun_visibility(x, sun, R, camera, mask_full, tau_mean, H, chmax)
    # the Sun's light reaching the lens (for glare and flare) also counts just outside the image
    sun_light = trans * _visible_to_lens(x, s_dir, R, camera)
    any_sun = o.sun_disc or o.sun_bloom or o.sun_glare or o.lens_flare
    bloom = 1.5e-4 * SUN_RADIANCE * sun_light if o.sun_bloom else 0.0
    glare = 2.5e-6 * SUN_RADIANCE * sun_light if o.sun_glare else 0.0
    has_glare = bloom > 0 or glare > 0

    add = _EMPTY3
    if o.lens_flare and sun_light > 0 and np.all(np.isfinite(sun_uv)):
        add = _flare(cd, sun_uv, 2.5e-6 * SUN_RADIANCE * vis * trans, cseed)
    has_add = add.shape[0] > 1

    payload = _EMPTY3
    if polygon is not None:
        earth_fill = 0.3
        payload = _payload_radiance(cd, polygon, R, sun, _sun_lit(x, s_dir), earth_fill,
                                    o.payload_reflections)
    has_mask = polygon is not None
    mask_arg = mask_full if has_mask else _EMPTY_MASK
    vign = cd.vignetting(o.vignetting) if o.vignetting > 0 else _EMPTY_VIGN
    has_vign = o.vignetting > 0
    cmap = clouds.cube_map(cseed, int(o.cloud_map_size)) if o.clouds else _DUMMY_CMAP
    detail = clouds.detail_tile(cseed) if o.clouds else _DUMMY_DETAIL
    moon_on = bool(o.moon and moon is not None)
    ttab = _ttab(o)

    # exposure
    if o.exposure == "auto":
        P = _params(h, R, x, s_dir, m_dir, m_cos, o, o.sun_disc and any_sun, bloom, glare, 1.0, moon_on)
        rm = cd.rays_meter
        rad = np.empty(rm.shape, np.float32)
        cls = np.empty(rm.shape[:2], np.uint8)
        K.render_radiance(rm, mask_meter if has_mask else _EMPTY_MASK, payload, add, _LOWRES / 8.0,
                          P, cmap, detail, ttab, has_mask, has_add, has_glare, rad, cls)
        if has_vign:
            rad *= vign[4::8, 4::8, None]
        exposure = _auto_exposure(rad, cls, o)
        wb = _white_balance(rad, cls) if o.white_balance else (1.0, 1.0, 1.0)
    else:
        exposure = float(o.exposure)
        wb = (1.0, 1.0, 1.0)
    P = _params(h, R, x, s_dir, m_dir, m_cos, o, o.sun_disc and any_sun, bloom, glare, exposure,
                moon_on, wb)
    lut = _lut(float(o.gamma), float(o.black_level))
    out = np.empty((camera.height, camera.width, 3), np.uint8)
    cls = np.empty((camera.height, camera.width), np.uint8)
    blur_disp = None
    if o.motion_blur and omega_c is not None:
        blur_disp = _blur_displacement(cd, np.asarray(omega_c, float), o.exposure_time_s)
    if blur_disp is None:
        sat_rows = np.empty(camera.height, np.int64)
        K.render_fused(cd.rays, mask_arg, payload, add, float(_LOWRES), vign, P, cmap, detail, ttab, lut,
                       seed & 0x7FFFFFFFFFFF, has_mask, has_add, has_glare, has_vign, out, cls, sat_rows)
        sat = float(sat_rows.sum()) / (camera.height * camera.width)
    else:
        rad = np.empty((camera.height, camera.width, 3), np.float32)
        K.render_radiance(cd.rays, mask_arg, payload, add, float(_LOWRES), P, cmap, detail, ttab,
                          has_mask, has_add, has_glare, rad, cls)
        blurred = np.empty_like(rad)
        K.motion_blur(rad, blur_disp, float(cd.blur_step), blurred)
        K.sensor_pass(blurred, vign, P, lut, seed & 0x7FFFFFFFFFFF, has_vign, out)
        sat = float(np.mean(np.any(out == lut[-1], axis=2)))
    e_earth = R.T @ (-x / np.linalg.norm(x))
    return RenderedFrame(
        image=out, pixel_class=cls, e_c_earth=e_earth, e_c_sun=s_c, e_c_moon=e_c_moon,
        sun_uv=sun_uv, moon_uv=moon_uv, sun_visible=_in_image_fraction(vis, sun_uv, camera),
        alpha=math.asin(min(1.0, earth.R_MEAN / np.linalg.norm(x))), height_m=h, exposure=exposure,
        saturated_fraction=sat,
        payload_mask=mask_full if mask_full is not None else np.zeros(cls.shape, bool))


_DUMMY_CMAP = np.zeros((6, 2, 2, 2), np.uint8)
_DUMMY_DETAIL = np.zeros((2, 2), np.float32)


def _in_image_fraction(vis: float, sun_uv, camera) -> float:
    if not np.all(np.isfinite(sun_uv)):
        return 0.0
    u, v = sun_uv
    return vis if (-0.5 < u < camera.width - 0.5 and -0.5 < v < camera.height - 0.5) else 0.0


def _sun_lit(x, s_dir) -> float:
    """1 if the vehicle is in sunlight (the Sun ray from x misses the Earth), else 0."""
    hit, _, _ = ray_ellipsoid(x, s_dir)
    return 0.0 if bool(hit) else 1.0


def _visible_to_lens(x, s_dir, R, camera) -> float:
    """Sunlight entering the lens: 1 inside the field of view, fading to 0 at 25 deg outside it,
    0 when the vehicle is in the Earth's shadow."""
    if _sun_lit(x, s_dir) == 0.0:
        return 0.0
    s_c = R.T @ s_dir
    theta = math.atan2(math.hypot(s_c[0], s_c[1]), s_c[2])
    # angle beyond the image border in that azimuth: use the lens range of the image corners
    excess = theta - camera.fov_theta
    if excess <= 0:
        return 1.0
    return max(0.0, 1.0 - excess / math.radians(25.0))


def _auto_exposure(rad: np.ndarray, cls: np.ndarray, o: RenderOptions) -> float:
    """Average metering with highlight headroom: k = target / mean(L) over non-Sun samples, and
    at most 1.15 / p99.5(L) so that only the brightest half percent clips."""
    y = rad.mean(axis=2)[cls != 3]
    lo, hi = o.exposure_limits
    if y.size == 0:
        return lo
    mean = float(np.mean(np.minimum(y, np.percentile(y, 99.0))))
    p = float(np.percentile(y, 99.5))
    k = o.exposure_target / max(mean, 1e-9)
    if p > 0:
        k = min(k, 1.15 / p)
    return float(min(max(k, lo), hi))


def _white_balance(rad: np.ndarray, cls: np.ndarray) -> tuple[float, float, float]:
    """Grey-world white balance on the Earth samples, 85 % corrected, gains within [0.6, 1.8]
    (green fixed at 1), as a camera's automatic white balance does."""
    e = rad[cls == 1]
    if e.shape[0] < 16:
        return (1.0, 1.0, 1.0)
    m = e.mean(axis=0).astype(float)
    if not np.all(m > 1e-9):
        return (1.0, 1.0, 1.0)
    g = np.clip((m[1] / m) ** 0.85, 0.6, 1.8)
    return (float(g[0]), 1.0, float(g[2]))


def _blur_displacement(cd: _CameraData, omega_c: np.ndarray, t_exp: float) -> np.ndarray | None:
    """Image displacement (end - start of the exposure) of scene points on the coarse grid, for
    a camera turning at ``omega_c``: a fixed direction's camera coordinates evolve as
    r(t) = exp(-[omega t x]) r(0). None if the motion is below half a pixel everywhere."""
    if omega_c.shape != (3,) or not np.all(np.isfinite(omega_c)):
        raise ValueError(f"render_frame: omega_c must be a finite (3,) rate [rad/s], got {omega_c!r}")
    phi = omega_c * t_exp
    if np.linalg.norm(phi) < 1e-9:
        return None
    r = cd.blur_rays
    a = project(cd.camera, r @ rotvec_to_matrix(0.5 * phi))       # exp(-[phi/2 x]) r
    b = project(cd.camera, r @ rotvec_to_matrix(-0.5 * phi))      # exp(+[phi/2 x]) r
    disp = np.nan_to_num(b - a)
    if np.max(np.hypot(disp[..., 0], disp[..., 1])) < 0.5:
        return None
    return np.ascontiguousarray(disp)


def encode_jpeg(image_rgb: np.ndarray, quality: int = 90) -> bytes:
    """JPEG bytes of an RGB uint8 image (``cv2.imencode``, baseline, 4:2:0)."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("cv2.imencode failed to encode the frame as JPEG")
    return buf.tobytes()


# ------------------------------------------------------------------------------------------------
# flight integration


@dataclass(frozen=True)
class FrameTruth:
    """Truth of one camera exposure: camera index, time [ns UTC], attitude R_ec, position x_e [m],
    optional camera rate omega_c [rad/s]."""

    camera_index: int
    t_ns: int
    R_ec: np.ndarray
    x_e: np.ndarray
    omega_c: np.ndarray | None = None


def _get(rec, name, default=None):
    if isinstance(rec, Mapping):
        return rec.get(name, default)
    return getattr(rec, name, default)


def render_flight_frames(scenario_cameras: Sequence[Camera], frames_truth: Iterable[Any], *,
                         seed: int = 0, options: RenderOptions | None = None,
                         progress: bool = True, ephemeris: Any = None,
                         total: int | None = None) -> Iterator[tuple[int, int, bytes]]:
    """Render and JPEG-encode every frame of a simulated flight.

    ``scenario_cameras``: the cameras' intrinsics, indexed by ``camera_index`` (a vision.camera model, or
    an object with a ``camera`` or ``intrinsics`` attribute holding one). ``frames_truth``: records
    (FrameTruth, or any mapping/object with ``camera_index``, ``t_ns``, ``R_ec``, ``x_e`` and
    optionally ``omega_c``). Sun and Moon come from :mod:`nav.ephemeris` at ``t_ns`` (pass
    ``ephemeris=(sun_position_e, moon_position_e)`` to override). Yields
    ``(camera_index, t_ns, jpeg_bytes)`` in input order; a tqdm progress bar on stderr unless
    ``progress=False``. The noise seed of frame i is derived from (seed, camera_index, t_ns), so a
    frame does not depend on which other frames are rendered.
    """
    from tqdm import tqdm

    if ephemeris is None:
        from nav.ephemeris import moon_position_e, sun_position_e
    else:
        sun_position_e, moon_position_e = ephemeris
    o = options or RenderOptions()
    cams = []
    for c in scenario_cameras:
        cam = c if isinstance(c, CAMERA_TYPES) else (_get(c, "camera") or _get(c, "intrinsics"))
        if not isinstance(cam, CAMERA_TYPES):
            raise ValueError(f"render_flight_frames: camera entry {c!r} is not a vision.camera model")
        cams.append(cam)
    if total is None and hasattr(frames_truth, "__len__"):
        total = len(frames_truth)  # type: ignore[arg-type]
    bar = tqdm(total=total, desc="render", unit="frame", disable=not progress)
    try:
        for rec in frames_truth:
            k = int(_get(rec, "camera_index"))
            t = int(_get(rec, "t_ns"))
            if not 0 <= k < len(cams):
                raise ValueError(f"render_flight_frames: camera_index {k} at t_ns {t} is out of "
                                 f"range; {len(cams)} camera(s)")
            frame_seed = _frame_seed(seed, k, t)
            fr = render_frame(cams[k], _get(rec, "R_ec"), _get(rec, "x_e"), sun_position_e(t),
                              moon_position_e(t), seed=frame_seed, options=o,
                              omega_c=_get(rec, "omega_c"), cloud_seed=seed)
            yield k, t, encode_jpeg(fr.image, o.jpeg_quality)
            bar.update(1)
    finally:
        bar.close()


def _frame_seed(seed: int, k: int, t_ns: int) -> int:
    """Per-frame noise seed; the cloud map depends on ``seed`` only (weather fixed for a flight)."""
    return int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, k, t_ns & 0xFFFFFFFFFFFF]).generate_state(1)[0])


def flight_frame_truths(flight: Any) -> list[FrameTruth]:
    """Per-frame truth records of a simulated flight (:class:`scenarios.sim.simulate.FlightData`),
    camera by camera: ``camera_index`` is the position in ``flight.cameras``, ``t_ns`` the true
    capture time (UTC), ``R_ec = R_eb R_bc`` with the true mount, ``omega_c = R_bc^T omega_ib_b``."""
    from nav.rotation import quat_to_matrix

    tr = flight.truth
    out = []
    for i, run in enumerate(flight.cameras):
        t_s = run.truth.t
        idx = np.round(t_s / tr.dt).astype(int)
        R_eb = quat_to_matrix(tr.q_eb[idx])
        R_ec = R_eb @ run.R_bc
        om = tr.omega_ib_b[idx] @ run.R_bc  # rows: R_bc^T omega_b
        t_true = tr.liftoff_ns + np.round(t_s * 1e9).astype(np.int64)
        for n in range(len(idx)):
            out.append(FrameTruth(i, int(t_true[n]), R_ec[n], tr.x_e[idx[n]], om[n]))
    return out


def scenario_render_options(scenario: Any, jpeg_quality: int | None = None) -> RenderOptions:
    """The renderer's options for a scenario's images: the default look with the scenario's
    ``[render]`` table (payload drawn or not, limb shift) and an optional JPEG quality."""
    rc = scenario.render
    kw: dict[str, Any] = {"limb_shift_m": rc.limb_shift_m}
    if not rc.payload:
        kw.update(payload_mask=None, payload_reflections=False)
    if jpeg_quality is not None:
        kw["jpeg_quality"] = jpeg_quality
    return RenderOptions(**kw)


def render_flight_images(flight: Any, *, options: RenderOptions | None = None,
                         progress: bool = True) -> Iterator[tuple[int, int, bytes]]:
    """Render every camera frame of a simulated flight for the log: yields ``(k, stamp_ns, jpeg)``
    with ``k`` the camera number of :class:`scenarios.sim.simulate.CameraRun` (1-based) and the stamp
    on the camera's own clock (true time + ``clock_offset_s``), frames in time order per camera.
    The weather (cloud seed) is the flight's seed."""
    recs = flight_frame_truths(flight)
    runs = flight.cameras
    offsets = [int(round(r.clock_offset_s * 1e9)) for r in runs]
    for i, t, jpg in render_flight_frames([r.camera for r in runs], recs, seed=int(flight.seed),
                                          options=options, progress=progress):
        yield runs[i].k, t + offsets[i], jpg
