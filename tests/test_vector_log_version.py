"""DirectionVector schema versions (scenarios/flightlog/format.py SCHEMA_VERSIONS): version 2 carries
the Earth edge height (sensitivity, fitted height and sigma, the arc's own height and sigma), logs
of version 1 still read, an unknown version is a one-line error; a vectors-only log teaches the
filter its edge height."""
import io

import numpy as np
import pytest

from scenarios.flightlog import format as lf
from scenarios.flightlog.reader import LogFormatError, read_log
from scenarios.flightlog.writer import LogWriter
from scenarios.replay.inputs import _vectors_of
from scenarios.replay.sight import log_vectors

T0 = 1_560_392_460_000_000_000
META = {"scenario": "", "seed": 0, "liftoff_utc_ns": T0, "kind": "simulated"}
DV = f"{lf.PKG}/DirectionVector"


def _v1_log(path, version_line: str = ""):
    """A log with /camera_1/vectors written by mcap_ros2 with the version 1 definition (the
    reference encoder; ``version_line`` appended to the top-level message)."""
    from mcap_ros2.writer import Writer
    text = lf.schema_text(DV).replace(lf.SCHEMA_VERSIONS[DV][2], lf.SCHEMA_VERSIONS[DV][1] + version_line)
    buf = io.BytesIO()
    w = Writer(buf)
    schema = w.register_msgdef(lf.ros2_name(DV), text)
    for i, tg in enumerate(("earth", "sun")):
        t = T0 + i * 10**9
        w.write_message("/camera_1/vectors", schema, {
            "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": "camera_1"},
            "target": tg, "vector": [0.0, 0.0, 1.0], "covariance": list(np.eye(3).ravel() * 1e-6),
            "covariance_overbound": list(np.eye(3).ravel() * 1e-6), "residual": 0.0, "pixel_count": 10,
            "inlier_count": 9, "conic_type": "", "alpha": 0.1}, log_time=t, publish_time=t)
    w.finish()
    path.write_bytes(buf.getvalue())


def test_round_trip_carries_the_edge_height(tmp_path):
    """Written and read back (column reader and the per-message reader of stamps with several
    vectors): the edge fields are the written values exactly (float64 in CDR), NaN where none."""
    p = tmp_path / "v2.mcap"
    t = T0 + np.array([0, 0, 10**9])
    g = np.array([[1e-7, -2e-7, 3e-8], [np.nan] * 3, [4e-7, 0.0, -1e-7]])
    h, hs, ha, has = [17.9e3, np.nan, 18.4e3], [9.1e3, np.nan, 8.7e3], [17.5e3, np.nan, 19e3], [9.4e3, np.nan, np.inf]
    with LogWriter(p, META) as w:
        w.write_vectors(1, t, ["earth", "sun", "earth"], np.tile([0, 0, 1.0], (3, 1)), np.eye(3) * 1e-6,
                        edge_sensitivity=g, edge_height=h, edge_height_sigma=hs, edge_height_arc=ha,
                        edge_height_arc_sigma=has)
    log = read_log(p)
    assert not [i for i in log.issues if "vectors" in i]      # no NaN or schema warning
    d = _vectors_of(p, log, 1)
    order = np.argsort([0, 1, 2] if d["target"][0] == "earth" else [1, 0, 2], kind="stable")
    np.testing.assert_array_equal(d["edge_sensitivity"], g[order])
    for key, want in (("edge_height", h), ("edge_height_sigma", hs), ("edge_height_arc", ha),
                      ("edge_height_arc_sigma", has)):
        np.testing.assert_array_equal(d[key], np.asarray(want)[order])
    inp = type("I", (), {"cameras": {1: type("C", (), {"vectors": d})()}})()
    vd = log_vectors(inp, [1], ("earth", "sun"), T0, T0 + 2 * 10**9, edge_state=True)
    hor = vd.target == "hor"
    np.testing.assert_array_equal(vd.dedge_c[hor], g[[0, 2]])
    np.testing.assert_array_equal(vd.edge_ref_m[hor], [17.9e3, 18.4e3])
    np.testing.assert_array_equal(vd.edge_data_sigma_m[hor], [9.4e3, np.inf])
    # without the state: no sensitivity, the height's part back in the covariance
    off = log_vectors(inp, [1], ("earth",), T0, T0 + 2 * 10**9)
    assert off.dedge_c is None
    np.testing.assert_allclose(off.P_c[0], np.eye(3) * 1e-6 + 9.1e3 ** 2 * np.outer(g[0], g[0]), rtol=1e-15)


