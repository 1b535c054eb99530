"""Observability report (scenarios/study/observability.py, ``horizon-nav tune --report``): the
prior propagation against its identities, and the flags against what a simulated flight can and
cannot observe (truth-derived vectors, no images)."""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from nav.navigator import VectorData, run
from nav.smoother import rts_smooth
from nav.tuning import StateGroupTuning
from scenarios.study.observability import observability, prior_variances, variance_reduction, write_report
from scenarios.study.tune import TuneInputs
from tests.test_navigator import flight_inputs, matched_tuning, truth_init


@pytest.fixture(scope="module")
def short():
    """atek T+60..T+100 with its GPS and the vectors of camera 0 only (camera 1 sees nothing)."""
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    fl = simulate_flight(load_scenario("atek"), seed=7, duration=100.0)
    fi = flight_inputs(fl, 60.0, seed=3)
    v = fi.vectors
    keep = v.camera == 0
    vec = VectorData(v.t_ns[keep], v.camera[keep], v.target[keep], v.e_c[keep], v.P_c[keep])
    return fi, TuneInputs(fi.imu, truth_init(fi), fi.gps, vec, fi.R_bc_nominal)


def base():
    """Table 3 (matched noises) with the gyro scale factors estimated, so that the report can
    flag them."""
    return matched_tuning().with_(gyro_scale=StateGroupTuning("E", 2e-3))


@pytest.fixture(scope="module")
def report(short):
    return observability(short[1], base())


def test_prior_without_updates_is_the_filters_propagation(short):
    """Identity: in a run without measurements the propagation without updates is the filter's own
    prior covariance (to rounding, 1e-9 relative), whose constant states keep sigma0^2."""
    fi, inp = short
    res = run(inp.imu, inp.init, base(), R_bc=inp.R_bc, store_for_smoother=True, unaided=False)
    P0 = prior_variances(res.store, res.P_full)
    ref = np.einsum("kii->ki", res.store.P_prior)
    assert np.allclose(P0, ref, rtol=1e-9, atol=0.0)


def test_reduction_from_the_arrays(report, short):
    """The report's numbers are 1 - (time average of P_smoothed / P_prior): for a constant state
    P_prior is its tuning variance sigma0^2 at every epoch (1e-12 relative: the process noise
    read back is zero there), and the reduction computed directly from the smoother's variances
    (an independent run of nav.smoother.rts_smooth) and sigma0^2 matches to 1e-9."""
    fi, inp = short
    from scenarios.study.tune import estimated_everywhere
    res = run(inp.imu, inp.init, estimated_everywhere(base()), gps=inp.gps, vectors=inp.vectors, R_bc=inp.R_bc,
              store_for_smoother=True, unaided=False)
    sm = rts_smooth(res)
    t = (sm.t_ns - sm.t_ns[0]) / 1e9
    for g in res.layout.groups:
        if g.name.startswith(("accel_", "gyro_", "psi_c_")):
            i, var0 = g.slice, np.asarray(g.sigma0, float) ** 2   # sigma0: one value or one per axis
            assert np.allclose(report.P_prior[:, i], var0, rtol=1e-12, atol=0.0), g.name
            direct = 1.0 - np.trapezoid(sm.P[:, i] / var0, t, axis=0) / (t[-1] - t[0])
            assert np.allclose(report.reduction[i], direct, rtol=0.0, atol=1e-9), g.name
    assert np.allclose(variance_reduction(t, sm.P, report.P_prior), report.reduction, atol=1e-12)


