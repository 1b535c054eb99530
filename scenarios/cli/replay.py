"""``horizon-nav replay FLIGHT.mcap``: vision, filter and smoother over a flight log; writes the
solution MCAP and a Rerun recording and prints a summary (docs/replay.md)."""
from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

from scenarios.errors import UserError

NAME = "replay"
HELP = "replay a flight log: vision front end, filter, smoother -> solution MCAP + Rerun recording + summary"
EPILOG = ("The summary ends with a verdict (docs/replay.md \"Verdict\"). Exit codes: 0 OK or DEGRADED, 2 input "
          "refused, 3 FAILED (the solution must not be used), 4 DEGRADED with --strict, 130 interrupted.")


def add_arguments(p) -> None:
    p.add_argument("log", help="flight log (.mcap)")
    p.add_argument("-o", "--output", default=None, help="solution log (default FLIGHT.solution.mcap)")
    p.add_argument("--tuning", default=None, help="filter tuning TOML (default: 003 table 3)")
    p.add_argument("--from", dest="t_from", default=None, help="start: T+<s> or UTC ISO (default: log start)")
    p.add_argument("--to", dest="t_to", default=None, help="end: T+<s> or UTC ISO (default: log end)")
    p.add_argument("--cameras", default=None, help="cameras to use, e.g. 1,2 (default: all)")
    p.add_argument("--targets", default="earth,sun", help="targets to use: earth,sun[,moon] (default earth,sun)")
    p.add_argument("--init", choices=("truth", "given", "triad", "align"), default=None,
                   help="initialisation (default: triad when vectors exist, else truth if the log has it, else align: in-motion alignment from GPS and the IMU over the first 60 s)")
    p.add_argument("--init-file", default=None, help="--init given: TOML with time and the attitude as q_eb, roll_deg/pitch_deg/heading_deg (NED) or launcher_azimuth_deg/launcher_elevation_deg [/roll_deg] [, position_e, velocity_e]")
    p.add_argument("--no-smoother", dest="smoother", action="store_false", default=True, help="skip the RTS smoother")
    p.add_argument("--vision", choices=("auto", "images", "vectors"), default="auto",
                   help="auto: images if the log has them, else its vectors")
    p.add_argument("--vision-config", default=None, help="vision config TOML (default: the library default)")
    p.add_argument("--vision-rate", type=float, default=None, metavar="HZ",
                   help="process at most HZ frames per second per camera (e.g. 5 for a 30 frames/s video; default: all)")
    p.add_argument("--rrd-image-rate", type=float, default=None, metavar="HZ",
                   help="camera images (with overlays) in the Rerun recording per second and camera "
                        "(default: every processed frame; vectors and time series keep every frame)")
    p.add_argument("--mask", action="append", default=[], metavar="K=FILE",
                   help="payload mask of camera K: an image of the camera's size, non-zero = payload "
                        "(ignored by the edge search); repeatable; default: the log's /camera_<K>/payload_mask")
    p.add_argument("--workers", type=int, default=0, help="vision worker processes (default: one per core)")
    p.add_argument("--rrd", default=None, help="Rerun recording (default: next to the solution, FLIGHT.rrd)")
    p.add_argument("--no-rerun", action="store_true", help="do not write a Rerun recording")
    p.add_argument("--spawn", action="store_true", help="open the Rerun viewer")
    p.add_argument("--json", nargs="?", const="-", default=None, metavar="PATH|-",
                   help="the summary and verdict as one JSON object: to stdout instead of the table (-, the "
                        "default) or written to PATH (the table still printed); put it after the log")
    p.add_argument("--strict", action="store_true",
                   help="a DEGRADED verdict exits with code 4 (FAILED always exits with 3)")
    p.epilog = EPILOG
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def camera_numbers(text: str | None):
    """``--cameras 1,2`` -> [1, 2]; None for all cameras."""
    if not text:
        return None
    try:
        return [int(c) for c in text.split(",") if c.strip()]
    except ValueError:
        raise UserError(f"--cameras {text}: expected camera numbers, e.g. 1,2") from None


def options_from_args(args):
    from scenarios.replay.pipeline import ReplayOptions
    cams = camera_numbers(args.cameras)
    targets = tuple(t.strip() for t in args.targets.split(",") if t.strip())
    masks = {}
    for item in getattr(args, "mask", []) or []:
        k, sep, f = item.partition("=")
        if not sep or not k.strip().isdigit() or not f:
            raise UserError(f"--mask {item}: expected K=FILE, e.g. --mask 2=payload_2.png")
        masks[int(k)] = f
    return ReplayOptions(tuning=args.tuning, t_from=args.t_from, t_to=args.t_to, cameras=cams, targets=targets,
                         init=args.init, init_file=args.init_file, smoother=args.smoother, vision=args.vision,
                         vision_config=args.vision_config, vision_rate_hz=getattr(args, "vision_rate", None),
                         rrd_image_rate_hz=getattr(args, "rrd_image_rate", None),
                         masks=masks, workers=args.workers, output=args.output,
                         rrd="" if args.no_rerun else args.rrd, spawn=args.spawn,
                         progress=not args.quiet and _json_target(args) != "-")


def _json_target(args):
    """``--json``: None, ``"-"`` (stdout) or a path (``True`` from a caller's namespace is ``"-"``)."""
    j = getattr(args, "json", None)
    return "-" if j is True else (j or None)


#: compiled kernels whose numba cache index marks a package as compiled (the filter's propagation
#: and the front end's limb profiles: the largest of each)
CACHE_MARKERS = (("nav", "filter_state.propagate_block-"), ("vision", "limb."))


def kernels_cached(root: Path | None = None) -> bool:
    """Whether numba's on-disk cache holds the filter's and the front end's kernels (the first
    run compiles them, 1-2 minutes). With ``NUMBA_CACHE_DIR`` set the cache is elsewhere and
    this answers True (nothing is claimed)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return True
    root = Path(__file__).resolve().parents[2] if root is None else Path(root)
    return all(any((root / pkg / "__pycache__").glob(stem + "*.nbi")) for pkg, stem in CACHE_MARKERS)


def run(args) -> int:
    from scenarios.replay.pipeline import replay
    from scenarios.replay.summary import format_table, summarize
    import logging
    logging.getLogger("nav.navigator").setLevel(logging.ERROR)  # rejections are counted in the summary
    opt = options_from_args(args)
    target = _json_target(args)
    if target not in (None, "-") and not Path(target).resolve().parent.is_dir():
        raise UserError(f"--json {target}: its folder does not exist")
    if not args.quiet and not kernels_cached():
        print("first run: numba compiles the filter and vision kernels once (1-2 min; the progress bar waits "
              "in init meanwhile); later runs load them from the cache", file=sys.stderr)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        rr = replay(args.log, opt)
    except KeyboardInterrupt:
        print("replay interrupted: partial solution log written (horizon-nav.status complete = false)", file=sys.stderr)
        return 130
    s = summarize(rr)
    code = rr.verdict.exit_code(strict=getattr(args, "strict", False))
    s["exit_code"] = code
    if target == "-":
        for w in s["warnings"]:     # the terminal says so even when stdout is JSON
            print(f"horizon-nav replay: warning: {w}", file=sys.stderr)
        print(json.dumps(s, indent=1))
    else:
        if target is not None:
            from scenarios.atomic import atomic_output
            atomic_output(target, lambda tmp: Path(tmp).write_text(json.dumps(s, indent=1) + "\n"))
        print(format_table(s))
    return code
