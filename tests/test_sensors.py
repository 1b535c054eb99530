"""IMU, GPS and camera-truth models: statistics against their configured values, geometry identities.

Statistical bounds: a sample standard deviation s of n independent normal draws has
(n - 1) s^2 / sigma^2 ~ chi^2(n - 1); for large n, s / sigma - 1 is about N(0, 1 / (2 n)). The tests
accept |s / sigma - 1| < 5 / sqrt(2 n) (5 sigma: false alarm probability 6e-7 per check), and sample
means within 5 sigma / sqrt(n).
"""
import copy

import numpy as np
import pytest

from scenarios.sim import camera_geometry as cg
from scenarios.sim.gps import simulate_gps, truth_at
from scenarios.sim.imu import (DEG_RT_H, MG, ImuSamples, apply_errors, draw_imu_errors, ideal_imu,
                                 noise_sigmas, simulate_imu)
from scenarios.sim.scenario import load_scenario
from scenarios.sim.simulate import rng_for, simulate_flight
from scenarios.sim.truth import simulate_truth
from vision.camera import atek_camera, from_fov


def _sd_ok(s, sigma, n):
    return abs(s / sigma - 1) < 5 / np.sqrt(2 * n)


@pytest.fixture(scope="module")
def short_flight():
    sc = load_scenario("atek")
    return sc, simulate_truth(sc, 80.0)


def test_white_noise_matches_density():
    cfg = copy.deepcopy(load_scenario("atek").imu)
    cfg.gyro_resolution_dps = 0.0
    n = 200_000
    for output in ("rate", "increment"):
        ideal = ImuSamples(np.arange(n) * 0.05, np.zeros((n, 3)), np.zeros((n, 3)), output, 0.05)
        out = apply_errors(ideal, cfg, None, np.random.default_rng(5))
        sg, sa = noise_sigmas(cfg, output, 0.05)
        k = 1 / np.sqrt(0.05) if output == "rate" else np.sqrt(0.05)
        assert np.isclose(sg, 0.05 * DEG_RT_H * k) and np.isclose(sa, 0.05 * MG * k)
        for a, s in ((out.gyro, sg), (out.accel, sa)):
            for j in range(3):
                assert _sd_ok(a[:, j].std(ddof=1), s, n)
                assert abs(a[:, j].mean()) < 5 * s / np.sqrt(n)


def test_turn_on_errors_statistics():
    cfg = load_scenario("atek").imu
    draws = [draw_imu_errors(cfg, rng_for(s, 1)) for s in range(3000)]
    n = 3 * len(draws)
    checks = [("gyro_bias", np.radians(6.0) / 3600), ("accel_bias", 2 * MG), ("gyro_scale", 2000e-6),
              ("accel_scale", 300e-6)]
    for name, sigma in checks:
        v = np.concatenate([getattr(d, name) for d in draws])
        assert _sd_ok(v.std(ddof=1), sigma, n), name
    off = ~np.eye(3, dtype=bool)
    for name, sigma in (("gyro_misalignment", 2e-3), ("accel_misalignment", 2e-3)):
        v = np.concatenate([getattr(d, name)[off] for d in draws])
        assert _sd_ok(v.std(ddof=1), sigma, 2 * n), name
        assert all(np.all(np.diag(getattr(d, name)) == 0) for d in draws)


def test_errors_applied_as_model():
    """y = M x + b exactly when noise, saturation and quantisation are off."""
    cfg = copy.deepcopy(load_scenario("atek").imu)
    cfg.gyro_resolution_dps = 0.0
    err = draw_imu_errors(cfg, np.random.default_rng(2))
    rng = np.random.default_rng(3)
    x = ImuSamples(np.arange(10.0), rng.normal(size=(10, 3)), rng.normal(size=(10, 3)) * 10, "rate", 0.05)
    y = apply_errors(x, cfg, err, None)
    np.testing.assert_allclose(y.gyro, x.gyro @ err.M_g.T + err.gyro_bias, atol=1e-15)
    np.testing.assert_allclose(y.accel, x.accel @ err.M_a.T + err.accel_bias, atol=1e-13)


