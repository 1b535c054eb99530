"""Rendered Moon frames with known truth for the Moon tests and the bench: a narrow-field camera
500 km above the Earth looking away from it, the Moon at its real distance (356-406 thousand km)
somewhere in the inner image, lit by the Sun from a chosen phase angle, at a chosen apparent
diameter in pixels (the camera's field of view is set for it), exposed so that the lit limb's
brightness ranges from a dim 40/255 to saturated (the renderer's Lommel-Seeliger Moon,
`scenarios.sim.render`), with photon and read noise and JPEG compression.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from nav import earth
from nav.ephemeris import MOON_RADIUS as MOON_RADIUS_M
from scenarios.sim import render
from vision.camera import from_fov, unproject

AU_M = 1.495978707e11
#: lens shapes r_d(theta) / f: "fisheye" equidistant (theta), "rectilinear" the pinhole's tan(theta)
#: as its odd series to theta^9 (within 2e-5 rad of tan below 30 deg off axis)
LENSES = {"fisheye": (1.0,), "rectilinear": (1.0, 1 / 3, 2 / 15, 17 / 315, 62 / 2835)}
_OPTS = render.RenderOptions(clouds=False, payload_mask=None, exposure=1.0, white_balance=False,
                             lens_flare=False)


@dataclass(frozen=True)
class MoonFrame:
    """One frame: ``image`` as decoded from JPEG (BGR), the camera, the truth Moon and Sun
    directions in the camera frame, the Moon's apparent radius [rad] and distance [m], the
    illuminated fraction, the peak linear signal of the lit limb and, where the Earth is in view,
    the truth geocentric nadir in the camera frame."""

    image: np.ndarray
    camera: object
    moon_c: np.ndarray
    sun_c: np.ndarray
    alpha: float
    distance_m: float
    lit_fraction: float
    signal: float
    earth_c: np.ndarray | None = None


def _unit(v):
    return v / np.linalg.norm(v)


def _perp(v, rng):
    t = np.cross(v, rng.normal(size=3))
    return _unit(t)


def moon_frame(rng: np.random.Generator, diameter_px: float, lit_fraction: float, signal: float,
               size=(400, 300), camera=None, seed: int = 0, lens: str = "fisheye") -> MoonFrame:
    """Render one Moon frame (see the module docstring). ``lit_fraction`` in (0, 1] sets the phase
    angle g, ``(1 + cos g) / 2 = lit_fraction``; ``signal`` the linear sensor signal of the lit
    limb (1 = full scale, above 1 saturated); ``camera`` None: a camera of the ``lens`` shape
    (`LENSES`) whose focal length gives the Moon ``diameter_px`` pixels across on the axis."""
    w, h = size
    dist = rng.uniform(356e6, 406e6)
    alpha = math.asin(MOON_RADIUS_M / dist)
    if camera is None:
        k = LENSES[lens]
        f = 0.5 * diameter_px / alpha
        half = _theta_of(k, 0.5 * w / f)
        camera = from_fov(w, h, math.degrees(2.0 * half), k)
    x = np.array([earth.A + 500e3, 0.0, 0.0])
    zen = _unit(x)
    t = _perp(zen, rng)
    bore = _unit(math.cos(math.radians(rng.uniform(0, 40))) * zen
                 + math.sin(math.radians(rng.uniform(0, 40))) * t)
    xc = _perp(bore, rng)
    R_ec = np.column_stack([xc, np.cross(bore, xc), bore])
    # Moon direction: inside 70 % of the half-width and half-height of the image
    uv = np.array([w / 2 + rng.uniform(-0.35, 0.35) * w, h / 2 + rng.uniform(-0.35, 0.35) * h])
    m_c = unproject(camera, uv)
    m_e = R_ec @ m_c
    g = math.acos(2.0 * lit_fraction - 1.0)
    eps = math.pi - g                       # elongation: angle Moon - camera - Sun
    s_e = _unit(math.cos(eps) * m_e + math.sin(eps) * _perp(m_e, rng))
    peak = 2.0 * 0.12 * math.exp(-0.85 * g)
    opts = _OPTS.__class__(**{**_OPTS.__dict__, "exposure": signal / peak})
    fr = render.render_frame(camera, R_ec, x, x + AU_M * s_e, x + dist * m_e, seed=seed, options=opts)
    img = cv2.imdecode(np.frombuffer(render.encode_jpeg(fr.image, 90), np.uint8), cv2.IMREAD_COLOR)
    return MoonFrame(img, camera, fr.e_c_moon, fr.e_c_sun, alpha, dist, lit_fraction, signal)


def _theta_of(k, r):
    """theta with r_d(theta) = r for the odd polynomial k (bisection)."""
    lo, hi = 0.0, 1.5
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        t2 = mid * mid
        val = mid * sum(c * t2 ** i for i, c in enumerate(k))
        lo, hi = (mid, hi) if val < r else (lo, mid)
    return 0.5 * (lo + hi)


def moon_set(n: int, seed: int = 0, size=(400, 300), lens: str = "fisheye"):
    """``n`` frames with diameters 8-60 px, 20-100 % lit, limb signals 0.04-2 (log-uniform: a dim
    40/255 half Moon to saturated)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        d = rng.uniform(8.0, 60.0)
        k = rng.uniform(0.2, 1.0)
        s = math.exp(rng.uniform(math.log(0.04), math.log(2.0)))
        out.append(moon_frame(rng, d, k, s, size=size, seed=seed * 1000 + i, lens=lens))
    return out


