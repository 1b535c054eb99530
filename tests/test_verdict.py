"""The replay's verdict (scenarios/replay/verdict.py, docs/replay.md "Verdict"): a small simulated
flight (atek, 200 s, truth-derived camera vectors from T+60) replayed clean and broken the way real
data break: cut at half its bytes, GPS offset by 3 km from mid-flight, GPS of another flight from
mid-flight, GPS velocity in the wrong frame. Clean ends OK (exit 0), truncated DEGRADED with the
reader's warning on the terminal (exit 0, 4 with --strict), the broken GPS FAILED (exit 3).
"""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from scipy.stats import chi2

from nav import earth
from scenarios.cli import main
from scenarios.flightlog.reader import read_log

DURATION, T_BREAK = 200.0, 130.0    #: flight length, when the GPS breaks [s after lift-off]


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """The clean flight and its broken variants as logs: name -> path (and the FlightData)."""
    from scenarios.cli.simulate import write_log
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    from scenarios.sim.truth_vectors import flight_truth_vectors
    d = tmp_path_factory.mktemp("verdict")
    sc = load_scenario("atek")
    fl = simulate_flight(sc, 0, DURATION)
    vec = flight_truth_vectors(fl)
    logs = {"clean": write_log(fl, d / "clean.mcap", vectors=vec)}
    data = (d / "clean.mcap").read_bytes()
    (d / "truncated.mcap").write_bytes(data[:len(data) // 2])
    logs["truncated"] = d / "truncated.mcap"
    g = fl.gps
    late = g.t >= T_BREAK
    # 3 km north of the true track from T_BREAK on
    lat, lon, _ = earth.ecef_to_geodetic(g.position)
    north = earth.R_en(lat, lon)[:, :, 0]
    bad = copy.deepcopy(fl)
    bad.gps.position[late] += 3000.0 * north[late]
    logs["offset"] = write_log(bad, d / "offset.mcap", vectors=vec)
    # the fixes of another flight (high-apogee: another motor, another trajectory) from T_BREAK on
    other = simulate_flight(load_scenario("high-apogee"), 0, DURATION)
    bad = copy.deepcopy(fl)
    bad.gps.position[late] = other.gps.position[late]
    bad.gps.velocity[late] = other.gps.velocity[late]
    logs["other"] = write_log(bad, d / "other.mcap", vectors=vec)
    # NED velocity written as ECEF
    bad = copy.deepcopy(fl)
    bad.gps.velocity[:] = np.einsum("nji,nj->ni", earth.R_en(lat, lon), g.velocity)
    logs["ned_as_ecef"] = write_log(bad, d / "ned.mcap", vectors=vec)
    return logs, fl, d


def _replay(log, d, capsys, *extra):
    """``horizon-nav replay LOG --json PATH`` (no smoother, no recording): exit code, stdout,
    stderr and the JSON summary."""
    js = d / f"{log.stem}{len(extra)}.json"
    rc = main(["replay", str(log), "-o", str(d / f"{log.stem}.solution.mcap"), "--no-smoother", "--no-rerun", "--quiet",
               *extra, "--json", str(js)])
    out = capsys.readouterr()
    s = json.loads(js.read_text()) if js.exists() else None
    print(out.out[-3000:])
    return rc, out.out, out.err, s
