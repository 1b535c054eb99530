"""Ephemeris accuracy (against astropy, offline) and speed (against astropy in the same run)."""
import time
import warnings

import numpy as np

from nav import ephemeris as E, timescales as T
from tests.test_ephemeris import _angle_deg, _astropy_itrs, _random_epochs


def test_bench_ephemeris(bench, is_quick, astropy_offline):
    warnings.filterwarnings("ignore")
    n = 200 if is_quick else 1000
    t = _random_epochs(n=n, seed=21)
    sun_err = _angle_deg(E.sun_position_e(t, beyond_table="hold"), _astropy_itrs("sun", t))
    moon_err = _angle_deg(E.moon_position_e(t, beyond_table="hold"), _astropy_itrs("moon", t))
    bench("ephem.sun_max_err_deg", sun_err.max(), "deg", baseline=0.005, baseline_name="acceptance bound 0.005 deg",
          epochs=int(n), span="1990-2050", ut1="UT1=UTC (dut1_s=0)")
    bench("ephem.moon_max_err_deg", moon_err.max(), "deg", baseline=0.05, baseline_name="acceptance bound 0.05 deg",
          epochs=int(n))

    # Speed: one scalar call per epoch, as the filter makes them; baseline astropy get_sun -> ITRS.
    from astropy.coordinates import ITRS, get_sun
    from astropy.time import Time

    m = 200 if is_quick else 1000
    ts = [int(x) for x in t[:m] if x < T.LEAP_TABLE_EXPIRES][:m]
    t0 = time.perf_counter()
    for x in ts:
        E.sun_position_e(x)
    ours = len(ts) / (time.perf_counter() - t0)
    k = 30 if is_quick else 100
    t0 = time.perf_counter()
    for x in ts[:k]:
        at = Time(x / 1e9, format="unix", scale="utc")
        get_sun(at).transform_to(ITRS(obstime=at))
    ref = k / (time.perf_counter() - t0)
    bench("ephem.sun_calls_per_s", ours, "calls/s", baseline=ref,
          baseline_name="astropy get_sun + ITRS, scalar calls, same run")
    # vectorised form, for reference
    t0 = time.perf_counter()
    E.sun_position_e(np.array(ts))
    vec_rate = len(ts) / (time.perf_counter() - t0)
    bench("ephem.sun_vectorised_epochs_per_s", vec_rate, "epochs/s", baseline=ours,
          baseline_name="scalar calls of sun_position_e (ephem.sun_calls_per_s), same run")
    assert sun_err.max() <= 0.005 and moon_err.max() <= 0.05
