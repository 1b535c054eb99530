"""``horizon-nav tune FLIGHT.mcap -o tuning.toml``: the filter's noise parameters estimated from the
flight by maximum likelihood of the innovations (:mod:`scenarios.study.tune`, docs/tuning.md).

The vision runs once (or the log's vectors are used); every likelihood evaluation replays the
filter on those vectors. Prints each estimate with its standard error, the parameters the flight
does not identify with the reason, the number of filter runs and the time per run; writes the
tuning file (overrides of the base tuning, each estimate commented) atomically. ``--report DIR``
adds the observability report (:mod:`scenarios.study.observability`) at the tuned parameters;
``--report-only`` writes it at the base tuning without the optimisation."""
from __future__ import annotations

import os

NAME = "tune"
HELP = "estimate the filter's noise parameters from a flight (maximum likelihood) -> tuning TOML"


def add_arguments(p) -> None:
    from scenarios.study.tune import DEFAULT_PARAMS, PARAMS
    p.add_argument("log", help="flight log (.mcap)")
    p.add_argument("-o", "--output", default=None, help="tuning TOML to write (required unless --report-only)")
    p.add_argument("--params", default=None,
                   help=f"comma-separated parameters to estimate (default: {','.join(DEFAULT_PARAMS)}; "
                        f"known: {','.join(sorted(PARAMS))}, and vector_cov_scale_<target>_camera_<k>; "
                        f"a target's P_c scale is estimated per camera when two or more cameras see it)")
    p.add_argument("--per-target-scales", action="store_true",
                   help="one P_c scale per target even where two or more cameras see it (default: one per camera)")
    p.add_argument("--tuning", default=None, help="base tuning TOML: the prior and the other settings (default: 003 table 3)")
    p.add_argument("--from", dest="t_from", default=None, help="start: T+<s> or UTC ISO (default: log start)")
    p.add_argument("--to", dest="t_to", default=None, help="end: T+<s> or UTC ISO (default: log end)")
    p.add_argument("--cameras", default=None, help="cameras to use, e.g. 1,2 (default: all)")
    p.add_argument("--targets", default="earth,sun", help="targets: earth,sun[,moon] (default earth,sun)")
    p.add_argument("--init", choices=("truth", "triad", "align"), default=None,
                   help="initialisation (default as for replay: triad when vectors exist)")
    p.add_argument("--vision", choices=("auto", "images", "vectors"), default="auto",
                   help="auto: images if the log has them, else its vectors")
    p.add_argument("--workers", type=int, default=0, help="vision worker processes (default: one per core)")
    p.add_argument("--max-iter", type=int, default=20, help="scoring iterations per round (default 20)")
    p.add_argument("-j", "--jobs", type=int, default=None,
                   help="local processes for the filter replays of each scoring iteration (default: one per core; "
                        "0: this process only)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="run the filter replays on this Dask distributed scheduler (as `study --scheduler`)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write the observability report (CSV, HTML, PNG per state group) into DIR")
    p.add_argument("--report-only", action="store_true",
                   help="no optimisation: the report at the base tuning (needs --report; -o not needed)")
    p.add_argument("--report-low", type=float, default=0.10,
                   help="variance reduction below which an estimated state is flagged for consideration (default 0.10)")
    p.add_argument("--report-high", type=float, default=0.50,
                   help="variance reduction from which a considered state is flagged for estimation (default 0.50)")
    p.add_argument("--verbose", action="store_true", help="print -log L and the parameters at every iteration")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    import logging
    import tomllib
    from pathlib import Path

    from tqdm import tqdm

    from scenarios import initialise, read_flight, see
    from scenarios.atomic import atomic_write_text
    from scenarios.cli.replay import camera_numbers
    from scenarios.errors import UserError
    from scenarios.replay.steps import _tuning
    from scenarios.study.tune import DEFAULT_PARAMS, PARAMS, TuneInputs, executor_mapper, param, tune, tuning_toml

    names = DEFAULT_PARAMS if not args.params else tuple(s.strip() for s in args.params.split(",") if s.strip())
    if not names:
        raise UserError(f"--params {args.params}: expected some of {','.join(sorted(PARAMS))}")
    for n in names:
        try:
            param(n)
        except ValueError as e:
            raise UserError(f"--params {args.params}: {e}") from None
    if args.report_only and not args.report:
        raise UserError("--report-only: needs --report DIR (the folder to write the report into)")
    if not args.output and not args.report_only:
        raise UserError("-o/--output: expected the tuning TOML to write (or --report DIR --report-only)")
    if args.jobs is None:
        args.jobs = os.cpu_count() or 1
    if args.jobs < 0:
        raise UserError(f"--jobs {args.jobs}: expected >= 0")
    if not 0.0 <= args.report_low <= args.report_high <= 1.0:
        raise UserError(f"--report-low/--report-high: expected 0 <= low <= high <= 1, got "
                        f"{args.report_low} and {args.report_high}")
    client = None
    if args.scheduler:   # an unreachable scheduler is reported before the vision runs
        from scenarios.study.execute import check_scheduler
        client = check_scheduler(args.scheduler)
    cams = camera_numbers(args.cameras)
    targets = tuple(t.strip() for t in args.targets.split(",") if t.strip())
    base = _tuning(args.tuning)
    overrides = tomllib.loads(Path(args.tuning).read_text()) if args.tuning else {}
    flight = read_flight(args.log, t_from=args.t_from, t_to=args.t_to, cameras=cams, vision=args.vision)
    init = args.init or "auto"
    sight = see(flight, init=init, targets=targets, workers=args.workers)
    start = sight.start if sight.start is not None else initialise(flight, sight, init=init)
    if start.alignment is not None:
        base = base.with_(init_att_sigma=max(base.init_att_sigma, start.alignment.att_sigma))
    base = base.for_cameras(flight.cam_numbers)
    inputs = TuneInputs(flight.imu, start.state, flight.gps, sight.vectors, flight.mounts,
                        cam_numbers=tuple(flight.cam_numbers))
    if args.verbose:
        h = logging.StreamHandler()
        h.setFormatter(logging.Formatter("%(message)s"))
        lg = logging.getLogger("scenarios.study.tune")
        lg.addHandler(h)
        lg.setLevel(logging.INFO)
    if args.report_only:
        return _report(args, inputs, base)
    with executor_mapper(args.jobs, client=client) as mapper, \
            tqdm(desc="tune: filter runs", unit="run", disable=args.quiet) as bar:
        try:
            res = tune(inputs, base, names, max_iter=args.max_iter, progress=bar, mapper=mapper,
                       cameras=not args.per_target_scales)
        except ValueError as e:
            raise UserError(f"--params: {e}") from None
    print(res.report())
    if not any(e.estimated for e in res.estimates):
        raise UserError(f"{args.log}: no parameter of --params is estimated from this flight (the reasons above); "
                        f"{args.output} not written")
    header = (f"Filter tuning estimated by `horizon-nav tune` from {Path(args.log).name} (maximum likelihood of the\n"
              f"innovations; standard errors from the Fisher information; base: {args.tuning or '003 table 3'}).\n"
              f"-log L {res.nll_prior:.1f} -> {res.nll:.1f} over {res.n_measurements} measurement blocks.")
    print(atomic_write_text(args.output, tuning_toml(res, overrides, header)))
    return _report(args, inputs, res.tuning) if args.report else 0


def _report(args, inputs, tuning) -> int:
    """The observability report of the flight at ``tuning`` into ``args.report``."""
    from scenarios.study.observability import observability, write_report
    rep = observability(inputs, tuning, low=args.report_low, high=args.report_high)
    print(rep.summary())
    for path in write_report(rep, args.report):
        if path.suffix != ".png":
            print(path)
    return 0
