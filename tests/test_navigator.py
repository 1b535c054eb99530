"""Navigation run (nav/navigator.py) on synthetic coasts with known truth.

``synthetic_coast`` builds the truth with the INS on error-free data (the INS itself is checked
against scipy's DOP853 in tests/test_ins.py), then corrupts it with the 003 table 3 error model:
IMU biases / scale factors / misalignments plus white noise, GPS white noise, and camera vectors
with a camera misalignment, a first-order Gauss-Markov error (003 eqs. (41)-(45)) and white noise.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation as Rot

from nav import earth, ins
from nav.ephemeris import sun_position_e
from nav.imu_errors import corrupt
from nav.navigator import GpsData, ImuData, InitialState, VectorData, run
from nav.rotation import matrix_to_rotvec, quat_to_matrix, rotvec_to_matrix
from nav.timescales import parse_utc
from nav.tuning import StateGroupTuning, Tuning

NS = 1_000_000_000
ASCENT_ATT_BOUND, ASCENT_POS_BOUND = 1e-4, 2.0  # measured 8.6e-6 rad, 0.2 m (2026-11)
T0 = parse_utc("2019-06-13T02:22:00Z")


@dataclass
class Synthetic:
    imu: ImuData
    gps: GpsData
    vectors: VectorData
    init: InitialState
    R_bc_nominal: list
    truth_x: np.ndarray
    truth_v: np.ndarray
    truth_q: np.ndarray
    psi_c_true: np.ndarray


def camera_mountings():
    """Two cameras on opposite sides (+-y_b) looking 20 deg down towards -x_b (the tail)."""
    out = []
    for side in (1.0, -1.0):
        z_c = np.array([-np.sin(np.radians(20)), side * np.cos(np.radians(20)), 0.0])
        x_c = np.array([0.0, 0.0, side])
        out.append(np.stack([x_c, np.cross(z_c, x_c), z_c], axis=1))
    return out


def synthetic_coast(seed=0, *, duration=60.0, rate_hz=20.0, imu_errors=True, noise=True,
                    gps_rate=1.0, vec_rate=2.0, vec_sigma=math.radians(0.05), mis_deg=1.0,
                    tuning: Tuning | None = None, cameras=(0, 1), gm=True):
    rng = np.random.default_rng(seed)
    tun = tuning or Tuning()
    lat, lon = np.radians([67.89, 21.10])
    x0 = earth.geodetic_to_ecef(lat, lon, 60e3)
    v0 = earth.R_en(lat, lon) @ np.array([400.0, 100.0, -1700.0])
    # nose up, rotating slowly (RCS limit 0.9 deg/s)
    R_nb = Rot.from_euler("zyx", [0, 80, 30], degrees=True).as_matrix()
    q0 = Rot.from_matrix(earth.R_en(lat, lon) @ R_nb).as_quat()
    n = int(round(duration * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    w_true = np.radians(0.5) * np.stack([np.sin(0.05 * t), np.cos(0.03 * t), 0.5 * np.sin(0.02 * t + 1)], 1)
    f_true = np.tile([0.01, 0.0, 0.0], (n, 1)) + 0.005 * np.sin(0.1 * t)[:, None]
    X, V, Q = ins.propagate(x0, v0, q0, t, f_true, w_true)
    if imu_errors:
        g = lambda s: rng.normal(0, s, 3)
        f_m, w_m = corrupt(f_true, w_true, b_f=g(tun.accel_bias.sigma), b_w=g(tun.gyro_bias.sigma),
                           s_f=g(tun.accel_scale.sigma), m_f=g(tun.accel_misalignment.sigma),
                           s_w=g(tun.gyro_scale.sigma), m_w=g(tun.gyro_misalignment.sigma))
    else:
        f_m, w_m = f_true.copy(), w_true.copy()
    if noise:
        # 003 table 3 white noise without the bracketed tuning extra
        f_m = f_m + rng.normal(0, 0.05e-3 * 9.80665 * np.sqrt(rate_hz), f_m.shape)
        w_m = w_m + rng.normal(0, np.radians(0.05) / 60 * np.sqrt(rate_hz), w_m.shape)
    t_ns = T0 + np.round(t * NS).astype(np.int64)
    # GPS
    step = int(round(rate_hz / gps_rate))
    gi = np.arange(0, n, step)
    sx, sv = (3.0, 0.05) if noise else (1e-3, 1e-5)
    gps = GpsData(t_ns[gi], X[gi] + (rng.normal(0, sx, (gi.size, 3)) if noise else 0),
                  np.tile(np.eye(3) * sx ** 2, (gi.size, 1, 1)),
                  V[gi] + (rng.normal(0, sv, (gi.size, 3)) if noise else 0), np.tile(np.eye(3) * sv ** 2, (gi.size, 1, 1)))
    # vectors
    R_bc_nom = camera_mountings()
    psi_c = rng.normal(0, np.radians(mis_deg), (2, 3))
    R_bc_true = [rotvec_to_matrix(psi_c[c]) @ R_bc_nom[c] for c in range(2)]
    vstep = int(round(rate_hz / vec_rate))
    vi = np.arange(vstep, n, vstep)
    sun = sun_position_e(t_ns[vi])
    rows = []
    phi = np.exp(-1.0 / vec_rate / tun.correlation_time_s)
    zeta = {}
    for kk, i in enumerate(vi):
        R = quat_to_matrix(Q[i])
        for c in cameras:
            for target in ("hor", "sun"):
                u = -X[i] / np.linalg.norm(X[i]) if target == "hor" else (sun[kk] - X[i]) / np.linalg.norm(sun[kk] - X[i])
                e = R_bc_true[c].T @ R.T @ u
                P_c = vec_sigma ** 2 * (np.eye(3) - np.outer(e, e))
                if noise:
                    key = (c, target)
                    L = np.linalg.cholesky(P_c + 1e-18 * np.eye(3))
                    if gm:
                        zeta[key] = (phi * zeta[key] + np.sqrt(1 - phi ** 2) * L @ rng.normal(size=3)
                                     if key in zeta else L @ rng.normal(size=3))
                        err = zeta[key]
                    else:
                        err = L @ rng.normal(size=3)
                    e = e + err
                    e /= np.linalg.norm(e)
                rows.append((t_ns[i], c, target, e, P_c))
    vec = VectorData(np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                     np.array([r[2] for r in rows]), np.array([r[3] for r in rows]), np.array([r[4] for r in rows]))
    return Synthetic(ImuData(t_ns, f_m, w_m, "point"), gps, vec, InitialState(int(t_ns[0]), X[0], V[0], Q[0]),
                     R_bc_nom, X, V, Q, psi_c)


def attitude_errors(q_est, q_true):
    """psi (in e) from estimated to true attitude, per sample."""
    return matrix_to_rotvec(quat_to_matrix(q_true) @ np.swapaxes(quat_to_matrix(q_est), -1, -2))


def perturbed_init(syn, rng, tun):
    """Initial state drawn from the initial covariance (truth minus error)."""
    i = syn.init
    dpsi = rng.normal(0, tun.init_att_sigma, 3)
    q = Rot.from_matrix(rotvec_to_matrix(-dpsi) @ quat_to_matrix(i.q_eb)).as_quat()
    return InitialState(i.t_ns, i.x_e - rng.normal(0, tun.init_pos_sigma, 3),
                        i.v_e - rng.normal(0, tun.init_vel_sigma, 3), q)


def test_error_free_filter_holds_truth():
    """Error-free IMU, GPS and vectors (no noise, no misalignment): the closed-loop filter stays on
    the truth to < 1e-5 rad (issue acceptance) and < 0.1 m."""
    syn = synthetic_coast(1, duration=60, imu_errors=False, noise=False, mis_deg=0.0)
    res = run(syn.imu, syn.init, Tuning(), gps=syn.gps, vectors=syn.vectors, R_bc=syn.R_bc_nominal)
    att = np.linalg.norm(attitude_errors(res.q_eb, syn.truth_q), axis=1)
    assert att.max() < 1e-5
    assert np.max(np.linalg.norm(res.x_e - syn.truth_x, axis=1)) < 0.1
    assert res.rejected == {}
    assert all(i.accepted for i in res.innovations)


def test_filter_converges_and_is_consistent():
    """table 3 errors, 1 deg camera misalignment, perturbed start: the final attitude error lies
    within 3 sigma per axis and the 3-sigma bound has shrunk well below its 6 deg start."""
    tun = Tuning()
    syn = synthetic_coast(2, duration=120)
    init = perturbed_init(syn, np.random.default_rng(3), tun)
    res = run(syn.imu, init, tun, gps=syn.gps, vectors=syn.vectors, R_bc=syn.R_bc_nominal)
    psi = attitude_errors(res.q_eb, syn.truth_q)
    sig = np.sqrt(res.P_diag[:, res.layout["psi"]])
    assert np.all(np.abs(psi[res.cov_idx[-1]]) < 3 * sig[-1])
    assert 3 * np.degrees(sig[-1]).max() < 2.0  # from 6 deg; 003 reaches 1.1 deg after 130 s
    for c in range(2):
        err = syn.psi_c_true[c] - res.misalignment[-1, c]
        assert np.all(np.abs(err) < 3.5 * res.misalignment_sigma[-1, c])
    assert np.all(np.isfinite(res.P_diag))
    assert len(res.triad_t_ns) > 0


def test_bad_input_is_rejected_and_counted(caplog):
    """NaN and saturated IMU samples, a time gap, out-of-order measurements, a 1 km GPS jump, a
    vector with NaN and one with a non-positive-definite covariance: each counted with its
    reason; the state stays finite and P symmetric."""
    tun = Tuning()
    syn = synthetic_coast(4, duration=30)
    imu = syn.imu
    f, w, t = imu.f_b.copy(), imu.w_b.copy(), imu.t_ns.copy()
    f[100] = np.nan
    w[200, 1] = 2 * tun.gyro_range
    t = np.delete(t, np.arange(300, 320)); f = np.delete(f, np.arange(300, 320), 0); w = np.delete(w, np.arange(300, 320), 0)
    imu = ImuData(t, f, w, "point")
    gps = syn.gps
    gx = gps.x_e.copy(); gx[10] += [1000.0, 0, 0]
    gt = gps.t_ns.copy(); gt[20] = gt[18]   # out of order
    gps = GpsData(gt, gx, gps.P_x, gps.v_e, gps.P_v)
    vec = syn.vectors
    e = vec.e_c.copy(); Pc = vec.P_c.copy()
    e[5] = np.nan
    Pc[9] = -Pc[9]
    vec = VectorData(vec.t_ns, vec.camera, vec.target, e, Pc)
    with caplog.at_level(logging.WARNING, logger="nav.navigator"):
        res = run(imu, syn.init, tun, gps=gps, vectors=vec, R_bc=syn.R_bc_nominal)
    r = res.rejected
    assert r["imu_nonfinite"] == 1 and r["imu_saturated"] == 1 and r["imu_time_gap"] == 1
    assert r["gps_out_of_order"] == 1
    assert r["gps_pos_chi-square gate"] == 1
    assert r.get("hor_non-finite vector", 0) + r.get("sun_non-finite vector", 0) == 1
    assert sum(v for k, v in r.items() if "positive" in k) == 1
    assert "rejected" in caplog.text
    assert np.all(np.isfinite(res.x_e)) and np.all(np.isfinite(res.q_eb)) and np.all(np.isfinite(res.P_diag))
    for P in res.P_full:
        assert np.array_equal(P, P.T)
        assert np.linalg.eigvalsh(P)[0] > 0


def test_triad_initialisation_back_propagated():
    """TRIAD at t0 + 40 s from noisy vectors (0.05 deg, camera misaligned 0.05 deg), carried back
    40 s with the gyros of a table-3 IMU: the start attitude is well inside 003's 2 deg (1 sigma)."""
    from nav.initialise import triad_initialise
    syn = synthetic_coast(11, duration=60, mis_deg=0.05)
    ti = triad_initialise(syn.imu, syn.gps, syn.vectors, syn.R_bc_nominal, int(syn.imu.t_ns[0]),
                          not_before_ns=int(syn.imu.t_ns[0]) + 40 * NS)
    assert ti.t_triad_ns >= syn.imu.t_ns[0] + 40 * NS
    err = np.degrees(np.linalg.norm(attitude_errors(ti.initial.q_eb, syn.truth_q[0])))
    assert err < 0.5
    assert np.linalg.norm(ti.initial.x_e - syn.truth_x[0]) < 20.0
    # the run starts from it
    res = run(syn.imu, ti.initial, Tuning(), gps=syn.gps, vectors=syn.vectors, R_bc=syn.R_bc_nominal)
    assert np.all(np.isfinite(res.q_eb))


