"""Which noise parameters can a flight tell apart? A Monte Carlo of likelihood-ratio tests that
checks ``tune``'s identification (``horizon-nav identify``, docs/tuning.md).

``tune`` calls a parameter unidentified when the standard error of its logarithm, from the
Fisher information of one flight, is at least ln 2. This module checks that claim without the
information matrix: for each parameter it simulates ``runs`` flights of the same scenario and
window, half with the parameter at ``1/factor`` of the tuning's value and half at ``factor``
times it (every other parameter at the tuning's value), and computes on each flight the
log-likelihood ratio of the two hypotheses,

    Lambda = -log L(theta_lo) - (-log L(theta_hi))         (positive: the data favour theta_hi)

(two filter replays per flight, :class:`scenarios.study.tune.Objective`, every group estimated, no
gate). The most powerful test of size 5 % between the two (Neyman-Pearson) rejects theta_lo when
Lambda exceeds its 95 % quantile under theta_lo; the Monte Carlo estimates that quantile from the
theta_lo flights and the test's *power*, the fraction of theta_hi flights above it. A power near
0.05 means one flight cannot distinguish a factor ``factor**2`` in the parameter; near 1, it can.

For a log-parameter whose estimate is Gaussian with standard error ``se`` the power is

    Phi(2 ln(factor) / se - 1.645)

(:func:`predicted_power`): with factor 2 it is 0.64 at ``se = ln 2``, ``tune``'s flat-likelihood
threshold, below it for a larger ``se``, and 1 - 1e-9 at ``se = ln(1.3) / 3``, the threshold
of *identified*. :func:`identifiability` also runs ``tune`` on one flight at the tuning's values
and reports its verdict and standard error beside the Monte Carlo power. The test knows the other
parameters (their true values), so its power bounds from above what a flight can do without them,
and is at least the power predicted from ``tune``'s marginal standard error.

The flights are simulated from the filter's own model, without the vision (vectors are the true
directions plus the vision error model, :func:`scenarios.study.runner.simulated_vectors`): IMU
white noise and turn-on biases drawn with the tuning's values, the Gauss-Markov gyro drift when the
tuning has the state on, gyro quantisation and axis misalignment off (the filter models neither as
drawn); GPS errors ``gps_noise_scale`` times the receiver's logged sigmas; vector errors
``cov_scale`` times the predicted vision covariance as a Gauss-Markov process of the tuning's
``T_c``, plus the tuning's white noise; the initial state drawn with the tuning's initial sigmas.
The flights are independent tasks: they run in this process, on local processes or on a Dask
cluster (:func:`scenarios.study.tune.executor_mapper`).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from scenarios.study.tune import PARAMS, Objective, TuneInputs

#: random stream of the initial-state error (the simulator's streams are 1, 2 and 100 + k)
INIT_STREAM = 400
#: the test's size
ALPHA = 0.05
Z_ALPHA = 1.6448536269514722   #: its one-sided normal quantile
MG = 1e-3 * 9.80665
DEG_H = math.radians(1.0) / 3600.0
DEG_RTH = math.radians(1.0) / 60.0


@dataclass(frozen=True)
class McTask:
    """One simulated flight: parameter ``name`` at ``factor`` times the tuning's value."""
    name: str
    hypothesis: str      #: "lo" or "hi"
    seed: int


def predicted_power(se: float, factor: float) -> float:
    """Power of the 5 % likelihood-ratio test between ``1/factor`` and ``factor`` times a
    parameter whose log-estimate is Gaussian with standard error ``se`` (module docstring)."""
    from scipy.stats import norm
    if not np.isfinite(se) or se <= 0:
        return ALPHA if not np.isfinite(se) else 1.0
    return float(norm.cdf(2.0 * math.log(factor) / se - Z_ALPHA))


def _imu_config(cfg, tun):
    """The scenario's IMU with the tuning's white noises, bias and drift sigmas, or its rate
    quantum where the tuning's Gauss-Markov gyro error is that rounding; no other quantisation,
    no axis misalignment."""
    quantum = math.degrees(tun.gyro_gm_quantum) if tun.gyro_gm.on else 0.0
    # a drift per body axis, unless the Gauss-Markov state is the rate output's rounding (simulated as such)
    gm = tuple(tun.gyro_gm_sigmas() / DEG_H) if tun.gyro_gm.on and quantum == 0 else 0.0
    return dataclasses.replace(cfg, gyro_noise_deg_rt_h=tun.gyro_white / DEG_RTH, accel_noise_mg_rt_hz=tun.accel_white / MG,
                               gyro_bias_deg_h=tun.gyro_bias.sigma / DEG_H if tun.gyro_bias.on else 0.0,
                               accel_bias_mg=tun.accel_bias.sigma / MG if tun.accel_bias.on else 0.0,
                               gyro_resolution_dps=quantum, accel_resolution_mg=0.0, gyro_misalignment_mrad=0.0,
                               accel_misalignment_mrad=0.0, gyro_gm_deg_h=gm, gyro_gm_tau_s=tun.gyro_gm_tau_s)


