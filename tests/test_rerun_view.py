"""The Rerun recording loads with the pinned Rerun (0.41) reader: `rerun rrd verify` passes and
`rerun rrd print` lists the entity paths of the view."""
import subprocess
import sys
from pathlib import Path

from tests.test_replay import _opt

RERUN = str(Path(sys.executable).parent / "rerun")


def test_recording_reads_back(vlog, tmp_path):
    from scenarios.replay.pipeline import replay
    rrd = tmp_path / "v.rrd"
    rr = replay(vlog, _opt(output=str(tmp_path / "v.solution.mcap"), rrd=str(rrd)))
    assert rr.rrd_path == rrd and rrd.is_file()
    v = subprocess.run([RERUN, "rrd", "verify", str(rrd)], capture_output=True, text=True)
    assert v.returncode == 0, v.stderr
    out = subprocess.run([RERUN, "rrd", "print", str(rrd)], capture_output=True, text=True).stdout
    for path in ("/world/earth", "/world/trajectory", "/world/vehicle/aided", "/world/vehicle/unaided",
                 "/world/vehicle/att_3sigma", "/world/vehicle/camera_1/earth", "/world/vehicle/sun",
                 "/innovation/camera_1/earth/0", "/misalignment/camera_1/x", "/attitude_3sigma/forward/x",
                 "/aided_minus_unaided/x", "/error/attitude/forward/x", "/gps_innovation/position/0",
                 "/angle_residual/aided/camera_1/earth", "/angle_residual/unaided/camera_1/earth",
                 "/triad_minus_solution/x", "/triad_minus_unaided/x"):
        assert path in out, path


def test_recording_in_this_process_without_fork(vlog, tmp_path, monkeypatch):
    """Where ``fork`` is unavailable the recording is drawn in the replay's process, synchronously:
    the same recording (the entity paths of both, `rerun rrd print`)."""
    import multiprocessing as mp
    from scenarios.replay.pipeline import replay
    a, b = tmp_path / "fork.rrd", tmp_path / "local.rrd"
    replay(vlog, _opt(output=str(tmp_path / "a.solution.mcap"), rrd=str(a)))
    monkeypatch.setattr(mp, "get_all_start_methods", lambda: ["spawn"])
    rr = replay(vlog, _opt(output=str(tmp_path / "b.solution.mcap"), rrd=str(b)))
    assert rr.rrd_path == b and b.is_file() and rr.rerun_timings.get("flush") is not None

    def paths(f):
        out = subprocess.run([RERUN, "rrd", "print", str(f)], capture_output=True, text=True).stdout
        got = {ln.split(" - ")[1] for ln in out.splitlines() if ln.startswith("Chunk(") and " - /" in ln}
        return {p for p in got if not p.startswith(("/view/", "/container/"))}   # the blueprint's ids are random
    assert paths(a) == paths(b) and "/world/trajectory" in paths(b)


def test_unwritable_recording_is_a_clear_error(vlog, tmp_path):
    """An --rrd path that cannot be written (its folder is a file): a UserError naming the path,
    before anything is computed (no solution file left, no recording process started)."""
    import multiprocessing as mp
    import pytest
    from scenarios.errors import UserError
    from scenarios.replay.pipeline import replay
    (tmp_path / "afile").write_text("x")
    out = tmp_path / "u.solution.mcap"
    with pytest.raises(UserError, match=r"rrd = .*afile.*cannot be written"):
        replay(vlog, _opt(output=str(out), rrd=str(tmp_path / "afile" / "u.rrd")))
    assert not out.exists()
    assert not [p for p in mp.active_children() if p.name == "horizon-nav-rerun"]


def test_recording_failure_is_raised_and_the_solution_kept(vlog, tmp_path, monkeypatch):
    """The recording process fails while drawing the smoother's time series (while the solution
    log is being written): the replay raises its error with the process's traceback, the solution log is
    complete, and neither the .rrd nor its temporary file remains."""
    import pytest
    from scenarios.flightlog.reader import read_log
    from scenarios.replay import rerun_view
    from scenarios.replay.pipeline import replay
    from scenarios.replay.recording_process import RecordingError

    def broken(*a, **k):
        raise ZeroDivisionError("drawing failed")
    monkeypatch.setattr(rerun_view, "_smoothed_timeseries", broken)     # inherited by the forked process
    out = tmp_path / "f.solution.mcap"
    with pytest.raises(RecordingError, match=r"ZeroDivisionError: drawing failed(.|\n)*_smoothed_timeseries"):
        replay(vlog, _opt(output=str(out), rrd=str(tmp_path / "f.rrd")))
    assert read_log(out).complete is True
    assert not [p for p in tmp_path.iterdir() if "rrd" in p.name]


def test_drawn_result_keeps_the_accepted_innovations(vlog, tmp_path):
    """What the recording process receives of the filter's result: every accepted innovation with
    its time, kind, camera, innovation and covariance, bit for bit, after a pickle round trip;
    none of the rejected ones; no full covariances."""
    import pickle

    import numpy as np
    from scenarios.replay.pipeline import replay
    from scenarios.replay.recording_process import drawn_result
    rr = replay(vlog, _opt(output=str(tmp_path / "d.solution.mcap")))
    got = pickle.loads(pickle.dumps(drawn_result(rr.nav)))
    want = [i for i in rr.nav.innovations if i.accepted]
    rows = list(got.innovations)
    assert len(rows) == len(want) > 0 and len(want) < len(rr.nav.innovations) + 1
    assert {i.kind for i in want} >= {"gps_pos", "gps_vel", "hor"}
    for a, b in zip(want, rows):
        assert (a.t_ns, a.kind, a.camera, True) == (b.t_ns, b.kind, b.camera, b.accepted)
        np.testing.assert_array_equal(np.ravel(a.s), b.s)
        np.testing.assert_array_equal(np.asarray(a.S), b.S)
    assert got.P_full.size == 0 and got.store is None


