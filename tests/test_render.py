"""Synthetic camera images (scenarios/sim/render.py): geometric truth, determinism, bad input."""
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from nav import earth, ephemeris, timescales
from scenarios.sim import render
from scenarios.cli.render import parse_mission_time
from scenarios.errors import UserError
from vision.camera import FisheyeCamera, camera_from_dict, from_fov, unproject
from tests.poses import pose

T0 = timescales.parse_utc("2019-06-13T02:24:40Z")  # ATEK T+220 s
SUN = ephemeris.sun_position_e(T0)
MOON = ephemeris.moon_position_e(T0)


def small_camera(w=480, h=270) -> FisheyeCamera:
    """ATEK-like lens (94.4 deg horizontal, OpenCV fisheye D = [0.08, -0.01, 0, 0]) at low resolution."""
    return from_fov(w, h, 94.4, k_shape=(1.0, 0.08, -0.01, 0.0, 0.0), name="small")


def hits_ellipsoid(x, d):
    """Independent test of the ray against x^2/a^2 + y^2/a^2 + z^2/b^2 = 1 (unscaled quadratic)."""
    W = np.array([1 / earth.A**2, 1 / earth.A**2, 1 / earth.B**2])
    a = np.sum(d * d * W, axis=-1)
    b = 2 * np.sum(x * d * W, axis=-1)
    c = np.sum(x * x * W) - 1.0
    disc = b * b - 4 * a * c
    return (disc >= 0) & (b < 0)


@pytest.mark.parametrize("az,down,roll", [(0.0, 20.0, 0.0), (200.0, 5.0, 30.0), (90.0, 45.0, -70.0)])
def test_geometric_mode_matches_ellipsoid_cone(az, down, roll):
    """Clean mode: every pixel whose centre ray hits the ellipsoid is white, every other black,
    except pixels the true horizon crosses (their four corner rays disagree): those may go either
    way (the renderer's float32 rays move the boundary by < 1e-4 px)."""
    cam = small_camera()
    R, x = pose(az, down, roll_deg=roll)
    fr = render.render_frame(cam, R, x, SUN, MOON, seed=0, options=render.RenderOptions.geometric())
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(float)
    d_c = unproject(cam, np.stack([u, v], -1))
    truth = hits_ellipsoid(x, d_c @ R.T)
    corners = [hits_ellipsoid(x, unproject(cam, np.stack([u + du, v + dv], -1)) @ R.T)
               for du in (-0.5, 0.5) for dv in (-0.5, 0.5)]
    crossed = ~(np.all(corners, axis=0) | ~np.any(corners, axis=0))
    white = fr.image[..., 0] > 127
    assert np.all(fr.image[..., 0] == fr.image[..., 1])
    assert set(np.unique(fr.image)) <= {0, 255}
    assert crossed.sum() > 100  # the horizon is in view
    assert np.array_equal(white[~crossed], truth[~crossed])
    assert np.array_equal(fr.earth_mask[~crossed], truth[~crossed])
    # the Earth fraction agrees with the independent count to the horizon pixels
    assert abs(white.sum() - truth.sum()) <= crossed.sum()


def test_geometric_mode_horizon_is_inside_the_spherical_cone_bounds():
    """Earth pixels lie inside the cone of 003 eq. (4) for the largest radius (a) and outside the
    cone for the smallest (b): the ellipsoid lies between these spheres."""
    cam = small_camera()
    R, x = pose(30.0, 20.0)
    fr = render.render_frame(cam, R, x, SUN, None, seed=0, options=render.RenderOptions.geometric())
    d = render._camera_data(cam).rays.astype(float)
    e_c = fr.e_c_earth
    cosang = d @ e_c
    r = np.linalg.norm(x)
    cos_a_big = math.cos(math.asin(earth.A / r))
    cos_a_small = math.cos(math.asin(earth.B / r))
    assert np.all(cosang[fr.earth_mask] >= cos_a_big - 1e-6)
    assert np.all(cosang[~fr.earth_mask] <= cos_a_small + 1e-6)


