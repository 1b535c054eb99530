"""Camera calibration (scenarios/cli/calibrate.py) on chessboards rendered through a known
fisheye camera with vision.camera.unproject (every pixel's ray intersected with the board plane,
4x4 supersampled so the corners are sub-pixel accurate): the recovered camera must reproject like
the true one."""
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from nav.rotation import rotvec_to_matrix
from scenarios.config.camera import load_camera
from scenarios.cli.calibrate import calibrate_images, parse_board
from scenarios.errors import UserError
from vision.camera import PinholeCamera, from_fov, project, unproject

BOARD = (9, 6)
SQUARE = 0.025


def true_camera():
    """ATEK-like lens (94.4 deg over the width, D = [0.08, -0.01, 0, 0]) at 960x540, off-centre."""
    c = from_fov(960, 540, 94.4, k_shape=(1.0, 0.08, -0.01, 0.0, 0.0), name="truth")
    from dataclasses import replace
    return replace(c, cx=c.cx + 6.0, cy=c.cy - 4.0)


def render_board(cam, rvec, t, ss=4):
    """Grey image of a 10x7-square chessboard (board frame: corners at (i, j) * SQUARE, z = 0) at
    pose x_c = R x_b + t; white margin one square wide, grey background."""
    o = (np.arange(ss) + 0.5) / ss - 0.5
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(float)
    acc = np.zeros((cam.height, cam.width))
    R = rotvec_to_matrix(np.asarray(rvec, float))
    n = R[:, 2]
    for du in o:
        for dv in o:
            d = unproject(cam, np.stack([u + du, v + dv], -1))
            with np.errstate(invalid="ignore", divide="ignore"):
                s = (n @ t) / (d @ n)                 # ray-plane distance
                p = (s[..., None] * d - t) @ R        # board coordinates
            i = np.floor(p[..., 0] / SQUARE + 1.0)
            j = np.floor(p[..., 1] / SQUARE + 1.0)
            on = (s > 0) & (i >= -1) & (i < BOARD[0] + 2) & (j >= -1) & (j < BOARD[1] + 2)
            inner = (i >= 0) & (i < BOARD[0] + 1) & (j >= 0) & (j < BOARD[1] + 1)
            val = np.where(on, np.where(inner, np.where((i + j) % 2 == 0, 20.0, 235.0), 235.0), 128.0)
            acc += np.nan_to_num(val, nan=128.0)
    return np.clip(acc / ss**2, 0, 255).astype(np.uint8)


def board_pose(rvec, az_deg, off_deg, dist):
    """(rvec, t) putting the board centre at ``dist`` along the ray ``off_deg`` off the axis at
    azimuth ``az_deg`` in the image, the board rotated by ``rvec``."""
    R = rotvec_to_matrix(np.asarray(rvec, float))
    a, o = math.radians(az_deg), math.radians(off_deg)
    d = np.array([math.sin(o) * math.cos(a), math.sin(o) * math.sin(a), math.cos(o)])
    centre = np.array([(BOARD[0] - 1) / 2, (BOARD[1] - 1) / 2, 0.0]) * SQUARE
    return rvec, dist * d - R @ centre


POSES = [board_pose((0, 0, 0), 0, 0, 0.3), board_pose((0, -0.5, 0), 0, 28, 0.3),
         board_pose((0, 0.5, 0.1), 180, 28, 0.3), board_pose((0.4, 0, 0), 90, 14, 0.3),
         board_pose((-0.4, 0, -0.1), 270, 14, 0.3), board_pose((0.3, -0.4, 0.2), 30, 30, 0.32),
         board_pose((-0.3, 0.4, 0.3), 210, 30, 0.32), board_pose((0.3, 0.4, -0.2), 150, 30, 0.32),
         board_pose((-0.3, -0.4, 0.0), 330, 30, 0.32), board_pose((0.0, 0.0, 0.7), 0, 10, 0.4)]


@pytest.fixture(scope="module")
def boards():
    cam = true_camera()
    return cam, {f"view{i}": render_board(cam, r, np.array(t)) for i, (r, t) in enumerate(POSES)}


def test_calibration_recovers_the_camera(boards, tmp_path):
    cam, imgs = boards
    cal = calibrate_images(imgs, BOARD, SQUARE, "cal")
    assert len(cal.per_image_px) >= 6, cal.skipped
    assert cal.rms_px < 0.2, cal.rms_px          # sub-pixel corners of a noise-free rendering
    got = cal.camera
    assert abs(got.fx / cam.fx - 1) < 5e-3 and abs(got.fy / cam.fy - 1) < 5e-3, (got.fx, cam.fx)
    assert abs(got.cx - cam.cx) < 1.5 and abs(got.cy - cam.cy) < 1.5, (got.cx, got.cy)
    # the calibrated model reprojects rays like the truth where the boards were (theta < 40 deg)
    d = reprojection_difference(got, cam, 40.0)
    assert d.max() < 1.0, d.max()


def reprojection_difference(got, truth, max_deg):
    """|project(got) - project(truth)| [px] of rays up to ``max_deg`` off the axis."""
    T, P = np.meshgrid(np.radians(np.linspace(0, max_deg, 9)), np.radians(np.arange(0, 360, 30)))
    rays = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    return np.linalg.norm(project(got, rays) - project(truth, rays), axis=1)


def write_images(imgs, tmp_path):
    """The images as PNG files; their paths."""
    paths = []
    for k, im in imgs.items():
        p = tmp_path / f"{k}.png"
        cv2.imwrite(str(p), im)
        paths.append(str(p))
    return paths


