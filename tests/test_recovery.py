"""Recovery after an IMU gap or a divergence (nav/recovery.py) on the simulated atek-nav-grade coast
(400 Hz IMU, 10 Hz GPS, no camera vectors): the state is re-initialised from GPS, the event is
recorded, and the later fixes are accepted again."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from nav.navigator import NS, GpsData, ImuData, run
from nav.recovery import gap_threshold_s
from nav.tuning import Tuning, tuning_from_dict
from tests.test_navigator import flight_inputs, truth_init

T_GAP, GAP_S, T_JUMP = 80.0, 20.0, 90.0   #: gap start [s after lift-off], gap length [s], velocity jump time


@pytest.fixture(scope="module")
def coast():
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    fl = simulate_flight(load_scenario("atek-nav-grade"), seed=5, duration=140.0)
    return flight_inputs(fl, 60.0, seed=5)


def _sim_t(fi):
    """Simulation time [s after lift-off] of every IMU sample."""
    return fi.truth.t[fi.truth_idx]


def _outcome(fi, res, keep, t_after: float, t_from: float) -> dict:
    """Position error against truth ``t_after`` s after lift-off, and the share of GPS fixes (position
    and velocity blocks) accepted from ``t_from`` on. ``keep``: the IMU samples given to the run."""
    idx = fi.truth_idx[keep][fi.start_idx:] if keep is not None else fi.truth_idx[fi.start_idx:]
    t = fi.truth.t[idx]
    i = int(np.searchsorted(t, t_after))
    err = float(np.linalg.norm(res.x_e[i] - fi.truth.x_e[idx[i]]))
    t_cut = fi.imu.t_ns[0] + int(round((t_from - _sim_t(fi)[0]) * NS))
    later = [inn.accepted for inn in res.innovations if inn.kind.startswith("gps") and inn.t_ns >= t_cut]
    return {"pos_err_m": err, "accepted": float(np.mean(later)), "n_later": len(later)}


def gap_run(fi, tuning: Tuning | None = None) -> dict:
    """The coast with IMU samples from T_GAP to T_GAP + GAP_S removed; position error 30 s after the
    gap's end and the later fixes' acceptance."""
    t = _sim_t(fi)
    keep = ~((t > T_GAP) & (t < T_GAP + GAP_S))
    imu = ImuData(fi.imu.t_ns[keep], fi.imu.f_b[keep], fi.imu.w_b[keep], fi.imu.sample)
    res = run(imu, truth_init(fi), tuning or Tuning(), gps=fi.gps, store_for_smoother=False, unaided=False)
    return dict(_outcome(fi, res, keep, T_GAP + GAP_S + 30.0, T_GAP + GAP_S), res=res)


def with_and_without(case, fi, what: str):
    """``case(fi)`` with the default tuning and with recovery off; both outcomes printed."""
    out, off = case(fi), case(fi, Tuning().with_(recovery=False))
    print(f"{what}: position error 30 s later {out['pos_err_m']:.2f} m, later GPS blocks accepted "
          f"{100 * out['accepted']:.1f} % of {out['n_later']}; without recovery {off['pos_err_m']:.2f} m, "
          f"{100 * off['accepted']:.1f} %; recoveries {out['res'].recoveries}")
    return out, off


def test_gap_recovers(coast, caplog):
    with caplog.at_level(logging.WARNING, logger="nav.navigator"):
        out, _ = with_and_without(gap_run, coast, "20 s IMU gap")
    res = out["res"]
    assert len(res.recoveries) == 1
    t_r, reason, details = res.recoveries[0]
    assert reason == "imu_gap" and abs(details["gap_s"] - GAP_S) < 0.01
    assert out["pos_err_m"] < 10.0
    assert out["accepted"] > 0.95
    assert any("recovery (imu_gap)" in r.getMessage() for r in caplog.records)


def jump_run(fi, tuning: Tuning | None = None) -> dict:
    """A 30 m/s velocity jump the IMU reports but the vehicle does not make (0.5 s of 60 m/s^2 added
    along x_b at T_JUMP): the filter's velocity is wrong far beyond its covariance."""
    t = _sim_t(fi)
    f = fi.imu.f_b.copy()
    f[(t >= T_JUMP) & (t < T_JUMP + 0.5), 0] += 60.0
    imu = ImuData(fi.imu.t_ns, f, fi.imu.w_b, fi.imu.sample)
    res = run(imu, truth_init(fi), tuning or Tuning(), gps=fi.gps, store_for_smoother=False, unaided=False)
    return dict(_outcome(fi, res, None, T_JUMP + 30.0, T_JUMP + 2.0), res=res)


