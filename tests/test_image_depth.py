"""16-bit frames (PNG/TIFF of scientific cameras, often 10-14-bit data in a 16-bit container):
scaled to 8 bits by their significant bits (`scenarios.flightlog.jpeg.to_8bit`) in
`horizon-nav vision` and in the import, not cut to their top byte (12-bit data: 0-15, a black
frame on which nothing is found)."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from scenarios.flightlog.jpeg import to_8bit


def test_to_8bit_scales_by_the_significant_bits():
    """Full scale of each depth maps to 255 and the scale is ``255 / (2^bits - 1)`` (exact in
    float32 to the rounding: tolerance 0); 8-bit frames pass unchanged; other types are refused
    with the frame's name."""
    for bits in (10, 12, 14, 16):
        top = 2 ** bits - 1
        v = np.array([[0, top // 3, top]], np.uint16)
        out, b = to_8bit(v, "f")
        assert b == bits and out.dtype == np.uint8
        assert out.tolist() == [[0, round(top // 3 * 255 / top), 255]]
    assert to_8bit(np.array([[4096]], np.uint16), "f")[1] == 14       # one count above 12 bits
    a = np.arange(256, dtype=np.uint8).reshape(16, 16)
    assert to_8bit(a, "f")[0] is a
    with pytest.raises(ValueError, match="f: pixel type float32"):
        to_8bit(a.astype(np.float32), "f")


def test_vision_on_a_16_bit_png(tmp_path):
    """A rendered horizon view with the Moon (`tests.moon_frames.pinhole_moon_view` 0, 640x480)
    as an 8-bit PNG and as a 12-bit one (16 v + a random 0-15 count, in a 16-bit PNG), each
    under the same file name (the RANSAC draws follow the name): the Earth vectors agree within
    0.01 deg (the scaled frame differs from the 8-bit one by at most one count, 255/4095 against
    1/16) and the Moon is found in both. Cut to its top byte the 12-bit frame was black and
    neither was found."""
    from scenarios.config.camera import save_camera

    from tests.moon_frames import pinhole_moon_view

    cam, fr, x = pinhole_moon_view(0)
    img8 = cv2.cvtColor(fr.image, cv2.COLOR_RGB2BGR)
    rng = np.random.default_rng(0)
    img16 = img8.astype(np.uint16) * 16 + rng.integers(0, 16, img8.shape).astype(np.uint16)
    save_camera(cam, tmp_path / "cam.toml")
    out = {}
    for name, img in (("d8", img8), ("d16", img16)):
        (tmp_path / name).mkdir()
        cv2.imwrite(str(tmp_path / name / "v.png"), img)
        p = subprocess.run([sys.executable, "-m", "scenarios.cli", "vision", "--camera", str(tmp_path / "cam.toml"),
                            str(tmp_path / name / "v.png"), "--height", "500e3", "--moon", "--json"],
                           capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        out[name] = (json.loads(p.stdout), p.stderr)
    e8, e16 = (np.array(out[n][0]["earth"]["vector_c"]) for n in ("d8", "d16"))
    assert math.degrees(math.acos(min(1.0, float(e8 @ e16)))) < 0.01
    assert out["d8"][0]["moon"] is not None and out["d16"][0]["moon"] is not None
    assert "16-bit image, 12 significant bits, scaled to 8 bits" in out["d16"][1]


def test_import_scales_16_bit_frames():
    """The import's re-encoding (`scenarios.importer.footage.encode_jpeg`) of a 12-bit frame in a
    16-bit container keeps its brightness: the decoded JPEG's mean within 1 count of the 8-bit
    original's (JPEG at quality 95 on a smooth ramp)."""
    from scenarios.flightlog.jpeg import decode_frame
    from scenarios.importer.footage import encode_jpeg

    ramp = np.tile(np.linspace(0, 255, 64).astype(np.uint8), (48, 1))
    img8 = np.repeat(ramp[:, :, None], 3, axis=2)
    back = decode_frame(encode_jpeg(img8.astype(np.uint16) * 16, 95, "f"))
    assert abs(float(back.mean()) - float(img8.mean())) < 1.0
