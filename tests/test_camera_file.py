"""Tests of scenarios/config/camera.py: TOML camera files, round trip and error messages."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenarios.config.camera import dumps_camera, load_camera, save_camera
from scenarios.errors import UserError
from vision.camera import FisheyeCamera, atek_camera, project, unproject

LIBRARY = Path(__file__).resolve().parents[1] / "scenarios" / "library" / "cameras"


def test_library_atek_file_is_the_default_camera():
    cam = load_camera(LIBRARY / "atek_gopro.toml")
    assert cam == atek_camera()


def test_save_load_roundtrip_exact(tmp_path):
    cam = FisheyeCamera(1280, 960, 600.123456789, 610.5, 655.3, 470.9,
                        (1.02, -0.05, 0.012, -0.002, 1.5e-4), name='lab "B"')
    p = tmp_path / "cam.toml"
    save_camera(cam, p, comment="test camera\nsecond line")
    back = load_camera(p)
    assert back == cam and back.name == cam.name  # floats written with repr: bit-exact
    assert p.read_text().startswith("# test camera\n# second line\n[camera]")
    uv = np.array([[3.0, 4.0], [1000.0, 900.0]])
    assert np.array_equal(unproject(back, uv), unproject(cam, uv))


def test_opencv_D_form(tmp_path):
    p = tmp_path / "cv.toml"
    p.write_text('[camera]\nwidth = 640\nheight = 480\nfx = 300.0\nfy = 300.0\ncx = 319.5\n'
                 'cy = 239.5\nopencv_D = [0.01, 0.0, 0.0, 0.0]\n')
    cam = load_camera(p)
    assert cam.k == (1.0, 0.01, 0.0, 0.0, 0.0)
    assert np.allclose(project(cam, np.array([0.0, 0.0, 1.0])), [319.5, 239.5])


@pytest.mark.parametrize("text, match", [
    ("[camera]\nwidth = 640\n", r"missing key 'height'"),
    ("[cam]\nwidth = 640\n", r"missing table \[camera\]"),
    ("[camera\nwidth = 640\n", "not valid TOML"),
    ('[camera]\nwidth = 640\nheight = 480\nfx = "300"\nfy = 300.0\ncx = 1.0\ncy = 1.0\nk = [1.0]\n',
     r"key 'fx' = '300'; expected a finite number"),
    ("[camera]\nwidth = 640\nheight = 480\nfx = 300.0\nfy = 300.0\ncx = 1.0\ncy = 1.0\n"
     "opencv_D = [0.1, 0.2]\n", r"key 'opencv_D' has 2 entries; expected 4"),
    ("[camera]\nwidth = 1000\nheight = 1000\nfx = 600.0\nfy = 600.0\ncx = 499.5\ncy = 499.5\n"
     "k = [1.0, -0.5]\n", r"not monotonic over the field of view: dr_d/dtheta <= 0 at theta = 46\.782 deg"),
])
def test_errors_name_file_and_key(tmp_path, text, match):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(UserError, match=match) as exc:
        load_camera(p)
    assert "bad.toml" in str(exc.value)


def test_missing_file(tmp_path):
    with pytest.raises(UserError, match="nope.toml: camera file not found"):
        load_camera(tmp_path / "nope.toml")


def test_dumps_is_loadable_toml():
    import tomllib
    d = tomllib.loads(dumps_camera(atek_camera()))
    assert d["camera"]["model"] == "fisheye" and d["camera"]["k"] == [1.0, 0.08, -0.01, 0.0, 0.0]
