"""``horizon-nav export LOG.mcap -o DIR``: a flight log as CSV tables, image folders, videos and camera
files, with mapping files that import them again (docs/import.md); a solution log as CSV and
Parquet tables of the forward and smoothed solutions, the free-inertial run and the measurements
(docs/replay.md "Exporting a solution"). Code: scenarios/importer/export.py."""
from __future__ import annotations

from pathlib import Path

NAME = "export"
HELP = ("export a flight log to CSV tables, image folders, videos, camera files and a re-import mapping, "
        "or a solution log to CSV and Parquet tables")


def add_arguments(p) -> None:
    p.add_argument("log", help="flight log or solution log (.mcap)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--no-images", dest="images", action="store_false", help="do not write image folders")
    p.add_argument("--no-video", dest="video", action="store_false", help="do not write videos")
    p.add_argument("--video-codec", default="mp4v", choices=["mp4v", "mjpg"],
                   help="mp4v (.mp4, default) or mjpg (.avi, quality --jpeg-quality)")
    p.add_argument("--jpeg-quality", type=int, default=95, help="JPEG quality of re-encoded frames (default 95)")


def run(args) -> int:
    from scenarios.importer.export import export_log

    res = export_log(Path(args.log), Path(args.output), images=args.images, video=args.video,
                     video_codec=args.video_codec, jpeg_quality=args.jpeg_quality)
    counts = ", ".join(f"{k} {v}" for k, v in res.counts.items())
    if res.t_plus_origin is not None:
        print(f"{res.out_dir}: rows: {counts} (CSV and Parquet each; t_plus_s counts from {res.t_plus_origin})")
        return 0
    print(f"{res.out_dir}: {counts}; re-import with `horizon-nav import {res.out_dir / 'mapping.toml'} -o FLIGHT.mcap`")
    return 0
