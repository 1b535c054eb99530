"""The gyro triad's non-orthogonality n_w (nav/imu_errors.py, group ``gyro_nonorthogonality`` in
nav/error_state.py and nav/filter_state.py): the split of a six-term axis misalignment into the
three-state rotation and the three symmetric terms, their transition and their feedback."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from nav.error_state import TransitionBuilder, build_layout, discrete_transition, error_dynamics
from nav.filter_state import FilterState, calibration_into, feedback_kernel
from nav.imu_errors import (ImuCalibration, apply_calibration, corrupt, nonorthogonality_jacobian,
                            split_misalignment, symmetric_offdiagonal)
from nav.tuning import StateGroupTuning, Tuning, tuning_from_toml


def _offdiag(rng, sigma, size=()):
    N = rng.normal(0.0, sigma, size + (3, 3))
    N[..., [0, 1, 2], [0, 1, 2]] = 0.0
    return N


def test_six_terms_are_rotation_plus_nonorthogonality():
    """Any off-diagonal N (the simulator's six independent terms, scenarios/sim/imu.py) is the
    rotation m plus S(n): ``N w = [w x] m + N(w) n`` to 1e-18 (an identity), and six independent
    terms of 1-sigma sigma give m and n 1-sigma sigma / sqrt(2) each: 100 000 draws, whose sample
    sigma has a 0.22 % 1-sigma, checked to 1 %."""
    rng = np.random.default_rng(3)
    N = _offdiag(rng, 2e-3)
    m, n = split_misalignment(N)
    w = rng.normal(0.0, 0.01, 3)
    np.testing.assert_allclose(N @ w, np.cross(w, m) + nonorthogonality_jacobian(w) @ n, atol=1e-18)
    np.testing.assert_allclose(symmetric_offdiagonal(n) @ w, nonorthogonality_jacobian(w) @ n, atol=1e-18)
    _, w_meas = corrupt(np.zeros((1, 3)), w[None], m_w=m, n_w=n)
    np.testing.assert_allclose(w_meas[0], w + N @ w, atol=1e-18)
    draws = _offdiag(rng, 2e-3, (100_000,))
    mn = np.array([np.concatenate(split_misalignment(d)) for d in draws[:20_000]])
    np.testing.assert_allclose(mn.std(axis=0), 2e-3 / math.sqrt(2), rtol=0.03)
    # the vectorised form of the same split over all draws
    m_all = 0.5 * np.stack([draws[:, 1, 2] - draws[:, 2, 1], draws[:, 2, 0] - draws[:, 0, 2],
                            draws[:, 0, 1] - draws[:, 1, 0]], 1)
    n_all = 0.5 * np.stack([draws[:, 1, 2] + draws[:, 2, 1], draws[:, 0, 2] + draws[:, 2, 0],
                            draws[:, 0, 1] + draws[:, 1, 0]], 1)
    np.testing.assert_allclose(m_all[:20_000], mn[:, :3], atol=1e-18)
    np.testing.assert_allclose(np.concatenate([m_all, n_all], 1).std(axis=0), 2e-3 / math.sqrt(2), rtol=0.01)


def test_calibration_inverts_the_model():
    """The calibration with the true (s, m, n) recovers the true rate from the corrupted one to
    second order in the errors ((2e-3)^2 * |w| ~ 4e-6 |w|): the affine inverse is exact for the
    first-order model, so the residual is the model's own second-order term."""
    rng = np.random.default_rng(5)
    w = rng.normal(0.0, 0.02, (50, 3))
    s, m, n = (rng.normal(0.0, 2e-3, 3) for _ in range(3))
    _, w_meas = corrupt(np.zeros_like(w), w, s_w=s, m_w=m, n_w=n)
    M = np.eye(3) + np.diag(s) - np.cross(np.eye(3), m) + symmetric_offdiagonal(n)
    np.testing.assert_allclose(w_meas, w @ M.T, atol=1e-18)
    cal = ImuCalibration(s_w=s, m_w=m, n_w=n)
    _, w_cal = apply_calibration(np.zeros_like(w), w_meas, cal)
    np.testing.assert_allclose(w_cal, w, atol=1e-15)
    assert np.abs(apply_calibration(np.zeros_like(w), w_meas, ImuCalibration())[1] - w).max() > 1e-5


def test_tuning_and_layout():
    """[states.gyro_nonorthogonality] with sigma_mrad; off by default (table 3 unchanged); in the
    layout right after the gyro misalignment."""
    assert Tuning().gyro_nonorthogonality.mode == "off"
    assert not build_layout(Tuning(), 2).has("gyro_nonorthogonality")
    t = tuning_from_toml('[states.gyro_nonorthogonality]\nmode = "C"\nsigma_mrad = 1.5\n')
    assert t.gyro_nonorthogonality == StateGroupTuning("C", 1.5e-3)
    lay = build_layout(t, 1)
    m = lay["gyro_misalignment"]
    assert lay["gyro_nonorthogonality"] == slice(m.stop, m.stop + 3)
    assert not lay.estimated_mask[lay["gyro_nonorthogonality"]].any()
    with pytest.raises(ValueError, match=r"gyro_nonorthogonality\] mode"):
        tuning_from_toml('[states.gyro_nonorthogonality]\nmode = "X"\n')


@pytest.mark.parametrize("mode", ["C", "E"])
def test_transition_matches_expm(mode):
    """With n_w in the layout (and the Gauss-Markov gyro error after it), the filter's compiled
    transition equals the reference discrete_transition to 1e-15 and is within (|F| dt)^3/6 of
    scipy's expm(F dt); the psi rows of n_w are -R_eb N(w)."""
    tun = Tuning().with_(gyro_nonorthogonality=StateGroupTuning(mode, 2e-3),
                         gyro_gm=StateGroupTuning("C", math.radians(5.0) / 3600.0), gyro_gm_tau_s=100.0)
    lay = build_layout(tun, 2)
    x = np.array([6.6e6, 1e5, 2e5])
    R = expm(np.cross(np.eye(3), [0.3, -0.2, 0.5]))
    f, w, dt = np.array([0.3, -0.1, 9.0]), np.radians([5.0, -3.0, 2.0]), 0.05
    F = error_dynamics(lay, x, R, f, w, 20.0, 0.0, 100.0)
    np.testing.assert_allclose(F[lay["psi"], lay["gyro_nonorthogonality"]], -R @ nonorthogonality_jacobian(w),
                               atol=1e-18)
    np.testing.assert_array_equal(F[lay["psi"], lay["gyro_gm"]], -R)
    Phi = discrete_transition(lay, F, dt)
    tr = TransitionBuilder(lay, 20.0, 0.0, 100.0)(x, R, f, w, dt)
    np.testing.assert_allclose(tr.full(), Phi, atol=1e-15)
    np.testing.assert_allclose(Phi, expm(F * dt), atol=np.linalg.norm(F * dt, 2) ** 3 / 6 * 2)


def test_estimated_nonorthogonality_feeds_the_calibration():
    """An estimated n_w is fed back into the calibration (ImuCalibration.n_w) and the INS's gyro
    matrix becomes (I + S(n_w))^-1; the camera mounting after it in ``fed`` is untouched."""
    tun = Tuning().with_(gyro_nonorthogonality=StateGroupTuning("E", 2e-3))
    lay = build_layout(tun, 1)
    st = FilterState(lay, tun, [6.6e6, 0, 0], [0.0, 7.5e3, 0.0], [0.0, 0.0, 0.0, 1.0], lay.initial_covariance(),
                     np.eye(3)[None], np.zeros(1))
    dx = np.zeros(lay.n)
    n = np.array([1e-3, -2e-3, 5e-4])
    dx[lay["gyro_nonorthogonality"]] = n
    assert feedback_kernel(dx, st.nav, st.fed, st.fb)
    assert st.affine_estimated
    calibration_into(st.fed, st.fb, st.cal_m, st.affine_estimated)
    np.testing.assert_allclose(st.calibration.n_w, n, atol=1e-18)
    np.testing.assert_allclose(st.cal_m[1, :3], np.linalg.inv(np.eye(3) + symmetric_offdiagonal(n)), atol=1e-15)
    np.testing.assert_array_equal(st.R_bc[0], np.eye(3))