def test_flags_against_what_the_flight_observes(report, short, tmp_path):
    """Camera 1 has no vector: no measurement involves its misalignment, so the smoother cannot
    reduce it (reduction 0 to 1e-9) and it is flagged for consideration. The gyro scale factor of
    the axis the vehicle barely rotates about (body rate RMS below 0.5 deg/s on the coast, so
    s_w w is below 0.5 deg/s * 2000 ppm = 3.6 deg/h, under the gyro bias it competes with) is
    flagged, that of the axis it turns about (RMS above 0.8 deg/s) is not; the attitude errors about e's x and y axes, the accelerometer bias (with GPS) and camera 0's
    misalignment are strongly observed (reduction > 0.5) and not flagged. The written CSV reads
    back with the same numbers."""
    fi, _ = short
    names = report.names
    r = dict(zip(names, report.reduction))
    flag = {n: report.flag(i) for i, n in enumerate(names)}
    print(report.summary())
    for ax in "xyz":
        assert abs(r[f"psi_c_1_{ax}"]) < 1e-9 and flag[f"psi_c_1_{ax}"] == "consider"
        assert r[f"accel_bias_{ax}"] > 0.5 and flag[f"accel_bias_{ax}"] == ""
        assert r[f"psi_c_0_{ax}"] > 0.5 and flag[f"psi_c_0_{ax}"] == ""
    assert r["psi_x"] > 0.5 and r["psi_y"] > 0.5
    w = fi.imu.w_b[fi.start_idx:]
    rms = np.degrees(np.sqrt(np.mean(w ** 2, axis=0)))
    print("body rate RMS deg/s", rms, {f"gyro_scale_{a}": r[f"gyro_scale_{a}"] for a in "xyz"})
    still = [a for a, v in zip("xyz", rms) if v < 0.5]
    assert still, rms
    for a in still:
        assert flag[f"gyro_scale_{a}"] == "consider", (a, r[f"gyro_scale_{a}"])
    for a in [a for a, v in zip("xyz", rms) if v > 0.8]:   # the axis it turns about: observed
        assert flag[f"gyro_scale_{a}"] == "", (a, r[f"gyro_scale_{a}"])
    paths = write_report(report, tmp_path / "rep")
    assert {p.suffix for p in paths} == {".csv", ".png", ".html"}
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in paths if p.suffix == ".png")
    rows = list(csv.DictReader(open(tmp_path / "rep" / "observability.csv")))
    assert [x["state"] for x in rows] == names
    assert all(math.isclose(float(x["reduction"]), r[x["state"]], rel_tol=1e-5, abs_tol=1e-9) for x in rows)


def test_cli_report_only(vlog, tmp_path, capsys):
    """``horizon-nav tune LOG --report DIR --report-only``: no optimisation, no tuning file; the
    table, the HTML and one PNG per state group are written, and the summary is printed. Missing
    or contradictory options give a one-line error (exit 2)."""
    from scenarios.cli._main import main
    d = tmp_path / "obs"
    rc = main(["tune", str(vlog), "--from", "T+60", "--to", "T+100", "--quiet", "--report", str(d), "--report-only"])
    text = capsys.readouterr().out
    print(text)
    assert rc == 0 and "observability:" in text and "filter runs" not in text
    rows = list(csv.DictReader(open(d / "observability.csv")))
    groups = {x["group"] for x in rows}
    assert {"dx", "dv", "psi", "psi_c_0", "psi_c_1"} <= groups
    assert all((d / f"sigma_{g}.png").stat().st_size > 0 for g in groups)
    assert "<table>" in (d / "observability.html").read_text()
    assert all(0.0 <= float(x["reduction"]) <= 1.0 + 1e-9 for x in rows)
    assert main(["tune", str(vlog), "--report-only", "--quiet"]) == 2
    assert main(["tune", str(vlog), "--quiet"]) == 2
    assert main(["tune", str(vlog), "--report", str(d), "--report-only", "--report-low", "0.6", "--quiet"]) == 2


def test_cli_report_after_tuning(vlog, tmp_path, capsys):
    """``tune -o FILE --report DIR``: the tuning file and the report are both written; the report's
    E/C column is the tuning's own choice (003 table 3 considers the IMU scale factors)."""
    from scenarios.cli._main import main
    d, out = tmp_path / "obs", tmp_path / "t.toml"
    rc = main(["tune", str(vlog), "--from", "T+60", "--to", "T+100", "--quiet", "--params", "gps_noise_scale",
               "--max-iter", "2", "-o", str(out), "--report", str(d), "-j", "0"])
    text = capsys.readouterr().out
    assert rc == 0 and out.exists() and "gps_noise_scale" in text and "observability:" in text
    rows = {x["state"]: x for x in csv.DictReader(open(d / "observability.csv"))}
    assert rows["gyro_scale_x"]["mode"] == "C" and rows["psi_c_0_x"]["mode"] == "E"
