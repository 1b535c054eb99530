"""Observation equations (nav/measurements.py), Gauss-Markov model (nav/gauss_markov.py) and the
error-state transition (nav/error_state.py) against finite differences and closed forms."""
import math

import numpy as np
import pytest
from scipy.linalg import expm, solve_discrete_lyapunov
from scipy.spatial.transform import Rotation as Rot

from nav import earth
from nav.error_state import TransitionBuilder, build_layout, discrete_transition, error_dynamics
from nav.gauss_markov import gm_input_noise, gm_process_noise, gm_propagate, gm_transition
from nav.measurements import (correct_mounting, gps_position, gps_velocity, predict_vector,
                              tangent_basis, target_direction_e, vector_covariance_problem,
                              vector_jacobians)
from nav.rotation import rotvec_to_matrix
from nav.tuning import Tuning, tuning_from_toml

rng = np.random.default_rng(0)
X = earth.geodetic_to_ecef(math.radians(68.0), math.radians(21.0), 200e3)
SUN = np.array([1.2e11, -0.8e11, 0.3e11])
R_EB = Rot.from_euler("zyx", [20, 60, -10], degrees=True).as_matrix()
R_BC = Rot.from_euler("zyx", [90, -20, 5], degrees=True).as_matrix()


@pytest.mark.parametrize("target", ["hor", "sun"])
def test_vector_jacobians_match_finite_differences(target):
    """H_psi, H_psi_c and H_dx of 003 eqs. (47)-(48) (conventions in the module docstring) equal
    central differences of eq. (39) under the true-attitude perturbations; step 1e-6 rad gives a
    truncation error ~1e-12, so 1e-9 is a safe bound."""
    tpos = SUN if target == "sun" else None

    def e(x, R_eb, R_bc):
        return predict_vector(target_direction_e(target, x, tpos), R_eb, R_bc)

    u = target_direction_e(target, X, tpos)
    H_dx, H_psi, H_psic = vector_jacobians(target, X, u, R_EB, R_BC, tpos)
    h = 1e-6
    for i in range(3):
        d = np.zeros(3); d[i] = h
        num = (e(X, rotvec_to_matrix(d) @ R_EB, R_BC) - e(X, rotvec_to_matrix(-d) @ R_EB, R_BC)) / (2 * h)
        np.testing.assert_allclose(H_psi[:, i], num, atol=1e-9)
        num = (e(X, R_EB, rotvec_to_matrix(d) @ R_BC) - e(X, R_EB, rotvec_to_matrix(-d) @ R_BC)) / (2 * h)
        np.testing.assert_allclose(H_psic[:, i], num, atol=1e-9)
        dx = np.zeros(3); dx[i] = 10.0
        num = (e(X + dx, R_EB, R_BC) - e(X - dx, R_EB, R_BC)) / 20.0
        np.testing.assert_allclose(H_dx[:, i], num, atol=1e-12)


def test_psic_jacobian_is_003_form_in_camera_frame():
    """003 eq. (48) gives [e_c x] for psi_c expressed in c; ours (psi_c in b) is [e_c x] R_bc^T."""
    u = target_direction_e("hor", X)
    _, _, H_psic = vector_jacobians("hor", X, u, R_EB, R_BC)
    e_c = predict_vector(u, R_EB, R_BC)
    sk = np.array([[0, -e_c[2], e_c[1]], [e_c[2], 0, -e_c[0]], [-e_c[1], e_c[0], 0]])
    np.testing.assert_allclose(H_psic @ R_BC, sk, atol=1e-15)


def test_gps_jacobians_and_lever_arm():
    lever = np.array([0.5, -0.2, 1.3])
    w = np.radians([0.5, -0.3, 0.8])
    x_pred, Hx, Hpsi = gps_position(X, R_EB, lever)
    np.testing.assert_allclose(x_pred, X + R_EB @ lever)
    h = 1e-6
    for i in range(3):
        d = np.zeros(3); d[i] = h
        num = (gps_position(np.zeros(3), rotvec_to_matrix(d) @ R_EB, lever)[0]
               - gps_position(np.zeros(3), rotvec_to_matrix(-d) @ R_EB, lever)[0]) / (2 * h)
        np.testing.assert_allclose(Hpsi[:, i], num, atol=1e-8)
        num = (gps_velocity(np.zeros(3), rotvec_to_matrix(d) @ R_EB, w, lever)[0]
               - gps_velocity(np.zeros(3), rotvec_to_matrix(-d) @ R_EB, w, lever)[0]) / (2 * h)
        np.testing.assert_allclose(gps_velocity(np.zeros(3), R_EB, w, lever)[2][:, i], num, atol=1e-10)