def test_ray_ellipsoid_tangent_height():
    """Tangent height of a ray grazing the equator from above: closed form r_c cos(elevation) - a."""
    x = np.array([earth.A + 230e3, 0.0, 0.0])
    for h_t in (0.0, 10e3, 80e3):
        cosb = (earth.A + h_t) / (earth.A + 230e3)
        d = np.array([-math.sqrt(1 - cosb**2), cosb, 0.0])  # tangent to the circle of radius a + h_t
        hit, _, h = render.ray_ellipsoid(x, d)
        assert not hit or h_t == 0.0
        assert abs(h - h_t) < 1.0  # 1 m: float round-off of a 7e6 m geometry


def test_deterministic_and_seeded():
    cam = small_camera()
    R, x = pose(60.0)
    o = render.RenderOptions(cloud_map_size=128)
    a = render.render_frame(cam, R, x, SUN, MOON, seed=3, options=o).image
    b = render.render_frame(cam, R, x, SUN, MOON, seed=3, options=o).image
    c = render.render_frame(cam, R, x, SUN, MOON, seed=4, cloud_seed=3, options=o).image
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    # only the noise differs: mean absolute difference is a few codes, not a different scene
    assert np.mean(np.abs(a.astype(int) - c.astype(int))) < 6.0


def test_noise_statistics_match_photon_and_read_noise():
    """Flat white Earth filling the image, linear tone curve: per-pixel std equals
    sqrt(e + read^2) / full_well, within 5 % (2e5 samples: the estimate's own error is 0.3 %)."""
    cam = small_camera()
    R, x = pose(0.0, 80.0)  # looking nearly straight down: Earth everywhere
    o = render.RenderOptions.geometric(noise=True, exposure=0.5, full_well_e=2000.0, read_noise_e=10.0)
    img = render.render_frame(cam, R, x, SUN, None, seed=9, options=o).image[..., 1].astype(float)
    expected = math.sqrt(0.5 * 2000 + 100) / 2000 * 255
    assert abs(img.mean() - 0.5 * 255) < 0.5
    assert abs(img.std() / expected - 1) < 0.05


def test_atmosphere_raises_the_apparent_horizon_by_a_bounded_height():
    """With the atmosphere on, bright space pixels (the limb) have tangent heights below 100 km;
    the limb radiance model peaks a few km up (below, the sunlight itself is dimmed) and falls off
    monotonically above the peak, so a threshold picks one height d."""
    cam = small_camera()
    R, x = pose(60.0)
    o = render.RenderOptions(noise=False, lens_flare=False, sun_bloom=False, sun_glare=False,
                             payload_mask=None, cloud_map_size=128, vignetting=0.0)
    fr = render.render_frame(cam, R, x, SUN, None, seed=1, options=o)
    d_e = render._camera_data(cam).rays.astype(float) @ R.T
    hit, _, h_t = render.ray_ellipsoid(np.broadcast_to(x, d_e.shape), d_e)
    bright_space = (fr.image.mean(axis=2) > 128) & ~hit & (fr.pixel_class == 0)
    assert bright_space.sum() > 50
    assert np.max(h_t[bright_space]) < 100e3
    prof = render.limb_profile(np.linspace(0, 150e3, 151), o).mean(axis=1)
    peak = int(np.argmax(prof))
    assert peak <= 15  # km
    assert np.all(np.diff(prof[peak:]) <= 0)
    assert prof[peak] > 1000 * prof[-1]


