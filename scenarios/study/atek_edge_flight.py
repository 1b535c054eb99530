"""Model-mismatch study of the Earth's edge height on the whole ATEK flight: the atek scenario
rendered with the limb's brightness edge at heights the front end does not assume
(`edge_mismatch.Case`: the threshold edge at 0, 10, 25, 45 and 60 km, two limb profiles) and
replayed end to end (vision with its defaults, filter, smoother) from T+60 to T+430, as `horizon-nav
demo` replays, with the tuning matched to the simulated sensors (scenarios/library/tuning/atek-sim.toml,
as the edge Monte Carlo `atek-edge-mc`) plus one edge-height state per camera (`[states.edge_height]
mode = "E"`, the limb edge, 20 km sigma: docs/vision.md). Not the demo's atek-ml.toml: its P_c
scales (0.18 / 0.10) were estimated for the vectors' marginal covariance, without the state, and
the state's vectors carry the covariance given the height, which those scales make optimistic.

The figures are `orbit_mismatch.flight_figures` per camera: the edge height the rendered frames'
fits have (``edge_truth_km``, the measurement model solved against the simulator's true nadir),
the smoother's height and its sigma, the nadir RMS as fitted and moved to the learned height, the
3-sigma containment before and after learning, the filter's attitude NEES, the smoothed attitude
RMS.

Run: ``python -m scenarios.study.atek_edge_flight [--heights KM ...] [--profiles NAME ...]
[--edge limb|threshold] [--out FILE.json]``: one line per camera and case as it finishes (the
render and the vision dominate its time, docs/vision.md; the JSON is rewritten after each). The
slow tests of tests/test_atek_edge_flight.py run it.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from scenarios.atomic import atomic_write_text
from scenarios.study.edge_mismatch import HEIGHTS_M, PROFILES, cases, quiet_filter_log

__all__ = ["TUNING", "EDGE_STATE", "tuning_file", "replay_log", "run_study", "main"]

_LIB = Path(__file__).resolve().parent.parent / "library"
#: the tuning matched to the simulated sensors (the edge Monte Carlo's), to which :data:`EDGE_STATE`
#: is added
TUNING = _LIB / "tuning" / "atek-sim.toml"
#: the edge-height state: estimated, the limb edge, the vision's limb-prior sigma
EDGE_STATE = '\n[states.edge_height]\nmode = "E"\n'


def tuning_file(workdir: Path, edge: str = "limb") -> Path:
    """:data:`TUNING` with :data:`EDGE_STATE` describing ``edge`` ("limb" or "threshold"),
    written under ``workdir``."""
    path = workdir / f"atek-sim-edge-{edge}.toml"
    atomic_write_text(path, TUNING.read_text(encoding="utf-8") + EDGE_STATE + f'edge = "{edge}"\n')
    return path


def replay_log(path: Path, out: Path, tuning: Path, workers: int = 0):
    """The demo's replay of ``path`` (T+60..T+430, Earth and Sun, smoother) without a Rerun file."""
    from scenarios.replay.pipeline import ReplayOptions, replay

    opt = ReplayOptions(tuning=str(tuning), t_from="T+60", t_to="T+430", targets=("earth", "sun"),
                        output=str(out), rrd="", progress=False, workers=workers)
    return replay(path, opt)


def run_study(heights=HEIGHTS_M, profiles=tuple(PROFILES), workdir: Path | None = None,
              on_row=lambda rows: None, edge: str = "limb", progress: bool = False) -> list[dict]:
    """Per case and camera the figures of `orbit_mismatch.flight_figures` (one simulated flight,
    rendered per case), with ``camera`` the log's camera number; ``on_row(rows)`` after each row
    (the rows so far); ``edge``: the edge the state describes (:func:`tuning_file`);
    ``progress``: a progress bar over the cases."""
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    from scenarios.study.orbit_mismatch import flight_figures, simulate_log

    sc = load_scenario("atek")
    flight = simulate_flight(sc, 0)
    workdir = Path(tempfile.mkdtemp(prefix="horizon-nav-atek-edge-")) if workdir is None else workdir
    tuning = tuning_file(workdir, edge)
    rows = []
    for case in cases(heights, profiles, progress):
        log = simulate_log(workdir / f"{case.name}.mcap", case, sc=sc, flight=flight)
        rr = replay_log(log, workdir / f"{case.name}.solution.mcap", tuning)
        for k, number in enumerate(rr.cam_numbers):
            rows.append(dict(flight_figures(rr, case, k), camera=int(number), edge=edge))
            on_row(rows)
        log.unlink()
    return rows


_HEAD = (f"{'case':<18}{'cam':>4}{'h true':>8}{'h smooth':>10}{'1sig':>6}{'RMS raw':>9}{'RMS':>8}{'state':>7}"
         f"{'other':>7}{'n oth':>6}{'at fits':>8}{'3s prior':>9}{'3s':>6}{'NEES in':>8}{'att sm':>8}")


def _line(r: dict) -> str:
    return (f"{r['case']:<18}{r['camera']:>4}{r['edge_truth_km']:>8.1f}{r['edge_smoothed_km']:>10.1f}"
            f"{r['edge_smoothed_sigma_km']:>6.1f}{r['nadir_rms_raw_deg']:>9.3f}{r['nadir_rms_deg']:>8.3f}"
            f"{r['nadir_rms_state_deg']:>7.3f}{r['nadir_rms_other_deg']:>7.3f}{r['frames'] - r['frames_with_sensitivity']:>6d}"
            f"{r['nadir_rms_fits_height_deg']:>8.3f}"
            f"{r['containment_prior']:>9.2f}{r['containment']:>6.2f}{r['nees_in_band']:>8.2f}"
            f"{r['att_rms_smoothed_deg']:>8.3f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m scenarios.study.atek_edge_flight",
                                 description="Edge-height model mismatch on the rendered ATEK flight, replayed end to end.")
    ap.add_argument("--heights", type=float, nargs="+", default=[h / 1e3 for h in HEIGHTS_M],
                    help="rendered threshold-edge heights [km] (default 0 10 25 45 60)")
    ap.add_argument("--profiles", nargs="+", default=list(PROFILES), choices=list(PROFILES))
    ap.add_argument("--edge", default="limb", choices=("limb", "threshold"),
                    help="the edge the edge-height state describes (default limb, docs/vision.md)")
    ap.add_argument("--workdir", type=Path, help="keep the solution logs here (default: a temporary directory)")
    ap.add_argument("--out", type=Path, help="write the per-case figures as JSON here")
    a = ap.parse_args(argv)
    from tqdm import tqdm
    quiet_filter_log()
    tqdm.write(_HEAD)

    def on_row(rows):
        tqdm.write(_line(rows[-1]))
        if a.out:   # after every row: an interrupted study keeps the cases it finished
            atomic_write_text(a.out, json.dumps(rows, indent=1))

    run_study([h * 1e3 for h in a.heights], a.profiles, a.workdir, on_row, a.edge, progress=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
