"""The notebook API (scenarios.read_flight, see, navigate, smooth): README's example runs on a short
simulated log and its figures agree with the log's truth within the filter's own sigma; the
functions write no file and leave the interpreter's global state as they found it; they give the
replay's results bit for bit; errors name the parameters."""
import gc
import importlib
import logging
import re
import signal
from pathlib import Path

import numpy as np
import pytest

from tests.import_flights import R_nb_zyx

from scenarios.errors import UserError
from tests.test_replay import _opt

ROOT = Path(__file__).resolve().parents[1]


def _readme_example() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("## From Python (notebook)", 1)[1].split("\n## ", 1)[0]
    return re.search(r"```python\n(.*?)```", section, re.DOTALL).group(1)


def _madvise_switch():
    mod = getattr(np, "_core", None) or getattr(np, "core", None)
    return getattr(getattr(mod, "multiarray", None), "_set_madvise_hugepage", None)


def _interpreter_state() -> dict:
    """What the API must not change: the garbage collector, numpy's huge-page switch and error
    settings, signal handlers, OpenCV's thread count and the loggers that exist now."""
    import cv2
    switch = _madvise_switch()
    madvise = None
    if switch is not None:
        madvise = switch(True)
        switch(madvise)
    loggers = {n: lg for n, lg in logging.root.manager.loggerDict.items() if isinstance(lg, logging.Logger)}
    return {"gc_frozen": gc.get_freeze_count(), "gc_enabled": gc.isenabled(), "gc_threshold": gc.get_threshold(),
            "madvise": madvise, "np_err": np.geterr(), "cv2_threads": cv2.getNumThreads(),
            "signals": {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGCHLD)},
            "root": (logging.root.level, tuple(logging.root.handlers)),
            "loggers": {n: (lg.level, lg.disabled, lg.propagate, tuple(lg.handlers)) for n, lg in loggers.items()}}


def _same_state(before: dict, after: dict) -> None:
    for key in before:
        if key != "loggers":
            assert after[key] == before[key], key
    for name, state in before["loggers"].items():
        assert after["loggers"][name] == state, name
    for name in set(after["loggers"]) - set(before["loggers"]):       # loggers of modules imported meanwhile
        assert after["loggers"][name][3] == () and after["loggers"][name][0] == logging.NOTSET, name


def _truth_match(truth, t_ns):
    j = np.searchsorted(truth.t_ns, t_ns)
    ok = j < truth.t_ns.size
    ok[ok] = truth.t_ns[j[ok]] == t_ns[ok]
    return j, ok