def test_divergence_recovers(coast):
    out, off = with_and_without(jump_run, coast, "30 m/s velocity jump")
    res = out["res"]
    assert off["accepted"] < 0.5   # without recovery: every later fix rejected
    assert [r[1] for r in res.recoveries] == ["divergence"]
    assert res.recoveries[0][2]["gated_fixes"] == Tuning().recovery_gated_fixes
    assert out["pos_err_m"] < 10.0
    assert out["accepted"] > 0.95


def test_position_only_gps_recovers_from_fix_difference(coast):
    """Without GPS velocity the re-initialised velocity is the difference of two fixes."""
    g = coast.gps
    fi = type(coast)(coast.imu, GpsData(g.t_ns, g.x_e, g.P_x), coast.vectors, coast.R_bc_nominal, coast.psi_c_true,
                     coast.truth_idx, coast.truth, coast.start_idx)
    out = gap_run(fi)
    res = out["res"]
    print(f"position-only GPS, 20 s gap: error {out['pos_err_m']:.2f} m, accepted {100 * out['accepted']:.1f} %")
    assert len(res.recoveries) == 1 and res.recoveries[0][2]["velocity_from"] == "difference"
    assert out["pos_err_m"] < 10.0
    assert out["accepted"] > 0.95


def test_gap_rule():
    """A gap triggers a recovery beyond both the time and the sample-count thresholds."""
    tun = Tuning()
    assert gap_threshold_s(np.arange(100) / 400.0, tun) == tun.recovery_gap_s
    assert gap_threshold_s(np.arange(100) / 20.0, tun) == pytest.approx(50 / 20.0)


def test_recovery_tuning_table():
    t = tuning_from_dict({"recovery": {"enabled": False, "gap_s": 5.0, "gap_samples": 10, "gated_fixes": 3,
                                       "gated_vectors": 7, "velocity_sigma_m_s": 1.0, "attitude_sigma_gap_deg": 4.0,
                                       "attitude_sigma_divergence_deg": 20.0}})
    assert (t.recovery, t.recovery_gap_s, t.recovery_gap_samples, t.recovery_gated_fixes, t.recovery_gated_vectors,
            t.recovery_vel_sigma) == (False, 5.0, 10.0, 3, 7, 1.0)
    assert t.recovery_att_sigma_gap == pytest.approx(np.radians(4.0))
    assert t.recovery_att_sigma_divergence == pytest.approx(np.radians(20.0))
    assert tuning_from_dict({}) == Tuning()
    with pytest.raises(ValueError, match="recovery.*unknown key 'gap_ms'"):
        tuning_from_dict({"recovery": {"gap_ms": 3}})
    with pytest.raises(ValueError, match="gated_fixes"):
        tuning_from_dict({"recovery": {"gated_fixes": 2.5}})
    with pytest.raises(ValueError, match=r"\[recovery\] gated_vectors: expected a non-negative integer"):
        tuning_from_dict({"recovery": {"gated_vectors": -1}})
    with pytest.raises(ValueError, match="enabled"):
        tuning_from_dict({"recovery": {"enabled": "yes"}})


