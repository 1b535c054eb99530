"""``horizon-nav study STUDY.toml -o results/``: filter-tuning Monte Carlo and parameter sweeps.

Runs every (variant, replicate) of a study file (:mod:`scenarios.study.studyfile`) on a local
process pool (default: all cores) or a Dask cluster (``--scheduler tcp://HOST:PORT``), resumably:
finished runs are kept in ``results/runs/`` and skipped when the command is started again. Writes
``metrics.parquet``, ``series.parquet``, a copy of the study file and ``report.html`` (see
``docs/studies.md``). Errors in the study file, a study larger than ``study.max_runs`` without
``--yes`` and an unreachable scheduler are reported before any run starts.
"""
from __future__ import annotations

import json

NAME = "study"
HELP = "filter Monte Carlo studies and parameter sweeps from a study file (Parquet tables + HTML report)"
#: the library's parameter spellings in its messages -> this command's options
FLAGS = {"yes=True": "--yes", "scheduler = ": "--scheduler ", "scheduler: a Dask scheduler": "--scheduler"}


def add_arguments(p) -> None:
    p.add_argument("study", metavar="STUDY.toml", help="study file (or the name of one in scenarios/library/studies)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="results directory (created; resumable)")
    p.add_argument("-j", "--workers", type=int, default=None,
                   help="local worker processes (default: all cores; 0: run in this process)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask distributed scheduler")
    p.add_argument("--max-runs", type=int, default=None, metavar="N",
                   help="stop after N new runs (the rest is done by running the command again)")
    p.add_argument("--yes", action="store_true", help="run even if the study exceeds study.max_runs")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--report-only", action="store_true", help="rebuild report.html from the tables in DIR")


def run(args) -> int:
    from scenarios.errors import UserError
    from scenarios.study.execute import run_study
    from scenarios.study.report import write_report
    from scenarios.study.studyfile import load_study

    if args.report_only:
        print(write_report(args.output))
        return 0
    if args.workers is not None and args.workers < 0:
        raise UserError(f"--workers {args.workers}: expected >= 0")
    if args.max_runs is not None and args.max_runs < 0:
        raise UserError(f"--max-runs {args.max_runs}: expected >= 0")
    study = load_study(args.study)
    summary = run_study(study, args.output, workers=args.workers, scheduler=args.scheduler,
                        max_runs=args.max_runs, yes=args.yes, progress=not args.no_progress)
    rpm = summary["runs_per_minute"]
    print(f"{study.name}: {summary['runs_done_now']} runs done, {summary['runs_skipped']} already finished, "
          f"{summary['runs_remaining']} remaining; {summary['wall_s']:.1f} s"
          + (f", {rpm:.1f} runs/min on {summary['workers']} {summary['executor']} worker(s)" if rpm else ""))
    if summary["runs_remaining"] == 0:
        from pathlib import Path
        verdicts = json.loads((Path(args.output) / "verdicts.json").read_text())
        for label, v in verdicts.items():
            print(f"  {label}: {v['text']}")
        print(f"report: {Path(args.output) / 'report.html'}")
    return 0