# ------------------------------------------------------------------------------------------------
# scenarios.sim.simulate flights
# ------------------------------------------------------------------------------------------------

@dataclass
class FlightInputs:
    imu: ImuData
    gps: GpsData
    vectors: VectorData
    R_bc_nominal: list
    psi_c_true: np.ndarray
    truth_idx: np.ndarray      #: truth index of every IMU sample
    truth: object
    start_idx: int             #: IMU index of the start time


def flight_inputs(fl, t_start_s, *, ideal_imu=False, vec_sigma=math.radians(0.05), seed=0, gm=True,
                  tc=20.0, noise=True, white=0.0):
    """Navigator inputs from a ``scenarios.sim.simulate.FlightData``. The vectors are the simulator's
    true camera-frame directions (where the horizon / the Sun is in view) plus the stand-in vision
    error the issue allows: isotropic ``vec_sigma`` per vector across the line of sight, as a
    Gauss-Markov process with T_c (003 eqs. (41)-(45)) (``gm=False``: white) plus optional white
    noise ``white``; ``P_c`` is the GM covariance."""
    from scenarios.sim import imu as imu_model
    tr = fl.truth
    imu = imu_model.ideal_imu(tr, fl.scenario.imu.rate_hz, fl.imu.output, fl.scenario.imu.sample) if ideal_imu else fl.imu
    g, a = imu.gyro, imu.accel
    if imu.output == "increment":
        g, a = g / imu.dt, a / imu.dt
    sample = "average" if (imu.output == "increment" or fl.scenario.imu.sample == "average") else "point"
    t_ns = fl.to_ns(imu.t)
    idx = np.round(imu.t / tr.dt).astype(int)
    start = int(np.searchsorted(imu.t, t_start_s - 1e-9))
    gp = fl.gps
    keep = gp.t >= imu.t[start] - 1e-9
    gps = GpsData(fl.to_ns(gp.t[keep]), gp.position[keep], np.tile(gp.position_cov, (keep.sum(), 1, 1)),
                  gp.velocity[keep], np.tile(gp.velocity_cov, (keep.sum(), 1, 1)))
    rng = np.random.default_rng(seed)
    rows = []
    for ci, cam in enumerate(fl.cameras):
        ct = cam.truth
        for target, vecs, vis in (("hor", ct.nadir_c, ct.horizon_visible), ("sun", ct.sun_c, ct.sun_in_view)):
            zeta = None
            last_t = None
            for i in np.flatnonzero(vis & (ct.t >= imu.t[start] - 1e-9)):
                e = vecs[i] / np.linalg.norm(vecs[i])
                P_c = vec_sigma ** 2 * (np.eye(3) - np.outer(e, e))
                if noise:
                    L = vec_sigma * _tangent(e)
                    if gm and zeta is not None and ct.t[i] - last_t < 3 * tc:
                        phi = np.exp(-(ct.t[i] - last_t) / tc)
                        zeta = phi * zeta + np.sqrt(1 - phi ** 2) * (L @ rng.normal(size=2))
                    else:
                        zeta = L @ rng.normal(size=2)
                    last_t = ct.t[i]
                    meas = e + zeta + white * (_tangent(e) @ rng.normal(size=2))
                    meas /= np.linalg.norm(meas)
                else:
                    meas = e
                rows.append((int(cam.t_ns[i]), ci, target, meas, P_c))
    rows.sort(key=lambda r: r[0])
    vec = VectorData(np.array([r[0] for r in rows], dtype=np.int64), np.array([r[1] for r in rows]),
                     np.array([r[2] for r in rows]), np.array([r[3] for r in rows]).reshape(-1, 3),
                     np.array([r[4] for r in rows]).reshape(-1, 3, 3))
    return FlightInputs(ImuData(t_ns, a, g, sample), gps, vec, [c.R_bc_nominal for c in fl.cameras],
                        np.array([c.psi_c for c in fl.cameras]), idx, tr, start)


