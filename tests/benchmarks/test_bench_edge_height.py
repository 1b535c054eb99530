"""Edge-height state benchmark: atek-nav-grade with the Earth's edge at 10 km, its horizon vectors
fitted at the 45 km prior (truth vectors with the fixed-height fit's sensitivity,
scenarios/sim/truth_vectors.py), the filter's h_e state estimated; error of the smoothed edge height
(worst camera). Baseline: the issue's acceptance bound of 3 km. QUICK: T+60..T+140, else T+60..T+430.
An accuracy figure, not a timing."""
from __future__ import annotations

import numpy as np

from tests.test_edge_height_filter import PRIOR_EDGE_M, TRUE_EDGE_M, edge_height_acceptance


def test_bench_edge_height(bench, is_quick):
    t_end = 140.0 if is_quick else 430.0
    a = edge_height_acceptance(t_end)
    err = np.abs(a["error_m"]) / 1e3
    bench("filter.edge_height_error_km", float(err.max()), "km", baseline=3.0, baseline_name="acceptance bound 3 km",
          smoothed_km=np.round(a["smoothed_m"] / 1e3, 3).tolist(), sigma_km=np.round(a["sigma_m"] / 1e3, 3).tolist(),
          notes=f"atek-nav-grade T+60..T+{t_end:g}, true edge {TRUE_EDGE_M / 1e3:g} km, prior "
                f"{PRIOR_EDGE_M / 1e3:g} +- 20 km; smoothed per camera {np.round(a['smoothed_m'] / 1e3, 2).tolist()} km "
                f"(1 sigma {np.round(a['sigma_m'] / 1e3, 2).tolist()} km)")