def test_cli_writes_a_camera_file(boards, tmp_path):
    cam, imgs = boards
    paths = write_images(imgs, tmp_path)
    out = tmp_path / "cam.toml"
    r = subprocess.run([sys.executable, "-m", "scenarios.cli", "calibrate", *paths, "--board", "9x6",
                        "--square", "0.025", "-o", str(out)], capture_output=True, text=True, cwd=".")
    assert r.returncode == 0, r.stderr
    assert "RMS reprojection error" in r.stdout
    c = load_camera(out)
    assert (c.width, c.height) == (960, 540) and abs(c.fx / cam.fx - 1) < 5e-3


def test_bad_input():
    with pytest.raises(UserError, match="--board"):
        parse_board("9by6")
    blank = {f"b{i}": np.full((120, 160), 128, np.uint8) for i in range(3)}
    with pytest.raises(UserError, match="found in 0 of 3"):
        calibrate_images(blank, BOARD, SQUARE)
    with pytest.raises(UserError, match="--square"):
        calibrate_images(blank, BOARD, -1.0)


PINHOLE_TRUTH = PinholeCamera(960, 720, 600.0, 601.5, 484.0, 356.0, (-0.2, 0.08, 1e-3, -5e-4, 0.0), name="truth")


@pytest.fixture(scope="module")
def pinhole_boards():
    return {f"view{i}": render_board(PINHOLE_TRUTH, r, np.array(t)) for i, (r, t) in enumerate(POSES)}


@pytest.mark.parametrize("rational", [False, True])
def test_pinhole_calibration_recovers_the_camera(pinhole_boards, rational):
    """cv2.calibrateCamera on boards rendered through a known plumb_bob pinhole (77 deg FOV): the
    focal lengths within 0.5 %, the principal point within 1.5 px (the corners are sub-pixel, ~0.05
    px, and 8-10 views constrain K to that level), and the model reprojects like the truth within
    0.5 px where the boards were (theta < 30 deg)."""
    cal = calibrate_images(pinhole_boards, BOARD, SQUARE, "cal", model="pinhole", rational=rational)
    got = cal.camera
    assert isinstance(got, PinholeCamera) and len(got.dist) == (8 if rational else 5)
    assert len(cal.per_image_px) >= 6, cal.skipped
    assert cal.rms_px < 0.2, cal.rms_px
    assert abs(got.fx / PINHOLE_TRUTH.fx - 1) < 5e-3 and abs(got.fy / PINHOLE_TRUTH.fy - 1) < 5e-3, (got.fx, got.fy)
    assert abs(got.cx - PINHOLE_TRUTH.cx) < 1.5 and abs(got.cy - PINHOLE_TRUTH.cy) < 1.5, (got.cx, got.cy)
    d = reprojection_difference(got, PINHOLE_TRUTH, 30.0)
    assert d.max() < 0.5, d.max()


def test_cli_writes_a_pinhole_camera_file(pinhole_boards, tmp_path):
    paths = write_images(pinhole_boards, tmp_path)
    out = tmp_path / "pin.toml"
    r = subprocess.run([sys.executable, "-m", "scenarios.cli", "calibrate", *paths, "--model", "pinhole",
                        "-o", str(out)], capture_output=True, text=True, cwd=".")
    assert r.returncode == 0, r.stderr
    assert "FOV" in r.stdout and "deg horizontal" in r.stdout
    c = load_camera(out)
    assert isinstance(c, PinholeCamera) and abs(c.fx / PINHOLE_TRUTH.fx - 1) < 5e-3


def with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """The JPEG with an EXIF APP1 segment holding only the orientation tag (0x0112), as cameras
    write it for a view held turned (6: the stored rows are shown turned 90 deg clockwise)."""
    import struct
    tiff = (b"MM\x00\x2a\x00\x00\x00\x08" + struct.pack(">H", 1)
            + struct.pack(">HHII", 0x0112, 3, 1, orientation << 16) + b"\x00\x00\x00\x00")
    app1 = b"Exif\x00\x00" + tiff
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpeg[2:]


def test_exif_orientation_is_not_applied(boards, tmp_path):
    """Chessboard JPEGs carrying EXIF orientation 6: `horizon-nav calibrate` describes the image
    as stored (960x540, as `horizon-nav vision` and the replay read it; with the orientation
    applied it was 540x960), and `horizon-nav vision` given a camera file of the turned shape
    says why the sizes differ."""
    cam, imgs = boards
    paths = []
    for k, im in imgs.items():
        ok, buf = cv2.imencode(".jpg", im, [int(cv2.IMWRITE_JPEG_QUALITY), 95])
        p = tmp_path / f"{k}.jpg"
        p.write_bytes(with_exif_orientation(buf.tobytes(), 6))
        paths.append(str(p))
    assert cv2.imread(paths[0]).shape[:2] == (960, 540)        # what an orientation-applying reader sees
    out = tmp_path / "cam.toml"
    r = subprocess.run([sys.executable, "-m", "scenarios.cli", "calibrate", *paths, "--board", "9x6",
                        "--square", "0.025", "-o", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    c = load_camera(out)
    assert (c.width, c.height) == (960, 540) and abs(c.fx / cam.fx - 1) < 5e-3
    turned = tmp_path / "turned.toml"
    turned.write_text(out.read_text().replace("width = 960", "width = 540").replace("height = 540", "height = 960")
                      .replace(f"cx = {c.cx!r}", f"cx = {269.5!r}").replace(f"cy = {c.cy!r}", f"cy = {479.5!r}"))
    r = subprocess.run([sys.executable, "-m", "scenarios.cli", "vision", "--camera", str(turned), paths[0],
                        "--height", "230e3"], capture_output=True, text=True)
    assert r.returncode == 2
    assert "size 960x540, but camera file" in r.stderr and "is 540x960; its EXIF orientation turns it" in r.stderr