def test_mounting_correction_eq50():
    """eq. (50) to first order, exact rotation: orthonormal and equal to (I + [psi x]) R + O(psi^2)."""
    psi = np.array([1e-3, -2e-3, 0.5e-3])
    R = correct_mounting(R_BC, psi)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    sk = np.array([[0, -psi[2], psi[1]], [psi[2], 0, -psi[0]], [-psi[1], psi[0], 0]])
    np.testing.assert_allclose(R, (np.eye(3) + sk) @ R_BC, atol=1e-5)


def test_vector_covariance_checks():
    e = np.array([0.0, 0.0, 1.0])
    good = 1e-6 * (np.eye(3) - np.outer(e, e))
    assert vector_covariance_problem(good, e) is None
    assert "non-finite" in vector_covariance_problem(good * np.nan, e)
    assert "semi-definite" in vector_covariance_problem(-good, e)
    assert "across" in vector_covariance_problem(1e-6 * np.outer([1, 0, 0], [1, 0, 0]), e)
    bad = good.copy(); bad[0, 1] = 1e-7
    assert "symmetric" in vector_covariance_problem(bad, e)
    T = tangent_basis(np.array([0.3, -0.4, 0.866]))
    np.testing.assert_allclose(T.T @ T, np.eye(2), atol=1e-15)
    np.testing.assert_allclose(T.T @ np.array([0.3, -0.4, 0.866]) / np.linalg.norm([0.3, -0.4, 0.866]), 0, atol=1e-15)


def test_gauss_markov_eqs_41_45():
    """Q of eq. (45) solves the discrete Lyapunov equation (44) (checked with scipy), and
    propagation (43) keeps the stationary covariance."""
    A = rng.normal(size=(3, 3))
    P_c = A @ A.T * 1e-6
    dt, tc = 0.5, 20.0
    Q = gm_input_noise(P_c, dt, tc)
    Phi = gm_transition(dt, tc, exact=False) * np.eye(3)
    Gam = dt / tc * np.eye(3)
    np.testing.assert_allclose(solve_discrete_lyapunov(Phi, Gam @ Q @ Gam.T), P_c, rtol=1e-10)
    np.testing.assert_allclose(gm_propagate(P_c, P_c, dt, tc), P_c, rtol=1e-14)
    np.testing.assert_allclose(gm_process_noise(P_c, dt, tc, exact=False), Gam @ Q @ Gam.T, rtol=1e-12)
    assert gm_transition(dt, tc) == pytest.approx(math.exp(-dt / tc))


def _transition_reference(layout, tc, x_e, R_eb, f_b, w_b, dt):
    """Plain numpy version of :class:`nav.error_state.TransitionBuilder` (its reference)."""
    from nav.earth import OMEGA_IE_E
    from nav.error_state import IMU_GROUPS, BlockTransition, gravity_gradient
    from nav.rotation import skew
    n = layout.n
    W = skew(OMEGA_IE_E)
    Fn = np.zeros((9, n))
    Fn[0:3, 3:6] = np.eye(3)
    Fn[3:6, 0:3] = gravity_gradient(x_e)
    Fn[3:6, 3:6] = -2.0 * W
    Fn[3:6, 6:9] = -skew(R_eb @ f_b)
    Fn[6:9, 6:9] = -W
    for name in IMU_GROUPS:
        if not layout.has(name):
            continue
        sl = layout[name]
        if name == "accel_bias":
            Fn[3:6, sl] = -R_eb
        elif name == "gyro_bias":
            Fn[6:9, sl] = -R_eb
        elif name == "accel_scale":
            Fn[3:6, sl] = -R_eb * f_b[None, :]
        elif name == "gyro_scale":
            Fn[6:9, sl] = -R_eb * w_b[None, :]
        elif name == "accel_misalignment":
            Fn[3:6, sl] = -R_eb @ skew(f_b)
        else:
            Fn[6:9, sl] = -R_eb @ skew(w_b)
    Fd = Fn * dt
    A = Fd + 0.5 * (Fd[:, :9] @ Fd)
    A[:, :9] += np.eye(9)
    d = np.ones(n)
    for g in layout.groups:
        if g.name.startswith("zeta_"):
            d[g.slice] = np.exp(-dt / tc)
    return BlockTransition(A, d)


