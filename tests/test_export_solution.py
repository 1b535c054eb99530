"""``horizon-nav export SOLUTION.mcap -o DIR`` (scenarios/importer/export.py, scenarios/replay/table.py,
docs/replay.md "Exporting a solution"): the forward and smoothed solutions, the free-inertial run
and the measurements as CSV and Parquet, checked against the filter's and smoother's arrays
(identity), pymap3d (geodetic and NED conversions) and the quaternion (Euler angles and their
sigmas); the smoothed topic carries the forward topic's states; the solution log reads back
without warnings; bad input is a one-line error.
"""
from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pymap3d
import pytest

from tests.import_flights import R_nb_zyx

from nav.rotation import quat_to_matrix, rotvec_to_matrix
from scenarios.cli import main
from scenarios.flightlog.reader import read_log

META = {"scenario": "test", "seed": "0", "liftoff_utc_ns": "1560392460000000000"}


@pytest.fixture(scope="module")
def exported(vlog, tmp_path_factory):
    """The vectors log (atek, truth-derived vectors: accel bias and two camera misalignments
    estimated) replayed T+60..T+100 with the smoother, then exported by the CLI."""
    from scenarios.replay.pipeline import ReplayOptions, replay
    d = tmp_path_factory.mktemp("export")
    sol = d / "v.solution.mcap"
    rr = replay(vlog, ReplayOptions(t_from="T+60", t_to="T+100", output=str(sol), rrd="", progress=False, workers=1))
    assert main(["export", str(sol), "-o", str(d / "out")]) == 0
    return rr, sol, d / "out"


def _tables(out, name):
    csv = pd.read_csv(out / f"{name}.csv")
    pq = pd.read_parquet(out / f"{name}.parquet")
    return csv, pq


def test_solution_log_reads_back_without_warnings(exported):
    """The free-inertial topic has no covariance (0x0), so reading our own log warns of nothing;
    /nav/smoothed carries the forward topic's state names and estimates."""
    rr, sol, _ = exported
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        log = read_log(sol)
    assert log.nav["ins_unaided"].covariance.shape[1:] == (0, 0)
    fwd, sm = log.nav["forward"], log.nav["smoothed"]
    assert fwd.state_names == sm.state_names
    assert {"accel_bias_x", "psi_c_1_x", "psi_c_2_z"} <= set(fwd.state_names)
    assert np.asarray(sm.state).shape == np.asarray(fwd.state).shape
    # the forward estimates at the last update epoch are the filter's final calibration and mounting
    j = fwd.state_names.index("accel_bias_x")
    np.testing.assert_array_equal(np.asarray(fwd.state)[-1, j:j + 3], rr.nav.calibration.b_f)
    k = fwd.state_names.index("psi_c_1_x")
    last = np.searchsorted(rr.nav.cov_t_ns, rr.nav.misalignment_t_ns[-1])
    np.testing.assert_allclose(np.asarray(fwd.state)[last, k:k + 3], rr.nav.misalignment[-1, 0], atol=1e-15)


def test_old_unaided_placeholder_reads_as_no_covariance(tmp_path):
    """Solution logs that carry the 1x1 NaN placeholder on /nav/ins_unaided read without a NaN
    warning, as an empty covariance."""
    from scenarios.flightlog.writer import LogWriter
    p = tmp_path / "old.solution.mcap"
    t = 1_560_392_460_000_000_000 + np.arange(3)
    with LogWriter(p, META | {"kind": "solution"}) as w:
        w.write_nav("/nav/ins_unaided", t, np.ones((3, 3)), np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (3, 1)),
                    np.full((3, 1), np.nan))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        log = read_log(p)
    assert log.nav["ins_unaided"].covariance.shape == (3, 0, 0)


