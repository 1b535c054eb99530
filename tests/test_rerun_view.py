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