def test_gap_in_a_turn_recovers_and_smooths():
    """The aircraft-like flight of tests/test_alignment.py (turns, speed changes; the attitude matters
    for the velocity) with a 20 s IMU gap from 50 s: without recovery the filter stays hundreds of
    metres off and rejects nearly every later fix; with it the position is back within 10 m 30 s
    after the gap, the later fixes are accepted, and the smoother runs across the re-initialisation."""
    from nav.navigator import InitialState
    from nav.smoother import rts_smooth
    from tests.test_alignment import aircraft_flight
    imu, gps, X, V, Q = aircraft_flight(1, duration=120.0)
    t = (imu.t_ns - imu.t_ns[0]) / NS
    keep = ~((t > 50.0) & (t < 70.0))
    gap = ImuData(imu.t_ns[keep], imu.f_b[keep], imu.w_b[keep], imu.sample)
    init = InitialState(int(imu.t_ns[0]), X[0], V[0], Q[0])
    i = int(np.searchsorted(t[keep], 100.0))
    t_cut = imu.t_ns[0] + 70 * NS
    out = {}
    logging.disable(logging.WARNING)
    try:
        for on in (True, False):
            res = run(gap, init, Tuning().with_(recovery=on), gps=gps)
            acc = np.mean([inn.accepted for inn in res.innovations if inn.kind.startswith("gps") and inn.t_ns > t_cut])
            out[on] = (float(np.linalg.norm(res.x_e[i] - X[keep][i])), float(acc), res)
    finally:
        logging.disable(logging.NOTSET)
    print(f"aircraft, 20 s gap in a turn: with recovery {out[True][0]:.2f} m, {100 * out[True][1]:.1f} % accepted; "
          f"without {out[False][0]:.0f} m, {100 * out[False][1]:.1f} %")
    res = out[True][2]
    assert [r[1] for r in res.recoveries] == ["imu_gap"]
    assert out[True][0] < 10.0 and out[True][1] > 0.95
    assert out[False][0] > 100.0 and out[False][1] < 0.5
    sm = rts_smooth(res)
    j = int(np.searchsorted(sm.idx, i))
    assert np.all(np.isfinite(sm.x_e)) and np.linalg.norm(sm.x_e[j] - X[keep][sm.idx[j]]) < 10.0


def test_attitude_divergence_recovers():
    """The aircraft-like flight started with a 30 deg tilt error (initial sigma 2 deg): the
    misprojected gravity drives the velocity off, the GPS fixes are gated, the divergence recovery
    re-initialises position and velocity with a wider attitude sigma, and the GPS then corrects
    the attitude: under 1 deg 30 s after the start, every later fix accepted."""
    from nav.navigator import InitialState
    from nav.rotation import matrix_to_quat, quat_to_matrix, rotvec_to_matrix
    from tests.test_alignment import aircraft_flight
    from tests.test_navigator import attitude_errors
    imu, gps, X, V, Q = aircraft_flight(1, duration=90.0)
    q0 = matrix_to_quat(rotvec_to_matrix(np.radians([30.0, 0.0, 0.0])) @ quat_to_matrix(Q[0]))
    logging.disable(logging.WARNING)
    try:
        res = run(imu, InitialState(int(imu.t_ns[0]), X[0], V[0], q0), Tuning(), gps=gps, store_for_smoother=False)
    finally:
        logging.disable(logging.NOTSET)
    i = int(np.searchsorted(res.t_ns, imu.t_ns[0] + 30 * NS))
    att = np.degrees(np.linalg.norm(attitude_errors(res.q_eb[i], Q[i])))
    acc = np.mean([inn.accepted for inn in res.innovations if inn.kind.startswith("gps") and inn.t_ns > res.recoveries[0][0]])
    print(f"30 deg tilt at the start: recoveries {[(r[1], r[2]['gated_fixes']) for r in res.recoveries]}, attitude error "
          f"at 30 s {att:.2f} deg, later GPS blocks accepted {100 * acc:.1f} %")
    assert [r[1] for r in res.recoveries] == ["divergence"]
    assert att < 1.0 and acc > 0.95


def test_recovery_table_in_a_tuning_file(tmp_path):
    from scenarios.config.tuning import load_tuning
    p = tmp_path / "t.toml"
    p.write_text("[recovery]\ngap_s = 3.0\ngated_fixes = 5\n")
    t = load_tuning(p)
    assert (t.recovery_gap_s, t.recovery_gated_fixes) == (3.0, 5)
    p.write_text("[recovery]\ngaps = 3.0\n")
    with pytest.raises(ValueError, match=r"t\.toml.*\[recovery\].*'gaps'"):
        load_tuning(p)


@pytest.fixture(scope="module")
def atek_vectors():
    """The atek flight to T+200 with the stand-in vision errors (tests/test_navigator.py), and the
    same vectors with camera 0's first horizon vector turned 4 deg across its line of sight at the
    stand-in's 0.05 deg covariance: a gross error the covariance does not hold."""
    import dataclasses
    from nav.measurements import tangent_basis
    from nav.rotation import rotvec_to_matrix
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    fi = flight_inputs(simulate_flight(load_scenario("atek"), seed=3, duration=200.0), 60.0, seed=3)
    v = fi.vectors
    j = int(np.flatnonzero((v.camera == 0) & (v.target == "hor"))[0])
    e = v.e_c.copy()
    e[j] = rotvec_to_matrix(np.radians(4.0) * tangent_basis(e[j])[:, 0]) @ e[j]
    return fi, dataclasses.replace(v, e_c=e)


