"""Camera models (vision.camera, vision.pinhole) against OpenCV, and the camera file readers.

Tolerances: projection 1e-6 px and unprojection 1e-9 rad (the acceptance figures); both sides
compute in float64 and converge far below them (~1e-12 px, ~1e-15 rad), so a wrong coefficient,
sign or convention fails by orders of magnitude. OpenCV's undistortion is run with tight
termination criteria (its default 5 fixed-point iterations leave ~1e-4 px at strongly distorted
corners). OpenCV 5 has no ``undistortPointsIter``: ``undistortPoints`` takes the criteria.
"""
import math

import cv2
import numpy as np
import pytest

from scenarios.config.camera import dumps_camera, load_camera
from scenarios.errors import UserError
from vision.camera import (EquidistantCamera, FisheyeCamera, PinholeCamera, atek_camera, fov_deg, from_opencv,
                           project, to_opencv, unproject, unproject_jacobian)

CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 300, 1e-14)

PINHOLES = {
    "plumb_bob": PinholeCamera(1280, 960, 2897.4, 2896.1, 641.3, 478.8, (-0.08, 0.12, 2e-4, -1e-4, 0.0)),
    "four": PinholeCamera(640, 480, 628.5, 629.0, 319.9, 243.4, (0.0638, -0.1002, 8.2e-4, 1.44e-3)),
    "wide_barrel": PinholeCamera(1920, 1080, 1000.0, 1002.0, 955.0, 545.0, (-0.28, 0.09, 1e-3, -5e-4, -0.012)),
    "rational": PinholeCamera(1600, 1200, 900.0, 900.0, 801.0, 598.0,
                              (0.5, -0.1, 1e-3, 2e-4, 0.02, 0.8, 0.05, 0.01)),
    "none": PinholeCamera(800, 600, 700.0, 700.0, 399.5, 299.5),
}


def image_grid(cam, step=8.0):
    """Pixels covering the whole image: a grid every ``step`` px plus the pixel-edge border."""
    u = np.append(np.arange(-0.5, cam.width - 0.5, step), cam.width - 0.5)
    v = np.append(np.arange(-0.5, cam.height - 0.5, step), cam.height - 0.5)
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu.ravel(), vv.ravel()], axis=1)