def test_transition_fast_path_matches_expm():
    """TransitionBuilder (the filter's structured path) equals discrete_transition and is within
    (|F| dt)^3/6 of scipy's expm(F dt) for a 0.05 s block."""
    tun = Tuning()  # every IMU group on (table 3), Gauss-Markov states on
    lay = build_layout(tun, 2)
    f = np.array([0.3, -0.1, 9.0])
    w = np.radians([5.0, -3.0, 2.0])
    F = error_dynamics(lay, X, R_EB, f, w, 20.0)
    dt = 0.05
    Phi = discrete_transition(lay, F, dt)
    tb = TransitionBuilder(lay, 20.0)
    tr = tb(X, R_EB, f, w, dt)
    np.testing.assert_allclose(tr.full(), Phi, atol=1e-15)
    np.testing.assert_allclose(_transition_reference(lay, 20.0, X, R_EB, f, w, dt).full(), Phi, atol=1e-15)
    np.testing.assert_allclose(Phi, expm(F * dt), atol=np.linalg.norm(F * dt, 2) ** 3 / 6 * 2)
    P = rng.normal(size=(lay.n, lay.n)); P = P @ P.T
    np.testing.assert_allclose(tr.apply(P), Phi @ P @ Phi.T, rtol=1e-12, atol=1e-12)


def test_layout_and_tuning_parse():
    lay = build_layout(Tuning(), 2)
    # 9 nav + 6 IMU groups * 3 + 2 cameras * 3 + 2 cameras * 2 targets * 3
    assert lay.n == 9 + 18 + 6 + 12
    est = lay.estimated_mask
    assert est[lay["accel_bias"]].all() and not est[lay["gyro_bias"]].any()
    assert est[lay["psi_c_1"]].all() and not est[lay["zeta_sun_0"]].any()
    t = tuning_from_toml('[states.accel_scale]\nmode = "off"\n[vectors]\ntargets = ["hor"]\n')
    lay = build_layout(t, 1)
    assert not lay.has("accel_scale") and lay.has("zeta_hor_0") and not lay.has("zeta_sun_0")
    with pytest.raises(ValueError, match=r"\[states.gyro_bias\] mode"):
        tuning_from_toml('[states.gyro_bias]\nmode = "X"\n')
    with pytest.raises(ValueError, match="unknown sections"):
        tuning_from_toml('[foo]\na = 1\n')


def test_default_tuning_file_is_table3():
    from scenarios.config.tuning import load_tuning
    t = load_tuning()
    assert t == Tuning()
    assert t.accel_bias.sigma == pytest.approx(2e-3 * 9.80665)
    assert t.gyro_white == pytest.approx(math.radians(math.hypot(0.05, 2.5)) / 60)
    assert t.camera_misalignment.mode == "E" and t.gyro_bias.mode == "C"


_TABLE3_IN_FULL = """
[imu]
accel_white_noise_mg_rthz = 0.05
accel_white_noise_extra_mg_rthz = 2.5
gyro_white_noise_deg_rth = 0.05
gyro_white_noise_extra_deg_rth = 2.5
gyro_range_deg_s = 1000.0
accel_range_g = 50.0
max_gap_s = 0.5
[states.accel_bias]
mode = "E"
sigma_mg = 2.0
[states.accel_scale]
mode = "C"
sigma_ppm = 300.0
[states.accel_misalignment]
mode = "C"
sigma_mrad = 2.0
[states.gyro_bias]
mode = "C"
sigma_deg_h = 6.0
[states.gyro_scale]
mode = "C"
sigma_ppm = 2000.0
[states.gyro_misalignment]
mode = "C"
sigma_mrad = 2.0
[states.camera_misalignment]
mode = "E"
sigma_deg = 1.0
[states.camera_clock_offset]
mode = "off"
sigma_ms = 50.0
[vectors]
targets = ["hor", "sun"]
white_noise = 0.005
gm_mode = "C"
correlation_time_s = 20.0
gm_default_sigma_deg = 0.1
[initial]
attitude_sigma_deg = 2.0
position_sigma_m = 10.0
velocity_sigma_m_s = 0.1
[filter]
max_cov_interval_s = 0.1
gate_probability = 0.99999
"""


def test_tuning_files_hold_overrides():
    """A key left out keeps the dataclass default; a file listing every table 3 value gives the
    defaults; an unknown key of any table is an error naming it."""
    assert tuning_from_toml("") == Tuning()
    assert tuning_from_toml(_TABLE3_IN_FULL) == Tuning()
    t = tuning_from_toml("[filter]\nmax_cov_interval_s = 0.01\n[imu]\naccel_white_noise_extra_mg_rthz = 1.0\n")
    assert t.max_cov_interval_s == 0.01 and t.gyro_white == Tuning().gyro_white
    assert t.accel_white == pytest.approx(math.hypot(0.05, 1.0) * 1e-3 * 9.80665, rel=1e-15)
    assert t.with_(max_cov_interval_s=0.1, accel_white=Tuning().accel_white) == Tuning()
    for table in ("imu", "vectors", "initial", "filter"):
        with pytest.raises(ValueError, match=rf"\[{table}\]: unknown key 'foo'"):
            tuning_from_toml(f"[{table}]\nfoo = 1\n")


