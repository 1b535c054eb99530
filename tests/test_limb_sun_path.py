"""Sun-path model of the fraction-of-peak limb edge (vision/limb.py eq. (4)-(5)) and the geodetic
Sun elevation at the limb tangent point, against independent references: the renderer's own 1-D
limb radiance (scenarios.sim.render.limb_profile, a separate implementation of the same physics),
closed forms, and exact tangent geometry on the WGS-84 ellipsoid."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from nav import earth
from scenarios.sim import render
from vision.config import LimbOptions
from vision.limb import fraction_height_shift, profile_height_shift, sun_elevation, sun_path_ratio


def _half_peak_height(el_deg: float) -> float:
    """Height [m] where the renderer's red limb radiance crosses half its maximum, above it
    (1 m grid: the comparison below is at 50 m)."""
    h = np.arange(0.0, 80e3, 1.0)
    b = render.limb_profile(h, sun_elevation_deg=el_deg)[..., 0]
    j = int(np.argmax(b))
    return float(h[j + int(np.argmax(b[j:] < 0.5 * b[j]))])


def test_shift_kernel_is_eq5_with_the_table():
    """`fraction_height_shift` (one numba kernel) against eq. (5) written with the numpy pieces:
    ``-H (interp(ln c(mu)) - interp(ln c(1)))`` on the ``_uf_table`` grid with `sun_path_ratio`,
    over day, grazing and twilight mu (down to the Earth's shadow) and a 2-D input shape; to
    1e-6 m (the two interpolations differ by the rounding of the grid index only)."""
    from vision.limb import _uf_table
    mu = np.concatenate([np.linspace(-0.2, 1.0, 1202), [0.0, -1e-12, 1e-12]]).reshape(-1, 5)
    for frac, H in ((0.5, 8000.0), (0.3, 7000.0)):
        lnc, lnu = _uf_table(frac)
        want = -H * (np.interp(np.log(np.maximum(sun_path_ratio(mu, H), 1e-300)), lnc, lnu)
                     - np.interp(np.log(sun_path_ratio(np.array([1.0]), H)), lnc, lnu))
        got = fraction_height_shift(mu, frac, H)
        assert got.shape == mu.shape
        assert np.max(np.abs(got - want)) < 1e-6


@pytest.mark.parametrize("el", [30.0, 10.0, 5.0, 2.0, 0.5])
def test_shift_matches_the_limb_radiance(el):
    """h_f(el) - h_f(90 deg) from eq. (5) equals the shift of the half-peak crossing of the
    renderer's limb radiance within 50 m (the two differ only in the Chapman-function constant:
    R_MEAN there, 6371 km here, and the 1 m grid), over a range where the shift is 0.5..7 km."""
    ref = _half_peak_height(90.0)
    got = float(fraction_height_shift(np.array([math.sin(math.radians(el))]))[0])
    assert abs(got - (_half_peak_height(el) - ref)) < 50.0, (el, got, _half_peak_height(el) - ref)


def test_sun_path_ratio_closed_forms():
    """c(mu) = Ch(mu) / 2C: 0.5 at grazing incidence (the sunlight's path is one half of the
    line of sight's), ~1/(2C) overhead, continuous at mu = 0, growing below (twilight: the
    Sun-side half of the grazing path through the sunray's lowest point, R mu^2 / 2 below, plus
    the erf part up to the point, tending to the whole grazing path, c -> exp(R mu^2 / 2H))."""
    C = math.sqrt(math.pi * 6371e3 / 16e3)
    c = sun_path_ratio(np.array([1.0, 0.0, 1e-9, -1e-9, -0.02, -0.2]))
    assert c[0] == pytest.approx(1.0 / (2 * C) / math.sqrt(1 + 1 / C**2), rel=1e-12)
    assert c[1] == pytest.approx(0.5, rel=1e-12)
    assert c[2] == pytest.approx(0.5, rel=1e-9) and c[3] == pytest.approx(0.5, rel=1e-7)
    assert c[4] == pytest.approx(0.5 * math.exp(6371e3 * 0.02**2 / 16e3) * (1 + math.erf(0.02 * C / math.sqrt(math.pi))),
                                 rel=1e-12)
    assert c[5] == pytest.approx(math.exp(6371e3 * 0.2**2 / 16e3), rel=1e-7)   # erf(3.99) = 1 - 2e-8


@pytest.mark.parametrize("lat_deg, el_deg", [(68.0, 10.0), (45.0, -2.0), (0.0, 0.5), (-30.0, 60.0)])
def test_sun_elevation_at_the_tangent_point(lat_deg, el_deg):
    """A ray tangent to the ellipsoid at a known point P (from a camera 2000 km away along the
    tangent): the Sun placed at elevation el above P's geodetic horizon must come out at el
    (to 1e-6 rad; the geocentric vertical would be off by up to 0.19 deg)."""
    lat, lon = math.radians(lat_deg), math.radians(20.0)
    P = earth.geodetic_to_ecef(lat, lon, 0.0)
    n = earth.R_en(lat, lon) @ np.array([0.0, 0.0, -1.0])     # geodetic up = -down
    north = earth.R_en(lat, lon) @ np.array([1.0, 0.0, 0.0])
    east = np.cross(n, north) * -1.0
    x_e = P + 2.0e6 * east
    ray = -east
    e = math.radians(el_deg)
    sun = math.cos(e) * north + math.sin(e) * n
    got = sun_elevation(ray[None, :], x_e, sun * 1.5e11)[0]
    assert abs(got - e) < 1e-6, (math.degrees(got), el_deg)


def test_twilight_table_validation():
    base = LimbOptions()
    with pytest.raises(ValueError, match="LimbOptions.twilight_el_deg"):
        dataclasses.replace(base, twilight_el_deg=(0.0, 1.0), twilight_dh_m=(1.0,))
    with pytest.raises(ValueError, match="LimbOptions.twilight_el_deg"):
        dataclasses.replace(base, twilight_el_deg=(1.0, 0.0), twilight_dh_m=(1.0, 2.0))
    with pytest.raises(ValueError, match="LimbOptions.scale_height_m"):
        dataclasses.replace(base, scale_height_m=0.0)
    with pytest.raises(ValueError, match="LimbOptions.min_sun_elev_deg"):
        dataclasses.replace(base, min_sun_elev_deg=-20.0)


def _render_params(H=8000.0, R=6371e3):
    from scenarios.sim import _render_kernel as K
    P = np.zeros(K.N_PARAMS)
    P[K.H_SCALE], P[K.CH_MAX], P[K.R_MEAN] = H, math.sqrt(math.pi * R / (2 * H)), R
    return K, P


@pytest.mark.parametrize("mu", [0.3, 0.02, 0.0, -1e-9, -0.005, -0.02, -0.04])
def test_sun_path_air_mass_renderer_equals_vision_model(mu):
    """The renderer's Sun-path air mass (scenarios.sim._render_kernel, numba) and the vision model's
    c = m_s / m (`sun_path_ratio`, numpy) are separate implementations of the same geometry:
    m_s = 2C c exp(-h/H) to 1e-12, continuous through mu = 0 (the erf form of twilight)."""
    K, P = _render_params()
    C = P[K.CH_MAX]
    for h in (20e3, 35e3):
        if mu < 0 and h < 0.5 * 6371e3 * mu * mu:
            continue
        ms = K._sun_transmission_m(mu, h, P)
        assert ms == pytest.approx(2 * C * float(sun_path_ratio(np.array([mu]))[0]) * math.exp(-h / 8000.0), rel=1e-12)
    up = K._sun_transmission_m(1e-12, 20e3, P)
    down = K._sun_transmission_m(-1e-12, 20e3, P)
    assert down == pytest.approx(up, rel=1e-9)          # the former 2C twilight form jumped by 2x here


def _brute_crossing(mu_c, k, tau, H=8000.0, R=6371e3, fraction=0.5, keep=0.85):
    """Fraction-of-peak crossing [m] on a 1 m grid, self-consistent in the anchor h_c (iterated
    to 1 m), with the renderer's Sun-path air mass (`_sun_transmission_m`) for the radiance
    (1 - exp(-tau m)) exp(-tau m_s): the detector's rules written out with numpy."""
    K, P = _render_params(H, R)
    C = P[K.CH_MAX]
    h = np.arange(80e3, -1.0, -1.0)               # scanning down from space
    hc = 20e3
    for _ in range(6):
        mu = np.clip(mu_c + k * (h - hc), -1, 1)
        ms = np.array([K._sun_transmission_m(m, x, P) for m, x in zip(mu, h)])
        b = np.where(ms >= 0, (1 - np.exp(-tau * 2 * C * np.exp(-h / H))) * np.exp(-tau * np.maximum(ms, 0)), 0.0)
        run = np.maximum.accumulate(b)
        drop = np.flatnonzero(b < keep * run)
        stop = drop[0] if drop.size else len(b) - 1
        peak = run[stop]
        j = int(np.argmax(b >= fraction * peak))
        new = h[j - 1] + (fraction * peak - b[j - 1]) / (b[j] - b[j - 1]) * (h[j] - h[j - 1])
        if abs(new - hc) < 1.0:
            break
        hc = new
    return new