def _tangent(e):
    from nav.measurements import tangent_basis
    return tangent_basis(e)


def truth_init(fi: FlightInputs):
    tr, i = fi.truth, fi.truth_idx[fi.start_idx]
    return InitialState(int(fi.imu.t_ns[fi.start_idx]), tr.x_e[i], tr.v_e[i], tr.q_eb[i])


@pytest.fixture(scope="module")
def atek_nav_grade_ideal():
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    return simulate_flight(load_scenario("atek-nav-grade"), seed=1, duration=430.0, imu_errors=False)


def test_zero_noise_ins_reproduces_coast(atek_nav_grade_ideal):
    """Error-free (ideal, unquantised) 400 Hz IMU over the atek-nav-grade coast T+60..T+430: the
    INS alone reproduces the simulator's truth to < 1e-6 rad and < 0.1 m (issue acceptance)."""
    fi = flight_inputs(atek_nav_grade_ideal, 60.0, ideal_imu=True)
    s = fi.start_idx
    ts = (fi.imu.t_ns[s:] - fi.imu.t_ns[s]) / NS
    init = truth_init(fi)
    X, V, Q = ins.propagate(init.x_e, init.v_e, init.q_eb, ts, fi.imu.f_b[s:], fi.imu.w_b[s:], sample=fi.imu.sample)
    ti = fi.truth_idx[s:]
    att = np.linalg.norm(attitude_errors(Q, fi.truth.q_eb[ti]), axis=1)
    pos = np.linalg.norm(X - fi.truth.x_e[ti], axis=1)
    print(f"zero-noise coast: max attitude error {att.max():.3g} rad, max position error {pos.max():.3g} m")
    assert att.max() < 1e-6
    assert pos.max() < 0.1