def _gps(tr, cfg, scale: float, rng, t0: float, t1: float):
    """GPS fixes in the window whose errors are ``scale`` times the logged sigmas."""
    from nav.navigator import GpsData
    from scenarios.sim.gps import simulate_gps
    if not cfg.enabled:
        return None
    gp = simulate_gps(tr, dataclasses.replace(cfg, position_sigma_m=scale * cfg.position_sigma_m,
                                              velocity_sigma_mps=scale * cfg.velocity_sigma_mps), rng)
    m = (gp.t >= t0 - 1e-9) & (gp.t <= t1 + 1e-9)
    n = int(m.sum())
    if n == 0:
        return None
    t_ns = tr.liftoff_ns + np.round(gp.t[m] * 1e9).astype(np.int64)
    return GpsData(t_ns, gp.position[m], np.tile(gp.position_cov / scale ** 2, (n, 1, 1)), gp.velocity[m],
                   np.tile(gp.velocity_cov / scale ** 2, (n, 1, 1)))


def _vectors(sc, tr, cams, seed: int, tun, t0: float, t1: float):
    """Simulated vectors of every target of the tuning: each with its own error scale and white
    noise (:func:`scenarios.study.runner.simulated_vectors` per target)."""
    from nav.navigator import VectorData
    from scenarios.study.runner import TARGETS, simulated_vectors
    from scenarios.study.studyfile import RunConfig
    parts = []
    for tg in TARGETS:
        if tg not in tun.targets:
            continue
        rc = RunConfig(t_start_s=t0, t_end_s=t1, correlation_time_s=tun.correlation_time_s,
                       error_scale=tun.vector_cov_scale_for(tg), gm_fraction=1.0)
        parts.append(simulated_vectors(sc, tr, cams, seed, rc, (tg,), tun.vector_white_for(tg)))
    t = np.concatenate([p.t_ns for p in parts]) if parts else np.zeros(0, np.int64)
    if t.size == 0:
        return None
    o = np.argsort(t, kind="stable")
    cat = [np.concatenate([getattr(p, f) for p in parts])[o] for f in ("t_ns", "camera", "target", "e_c", "P_c")]
    return VectorData(*cat)


def simulate_inputs(sc, tun, seed: int, t0: float, t1: float) -> TuneInputs:
    """A flight of scenario ``sc`` over ``[t0, t1]`` drawn from the filter model of ``tun``
    (module docstring)."""
    from nav.navigator import ImuData, InitialState
    from nav.rotation import matrix_to_quat, quat_to_matrix, rotvec_to_matrix
    from scenarios.sim import simulate as S
    from scenarios.study.runner import cached_truth
    tr = cached_truth(sc, t1)
    imu, _ = S.simulate_imu(tr, _imu_config(sc.imu, tun), S.rng_for(seed, S.STREAM_IMU))
    keep = imu.t <= t1 + 1e-9
    g, a = (imu.gyro / imu.dt, imu.accel / imu.dt) if imu.output == "increment" else (imu.gyro, imu.accel)
    sample = "average" if (imu.output == "increment" or sc.imu.sample == "average") else "point"
    t_ns = tr.liftoff_ns + np.round(imu.t[keep] * 1e9).astype(np.int64)
    start = int(np.searchsorted(imu.t[keep], t0 - 1e-9))
    cams = S.simulate_cameras(sc, tr, seed) if sc.cameras else []
    rng = S.rng_for(seed, INIT_STREAM)
    i0 = int(round(imu.t[start] / tr.dt))
    dpsi = rng.normal(0.0, tun.init_att_sigma, 3)
    x0 = tr.x_e[i0] - rng.normal(0.0, tun.init_pos_sigma, 3)
    v0 = tr.v_e[i0] - rng.normal(0.0, tun.init_vel_sigma, 3)
    q0 = matrix_to_quat(rotvec_to_matrix(-dpsi) @ quat_to_matrix(tr.q_eb[i0]))
    return TuneInputs(ImuData(t_ns[start:], a[keep][start:], g[keep][start:], sample),
                      InitialState(int(t_ns[start]), x0, v0, q0), _gps(tr, sc.gps, tun.gps_noise_scale,
                                                                     S.rng_for(seed, S.STREAM_GPS), t0, t1),
                      _vectors(sc, tr, cams, seed, tun, t0, t1) if cams else None, [c.R_bc_nominal for c in cams])


def llr(sc, tun, task: McTask, factor: float, t0: float, t1: float) -> float:
    """Lambda of one flight drawn with ``task.name`` at ``factor**(-1 or +1)`` times ``tun``'s value."""
    import logging
    logging.getLogger("nav.navigator").setLevel(logging.ERROR)
    p = PARAMS[task.name]
    v = p.get(tun)
    truth = p.set(tun, v * (factor if task.hypothesis == "hi" else 1.0 / factor))
    obj = Objective(simulate_inputs(sc, truth, task.seed, t0, t1), tun, [p])
    th = math.log(v)
    f_lo = obj(np.array([th - math.log(factor)]))[0]
    f_hi = obj(np.array([th + math.log(factor)]))[0]
    return float(f_lo - f_hi)


def _llr_task(args) -> float:
    return llr(*args)


