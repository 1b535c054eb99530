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


def test_tuning_per_axis():
    """sigma_deg_h and correlation_time_s take three values (body x, y, z): the layout's P0 and
    Tuning.gyro_gm_sigmas hold them per axis, a scalar gives three equal ones; a list of another
    length is refused naming the key."""
    t = tuning_from_toml('[states.gyro_gm]\nmode = "C"\nsigma_deg_h = [1, 18, 20]\ncorrelation_time_s = [0.3, 1.3, 1.7]\n')
    np.testing.assert_allclose(t.gyro_gm_sigmas(), np.array([1, 18, 20]) * DEG_H, rtol=1e-15)
    assert t.gyro_gm_tau_s == (0.3, 1.3, 1.7)
    lay = build_layout(t, 1)
    np.testing.assert_allclose(np.diag(lay.initial_covariance())[lay["gyro_gm"]], (np.array([1, 18, 20]) * DEG_H) ** 2,
                               rtol=1e-15)
    np.testing.assert_array_equal(_gm_tuning().gyro_gm_sigmas(), np.full(3, GM_SIGMA_DEG_H * DEG_H))
    with pytest.raises(ValueError, match=r"gyro_gm\] sigma_deg_h: expected a number or three"):
        tuning_from_toml('[states.gyro_gm]\nmode = "C"\nsigma_deg_h = [1, 2]\n')
    with pytest.raises(ValueError, match=r"gyro_gm\] correlation_time_s"):
        tuning_from_toml('[states.gyro_gm]\nmode = "C"\ncorrelation_time_s = [1, 0, 2]\n')


def test_tuning_quantum():
    """[states.gyro_gm] quantum_dps: the rate step, from which the sigma (q / sqrt(12) per axis, in
    the layout's P0 too) and the correlation time follow; quantum_scale and quantum_window_s
    override c and the slope window. Beside sigma_deg_h or correlation_time_s, without
    quantum_dps, or zero: refused naming the key."""
    t = tuning_from_toml('[states.gyro_gm]\nmode = "C"\nquantum_dps = 0.03\nquantum_scale = 20\n')
    q = math.radians(0.03)
    assert t.gyro_gm_quantum == pytest.approx(q, rel=1e-15) and t.gyro_gm_quantum_scale == 20.0
    assert t.gyro_gm_quantum_window_s == Tuning().gyro_gm_quantum_window_s
    np.testing.assert_allclose(t.gyro_gm_sigmas(), q / math.sqrt(12.0), rtol=1e-15)
    lay = build_layout(t, 1)
    np.testing.assert_allclose(np.diag(lay.initial_covariance())[lay["gyro_gm"]], q * q / 12.0, rtol=1e-15)
    for text, key in (('quantum_dps = 0.03\nsigma_deg_h = 5', "sigma_deg_h"),
                      ('quantum_dps = 0.03\ncorrelation_time_s = 5', "correlation_time_s"),
                      ('quantum_scale = 20', "quantum_scale"), ('quantum_dps = 0', "quantum_dps"),
                      ('quantum_dps = 0.03\nquantum_window_s = -1', "quantum_window_s")):
        with pytest.raises(ValueError, match=rf"\[states.gyro_gm\] {key}"):
            tuning_from_toml(f'[states.gyro_gm]\nmode = "C"\n{text}\n')


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


def test_transition_per_axis():
    """Three correlation times: the compiled transition equals the reference discrete_transition
    (g_w_dot = -diag(1/tau) g_w) to 1e-15 and its g_w entries are exp(-dt/tau_i)."""
    taus = (0.3, 1.3, 100.0)
    tun = _gm_tuning().with_(gyro_gm_tau_s=taus)
    lay = build_layout(tun, 1)
    x = np.array([6.6e6, 1e5, 2e5])
    R = expm(np.cross(np.eye(3), [0.3, -0.2, 0.5]))
    f, w, dt = np.array([0.3, -0.1, 9.0]), np.radians([5.0, -3.0, 2.0]), 0.05
    F = error_dynamics(lay, x, R, f, w, 20.0, 0.0, taus)
    Phi = discrete_transition(lay, F, dt)
    tr = TransitionBuilder(lay, 20.0, 0.0, taus)(x, R, f, w, dt)
    np.testing.assert_allclose(tr.full(), Phi, atol=1e-15)
    ig = lay["gyro_gm"]
    np.testing.assert_allclose(np.diag(Phi[ig, ig]), np.exp(-dt / np.array(taus)), rtol=1e-15)


