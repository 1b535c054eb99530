"""Running a study: local process pool (default) or a Dask distributed cluster; resumable.

Layout of the output directory::

    OUT/study.toml              copy of the study file
    OUT/runs/<run_id>.parquet   one finished run: its metric rows (written last, atomically)
    OUT/runs/<run_id>.series.parquet   its per-time-step NEES / NIS / error series
    OUT/metrics.parquet         all runs, one row per (run, metric): study, run_id, variant,
                                variant_label, replicate, seed, <varied parameters>, metric, value
    OUT/series.parquet          all series rows: run_id, variant, seed, quantity, t_s, value, dof
    OUT/timing.json             wall time, runs per minute, executor, workers

A run is *finished* when its ``runs/<run_id>.parquet`` exists (the series file is written first,
both by rename from a temporary file), so a study stopped at any point and started again skips the
finished runs and redoes at most the ones that were in flight. The final tables are assembled from
the per-run files, sorted by run index: the same seeds give the same tables whatever the executor,
the number of workers or the order in which runs finish.

Ctrl-C (SIGINT) stops a local study gracefully: the runs under way finish and are kept, no new run
starts, then ``KeyboardInterrupt`` is raised (the CLI prints "interrupted", exit 130); a second
Ctrl-C stops at once. An interrupt is never raised inside a run's library code (e.g. while numba
loads a cached kernel, where Python could only print it as an ignored exception).
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

import numpy as np
import pandas as pd

from scenarios.atomic import atomic_output, atomic_write_text
from scenarios.errors import UserError
from scenarios.study.studyfile import RunSpec, Study, build_variant, load_base, study_from_text

METRIC_COLUMNS = ["study", "run_id", "run_index", "variant", "variant_label", "replicate", "seed"]


def check_size(study: Study, yes: bool) -> None:
    """Refuse a study larger than ``study.max_runs`` unless confirmed (``yes``)."""
    n = study.declared_runs or study.n_runs
    if n > study.max_runs and not yes:
        raise UserError(f"{study.path}: the study asks for {n} runs ({n // study.runs} variants x "
                        f"{study.runs} runs), more than study.max_runs = {study.max_runs}; "
                        f"pass yes=True to run it anyway or raise max_runs")
    if not study.variants:
        raise UserError(f"{study.path}: {n} runs declared; too many to enumerate (limit {100 * study.max_runs})")


def check_scheduler(address: str, timeout: float = 3.0):
    """A connected ``dask.distributed.Client`` or a UserError naming the address (before any work)."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise UserError("scheduler: a Dask scheduler needs dask[distributed] (pip install 'dask[distributed]')") from None
    try:
        return Client(address, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as e:
        raise UserError(f"scheduler = {address}: cannot reach the Dask scheduler ({type(e).__name__}: {e})") from None


# ------------------------------------------------------------------------------------------------
# One task (runs in a worker process)
# ------------------------------------------------------------------------------------------------
_BASES: dict = {}
_STUDIES: dict = {}


def _variant_config(study_text: str, study_path: str, variant: int) -> tuple:
    key = (study_text, study_path)
    if key not in _STUDIES:
        st = study_from_text(study_text, study_path)
        _STUDIES.clear(); _BASES.clear()
        _STUDIES[key] = st
        _BASES[key] = load_base(st)
    st = _STUDIES[key]
    return st, build_variant(st, st.variants[variant], _BASES[key])


def _params_of(study: Study, variant: int) -> dict:
    """Parameter values of a variant as table columns (``{times = k}`` resolved to the value)."""
    cfg = build_variant(study, study.variants[variant])
    out = {}
    for name in study.varied:
        obj = cfg
        parts = name.split(".")
        obj = cfg[parts[0]]
        for p in parts[1:]:
            obj = obj[int(p)] if isinstance(obj, list) else getattr(obj, p)
        out[name] = obj if isinstance(obj, (int, float, str, bool)) else json.dumps(obj)
    return out


def execute_run(study_text: str, study_path: str, spec: RunSpec, out_dir: str) -> dict:
    """Run one study run in this process and write its two files; returns its timing."""
    import logging
    from scenarios.study.runner import run_one
    logging.getLogger("nav").setLevel(logging.ERROR)  # rejections are counted in the 'rejected' metric
    st, cfg = _variant_config(study_text, study_path, spec.variant)
    res = run_one(cfg, spec, st.metrics)
    v = st.variants[spec.variant]
    params = _params_of(st, spec.variant)
    runs = Path(out_dir) / "runs"
    ser = [pd.DataFrame({"run_id": spec.run_id, "run_index": spec.index, "variant": spec.variant,
                         "seed": np.uint64(spec.seed), "quantity": q, "t_s": np.asarray(t, float),
                         "value": np.asarray(val, float), "dof": np.asarray(d, float)})
           for q, t, val, d in res.series]
    ser_df = pd.concat(ser, ignore_index=True) if ser else pd.DataFrame(
        columns=["run_id", "run_index", "variant", "seed", "quantity", "t_s", "value", "dof"])
    names = sorted(res.metrics)
    met = pd.DataFrame({"study": st.name, "run_id": spec.run_id, "run_index": spec.index,
                        "variant": spec.variant, "variant_label": v.label, "replicate": spec.replicate,
                        "seed": np.uint64(spec.seed), **{k: [params[k]] * len(names) for k in params},
                        "metric": names, "value": [float(res.metrics[k]) for k in names]})
    atomic_output(runs / f"{spec.run_id}.series.parquet", lambda p: ser_df.to_parquet(p, index=False))
    atomic_output(runs / f"{spec.run_id}.parquet", lambda p: met.to_parquet(p, index=False))
    return {"run_id": spec.run_id, "elapsed_s": res.elapsed_s}


# ------------------------------------------------------------------------------------------------
# The study
# ------------------------------------------------------------------------------------------------
def finished_runs(out_dir: Path) -> set[str]:
    d = Path(out_dir) / "runs"
    if not d.is_dir():
        return set()
    return {p.name[:-len(".parquet")] for p in d.glob("*.parquet") if not p.name.endswith(".series.parquet")
            and not p.name.startswith(".")}


def prepare_output(study: Study, out_dir: Path) -> None:
    """Create OUT/runs and copy the study file; refuse an OUT holding a different study."""
    out_dir = Path(out_dir)
    (out_dir / "runs").mkdir(parents=True, exist_ok=True)
    copy = out_dir / "study.toml"
    if copy.exists() and copy.read_text(encoding="utf-8") != study.text and finished_runs(out_dir):
        raise UserError(f"{out_dir}: holds results of a different study file ({copy}); "
                        "use another output directory or remove it")
    atomic_write_text(copy, study.text)


@contextlib.contextmanager
def _graceful_interrupt():
    """Within: the first SIGINT only sets the flag the yielded function returns (a message says the
    runs under way are being finished); the second raises ``KeyboardInterrupt``. Outside the main
    thread (no signal handlers there) the flag stays False and SIGINT behaves as usual."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    count = [0]

    def handler(signum, frame):
        count[0] += 1
        if count[0] > 1:
            raise KeyboardInterrupt
        print("horizon-nav study: interrupted: finishing the runs under way (Ctrl-C again to stop now)",
              file=sys.stderr, flush=True)

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: count[0] > 0
    finally:
        signal.signal(signal.SIGINT, previous)


def _ignore_sigint() -> None:
    """Pool worker initializer: the terminal's Ctrl-C reaches the whole process group; the parent
    decides (finish the runs under way), a worker must not die mid-run."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_study(study: Study, out_dir, *, workers: int | None = None, scheduler: str | None = None,
              client=None, max_runs: int | None = None, yes: bool = False, progress: bool = True,
              report: bool = True) -> dict:
    """Run every unfinished run of ``study`` into ``out_dir``; assemble the tables (and the report)
    when all runs are finished.

    ``workers``: local processes (default: all cores; 0 runs in this process). ``scheduler``: a
    Dask scheduler address (``tcp://host:port``) or ``client``: a ``dask.distributed.Client``.
    ``max_runs``: stop after this many new runs (for tests and partial runs).
    Returns a summary dict (runs done now, skipped, remaining, wall time, runs per minute).
    """
    check_size(study, yes)
    if scheduler and client is None:
        client = check_scheduler(scheduler)
    out_dir = Path(out_dir)
    prepare_output(study, out_dir)
    specs = study.run_specs()
    done = finished_runs(out_dir)
    todo = [s for s in specs if s.run_id not in done]
    if max_runs is not None:
        todo = todo[:max_runs]
    t0 = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(specs), initial=len(specs) - len([s for s in specs if s.run_id not in done]),
                   unit="run", desc=study.name, smoothing=0.05)
    timings = []

    def tick(r):
        timings.append(r)
        if bar is not None:
            bar.update(1)

    args = (study.text, study.path)
    executor = "dask" if client is not None else ("inline" if workers == 0 else "processes")
    n_workers = 1
    try:
        if client is not None:
            n_workers = max(1, len(client.scheduler_info().get("workers", {})))
            futs = client.map(execute_run, *zip(*[(args[0], args[1], s, str(out_dir)) for s in todo]), pure=False) \
                if todo else []
            from dask.distributed import as_completed
            for f in as_completed(futs):
                tick(f.result())
        else:
            with _graceful_interrupt() as interrupted:
                if workers == 0:
                    for s in todo:
                        if interrupted():
                            break
                        tick(execute_run(*args, s, str(out_dir)))
                elif todo:
                    n_workers = workers or os.cpu_count() or 1
                    _run_pool(n_workers, [(*args, s, str(out_dir)) for s in todo], tick, interrupted)
                if interrupted():
                    raise KeyboardInterrupt
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t0
    remaining = len([s for s in specs if s.run_id not in finished_runs(out_dir)])
    summary = {"study": study.name, "runs_total": len(specs), "runs_done_now": len(timings),
               "runs_skipped": len(done & {s.run_id for s in specs}),
               "runs_remaining": remaining, "wall_s": wall, "executor": executor, "workers": n_workers,
               "runs_per_minute": (60.0 * len(timings) / wall) if timings and wall > 0 else None,
               "mean_run_s": float(np.mean([t["elapsed_s"] for t in timings])) if timings else None}
    if remaining == 0:
        assemble(study, out_dir)
        atomic_write_text(out_dir / "timing.json", json.dumps(summary, indent=1))
        if report:
            from scenarios.study.report import write_report
            write_report(out_dir)
    return summary