def angle(a, b):
    """Angle [rad] between rows of a and b (atan2 form: accurate for tiny angles)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


@pytest.mark.parametrize("key", sorted(PINHOLES))
def test_pinhole_matches_opencv_over_the_whole_image(key):
    cam = PINHOLES[key]
    K, D = to_opencv(cam)
    uv = image_grid(cam)
    rays = unproject(cam, uv)
    assert np.all(np.isfinite(rays))
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, D, criteria=CRIT).reshape(-1, 2)
    ref = np.column_stack([xy, np.ones(len(xy))])
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    assert np.max(angle(rays, ref)) < 1e-9
    proj = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
    assert np.max(np.abs(project(cam, rays) - proj)) < 1e-6
    assert np.max(np.abs(project(cam, rays) - uv)) < 1e-6          # round trip


def test_pinhole_jacobian_matches_finite_differences():
    # central differences with h = 1e-3 px: truncation ~h^2 |d3 ray| ~ 1e-16 /px, rounding of the
    # converged rays (~1e-15) / 2h ~ 1e-12 /px; a wrong term is of order |J| ~ 1e-3 /px
    cam = PINHOLES["wide_barrel"]
    uv = image_grid(cam, 97.0)
    _, J = unproject_jacobian(cam, uv)
    h = 1e-3
    for j, d in enumerate(np.eye(2) * h):
        num = (unproject(cam, uv + d) - unproject(cam, uv - d)) / (2 * h)
        assert np.max(np.abs(J[:, :, j] - num)) < 1e-11


def test_pinhole_without_distortion_is_the_closed_form():
    cam = PINHOLES["none"]
    uv = image_grid(cam, 50.0)
    x = np.column_stack([(uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy, np.ones(len(uv))])
    assert np.max(angle(unproject(cam, uv), x)) < 1e-15
    hf = 2 * math.degrees(math.atan((cam.width / 2) / cam.fx))
    assert fov_deg(cam)[0] == pytest.approx(hf, abs=1e-12)


@pytest.mark.parametrize("D", [(0.08, -0.01, 0.0, 0.0), (-0.02, 0.003, -0.001, 2e-4), (0.0, 0.0, 0.0, 0.0)])
def test_opencv_fisheye_matches_cv2_fisheye(D):
    cam = from_opencv(np.array([[820.0, 0, 962.0], [0, 818.0, 537.0], [0, 0, 1]]), D, 1920, 1080)
    K, Dk = to_opencv(cam)
    uv = image_grid(cam)
    rays = unproject(cam, uv)
    assert np.all(rays[:, 2] > 0)            # this lens sees < 90 deg: OpenCV's x/z form applies
    xy = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), K, Dk, criteria=CRIT).reshape(-1, 2)
    ref = np.column_stack([xy, np.ones(len(xy))])
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    assert np.max(angle(rays, ref)) < 1e-9
    proj = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, Dk)[0].reshape(-1, 2)
    assert np.max(np.abs(project(cam, rays) - proj)) < 1e-6


def test_fisheye_beyond_90_deg():
    # a 200 deg circular fisheye (OpenCV fisheye coefficients): OpenCV's functions work on x/z and
    # cannot represent theta >= 90 deg, so the truth is the model equation itself:
    # |q| = theta (1 + d1 theta^2 + ...) with theta the angle of the returned ray, and the round trip.
    D = (-0.01, 0.002, 0.0, 0.0)
    cam = from_opencv(np.array([[300.0, 0, 639.5], [0, 300.0, 479.5], [0, 0, 1]]), D, 1280, 960)
    uv = image_grid(cam)
    rays = unproject(cam, uv)
    theta = np.arccos(np.clip(rays[:, 2], -1, 1))
    assert theta.max() > math.radians(100)
    q = np.hypot((uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy)
    rd = theta * (1 + D[0] * theta**2 + D[1] * theta**4)
    assert np.max(np.abs(rd - q) * cam.fx) < 1e-6
    assert np.max(np.abs(project(cam, rays) - uv)) < 1e-6


def test_equidistant_is_r_equals_f_theta():
    cam = EquidistantCamera(1280, 960, 400.0, 400.0, 639.5, 479.5, name="eq")
    assert cam == EquidistantCamera(1280, 960, 400.0, 400.0, 639.5, 479.5, name="eq")
    assert cam.model == "equidistant" and cam.k == (1.0,)
    uv = image_grid(cam, 20.0)
    rays = unproject(cam, uv)
    theta = np.arccos(np.clip(rays[:, 2], -1, 1))
    assert np.max(np.abs(theta * cam.fx - np.hypot(uv[:, 0] - cam.cx, uv[:, 1] - cam.cy))) < 1e-9
    assert fov_deg(cam)[0] == pytest.approx(math.degrees(cam.width / cam.fx), abs=1e-9)
    with pytest.raises(ValueError, match="equidistant model has k = \\[1.0\\]"):
        EquidistantCamera(1280, 960, 400.0, 400.0, 639.5, 479.5, k=(1.0, 0.1))


def test_bad_cameras_name_the_key():
    with pytest.raises(ValueError, match="dist = .*cannot be inverted over the image"):
        PinholeCamera(1280, 960, 1000.0, 1000.0, 639.5, 479.5, (-0.5, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="dist = .*expected 0, 4, 5 or 8"):
        PinholeCamera(1280, 960, 1000.0, 1000.0, 639.5, 479.5, (-0.1, 0.0, 0.0))
    with pytest.raises(ValueError, match="principal point cy = 1200.0 lies outside the 1280x960 image"):
        PinholeCamera(1280, 960, 1000.0, 1000.0, 639.5, 1200.0)
    with pytest.raises(ValueError, match="principal point cx = -3.0"):
        FisheyeCamera(1280, 960, 1000.0, 1000.0, -3.0, 479.5)


def test_pinhole_outside_its_valid_region_projects_to_nan():
    cam = PINHOLES["plumb_bob"]
    uv = project(cam, np.array([[0.1, 0.0, -1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    assert np.all(np.isnan(uv[:2])) and np.allclose(uv[2], [cam.cx, cam.cy])


# ------------------------------------------------------------------------------------------------
# camera files

#: ost.yaml as ROS camera_calibration (cameracalibrator.py) writes it, verbatim.
ROS_OST_YAML = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [628.52464, 0., 319.86038, 0., 629.03787, 243.35891, 0., 0., 1.]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.063806, -0.100236, 0.000817, 0.001437, 0.000000]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1., 0., 0., 0., 1., 0., 0., 0., 1.]
projection_matrix:
  rows: 3
  cols: 4
  data: [633.96204, 0., 320.68237, 0., 0., 635.9884, 243.84453, 0., 0., 0., 1., 0.]
"""