def moon_over_earth(rng: np.random.Generator, diameter_px: float, lit_fraction: float, size=(400, 300),
                    seed: int = 0) -> MoonFrame:
    """A rectilinear-lens camera 500 km up looking at the horizon: the Earth's limb (atmosphere,
    clouds) across the lower part of the image, the Moon above it, auto exposure set by the Earth
    (the Moon dim, as in orbital photographs). ``signal`` is NaN (the exposure decides it)."""
    w, h = size
    dist = rng.uniform(356e6, 406e6)
    alpha = math.asin(MOON_RADIUS_M / dist)
    k = LENSES["rectilinear"]
    f = 0.5 * diameter_px / alpha
    camera = from_fov(w, h, math.degrees(2.0 * _theta_of(k, 0.5 * w / f)), k)
    x = np.array([earth.A + 500e3, 0.0, 0.0])
    up = _unit(x)
    north = np.array([0.0, 0.0, 1.0])
    east = np.cross(north, up)
    az = rng.uniform(0, 2 * math.pi)
    fwd = math.cos(az) * north + math.sin(az) * east
    dip = math.acos(earth.A / np.linalg.norm(x))            # the horizon's depression
    half_v = math.atan(0.5 * h / f)
    el = -dip + 0.5 * half_v                                # the limb ~3/4 down the image
    bore = _unit(math.cos(el) * fwd + math.sin(el) * up)
    xc = _unit(np.cross(bore, up))                          # image x horizontal, v down = towards the Earth
    R_ec = np.column_stack([xc, np.cross(bore, xc), bore])
    uv = np.array([w / 2 + rng.uniform(-0.35, 0.35) * w, h * rng.uniform(0.15, 0.4)])
    m_e = R_ec @ unproject(camera, uv)
    g = math.acos(2.0 * lit_fraction - 1.0)
    eps = math.pi - g
    s_e = _unit(math.cos(eps) * m_e + math.sin(eps) * _perp(m_e, rng))
    opts = render.RenderOptions(payload_mask=None, cloud_map_size=256, lens_flare=False)
    fr = render.render_frame(camera, R_ec, x, x + AU_M * s_e, x + dist * m_e, seed=seed, options=opts)
    img = cv2.imdecode(np.frombuffer(render.encode_jpeg(fr.image, 90), np.uint8), cv2.IMREAD_COLOR)
    return MoonFrame(img, camera, fr.e_c_moon, fr.e_c_sun, alpha, dist, lit_fraction, math.nan, fr.e_c_earth)


def sun_and_moon(rng: np.random.Generator, camera, seed: int = 0) -> tuple[MoonFrame, object]:
    """The Sun near one corner of ``camera``'s image and the Moon near the opposite one (about
    90 deg apart: a half Moon), 500 km above the Earth looking away from it, auto exposure (the
    Sun saturated, its glare over the sky). Returns (MoonFrame, the rendered frame)."""
    w, h = camera.width, camera.height
    x = np.array([earth.A + 500e3, 0.0, 0.0])
    zen = _unit(x)
    bore = _unit(zen + 0.3 * _perp(zen, rng))
    xc = _perp(bore, rng)
    R_ec = np.column_stack([xc, np.cross(bore, xc), bore])
    s_c = unproject(camera, np.array([rng.uniform(0.03, 0.1) * w, rng.uniform(0.06, 0.18) * h]))
    m_c = unproject(camera, np.array([rng.uniform(0.86, 0.96) * w, rng.uniform(0.8, 0.92) * h]))
    dist = rng.uniform(356e6, 406e6)
    fr = render.render_frame(camera, R_ec, x, x + AU_M * (R_ec @ s_c), x + dist * (R_ec @ m_c), seed=seed,
                             options=render.RenderOptions(clouds=False, payload_mask=None))
    k = (1.0 - float(s_c @ m_c)) / 2.0
    return MoonFrame(fr.image, camera, fr.e_c_moon, fr.e_c_sun, math.asin(MOON_RADIUS_M / dist), dist, k,
                     math.nan), fr


def pinhole_moon_view(i: int, width: int = 640):
    """(camera, RenderedFrame, x_e) of `tests.poses.moon_poses` view ``i`` (of 4) through the 25 deg
    pinhole of scenarios/library/cameras/pinhole_25deg.toml scaled to ``width`` px (4:3), the
    limb lowered to the real cameras' 0-1 km, the Moon at T0_ORBIT_NS (half lit)."""
    from nav import ephemeris
    from scenarios.config.camera import load_camera
    from vision.camera import from_opencv

    from tests.poses import T0_ORBIT_NS, moon_poses

    cam = load_camera("scenarios/library/cameras/pinhole_25deg.toml")
    s, h = width / cam.width, width * 3 // 4
    K = np.array([[cam.fx * s, 0.0, (width - 1) / 2], [0.0, cam.fy * s, (h - 1) / 2], [0.0, 0.0, 1.0]])
    small = from_opencv(K, [-0.08, 0.12, 0.0002, -0.0001, 0.0], width, h, name=f"pinhole_25deg_{width}",
                        model="pinhole")
    R, x = moon_poses(4)[i]
    opts = render.RenderOptions(payload_mask=None, payload_reflections=False, limb_shift_m=-45e3)
    fr = render.render_frame(small, R, x, ephemeris.sun_position_e(T0_ORBIT_NS), ephemeris.moon_position_e(T0_ORBIT_NS),
                             seed=i, options=opts, cloud_seed=i)
    return small, fr, x
