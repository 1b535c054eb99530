"""A camera below the height the Earth's cone is built at (`vision.frontend`, ``edge.start_m`` =
45 km): a balloon, a rocket's ascent. The cone then starts at the threshold edge's prior mean
(``atmosphere_m``), the height being estimated; with a fixed height the Earth is skipped with the
reason, and the frame's other targets are still processed. Before, the frame raised: the replay
lost its every vector (the Sun's too) and `horizon-nav vision` stopped the whole batch at it."""
from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from nav import earth, ephemeris
from scenarios.config.camera import load_camera
from scenarios.config.vision import load_vision_config
from scenarios.sim import render
from vision.config import FramePrior
from vision.frontend import process_frame

from tests.poses import T0_ORBIT_NS, pose

CAMERA = "scenarios/library/cameras/atek_gopro.toml"
H_LOW = 30e3


@pytest.fixture(scope="module")
def low_view():
    """(camera, image BGR, R_ec, x_e, truth e_c) of the ATEK fisheye 30 km up, looking 15 deg
    below the horizon (which dips 5.6 deg) 20 deg north of the sub-solar point."""
    cam = load_camera(CAMERA)
    sun = ephemeris.sun_position_e(T0_ORBIT_NS)
    lat, lon, _ = earth.ecef_to_geodetic(sun / np.linalg.norm(sun) * earth.A)
    dip = math.degrees(math.acos(earth.A / (earth.A + H_LOW)))
    R, x = pose(120.0, dip + 15.0, h=H_LOW, lat=math.degrees(lat) + 20.0, lon=math.degrees(lon))
    fr = render.render_frame(cam, R, x, sun, ephemeris.moon_position_e(T0_ORBIT_NS), seed=1, cloud_seed=1,
                             options=render.RenderOptions(payload_mask=None, payload_reflections=False))
    return cam, fr.image[:, :, ::-1].copy(), R, x, fr.e_c_earth


def _err_deg(rec, truth) -> float:
    return math.degrees(math.acos(min(1.0, float(rec.e_c @ truth))))


def test_camera_below_the_cone_height_gets_an_honest_earth(low_view):
    """With the height alone (substitute sphere) and with the position and attitude prior
    (ellipsoid): an Earth vector whose error lies inside its 3 sigma (the renderer's edge is not
    the prior's: 2-3 deg off at 3 sigma 3.5-4 deg here), its height below the camera."""
    cam, img, R, x, e_true = low_view
    cfg = load_vision_config(camera=cam)
    for kw in (dict(height_m=H_LOW), dict(prior=FramePrior(x_e=x, R_ec=R))):
        res = process_frame(img, cam, cfg, **kw)
        rec = res.record("earth")
        assert rec is not None, res.reasons
        assert _err_deg(rec, e_true) <= 3.0 * rec.sigma_deg
        assert 0.0 <= rec.edge_height_m < H_LOW


def test_fixed_edge_height_above_the_camera_skips_the_earth_only(low_view):
    """A fixed edge height (not estimated) at 45 km: no Earth cone exists from 30 km; the Earth
    has that reason and the Sun is searched as usual (its reason is the search's, not the
    Earth's failure)."""
    cam, img, R, x, _ = low_view
    cfg = load_vision_config(camera=cam)
    fixed = dataclasses.replace(cfg, earth=dataclasses.replace(
        cfg.earth, atmosphere_m=45e3, edge=dataclasses.replace(cfg.earth.edge, estimate=False)))
    res = process_frame(img, cam, fixed, prior=FramePrior(x_e=x, R_ec=R))
    assert res.record("earth") is None
    assert "not above the Earth's edge height 45 km" in res.reasons["earth"]
    assert "sun" in res.reasons and "edge height" not in res.reasons["sun"]


def test_vision_cli_goes_on_past_a_low_image(tmp_path, low_view):
    """`horizon-nav vision` on the 30 km view with its height: exit 0 and an Earth vector (the
    call stopped with "expected a finite height above the effective atmosphere thickness d =
    45000.0 m" before)."""
    cam, img, *_ = low_view
    cv2.imwrite(str(tmp_path / "low.png"), img)
    p = subprocess.run([sys.executable, "-m", "scenarios.cli", "vision", "--camera", CAMERA, str(tmp_path / "low.png"),
                        "--height", str(H_LOW), "--json"], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["earth"] is not None and 0.0 <= out["earth"]["edge_height_m"] < H_LOW


def test_vision_cli_notes_a_height_that_looks_like_km(tmp_path, low_view):
    """A height below 1 km (``--height 30``: kilometres typed for metres) runs, and stderr says
    the heights are in metres with the value it would be; 30 km itself gets no such note."""
    cam, img, *_ = low_view
    cv2.imwrite(str(tmp_path / "low.png"), img)
    run = [sys.executable, "-m", "scenarios.cli", "vision", "--camera", CAMERA, str(tmp_path / "low.png"), "--json"]
    p = subprocess.run(run + ["--height", "30"], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert "height 30 m above the ellipsoid (heights are in metres: 30 km would be 30000)" in p.stderr
    p = subprocess.run(run + ["--height", "30e3"], capture_output=True, text=True)
    assert p.returncode == 0 and "heights are in metres" not in p.stderr
