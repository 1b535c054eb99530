"""The README's real-flight commands ("What a user runs": import of the shipped sample, replay,
export of the solution) run as written: the lines are read out of README.md, so the test fails
when the README drifts from what runs. ``$H`` becomes this interpreter's ``-m scenarios.cli`` and
the commands run in a scratch folder that holds the sample at the same relative path.

The sample (scenarios/library/import/sample/) is what :func:`tests.import_flights.sample_tables`
writes: its truth is known, so the imported log and the solution are checked against it.
"""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from tests.import_flights import plane_truth, sample_tables

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = Path("scenarios/library/import/sample")


def _readme_flight_commands() -> list[str]:
    """The ``$H`` lines of README's "What a user runs" that make or read ``logs/flight*``."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## What a user runs\s*```sh\n(.*?)```", text, re.DOTALL).group(1)
    lines = [ln.split("  #", 1)[0].strip() for ln in block.splitlines()]
    return [ln for ln in lines if ln.startswith("$H ") and "logs/flight" in ln]


def test_sample_is_what_the_generator_writes(tmp_path):
    """The shipped tables are reproducible from the generator (and stay small)."""
    sample_tables(tmp_path)
    for name in ("imu.csv", "gps.csv"):
        assert (tmp_path / name).read_bytes() == (ROOT / SAMPLE / name).read_bytes(), name
    assert sum(p.stat().st_size for p in (ROOT / SAMPLE).iterdir()) < 300_000


def test_readme_import_replay_export_run_as_written(tmp_path):
    cmds = _readme_flight_commands()
    assert [c.split()[1] for c in cmds] == ["import", "replay", "export"], cmds
    assert f"{SAMPLE}/mapping.toml" in cmds[0]
    shutil.copytree(ROOT / SAMPLE, tmp_path / SAMPLE)
    (tmp_path / "logs").mkdir()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for c in cmds:
        args = [sys.executable, "-m", "scenarios.cli"] + shlex.split(c)[1:]
        r = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, (c, r.stdout[-2000:], r.stderr[-2000:])
    from scenarios.flightlog.reader import read_log
    log = read_log(tmp_path / "logs/flight.mcap")
    t, x, v, R_eb, f_b, w_b = plane_truth(80.0, 40.0)
    assert len(log.imu.t_ns) == t.size and len(log.gps.t_ns) == 401
    # the gyro back in body axes and rad/s: the truth plus the 2e-4 rad/s noise and the 1e-4 deg/s
    # resolution (5 sigma: 1e-3 rad/s)
    assert np.max(np.abs(log.imu.gyro - w_b)) < 1e-3
    # the IMU stamps: 2024-05-14T09:30:00Z (GPS week 2314, 18 leap seconds) + 25 ms steps, exactly
    assert log.imu.t_ns[0] == 1_715_679_000_000_000_000 and np.all(np.diff(log.imu.t_ns) == 25_000_000)
    # the smoothed solution against the truth: GPS of 1.5 m / 3 m at 5 Hz, 0.05 m/s velocities
    sm = pd.read_csv(tmp_path / "out/flight/smoothed.csv")
    k = np.round((sm["t_ns"].to_numpy() - log.imu.t_ns[0]) / 25e6).astype(int)
    err = np.linalg.norm(sm[["x", "y", "z"]].to_numpy() - x[k], axis=1)
    bound = 3 * np.sqrt(np.mean(sm["pos_sd"] ** 2))      # three times the smoother's own 1-sigma, RMS
    assert np.sqrt(np.mean(err ** 2)) < bound, (np.sqrt(np.mean(err ** 2)), bound)
    assert (tmp_path / "out/flight/forward.parquet").exists()