def test_quantisation_and_saturation():
    cfg = copy.deepcopy(load_scenario("atek").imu)
    cfg.gyro_noise_deg_rt_h = 0.0
    q = np.radians(cfg.gyro_resolution_dps)
    n = 100_000
    rng = np.random.default_rng(4)
    x = rng.uniform(-0.5, 0.5, (n, 3))  # rad/s, far inside the range
    y = apply_errors(ImuSamples(np.arange(n) * 0.05, x, np.zeros((n, 3)), "rate", 0.05), cfg, None, None).gyro
    e = y - x
    assert np.all(np.abs(e) <= q / 2 + 1e-15)
    assert np.allclose(np.round(y / q), y / q)
    assert _sd_ok(e.std(ddof=1), q / np.sqrt(12), 3 * n)  # uniform quantisation error q^2/12
    # increments: residual carried, so the sum of outputs stays within one quantum of the input sum
    inc = apply_errors(ImuSamples(np.arange(n) * 0.05, x * 0.05, np.zeros((n, 3)), "increment", 0.05),
                       cfg, None, None).gyro
    assert np.max(np.abs(np.cumsum(inc - x * 0.05, axis=0))) <= q * 0.05 / 2 + 1e-12
    # saturation at +-1000 deg/s
    big = ImuSamples(np.arange(3.0), np.full((3, 3), np.radians(1500.0)), np.zeros((3, 3)), "rate", 0.05)
    assert np.all(np.degrees(apply_errors(big, cfg, None, None).gyro) <= 1000.0 + 1e-9)


def test_rate_quantum_grid_phase_is_drawn_per_run():
    """With a generator, the rate quantum grid's phase u ~ U(0, q) is drawn per run and axis: within
    a run the outputs lie on one grid u + k q (differences are whole quanta) within q/2 of the input;
    over runs the error of the same input is uniform on [-q/2, q/2): mean 0, sd q / sqrt(12) (the
    aligned grid of rng None gives every run the same error)."""
    cfg = copy.deepcopy(load_scenario("atek").imu)
    cfg.gyro_noise_deg_rt_h = 0.0
    cfg.accel_noise_mg_rt_hz = 0.0
    cfg.accel_resolution_mg = 0.5
    q = np.radians(cfg.gyro_resolution_dps)
    x = ImuSamples(np.arange(200) * 0.05, np.linspace(-0.01, 0.01, 200)[:, None] * [1.0, 0.7, -0.3],
                   np.full((200, 3), 0.0123), "rate", 0.05)
    runs = 4000
    e = np.empty((runs, 3))
    for r in range(runs):
        y = apply_errors(x, cfg, None, np.random.default_rng(r))
        k = (y.gyro - y.gyro[:1]) / q
        assert np.allclose(k, np.round(k), atol=1e-9) and np.all(np.abs(y.gyro - x.gyro) <= q / 2 + 1e-15)
        assert np.all(np.abs(y.accel - x.accel) <= 0.5 * MG / 2 + 1e-15)
        e[r] = y.gyro[100] - x.gyro[100]
    for j in range(3):
        assert abs(e[:, j].mean()) < 5 * q / np.sqrt(12 * runs), e[:, j].mean() / q
        assert _sd_ok(e[:, j].std(ddof=1), q / np.sqrt(12), runs)
    k0 = apply_errors(x, cfg, None, None).gyro / q
    assert np.allclose(k0, np.round(k0), atol=1e-9)  # rng None: the grid is aligned with zero