def test_ros_camera_info_yaml(tmp_path):
    p = tmp_path / "ost.yaml"
    p.write_text(ROS_OST_YAML)
    cam = load_camera(p)
    assert isinstance(cam, PinholeCamera) and cam.name == "narrow_stereo"
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (640, 480, 628.52464, 629.03787, 319.86038,
                                                                        243.35891)
    assert cam.dist == (0.063806, -0.100236, 0.000817, 0.001437, 0.0)
    fish = ROS_OST_YAML.replace("plumb_bob", "equidistant").replace("cols: 5", "cols: 4").replace(
        "0.001437, 0.000000]", "0.001437]")
    (tmp_path / "fish.yml").write_text(fish)
    f = load_camera(tmp_path / "fish.yml")
    assert isinstance(f, FisheyeCamera) and f.k == (1.0, 0.063806, -0.100236, 0.000817, 0.001437)


@pytest.mark.parametrize("edit, message", [
    (("plumb_bob", "rational_polynomial"), "key 'distortion_coefficients'.*takes 8"),
    (("plumb_bob", "fov"), "key 'distortion_model'.*'fov' is not supported"),
    (("data: [0.063806", "data: [-0.9"), "key 'distortion_coefficients'.*cannot be inverted"),
    (("rows: 1\n  cols: 5", "rows: 1\n  cols: 6"), "key 'distortion_coefficients': rows 1 x cols 6"),
    (("319.86038", "719.86038"), "key 'camera_matrix'.*principal point cx"),
    (("image_width: 640", "image_width: -640"), "key 'image_width'"),
])
def test_ros_yaml_errors_name_file_and_key(tmp_path, edit, message):
    p = tmp_path / "bad.yaml"
    p.write_text(ROS_OST_YAML.replace(*edit))
    with pytest.raises(UserError, match=f"bad.yaml: {message}") as exc:
        load_camera(p)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("ext", ["yml", "xml"])