def test_readme_example(vlog, tmp_path, monkeypatch):
    """README's example on a short vectors log (the path substituted): the smoothed attitude and
    position agree with the truth within 3 times the forward filter's own 1-sigma (RMS over the
    aided phase), the frames have the documented columns, dtypes and one row per covariance
    epoch, no file appears in the working or the log's folder, and the interpreter's state is
    unchanged."""
    from scenarios.replay.summary import attitude_error
    from scenarios.replay.table import euler_zyx_deg
    from nav import earth
    from nav.rotation import quat_to_matrix
    code = _readme_example()
    assert '"logs/atek.mcap"' in code
    code = code.replace('"logs/atek.mcap"', repr(str(vlog)))
    monkeypatch.chdir(tmp_path)
    log_folder = sorted(p.name for p in Path(vlog).parent.iterdir())
    importlib.import_module("scenarios.replay.steps")     # its imports before the snapshot of the loggers
    before = _interpreter_state()
    ns: dict = {}
    exec(compile(code, "README.md", "exec"), ns)
    _same_state(before, _interpreter_state())
    assert list(tmp_path.iterdir()) == []
    assert sorted(p.name for p in Path(vlog).parent.iterdir()) == log_folder

    log, sight, sol, sm, df, fwd = (ns[k] for k in ("log", "sight", "sol", "sm", "df", "fwd"))
    assert sol.start.method == "triad" and sight.start is None and log.vision == "vectors"
    assert re.fullmatch(r"Flight\(v\.mcap: T\+60\.0 \.\. T\+140\.0 s, \d+ IMU samples, \d+ GPS fixes, cameras \[1, 2\], "
                        r"vectors from the log, truth\)", repr(log)), repr(log)
    assert re.fullmatch(r"Sight\(vectors, \d+ vectors \(earth \d+, sun \d+\)\)", repr(sight)), repr(sight)
    assert re.fullmatch(r"Solution\(forward, T\+60\.0 \.\. T\+140\.0 s, \d+ epochs, init triad, measurements: "
                        r"\d+ used, \d+ rejected\)", repr(sol)), repr(sol)
    assert repr(sm) == f"Smoothed(T+60.0 .. T+140.0 s, {len(sol.nav.cov_t_ns)} epochs, init triad)"
    cols = ["t_ns", "t_plus_s", "lat", "lon", "height", "x", "y", "z", "vx", "vy", "vz", "VN", "VE", "VD",
            "qx", "qy", "qz", "qw", "roll", "pitch", "heading", "x_sd", "y_sd", "z_sd", "pos_sd", "vx_sd", "vy_sd",
            "vz_sd", "vel_sd", "psi_x_sd", "psi_y_sd", "psi_z_sd", "att_sd", "N_sd", "E_sd", "D_sd", "VN_sd",
            "VE_sd", "VD_sd", "roll_sd", "pitch_sd", "heading_sd"]
    # the estimated states of the default tuning with two cameras: accelerometer bias and the
    # cameras' misalignments, each with its 1-sigma
    cols += [f"{g}_{a}{sd}" for g in ("accel_bias", "psi_c_1", "psi_c_2") for a in "xyz" for sd in ("", "_sd")]
    for f in (df, fwd):
        assert list(f.columns) == cols
        assert len(f) == len(sol.nav.cov_t_ns) and f.index.name == "time" and str(f.index.tz) == "UTC"
        assert f["t_ns"].dtype == np.int64 and all(f[c].dtype == np.float64 for c in cols[1:])
        np.testing.assert_array_equal(f.index.asi8, f["t_ns"].to_numpy())
        assert np.all(np.isfinite(f[cols[1:]].to_numpy()))
    np.testing.assert_array_equal(fwd["t_ns"].to_numpy(), sol.nav.cov_t_ns)
    assert fwd["t_plus_s"].iloc[0] == pytest.approx(60.0) and fwd["t_plus_s"].iloc[-1] == pytest.approx(140.0)

    truth = log.truth
    t = df["t_ns"].to_numpy()
    j, ok = _truth_match(truth, t)
    assert ok.all()
    aided = t >= min(i.t_ns for i in sol.nav.innovations if i.kind in ("hor", "sun"))
    att = np.degrees(np.linalg.norm(attitude_error(sm.result.q_eb, truth.q_eb[j]), axis=1))
    att_rms, att_bound = np.sqrt(np.mean(att[aided] ** 2)), 3 * np.sqrt(np.mean(fwd["att_sd"].to_numpy()[aided] ** 2))
    assert att_rms < att_bound, (att_rms, att_bound)
    dpos = np.linalg.norm(df[["x", "y", "z"]].to_numpy() - truth.x_e[j], axis=1)
    pos_rms, pos_bound = np.sqrt(np.mean(dpos ** 2)), 3 * np.sqrt(np.mean(fwd["pos_sd"].to_numpy() ** 2))
    assert pos_rms < pos_bound, (pos_rms, pos_bound)
    # the geodetic and NED columns are the ECEF ones seen from the ellipsoid
    lat, lon, h = earth.ecef_to_geodetic(truth.x_e[j])
    assert np.max(np.abs(df["height"].to_numpy() - h)) < 5 * pos_bound
    assert np.max(np.abs(np.radians(df["lat"].to_numpy()) - lat)) * earth.A < 5 * pos_bound
    R_ne = np.swapaxes(earth.R_en(np.radians(df["lat"]), np.radians(df["lon"])), -1, -2)
    np.testing.assert_allclose(df[["VN", "VE", "VD"]].to_numpy(),
                               np.einsum("kij,kj->ki", R_ne, df[["vx", "vy", "vz"]].to_numpy()), atol=1e-9)
    r, p, y = np.radians(df["roll"]), np.radians(df["pitch"]), np.radians(df["heading"])
    np.testing.assert_allclose(R_nb_zyx(r, p, y), R_ne @ quat_to_matrix(sm.result.q_eb), atol=1e-9)
    assert np.all((df["heading"] >= 0) & (df["heading"] < 360))
    assert euler_zyx_deg(np.eye(3)) == (0.0, -0.0, 0.0)