def test_atek_gyros_saturate_in_spin_and_nav_grade_does_not(short_flight):
    sc, tr = short_flight
    meas, _ = simulate_imu(tr, sc.imu, rng_for(1, 1))
    spin = (meas.t > 35) & (meas.t < 56)
    assert np.all(np.abs(np.degrees(meas.gyro[spin, 0]) - 1000.0) < 0.05)  # clipped (+ one quantum)
    ng = load_scenario("atek-nav-grade")
    m2, _ = simulate_imu(tr, ng.imu, rng_for(1, 1))
    s2 = (m2.t > 35) & (m2.t < 56)
    ideal = ideal_imu(tr, 400.0, "rate", "average")
    np.testing.assert_allclose(m2.gyro[s2, 0], ideal.gyro[s2, 0], rtol=1e-4, atol=1e-4)
    assert np.degrees(m2.gyro[s2, 0]).max() > 1200


def test_average_samples_are_interval_means(short_flight):
    """Averages from the carried integrals equal the trapezoid mean of the dense truth (to O(dt^2))."""
    _, tr = short_flight
    avg = ideal_imu(tr, 20.0, "rate", "average")
    m = 20
    k = 500  # sample at t = 25 s
    i = int(round(avg.t[k] / tr.dt))
    w = tr.omega_ib_b[i - m:i + 1]
    trap = (w[1:] + w[:-1]).sum(axis=0) / 2 / m
    np.testing.assert_allclose(avg.gyro[k], trap, atol=2e-4)


def test_gps_noise_latency_outages(short_flight):
    sc, tr = short_flight
    cfg = copy.deepcopy(sc.gps)
    cfg.outages_s = [[20.0, 30.0]]
    fix = simulate_gps(tr, cfg, np.random.default_rng(7))
    assert not np.any((fix.t >= 20) & (fix.t < 30)) and len(fix.t) == 801 - 100
    p, v = truth_at(tr, fix.t)
    n = 3 * len(fix.t)
    assert _sd_ok((fix.position - p).std(ddof=1), 3.0, n)
    assert _sd_ok((fix.velocity - v).std(ddof=1), 0.1, n)
    np.testing.assert_allclose(fix.position_cov, 9.0 * np.eye(3))
    cfg.position_sigma_m, cfg.velocity_sigma_mps, cfg.latency_s, cfg.outages_s = 0.0, 0.0, 0.25, []
    fix = simulate_gps(tr, cfg, np.random.default_rng(7))
    i = np.round((fix.t - 0.25) / tr.dt).astype(int)  # the latency is a multiple of the truth step
    np.testing.assert_allclose(fix.position, tr.x_e[i], atol=1e-6)
    np.testing.assert_allclose(fix.velocity, tr.v_e[i], atol=1e-9)


def test_sensor_streams_are_independent(short_flight):
    """Changing the GPS configuration leaves the IMU and camera draws unchanged."""
    sc, _ = short_flight
    a = simulate_flight(sc, seed=11, duration=20.0)
    sc2 = copy.deepcopy(sc)
    sc2.gps.rate_hz, sc2.gps.position_sigma_m = 5.0, 10.0
    b = simulate_flight(sc2, seed=11, duration=20.0)
    np.testing.assert_array_equal(a.imu.gyro, b.imu.gyro)
    np.testing.assert_array_equal(a.cameras[1].psi_c, b.cameras[1].psi_c)
    assert len(b.gps.t) != len(a.gps.t)
    c = simulate_flight(sc, seed=12, duration=20.0)
    assert not np.array_equal(a.imu.gyro, c.imu.gyro)


def test_mount_geometry():
    R = cg.mount_rotation(90.0, 20.0)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
    assert np.isclose(np.linalg.det(R), 1.0)
    d = np.radians(20.0)
    np.testing.assert_allclose(R[:, 2], [-np.sin(d), 0.0, np.cos(d)], atol=1e-15)  # radial = +z_b
    assert R[0, 1] < -0.9  # image "down" points towards the tail (-x_b)