def test_opencv_filestorage(tmp_path, ext):
    p = tmp_path / f"calib.{ext}"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 960)
    fs.write("camera_matrix", np.array([[2880.0, 0, 640.2], [0, 2881.0, 480.1], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[-0.1, 0.05, 1e-4, -2e-4, 0.01]]))
    fs.release()
    cam = load_camera(p)
    assert isinstance(cam, PinholeCamera)
    assert (cam.fx, cam.cy, cam.dist) == (2880.0, 480.1, (-0.1, 0.05, 1e-4, -2e-4, 0.01))
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 960)
    fs.write("fisheye_model", 1)
    fs.write("camera_matrix", np.array([[600.0, 0, 640.0], [0, 600.0, 480.0], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([0.01, -0.002, 0.0, 0.0]))
    fs.release()
    f = load_camera(p)
    assert isinstance(f, FisheyeCamera) and f.k == (1.0, 0.01, -0.002, 0.0, 0.0)
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("camera_matrix", np.eye(3))
    fs.release()
    with pytest.raises(UserError, match=f"calib.{ext}: key 'image_height' missing"):
        load_camera(p)


@pytest.mark.parametrize("cam", [PINHOLES["rational"], PINHOLES["none"], atek_camera(),
                                 EquidistantCamera(1280, 960, 400.0, 400.0, 639.5, 479.5, name="eq")])
def test_toml_round_trip_every_model(tmp_path, cam):
    p = tmp_path / "c.toml"
    p.write_text(dumps_camera(cam))
    assert load_camera(p) == cam and type(load_camera(p)) is type(cam)


def test_toml_model_key(tmp_path):
    base = "[camera]\nwidth = 1280\nheight = 960\nfx = 2900.0\nfy = 2900.0\ncx = 639.5\ncy = 479.5\n"
    cases = {'model = "pinhole"\nopencv_D = [-0.1, 0.05, 0.0, 0.0, 0.0, 0.0]': "key 'opencv_D' has 6 entries",
             'model = "equidistant"\nk = [1.0, 0.1]': "key 'k' does not apply to model 'equidistant'",
             'model = "pinhole"\nopencv_D = [-3.0, 0.0, 0.0, 0.0]': "key opencv_D: .*cannot be inverted",
             'model = "fisheye"': "give exactly one of 'k'"}
    for extra, message in cases.items():
        (tmp_path / "c.toml").write_text(base + extra + "\n")
        with pytest.raises(UserError, match=f"c.toml \\[camera\\]: {message}"):
            load_camera(tmp_path / "c.toml")
    (tmp_path / "c.toml").write_text(base + "k = [1.0]\n")    # no model: the fisheye, k = [1] equidistant
    cam = load_camera(tmp_path / "c.toml")
    assert type(cam) is FisheyeCamera and cam.k == (1.0,)
    lib = load_camera("scenarios/library/cameras/pinhole_25deg.toml")
    assert fov_deg(lib)[0] == pytest.approx(25.0, abs=1e-9)


def test_pixel_angle_of_a_pinhole_is_the_closed_form():
    """Largest angle one pixel subtends, from the unproject Jacobian (vision.ransac.pixel_angle):
    for a distortion-free pinhole with fx = fy = f, d ray / d(u, v) has singular values
    cos(theta)^2 / f (radial) and cos(theta) / f (tangential), so the largest is cos(theta) / f."""
    from vision.image_geometry import fast_pixel_angle, max_pixel_angle
    from vision.ransac import pixel_angle

    cam = PINHOLES["none"]
    uv = image_grid(cam, 37.0)
    rays = unproject(cam, uv)
    expect = rays[:, 2] / cam.fx
    assert np.max(np.abs(pixel_angle(cam, uv) / expect - 1)) < 1e-12
    assert np.array_equal(fast_pixel_angle(cam, uv), pixel_angle(cam, uv))
    assert max_pixel_angle(cam) == pytest.approx(1 / cam.fx, rel=1e-6)     # at the principal point


def test_front_end_on_a_rendered_pinhole_frame():
    """process_frame on geometric renderings (white WGS-84 ellipsoid, no atmosphere) through the
    25 deg pinhole file at 500 km, with the edge height 0: the nadir within 0.02 deg (one pixel is
    0.0198 deg; the fit of ~1000 edge points measures 0.001-0.004 deg) of the renderer's truth."""
    import dataclasses

    from scenarios.config.vision import load_vision_config
    from scenarios.sim import render
    from tests.poses import T0_ORBIT_NS as T0_NS, orbit_poses
    from nav import ephemeris
    from vision.frontend import FramePrior, process_frame

    cam = load_camera("scenarios/library/cameras/pinhole_25deg.toml")
    cfg = load_vision_config(camera=cam)
    cfg = dataclasses.replace(cfg, earth=dataclasses.replace(cfg.earth, atmosphere_m=0.0, atmosphere_sigma_m=0.0))
    for R_ec, x in orbit_poses(2):
        fr = render.render_frame(cam, R_ec, x, ephemeris.sun_position_e(T0_NS), None,
                                 options=render.RenderOptions.geometric())
        rec = process_frame(fr.image, cam, cfg, prior=FramePrior(x, R_ec)).record("earth")
        assert rec is not None
        assert math.degrees(angle(rec.e_c, fr.e_c_earth)) < 0.02
    with pytest.raises(ValueError, match="size 640x480 .*expected 1280x960"):
        process_frame(np.zeros((480, 640, 3), np.uint8), cam, cfg, prior=FramePrior(x, R_ec))


@pytest.mark.parametrize("cam", [PINHOLES["plumb_bob"], PINHOLES["rational"], atek_camera()])
def test_flight_log_camera_info_round_trip(tmp_path, cam):
    """LogWriter.write_camera writes the model's ROS CameraInfo; the replay reads the same camera
    back (scenarios.replay.inputs.camera_from_info): identical projection."""
    from scenarios.flightlog.reader import read_log
    from scenarios.flightlog.writer import LogWriter
    from scenarios.replay.inputs import camera_from_info

    t0 = 1_560_392_460_000_000_000
    path = tmp_path / "cam.mcap"
    with LogWriter(path, {"scenario": "", "seed": 0, "liftoff_utc_ns": t0, "kind": "simulated"}) as w:
        w.write_camera(1, np.array([t0], np.int64), cam)
    back = camera_from_info(read_log(path).cameras[1].info)
    assert type(back) is type(cam)
    uv = image_grid(cam, 64.0)
    assert np.max(np.abs(project(back, unproject(cam, uv)) - uv)) < 1e-9