def test_zero_noise_filter_holds_on_coast(atek_nav_grade_ideal):
    """Error-free IMU, GPS and vectors (simulator truth, true mountings): the filter holds the
    attitude to < 1e-5 rad (issue acceptance)."""
    fl = atek_nav_grade_ideal
    fi = flight_inputs(fl, 60.0, ideal_imu=True, noise=False)
    s = fi.start_idx
    end = s + 400 * 120  # 120 s of the coast keep the test short
    imu = ImuData(fi.imu.t_ns[:end], fi.imu.f_b[:end], fi.imu.w_b[:end], fi.imu.sample)
    # error-free GPS: the truth at the fix times (covariance shrunk accordingly)
    from scenarios.sim.gps import truth_at
    xg, vg = truth_at(fl.truth, (fi.gps.t_ns - fl.liftoff_ns) / NS)
    gps = GpsData(fi.gps.t_ns, xg, fi.gps.P_x * 1e-6, vg, fi.gps.P_v * 1e-6)
    res = run(imu, truth_init(fi), Tuning(), gps=gps, vectors=fi.vectors, R_bc=[c.R_bc for c in fl.cameras])
    ti = fi.truth_idx[s:end]
    att = np.linalg.norm(attitude_errors(res.q_eb, fi.truth.q_eb[ti]), axis=1)
    print(f"zero-noise filter: max attitude error {att.max():.3g} rad")
    assert att.max() < 1e-5


def test_ins_through_spinning_ascent(atek_nav_grade_ideal):
    """Drift of the unaided INS from lift-off through the 3.6 Hz spin to T+60 (ideal 400 Hz IMU).
    The bound is this implementation's measured drift with a factor ~10 margin: RK4 on
    interval-mean rates loses the coning correction, an error of order w_spin * w_cone * dt^2."""
    fi = flight_inputs(atek_nav_grade_ideal, 0.0, ideal_imu=True)
    s = fi.start_idx
    end = int(np.searchsorted(atek_nav_grade_ideal.imu.t, 60.0))
    ts = (fi.imu.t_ns[s:end] - fi.imu.t_ns[s]) / NS
    tr, i0 = fi.truth, fi.truth_idx[s]
    X, V, Q = ins.propagate(tr.x_e[i0], tr.v_e[i0], tr.q_eb[i0], ts, fi.imu.f_b[s:end], fi.imu.w_b[s:end], sample="average")
    ti = fi.truth_idx[s:end]
    att = np.linalg.norm(attitude_errors(Q, tr.q_eb[ti]), axis=1)
    pos = np.linalg.norm(X - tr.x_e[ti], axis=1)
    print(f"spinning ascent T+0..T+60: max attitude drift {att.max():.3g} rad, position {pos.max():.3g} m")
    assert att.max() < ASCENT_ATT_BOUND and pos.max() < ASCENT_POS_BOUND


