"""``horizon-nav import MAPPING.toml -o logs/FLIGHT.mcap``: build a flight log from real flight data.

Reads the IMU and GPS tables (CSV / Parquet) and camera footage (video or image folder) that the
mapping file describes (docs/import.md; examples in scenarios/library/import/), converts units,
time bases and axes, prints a validation report (rates, gaps, saturation, unit plausibility) and
writes the MCAP log (docs/log-format.md). Errors in the report stop the import (nothing written)
unless ``--force``; a bad frame found while writing discards the log unless ``--keep-partial``.
"""
from __future__ import annotations

import sys
from pathlib import Path

from scenarios.errors import UserError

NAME = "import"
HELP = "import a real flight (IMU/GPS tables, video or images) into an MCAP log via a TOML mapping file"
#: the library's parameter spellings in its messages -> this command's options
FLAGS = {"force=True": "--force", "keep_partial=True": "--keep-partial"}


def add_arguments(p) -> None:
    p.add_argument("mapping", help="mapping file (.toml); see docs/import.md and scenarios/library/import/")
    p.add_argument("-o", "--output", required=True, help="output log, e.g. logs/flight.mcap")
    p.add_argument("--keep-partial", action="store_true",
                   help="on an error while writing (bad frame, short video) keep a partial log instead of nothing")
    p.add_argument("--report", metavar="DIR", default=None, help="also write report.json and report.png into DIR")
    p.add_argument("--force", action="store_true", help="write the log even when the validation report has errors")
    p.add_argument("--check", action="store_true", help="read and validate only; write no log")
    p.add_argument("--quiet", action="store_true", help="print only errors and the summary line")


def run(args) -> int:
    from scenarios.importer.build import ValidationFailed, import_flight, prepare
    from scenarios.importer.mapping import load_mapping
    from scenarios.importer.validate import save_report

    out = Path(args.output)
    if out.suffix != ".mcap":
        raise UserError(f"-o {out}: expected a .mcap file name")
    m = load_mapping(args.mapping)
    if args.check:
        prep = prepare(m)
        print(prep.report.text())
        if args.report:
            save_report(prep.report, Path(args.report), prep.imu, prep.gps, prep.footages)
        return 1 if prep.report.errors else 0
    try:
        res = import_flight(m, out, keep_partial=args.keep_partial, force=args.force, report_dir=args.report)
    except ValidationFailed as exc:
        print(exc.report.text(), file=sys.stderr)
        raise
    if not args.quiet:
        print(res.report.text())
    c = res.counts
    cams = ", ".join(f"{v} frames camera {k.split('_')[1]}" for k, v in c.items() if k.startswith("camera_"))
    print(f"{out}: {m.name}: {c.get('imu', 0)} IMU samples, {c.get('gps', 0)} GPS fixes"
          + (f", {cams}" if cams else "") + f"; {len(res.report.errors)} error(s), "
          f"{len(res.report.warnings)} warning(s)" + (f"; report in {args.report}" if args.report else ""))
    return 0
