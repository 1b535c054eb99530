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
                 "/aided_minus_unaided/x", "/error/attitude/forward/x"):
        assert path in out, path
