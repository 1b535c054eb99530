"""Edge-height model mismatch (scenarios/study/edge_mismatch.py): ATEK frames rendered with the
limb's brightness edge at 0, 10, 25, 45 and 60 km and a second limb profile, processed with the
front end's defaults. Records vision.mismatch_nadir_rms_deg_max (worst nadir RMS over the edge
heights of the standard profile; baseline: the nadir RMS at the default height, 45 km, same run)
and vision.mismatch_containment_min (worst per-frame 3-sigma containment over every case;
baseline the acceptance's 0.97). QUICK: 12 frames, else 48 frames over the coast.
"""
from __future__ import annotations

from scenarios.study.edge_mismatch import NOMINAL_EDGE_M, run_study


def test_bench_edge_mismatch(bench, is_quick):
    rows = run_study(12 if is_quick else 48)
    std = [r for r in rows if r["profile"] == "standard"]
    clean = next(r for r in std if r["height_km"] == NOMINAL_EDGE_M / 1e3)
    worst = max(std, key=lambda r: r["nadir_rms_deg"])
    table = {r["case"]: {k: r[k] for k in ("found", "frames", "wrong_edge", "nadir_rms_deg", "containment",
                                           "edge_est_median_km", "edge_truth_median_km")} for r in rows}
    bench("vision.mismatch_nadir_rms_deg_max", worst["nadir_rms_deg"], "deg", baseline=clean["nadir_rms_deg"],
          baseline_name="nadir RMS at the default edge height (45 km), same frames, same run",
          worst_case=worst["case"], cases=table)
    cmin = min(rows, key=lambda r: r["containment"])
    bench("vision.mismatch_containment_min", cmin["containment"], "fraction", baseline=0.97,
          baseline_name="acceptance: per-frame 3-sigma containment >= 0.97 at every edge height",
          worst_case=cmin["case"], found=cmin["found"], frames=cmin["frames"],
          found_fraction_min=min(r["found"] / r["frames"] for r in rows))