def test_propagate_covariance_equals_block_transition():
    """The in-place propagation kernel (issue 7) equals BlockTransition.apply + q dt + the
    Gauss-Markov blocks, symmetrised (45 states; round-off: 1e-14 of |P|)."""
    from nav.error_state import BlockTransition, propagate_covariance
    rng = np.random.default_rng(4)
    n = 45
    B = rng.normal(size=(n, n)); P = B @ B.T
    A = np.zeros((9, n)); A[:, :27] = 0.01 * rng.normal(size=(9, 27)); A[:, :9] += np.eye(9)
    d = np.ones(n); d[33:] = 0.98
    q = np.zeros(n); q[3:9] = 1e-3
    zs = np.array([33, 36, 39, 42]); Pc = np.stack([np.diag(rng.uniform(1, 2, 3)) * 1e-4 for _ in range(4)])
    ref = BlockTransition(A, d).apply(P)
    ref[np.arange(n), np.arange(n)] += q
    for z in range(4):
        ref[zs[z]:zs[z] + 3, zs[z]:zs[z] + 3] += 0.04 * Pc[z]
    ref = 0.5 * (ref + ref.T)
    P2 = P.copy()
    propagate_covariance(P2, A, d, q, zs, Pc, 0.04, np.empty((n, n)))
    np.testing.assert_allclose(P2, ref, rtol=0, atol=1e-14 * np.abs(ref).max())


def test_gps_rows_kernel_equals_measurement_functions():
    """The navigator's GPS kernel reproduces gps_position / gps_velocity (lever arm 1 m, rate
    0.1 rad/s): innovations and Jacobian blocks to 1e-12."""
    from nav.measurements import gps_position, gps_velocity
    from nav.updates import gps_rows_kernel
    from nav.rotation import rotvec_to_matrix
    rng = np.random.default_rng(5)
    R = rotvec_to_matrix(rng.normal(size=3))
    x, v, w, lever = rng.normal(size=3) * 1e6, rng.normal(size=3) * 1e3, rng.normal(size=3) * 0.1, rng.normal(size=3)
    xg, vg = x + rng.normal(size=3), v + rng.normal(size=3)
    n = 15
    H = np.zeros((6, n)); s = np.empty(6)
    gps_rows_kernel(x, v, R, w, lever, xg, vg, True, np.array([0, 3, 6]), H, s)
    pp, Hx, Hpsi = gps_position(x, R, lever)
    pv, Hv, Hpsi_v = gps_velocity(v, R, w, lever)
    np.testing.assert_allclose(s, np.concatenate([xg - pp, vg - pv]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(H[:3, :3], Hx); np.testing.assert_allclose(H[:3, 6:9], Hpsi, atol=1e-12)
    np.testing.assert_allclose(H[3:, 3:6], Hv); np.testing.assert_allclose(H[3:, 6:9], Hpsi_v, atol=1e-12)
    assert np.all(H[:3, 3:6] == 0) and np.all(H[3:, :3] == 0) and np.all(H[:, 9:] == 0)


def test_vector_covariance_problems_equal_scalar():
    """The vectorised check gives the scalar check's answer for good and for each kind of bad
    covariance."""
    from nav.measurements import vector_covariance_problem, vector_covariance_problems
    rng = np.random.default_rng(6)
    e = rng.normal(size=(7, 3)); e /= np.linalg.norm(e, axis=1, keepdims=True)
    P = np.stack([1e-6 * (np.eye(3) - np.outer(u, u)) for u in e])
    P[1, 0, 1] += 1e-9                       # non-symmetric
    P[2, 0, 0] = np.nan                      # non-finite
    P[3] = -P[3]                             # negative
    P[4] = 1e-6 * np.outer(e[4], e[4])       # zero across the vector
    P[5] = P[5] + 1e-6 * np.eye(3)           # full rank: fine
    got = vector_covariance_problems(P, e)
    assert list(got) == [vector_covariance_problem(P[i], e[i]) for i in range(7)]
    assert got[0] is None and got[5] is None and got[6] is None and all(g is not None for g in got[1:5])
