"""Maximum-likelihood tuning benchmarks (``horizon-nav tune``, scenarios/study/tune.py):

* ``tune.param_rel_err_max``: the largest relative error of the identified parameters on the
  simulated atek coast of tests/test_tune.py, whose true vector white noise, Gauss-Markov scale
  and GPS noise scale are set x0.3, x2.5 and x2 away from the prior;
* ``tune.minutes_demo``: wall time of ``tune`` (the default parameters, the simulated sensors'
  tuning scenarios/library/tuning/atek-sim.toml as prior) on
  the demo flight's log with its vectors (the vision cached: the simulator's vectors), T+60..T+430
  (QUICK: T+60..T+130, three parameters);
* ``filter.att_3sigma_final_deg_atek_tuned``: the final 3-sigma attitude bound of the filter with
  that estimate, with the RMS attitude error beside it;
* ``tune.nees_inside_band_fraction``: the share of epochs whose Monte Carlo attitude NEES is
  inside its 95 % band, for the filter tuned by ``tune`` from one flight of the Monte Carlo's
  model (tests/test_navigator.py ``consistency_study``), starting from atek-sim.toml (the
  simulated sensors' tuning, with the misalignment reset of docs/tuning.md).

Wall-clock figures are recorded, never asserted."""
from __future__ import annotations

import logging
import math
import time

import numpy as np

from nav.navigator import run
from scenarios.config.tuning import DEFAULT_TUNING_FILE, load_tuning
from scenarios.study.tune import DEFAULT_PARAMS, TuneInputs, tune
from tests.test_navigator import (VEC_GM_DEG, VEC_WHITE_DEG, attitude_errors, consistency_study, flight_inputs,
                                  truth_init)
from tests.test_tune import base_tuning, check_recovery, draw


#: the tuning the simulated flights ship with: the prior of the demo and consistency benchmarks
SIM_TUNING = DEFAULT_TUNING_FILE.parent / "atek-sim.toml"

#: the parameters QUICK estimates (the vectors' white noise and the GPS scale)
QUICK_PARAMS = ("vector_white_hor", "vector_white_sun", "gps_noise_scale")


def _recovery(bench):
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    fl = simulate_flight(load_scenario("atek"), seed=7, duration=200.0)
    truth = {"vector_white_hor": 0.3 * 0.002, "vector_cov_scale_hor": 2.5, "gps_noise_scale": 2.0}
    res = tune(draw(fl, 11, truth["vector_white_hor"], truth["vector_cov_scale_hor"], truth["gps_noise_scale"]),
               base_tuning(), list(truth), cameras=False)   # the drawn P_c scale is per target
    rel, cover = check_recovery(res, truth)
    bench("tune.param_rel_err_max", max(rel.values()) if rel else math.inf, "fraction", baseline=0.30,
          baseline_name="target 30 %", identified=len(rel), covered_3se=int(sum(cover.values())),
          notes="atek T+60..T+200, one draw; " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in rel.items()))


def _demo(bench, is_quick):
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    t_end = 130.0 if is_quick else 430.0
    fl = simulate_flight(load_scenario("atek"), seed=0, duration=t_end)
    fi = flight_inputs(fl, 60.0, seed=0, vec_sigma=math.radians(VEC_GM_DEG), white=math.radians(VEC_WHITE_DEG))
    inp = TuneInputs(fi.imu, truth_init(fi), fi.gps, fi.vectors, fi.R_bc_nominal)
    t0 = time.perf_counter()
    names = QUICK_PARAMS if is_quick else DEFAULT_PARAMS
    res = tune(inp, load_tuning(SIM_TUNING), names)
    minutes = (time.perf_counter() - t0) / 60
    bench("tune.minutes_demo", minutes, "min", baseline=10.0, baseline_name="target 10 min on 2 cores",
          evaluations=res.evaluations, s_per_evaluation=res.seconds_per_evaluation,
          notes=f"atek T+60..T+{t_end:g}, vectors given (vision cached), {len(names)} parameters; "
                f"identified {sum(e.identified for e in res.estimates)} of {len(res.estimates)}")
    out = run(fi.imu, truth_init(fi), res.tuning, gps=fi.gps, vectors=fi.vectors, R_bc=fi.R_bc_nominal,
              store_for_smoother=False, unaided=False)
    psi = attitude_errors(out.q_eb, fi.truth.q_eb[fi.truth_idx[fi.start_idx:]])
    rms = float(np.degrees(np.sqrt(np.mean(np.sum(psi ** 2, 1)))))
    sig3 = float(3 * np.degrees(np.sqrt(out.P_diag[-1, out.layout["psi"]].max())))
    bench("filter.att_3sigma_final_deg_atek_tuned", sig3, "deg", baseline=1.8,
          baseline_name="target 1.8 deg (003 §7, end of flight)",
          notes=f"T+{t_end:g}, tuning estimated by tune from the same flight; RMS attitude error {rms:.3f} deg, "
                f"final error {np.degrees(np.linalg.norm(psi[-1])):.3f} deg")
    return res


def _consistency(bench, is_quick):
    """Tune on one flight of the consistency study's model, then the study with that tuning."""
    from scenarios.sim import simulate as S
    from scenarios.sim.scenario import load_scenario
    from tests.test_navigator import _truth_cache
    sc, t_end, seed = load_scenario("atek"), 250.0, 99
    tr = _truth_cache("atek", t_end)
    imu, errs = S.simulate_imu(tr, sc.imu, S.rng_for(seed, S.STREAM_IMU))
    fl = S.FlightData(sc, seed, t_end, tr, imu, errs, S.simulate_gps(tr, sc.gps, S.rng_for(seed, S.STREAM_GPS)),
                      S.simulate_cameras(sc, tr, seed))
    fi = flight_inputs(fl, 60.0, seed=seed, vec_sigma=math.radians(VEC_GM_DEG), white=math.radians(VEC_WHITE_DEG))
    res = tune(TuneInputs(fi.imu, truth_init(fi), fi.gps, fi.vectors, fi.R_bc_nominal), load_tuning(SIM_TUNING),
               QUICK_PARAMS if is_quick else QUICK_PARAMS + ("gyro_white", "accel_white"))
    n = 4 if is_quick else 8
    st = consistency_study(n, t_end=t_end, tuning=res.tuning)
    bench("tune.nees_inside_band_fraction", st.inside_band_fraction("att"), "fraction", baseline=0.95,
          baseline_name="a consistent filter's share inside the 95 % band",
          notes=f"{n} runs, atek T+60..T+{t_end:g}, tuning estimated from one flight starting at atek-sim.toml; "
                f"time-averaged attitude NEES {st.time_avg('att'):.2f} (band {st.band['att'][0]:.2f}.."
                f"{st.band['att'][1]:.2f}); NIS means " + ", ".join(f"{k} {v:.2f}" for k, v in st.nis_mean.items()))


def test_bench_tune(bench, is_quick):
    logging.disable(logging.WARNING)
    try:
        _recovery(bench)
        _consistency(bench, is_quick)
        _demo(bench, is_quick)
    finally:
        logging.disable(logging.NOTSET)
