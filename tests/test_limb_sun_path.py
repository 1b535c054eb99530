"""Sun-path model of the fraction-of-peak limb edge (vision/limb.py eq. (4)-(5)) and the geodetic
Sun elevation at the limb tangent point, against independent references: the renderer's own 1-D
limb radiance (scenarios.render.limb_profile, a separate implementation of the same physics),
closed forms, and exact tangent geometry on the WGS-84 ellipsoid."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from nav import earth
from scenarios import render
from vision.frontend import TargetConfig
from vision.limb import fraction_height_shift, sun_elevation, sun_path_ratio


def _half_peak_height(el_deg: float) -> float:
    """Height [m] where the renderer's red limb radiance crosses half its maximum, above it
    (1 m grid: the comparison below is at 50 m)."""
    h = np.arange(0.0, 80e3, 1.0)
    b = render.limb_profile(h, sun_elevation_deg=el_deg)[..., 0]
    j = int(np.argmax(b))
    return float(h[j + int(np.argmax(b[j:] < 0.5 * b[j]))])


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
    line of sight's), ~1/(2C) overhead, continuous at mu = 0, growing below (twilight)."""
    C = math.sqrt(math.pi * 6371e3 / 16e3)
    c = sun_path_ratio(np.array([1.0, 0.0, 1e-9, -1e-9, -0.02]))
    assert c[0] == pytest.approx(1.0 / (2 * C) / math.sqrt(1 + 1 / C**2), rel=1e-12)
    assert c[1] == pytest.approx(0.5, rel=1e-12)
    assert c[2] == pytest.approx(0.5, rel=1e-9) and c[3] == pytest.approx(0.5, rel=1e-9)
    assert c[4] == pytest.approx(0.5 * math.exp(6371e3 * 0.02**2 / 16e3), rel=1e-12)


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
    base = TargetConfig()
    with pytest.raises(ValueError, match="limb_twilight_el_deg"):
        dataclasses.replace(base, limb_twilight_el_deg=(0.0, 1.0), limb_twilight_dh_m=(1.0,))
    with pytest.raises(ValueError, match="limb_twilight_el_deg"):
        dataclasses.replace(base, limb_twilight_el_deg=(1.0, 0.0), limb_twilight_dh_m=(1.0, 2.0))
    with pytest.raises(ValueError, match="limb_scale_height_m"):
        dataclasses.replace(base, limb_scale_height_m=0.0)
    with pytest.raises(ValueError, match="limb_min_sun_elev_deg"):
        dataclasses.replace(base, limb_min_sun_elev_deg=-20.0)