@pytest.mark.parametrize("el_deg, k_deg_per_km", [(20.0, 0.0), (3.0, 0.0), (3.0, 0.03), (0.5, -0.02),
                                                   (-0.5, 0.02), (-1.5, -0.03), (-2.5, 0.01)])
def test_profile_height_shift_against_a_brute_force_profile(el_deg, k_deg_per_km):
    """`profile_height_shift` (numba: 1 km scan, golden section, bisection, two fixed-point
    steps) against a 1 m grid search of the same radiance built on the renderer's air mass, tau =
    0.09 (the renderer's red): within 25 m (grid, iteration and the fixed point's 0.05 contraction)
    for shifts of 0.5..18 km; with dmu/dh = 0 it is eq. (5) (`fraction_height_shift`) to 1 m."""
    tau = 0.09
    ref = _brute_crossing(1.0, 0.0, tau)
    mu = math.sin(math.radians(el_deg))
    k = math.radians(k_deg_per_km) / 1e3
    got = float(profile_height_shift(np.array([mu]), np.array([k]), height_m=ref, radius_m=6371e3)[0])
    want = _brute_crossing(mu, k, tau) - ref
    assert abs(got - want) < 25.0, (got, want)
    if k == 0.0:
        assert abs(got - float(fraction_height_shift(np.array([mu]))[0])) < 1.0


def test_tangent_height_sun_against_ray_ellipsoid():
    """`tangent_height_sun`'s height equals the renderer's `ray_ellipsoid` tangent height (numpy,
    a separate implementation) to 1 mm for rays grazing the Earth from 300 km at 68 deg N."""
    from vision.limb import tangent_height_sun
    rng = np.random.default_rng(3)
    x_e = earth.geodetic_to_ecef(math.radians(68.0), math.radians(16.0), 300e3)
    down = -x_e / np.linalg.norm(x_e)
    side = np.cross(down, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    rays = []
    for az, dip in zip(rng.uniform(0, 2 * math.pi, 50), rng.uniform(15.0, 16.6, 50)):
        horiz = math.cos(az) * side + math.sin(az) * np.cross(down, side)
        d = math.cos(math.radians(90 - dip)) * down + math.sin(math.radians(90 - dip)) * horiz
        rays.append(d / np.linalg.norm(d))
    rays = np.array(rays)
    hit, _, h_ref = render.ray_ellipsoid(x_e, rays)
    h, mu = tangent_height_sun(rays, x_e, np.array([1.0, 0.0, 0.0]))
    assert np.all(~hit) and np.all(np.abs(h - h_ref) < 1e-3), np.max(np.abs(h - h_ref))
