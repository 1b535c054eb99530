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
    assert "16-bit image, 12 significant bits (from its largest value), scaled to 8 bits" in out["d16"][1]


def test_import_scales_16_bit_frames():
    """The import's re-encoding (`scenarios.importer.footage.encode_jpeg`) of a 12-bit frame in a
    16-bit container keeps its brightness: the decoded JPEG's mean within 1 count of the 8-bit
    original's (JPEG at quality 95 on a smooth ramp)."""
    from scenarios.flightlog.jpeg import decode_frame
    from scenarios.importer.footage import encode_jpeg

    ramp = np.tile(np.linspace(0, 255, 64).astype(np.uint8), (48, 1))
    img8 = np.repeat(ramp[:, :, None], 3, axis=2)
    back = decode_frame(encode_jpeg(img8.astype(np.uint16) * 16, 95, "f")[0])
    assert abs(float(back.mean()) - float(img8.mean())) < 1.0


def test_a_given_depth_scales_every_frame_alike():
    """With ``bits`` the scale is ``255 / (2^bits - 1)`` whatever the frame holds: a dark 12-bit
    frame (largest value 1023) stays dark (64, not the 255 its own largest value gives); a value
    the depth cannot hold is refused with the depth named."""
    dark = np.array([[0, 1023]], np.uint16)
    assert to_8bit(dark, "f")[0].tolist() == [[0, 255]]
    out, bits = to_8bit(dark, "f", bits=12)
    assert bits == 12 and out.tolist() == [[0, 64]]
    with pytest.raises(ValueError, match=r"f: pixel value 1024 does not fit the 10-bit depth"):
        to_8bit(np.array([[1024]], np.uint16), "f", bits=10)


def _depth_footage(tmp_path, bit_depth: str):
    """An import of three 64x48 16-bit PNGs of a 12-bit camera: a dark frame (values 0-900) and
    two bright ones (0-4000); returns (result or exception, the dark frame's 12-bit values)."""
    from scenarios.errors import UserError
    from scenarios.importer.build import import_flight

    from tests.test_import import _camera_file, _camera_mapping, _small_imu

    _small_imu(tmp_path, np.arange(100) / 20.0)
    _camera_file(tmp_path)
    (tmp_path / "img").mkdir()
    ramp = np.tile(np.linspace(0, 1, 64), (48, 1))
    frames = [np.rint(ramp * top).astype(np.uint16) for top in (900, 4000, 3800)]
    for i, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / "img" / f"f{i}.png"), f)
    m = _camera_mapping(tmp_path, f'images = "img"\nstart_s = 0.5\nrate_hz = 1.0\n{bit_depth}')
    try:
        return import_flight(m, tmp_path / "o.mcap", report_dir=tmp_path / "report"), frames[0]
    except UserError as exc:
        return exc, frames[0]


def _bit_depth_finding(res):
    return [f for f in res.report.findings if f.check == "bit_depth"]


def test_import_warns_of_frames_scaled_by_different_depths(tmp_path):
    """Without ``bit_depth`` each 16-bit frame is scaled by its own largest value: the dark frame
    as 10-bit data (4x brighter than its siblings' scale), and the report warns, naming the key
    and the depth to give, in the report directory's report.json as well."""
    from scenarios.flightlog.reader import read_log

    res, dark = _depth_footage(tmp_path, "")
    (f,) = _bit_depth_finding(res)
    assert f.level == "warning" and "10 bits on 1, 12 bits on 2" in f.message and "bit_depth = 12" in f.message
    saved = json.loads((tmp_path / "report" / "report.json").read_text())     # --report's file has it too
    assert "bit_depth = 12" in json.dumps(saved) and (tmp_path / "report" / "report.png").is_file()
    back = cv2.imdecode(np.frombuffer(read_log(tmp_path / "o.mcap").cameras[1].images[0], np.uint8), cv2.IMREAD_GRAYSCALE)
    assert abs(float(back.mean()) - dark.mean() * 255 / 1023) < 1.0      # JPEG 95 on a smooth ramp: < 1 count


def test_import_with_the_camera_depth_scales_alike(tmp_path):
    """``bit_depth = 12``: the dark frame keeps its 12-bit brightness (mean within 1 count of
    ``v 255 / 4095``), the report says the depth as information; ``bit_depth = 10`` refuses the
    first bright frame naming the value and the key; a depth outside 9..16 names the key."""
    from scenarios.errors import UserError
    from scenarios.flightlog.reader import read_log

    (tmp_path / "a").mkdir()
    res, dark = _depth_footage(tmp_path / "a", "bit_depth = 12")
    (f,) = _bit_depth_finding(res)
    assert f.level == "info" and "12-bit data (bit_depth): 12 bits on 3" in f.message
    back = cv2.imdecode(np.frombuffer(read_log(tmp_path / "a" / "o.mcap").cameras[1].images[0], np.uint8),
                        cv2.IMREAD_GRAYSCALE)
    assert abs(float(back.mean()) - dark.mean() * 255 / 4095) < 1.0
    (tmp_path / "b").mkdir()
    exc, _ = _depth_footage(tmp_path / "b", "bit_depth = 10")
    assert isinstance(exc, UserError) and "f1.png" in str(exc)
    assert "pixel value 4000 does not fit the 10-bit depth" in str(exc) and "check the footage's 'bit_depth'" in str(exc)
    (tmp_path / "c").mkdir()
    exc, _ = _depth_footage(tmp_path / "c", "bit_depth = 20")
    assert isinstance(exc, UserError) and "key 'bit_depth' = 20; expected" in str(exc)


def test_vision_bit_depth_option(tmp_path):
    """``horizon-nav vision --bit-depth 12`` scales a dark 12-bit image by 12 bits and says so;
    a depth outside 9..16 is a one-line error naming the option."""
    from scenarios.config.camera import save_camera

    from tests.moon_frames import pinhole_moon_view

    cam, fr, _ = pinhole_moon_view(0)
    save_camera(cam, tmp_path / "cam.toml")
    img16 = cv2.cvtColor(fr.image, cv2.COLOR_RGB2BGR).astype(np.uint16) * 16
    cv2.imwrite(str(tmp_path / "v.png"), img16)
    run = [sys.executable, "-m", "scenarios.cli", "vision", "--camera", str(tmp_path / "cam.toml"),
           str(tmp_path / "v.png"), "--height", "500e3", "--json"]
    p = subprocess.run(run + ["--bit-depth", "12"], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert "12 significant bits (given by --bit-depth)" in p.stderr
    p = subprocess.run(run + ["--bit-depth", "20"], capture_output=True, text=True)
    assert p.returncode != 0 and p.stderr.strip().endswith("--bit-depth 20: expected the 16-bit images' significant bits, 9..16")