# ------------------------------------------------------------------------------------------------
# Monte Carlo consistency on the atek coast
# ------------------------------------------------------------------------------------------------

VEC_GM_DEG, VEC_WHITE_DEG = 0.05, 0.02   # stand-in vision error: GM (T_c = 20 s) + white, per vector
GYRO_WHITE_MATCHED = 0.05  # deg/sqrt(h), the angular random walk, see matched_tuning
GYRO_QUANTUM_DPS = 0.03   # the atek gyro's rate step, see matched_tuning
GYRO_MISALIGNMENT_SPLIT_MRAD = 1.4142  # 2 mrad / sqrt(2), see matched_tuning


def matched_tuning(base: Tuning | None = None) -> Tuning:
    """Table 3 with the error models of the simulated sensors instead of 003's flight tuning:
    accelerometer 0.05 mg/sqrt(Hz); gyro 0.05 deg/sqrt(h) and the atek gyro's 0.03 deg/s rate
    quantisation as an estimated Gauss-Markov rate error whose correlation time follows the rates
    (nav/quantisation.py; scenarios/library/tuning/atek-sim.toml derives them); the simulator's six
    2 mrad axis-misalignment terms as their rotation and their non-orthogonality, 2 / sqrt(2) mrad
    each (nav/imu_errors.py), both considered; vector white noise as simulated."""
    t = base or Tuning()
    mis = StateGroupTuning("C", GYRO_MISALIGNMENT_SPLIT_MRAD * 1e-3)
    q = math.radians(GYRO_QUANTUM_DPS)
    return t.with_(accel_white=0.05e-3 * 9.80665, gyro_white=math.radians(GYRO_WHITE_MATCHED) / 60.0,
                   vector_white=math.radians(VEC_WHITE_DEG), gyro_misalignment=mis, gyro_nonorthogonality=mis,
                   gyro_gm=StateGroupTuning("E", q / math.sqrt(12.0)), gyro_gm_quantum=q)


@dataclass
class McStats:
    nees: dict            #: block -> (n_epochs,) MC-averaged NEES
    band: dict            #: block -> (lo, hi) 95 % band of the MC average (3 N dof)
    inside3: dict         #: block -> fraction of (run, epoch, axis) with |error| < 3 sigma
    nis_mean: dict        #: kind -> mean NIS over all runs and epochs
    nis_band: dict        #: kind -> (lo, hi) 95 % band of a run's time-averaged NIS, averaged over runs
    att_rms_deg: float
    att3_final_deg: float
    t_s: np.ndarray

    def time_avg(self, b):
        return float(np.mean(self.nees[b]))

    def inside_band_fraction(self, b):
        lo, hi = self.band[b]
        return float(np.mean((self.nees[b] > lo) & (self.nees[b] < hi)))


