"""``horizon-nav identify SCENARIO -o DIR``: which noise parameters a flight of the scenario can tell
apart (:mod:`scenarios.study.identifiability`, docs/tuning.md).

Runs ``tune`` on one simulated flight at the base tuning's values, then, per parameter, a Monte
Carlo of simulated flights (vectors from the vision error model, no images) with the parameter at
1/factor and factor times its value, and the power of the 5 % likelihood-ratio test between the
two: near 0.05 for a parameter the flight cannot distinguish, near 1 for one it pins down. Prints
the table beside ``tune``'s verdicts and writes ``identifiability.csv`` and ``identifiability.txt``
into DIR (atomically). The flights run in this process, on ``-j`` local processes or on a Dask
cluster (``--scheduler``), as ``horizon-nav study``.
"""
from __future__ import annotations

NAME = "identify"
HELP = "Monte Carlo check of which noise parameters a flight identifies (likelihood-ratio power per parameter)"


def add_arguments(p) -> None:
    from scenarios.study.tune import DEFAULT_PARAMS
    p.add_argument("scenario", help="scenario (library name or .toml path)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for identifiability.csv/.txt")
    p.add_argument("--tuning", default=None, help="base tuning TOML: the values the flights are drawn at "
                                                  "(default: 003 table 3)")
    p.add_argument("--params", default=None, help=f"comma-separated parameters (default: {','.join(DEFAULT_PARAMS)}, "
                                                  "those the flight carries)")
    p.add_argument("--from", dest="t_from", type=float, default=60.0, help="window start, mission time [s] (default 60)")
    p.add_argument("--to", dest="t_to", type=float, default=120.0, help="window end, mission time [s] (default 120)")
    p.add_argument("--runs", type=int, default=200,
                   help="flights per parameter tune does not call identified, half per hypothesis (default 200)")
    p.add_argument("--control-runs", type=int, default=40, help="flights per identified parameter (default 40)")
    p.add_argument("--factor", type=float, default=2.0, help="hypotheses x1/factor and x factor (default 2)")
    p.add_argument("--seed", type=int, default=10_000, help="first seed of the Monte Carlo flights")
    p.add_argument("-j", "--jobs", type=int, default=0, help="local worker processes (default 0: this process)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the flights on this Dask scheduler")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    from pathlib import Path

    from tqdm import tqdm

    from scenarios.atomic import atomic_output, atomic_write_text
    from scenarios.errors import UserError
    from scenarios.replay.steps import _tuning
    from scenarios.sim.scenario import load_scenario
    from scenarios.study.identifiability import identifiability
    from scenarios.study.tune import DEFAULT_PARAMS, executor_mapper

    names = DEFAULT_PARAMS if not args.params else tuple(s.strip() for s in args.params.split(",") if s.strip())
    if not 0 <= args.t_from < args.t_to:
        raise UserError(f"--from {args.t_from} --to {args.t_to}: expected 0 <= from < to")
    if args.jobs < 0:
        raise UserError(f"--jobs {args.jobs}: expected >= 0")
    client = None
    if args.scheduler:
        from scenarios.study.execute import check_scheduler
        client = check_scheduler(args.scheduler)
    sc = load_scenario(args.scenario)
    tun = _tuning(args.tuning)
    with executor_mapper(args.jobs, client=client) as mapper, \
            tqdm(desc="identify: flights", unit="flight", disable=args.quiet) as bar:
        try:
            res = identifiability(sc, tun, names, runs=args.runs, control_runs=args.control_runs, factor=args.factor,
                                  t0=args.t_from, t1=args.t_to, seed0=args.seed, mapper=mapper, progress=bar)
        except ValueError as e:
            raise UserError(f"identify: {e}") from None
    text = res.report()
    print(text)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    atomic_output(out / "identifiability.csv", lambda p: res.table().to_csv(p, index=False))
    print(atomic_write_text(out / "identifiability.txt", text + "\n"))
    return 0
