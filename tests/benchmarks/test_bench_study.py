"""Study throughput and executor identity: study.runs_per_minute, study.dask_identical.

A small study of the atek coast (vectors from truth plus the vision error model) on a local pool
of 2 processes and on a Dask LocalCluster of 2 worker processes; QUICK: 4 runs of T+60..T+120,
otherwise 8 runs of the full coast T+60..T+430. The baseline is the mean single-run time measured
in the same pool (runs per minute of an ideal 2-worker pool = 2 * 60 / mean run time).
"""
from __future__ import annotations

import pandas as pd

from scenarios.study.execute import run_study
from scenarios.study.studyfile import load_study
from tests.test_study import study_text


def _study(tmp_path, quick):
    runs, t_end = (4, 120.0) if quick else (8, 430.0)
    p = tmp_path / "bench.toml"
    p.write_text(study_text("bench", runs, t_end, seed=1))
    return load_study(p)


def test_bench_study(tmp_path, bench, is_quick):
    from dask.distributed import Client, LocalCluster
    st = _study(tmp_path, is_quick)
    s = run_study(st, tmp_path / "pool", workers=2, progress=False, report=False)
    ideal = 2 * 60.0 / s["mean_run_s"]
    bench("study.runs_per_minute", s["runs_per_minute"], "runs/min", baseline=ideal,
          baseline_name="ideal 2-worker pool: 2 * 60 / mean single-run time, same run", notes=f"{st.n_runs} runs, 2 processes, incl. truth per worker")
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cl, \
            Client(cl) as client:
        run_study(st, tmp_path / "dask", client=client, progress=False, report=False)
    same = all(pd.read_parquet(tmp_path / "pool" / f).equals(pd.read_parquet(tmp_path / "dask" / f))
               for f in ("metrics.parquet", "series.parquet"))
    bench("study.dask_identical", 1.0 if same else 0.0, "bool")
    assert same