def consistency_study(n_runs: int, *, t_end=430.0, tuning: Tuning | None = None, scenario="atek", seed0=100):
    """n_runs filters over the coast (T+60..t_end) of one simulated truth with independent IMU,
    GPS, camera-misalignment, vector-error and initial-error draws per run."""
    from scipy.stats import chi2
    from scenarios.sim import simulate as S
    from scenarios.sim.scenario import load_scenario
    sc = load_scenario(scenario)
    tr = _truth_cache(scenario, t_end)
    tun = tuning or matched_tuning()
    err2 = {"pos": [], "vel": [], "att": []}
    inside = {"pos": [], "vel": [], "att": []}
    nis = {}
    att_rms, att3 = [], []
    t_ref = None
    for r in range(n_runs):
        seed = seed0 + r
        imu, errs = S.simulate_imu(tr, sc.imu, S.rng_for(seed, S.STREAM_IMU))
        gps = S.simulate_gps(tr, sc.gps, S.rng_for(seed, S.STREAM_GPS))
        cams = S.simulate_cameras(sc, tr, seed)
        fl = S.FlightData(sc, seed, t_end, tr, imu, errs, gps, cams)
        fi = flight_inputs(fl, 60.0, seed=seed, vec_sigma=math.radians(VEC_GM_DEG), white=math.radians(VEC_WHITE_DEG))
        init = perturbed_init(type("S", (), {"init": truth_init(fi)})(), np.random.default_rng(seed), tun)
        res = run(fi.imu, init, tun, gps=fi.gps, vectors=fi.vectors, R_bc=fi.R_bc_nominal, store_for_smoother=False,
                  unaided=False)
        # full covariance at the measurement epochs (every GPS fix)
        mi = np.searchsorted(res.t_ns, res.meas_t_ns)
        ti = fi.truth_idx[fi.start_idx + mi]
        e = {"pos": tr.x_e[ti] - res.x_e[mi], "vel": tr.v_e[ti] - res.v_e[mi],
             "att": attitude_errors(res.q_eb[mi], tr.q_eb[ti])}
        lay = res.layout
        for b, sl in (("pos", lay["dx"]), ("vel", lay["dv"]), ("att", lay["psi"])):
            Pb = res.P_full[:, sl, sl]
            err2[b].append(np.einsum("ki,kij,kj->k", e[b], np.linalg.inv(Pb), e[b]))
            inside[b].append(np.abs(e[b]) < 3 * np.sqrt(np.diagonal(Pb, axis1=1, axis2=2)))
        for kind in ("gps_pos", "gps_vel", "hor", "sun"):
            v = res.nis(kind)
            if v.size:
                nis.setdefault(kind, []).append(v.mean())
        psi_all = attitude_errors(res.q_eb, tr.q_eb[fi.truth_idx[fi.start_idx:]])
        att_rms.append(np.mean(np.sum(psi_all ** 2, 1)))
        att3.append(3 * np.degrees(np.sqrt(res.P_diag[-1, lay["psi"]].max())))
        t_ref = (res.meas_t_ns - fl.liftoff_ns) / NS
    k = min(len(x) for x in err2["pos"])
    nees = {b: np.mean([x[:k] for x in err2[b]], axis=0) for b in err2}
    band = {b: (chi2.ppf(0.025, 3 * n_runs) / n_runs, chi2.ppf(0.975, 3 * n_runs) / n_runs) for b in err2}
    dof = {"gps_pos": 3, "gps_vel": 3, "hor": 2, "sun": 2}
    nis_band = {kk: (chi2.ppf(0.025, dof[kk] * len(v)) / len(v), chi2.ppf(0.975, dof[kk] * len(v)) / len(v))
                for kk, v in nis.items()}
    return McStats(nees, band, {b: float(np.mean(np.concatenate(inside[b]))) for b in inside},
                   {kk: float(np.mean(v)) for kk, v in nis.items()}, nis_band,
                   float(np.degrees(np.sqrt(np.mean(att_rms)))), float(np.mean(att3)), t_ref[:k])


_TRUTH = {}


def _truth_cache(name, t_end):
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.truth import simulate_truth
    if (name, t_end) not in _TRUTH:
        _TRUTH[(name, t_end)] = simulate_truth(load_scenario(name), t_end)
    return _TRUTH[(name, t_end)]


def _check_consistency(st: McStats, n_runs: int, min_inside3: float):
    for b in ("pos", "vel", "att"):
        lo, hi = st.band[b]
        assert lo < st.time_avg(b) < hi, (b, st.time_avg(b), st.band[b])
        assert st.inside3[b] >= min_inside3, (b, st.inside3[b])
    for kind, m in st.nis_mean.items():
        lo, hi = st.nis_band[kind]
        assert lo < m < hi, (kind, m, st.nis_band[kind])


def test_consistency_small_monte_carlo():
    """8 runs of the atek coast to T+250 (the 50-run study is marked slow). The 95 % band of the
    MC-averaged NEES is chi2(3 N)/N, which is already wide for N = 8 (1.55..4.92); per-axis errors
    within 3 sigma >= 98 % (the 50-run study asks 99 %)."""
    st = consistency_study(8, t_end=250.0)
    _check_consistency(st, 8, 0.98)


@pytest.mark.slow
def test_consistency_monte_carlo_50_runs():
    """50 runs of the full atek coast (T+60..T+430): NEES of position, velocity and attitude in its
    95 % band, per-axis errors within 3 sigma >= 99 % of the time, each NIS in its band; then the
    same with the camera misalignment only considered, which stays consistent but is less
    accurate (the printout gives the difference)."""
    st = consistency_study(50)
    _check_consistency(st, 50, 0.99)
    tun = matched_tuning()
    st_c = consistency_study(50, tuning=tun.with_(camera_misalignment=StateGroupTuning("C", tun.camera_misalignment.sigma)))
    print(f"attitude RMS {st.att_rms_deg:.3f} deg (psi_c estimated) vs {st_c.att_rms_deg:.3f} deg (considered); "
          f"final 3-sigma {st.att3_final_deg:.3f} vs {st_c.att3_final_deg:.3f} deg")
    assert st.att_rms_deg < st_c.att_rms_deg


# ------------------------------------------------------------------------------------------------
# GNSS/INS against pyins (PyPI python-ins) on the same data
# ------------------------------------------------------------------------------------------------

