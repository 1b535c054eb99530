"""Tests of vision/camera.py: fisheye model of 003 eq. (13) against identities and OpenCV."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from vision.camera import (FisheyeCamera, atek_camera, camera_from_dict, camera_to_dict,
                           from_camera_info, from_fov, from_opencv, inverse_radial, pixel_rays,
                           project, radial_distance, to_camera_info, to_opencv, unproject,
                           unproject_jacobian)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between rows, accurate near 0 (atan2 of |a x b| and a.b)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.einsum("...i,...i->...", a, b))


CAMERAS = [
    atek_camera(),
    # 5-coefficient model, non-square pixels, off-centre principal point
    FisheyeCamera(1280, 960, 600.0, 610.0, 655.3, 470.9, (1.02, -0.05, 0.012, -0.002, 1.5e-4)),
    # 190 deg fisheye: image circle beyond 90 deg, rays with z < 0 inside the image
    FisheyeCamera(1000, 1000, 290.0, 290.0, 499.5, 499.5, (1.0, -0.02, 0.001)),
]


def _image_rays(cam: FisheyeCamera, rng: np.random.Generator, n: int = 20000) -> np.ndarray:
    """Random rays whose pixels lie in the image: theta over the whole field of view."""
    uv = np.stack([rng.uniform(-0.5, cam.width - 0.5, n), rng.uniform(-0.5, cam.height - 0.5, n)], -1)
    return unproject(cam, uv)


@pytest.mark.parametrize("cam", CAMERAS, ids=["atek", "poly5", "fish190"])
def test_roundtrip_ray_pixel_ray(cam):
    # Identity: unproject(project(p)) == p/|p| to < 1e-9 rad over the whole FOV (requirement);
    # Newton stops at 1e-13 rad, the rest is float64 rounding in sin/cos (~1e-15).
    rng = np.random.default_rng(1)
    rays = _image_rays(cam, rng)
    rays = rays * rng.uniform(0.1, 10.0, (rays.shape[0], 1))  # any length
    back = unproject(cam, project(cam, rays))
    err = _angle(back, rays)
    assert np.max(err) < 1e-9
    assert np.allclose(np.linalg.norm(back, axis=1), 1.0, atol=1e-15 * 10)
    theta = np.arccos(np.clip(rays[:, 2] / np.linalg.norm(rays, axis=1), -1, 1))
    assert theta.max() > 0.9 * cam.fov_theta  # the sample did reach the edge of the FOV


@pytest.mark.parametrize("cam", CAMERAS, ids=["atek", "poly5", "fish190"])
def test_roundtrip_pixel_ray_pixel(cam):
    rng = np.random.default_rng(2)
    uv = np.stack([rng.uniform(-0.5, cam.width - 0.5, 20000),
                   rng.uniform(-0.5, cam.height - 0.5, 20000)], -1)
    # 1e-9 px: pixel coordinates ~1e3 carry float64 rounding ~1e-13
    assert np.max(np.abs(project(cam, unproject(cam, uv)) - uv)) < 1e-9


def test_inverse_radial_precision_and_axis():
    cam = CAMERAS[1]
    th = np.linspace(0.0, cam.fov_theta, 10001)
    assert np.max(np.abs(inverse_radial(cam, radial_distance(cam, th)) - th)) < 1e-12
    # the principal point is the optical axis
    assert np.allclose(unproject(cam, np.array([cam.cx, cam.cy])), [0, 0, 1], atol=0)
    assert np.isnan(inverse_radial(cam, np.array(cam.max_radius * 1.01)))


@pytest.mark.parametrize("cam", CAMERAS, ids=["atek", "poly5", "fish190"])
def test_kernels_agree_with_the_numpy_reference(cam):
    # The numba kernels (table start + one Newton step per pixel) against the vectorised numpy
    # references (all pixels iterated together, tests/vision_reference.py): both stop at
    # Newton steps below 1e-13 rad, so they agree to float64 rounding (a few 1e-16 rad; 1e-14
    # allows for the ulps of sin/cos/atan2). Invalid radii, the axis, NaN and far-off pixels too.
    from tests.vision_reference import project_reference, unproject_reference
    from vision.camera import _inverse_radial_bracketed
    rng = np.random.default_rng(7)
    uv = np.stack([rng.uniform(-0.5, cam.width - 0.5, 50000), rng.uniform(-0.5, cam.height - 0.5, 50000)], -1)
    uv = np.vstack([uv, [[cam.cx, cam.cy], [cam.cx + 1e-7, cam.cy], [np.nan, 1.0], [1e7, 1e7]]])
    r = np.hypot((uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy)
    r = np.concatenate([r, [0.0, cam.max_radius, -1e-3, cam.max_radius * 1.01]])
    th, th_ref = inverse_radial(cam, r), _inverse_radial_bracketed(cam, r)
    np.testing.assert_array_equal(np.isnan(th), np.isnan(th_ref))
    assert np.nanmax(np.abs(th - th_ref)) < 1e-14
    rays, ref = unproject(cam, uv), unproject_reference(cam, uv)
    np.testing.assert_array_equal(np.isnan(rays), np.isnan(ref))
    assert np.nanmax(np.abs(rays - ref)) < 1e-14
    ok = np.all(np.isfinite(rays), axis=1)
    p = np.vstack([rays[ok] * rng.uniform(0.1, 10.0, (ok.sum(), 1)), [[0, 0, -1.0], [0, 0, 0.0], [0, 0, 2.0]]])
    uv2, uv_ref = project(cam, p), project_reference(cam, p)
    np.testing.assert_array_equal(np.isnan(uv2), np.isnan(uv_ref))
    assert np.nanmax(np.abs(uv2 - uv_ref)) < 1e-9    # pixels ~1e3: float64 rounding ~1e-13
    # shapes: scalars and leading axes pass through
    assert unproject(cam, uv[:6].reshape(2, 3, 2)).shape == (2, 3, 3)
    assert project(cam, rays[:6].reshape(3, 2, 3)).shape == (3, 2, 2)
    assert inverse_radial(cam, np.array(0.3)).shape == ()


def test_theta_beyond_90_deg():
    cam = CAMERAS[2]
    assert cam.fov_theta > math.radians(95)  # image corners see behind the image plane
    ray = np.array([math.sin(math.radians(95)), 0.0, math.cos(math.radians(95))])
    uv = project(cam, ray)
    # r_d(theta) closed form
    th = math.radians(95)
    r = 1.0 * th - 0.02 * th**3 + 0.001 * th**5
    assert uv[0] == pytest.approx(cam.cx + cam.fx * r, abs=1e-9) and uv[1] == pytest.approx(cam.cy)
    assert _angle(unproject(cam, uv), ray) < 1e-12


@pytest.mark.parametrize("cam", CAMERAS[:2], ids=["atek", "poly5"])
def test_agrees_with_cv2_fisheye(cam):
    # OpenCV fisheye (4 coefficients, k1 folded into K): agreement to < 1e-6 px (requirement),
    # for rays in front of the camera (OpenCV's model uses x/z and cannot see theta >= 90 deg).
    rng = np.random.default_rng(3)
    rays = _image_rays(cam, rng, 5000)
    K, D = to_opencv(cam)
    obj = (rays / rays[:, 2:3] * rng.uniform(1, 50, (rays.shape[0], 1)))[None]
    ref, _ = cv2.fisheye.projectPoints(obj.astype(np.float64), np.zeros(3), np.zeros(3), K, D)
    assert np.max(np.abs(ref[0] - project(cam, rays))) < 1e-6


def test_opencv_roundtrip_and_errors():
    K = np.array([[800.0, 0, 640.2], [0, 805.0, 360.7], [0, 0, 1]])
    D = np.array([0.01, -0.003, 0.0005, -0.0001])
    cam = from_opencv(K, D, 1280, 720)
    K2, D2 = to_opencv(cam)
    assert np.array_equal(K2, K) and np.array_equal(D2, D)
    with pytest.raises(ValueError, match="4 distortion coefficients"):
        from_opencv(K, [0.1, 0.0, 0.0, 0.0, 0.0], 1280, 720)
    with pytest.raises(ValueError, match="skew"):
        from_opencv(np.array([[800.0, 1.0, 640], [0, 800, 360], [0, 0, 1]]), D, 1280, 720)
    # a 5-coefficient model with k1 != 1 converts by folding k1 into fx, fy: same pixels
    cam5 = CAMERAS[1]
    K5, D5 = to_opencv(cam5)
    assert K5[0, 0] == pytest.approx(cam5.fx * cam5.k[0])
    again = from_opencv(K5, D5, cam5.width, cam5.height)
    rays = _image_rays(cam5, np.random.default_rng(4), 1000)
    assert np.max(np.abs(project(again, rays) - project(cam5, rays))) < 1e-9


def test_camera_info_roundtrip():
    cam = atek_camera()
    info = to_camera_info(cam)
    assert info["distortion_model"] == "equidistant" and len(info["D"]) == 4
    assert len(info["K"]) == 9 and len(info["P"]) == 12 and len(info["R"]) == 9
    back = from_camera_info(info)
    rays = _image_rays(cam, np.random.default_rng(5), 1000)
    assert np.max(np.abs(project(back, rays) - project(cam, rays))) < 1e-9
    with pytest.raises(ValueError, match="distortion_model 'fov'"):
        from_camera_info(dict(info, distortion_model="fov"))
    with pytest.raises(ValueError, match="'rational_polynomial' takes 8"):
        from_camera_info(dict(info, distortion_model="rational_polynomial"))


def test_non_monotonic_polynomial_is_rejected():
    # r_d = theta - 0.5 theta^3: dr/dtheta = 1 - 1.5 theta^2 = 0 at theta = sqrt(2/3) = 46.78 deg;
    # the image corner (r_d = 0.6 / ...) needs more than r_d(max) = 0.544
    with pytest.raises(ValueError, match=r"not monotonic.*46\.78\d* deg") as exc:
        FisheyeCamera(1000, 1000, 600.0, 600.0, 499.5, 499.5, (1.0, -0.5))
    assert "k = [1.0, -0.5]" in str(exc.value)
    # the same polynomial is fine if the image stays inside the monotonic range
    ok = FisheyeCamera(400, 400, 600.0, 600.0, 199.5, 199.5, (1.0, -0.5))
    assert ok.max_theta == pytest.approx(math.sqrt(2 / 3), abs=1e-12)
    assert np.all(np.isnan(project(ok, np.array([math.sin(0.9), 0, math.cos(0.9)]))))


def test_from_fov_definition():
    for axis, half_px in (("horizontal", 960.0), ("vertical", 540.0),
                          ("diagonal", math.hypot(1920, 1080) / 2)):
        cam = from_fov(1920, 1080, 94.4, k_shape=(1.0, 0.05), axis=axis)
        # ray through the image edge (pixel edge) at the stated half-angle, through the centre
        if axis == "horizontal":
            uv = np.array([[-0.5, cam.cy], [cam.width - 0.5, cam.cy]])
        elif axis == "vertical":
            uv = np.array([[cam.cx, -0.5], [cam.cx, cam.height - 0.5]])
        else:
            uv = np.array([[-0.5, -0.5], [cam.width - 0.5, cam.height - 0.5]])
        r = unproject(cam, uv)
        assert math.degrees(_angle(r[0], r[1])) == pytest.approx(94.4, abs=1e-9)
        assert cam.fx == cam.fy
    atek = atek_camera()
    r = unproject(atek, np.array([[-0.5, 539.5], [1919.5, 539.5]]))
    assert math.degrees(_angle(r[0], r[1])) == pytest.approx(94.4, abs=1e-9)
    # "strongly distorted": at the image edge the radius is well below a pinhole's
    assert (960 / atek.fx) / math.tan(math.radians(47.2)) < 0.85


def test_jacobian_against_finite_differences():
    cam = CAMERAS[1]
    rng = np.random.default_rng(6)
    uv = np.stack([rng.uniform(0, cam.width, 200), rng.uniform(0, cam.height, 200)], -1)
    uv = np.vstack([uv, [[cam.cx, cam.cy], [cam.cx + 1e-3, cam.cy - 2e-3]]])  # on/near the axis
    rays, J = unproject_jacobian(cam, uv)
    assert np.allclose(rays, unproject(cam, uv), atol=1e-15)
    h = 1e-4
    num = np.stack([(unproject(cam, uv + [h, 0]) - unproject(cam, uv - [h, 0])) / (2 * h),
                    (unproject(cam, uv + [0, h]) - unproject(cam, uv - [0, h])) / (2 * h)], -1)
    # central differences: truncation ~h^2 * |d3 ray| ~ 1e-8 * 1e-9 and rounding ~1e-16/h
    assert np.max(np.abs(J - num)) < 1e-10


def test_pixel_rays_grid():
    cam = FisheyeCamera(64, 48, 40.0, 41.0, 31.7, 23.2, (1.0, 0.03))
    g = pixel_rays(cam)
    assert g.shape == (48, 64, 3)
    assert np.allclose(g[10, 20], unproject(cam, np.array([20.0, 10.0])), atol=0)
    assert np.allclose(np.linalg.norm(g, axis=-1), 1.0, atol=1e-15)


def test_dict_roundtrip_and_errors():
    cam = CAMERAS[1]
    assert camera_from_dict(camera_to_dict(cam)) == cam
    d = camera_to_dict(atek_camera())
    d.pop("k")
    d["opencv_D"] = [0.08, -0.01, 0.0, 0.0]
    assert camera_from_dict(d) == atek_camera()  # opencv_D = [d1..d4] means k = [1, d1..d4]
    with pytest.raises(ValueError, match="missing key 'fx'"):
        camera_from_dict({k: v for k, v in camera_to_dict(cam).items() if k != "fx"}, where="x.toml")
    with pytest.raises(ValueError, match="x.toml: key 'width'"):
        camera_from_dict(dict(camera_to_dict(cam), width=-3), where="x.toml")
    with pytest.raises(ValueError, match="exactly one of"):
        camera_from_dict(dict(camera_to_dict(cam), opencv_D=[0, 0, 0, 0]))
    with pytest.raises(ValueError, match="unknown key"):
        camera_from_dict(dict(camera_to_dict(cam), k6=1.0))
    with pytest.raises(ValueError, match="'model' = 'orthographic'"):
        camera_from_dict(dict(camera_to_dict(cam), model="orthographic"))
    with pytest.raises(ValueError, match="key 'k' does not apply to model 'pinhole'"):
        camera_from_dict(dict(camera_to_dict(cam), model="pinhole"))
