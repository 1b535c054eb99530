"""Import plausibility and physical cross-checks (scenarios/importer/plausibility.py, crosscheck.py,
docs/import.md "Checks"), position-only GPS and GPS without uncertainty columns.

Each test writes a small simulated flight as CSV tables (tests/import_flights.py: the ATEK rocket,
120 s, and an aircraft-like flight, 180 s), breaks one thing the way a user would, and checks that
the import refuses it (exit code 2, one error line naming the likely cause, nothing at the output
path) or, for inputs that are incomplete but correct, that it imports and replays to a correct
solution.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nav.timescales import utc_to_gps_ns
from scenarios.cli import main
from scenarios.errors import UserError
from scenarios.flightlog.reader import read_log
from scenarios.importer.build import ValidationFailed, _windows, import_flight
from scenarios.importer.mapping import load_mapping
from tests.import_flights import T0, mapping, plane_tables, rocket_tables, write_csv

ROOT = Path(__file__).resolve().parents[1]
CROSS = ("gps_velocity", "specific_force", "time_lag", "gyro_rotation", "body_axes")


@pytest.fixture(scope="module")
def rocket(tmp_path_factory):
    d = tmp_path_factory.mktemp("rocket")
    return d, rocket_tables(d)


@pytest.fixture(scope="module")
def plane(tmp_path_factory):
    d = tmp_path_factory.mktemp("plane")
    return d, plane_tables(d)


def _cli(args, capsys):
    rc = main(["import", *map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


def _refused(d, m, capsys, *patterns):
    """The import of mapping ``m`` is refused: exit code 2, one error line matching every pattern,
    nothing written; ``--check`` refuses it the same way."""
    out = d / "out.mcap"
    rc, _, err = _cli([m, "-o", out], capsys)
    assert rc == 2 and err.count("\n") == 1, err
    for p in patterns:
        assert p in err, (p, err)
    assert not out.exists() and not list(d.glob(".out.mcap*"))
    rc, _, err2 = _cli([m, "-o", out, "--check", "--quiet"], capsys)
    assert rc == 2 and err2.count("\n") == 1 and all(p in err2 for p in patterns), err2
    return err


# ------------------------------------------------------------------------------------------------
def test_correct_flights_pass_every_check(rocket, plane, capsys):
    for d, _ in (rocket, plane):
        m = mapping(d, "ok.toml")
        rc, out, err = _cli([m, "-o", d / "ok.mcap", "--check"], capsys)
        assert rc == 0 and "every check passed" in out, err
        res = import_flight(m, d / "ok.mcap")
        assert not res.report.errors
        found = {f.check: f for f in res.report.findings}
        for c in CROSS:
            assert c in found and found[c].level == "info", c
        # every cross-check ran (none skipped) and reports its statistic
        assert all("skipped" not in found[c].message for c in CROSS)
        print(f"\n{d.name}: " + " | ".join(found[c].message for c in CROSS))
    pl = {f.check: f.message for f in import_flight(mapping(plane[0], "ok.toml"), plane[0] / "ok.mcap").report.findings}
    assert "= 1 (median" in pl["specific_force"] or "= 0.99" in pl["specific_force"] or "= 1.00" in pl["specific_force"]


def test_unix_ms_declared_as_s_refused_fast_in_bounded_memory(rocket):
    """A fresh process (CLI) refuses it with exit code 2 and one line naming the unit that fits,
    within 10 s and 500 MB peak RSS (ru_maxrss of the child)."""
    d, _ = rocket
    m = mapping(d, "ms_as_s.toml", imu_unit="s")
    code = ("import resource, subprocess, sys, time\n"
            "t = time.perf_counter()\n"
            f"p = subprocess.run([sys.executable, '-m', 'scenarios.cli', 'import', {str(m)!r}, '-o', "
            f"{str(d / 'ms.mcap')!r}], capture_output=True, text=True)\n"
            "wall = time.perf_counter() - t\n"
            "rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024\n"
            "import json; print(json.dumps({'rc': p.returncode, 'err': p.stderr, 'wall': wall, 'rss_mb': rss}))\n")
    r = json.loads(subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                                  check=True).stdout)
    print(f"\nrefused in {r['wall']:.2f} s, peak RSS {r['rss_mb']:.0f} MB: {r['err']}")
    assert r["rc"] == 2 and r["err"].count("\n") == 1
    assert "imu.time: base = 'unix', unit = 's' gives a record that starts" in r["err"]
    assert "unit = 'ms' would give 120 s at 20 Hz" in r["err"]
    assert r["wall"] < 10.0 and r["rss_mb"] < 500.0
    assert not (d / "ms.mcap").exists()


def test_gps_seconds_of_week_as_unix_refused_naming_gps_week(rocket, capsys):
    d, fl = rocket
    g = fl.gps
    t_ns = T0 + np.round(g.t * 1e9).astype(np.int64)
    gps_ns = utc_to_gps_ns(t_ns)
    week, sow = np.divmod(gps_ns, 604_800 * 10**9)
    sub = d / "sow"
    sub.mkdir(exist_ok=True)
    (sub / "imu.csv").write_bytes((d / "imu.csv").read_bytes())
    import pyarrow.csv as pcsv
    tab = pcsv.read_csv(d / "gps.csv")
    write_csv(sub / "gps.csv", {**{c: tab.column(c) for c in tab.column_names}, "t": sow / 1e9})
    err = _refused(sub, mapping(sub, "sow.toml"), capsys, "gps.time: base = 'unix', unit = 's'",
                   f"base = 'gps_week', week = {int(week[0])}, unit = 's' would give 120 s at 10 Hz")
    assert "from 2019-06-13T02:21:00Z" in err
    # the suggested time table imports
    res = import_flight(mapping(sub, "fixed.toml", gps_base="gps_week", gps_week=f", week = {int(week[0])}"),
                        sub / "ok.mcap")
    assert not res.report.errors and np.array_equal(read_log(sub / "ok.mcap").gps.t_ns, t_ns)


def test_ned_velocity_declared_ecef_refused(rocket, plane, capsys):
    for d, _ in (rocket, plane):
        _refused(d, mapping(d, "ned_as_ecef.toml", vel_frame="ecef"), capsys, "gps gps_velocity:",
                 "likely cause: NED velocities declared as frame = 'ecef'")


def test_gps_time_offset_refused_naming_the_cause(rocket, plane, capsys):
    """GPS stamps shifted against the IMU's: by the 18 s of GPS - UTC in 2019 (GPS time read as UTC)
    and by half a second (a latency). The boost (rocket) and the turns (aircraft) fix the lag; the
    simulated sensors share one clock, so the correct flights give 0.00 s (test above)."""
    d, _ = rocket
    _refused(d, mapping(d, "leap.toml", gps_week=", offset_s = 18.0"), capsys, "gps time_lag:",
             "GPS stamps +18.00 s off the IMU's", "GPS time read as UTC or UTC as GPS time (GPS - UTC = 18 s",
             "offset_s = -18.000 in [gps.time] corrects it")
    for d, _ in (rocket, plane):
        _refused(d, mapping(d, "late.toml", gps_week=", offset_s = 0.5"), capsys, "gps time_lag:",
                 "GPS stamps +0.50 s off the IMU's", "a receiver latency or a clock offset")


def test_lat_lon_swapped_refused(rocket, plane, capsys):
    for d, _ in (rocket, plane):
        _refused(d, mapping(d, "swap.toml", latlon='"lon", "lat"'), capsys, "gps gps_velocity:",
                 "likely cause: latitude and longitude swapped")


def test_gyro_units_wrong_either_way_refused(plane, tmp_path, capsys):
    d, _ = plane
    # the table in rad/s declared deg/s: the attitude barely turns
    _refused(d, mapping(d, "rad_as_deg.toml", gyro_unit="deg/s"), capsys, "imu gyro_rotation:",
             "likely cause: the gyro is in rad/s but declared deg/s")
    # the table in deg/s declared rad/s: the attitude turns 57 times too fast
    import pyarrow.csv as pcsv
    tab = pcsv.read_csv(d / "imu.csv")
    cols = {c: tab.column(c).to_numpy() for c in tab.column_names}
    for c in ("gx", "gy", "gz"):
        cols[c] = np.degrees(cols[c])
    write_csv(tmp_path / "imu.csv", cols)
    (tmp_path / "gps.csv").write_bytes((d / "gps.csv").read_bytes())
    _refused(tmp_path, mapping(tmp_path, "deg_as_rad.toml", gyro_unit="rad/s"), capsys, "imu gyro_rotation:",
             "likely cause: the gyro is in deg/s but declared rad/s")
    assert not import_flight(mapping(tmp_path, "ok.toml", gyro_unit="deg/s"), tmp_path / "ok.mcap").report.errors


def test_sensor_axes_left_up_without_axes_refused(tmp_path, capsys):
    """An IMU mounted with sensor x left, y up, z forward: body x = sensor +z, y = -x, z = -y."""
    R_bs = np.array([[0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0]])
    plane_tables(tmp_path, sensor_R=R_bs)
    _refused(tmp_path, mapping(tmp_path, "no_axes.toml"), capsys, "imu body_axes:", "not +y",
             "likely cause: the sensor axes differ from the body axes: set [imu] axes")
    res = import_flight(mapping(tmp_path, "axes.toml", imu_extra='axes = ["+z", "-x", "-y"]\n'), tmp_path / "ok.mcap")
    assert not res.report.errors


# ------------------------------------------------------------------------------------------------
def _replay_error(d, log, fl, name, tuning=None, smoother=False):
    """Replay T+60..T+120 (the coast) from the true attitude at T+60, position and velocity from
    the GPS; the position error [m] at the end of the forward solution (and with ``smoother``, the
    RMS error of the smoothed solution from T+70 on: the first 10 s hold the start's transient)."""
    from scenarios.replay.pipeline import ReplayOptions, replay
    tr = fl.truth
    i = int(np.searchsorted(tr.t, 60.0))
    init = d / "init.toml"
    init.write_text(f'time = "T+60"\nq_eb = {list(map(float, tr.q_eb[i]))}\n')
    opt = ReplayOptions(t_from="T+60", t_to="T+120", init="given", init_file=str(init), workers=1, vision="auto",
                        smoother=smoother, output=str(d / f"{name}.solution.mcap"), rrd="", progress=False,
                        tuning=tuning)
    r = replay(log, opt)

    def error(t_ns, x):
        t = (t_ns - T0) / 1e9
        j = np.clip(np.searchsorted(tr.t, t - 1e-9), 0, tr.t.size - 1)
        assert np.all(np.abs(tr.t[j] - t) < 1e-6)
        return t, np.linalg.norm(x - tr.x_e[j], axis=1)
    t, err = error(r.nav.t_ns, r.nav.x_e)
    last = t > t[-1] - 30.0
    print(f"\n{name}: position error at the end {err[-1]:.3f} m, RMS over the last 30 s "
          f"{np.sqrt(np.mean(err[last] ** 2)):.3f} m, max {err.max():.3f} m")
    if not smoother:
        return float(err[-1]), r
    ts, es = error(r.smooth.t_ns, r.smooth.x_e)
    rms = float(np.sqrt(np.mean(es[ts >= 70.0] ** 2)))
    print(f"{name}: smoothed position error RMS from T+70 {rms:.3f} m")
    return float(err[-1]), r, rms


def test_position_only_gps_imports_and_replays(rocket):
    d, fl = rocket
    res = import_flight(mapping(d, "posonly.toml", vel_frame=None), d / "posonly.mcap")
    assert not res.report.errors
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no NaN warning: NaN velocity is "no measurement"
        log = read_log(d / "posonly.mcap")
    assert np.all(np.isnan(log.gps.velocity)) and np.all(np.isnan(log.gps.velocity_covariance))
    assert log.info["gps_velocity"] == "none"
    from scenarios.importer.export import export_log
    exp = export_log(d / "posonly.mcap", d / "posonly-export", images=False, video=False)
    import_flight(exp.files["mapping"], d / "posonly-again.mcap")
    again = read_log(d / "posonly-again.mcap").gps
    assert np.array_equal(again.position, log.gps.position) and np.all(np.isnan(again.velocity))
    import_flight(mapping(d, "posvel.toml"), d / "posvel.mcap")
    e_pv, _, s_pv = _replay_error(d, d / "posvel.mcap", fl, "posvel", smoother=True)
    e_po, r, s_po = _replay_error(d, d / "posonly.mcap", fl, "posonly", smoother=True)
    print(f"\nposition error at T+120 (forward): pos+vel {e_pv:.3f} m, position only {e_po:.3f} m; smoothed RMS "
          f"from T+70: pos+vel {s_pv:.3f} m, position only {s_po:.3f} m")
    kinds = {(i.kind, i.accepted) for i in r.nav.innovations}
    assert ("gps_vel", True) not in kinds and ("gps_vel", False) not in kinds
    acc = [i.accepted for i in r.nav.innovations if i.kind == "gps_pos"]
    assert np.mean(acc) > 0.95
    # The initial velocity of the position-only run is the fixes' slope over +-1 s, and the
    # filter starts with its sigma (1.08 m/s here: 21 fixes of 3 m), not the 0.1 m/s meant for a
    # measured velocity.
    assert r.nav.P_diag[0, 3:6] == pytest.approx([3.0 ** 2 / 7.7] * 3, rel=0.01)   # sum (t - mean t)^2 = 7.7 s^2
    # Bounds (3 m fixes at 10 Hz over the 60 s coast, 600 fixes): without velocities the positions
    # alone carry the solution, and the 2 mg accelerometer bias must come from their curvature:
    # the Cramer-Rao bound of a quadratic fit is 0.63 m (3D) at the end point and 0.37 m RMS over
    # the window, against 0.21 m for positions averaged with a perfectly known velocity. Measured
    # on this flight (seed 3): smoothed RMS 0.31 m against 0.20 m (1.5 x; over 8 seeds 0.39 m
    # against 0.22 m, 1.8 x), the post-flight product and within the acceptance's 2 x; the
    # forward end point 0.56 m against 0.25 m (2.2 x; over 8 seeds 0.65 m against 0.28 m, 2.3 x,
    # at its bound), which no filter brings to 2 x. Hence 2 x on the smoothed RMS and 2.5 x on the
    # forward end point.
    assert s_po <= 2.0 * s_pv and s_po < 0.5
    assert e_po < 1.0 and e_po <= 2.5 * e_pv


def test_gps_without_sigmas_takes_defaults_with_a_warning(rocket, capsys):
    d, fl = rocket
    m = mapping(d, "nosig.toml", sigmas=False)
    rc, out, err = _cli([m, "-o", d / "nosig.mcap"], capsys)
    assert rc == 0, err
    assert "WARNING  gps: uncertainties from defaults: sigma_pos_m = 5 m, sigma_vel_mps = 0.2 m/s" in out
    log = read_log(d / "nosig.mcap")
    assert np.allclose(log.gps.position_covariance, 25.0 * np.eye(3))
    assert np.allclose(log.gps.velocity_covariance, 0.04 * np.eye(3))
    # mapping keys and receiver classes
    m2 = mapping(d, "keys.toml", sigmas=False, gps_extra="sigma_pos_m = 3.0\nsigma_vel_mps = 0.1\n")
    g = import_flight(m2, d / "keys.mcap").prepared.gps
    assert np.allclose(g.position_cov, 9.0 * np.eye(3)) and "the mapping's sigma_pos_m" in g.sigma_default
    m3 = mapping(d, "rtk.toml", sigmas=False, gps_extra='receiver = "rtk"\n')
    assert np.allclose(load_mapping(m3).gps.position_cov.value, 0.05)
    import_flight(mapping(d, "posvel.toml"), d / "posvel.mcap")
    e_sig, _ = _replay_error(d, d / "posvel.mcap", fl, "sig")
    e_def, r = _replay_error(d, d / "nosig.mcap", fl, "nosig")
    print(f"\nposition error at T+120: sigma columns {e_sig:.3f} m, defaults {e_def:.3f} m")
    acc = [i.accepted for i in r.nav.innovations if i.kind.startswith("gps")]
    assert np.mean(acc) > 0.95
    assert e_def <= 1.5 * e_sig


def test_zero_sigma_cells_take_the_default(rocket, tmp_path):
    d, _ = rocket
    import pyarrow.csv as pcsv
    tab = pcsv.read_csv(d / "gps.csv")
    cols = {c: tab.column(c).to_numpy() for c in tab.column_names}
    cols["sig_p"] = cols["sig_p"].copy()
    cols["sig_p"][:10] = 0.0
    write_csv(tmp_path / "gps.csv", cols)
    (tmp_path / "imu.csv").write_bytes((d / "imu.csv").read_bytes())
    res = import_flight(mapping(tmp_path, "z.toml"), tmp_path / "z.mcap")
    P = res.prepared.gps.position_cov
    assert np.allclose(P[:10], 25.0 * np.eye(3)) and np.allclose(P[10:], 9.0 * np.eye(3))
    assert any(f.check == "sigma" and "10 fix(es)" in f.message for f in res.report.warnings)


# ------------------------------------------------------------------------------------------------
def test_imu_sample_key(rocket, tmp_path):
    d, _ = rocket
    assert read_log(d / "posvel.mcap").info["imu_sample"] == "average" if (d / "posvel.mcap").exists() else True
    m = mapping(d, "point.toml", imu_extra='imu_sample = "point"\n')
    import_flight(m, tmp_path / "p.mcap")
    assert read_log(tmp_path / "p.mcap").info["imu_sample"] == "point"
    from scenarios.replay.inputs import load_inputs
    assert load_inputs(tmp_path / "p.mcap").imu.sample == "point"
    import_flight(mapping(d, "interval.toml", imu_extra='imu_sample = "interval"\n'), tmp_path / "i.mcap")
    assert load_inputs(tmp_path / "i.mcap").imu.sample == "average"
    bad = mapping(d, "bad.toml", imu_extra='imu_sample = "instant"\n')
    with pytest.raises(UserError, match=r"imu_sample.*expected one of \['interval', 'point'\]"):
        load_mapping(bad)


def test_write_windows_are_bounded_by_the_data():
    """Stamps 50 years apart (what a wrong unit gave before the time checks): a handful of
    windows, not 157 million."""
    a = np.array([0, 10**9, 2 * 10**9], np.int64)
    b = np.array([50 * 365 * 86400 * 10**9], np.int64)
    edges = list(_windows(0, int(b[0]), 10.0, [a, b]))
    assert len(edges) <= 4 and edges[-1] == b[0] + 1
    # dense data: every 10 s window, as before
    t = np.arange(0, 100 * 10**9, 10**8, dtype=np.int64)
    assert list(_windows(0, int(t[-1]), 10.0, [t])) == list(range(10 * 10**9, 100 * 10**9, 10 * 10**9)) + [t[-1] + 1]


def test_validation_failure_is_one_line_and_force_still_writes(rocket, capsys):
    d, _ = rocket
    m = mapping(d, "ned_as_ecef.toml", vel_frame="ecef")
    with pytest.raises(ValidationFailed, match="gps_velocity"):
        import_flight(m, d / "x.mcap")
    res = import_flight(m, d / "x.mcap", force=True)
    assert res.report.errors and read_log(d / "x.mcap").complete


def test_camera_frames_outside_the_imu_record_refused(rocket, capsys):
    """Frames stamped with a start in the wrong unit (T+60 000 s, milliseconds declared as seconds)
    share no time with the IMU: refused naming the camera stream."""
    d, _ = rocket
    (d / "cam.toml").write_text("[camera]\nwidth = 64\nheight = 48\nfx = 40.0\nfy = 40.0\ncx = 31.5\n"
                                "cy = 23.5\nk = [1.0, 0.05]\n")
    (d / "frames").mkdir(exist_ok=True)
    import cv2
    cv2.imwrite(str(d / "frames" / "f0.jpg"), np.zeros((48, 64, 3), np.uint8))
    m = mapping(d, "cam-map.toml")
    text = m.read_text() + ('\n[[cameras]]\ncamera_file = "cam.toml"\nmount = { azimuth_deg = 90.0, '
                            'depression_deg = 20.0 }\n[cameras.footage]\nimages = "frames"\n'
                            'start_s = START\nrate_hz = 1.0\n')
    m.write_text(text.replace("START", "60000.0"))
    _refused(d, m, capsys, "camera_1 overlap: all 1 stamps lie outside the IMU record")
    m.write_text(text.replace("START", "60.0"))
    assert not import_flight(m, d / "cam.mcap").report.errors