def pyins_run(fi: FlightInputs, init: InitialState, *, t_end_s=None, imu_noise=(0.05e-3 * 9.80665, math.radians(0.3) / 60)):
    """pyins' feedback EKF (``pyins.filters.run_feedback_filter``) on the same IMU samples and GPS
    fixes. The interval-mean samples are handed over as increments (mean * dt), which is what they
    are; times are seconds since the start, rounded to the microsecond so that GPS times match
    IMU times (pyins uses a measurement only at an exact increment time). Returns (t_ns, x_e, v_e)."""
    import pandas as pd
    from pyins import filters, measurements, strapdown, transform
    from pyins.inertial_sensor import EstimationModel
    from nav.rotation import quat_to_matrix
    s = fi.start_idx
    t_ns = fi.imu.t_ns[s:]
    if t_end_s is not None:
        t_ns = t_ns[(t_ns - t_ns[0]) / NS <= t_end_s]
    n = t_ns.size
    ts = np.round((t_ns - t_ns[0]) / NS, 6)
    dt = np.diff(ts)
    # increment at row k covers (t_{k-1}, t_k]; the first row is the "before" sample
    gyro = np.vstack([np.zeros(3), fi.imu.w_b[s + 1:s + n] * dt[:, None]])
    accel = np.vstack([np.zeros(3), fi.imu.f_b[s + 1:s + n] * dt[:, None]])
    imu = pd.DataFrame(np.hstack([gyro, accel]), index=ts,
                       columns=["gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"])
    inc = strapdown.compute_increments_from_imu(imu, "increment")
    lat, lon, h = earth.ecef_to_geodetic(init.x_e)
    Ren = earth.R_en(lat, lon)
    rph = transform.mat_to_rph(Ren.T @ quat_to_matrix(init.q_eb))
    v_n = Ren.T @ init.v_e
    pva = pd.Series({"lat": np.degrees(lat), "lon": np.degrees(lon), "alt": h, "VN": v_n[0], "VE": v_n[1],
                     "VD": v_n[2], "roll": rph[0], "pitch": rph[1], "heading": rph[2]}, name=0.0)
    g = fi.gps
    keep = (g.t_ns >= t_ns[0]) & (g.t_ns <= t_ns[-1])
    tg = np.round((g.t_ns[keep] - t_ns[0]) / NS, 6)
    glat, glon, gh = earth.ecef_to_geodetic(g.x_e[keep])
    gvn = np.einsum("kji,kj->ki", earth.R_en(glat, glon), g.v_e[keep])
    pos = pd.DataFrame({"lat": np.degrees(glat), "lon": np.degrees(glon), "alt": gh}, index=tg)
    vel = pd.DataFrame(gvn, index=tg, columns=["VN", "VE", "VD"])
    sp, sv = np.sqrt(g.P_x[0, 0, 0]), np.sqrt(g.P_v[0, 0, 0])
    meas = [measurements.Position(pos, sp), measurements.NedVelocity(vel, sv)]
    tun = Tuning()
    gyro_model = EstimationModel(bias_sd=tun.gyro_bias.sigma, noise=imu_noise[1])
    accel_model = EstimationModel(bias_sd=tun.accel_bias.sigma, noise=imu_noise[0])
    out = filters.run_feedback_filter(pva, tun.init_pos_sigma, tun.init_vel_sigma,
                                      math.degrees(tun.init_att_sigma), math.degrees(tun.init_att_sigma),
                                      inc, gyro_model, accel_model, meas, time_step=0.1)
    tr = out.trajectory
    x = earth.geodetic_to_ecef(np.radians(tr.lat.values), np.radians(tr.lon.values), tr.alt.values)
    v = np.einsum("kij,kj->ki", earth.R_en(np.radians(tr.lat.values), np.radians(tr.lon.values)),
                  tr[["VN", "VE", "VD"]].values)
    t_out = t_ns[0] + np.round(tr.index.values * NS).astype(np.int64)
    return t_out, x, v


def gnss_ins_comparison(fl, t_end_s=None):
    """Our GPS/INS (no cameras) and pyins on the same data; RMS position/velocity errors of both."""
    fi = flight_inputs(fl, 60.0, noise=False)
    init = truth_init(fi)
    res = run(fi.imu, init, matched_tuning(), gps=fi.gps, store_for_smoother=False, unaided=False)
    t_p, x_p, v_p = pyins_run(fi, init, t_end_s=t_end_s)
    ti_p = fi.truth_idx[fi.start_idx + np.searchsorted(fi.imu.t_ns[fi.start_idx:], t_p)]
    m = np.searchsorted(res.t_ns, t_p)
    ti = fi.truth_idx[fi.start_idx + m]
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e ** 2, 1))))
    tr = fi.truth
    return {"ours_pos": rms(res.x_e[m] - tr.x_e[ti]), "ours_vel": rms(res.v_e[m] - tr.v_e[ti]),
            "pyins_pos": rms(x_p - tr.x_e[ti_p]), "pyins_vel": rms(v_p - tr.v_e[ti_p])}


def _pyins_case(t_end_s):
    from scenarios.sim import simulate as S
    from scenarios.sim.scenario import load_scenario
    sc = load_scenario("atek")
    tr = _truth_cache("atek", 430.0)
    imu, errs = S.simulate_imu(tr, sc.imu, S.rng_for(7, S.STREAM_IMU))
    gps = S.simulate_gps(tr, sc.gps, S.rng_for(7, S.STREAM_GPS))
    fl = S.FlightData(sc, 7, 430.0, tr, imu, errs, gps, [])
    c = gnss_ins_comparison(fl, t_end_s=t_end_s)
    print("GNSS/INS RMS errors:", c)
    assert c["ours_pos"] <= 1.1 * c["pyins_pos"]
    assert c["ours_vel"] <= 1.1 * c["pyins_vel"]
    return c


def test_gnss_ins_no_worse_than_pyins_short():
    """atek coast T+60..T+80, GPS (10 Hz) + 20 Hz IMU only: our position and velocity RMS errors
    are no worse than pyins' on the same data (10 % allowance for the different process models;
    pyins' Python loop makes longer spans slow, see the slow variant)."""
    _pyins_case(20.0)