def _synthetic(camera, axis_e, up_e, h=230e3):
    """Camera at height h above the pole region, optical axis axis_e, image 'up' ~ up_e."""
    from nav import earth
    x = earth.geodetic_to_ecef(np.radians(67.9), np.radians(21.1), h)
    z = axis_e / np.linalg.norm(axis_e)
    y = -(up_e - (up_e @ z) * z)
    y /= np.linalg.norm(y)
    R_ec = np.stack([np.cross(y, z), y, z], axis=-1)
    from nav.rotation import matrix_to_quat
    q = matrix_to_quat(R_ec)  # body = camera (R_bc = I)
    sun = np.array([[1.0, 0.0, 0.0]])
    return cg.camera_truth(camera, np.eye(3), np.zeros(1), x[None], np.array([h]), q[None], sun, sun,
                           radial_b=np.array([0.0, 0.0, 1.0]), mask_deg=-90.0), x


def test_horizon_visibility_and_conic_type():
    from nav import earth
    cam = atek_camera()
    lat, lon = np.radians(67.9), np.radians(21.1)
    R_en = earth.R_en(lat, lon)
    down, north = R_en[:, 2], R_en[:, 0]
    # looking straight down: the Earth (alpha ~ 75 deg) fills the 107 deg diagonal field of view
    ct, x = _synthetic(cam, down, north)
    assert not ct.horizon_visible[0] and ct.earth_fraction[0] == 1.0 and ct.conic_type[0] == ""
    # the optical axis is the ellipsoid normal; the nadir (to the centre) is off by the geocentric/
    # geodetic latitude difference (003 §2.8)
    np.testing.assert_allclose(ct.nadir_c[0, 2], (-x / np.linalg.norm(x)) @ down, atol=1e-12)
    # looking up: only space
    ct, _ = _synthetic(cam, -down, north)
    assert not ct.horizon_visible[0] and ct.earth_fraction[0] == 0.0
    # looking horizontally: the horizon (dip ~15 deg) crosses the image below the centre; hyperbola
    ct, _ = _synthetic(cam, north, -down)
    assert ct.horizon_visible[0] and ct.conic_type[0] == "hyperbola"
    assert 0.05 < ct.earth_fraction[0] < 0.5
    # 003 eq. (5): alpha from the geocentric radius below the camera
    r = np.linalg.norm(x)
    assert np.isclose(ct.alpha[0], np.arcsin((r - 230e3) / r))
    # a 170 deg fisheye at 700 km looking down sees the whole Earth disc: ellipse
    wide = from_fov(1000, 1000, 170.0)
    ct, _ = _synthetic(wide, down, north, h=700e3)
    assert ct.horizon_visible[0] and ct.conic_type[0] == "ellipse" and 0.3 < ct.earth_fraction[0] < 1


def test_flight_camera_truth(short_flight):
    """Per-frame nadir vectors equal R_cb R_be (-x/|x|) computed independently with scipy."""
    from scipy.spatial.transform import Rotation
    sc, tr = short_flight
    fl = simulate_flight(sc, seed=3, duration=80.0)
    for c in fl.cameras:
        assert np.degrees(np.abs(c.psi_c)).max() < 5  # 1 deg sigma draws
        idx = np.round(c.truth.t / tr.dt).astype(int)
        R_eb = Rotation.from_quat(tr.q_eb[idx])
        x = tr.x_e[idx]
        e_b = R_eb.inv().apply(-x / np.linalg.norm(x, axis=1, keepdims=True))
        np.testing.assert_allclose(c.truth.nadir_c, e_b @ c.R_bc, atol=1e-12)
        assert np.allclose(np.linalg.norm(c.truth.sun_c, axis=1), 1.0)
        assert c.t_ns[0] == tr.liftoff_ns + 60 * 10**9  # atek cameras: coast from T+60 (start_s)
        assert np.all(np.diff(c.t_ns) == 10**9)
