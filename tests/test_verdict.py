"""The replay's verdict (scenarios/replay/verdict.py, docs/replay.md "Verdict"): a small simulated
flight (atek, 200 s, truth-derived camera vectors from T+60) replayed clean and broken the way real
data break: cut at half its bytes, GPS offset by 3 km from mid-flight, GPS of another flight from
mid-flight, GPS velocity in the wrong frame, a 20 s IMU gap, the IMU cut at mid-flight. Clean
ends OK (exit 0), truncated DEGRADED with the reader's warning on the terminal (exit 0, 4 with
--strict), the broken GPS FAILED (exit 3), the IMU gap and cut DEGRADED.
"""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from scipy.stats import chi2

from nav import earth
from scenarios.cli import main
from scenarios.flightlog.reader import read_log

DURATION, T_BREAK = 200.0, 130.0    #: flight length, when the GPS breaks [s after lift-off]


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """The clean flight and its broken variants as logs: name -> path (and the FlightData)."""
    from scenarios.cli.simulate import write_log
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    from scenarios.sim.truth_vectors import flight_truth_vectors
    d = tmp_path_factory.mktemp("verdict")
    sc = load_scenario("atek")
    fl = simulate_flight(sc, 0, DURATION)
    vec = flight_truth_vectors(fl)
    logs = {"clean": write_log(fl, d / "clean.mcap", vectors=vec)}
    data = (d / "clean.mcap").read_bytes()
    (d / "truncated.mcap").write_bytes(data[:len(data) // 2])
    logs["truncated"] = d / "truncated.mcap"
    g = fl.gps
    late = g.t >= T_BREAK
    # 3 km north of the true track from T_BREAK on
    lat, lon, _ = earth.ecef_to_geodetic(g.position)
    north = earth.R_en(lat, lon)[:, :, 0]
    bad = copy.deepcopy(fl)
    bad.gps.position[late] += 3000.0 * north[late]
    logs["offset"] = write_log(bad, d / "offset.mcap", vectors=vec)
    # the fixes of another flight (high-apogee: another motor, another trajectory) from T_BREAK on
    other = simulate_flight(load_scenario("high-apogee"), 0, DURATION)
    bad = copy.deepcopy(fl)
    bad.gps.position[late] = other.gps.position[late]
    bad.gps.velocity[late] = other.gps.velocity[late]
    logs["other"] = write_log(bad, d / "other.mcap", vectors=vec)
    # NED velocity written as ECEF
    bad = copy.deepcopy(fl)
    bad.gps.velocity[:] = np.einsum("nji,nj->ni", earth.R_en(lat, lon), g.velocity)
    logs["ned_as_ecef"] = write_log(bad, d / "ned.mcap", vectors=vec)
    # sigmas declared 10 times too large (a unit slip)
    bad = copy.deepcopy(fl)
    bad.gps.position_cov = 100.0 * g.position_cov
    bad.gps.velocity_cov = 100.0 * g.velocity_cov
    logs["loose"] = write_log(bad, d / "loose.mcap", vectors=vec)
    # "no fix" rows (NaN position and velocity) from T+100 to T+115
    bad = copy.deepcopy(fl)
    nofix = (g.t >= 100.0) & (g.t < 115.0)
    bad.gps.position[nofix] = np.nan
    bad.gps.velocity[nofix] = np.nan
    logs["nofix"] = write_log(bad, d / "nofix.mcap", vectors=vec)
    # camera 1's first Earth vector turned 4 deg across its line of sight (covariance kept): a
    # gross error accepted while the priors are wide, which locks the camera's misalignment
    from nav.measurements import tangent_basis
    from nav.rotation import rotvec_to_matrix
    lock = copy.deepcopy(vec)
    j = int(np.flatnonzero((lock.camera == 1) & (lock.target == "earth"))[0])
    lock.e_c[j] = rotvec_to_matrix(np.radians(4.0) * tangent_basis(lock.e_c[j])[:, 0]) @ lock.e_c[j]
    logs["lockout"] = write_log(fl, d / "lockout.mcap", vectors=lock)
    # camera 1's vectors all turned 8 deg about its z axis: a camera file whose mounting is off
    # by 8 prior sigmas
    mount = copy.deepcopy(vec)
    m1 = mount.camera == 1
    mount.e_c[m1] = mount.e_c[m1] @ rotvec_to_matrix(np.radians([0.0, 0.0, 8.0])).T
    logs["mounted"] = write_log(fl, d / "mounted.mcap", vectors=mount)
    # IMU samples missing: 20 s from T+100 (a gap), or everything after T_BREAK (a cut table)
    t = fl.imu.t
    for name, drop in (("imu_gap", (t > 100.0) & (t < 120.0)), ("imu_cut", t > T_BREAK)):
        bad = copy.deepcopy(fl)
        bad.imu.t, bad.imu.gyro, bad.imu.accel = t[~drop], fl.imu.gyro[~drop], fl.imu.accel[~drop]
        logs[name] = write_log(bad, d / f"{name}.mcap", vectors=vec)
    return logs, fl, d


def _replay(log, d, capsys, *extra):
    """``horizon-nav replay LOG --json PATH`` (no smoother, no recording): exit code, stdout,
    stderr and the JSON summary."""
    js = d / f"{log.stem}{len(extra)}.json"
    rc = main(["replay", str(log), "-o", str(d / f"{log.stem}.solution.mcap"), "--no-smoother", "--no-rerun", "--quiet",
               *extra, "--json", str(js)])
    out = capsys.readouterr()
    s = json.loads(js.read_text()) if js.exists() else None
    return rc, out.out, out.err, s


def _window_fixes(fl, t_end=DURATION):
    """GPS fixes of the simulated flight in the replay's window (T+60, the first camera frame, to t_end)."""
    return int(np.sum((fl.gps.t >= 60.0 - 1e-9) & (fl.gps.t <= t_end + 1e-9)))


def _logged(sol_path, source):
    """(used, NIS) of ``source`` in the solution log's /nav/measurements: the record the verdict
    is checked against, read back independently of the summary."""
    m = read_log(sol_path).measurements
    sel = np.asarray(m.source).astype(str) == source
    return np.asarray(m.used, bool)[sel], np.asarray(m.nis, float)[sel]


def test_clean_flight_is_ok(flights, capsys):
    logs, fl, d = flights
    rc, out, _, s = _replay(logs["clean"], d, capsys)
    assert rc == 0 and s["exit_code"] == 0
    assert s["verdict"]["status"] == "OK" and s["verdict"]["reasons"] == []
    assert out.rstrip().splitlines()[-1] == "verdict: OK"
    n = _window_fixes(fl)
    used, nis = _logged(d / "clean.solution.mcap", "gps/position")
    for src, dof in (("gps/position", 3), ("gps/velocity", 3)):
        g = s["sensors"][src]
        assert g["offered"] == n and g["accepted"] == n and g["rejected"] == {}
        # the band of the mean of N chi-square(3) values: chi2(3N) / N, from scipy
        lo, hi = chi2.ppf([0.025, 0.975], dof * n) / n
        assert np.allclose(g["nis"]["band95"], [lo, hi], rtol=1e-9)
        # a consistent filter: inside the 1e-4 two-sided band (the velocity NIS of this filter sits
        # at the 95 % band's lower edge, conservative; the position NIS inside it)
        lo4, hi4 = chi2.ppf([1e-4, 1 - 1e-4], dof * n) / n
        assert lo4 < g["nis"]["mean"] < hi4, (src, g["nis"]["mean"], lo4, hi4)
    assert lo < s["sensors"]["gps/position"]["nis"]["mean"] < hi
    assert used.all() and used.size == n and np.isclose(nis.mean(), s["sensors"]["gps/position"]["nis"]["mean"])
    for k in (1, 2):    # the truth-derived vectors: every frame from T+60, one per second
        assert s["sensors"][f"camera_{k}/earth"]["accepted"] == int(DURATION - 60) + 1
    assert s["imu_gaps"]["count"] == 0 and s["recoveries"] == [] and s["warnings"] == [] and s["gps_steps"] == []
    assert s["position_sigma_m"]["final"] < 1.0     # 3 m fixes at 10 Hz with 0.1 m/s velocities
    meta = read_log(d / "clean.solution.mcap").metadata["horizon-nav.verdict"]
    assert meta["status"] == "OK" and json.loads(meta["reasons"]) == []


def test_pc_scales_estimated_without_the_edge_state_are_degraded(flights, capsys):
    """A tuning whose P_c scales `tune` estimated with the edge-height state off
    (``cov_scale_edge_state = "off"``, as scenarios/library/tuning/atek-ml.toml), replayed with
    the state on: the vectors then carry P_c given the height, which those scales make optimistic
    (attitude NEES mean 10.9 on the rendered ATEK 45 km flight, docs/vision.md). The replay says
    so in one warning and the verdict is DEGRADED for it; the same file with the state off, or
    without the record, gives no warning; a mode that is not one is refused naming the key."""
    from nav.tuning import consistency_warnings, tuning_from_toml
    logs, fl, d = flights
    scales = '[vectors]\ncov_scale_hor = 0.2\ncov_scale_edge_state = "off"\n'
    on = d / "scales-edge-on.toml"
    on.write_text(scales + '[states.edge_height]\nmode = "E"\n')
    rc, out, _, s = _replay(logs["clean"], d, capsys, "--tuning", str(on))
    warn = consistency_warnings(tuning_from_toml(on.read_text()))
    assert len(warn) == 1 and "optimistic" in warn[0] and "cov_scale" in warn[0]
    assert rc == 0 and s["verdict"]["status"] == "DEGRADED" and s["warnings"] == warn
    assert f"WARNING: {warn[0]}" in out and "1 input warning(s): " + warn[0] in s["verdict"]["reasons"]
    for text in (scales, scales.replace('cov_scale_edge_state = "off"\n', "") + '[states.edge_height]\nmode = "E"\n'):
        assert consistency_warnings(tuning_from_toml(text)) == []
    with pytest.raises(ValueError, match="cov_scale_edge_state: expected one of"):
        tuning_from_toml('[vectors]\ncov_scale_edge_state = "on"\n')


def test_truncated_log_is_degraded_and_says_so(flights, capsys):
    logs, fl, d = flights
    rc, out, _, s = _replay(logs["truncated"], d, capsys)
    size = logs["truncated"].stat().st_size
    assert rc == 0 and s["verdict"]["status"] == "DEGRADED" and s["truncated"]
    warn = [w for w in s["warnings"] if "truncated or damaged" in w]
    assert len(warn) == 1 and f" of {size};" in warn[0]
    assert f"WARNING: {warn[0]}" in out                      # on the terminal
    assert s["verdict"]["reasons"][0] == "input truncated: " + warn[0]
    assert out.rstrip().splitlines()[-1].startswith("verdict: DEGRADED: input truncated: ")
    # the solution ends where the log was cut, before the flight's end
    t_end = s["window_tplus_s"][1]
    assert 60.0 < t_end < DURATION / 2 + 10
    g = s["sensors"]["gps/position"]
    assert g["offered"] == _window_fixes(fl, t_end) and g["accepted"] == g["offered"]
    rc, *_ = _replay(logs["truncated"], d, capsys, "--strict")
    assert rc == 4
    # JSON on stdout: the warning still reaches the terminal, on stderr
    rc = main(["replay", str(logs["truncated"]), "-o", str(d / "t2.solution.mcap"), "--no-smoother", "--no-rerun",
               "--json", "-"])
    o = capsys.readouterr()
    assert rc == 0 and json.loads(o.out)["verdict"]["status"] == "DEGRADED"
    assert "horizon-nav replay: warning: " + warn[0] in o.err


@pytest.mark.parametrize("name,step_m", [("offset", 3000.0), ("other", None)])
def test_gps_corrupted_after_mid_flight_fails(flights, capsys, name, step_m):
    """The GPS jumps at T_BREAK (3 km north; or to another flight's fixes). The filter gates the
    new fixes, re-initialises onto them after 10 (a divergence recovery) and then follows them:
    the trajectory from T_BREAK on is wrong by the jump. The verdict sees the step in the GPS
    track that the GPS velocity does not explain, followed by that recovery."""
    logs, fl, d = flights
    rc, out, _, s = _replay(logs[name], d, capsys)
    assert rc == 3 and s["exit_code"] == 3 and s["verdict"]["status"] == "FAILED"
    assert out.rstrip().splitlines()[-1].startswith("verdict: FAILED: the GPS track steps by")
    steps = s["gps_steps"]
    assert len(steps) == 1 and abs(steps[0]["tplus_s"] - T_BREAK) < 1e-6
    if step_m is not None:   # 3 km plus the fixes' noise (3 m per axis)
        assert abs(steps[0]["size_m"] - step_m) < 30.0
    rec = s["recoveries"]
    assert len(rec) == 1 and rec[0]["reason"] == "divergence" and 0 < rec[0]["tplus_s"] - T_BREAK < 2.0
    assert rec[0]["details"]["position_jump_m"] > 0.9 * steps[0]["size_m"]
    # never exit code 0, strict or not
    assert _replay(logs[name], d, capsys, "--strict")[0] == 3


def test_camera_lockout_is_reopened_and_degraded(flights, capsys):
    """Camera 1's first Earth vector 4 deg off: its misalignment is re-opened after 20 of its
    vectors in a row were gated (nav/recovery.py), its later vectors are accepted, and the verdict
    is DEGRADED naming the camera (exit 0; 4 with --strict). The GPS rules that follow
    re-initialisations do not read it as one."""
    logs, fl, d = flights
    rc, out, _, s = _replay(logs["lockout"], d, capsys)
    assert rc == 0 and s["verdict"]["status"] == "DEGRADED"
    (r,) = s["recoveries"]
    assert r["reason"] == "camera_gated" and r["details"]["camera_name"] == "camera_1"
    assert r["details"]["gated_vectors"] == 20
    assert s["verdict"]["reasons"][0].startswith(f"camera_1: misalignment re-opened after 20 of its vectors in a row "
                                                 f"were gated at T+{r['tplus_s']:.1f} s: ")
    assert f"recoveries: T+{r['tplus_s']:.1f} s camera_gated (camera_1)" in out
    used, _ = _logged(d / "lockout.solution.mcap", "camera_1/earth")
    assert used[:1].all() and not used[1:21].any() and used[21:].all()
    assert not any("recovery" in x or "re-initialised" in x for x in s["verdict"]["reasons"])
    assert _replay(logs["lockout"], d, capsys, "--strict")[0] == 4


def test_misalignment_beyond_its_prior_is_degraded(flights, capsys):
    """Camera 1 mounted 8 deg off what its file says (its vectors turned about the camera's z
    axis): every vector is accepted, and before this rule the verdict was OK although the forward
    attitude error is several times the clean flight's. The misalignment estimate ends beyond 3
    sigma of its 1 deg prior, and that makes the run DEGRADED naming the camera (exit 0, 4 with
    --strict)."""
    logs, fl, d = flights
    rc, out, _, s = _replay(logs["mounted"], d, capsys)
    clean = _replay(logs["clean"], d, capsys)[3]
    assert rc == 0 and s["verdict"]["status"] == "DEGRADED"
    (m,) = s["misalignment_beyond_prior"]
    assert m["camera"] == "camera_1" and m["prior_sigma_deg"] == pytest.approx(1.0) and max(map(abs, m["psi_c_deg"])) > 3.0
    assert s["verdict"]["reasons"] == [f"camera_1: misalignment estimated {m['psi_c_deg']} deg (body axes), beyond 3 "
                                       "sigma of its 1 deg prior: the camera file's mounting may be off by more than "
                                       "the filter's small-angle misalignment holds"]
    assert s["truth"]["forward"]["att_rms_deg"] > 2 * clean["truth"]["forward"]["att_rms_deg"]
    assert clean["misalignment_beyond_prior"] == []
    assert _replay(logs["mounted"], d, capsys, "--strict")[0] == 4


def test_most_gps_rejected_fails(flights, capsys):
    """NED velocity written as ECEF: the velocity blocks are gated, the filter re-initialises again
    and again; over half of the GPS is rejected."""
    logs, fl, d = flights
    rc, out, _, s = _replay(logs["ned_as_ecef"], d, capsys)
    assert rc == 3 and s["verdict"]["status"] == "FAILED"
    n = _window_fixes(fl)
    for src in ("gps/position", "gps/velocity"):
        used, _ = _logged(d / "ned.solution.mcap", src)
        g = s["sensors"][src]
        assert g["offered"] == used.size == n and g["accepted"] == int(used.sum())
        assert g["rejected_share"] == pytest.approx(1 - used.mean()) and g["rejected_share"] > 0.5
    assert any(r.startswith("gps/velocity: ") and "fixes rejected" in r for r in s["verdict"]["reasons"])
    assert len(s["recoveries"]) >= 2
    meta = read_log(d / "ned.solution.mcap").metadata["horizon-nav.verdict"]
    assert meta["status"] == "FAILED" and json.loads(meta["reasons"]) == s["verdict"]["reasons"]


def test_python_api_exposes_the_verdict(flights):
    import scenarios
    logs, _, _ = flights
    ok = scenarios.navigate(scenarios.read_flight(logs["clean"]), smoother=False)
    bad = scenarios.navigate(scenarios.read_flight(logs["offset"]), smoother=False)
    assert ok.verdict.status == "OK" and ok.verdict.exit_code() == 0
    assert bad.verdict.status == "FAILED" and bad.verdict.exit_code() == 3 and bad.verdict.reasons
    assert bad.verdict.statistics["gps_steps"][0]["size_m"] > 2900.0


def test_nis_band_and_gross_limit_against_scipy():
    from scenarios.replay.verdict import gross_limit, mean_band
    for n, m in ((1, 2), (10, 3), (1401, 3), (20000, 2)):
        assert np.allclose(mean_band(n, m), chi2.ppf([0.025, 0.975], n * m) / n, rtol=1e-9)
        assert gross_limit(n, m) == pytest.approx(max(chi2.ppf(1 - 1e-6, n * m) / n, 2.0 * m), rel=1e-9)


def test_gps_step_detector_on_a_synthetic_track():
    """A straight 1.8 km/s track at 10 Hz with 3 m / 0.1 m/s white noise and a step from fix 300
    on. With velocities, 40 m is one step at fix 300 (against a per-axis sigma of sqrt(2 x 9) =
    4.2 m: 9.4 sigma); position only (per-axis sigma sqrt((9 + 4 x 9 + 9) ... ) = 7.6 m with the
    acceleration allowance), 80 m shows in the predictions of fixes 300 and 301 (10.5 sigma).
    Nothing else is a step (per pair chi-square(3) > 36: 7.5e-8, 600 pairs)."""
    from types import SimpleNamespace
    from scenarios.replay.verdict import gaps, gps_steps
    rng = np.random.default_rng(4)
    n, dt = 600, 0.1
    t = np.arange(n) * dt
    t_ns = (t * 1e9).astype(np.int64)
    v = np.tile([1800.0, 200.0, -50.0], (n, 1))
    x = 4.0e6 + t[:, None] * v + rng.normal(0, 3.0, (n, 3))
    vm = v + rng.normal(0, 0.1, (n, 3))
    P_x, P_v = np.tile(9.0 * np.eye(3), (n, 1, 1)), np.tile(0.01 * np.eye(3), (n, 1, 1))
    for step, vel, at in ((40.0, True, [300]), (80.0, False, [300, 301])):
        xs = x.copy()
        xs[300:] += [0.0, step, 0.0]
        found = gps_steps(SimpleNamespace(t_ns=t_ns, x_e=xs, P_x=P_x, v_e=vm if vel else None,
                                          P_v=P_v if vel else None))
        assert [s[0] for s in found] == [t_ns[i] for i in at], found
        assert abs(found[0][1] - step) < 4 * (4.2 if vel else 7.6)
    # gaps: the 10 Hz fixes with 3 s removed at 20 s, window 1 s longer at the end than the fixes
    keep = (t < 20.0) | (t >= 23.0)
    g = gaps(t_ns[keep], 0, int(t_ns[-1] + 1.5e9), 2.0)
    assert g["count"] == 1 and g["longest_s"] == pytest.approx(3.1) and g["longest_from_ns"] == t_ns[199]


def test_a_verdict_that_cannot_be_computed_is_failed():
    from types import SimpleNamespace
    from scenarios.replay.verdict import assess
    sol = SimpleNamespace(flight=SimpleNamespace(inputs=None, gps=None, cam_numbers=[]), nav=None, tuning=None)
    v = assess(sol)
    assert v.status == "FAILED" and v.exit_code() == 3 and v.reasons[0].startswith("the verdict could not be computed")


def test_imu_gap_and_cut_imu_are_degraded(flights, capsys):
    """A 20 s IMU gap: the filter re-initialises from the first fix after it and goes on (the
    solution is right again afterwards: position within 10 m of the truth 30 s later); an IMU
    record that stops at T_BREAK while GPS goes on: the solution stops with it, which is said."""
    logs, fl, d = flights
    rc, out, _, s = _replay(logs["imu_gap"], d, capsys)
    assert rc == 0 and s["verdict"]["status"] == "DEGRADED"
    assert s["imu_gaps"]["count"] == 1 and s["imu_gaps"]["longest_s"] == pytest.approx(20.05, abs=0.06)
    rec = s["recoveries"]
    assert len(rec) == 1 and rec[0]["reason"] == "imu_gap" and 120.0 <= rec[0]["tplus_s"] < 120.2
    g = s["sensors"]["gps/position"]
    assert g["accepted"] == g["offered"] - g["rejected"].get("chi-square gate", 0) and g["rejected_share"] < 0.05
    i = int(np.searchsorted(fl.truth.t, 150.0))
    sol = read_log(d / "imu_gap.solution.mcap").nav["forward"]
    j = int(np.argmin(np.abs(sol.t_ns - (fl.truth.liftoff_ns + 150 * 10 ** 9))))
    assert np.linalg.norm(np.asarray(sol.position_e[j]) - fl.truth.x_e[i]) < 10.0
    rc, out, _, s = _replay(logs["imu_cut"], d, capsys, "--strict")
    assert rc == 4 and s["verdict"]["status"] == "DEGRADED"
    assert s["imu_ends_before_gps_s"] == pytest.approx(DURATION - T_BREAK, abs=0.1)
    assert s["window_tplus_s"][1] == pytest.approx(T_BREAK, abs=0.06)


def test_no_fix_rows_are_an_outage_not_rejections(flights, capsys):
    """150 NaN fixes (a receiver without a fix for 15 s): missing, not offered and rejected; the
    outage is DEGRADED (longer than 10 s), the rest of the GPS accepted."""
    logs, fl, d = flights
    rc, out, _, s = _replay(logs["nofix"], d, capsys)
    assert rc == 0 and s["verdict"]["status"] == "DEGRADED"
    g = s["sensors"]["gps/position"]
    assert g["non_finite"] == 150 and g["offered"] == _window_fixes(fl) - 150 and g["rejected"] == {}
    assert g["gaps"]["count"] == 1 and g["gaps"]["longest_s"] == pytest.approx(15.1, abs=1e-6)
    assert "GPS outage of 15.1 s" in s["verdict"]["reasons"]


def test_gps_sigmas_ten_times_too_large_are_degraded(flights, capsys):
    """Sigmas 10 x the fixes' errors: every fix accepted, the NIS mean about 100 times below its
    expectation m = 3 (S is then mostly the declared R; the filter's own share shrinks with it)."""
    logs, fl, d = flights
    rc, out, _, s = _replay(logs["loose"], d, capsys)
    assert rc == 0 and s["verdict"]["status"] == "DEGRADED"
    for src in ("gps/position", "gps/velocity"):
        g = s["sensors"][src]
        assert g["accepted"] == g["offered"] == _window_fixes(fl)
        assert g["nis"]["mean"] < 0.1 * 3 < g["nis"]["band95"][0]
        # innovations of variance about R against S of about 100 R: 100 x the mean is a NIS mean of
        # a consistent filter, inside its 1e-4 two-sided band (2.76..3.24 for 1401 fixes) up to the
        # filter's own small share of S (measured 3.08 and 3.03)
        lo4, hi4 = chi2.ppf([1e-4, 1 - 1e-4], 3 * g["offered"]) / g["offered"]
        assert lo4 < 100.0 * g["nis"]["mean"] < hi4
        assert any(r.startswith(f"{src}: NIS mean") and "overstate" in r for r in s["verdict"]["reasons"])