def test_unaided_angle_residual_matches_free_inertial_prediction(vlog, tmp_path):
    """fig. 42 a: the angle between a measured Earth vector and the one predicted with the
    free-inertial attitude equals the angle recomputed here from the geocentric nadir (003 eq.
    (39)) rotated into the camera frame with that attitude and the nominal mount."""
    import numpy as np
    from nav.rotation import quat_to_matrix
    from scenarios.replay.pipeline import replay
    from scenarios.replay.rerun_view import _predicted_c
    rr = replay(vlog, _opt(output=str(tmp_path / "u.solution.mcap"), smoother=False))
    v, res = rr.vectors, rr.nav
    n = int(np.flatnonzero(v.target == "hor")[5])
    j = int(np.searchsorted(res.t_ns, v.t_ns[n]))
    x = res.x_e[j]
    d_e = -x / np.linalg.norm(x)
    R_bc = rr.inputs.cameras[rr.cam_numbers[int(v.camera[n])]].R_bc
    want = R_bc.T @ quat_to_matrix(res.unaided_q_eb[j]).T @ d_e
    got = _predicted_c(rr.inputs, res.unaided_q_eb[j:j + 1], res.x_e[j:j + 1], res.t_ns[j:j + 1], "hor", R_bc)[0]
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_recording_process_preloads_what_drawing_imports(tmp_path):
    """The recording process imports its modules (recording_process.PRELOADED) while the replay
    reads the log: after them, opening a recording with the blueprint and drawing points, strips
    and scalars imports no further package (pyarrow's lazy pandas import on the first list
    conversion cost 0.25-0.35 s inside rerun_view.begin, while the vision workers ran). In a fresh
    interpreter, so that nothing imported earlier hides an import."""
    code = f"""
import importlib, sys
import numpy as np
from scenarios.replay.recording_process import PRELOADED
from scenarios.replay import rerun_view
for name in PRELOADED:
    importlib.import_module(name)
import rerun as rr
before = {{m.split(".")[0] for m in sys.modules}}
rec = rr.RecordingStream("t", recording_id="t")
rec.save({str(tmp_path / "p.rrd")!r}, default_blueprint=rerun_view.blueprint([1, 2], np.array([[7e6, 0, 0], [7.1e6, 1e4, 0]])))
rec.log("a", rr.Points2D([[1.0, 2.0]], colors=[[1, 2, 3]], radii=[1.0]))
rec.log("b", rr.LineStrips2D([[[0.0, 0.0], [1.0, 1.0]]], colors=[[1, 2, 3]]))
rec.send_columns("c", indexes=[rr.TimeColumn("t", duration=[1.0, 2.0])], columns=rr.Scalars.columns(scalars=[1.0, 2.0]))
rec.flush()
print(sorted({{m.split(".")[0] for m in sys.modules}} - before))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=Path(__file__).parents[1])
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


def test_recording_moved_into_place_over_an_old_one(tmp_path):
    """The finished recording replaces a file of the same name (renamed aside, then deleted: no
    ``.old`` left) or takes a free name; the content is the new file's."""
    from scenarios.atomic import move_into_place
    path = tmp_path / "r.rrd"
    path.write_bytes(b"old recording")
    (tmp_path / ".r.rrd.tmp").write_bytes(b"new recording")
    move_into_place(tmp_path / ".r.rrd.tmp", path)
    assert path.read_bytes() == b"new recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.rrd"]
    (tmp_path / ".s.rrd.tmp").write_bytes(b"first")
    move_into_place(tmp_path / ".s.rrd.tmp", tmp_path / "s.rrd")
    assert (tmp_path / "s.rrd").read_bytes() == b"first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.rrd", "s.rrd"]


def test_recoveries_are_events_at_their_times(tmp_path):
    """The filter's recoveries as Rerun text-log warnings on /events, at their mission times, in
    the verdict's words (`verdict.recovery_text`): a re-opened camera by its log name, a GPS
    re-initialisation with its cause and jump. Read back with `rerun rrd print -vvv`."""
    from types import SimpleNamespace

    import numpy as np
    import rerun as rr
    from scenarios.replay import rerun_view as RV
    t0 = 10 ** 18
    rec = rr.RecordingStream("t", recording_id="t")
    rec.save(str(tmp_path / "e.rrd"))
    inp = SimpleNamespace(mission_time=lambda t: (np.asarray(t, np.int64) - t0) / 1e9)
    res = SimpleNamespace(recoveries=[
        (t0 + 84 * 10 ** 9, "camera_gated", {"camera": 1, "gated_vectors": 20, "sigma_added_deg": 1.0}),
        (t0 + 121 * 10 ** 9, "imu_gap", {"gap_s": 20.05, "position_jump_m": 3.21, "velocity_jump_m_s": 0.1})])
    RV._events(rec, rr, inp, res, [1, 3])
    rec.flush()
    out = subprocess.run([RERUN, "rrd", "print", "-vvv", str(tmp_path / "e.rrd")], capture_output=True, text=True).stdout
    rows = [ln for ln in out.splitlines() if "[WARN]" in ln]
    assert len(rows) == 2
    assert "PT84S" in rows[0] and "[camera_3: misalignment re-opened after 20 of its vectors in a row were gated]" in rows[0]
    assert "PT121S" in rows[1] and "re-initialised from GPS (imu_gap: 20.1 s IMU gap; position moved 3.2 m)" in rows[1]