@pytest.mark.slow
def test_gnss_ins_no_worse_than_pyins_120s():
    """As above over T+60..T+180 (pyins needs ~1.5 min)."""
    _pyins_case(120.0)


# ------------------------------------------------------------------------------------------------
# Accuracy on atek with 003's tuning (table 3)
# ------------------------------------------------------------------------------------------------

def atek_accuracy(mis_deg=1.0, seed=21, t_end=430.0, smoother=False):
    """atek flight, table-3 errors, camera misalignment ``mis_deg`` (1 sigma per axis), stand-in
    vision errors; the filter is tuned as 003 table 3 (camera misalignment sigma = ``mis_deg``)
    and initialised as in 003 §7.4 (TRIAD at the first epoch with both vectors, back-propagated
    to T+60). Returns figures for the report / benchmark."""
    import copy
    from nav.initialise import triad_initialise
    from nav.smoother import rts_smooth
    from scenarios.sim import simulate as S
    from scenarios.sim.scenario import load_scenario
    sc = copy.deepcopy(load_scenario("atek"))
    for c in sc.cameras:
        c.misalignment_sigma_deg = mis_deg
    tr = _truth_cache("atek", t_end)
    imu, errs = S.simulate_imu(tr, sc.imu, S.rng_for(seed, S.STREAM_IMU))
    gps = S.simulate_gps(tr, sc.gps, S.rng_for(seed, S.STREAM_GPS))
    cams = S.simulate_cameras(sc, tr, seed)
    fl = S.FlightData(sc, seed, t_end, tr, imu, errs, gps, cams)
    fi = flight_inputs(fl, 60.0, seed=seed, vec_sigma=math.radians(VEC_GM_DEG), white=math.radians(VEC_WHITE_DEG))
    tun = Tuning().with_(camera_misalignment=StateGroupTuning("E", math.radians(mis_deg)))
    ti_init = triad_initialise(fi.imu, fi.gps, fi.vectors, fi.R_bc_nominal, int(fi.imu.t_ns[fi.start_idx]))
    res = run(fi.imu, ti_init.initial, tun, gps=fi.gps, vectors=fi.vectors, R_bc=fi.R_bc_nominal,
              store_for_smoother=smoother)
    ti = fi.truth_idx[fi.start_idx:]
    psi = attitude_errors(res.q_eb, tr.q_eb[ti])
    t_first = min(i.t_ns for i in res.innovations if i.kind in ("hor", "sun"))
    aided = res.t_ns >= t_first
    sig = np.sqrt(res.P_diag[:, res.layout["psi"]])
    t_cov = (res.cov_t_ns - fl.liftoff_ns) / NS
    i300 = int(np.searchsorted(t_cov, 300.0))
    out = {"att_rms_deg": float(np.degrees(np.sqrt(np.mean(np.sum(psi[aided] ** 2, 1))))),
           "att_3sigma_final_deg": float(3 * np.degrees(sig[-1].max())),
           "att_3sigma_start_deg": float(3 * np.degrees(sig[0].max())),
           "att_3sigma_t300_deg": float(3 * np.degrees(sig[min(i300, len(sig) - 1)].max())),
           "att_err_final_deg": float(np.degrees(np.linalg.norm(psi[-1]))),
           "inside3_final": bool(np.all(np.abs(psi[res.cov_idx[-1]]) < 3 * sig[-1])),
           "triad_init_err_deg": float(np.degrees(np.linalg.norm(attitude_errors(ti_init.initial.q_eb, tr.q_eb[ti[0]])))),
           "unaided_err_final_deg": float(np.degrees(np.linalg.norm(attitude_errors(res.unaided_q_eb[-1], tr.q_eb[ti[-1]])))),
           "res": res, "truth_idx": ti, "truth": tr}
    if smoother:
        sm = rts_smooth(res)
        psi_s = attitude_errors(sm.q_eb, tr.q_eb[ti[sm.idx]])
        a = aided[sm.idx]
        out["att_rms_deg_smoothed"] = float(np.degrees(np.sqrt(np.mean(np.sum(psi_s[a] ** 2, 1)))))
        out["att_rms_deg_filter_epochs"] = float(np.degrees(np.sqrt(np.mean(np.sum(psi[sm.idx][a] ** 2, 1)))))
    return out


def test_atek_accuracy_table3_tuning():
    """003's tuning on the atek flight: the 3-sigma attitude bound falls from the 6 deg of the
    2 deg initialisation to below 3 deg by T+300 (measured 2.2 deg; 003 reports 1.1 deg with many
    more vector frames per second than the simulator's 1 Hz cameras and the 0.005 white noise of
    table 3 per vector), the final error is inside it, and the smoother's RMS error during the
    aided phase is below the filter's."""
    a = atek_accuracy(1.0, smoother=True)
    print({k: v for k, v in a.items() if isinstance(v, (float, bool))})
    assert math.degrees(3 * Tuning().init_att_sigma) == pytest.approx(6.0)
    assert a["att_3sigma_t300_deg"] < 3.0
    assert a["inside3_final"]
    assert a["att_rms_deg_smoothed"] < a["att_rms_deg_filter_epochs"]
