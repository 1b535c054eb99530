"""The two readings of the NEES band in scenarios/study/report.py against closed forms: each run's
value against the band of one chi2(3) value, and the N-run mean against the band of a mean."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.stats import chi2

from scenarios.study.report import band_fraction, run_band_fraction


def _series(values: np.ndarray) -> pd.DataFrame:
    """A study series of attitude NEES: ``values`` (runs, epochs) at 1-s epochs T+60.."""
    runs, epochs = values.shape
    t = np.tile(60.0 + np.arange(epochs), runs)
    return pd.DataFrame({"variant": 0, "run_index": np.repeat(np.arange(runs), epochs), "quantity": "nees_att",
                         "t_s": t, "value": values.ravel(), "dof": 3.0})


def test_run_band_fraction_of_a_consistent_and_a_cautious_filter():
    """chi2(3) draws (a consistent filter): 95 % of 40 000 run-epochs inside [0.216, 9.35], 2.5 %
    on either side, to 4 binomial sigmas (0.0044 and 0.0031). The same draws times 0.95 (5 %
    cautious, the shipped ATEK tuning's pooled mean NEES 2.84): each run-epoch's share stays near
    0.95 (closed form P(0.216 / 0.95 <= chi2(3) <= 9.35 / 0.95) = 0.9480), while the 200-run mean
    falls below its band [2.67, 3.35] at a rate that the closed form of a normal mean gives."""
    rng = np.random.default_rng(7)
    x = rng.chisquare(3, size=(200, 200))
    r = run_band_fraction(_series(x), 0, windows=((60.0, 160.0),))
    n = x.size
    assert r["all"]["epochs"] == n and r[(60.0, 160.0)]["epochs"] == n // 2
    assert r["all"]["inside"] == pytest.approx(0.95, abs=4 * np.sqrt(0.95 * 0.05 / n))
    for side in ("above", "below"):
        assert r["all"][side] == pytest.approx(0.025, abs=4 * np.sqrt(0.025 * 0.975 / n))
    lo, hi = chi2.ppf([0.025, 0.975], 3)
    assert (lo, hi) == pytest.approx((0.2158, 9.348), abs=1e-3)
    c = run_band_fraction(_series(0.95 * x), 0)["all"]
    p = chi2.cdf(hi / 0.95, 3) - chi2.cdf(lo / 0.95, 3)
    assert c["inside"] == pytest.approx(p, abs=4 * np.sqrt(p * (1 - p) / n))
    # the 200-run mean: mean 0.95 * 3, sd 0.95 * sqrt(6 / 200); below its band's lower end
    m = band_fraction(_series(0.95 * x), 0)["all"]
    lo_m = chi2.ppf(0.025, 600) / 200
    p_below = chi2.cdf(lo_m * 200 / 0.95, 600)
    assert m["below"] == pytest.approx(p_below, abs=4 * np.sqrt(p_below * (1 - p_below) / 200))
    assert m["below"] > 3 * c["below"]
