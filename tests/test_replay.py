"""horizon-nav replay on short simulated logs: vectors without images, without truth, bad input,
SIGINT, solution round trip."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scenarios.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
EXE = [sys.executable, "-m", "scenarios.cli"]


def _copy_without(src, dst, drop):
    """Copy an MCAP log leaving out topics starting with any of ``drop``."""
    from mcap.reader import make_reader
    from mcap.writer import Writer
    with open(src, "rb") as f, open(dst, "wb") as g:
        r = make_reader(f)
        w = Writer(g)
        w.start(profile="ros2", library="test")
        summ = r.get_summary()
        for m in r.iter_metadata():
            w.add_metadata(m.name, m.metadata)
        sch, chn = {}, {}
        for s in summ.schemas.values():
            sch[s.id] = w.register_schema(s.name, s.encoding, s.data)
        for c in summ.channels.values():
            if not any(c.topic.startswith(d) for d in drop):
                chn[c.id] = w.register_channel(c.topic, c.message_encoding, sch[c.schema_id])
        for s, c, m in r.iter_messages():
            if c.id in chn:
                w.add_message(chn[c.id], m.log_time, m.data, m.publish_time)
        w.finish()


def _opt(**kw):
    from scenarios.replay.pipeline import ReplayOptions
    kw.setdefault("rrd", "")
    kw.setdefault("progress", False)
    return ReplayOptions(**kw)


def test_replay_vectors_log_and_round_trip(vlog, tmp_path):
    """Vectors-only log: every vector is offered, the attitude converges inside its 3 sigma, the
    solution MCAP round-trips (one /nav/measurements message per innovation + TRIAD) and
    `rerun mcap convert` opens it."""
    from scenarios.flightlog.reader import read_log
    from scenarios.replay.inputs import read_multi
    from scenarios.replay.pipeline import replay
    from scenarios.replay.summary import summarize
    out = tmp_path / "s.mcap"
    rr = replay(vlog, _opt(output=str(out)))
    s = summarize(rr)
    assert rr.vision_mode == "vectors" and rr.init_method == "triad"
    n_vec = sum(len(c.vectors["t_ns"]) for c in rr.inputs.cameras.values() if c.vectors is not None)
    assert sum(v["used"] + sum(v["rejected"].values()) for k, v in s["measurements"].items() if k.startswith("camera")) == n_vec
    assert s["truth"]["forward"]["att_final_inside_3sigma"]
    log = read_log(out)
    assert log.complete is True
    assert len(log.nav["forward"]) == len(rr.nav.cov_t_ns)
    np.testing.assert_allclose(log.nav["forward"].q_eb, rr.nav.q_eb[rr.nav.cov_idx])
    m = read_multi(out, "/nav/measurements")
    assert len(m["t_ns"]) == len(rr.nav.innovations) + len(rr.nav.triad_t_ns)
    rrd = tmp_path / "s_conv.rrd"
    r = subprocess.run([str(Path(sys.executable).parent / "rerun"), "mcap", "convert", str(out), "-o", str(rrd)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert rrd.stat().st_size > 0


def test_replay_without_truth(vlog, tmp_path):
    from scenarios.replay.pipeline import replay
    from scenarios.replay.summary import format_table, summarize
    p = tmp_path / "nt.mcap"
    _copy_without(vlog, p, ["/truth", "/camera_1/truth", "/camera_2/truth"])
    rr = replay(p, _opt(output=str(tmp_path / "nt.solution.mcap")))
    s = summarize(rr)
    assert "truth" not in s and rr.init_method == "triad"
    assert "errors against truth" not in format_table(s)
    # each camera's model and field of view from the log's CameraInfo (the ATEK fisheye: 94.40 deg)
    assert "camera_1: camera (fisheye, 1920x1080 px" in format_table(s)
    assert "FOV 94.40 deg horizontal" in s["cameras"]["camera_1"]


def test_bad_input(vlog, tmp_path):
    from scenarios.replay.pipeline import replay
    p = tmp_path / "noimu.mcap"
    _copy_without(vlog, p, ["/imu"])
    with pytest.raises(UserError, match="no IMU"):
        replay(p, _opt())
    p = tmp_path / "nogps.mcap"
    _copy_without(vlog, p, ["/gps"])
    with pytest.raises(UserError, match="no GPS"):
        replay(p, _opt())
    with pytest.raises(UserError, match="outside the log"):
        replay(vlog, _opt(t_from="T+1000", t_to="T+1100"))
    with pytest.raises(UserError, match="has no camera images"):
        replay(vlog, _opt(vision="images"))
    with pytest.raises(UserError, match="camera"):
        replay(vlog, _opt(cameras=[7]))


_SIGINT_CHILD = """
import os, signal, sys, time
import nav.navigator
def run(*a, **k):
    os.kill(os.getpid(), signal.SIGINT)   # a real Ctrl-C, delivered while the filter runs
    time.sleep(10)
    raise AssertionError("SIGINT not delivered")
nav.navigator.run = run
from scenarios.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_sigint_leaves_valid_partial_log(vlog, tmp_path):
    """SIGINT while the filter runs (the CLI process signals itself from inside the filter call, so
    the moment does not depend on the machine's speed): exit code 130, and the solution file is a
    valid MCAP marked incomplete, with the vectors given to the filter (docs/replay.md: what 'up to
    the interruption' contains). The Rerun recording, begun before the filter, is abandoned: neither
    the .rrd nor its temporary file remains."""
    from scenarios.flightlog.reader import read_log
    out = tmp_path / "int.solution.mcap"
    rrd = tmp_path / "int.rrd"
    proc = subprocess.run([sys.executable, "-c", _SIGINT_CHILD, "replay", str(vlog), "-o", str(out), "--rrd", str(rrd),
                           "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert sorted(p.name for p in tmp_path.iterdir() if "rrd" in p.name) == [], list(tmp_path.iterdir())
    assert proc.returncode == 130, proc.stderr
    assert "partial solution log written" in proc.stderr
    log = read_log(out)
    assert log.complete is False
    assert log.metadata["horizon-nav.status"]["reason"] == "KeyboardInterrupt during filter"
    assert any(t.endswith("/vectors") for t in log.topics)


def test_triad_epoch_at_window_start(vlog, tmp_path):
    """A frame with both vectors exactly at --from: TRIAD cannot be back-propagated over zero IMU
    intervals, so the next epoch is used; the navigation still starts at --from and every GPS fix
    passes the gate (a broken start would diverge and the gate would reject them)."""
    from scenarios.replay.pipeline import replay
    from scenarios.replay.summary import summarize
    rr = replay(vlog, _opt(t_from="T+70", t_to="T+100", output=str(tmp_path / "s.mcap"), smoother=False))
    assert rr.init_method == "triad"
    assert rr.inputs.mission_time(rr.nav.t_ns[0]) == pytest.approx(70.0)
    assert rr.inputs.mission_time(rr.triad_init.t_triad_ns) == pytest.approx(71.0)
    s = summarize(rr)
    for src in ("gps/position", "gps/velocity"):
        assert s["measurements"][src]["rejected"] == {}, s["measurements"][src]