def test_version_1_log_reads(tmp_path):
    """A log written with the version 1 definition (no edge fields) reads without a schema
    warning, its vectors as written, and gives vectors without a sensitivity."""
    p = tmp_path / "v1.mcap"
    _v1_log(p)
    log = read_log(p)
    assert not [i for i in log.issues if "schema" in i]
    d = _vectors_of(p, log, 1)
    assert "edge_sensitivity" not in d and d["target"].tolist() == ["earth", "sun"]
    np.testing.assert_array_equal(d["vector"], [[0, 0, 1.0]] * 2)
    inp = type("I", (), {"cameras": {1: type("C", (), {"vectors": d})()}})()
    vd = log_vectors(inp, [1], ("earth", "sun"), T0, T0 + 10**9, edge_state=True)
    assert vd.dedge_c is None and len(vd.t_ns) == 2


def test_unknown_version_is_one_line_error(tmp_path):
    """A DirectionVector schema declaring a version the reader does not know: LogFormatError, one
    line naming the file, the topic and the version."""
    p = tmp_path / "v9.mcap"
    _v1_log(p, "uint16 SCHEMA_VERSION=9\n")
    with pytest.raises(LogFormatError) as e:
        read_log(p)
    msg = str(e.value)
    assert "\n" not in msg and "/camera_1/vectors" in msg and "version 9" in msg and str(p) in msg


def test_vectors_only_log_teaches_the_edge_height(tmp_path):
    """A simulated vectors-only log of the mismatch flight (atek-nav-grade, edge 10 km, Earth vectors
    fitted at 45 km with their sensitivity: scenarios/sim/truth_vectors.py; T+60..T+140 as in
    tests/test_edge_height_filter.py) replayed with ``[states.edge_height] mode = "E"``
    (scenarios.replay.pipeline.replay, ``vision = "vectors"``): the vectors come back with their
    sensitivity and height, and each camera's smoothed height is within 3 km of the truth (the
    issue's bound, which the in-memory vectors of the same flight meet with 0.9 km to spare)."""
    import dataclasses

    from scenarios.cli.simulate import write_log
    from scenarios.replay.pipeline import replay
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    from scenarios.sim.truth_vectors import flight_truth_vectors
    from tests.test_edge_height_filter import PRIOR_EDGE_M, TRUE_EDGE_M
    from tests.test_replay import _opt
    sc = load_scenario("atek-nav-grade")
    sc = dataclasses.replace(sc, simulation=dataclasses.replace(sc.simulation, horizon_atmosphere_m=TRUE_EDGE_M))
    fl = simulate_flight(sc, seed=3, duration=140.0)
    log = write_log(fl, tmp_path / "vec.mcap", vectors=flight_truth_vectors(fl, edge_ref_m=PRIOR_EDGE_M))
    tun = tmp_path / "edge.toml"
    tun.write_text('[states.edge_height]\nmode = "E"\nsigma_km = 20\n')
    rr = replay(log, _opt(output=str(tmp_path / "vec.solution.mcap"), vision="vectors", tuning=str(tun),
                          t_from="T+60", init="truth"))
    hor = rr.vectors.target == "hor"
    assert np.all(np.isfinite(rr.vectors.dedge_c[hor])) and np.all(rr.vectors.edge_ref_m[hor] == PRIOR_EDGE_M)
    idx = [rr.nav.layout[f"h_e_{c}"].start for c in range(2)]
    h = rr.smooth.estimates[0, idx]
    print(f"smoothed edge heights from the log's vectors {np.round(h / 1e3, 2)} km, truth {TRUE_EDGE_M / 1e3} km")
    assert np.all(np.abs(h - TRUE_EDGE_M) < 3e3), h