def _assert_same_nav(a, b):
    for name in ("t_ns", "x_e", "v_e", "q_eb", "cov_t_ns", "P_diag", "P_full", "unaided_q_eb", "triad_q_eb",
                 "misalignment"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_api_gives_the_replays_results(vlog, tmp_path):
    """navigate + smooth on the same window and options give the replay's arrays bit for bit, and
    the replay, which freezes the garbage collector's generations for its run, unfreezes them."""
    from scenarios import navigate, read_flight, smooth
    from scenarios.replay.pipeline import replay
    frozen = gc.get_freeze_count()
    rr = replay(vlog, _opt(t_from="T+70", t_to="T+120", output=str(tmp_path / "s.mcap")))
    assert gc.get_freeze_count() == frozen
    log = read_flight(vlog, t_from="T+70", t_to="T+120")
    sol = navigate(log)
    sm = smooth(sol)
    _assert_same_nav(sol.nav, rr.nav)
    for name in ("t_ns", "x_e", "v_e", "q_eb", "P"):
        np.testing.assert_array_equal(getattr(sm.result, name), getattr(rr.smooth, name), err_msg=name)
    assert sol.start.method == rr.init_method and sol.notes == rr.messages
    np.testing.assert_array_equal(sol.vectors.e_c, rr.vectors.e_c)


def test_images_api_gives_the_replays_results(ilog, tmp_path):
    """On an image log: see() (TRIAD search, attitude priors, every frame) and navigate() give the
    replay's vectors and solution bit for bit; navigate without vectors runs see itself; the
    interpreter's state is unchanged (OpenCV's thread count included)."""
    from scenarios import navigate, read_flight, see
    from scenarios.replay.pipeline import replay
    rr = replay(ilog, _opt(output=str(tmp_path / "i.solution.mcap"), workers=2, smoother=False))
    log = read_flight(ilog)
    before = _interpreter_state()
    sight = see(log, workers=2)
    _same_state(before, _interpreter_state())
    assert repr(sight) == f"Sight(images: 10 frames, {len(rr.vectors.t_ns)} vectors (earth {sum(rr.vectors.target == 'hor')}, " \
                          f"sun {sum(rr.vectors.target == 'sun')}), start {rr.init_method})"
    np.testing.assert_array_equal(sight.vectors.e_c, rr.vectors.e_c)
    np.testing.assert_array_equal(sight.vectors.t_ns, rr.vectors.t_ns)
    sol = navigate(log, vectors=sight, smoother=False)
    _assert_same_nav(sol.nav, rr.nav)
    assert len(sol.notes) == len(rr.messages)      # the same notes, worded for Python
    again = navigate(log, init="truth", workers=1, smoother=False)       # see() inside, with the truth as prior
    assert again.start.method == "truth" and len(again.frames) == 10
    assert list(tmp_path.iterdir()) == [tmp_path / "i.solution.mcap"]


def test_errors_name_the_parameters(vlog, tmp_path):
    """The functions' errors name their parameters (the command line's name its flags)."""
    from nav.navigator import InitialState
    from scenarios import navigate, read_flight, see, smooth
    with pytest.raises(UserError, match=r"^t_from/t_to: the window lies outside the log"):
        read_flight(vlog, t_from="T+1000", t_to="T+1100")
    with pytest.raises(UserError, match=r"^t_from T\+x: expected T\+<seconds>"):
        read_flight(vlog, t_from="T+x")
    with pytest.raises(UserError, match=r"^cameras: camera\(s\) \[7\] not in"):
        read_flight(vlog, cameras=[7])
    with pytest.raises(UserError, match=r"^vision='images': .* has no camera images; it has vectors: use vision='vectors'"):
        read_flight(vlog, vision="images")
    log = read_flight(vlog, t_from="T+70", t_to="T+80")
    with pytest.raises(UserError, match=r"^targets mars: expected earth, sun or moon"):
        see(log, targets=("earth", "mars"))
    with pytest.raises(UserError, match=r"^init: expected 'auto', 'truth', 'triad', 'align', a state file or an InitialState"):
        navigate(log, init=3)
    missing = tmp_path / "none.toml"
    with pytest.raises(UserError, match=r"^init .*none\.toml: state file not found"):
        navigate(log, init=missing)
    with pytest.raises(UserError, match=r"tuning file"):
        navigate(log, tuning=missing)
    sol = navigate(log, init="truth", smoother=False)
    assert sol.start.method == "truth"
    with pytest.raises(UserError, match=r"^solution: made without the smoother's store"):
        smooth(sol)
    # a given state: the truth's, as an InitialState and as a state file, gives the truth start's solution
    s0 = sol.start.state
    given = navigate(log, init=InitialState(s0.t_ns, s0.x_e, s0.v_e, s0.q_eb), smoother=False)
    f = tmp_path / "state.toml"
    f.write_text(f"q_eb = {s0.q_eb.tolist()}\nposition_e = {s0.x_e.tolist()}\nvelocity_e = {s0.v_e.tolist()}\n")
    from_file = navigate(log, init=f, smoother=False)
    assert given.start.method == from_file.start.method == "given"
    _assert_same_nav(given.nav, sol.nav)
    _assert_same_nav(from_file.nav, sol.nav)
