"""Alignment without a given attitude (nav/initialise.py): roll / pitch / heading conversion, the
launcher, and the in-motion alignment from GPS and the IMU, checked against independent truths: an
aircraft-like flight whose truth and exact IMU come from analytic body rates and specific force,
and the simulator's rocket flights."""
from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation as Rot

from nav import earth, ins
from nav.imu_errors import corrupt
from nav.initialise import (aligned_initial_state, euler_to_q_eb, in_motion_alignment, launcher_alignment,
                            q_eb_to_euler)
from nav.navigator import NS, GpsData, ImuData, InitialState, run
from nav.rotation import quat_to_matrix
from nav.tuning import Tuning
from tests.test_navigator import T0, attitude_errors


def heading_error_deg(q_est, q_true, x_e) -> np.ndarray:
    """Error about the local vertical [deg] (the down component of psi in NED)."""
    psi = np.atleast_2d(attitude_errors(q_est, q_true))
    lat, lon, _ = earth.ecef_to_geodetic(np.atleast_2d(x_e))
    psi_n = np.einsum("nji,nj->ni", earth.R_en(lat, lon), psi)
    return np.degrees(np.abs(psi_n[:, 2]))


def aircraft_flight(seed=0, *, duration=240.0, rate_hz=200.0, gps_hz=5.0):
    """An aircraft-like flight at 1 km: 80 m/s heading 30 deg, speed changes of +-25 m/s (80 s period)
    and left / right turns (yaw rate up to 3 deg/s, 100 s period) with the lateral specific force
    that makes them, the specific force across holding the height. Truth: the INS on the error-free
    body rates and specific force (point samples); the IMU is that plus 003 table 3 biases, scale
    factors, misalignments and white noise; GPS 1.5 m / 0.05 m/s white noise."""
    rng = np.random.default_rng(seed)
    tun = Tuning()
    x0 = earth.geodetic_to_ecef(math.radians(47.0), math.radians(8.0), 1000.0)
    q0 = euler_to_q_eb(0.0, 0.0, 30.0, x0)
    v0 = quat_to_matrix(q0) @ np.array([80.0, 0.0, 0.0])
    n = int(round(duration * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    w_a = 2 * np.pi / 80.0
    a_x = 2.0 * np.sin(w_a * t)
    speed = 80.0 + 2.0 / w_a * (1 - np.cos(w_a * t))
    r = math.radians(3.0) * np.sin(2 * np.pi * t / 100.0)
    f_true = np.stack([a_x, speed * r, np.full(n, -9.807)], axis=1)
    w_true = np.stack([np.zeros(n), np.zeros(n), r], axis=1)
    X, V, Q = ins.propagate(x0, v0, q0, t, f_true, w_true)
    g = lambda s: rng.normal(0, s, 3)
    f_m, w_m = corrupt(f_true, w_true, b_f=g(tun.accel_bias.sigma), b_w=g(tun.gyro_bias.sigma),
                       s_f=g(tun.accel_scale.sigma), m_f=g(tun.accel_misalignment.sigma),
                       s_w=g(tun.gyro_scale.sigma), m_w=g(tun.gyro_misalignment.sigma))
    f_m = f_m + rng.normal(0, 0.05e-3 * 9.80665 * np.sqrt(rate_hz), f_m.shape)
    w_m = w_m + rng.normal(0, math.radians(0.05) / 60 * np.sqrt(rate_hz), w_m.shape)
    t_ns = T0 + np.round(t * NS).astype(np.int64)
    gi = np.arange(0, n, int(round(rate_hz / gps_hz)))
    gps = GpsData(t_ns[gi], X[gi] + rng.normal(0, 1.5, (gi.size, 3)), np.tile(np.eye(3) * 1.5 ** 2, (gi.size, 1, 1)),
                  V[gi] + rng.normal(0, 0.05, (gi.size, 3)), np.tile(np.eye(3) * 0.05 ** 2, (gi.size, 1, 1)))
    return ImuData(t_ns, f_m, w_m, "point"), gps, X, V, Q


@pytest.fixture(scope="module")
def aircraft():
    return aircraft_flight(1)


def test_euler_round_trip_and_convention():
    x = earth.geodetic_to_ecef(math.radians(67.9), math.radians(21.1), 330.0)
    for rph in [(10.0, -20.0, 135.0), (-170.0, 45.0, 5.0), (0.0, 0.0, 0.0)]:
        q = euler_to_q_eb(*rph, x)
        assert np.allclose(q_eb_to_euler(q, x), rph, atol=1e-9)
        R_nb = Rot.from_euler("ZYX", [rph[2], rph[1], rph[0]], degrees=True).as_matrix()
        lat, lon, _ = earth.ecef_to_geodetic(x)
        assert np.allclose(quat_to_matrix(q), earth.R_en(lat, lon) @ R_nb, atol=1e-12)
    # heading 90, pitch 0: the nose points east
    q = euler_to_q_eb(0.0, 0.0, 90.0, x)
    lat, lon, _ = earth.ecef_to_geodetic(x)
    assert np.allclose(quat_to_matrix(q) @ [1, 0, 0], earth.R_en(lat, lon)[:, 1], atol=1e-12)


def test_in_motion_alignment_aircraft(aircraft):
    """Heading within 1 deg after 60 s of motion, the error inside 3 sigma of the estimate."""
    imu, gps, X, V, Q = aircraft
    al = in_motion_alignment(imu, gps, int(imu.t_ns[0]), window_s=60.0)
    err = heading_error_deg(al.q_eb, Q[0], X[0])[0]
    tot = math.degrees(np.linalg.norm(attitude_errors(al.q_eb, Q[0])))
    print(f"aircraft in-motion alignment over 60 s: heading error {err:.3f} deg, total {tot:.3f} deg, "
          f"estimated sigma {math.degrees(al.att_sigma):.3f} deg")
    assert err < 1.0
    assert tot < 3 * math.degrees(al.att_sigma) + 0.05


def test_straight_flight_heading_is_unobservable():
    """Constant velocity, no turn: the heading is not determined and the covariance says so."""
    imu, gps, X, V, Q = aircraft_flight(2, duration=30.0)
    # the first 4 s: speed change 2 (1 - cos) / w < 0.5 m/s, heading change < 1.5 deg
    al = in_motion_alignment(imu, gps, int(imu.t_ns[0]), window_s=4.0)
    assert math.degrees(al.att_sigma) > 1.0


def filter_attitude_rms(imu, gps, init: InitialState, Q_true, tuning: Tuning, t_from_s: float) -> float:
    res = run(imu, init, tuning, gps=gps, store_for_smoother=False, unaided=False)
    i0 = int(np.searchsorted(imu.t_ns, init.t_ns))
    i1 = i0 + int(np.searchsorted((res.t_ns - res.t_ns[0]) / NS, t_from_s))
    err = np.degrees(np.linalg.norm(attitude_errors(res.q_eb[i1 - i0:], Q_true[i1:]), axis=1))
    return float(np.sqrt(np.mean(err ** 2)))


def test_filter_from_alignment_matches_truth_start(aircraft):
    """From 60 s on, a GPS/INS run started from the aligned attitude has an attitude RMS within 10 %
    of the same run started from the true attitude."""
    imu, gps, X, V, Q = aircraft
    init, al = aligned_initial_state(imu, gps, int(imu.t_ns[0]), window_s=60.0)
    tun = Tuning()
    logging.disable(logging.WARNING)
    try:
        rms_al = filter_attitude_rms(imu, gps, init, Q, tun.with_(init_att_sigma=max(al.att_sigma, math.radians(0.1))),
                                     60.0)
        rms_tr = filter_attitude_rms(imu, gps, InitialState(init.t_ns, init.x_e, init.v_e, Q[0]), Q, tun, 60.0)
    finally:
        logging.disable(logging.NOTSET)
    print(f"attitude RMS from 60 s on: aligned start {rms_al:.4f} deg, true start {rms_tr:.4f} deg "
          f"(ratio {rms_al / rms_tr:.3f})")
    assert rms_al <= 1.1 * rms_tr


@pytest.fixture(scope="module")
def nav_grade_ascent():
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    from tests.test_navigator import flight_inputs
    fl = simulate_flight(load_scenario("atek-nav-grade"), seed=2, duration=70.0)
    return fl, flight_inputs(fl, 0.0, seed=2)


def test_in_motion_alignment_rocket_ascent(nav_grade_ascent):
    """atek-nav-grade (400 Hz, 2000 deg/s gyros: unsaturated in the spin): the in-motion alignment
    over the ascent T+0..T+60, carried to T+60 by the INS, against the simulator's attitude there."""
    fl, fi = nav_grade_ascent
    init, al = aligned_initial_state(fi.imu, fi.gps, int(fi.gps.t_ns[0]), window_s=60.0, at_end=True)
    i = int(np.searchsorted(fi.imu.t_ns, init.t_ns))
    q_true, x_true = fi.truth.q_eb[fi.truth_idx[i]], fi.truth.x_e[fi.truth_idx[i]]
    err = heading_error_deg(init.q_eb, q_true, x_true)[0]
    tot = math.degrees(np.linalg.norm(attitude_errors(init.q_eb, q_true)))
    print(f"atek-nav-grade ascent alignment, at T+60: heading error {err:.3f} deg, total {tot:.3f} deg, "
          f"sigma {math.degrees(al.att_sigma):.3f} deg")
    assert err < 1.0


@pytest.mark.parametrize("name", ["atek", "high-apogee"])
def test_launcher_alignment_rocket(name):
    """On the rail before lift-off: the attitude from the launcher's azimuth / elevation and the
    roll from the accelerometer, against the simulator's truth at lift-off. The simulator starts at
    lift-off, so the accelerometer at rest is the error-free reading there (:func:`nav.ins.stationary_imu`)
    plus a 003 table 3 bias and 1 s of white noise."""
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    sc = load_scenario(name)
    tr = simulate_flight(sc, seed=4, duration=1.0).truth
    j = int(np.searchsorted(tr.t, 0.0))
    rng = np.random.default_rng(4)
    f0, _ = ins.stationary_imu(tr.x_e[j], tr.q_eb[j])
    f = f0 + rng.normal(0, Tuning().accel_bias.sigma, 3) + rng.normal(0, 0.05e-3 * 9.80665 * np.sqrt(20), (20, 3))
    L = sc.launch
    al = launcher_alignment(L.azimuth_deg, L.elevation_deg, tr.x_e[j], f_b=f)
    given = launcher_alignment(L.azimuth_deg, L.elevation_deg, tr.x_e[j], roll_deg=L.roll_deg)
    e_acc = np.degrees(attitude_errors(al.q_eb, tr.q_eb[j]))
    e_giv = math.degrees(np.linalg.norm(attitude_errors(given.q_eb, tr.q_eb[j])))
    h_acc = heading_error_deg(al.q_eb, tr.q_eb[j], tr.x_e[j])[0]
    print(f"{name} launcher: roll from the accelerometer: error {np.linalg.norm(e_acc):.3f} deg (about the vertical "
          f"{h_acc:.3f}), sigma {math.degrees(al.att_sigma):.2f} deg; given roll: {e_giv:.2e} deg")
    assert e_giv < 1e-6
    assert np.linalg.norm(e_acc) < 3 * math.degrees(al.att_sigma)
