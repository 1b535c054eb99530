"""The front end's shortcuts against what they stand for: the Sun's search rows near the predicted
direction, the gate pre-filter, the per-candidate RANSAC generator, and the numba forms of small
numpy expressions (vision/frontend.py, vision/oblate.py)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from nav import earth
from nav.rotation import tangent_basis
from vision import fitting, frontend as F, image_geometry, scoring
from vision.borders import SearchConfig, search_line_spacing, search_rows
from vision.camera import atek_camera, project
from vision.candidates import Candidate
from vision.oblate import ellipsoid_model
from scenarios.sim import render
from tests.poses import pose
from tests.test_frontend import CAM, GEO_POSES, SUN, angle_deg, geometric_config


@pytest.fixture(scope="module")
def geo_frame():
    """The first geometric frame of tests/test_frontend.py."""
    az, down, roll, h = GEO_POSES[0]
    R, x = pose(az, down, h=h, roll_deg=roll)
    return R, x, render.render_frame(CAM, R, x, SUN, None, options=render.RenderOptions.geometric())


def _direction(off_axis_deg: float, azimuth_deg: float) -> np.ndarray:
    a, b = math.radians(off_axis_deg), math.radians(azimuth_deg)
    return np.array([math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)])


def test_gate_search_rows_keep_every_row_a_disc_in_the_gate_crosses():
    """A disc (radius <= alpha_max) centred within gate_deg of the prediction crosses only raster
    rows that `gate_search_rows` keeps: 400 random discs per prediction, their rims projected
    through the camera (the independent construction); the kept rows are a subset of the raster."""
    cam = atek_camera()
    search = SearchConfig(line_spacing_px=search_line_spacing(cam.fx, math.radians(0.5)))
    raster = search_rows(cam.height, search.line_spacing_px, search.line_offset_px)
    gate, alpha_max = 10.0, 4.0
    cap = math.radians(gate + alpha_max)
    rng = np.random.default_rng(3)
    psi = np.linspace(0.0, 2 * math.pi, 720)
    checked = 0
    for off, az in ((0.0, 0.0), (20.0, 30.0), (35.0, 200.0), (40.0, 95.0)):
        pred = _direction(off, az)
        rows = image_geometry.gate_search_rows(cam, pred, cap, search)
        assert rows is not None and set(rows.tolist()) <= set(raster.tolist())
        assert rows.size < raster.size          # the point of it: fewer rows than the raster
        T = tangent_basis(pred)
        for _ in range(400):
            # centre uniformly in the gate's cap, radius in [0.2, alpha_max] deg
            g = math.radians(gate) * math.sqrt(rng.uniform())
            w = rng.uniform(0, 2 * math.pi)
            c = math.cos(g) * pred + math.sin(g) * (math.cos(w) * T[:, 0] + math.sin(w) * T[:, 1])
            a = math.radians(rng.uniform(0.2, alpha_max))
            Tc = tangent_basis(c)
            rim = math.cos(a) * c + math.sin(a) * (np.cos(psi)[:, None] * Tc[:, 0] + np.sin(psi)[:, None] * Tc[:, 1])
            v = project(cam, rim)[:, 1]
            assert np.all(np.isfinite(v))
            crossed = raster[(raster >= v.min()) & (raster <= v.max())]
            assert set(crossed.tolist()) <= set(rows.tolist()), (off, az, crossed, rows)
            checked += crossed.size
    assert checked > 1000
    # a cap wholly beyond the lens's range: no row; partly beyond it: the whole raster (None)
    beyond = _direction(math.degrees(cam.max_theta) + 20.0, 0.0)
    assert image_geometry.gate_search_rows(cam, beyond, cap, search).size == 0
    edge = _direction(math.degrees(cam.max_theta) - 5.0, 0.0)
    assert image_geometry.gate_search_rows(cam, edge, cap, search) is None
    # no raster (Earth search: image border only): nothing to restrict
    assert image_geometry.gate_search_rows(cam, _direction(10.0, 0.0), cap, SearchConfig()) is None


def test_gate_pre_filter_rejects_only_what_the_gate_rejects(geo_frame, monkeypatch):
    """The gate pre-filter is a shortcut: with it switched off, a prior 15 deg off still gives no
    vector (the gate after the fit rejects it), and with a prior 3 deg off both give the same
    vector."""
    from nav.rotation import rotvec_to_matrix

    R, x, fr = geo_frame
    e_true = np.asarray(fr.e_c_earth, dtype=float)
    axis = np.cross(e_true, [0.0, 0.0, 1.0])
    axis /= np.linalg.norm(axis)
    cfg = geometric_config()
    for psi_deg in (15.0, 3.0):
        R_wrong = R @ rotvec_to_matrix(math.radians(psi_deg) * axis)
        prior = F.FramePrior(x, R_wrong)
        with_filter = F.process_frame(fr.image, CAM, cfg, prior=prior, rng=np.random.default_rng(1))
        with monkeypatch.context() as mp:
            mp.setattr(scoring, "_gate_reachable", lambda *a, **k: True)
            without = F.process_frame(fr.image, CAM, cfg, prior=prior, rng=np.random.default_rng(1))
        a, b = with_filter.record("earth"), without.record("earth")
        if psi_deg > cfg.earth.gate_deg:
            assert a is None and b is None
            assert "gate: fewer than" in with_filter.reasons["earth"]
            assert "from the predicted nadir > gate_deg" in without.reasons["earth"]
        else:
            assert a is not None and b is not None
            assert angle_deg(a.e_c, b.e_c) < 1e-9


def _candidate(points) -> Candidate:
    p = np.asarray(points, dtype=float)
    return Candidate(p, 0, False, "left", "right", float(len(p)))


def test_candidate_rng_depends_on_the_frame_seed_and_the_candidate_only():
    """Same frame seed and candidate: the same draws, whatever was drawn before; another first
    pixel, length or frame seed: other draws."""
    c1 = _candidate([[10, 20], [11, 20], [12, 21]])
    c2 = _candidate([[10, 21], [11, 21], [12, 22]])
    c3 = _candidate([[10, 20], [11, 20], [12, 21], [13, 21]])
    first = scoring.candidate_rng(7, c1).integers(0, 1000, 50)
    scoring.candidate_rng(7, c2).integers(0, 1000, 500)      # another candidate in between
    again = scoring.candidate_rng(7, c1).integers(0, 1000, 50)
    assert np.array_equal(first, again)
    for seed, c in ((7, c2), (7, c3), (8, c1)):
        assert not np.array_equal(first, scoring.candidate_rng(seed, c).integers(0, 1000, 50))


def test_spread_indices_is_the_numpy_expression():
    for m in range(3, 3000, 7):
        for k in (2, 3, 16, 100, 512):
            if m > k:
                ref = np.unique(np.linspace(0, m - 1, k).round().astype(np.int64))
                assert np.array_equal(fitting._spread_indices(m, k), ref), (m, k)


def test_pixel_angle_is_np_interp_on_its_table_and_bounds_the_exact_one():
    """`vision.image_geometry.fast_pixel_angle` (a kernel on the uniform radius grid) equals np.interp on the table (to a few
    ulp: the kernel finds the interval by division, np.interp by search), end values beyond the
    grid, NaN for NaN pixels; and it is within 1e-5 of the exact `pixel_angle` relative (measured
    9e-7 over the image: the function is smooth on the table's 256 radii)."""
    from vision.ransac import pixel_angle
    rng = np.random.default_rng(3)
    uv = np.concatenate([rng.uniform([-50.0, -50.0], [CAM.width + 50.0, CAM.height + 50.0], (4000, 2)),
                         [[CAM.cx, CAM.cy], [np.nan, 5.0], [-1e6, 0.0]]])
    q, tab, _ = image_geometry.pixel_angle_table(CAM)
    r = np.hypot((uv[:, 0] - CAM.cx) / CAM.fx, (uv[:, 1] - CAM.cy) / CAM.fy)
    got = image_geometry.fast_pixel_angle(CAM, uv)
    np.testing.assert_allclose(got, np.interp(r, q, tab), rtol=1e-14, atol=0.0)
    assert math.isnan(got[-2]) and got[-1] == tab[-1] and got[-3] == tab[0]
    inside = r <= q[-1]
    np.testing.assert_allclose(got[inside], pixel_angle(CAM, uv[inside]), rtol=1e-5)
    assert image_geometry.fast_pixel_angle(CAM, uv[:6].reshape(2, 3, 2)).shape == (2, 3)


def test_ellipsoid_to_fit_is_the_normalised_linear_map():
    """`LimbModel.to_fit` (numba kernel) against ``p = r M^T, p / |p|`` in numpy: equal to 1e-15
    (a few roundings of unit-size numbers)."""
    rng = np.random.default_rng(5)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    model = ellipsoid_model(np.array([earth.A + 200e3, 1e5, 3e6]), R, 45e3)
    rays = rng.normal(size=(300, 3))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    ref = rays @ model.M.T
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    assert np.max(np.abs(model.to_fit(rays) - ref)) < 1e-15
    assert np.max(np.abs(model.to_fit(rays[0]) - ref[0])) < 1e-15


def test_alpha_sensitivity_is_the_normal_equation_solution():
    """`_alpha_sensitivity` (2x2 by Cramer's rule in numba) against np.linalg.solve of the same
    normal equations (module docstring: de/dc = T (T^T N T)^-1 T^T H^T 1, times -sin alpha)."""
    rng = np.random.default_rng(2)
    e = _direction(25.0, 40.0)
    alpha = math.radians(70.0)
    T = tangent_basis(e)
    psi = rng.uniform(0.0, 1.5, 200)
    H = math.cos(alpha) * e + math.sin(alpha) * (np.cos(psi)[:, None] * T[:, 0] + np.sin(psi)[:, None] * T[:, 1])
    A = H @ T
    ref = (T @ np.linalg.solve(A.T @ A, A.T @ np.ones(len(H)))) * (-math.sin(alpha))
    assert np.allclose(fitting.alpha_sensitivity(H, e, alpha), ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("config_kw", [{}, {"gate_deg": 20.0}])
def test_gate_search_rows_follow_the_configuration(config_kw):
    """The Sun's rows come from its own raster and cap (gate_deg + alpha_max_deg): a wider gate
    keeps at least the rows of the narrower one."""
    cfg = F.default_config(CAM.fx)
    tc = dataclasses.replace(cfg.sun, **config_kw)
    pred = _direction(20.0, 60.0)
    narrow = image_geometry.gate_search_rows(CAM, pred, math.radians(cfg.sun.gate_deg + cfg.sun.alpha_max_deg),
                                cfg.sun.detection.search)
    rows = image_geometry.gate_search_rows(CAM, pred, math.radians(tc.gate_deg + tc.alpha_max_deg), tc.detection.search)
    assert set(narrow.tolist()) <= set(rows.tolist())