def test_forward_and_smoothed_tables_match_the_arrays(exported):
    """CSV and Parquet hold the NavResult / SmoothResult values: the ECEF columns bit for bit
    (Arrow writes the shortest repr that reads back), the sigmas as the square roots of the
    variances, the estimated states as NavResult.estimates / SmoothResult.estimates; both tables
    have the same state columns."""
    rr, _, out = exported
    res, sm = rr.nav, rr.smooth
    ci = res.cov_idx
    for name, t, x, v, q, var, est in (
            ("forward", res.cov_t_ns, res.x_e[ci], res.v_e[ci], res.q_eb[ci], res.P_diag, res.estimates),
            ("smoothed", sm.t_ns, sm.x_e, sm.v_e, sm.q_eb, sm.P, sm.estimates)):
        csv, pq = _tables(out, name)
        for df in (csv, pq):
            np.testing.assert_array_equal(df["t_ns"], t)
            np.testing.assert_array_equal(df[["x", "y", "z"]], x)
            np.testing.assert_array_equal(df[["vx", "vy", "vz"]], v)
            np.testing.assert_array_equal(df[["qx", "qy", "qz", "qw"]], q)
            np.testing.assert_array_equal(df[["x_sd", "y_sd", "z_sd"]], np.sqrt(var[:, 0:3]))
            lay = res.layout
            for grp in ("accel_bias", "psi_c_0", "psi_c_1"):
                k = {"psi_c_0": "psi_c_1", "psi_c_1": "psi_c_2"}.get(grp, grp)
                cols = [f"{k}_{a}" for a in "xyz"]
                np.testing.assert_array_equal(df[cols], est[:, lay[grp]])
                np.testing.assert_array_equal(df[[c + "_sd" for c in cols]], np.sqrt(var[:, lay[grp]]))
        assert pq["time_utc"].dt.tz is not None
        np.testing.assert_array_equal(pq["time_utc"].astype("int64"), t)
        np.testing.assert_array_equal(pd.to_datetime(csv["time_utc"]).astype("int64"), t)
        liftoff = int(read_log(rr.solution_path).info["liftoff_utc_ns"])
        np.testing.assert_allclose(csv["t_plus_s"], (t - liftoff) / 1e9, rtol=0, atol=1e-9)
    f, s = _tables(out, "forward")[0], _tables(out, "smoothed")[0]
    assert list(f.columns) == list(s.columns)
    assert {"accel_bias_x", "accel_bias_x_sd", "psi_c_2_z", "psi_c_2_z_sd"} <= set(f.columns)


def test_to_frame_is_the_exported_table(exported):
    """Solution.to_frame and the export share one column builder: the same columns and values."""
    from scenarios.replay.table import forward_columns, solution_frame
    rr, _, out = exported
    df = solution_frame(forward_columns(rr.nav, rr.inputs.mission_time(rr.nav.cov_t_ns), rr.cam_numbers))
    pq = pd.read_parquet(out / "forward.parquet")
    assert list(pq.columns) == ["time_utc"] + list(df.columns)
    for c in df.columns:
        np.testing.assert_allclose(pq[c].to_numpy(float), df[c].to_numpy(float), rtol=0, atol=1e-12, err_msg=c)


