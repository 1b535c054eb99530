"""Reader cases the replay depends on: several messages at one stamp where the schema allows it,
and empty covariances."""
import warnings

import numpy as np

from scenarios.flightlog.reader import read_log
from scenarios.flightlog.writer import LogWriter

T0 = 1_560_392_460_000_000_000
META = {"scenario": "", "seed": 0, "liftoff_utc_ns": T0, "kind": "simulated"}


def test_vectors_and_measurements_share_stamps(tmp_path):
    p = tmp_path / "multi.mcap"
    t = T0 + np.array([0, 0, 10**9, 10**9])
    e = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0]])
    P = np.broadcast_to(np.eye(3) * 1e-6, (4, 3, 3))
    with LogWriter(p, META) as w:
        w.write_vectors(1, t, ["earth", "sun", "earth", "sun"], e, P)
        w.write_measurement(t, ["gps", "camera_1/earth", "gps", "camera_1/sun"], [True] * 4, [""] * 4,
                            np.zeros((4, 2)), np.zeros((4, 4)), np.ones(4))
        # a sensor stream must not have duplicates: the second IMU sample at T0 is dropped
        w.write_imu(T0 + np.array([0, 0, 5]), np.zeros((3, 3)), np.zeros((3, 3)))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = read_log(p)
    v = log.cameras[1].vectors
    # every message is kept; the order within one stamp carries no meaning
    got = sorted(zip(v.t_ns.tolist(), v.target, map(tuple, v.vector)))
    assert got == sorted(zip(t.tolist(), ["earth", "sun", "earth", "sun"], map(tuple, e)))
    m = log.measurements
    assert sorted(zip(m.t_ns.tolist(), m.source)) == sorted(
        zip(t.tolist(), ["gps", "camera_1/earth", "gps", "camera_1/sun"]))
    assert len(log.imu.t_ns) == 2
    msgs = [str(c.message) for c in caught]
    assert any("/imu" in m and "duplicate" in m for m in msgs)
    assert not any(("/camera_1/vectors" in m or "/nav/measurements" in m) and "duplicate" in m for m in msgs)


def test_nav_solution_with_empty_covariance(tmp_path):
    p = tmp_path / "nav.mcap"
    with LogWriter(p, META) as w:
        w.write_nav("/nav/ins_unaided", T0 + np.arange(3), np.zeros((3, 3)), np.zeros((3, 3)),
                    np.tile([0, 0, 0, 1.0], (3, 1)), np.zeros((3, 0, 0)))
    nav = read_log(p).nav["ins_unaided"]
    assert nav.covariance.shape == (3, 0, 0)