@pytest.mark.parametrize("form", ["common", "per_axis", "quantum"])
def test_propagation_and_feedback(form):
    """One 0.1 s block: P equals Phi P0 Phi^T + q dt + (1 - phi^2) sigma^2 on g_w with Phi from the
    block's recorded transition (closed form of the first-order Gauss-Markov process); the
    estimate decays by phi and the INS subtracts b_w + g_w (its calibration row). In the
    rate-quantum form sigma is q / sqrt(12) and 1 / tau the block's per-sample rates."""
    sig = np.array([1.0, 18.0, 20.0]) * DEG_H if form == "per_axis" else np.full(3, GM_SIGMA_DEG_H * DEG_H)
    tau = np.array([0.3, 1.3, GM_TAU_S]) if form == "per_axis" else np.full(3, GM_TAU_S)
    tun = _gm_tuning().with_(vector_gm_mode="off")
    if form == "per_axis":
        tun = tun.with_(gyro_gm=StateGroupTuning("E", tuple(sig)), gyro_gm_tau_s=tuple(tau))
    if form == "quantum":
        q = math.radians(0.03)
        tun = tun.with_(gyro_gm_quantum=q)
        sig, tau = np.full(3, q / math.sqrt(12.0)), np.array([0.4, 2.5, 60.0])
    lay = build_layout(tun, 1)
    n = lay.n
    B = np.random.default_rng(1).normal(size=(n, n)) * 1e-3
    P0 = B @ B.T + lay.initial_covariance()
    st = FilterState(lay, tun, [6.6e6, 0, 0], [0.0, 7.5e3, 0.0], [0.0, 0.0, 0.0, 1.0], P0.copy(), np.eye(3)[None],
                     np.zeros(1))
    if form == "quantum":
        st.follow_rates(np.vstack([1.0 / tau, [9.0, 9.0, 9.0]]))   # the block reads sample 0's rates
    st.gw_hat[:] = [1e-5, -2e-5, 3e-5]
    st.cal_arr[1] = [4e-6, 0.0, -4e-6]
    fw = np.zeros((2, 2, 3))
    fw[:, 1, 2] = 0.01
    A, d = np.empty((9, n)), np.empty(n)
    st.propagate(np.array([0.0, 0.1]), fw, np.empty((2, 10)), 0, 1, True, A, d)
    ig = lay["gyro_gm"]
    phi = np.exp(-0.1 / tau)
    np.testing.assert_allclose(d[ig], phi, rtol=1e-15)
    # the attitude's column of g_w: -R_eb dt (1 - dt / (2 tau)), the second-order term of its decay;
    # R_eb turns by 1e-3 rad over the block (cos: 5e-7 on the diagonal), dt / (2 tau) >= 8e-4
    np.testing.assert_allclose(np.diag(A[6:9, ig]), -0.1 + 0.1 ** 2 / (2 * tau), rtol=1e-6)
    Phi = np.diag(d)
    Phi[:9] = A
    P_exp = Phi @ P0 @ Phi.T + np.diag(st.model[3:] * 0.1)
    P_exp[ig, ig] += np.diag((1 - phi ** 2) * sig ** 2)
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