def _run_pool(n_workers: int, calls: list, tick, interrupted) -> None:
    """``execute_run(*call)`` for each call on a local process pool, ``tick`` on each result; once
    ``interrupted()``, the runs not yet started are cancelled and the ones under way awaited."""
    with ProcessPoolExecutor(max_workers=n_workers, initializer=_ignore_sigint) as pool:
        pending = {pool.submit(execute_run, *c) for c in calls}
        try:
            while pending:
                fin, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                for f in fin:
                    if not f.cancelled():
                        tick(f.result())
                if interrupted():
                    for f in pending:
                        f.cancel()
        except BaseException:
            for f in pending:
                f.cancel()
            raise


def assemble(study: Study, out_dir) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Concatenate the per-run files (sorted by run index) into metrics.parquet and series.parquet."""
    out_dir = Path(out_dir)
    specs = study.run_specs()
    runs = out_dir / "runs"
    met = pd.concat([pd.read_parquet(runs / f"{s.run_id}.parquet") for s in specs], ignore_index=True)
    ser = pd.concat([pd.read_parquet(runs / f"{s.run_id}.series.parquet") for s in specs], ignore_index=True)
    met = met.sort_values(["run_index", "metric"], kind="stable").reset_index(drop=True)
    ser = ser.sort_values(["run_index", "quantity", "t_s"], kind="stable").reset_index(drop=True)
    atomic_output(out_dir / "metrics.parquet", lambda p: met.to_parquet(p, index=False))
    atomic_output(out_dir / "series.parquet", lambda p: ser.to_parquet(p, index=False))
    return met, ser

