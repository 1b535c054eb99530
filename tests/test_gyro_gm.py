"""The optional Gauss-Markov gyro error state g_w (nav/error_state.py group ``gyro_gm``,
nav/filter_state.py) and the simulator's Gauss-Markov gyro drift (scenarios/sim/imu.py)."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from scipy.linalg import expm

from nav.error_state import TransitionBuilder, build_layout, discrete_transition, error_dynamics
from nav.filter_state import FilterState
from nav.tuning import StateGroupTuning, Tuning, tuning_from_toml

DEG_H = math.radians(1.0) / 3600.0
GM_SIGMA_DEG_H, GM_TAU_S = 5.0, 100.0   #: the simulated drift (the issue's example)


def test_tuning_table():
    """[states.gyro_gm]: mode, sigma_deg_h and correlation_time_s (positive); off by default."""
    t = tuning_from_toml('[states.gyro_gm]\nmode = "C"\nsigma_deg_h = 5\ncorrelation_time_s = 300\n')
    assert t.gyro_gm == StateGroupTuning("C", 5 * DEG_H) and t.gyro_gm_tau_s == 300.0
    assert Tuning().gyro_gm.mode == "off" and not build_layout(Tuning(), 2).has("gyro_gm")
    with pytest.raises(ValueError, match=r"gyro_gm\] correlation_time_s"):
        tuning_from_toml('[states.gyro_gm]\nmode = "E"\ncorrelation_time_s = 0\n')
    lay = build_layout(t, 1)
    assert lay["gyro_gm"] == slice(lay["gyro_misalignment"].stop, lay["gyro_misalignment"].stop + 3)
    assert not lay.estimated_mask[lay["gyro_gm"]].any()


def _gm_tuning(mode="E"):
    return Tuning().with_(gyro_gm=StateGroupTuning(mode, GM_SIGMA_DEG_H * DEG_H), gyro_gm_tau_s=GM_TAU_S)


def test_transition_matches_expm():
    """With g_w on, the filter's compiled transition equals the reference discrete_transition
    (exp(F dt) to second order, F with psi_dot = -R_eb g_w and g_w_dot = -g_w / tau) to 1e-15, is
    within (|F| dt)^3/6 of scipy's expm(F dt), and its g_w entry is exp(-dt/tau)."""
    tun = _gm_tuning()
    lay = build_layout(tun, 1)
    x = np.array([6.6e6, 1e5, 2e5])
    R = expm(np.cross(np.eye(3), [0.3, -0.2, 0.5]))
    f, w, dt = np.array([0.3, -0.1, 9.0]), np.radians([5.0, -3.0, 2.0]), 0.05
    F = error_dynamics(lay, x, R, f, w, 20.0, 0.0, GM_TAU_S)
    ig, ip = lay["gyro_gm"], lay["psi"]
    np.testing.assert_array_equal(F[ip, ig], -R)
    Phi = discrete_transition(lay, F, dt)
    tr = TransitionBuilder(lay, 20.0, 0.0, GM_TAU_S)(x, R, f, w, dt)
    np.testing.assert_allclose(tr.full(), Phi, atol=1e-15)
    np.testing.assert_allclose(Phi, expm(F * dt), atol=np.linalg.norm(F * dt, 2) ** 3 / 6 * 2)
    np.testing.assert_allclose(np.diag(Phi[ig, ig]), math.exp(-dt / GM_TAU_S), rtol=1e-15)


def test_propagation_and_feedback():
    """One 0.1 s block: P equals Phi P0 Phi^T + q dt + (1 - phi^2) sigma^2 on g_w with Phi from the
    block's recorded transition (closed form of the first-order Gauss-Markov process); the
    estimate decays by phi and the INS subtracts b_w + g_w (its calibration row)."""
    tun = _gm_tuning().with_(vector_gm_mode="off")
    lay = build_layout(tun, 1)
    n = lay.n
    B = np.random.default_rng(1).normal(size=(n, n)) * 1e-3
    P0 = B @ B.T + lay.initial_covariance()
    st = FilterState(lay, tun, [6.6e6, 0, 0], [0.0, 7.5e3, 0.0], [0.0, 0.0, 0.0, 1.0], P0.copy(), np.eye(3)[None],
                     np.zeros(1))
    st.gw_hat[:] = [1e-5, -2e-5, 3e-5]
    st.cal_arr[1] = [4e-6, 0.0, -4e-6]
    fw = np.zeros((2, 2, 3))
    fw[:, 1, 2] = 0.01
    A, d = np.empty((9, n)), np.empty(n)
    st.propagate(np.array([0.0, 0.1]), fw, np.empty((2, 10)), 0, 1, True, A, d)
    ig = lay["gyro_gm"]
    phi = math.exp(-0.1 / GM_TAU_S)
    np.testing.assert_allclose(d[ig], phi, rtol=1e-15)
    Phi = np.diag(d)
    Phi[:9] = A
    P_exp = Phi @ P0 @ Phi.T + np.diag(st.model[3:] * 0.1)
    P_exp[ig, ig] += (1 - phi ** 2) * (GM_SIGMA_DEG_H * DEG_H) ** 2 * np.eye(3)
    np.testing.assert_allclose(st.P, P_exp, rtol=1e-12, atol=1e-12 * np.abs(P_exp).max())
    np.testing.assert_allclose(st.gw_hat, phi * np.array([1e-5, -2e-5, 3e-5]), rtol=1e-15)
    np.testing.assert_allclose(st.cal_m[1, 3], st.cal_arr[1] + st.gw_hat, rtol=1e-15)


def test_simulated_drift_statistics():
    """The simulator's drift (20000 samples at 10 Hz, tau 100 s) against the process it draws:
    stationary 1-sigma (200 correlation times: the sample variance has ~10 % 1-sigma, so 0.3 is 3
    sigma), the least-squares lag-1 s coefficient exp(-1/100) (its 1-sigma sqrt((1 - phi^2) / 2000)
    = 0.003: 0.01 is 3 sigma) and the 1 s innovation's 1-sigma sqrt(1 - phi^2) (2000 independent
    values: 1.6 % 1-sigma, 5 % tolerance)."""
    from scenarios.sim.imu import gauss_markov_drift
    g = gauss_markov_drift(20000, 0.1, 1.0, GM_TAU_S, np.random.default_rng(4))
    assert np.std(g, axis=0) == pytest.approx([1.0] * 3, abs=0.3)
    phi = math.exp(-1.0 / GM_TAU_S)
    phi_hat = np.sum(g[10:] * g[:-10], axis=0) / np.sum(g[:-10] ** 2, axis=0)
    np.testing.assert_allclose(phi_hat, phi, atol=0.01)
    np.testing.assert_allclose(np.std(g[10:] - phi * g[:-10], axis=0), math.sqrt(1 - phi ** 2), rtol=0.05)