def test_geodetic_ned_and_euler_columns(exported):
    """lat/lon/height and NED velocity against pymap3d; the quaternion has unit norm; roll, pitch
    and heading rebuild the quaternion's rotation; NED position and velocity sigmas are the ECEF
    blocks rotated (pymap3d's ecef2ned applied to the covariance's columns); the Euler sigmas match
    a finite-difference Jacobian of the angles."""
    rr, _, out = exported
    res = rr.nav
    df = pd.read_parquet(out / "forward.parquet")
    lat, lon, h = pymap3d.ecef2geodetic(df["x"], df["y"], df["z"])
    np.testing.assert_allclose(df["lat"], lat, atol=1e-9)     # 1e-9 deg ~ 0.1 mm
    np.testing.assert_allclose(df["lon"], lon, atol=1e-9)
    np.testing.assert_allclose(df["height"], h, atol=1e-4)
    vn, ve, vd = pymap3d.ecef2nedv(df["vx"], df["vy"], df["vz"], lat, lon)
    np.testing.assert_allclose(df[["VN", "VE", "VD"]], np.stack([vn, ve, vd], 1), atol=1e-9)
    q = df[["qx", "qy", "qz", "qw"]].to_numpy()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    r, p, y = (np.radians(df[c].to_numpy()) for c in ("roll", "pitch", "heading"))
    R_ne = np.stack([np.stack(pymap3d.ecef2nedv(*np.eye(3)[i], lat, lon), -1) for i in range(3)], -1)
    np.testing.assert_allclose(R_ne @ quat_to_matrix(q), R_nb_zyx(r, p, y), atol=1e-9)
    # NED sigmas: the 3x3 blocks rotated with pymap3d's rotation
    P = res.P_nav
    for b, cols in ((0, ["N_sd", "E_sd", "D_sd"]), (1, ["VN_sd", "VE_sd", "VD_sd"])):
        C = R_ne @ P[:, 3 * b:3 * b + 3, 3 * b:3 * b + 3] @ np.swapaxes(R_ne, -1, -2)
        np.testing.assert_allclose(df[cols], np.sqrt(np.einsum("kii->ki", C)), rtol=1e-9)
    # Euler sigmas: central differences of the angles under small rotations psi in e (conventions.md)
    k = len(df) // 2
    R_eb = quat_to_matrix(q[k])
    J = np.zeros((3, 3))
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1e-6
        a = [_euler(R_ne[k] @ rotvec_to_matrix(s * e) @ R_eb) for s in (1, -1)]
        dd = a[0] - a[1]
        dd[2] = (dd[2] + 180) % 360 - 180
        J[:, i] = np.radians(dd) / 2e-6
    C = J @ P[k, 6:9, 6:9] @ J.T
    np.testing.assert_allclose(df.loc[k, ["roll_sd", "pitch_sd", "heading_sd"]].to_numpy(float),
                               np.degrees(np.sqrt(np.diag(C))), rtol=1e-5)


def _euler(R_nb):
    from nav.rotation import euler_zyx_deg
    return np.array(euler_zyx_deg(R_nb), float)


def test_unaided_and_measurements_tables(exported):
    rr, _, out = exported
    res = rr.nav
    ins, _ = _tables(out, "ins_unaided")
    ci = res.cov_idx
    np.testing.assert_array_equal(ins[["x", "y", "z"]], res.unaided_x_e[ci])
    assert not any(c.endswith("_sd") for c in ins.columns)
    m, mp = _tables(out, "measurements")
    inn = res.innovations
    assert len(m) == len(inn) + len(res.triad_t_ns)
    g = m[m["source"] == "gps/position"]
    gi = [i for i in inn if i.kind == "gps_pos"]
    np.testing.assert_array_equal(g["t_ns"], [i.t_ns for i in gi])
    np.testing.assert_array_equal(g[["innovation_0", "innovation_1", "innovation_2"]], [i.s for i in gi])
    np.testing.assert_array_equal(g["nis"], [i.nis for i in gi])
    np.testing.assert_array_equal(g["used"], [i.accepted for i in gi])
    np.testing.assert_allclose(g["innovation_sd_0"], [np.sqrt(i.S[0, 0]) for i in gi], rtol=1e-15)
    assert set(mp["source"]) == set(m["source"])


def test_bad_input_is_one_line(tmp_path, capsys):
    """Not an MCAP, an MCAP that is neither a flight log nor a solution, a solution log without a
    solution (a replay interrupted before it): one error line, exit 2, no output folder."""
    from scenarios.flightlog.writer import LogWriter
    bad = tmp_path / "bad.mcap"
    bad.write_text("not an mcap\n")
    empty = tmp_path / "empty.mcap"
    with LogWriter(empty, META | {"kind": "real"}):
        pass
    cut = tmp_path / "cut.solution.mcap"
    with LogWriter(cut, META | {"kind": "solution"}):
        pass
    for p, pat in ((bad, "not an MCAP file"), (empty, "nothing to export"), (cut, "without /nav/forward")):
        assert main(["export", str(p), "-o", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(p) in err[0] and pat in err[0], err
        assert not (tmp_path / "out").exists()