def _nav_grade_tuning() -> Tuning:
    """Table 3's groups with the atek-nav-grade IMU's figures (scenarios/library/atek-nav-grade.toml)
    and a 0.01 deg initial attitude sigma (the runs start on the truth), gyro range 2000 deg/s."""
    g = 9.80665
    return Tuning().with_(gyro_bias=StateGroupTuning("C", 0.01 * DEG_H), gyro_scale=StateGroupTuning("C", 5e-6),
                          gyro_misalignment=StateGroupTuning("C", 2e-5),
                          accel_bias=StateGroupTuning("E", 0.025e-3 * g), accel_scale=StateGroupTuning("C", 50e-6),
                          accel_misalignment=StateGroupTuning("C", 2e-5), init_att_sigma=math.radians(0.01),
                          accel_white=0.02e-3 * g, gyro_white=math.radians(0.01) / 60.0,
                          gyro_range=math.radians(2000.0))


def gm_coast(seeds=(1, 2, 3), t_end: float = 360.0) -> dict:
    """GPS/INS coast T+60..t_end of atek-nav-grade (100 Hz IMU, no cameras) whose gyros carry a
    Gauss-Markov drift of 5 deg/h, tau 100 s, filtered with the state off and on (E and C). In the
    coast the specific force is ~0, so GPS does not observe the attitude: its error is the integral
    of the gyro errors, and only a filter that models the drift can bound it. Per mode, per seed:
    the fraction of covariance epochs with every axis of the attitude error inside 3 sigma, and
    the mean attitude NEES (3 for a consistent filter)."""
    from nav.navigator import run
    from scenarios.sim import simulate as S
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.truth import simulate_truth
    from tests.test_navigator import attitude_errors, flight_inputs, truth_init
    sc = copy.deepcopy(load_scenario("atek-nav-grade"))
    sc.imu.rate_hz, sc.imu.gyro_gm_deg_h, sc.imu.gyro_gm_tau_s = 100.0, GM_SIGMA_DEG_H, GM_TAU_S
    sc.cameras = []
    tr = simulate_truth(sc, t_end)
    base = _nav_grade_tuning()
    tunings = {"off": base, "E": base.with_(gyro_gm=_gm_tuning("E").gyro_gm, gyro_gm_tau_s=GM_TAU_S),
               "C": base.with_(gyro_gm=_gm_tuning("C").gyro_gm, gyro_gm_tau_s=GM_TAU_S)}
    out = {m: {"inside3": [], "nees": []} for m in tunings}
    for seed in seeds:
        imu, errs = S.simulate_imu(tr, sc.imu, S.rng_for(seed, S.STREAM_IMU))
        gps = S.simulate_gps(tr, sc.gps, S.rng_for(seed, S.STREAM_GPS))
        fi = flight_inputs(S.FlightData(sc, seed, t_end, tr, imu, errs, gps, []), 60.0, seed=seed)
        ti = fi.truth_idx[fi.start_idx:]
        for mode, tun in tunings.items():
            res = run(fi.imu, truth_init(fi), tun, gps=fi.gps, vectors=None, R_bc=fi.R_bc_nominal, unaided=False,
                      store_for_smoother=False)
            psi = attitude_errors(res.q_eb[res.cov_idx], tr.q_eb[ti[res.cov_idx]])
            var = res.P_diag[:, res.layout["psi"]]
            out[mode]["inside3"].append(float(np.mean(np.all(psi ** 2 < 9 * var, axis=1))))
            out[mode]["nees"].append(float(np.mean(np.sum(psi ** 2 / var, axis=1))))
    return out


def test_coast_with_gyro_drift_is_consistent_only_with_the_state():
    """gm_coast: with g_w on (estimated or considered) the attitude error is inside 3 sigma on
    >= 95 % of the epochs of every run and the mean NEES is below 2 x 3 (measured 1.4..2.4: the
    integral of the drift is a sum over ~3 correlation times, so a run's NEES is far from its
    expectation 3, but never near the state-off figures); with it off, the filter's 0.03 deg bound
    holds on < 50 % of the epochs (measured 8..13 %) and the NEES is > 100 (measured 490..760)."""
    out = gm_coast()
    print(out)
    for mode in ("E", "C"):
        assert min(out[mode]["inside3"]) >= 0.95, (mode, out[mode])
        assert max(out[mode]["nees"]) < 6.0, (mode, out[mode])
    assert max(out["off"]["inside3"]) < 0.5 and min(out["off"]["nees"]) > 100.0, out["off"]