@dataclass
class ParamPower:
    """The Monte Carlo of one parameter and ``tune``'s verdict on the reference flight."""
    name: str
    lam_lo: np.ndarray     #: Lambda on the flights at 1/factor
    lam_hi: np.ndarray     #: Lambda on the flights at factor
    status: str            #: tune's verdict on the reference flight
    se_log: float          #: tune's standard error there
    factor: float

    @property
    def threshold(self) -> float:
        """The 95 % quantile of Lambda under theta_lo (the test's critical value)."""
        return float(np.quantile(self.lam_lo, 1.0 - ALPHA))

    @property
    def power(self) -> float:
        return float(np.mean(self.lam_hi > self.threshold))

    @property
    def power_se(self) -> float:
        """Binomial standard error of the power (the quantile's own error not included)."""
        p = self.power
        return math.sqrt(max(p * (1 - p), 1.0 / self.lam_hi.size) / self.lam_hi.size)

    @property
    def predicted(self) -> float:
        return predicted_power(self.se_log, self.factor)

    def line(self) -> str:
        return (f"{self.name:22s} tune: {self.status:12s} SE {self.se_log:6.3f}  MC power {self.power:5.2f} "
                f"+- {self.power_se:4.2f} ({self.lam_lo.size}+{self.lam_hi.size} flights; predicted from SE "
                f"{self.predicted:4.2f})")


@dataclass
class IdentifiabilityResult:
    params: list
    runs: int
    seconds: float
    factor: float

    def report(self) -> str:
        head = (f"likelihood-ratio test x1/{self.factor:g} against x{self.factor:g} at 5 %: power per parameter "
                f"({self.runs} flights, {self.seconds:.0f} s)")
        return "\n".join([head] + [p.line() for p in self.params])

    def table(self):
        import pandas as pd
        return pd.DataFrame([{"param": p.name, "status": p.status, "se_log": p.se_log, "power": p.power,
                              "power_se": p.power_se, "predicted_power": p.predicted, "threshold": p.threshold,
                              "flights_lo": p.lam_lo.size, "flights_hi": p.lam_hi.size} for p in self.params])


def reference_tune(sc, tun, names, t0: float, t1: float, seed: int = 0, mapper=map) -> dict:
    """``tune``'s estimates (name -> Estimate) of the parameters of ``names`` the flight carries,
    on one flight at ``tun``'s values."""
    from scenarios.study.tune import available, tune
    inp = simulate_inputs(sc, tun, seed, t0, t1)
    kinds = ({"gps_pos", "gps_vel"} if inp.gps is not None else set()) | (
        set(np.unique(inp.vectors.target).tolist()) if inp.vectors is not None else set())
    # the simulated vectors draw one P_c scale per target (:func:`_vectors`): estimated per target
    params, _why = available(list(names), tun, kinds, cameras=False)
    return tune(inp, tun, [p.name for p in params], mapper=mapper, cameras=False).by_name()


def identifiability(sc, tun, names, *, runs: int = 200, control_runs: int = 40, factor: float = 2.0,
                    t0: float = 60.0, t1: float = 120.0, seed0: int = 10_000, mapper=map, progress=None,
                    reference_seed: int = 0, reference: dict | None = None) -> IdentifiabilityResult:
    """The Monte Carlo of the module docstring for the parameters ``names``: ``tune`` on one
    flight (``reference_seed``) at ``tun``'s values, then ``runs`` flights (half at ``1/factor``,
    half at ``factor``) for each parameter it does not call identified and ``control_runs`` for
    each it does (their power is ~1: a few flights show it); ``reference`` (name -> Estimate of an
    earlier :func:`reference_tune`) skips that tune. Parameters the flight cannot carry
    (no measurement they need, state off) are left out. ``mapper`` runs the flights (e.g.
    :func:`scenarios.study.tune.executor_mapper`); ``progress`` (tqdm-like) is advanced per flight."""
    for n, what in ((runs, "runs"), (control_runs, "control_runs")):
        if n < 4 or n % 2:
            raise ValueError(f"{what} = {n}: expected an even number >= 4 (half per hypothesis)")
    if not factor > 1.0:
        raise ValueError(f"factor = {factor}: expected > 1")
    t_start = time.perf_counter()
    ref = reference if reference is not None else reference_tune(sc, tun, names, t0, t1, reference_seed, mapper)
    names = [n for n in names if n in ref]
    n_of = {n: control_runs if ref[n].identified else runs for n in names}
    tasks = [McTask(n, h, seed0 + k) for n in names for h in ("lo", "hi") for k in range(n_of[n] // 2)]
    lam = []
    for x in mapper(_llr_task, [(sc, tun, t, factor, t0, t1) for t in tasks]):
        lam.append(x)
        if progress is not None:
            progress.update(1)
    out, i = [], 0
    for n in names:
        h = n_of[n] // 2
        out.append(ParamPower(n, np.array(lam[i:i + h]), np.array(lam[i + h:i + 2 * h]), ref[n].status,
                              ref[n].se_log, factor))
        i += 2 * h
    return IdentifiabilityResult(out, len(tasks), time.perf_counter() - t_start, factor)