def test_camera_looking_at_the_sun_gives_a_saturated_valid_image():
    cam = small_camera()
    s = (SUN - pose(0.0)[1])
    x = pose(0.0)[1]
    z = s / np.linalg.norm(s)
    xx = np.cross(z, [0, 0, 1.0])
    xx /= np.linalg.norm(xx)
    R = np.column_stack([xx, np.cross(z, xx), z])
    fr = render.render_frame(cam, R, x, SUN, MOON, seed=0, options=render.RenderOptions(cloud_map_size=128))
    c = np.round(fr.sun_uv).astype(int)
    assert np.allclose(fr.sun_uv, [cam.cx, cam.cy], atol=1e-6)
    assert np.all(fr.image[c[1], c[0]] == 255)
    assert fr.sun_visible == pytest.approx(1.0)
    assert fr.pixel_class[c[1], c[0]] == 3
    jpg = render.encode_jpeg(fr.image, 80)
    assert cv2.imdecode(np.frombuffer(jpg, np.uint8), cv2.IMREAD_COLOR).shape == fr.image.shape


def test_non_monotonic_distortion_camera_is_a_clear_error():
    d = {"width": 1920, "height": 1080, "fx": 700.0, "fy": 700.0, "cx": 959.5, "cy": 539.5,
         "k": [1.0, -0.5]}  # dr/dtheta = 1 - 1.5 theta^2 vanishes at 47 deg, inside the FOV
    with pytest.raises(ValueError, match="not monotonic"):
        camera_from_dict(d, where="bad_camera.toml")


@pytest.mark.parametrize("kw,msg", [
    (dict(R_ec=np.diag([1.0, 1.0, -1.0])), "proper rotation"),
    (dict(x_e=np.array([earth.A - 10.0, 0.0, 0.0])), "above the WGS-84 ellipsoid"),
    (dict(sun_e=np.array([0.0, 0.0, 1.0])), "geocentric Sun position"),
])
def test_bad_pose_inputs_name_the_problem(kw, msg):
    cam = small_camera(64, 36)
    R, x = pose(0.0)
    args = dict(R_ec=R, x_e=x, sun_e=SUN)
    args.update(kw)
    with pytest.raises(ValueError, match=msg):
        render.render_frame(cam, args["R_ec"], args["x_e"], args["sun_e"], None, seed=0)


def test_render_options_validation():
    with pytest.raises(ValueError, match="cloud_cover"):
        render.RenderOptions(cloud_cover=1.5)
    with pytest.raises(ValueError, match="jpeg_quality"):
        render.RenderOptions(jpeg_quality=0)


def test_motion_blur_smears_along_the_rotation():
    """A fast roll about the optical axis blurs the horizon: fewer sharp transitions."""
    cam = small_camera()
    R, x = pose(0.0)
    o = render.RenderOptions.geometric(motion_blur=True, exposure_time_s=0.01)
    sharp = render.render_frame(cam, R, x, SUN, None, seed=0, options=o).image[..., 0]
    blur = render.render_frame(cam, R, x, SUN, None, seed=0, options=o,
                               omega_c=np.array([0.0, 0.0, math.radians(360.0)])).image[..., 0]
    grey = lambda im: np.mean((im > 10) & (im < 245))
    assert grey(sharp) == 0.0
    assert grey(blur) > 0.005


def test_render_flight_frames_yields_decodable_jpegs():
    cam = small_camera(160, 90)
    recs = []
    for k, az in enumerate((0.0, 180.0)):
        R, x = pose(az)
        recs.append(render.FrameTruth(k, T0 + k, R, x))
    out = list(render.render_flight_frames([cam, cam], recs, seed=2, progress=False,
                                           options=render.RenderOptions(cloud_map_size=64)))
    assert [(k, t) for k, t, _ in out] == [(0, T0), (1, T0 + 1)]
    for _, _, jpg in out:
        img = cv2.imdecode(np.frombuffer(jpg, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (90, 160, 3)


def test_mission_time_parsing():
    assert parse_mission_time("171") == 171.0
    assert parse_mission_time("T+171.5") == 171.5
    with pytest.raises(UserError, match="T\\+171"):
        parse_mission_time("yesterday")


def test_cli_time_outside_flight_is_one_line_error():
    r = subprocess.run([sys.executable, "-m", "scenarios.cli", "render", "atek", "--time", "T+5000",
                        "-o", "/tmp/never.png"], capture_output=True, text=True)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert "outside the flight" in r.stderr and len(r.stderr.strip().splitlines()) == 1
