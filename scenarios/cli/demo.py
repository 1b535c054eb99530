"""``horizon-nav demo`` (``make demo``): the main job on the built-in ATEK scenario.

1. simulate ``atek`` with rendered camera images (two cameras at 1 Hz in the coast T+60..T+430)
   into ``logs/atek.mcap`` (skipped when that log exists and ``--fresh`` is not given);
2. replay it: vision front end in worker processes, filter, smoother
   (``logs/atek.solution.mcap``, Rerun recording ``logs/atek.rrd``), with the noise parameters
   that ``horizon-nav tune`` estimates from this log (``scenarios/library/tuning/atek-ml.toml``;
   ``--tuning table3`` replays with 003's table 3 instead);
3. print the summary (attitude errors against the simulator's truth).

Open the recording with ``make view`` (``.venv/bin/rerun logs/atek.rrd``).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

#: the tuning the demo replays with: ``tune`` on the demo's own log (docs/tuning.md)
DEMO_TUNING = Path(__file__).resolve().parents[1] / "library" / "tuning" / "atek-ml.toml"

NAME = "demo"
HELP = "simulate the ATEK flight with images, replay it, print the summary, write logs/atek.rrd"


def add_arguments(p) -> None:
    p.add_argument("--out-dir", default="logs", help="output folder (default logs/)")
    p.add_argument("--fresh", action="store_true", help="simulate again even if logs/atek.mcap exists")
    p.add_argument("--workers", type=int, default=0, help="vision worker processes (default: one per core)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--tuning", default=str(DEMO_TUNING),
                   help="filter tuning TOML, or 'table3' for 003's table 3 (default: the noise parameters "
                        "`horizon-nav tune` estimates from the demo log, scenarios/library/tuning/atek-ml.toml)")


def run(args) -> int:
    from scenarios.cli import replay as replay_cmd
    from scenarios.replay.summary import viewer_command
    from scenarios.cli import simulate as sim_cmd
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    log = out / "atek.mcap"
    t0 = time.perf_counter()
    if args.fresh or not log.is_file():
        sa = argparse.Namespace(scenario="atek", output=str(log), seed=0, duration=None, images=True,
                                jpeg_quality=None, truth_rate=None, vectors=False, quiet=args.quiet)
        sim_cmd.run(sa)
    else:
        print(f"{log}: exists, not simulated again (--fresh to redo)")
    t1 = time.perf_counter()
    tuning = None if args.tuning == "table3" else args.tuning
    print(f"tuning: {tuning or '003 table 3'}" + (" (estimated from this log by `horizon-nav tune`)"
                                                  if tuning == str(DEMO_TUNING) else ""))
    ra = argparse.Namespace(log=str(log), output=str(out / "atek.solution.mcap"), tuning=tuning, t_from="T+60",
                            t_to="T+430", cameras=None, targets="earth,sun", init=None, init_file=None, smoother=True,
                            vision="auto", vision_config=None, workers=args.workers, rrd=str(out / "atek.rrd"),
                            no_rerun=False, spawn=False, json=False, quiet=args.quiet)
    rc = replay_cmd.run(ra)
    t2 = time.perf_counter()
    print(f"\ndemo: simulation {t1 - t0:.0f} s, replay {t2 - t1:.0f} s. Open the recording with: "
          f"{viewer_command(out / 'atek.rrd')} (or: make view)")
    return rc