def _lockout_run(fi, vectors, gated_vectors: int) -> dict:
    from nav.smoother import rts_smooth
    from tests.test_navigator import attitude_errors
    logging.disable(logging.WARNING)
    try:
        res = run(fi.imu, truth_init(fi), Tuning().with_(recovery_gated_vectors=gated_vectors), gps=fi.gps,
                  vectors=vectors, R_bc=fi.R_bc_nominal, store_for_smoother=True, unaided=False)
    finally:
        logging.disable(logging.NOTSET)
    t_re = res.recoveries[0][0] if res.recoveries else 0
    hor0 = [i for i in res.innovations if i.camera == 0 and i.kind == "hor"]
    sm = rts_smooth(res)
    q_true = fi.truth.q_eb[fi.truth_idx[fi.start_idx:]]

    def rms_after(q_eb, idx):
        """Attitude RMS error [deg] of the solution at IMU samples ``idx`` after the re-opening."""
        keep = res.t_ns[idx] > t_re
        return float(np.degrees(np.sqrt(np.mean(np.sum(attitude_errors(q_eb[keep], q_true[idx][keep]) ** 2, 1)))))
    return {"res": res, "hor0": hor0, "after": float(np.mean([i.accepted for i in hor0 if i.t_ns > t_re])),
            "err": np.degrees(res.misalignment[-1, 0] - fi.psi_c_true[0]),
            "sig3": 3 * np.degrees(res.misalignment_sigma[-1, 0]),
            "rms_fwd": rms_after(res.q_eb, np.arange(res.t_ns.size)), "rms_smoothed": rms_after(sm.q_eb, sm.idx)}


def test_camera_lockout_reopens_misalignment(atek_vectors):
    """A camera whose first horizon vector is 4 deg off with a 0.05 deg covariance, accepted while
    the misalignment prior is wide (1 deg): without the re-opening the misalignment locks onto it
    (over 3 sigma off, under 5 % of the camera's later horizon vectors accepted). With it
    (``[recovery] gated_vectors``, 20), the 20th gated vector in a row re-opens camera 0's
    misalignment once; afterwards every one of its vectors is accepted, the final misalignment is
    inside its 3 sigma of the simulated one, and the smoother, which sees the re-opening as process
    noise, is finite and no worse than the forward attitude after it. Truth: the simulation's."""
    fi, bad = atek_vectors
    off, on = _lockout_run(fi, bad, 0), _lockout_run(fi, bad, 20)
    print(f"locked: misalignment error {off['err'].round(3)} deg (3 sigma {off['sig3'].round(3)}), "
          f"{100 * np.mean([i.accepted for i in off['hor0']]):.1f} % of camera 0's horizon vectors accepted; "
          f"re-opened: {on['res'].recoveries}, error {on['err'].round(3)} deg (3 sigma {on['sig3'].round(3)}), "
          f"{100 * on['after']:.1f} % accepted after it, attitude RMS after it forward {on['rms_fwd']:.3f} / smoothed "
          f"{on['rms_smoothed']:.3f} deg")
    assert off["res"].recoveries == []
    assert np.any(np.abs(off["err"]) > off["sig3"]) and np.mean([i.accepted for i in off["hor0"]]) < 0.05
    (t_re, reason, det), = on["res"].recoveries
    gated = [i for i in on["hor0"] if i.reason == "chi-square gate"]
    assert (reason, det["camera"], det["gated_vectors"]) == ("camera_gated", 0, 20) and t_re == gated[19].t_ns
    assert on["after"] == 1.0
    assert np.all(np.abs(on["err"]) < on["sig3"])
    assert np.isfinite(on["rms_smoothed"]) and on["rms_smoothed"] <= on["rms_fwd"]


def test_camera_reopening_leaves_a_clean_flight_alone(atek_vectors):
    """On the same flight without the bad vector no camera is gated 20 times in a row, and the
    run is the one without the rule (the same estimates to the last bit)."""
    fi, _ = atek_vectors
    on, off = _lockout_run(fi, fi.vectors, 20), _lockout_run(fi, fi.vectors, 0)
    assert on["res"].recoveries == []
    assert np.array_equal(on["res"].q_eb, off["res"].q_eb) and np.array_equal(on["res"].misalignment, off["res"].misalignment)
