"""Strapdown IMU model: ideal samples from the truth, then the errors of 003 table 3.

Ideal samples (error free, at ``t_k = k / rate``, k >= 1):

* ``sample = "point"``: ``omega_ib_b(t_k)`` and ``f_b(t_k)`` (the right limit at an RCS switch);
* ``sample = "average"``: the mean over ``(t_k - dt, t_k]``, i.e. ``(int(t_k) - int(t_k - dt)) / dt``
  from the integrals the truth integrator carries (exact to the RK4 accuracy);
* ``output = "increment"``: the integrals themselves, ``delta_angle = int omega_ib_b dt`` and
  ``delta_velocity = int f_b dt`` over the interval. These are plain integrals of the body-frame
  signals: with coning or sculling motion they differ from a rotation vector / a velocity change in a
  fixed frame by the second-order terms a strapdown algorithm corrects for.

Measurement model (per sensor triad, 003 table 3)::

    y = M x + b + n,   M = I + diag(s) + N_off,

with the scale factors ``s`` (N(0, sigma_s^2) per axis), the misalignment ``N_off`` (six independent
off-diagonal elements, N(0, sigma_m^2): non-orthogonal axes), the turn-on bias ``b`` (N(0, sigma_b^2)
per axis), all drawn once per run, and white noise ``n``. Optionally (``gyro_gm_deg_h`` > 0) the gyro
bias also carries a first-order Gauss-Markov drift ``g_k = phi g_(k-1) + sigma sqrt(1 - phi^2) w_k``,
``phi = exp(-dt / gyro_gm_tau_s)``, started from its stationary distribution N(0, sigma^2) (drawn
after the turn-on errors, so a scenario without it draws the same numbers as before). A white-noise density N (angular / velocity
random walk) gives a per-sample standard deviation ``N / sqrt(dt)`` for rate outputs (the variance of
the mean of white noise over dt) and ``N sqrt(dt)`` for increments. Units: gyro N in deg/sqrt(h)
= (deg/s)/sqrt(Hz) / 60; accelerometer N in mg/sqrt(Hz).

Then saturation (clip at +-range; increments at +-range * dt) and quantisation. Rates are rounded to
a grid of the resolution ``q`` whose phase ``u`` relative to the true zero rate is drawn per run and
per axis, ``u ~ U(0, q)`` (after the noise, from the same generator)::

    y_q = round((y - u) / q) q + u.

The converter counts ``round((y + o) / q)`` with a zero offset ``o`` of many quanta, which the
calibration removes (``y_q = counts q - o``); the fractional part of ``o / q`` is arbitrary, hence
``u = -o mod q`` uniform. For any input the error ``y_q - y`` is then uniform on [-q/2, q/2) over runs,
with mean zero, while within a run it keeps the time correlation of the rounding of a slowly varying
rate (a run's error is a deterministic function of ``y - u``). With ``rng`` None (no noise) the grid
is aligned with zero (``u = 0``). Increments are quantised with the residual carried to the next
sample (the sum of the outputs stays within one quantum of the sum of the inputs, as in a
pulse-counting sensor).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenarios.sim.scenario import G0, ImuConfig
from scenarios.sim.truth import Truth

DEG_RT_H = np.pi / 180.0 / 60.0  # 1 deg/sqrt(h) in rad/sqrt(s)
MG = 1e-3 * G0


@dataclass
class ImuSamples:
    """IMU output: ``t`` [s after lift-off] (N,), ``gyro`` (N, 3) [rad/s or rad], ``accel`` (N, 3)
    [m/s^2 or m/s] in b, ``output`` ("rate" or "increment"), ``dt`` the sample interval [s]."""
    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    output: str
    dt: float


@dataclass
class ImuErrors:
    """Errors drawn for one run: ``M_g``, ``M_a`` (3, 3) = I + scale + misalignment; biases [rad/s],
    [m/s^2]; the scale factors and misalignments also separately for reporting."""
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    gyro_scale: np.ndarray
    accel_scale: np.ndarray
    gyro_misalignment: np.ndarray  # (3, 3), zero diagonal
    accel_misalignment: np.ndarray
    gyro_gm: np.ndarray | None = None  # (N, 3) Gauss-Markov gyro drift at each sample [rad/s]; None: none

    @property
    def M_g(self) -> np.ndarray:
        return np.eye(3) + np.diag(self.gyro_scale) + self.gyro_misalignment

    @property
    def M_a(self) -> np.ndarray:
        return np.eye(3) + np.diag(self.accel_scale) + self.accel_misalignment


def _stride(truth: Truth, rate_hz: float) -> int:
    truth_rate = 1.0 / truth.dt
    m = int(round(truth_rate / rate_hz))
    if m < 1 or abs(m * rate_hz - truth_rate) > 1e-6 * truth_rate:
        raise ValueError(f"imu rate {rate_hz} Hz must divide the truth rate {truth_rate:g} Hz")
    return m


def ideal_imu(truth: Truth, rate_hz: float, output: str = "rate", sample: str = "average") -> ImuSamples:
    """Error-free IMU samples from the truth (see the module docstring)."""
    m = _stride(truth, rate_hz)
    dt = m * truth.dt
    idx = np.arange(m, len(truth.t), m)
    if output == "increment" or sample == "average":
        dth = truth.int_omega_b[idx] - truth.int_omega_b[idx - m]
        dv = truth.int_f_b[idx] - truth.int_f_b[idx - m]
        if output == "increment":
            return ImuSamples(truth.t[idx], dth, dv, "increment", dt)
        return ImuSamples(truth.t[idx], dth / dt, dv / dt, "rate", dt)
    if sample != "point":
        raise ValueError(f"imu sample {sample!r}: expected 'average' or 'point'")
    return ImuSamples(truth.t[idx], truth.omega_ib_b[idx].copy(), truth.f_b[idx].copy(), "rate", dt)


def draw_imu_errors(cfg: ImuConfig, rng: np.random.Generator) -> ImuErrors:
    """Turn-on errors of 003 table 3, drawn once per run (order: gyro bias, scale, misalignment,
    then the same for the accelerometers)."""
    def off(sigma):
        a = rng.normal(0.0, sigma, (3, 3))
        np.fill_diagonal(a, 0.0)
        return a
    gb = rng.normal(0.0, np.radians(cfg.gyro_bias_deg_h) / 3600.0, 3)
    gs = rng.normal(0.0, cfg.gyro_scale_ppm * 1e-6, 3)
    gm = off(cfg.gyro_misalignment_mrad * 1e-3)
    ab = rng.normal(0.0, cfg.accel_bias_mg * MG, 3)
    as_ = rng.normal(0.0, cfg.accel_scale_ppm * 1e-6, 3)
    am = off(cfg.accel_misalignment_mrad * 1e-3)
    return ImuErrors(gb, ab, gs, as_, gm, am)


def gauss_markov_drift(n: int, dt: float, sigma, tau, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) first-order Gauss-Markov sequence of stationary 1-sigma ``sigma`` and correlation time
    ``tau`` [s] (each one value or one per axis) sampled every ``dt`` [s], starting from its
    stationary distribution (module docstring)."""
    from scipy.signal import lfilter
    phi = np.exp(-dt / np.asarray(tau, float))
    e = rng.normal(0.0, sigma, (n, 3))
    e[1:] *= np.sqrt(1.0 - phi * phi)
    if phi.ndim == 0:
        return lfilter([1.0], [1.0, -phi], e, axis=0)
    return np.stack([lfilter([1.0], [1.0, -p], e[:, i]) for i, p in enumerate(phi)], axis=1)


def noise_sigmas(cfg: ImuConfig, output: str, dt: float) -> tuple[float, float]:
    """Per-sample white-noise standard deviations (gyro, accel) for the output type."""
    ng = cfg.gyro_noise_deg_rt_h * DEG_RT_H
    na = cfg.accel_noise_mg_rt_hz * MG
    if output == "increment":
        return ng * np.sqrt(dt), na * np.sqrt(dt)
    return ng / np.sqrt(dt), na / np.sqrt(dt)


def _quantise_carry(x: np.ndarray, q: float) -> np.ndarray:
    """Quantise increments with the residual carried forward: outputs are differences of the
    rounded cumulative sum."""
    c = np.round(np.cumsum(x, axis=0) / q) * q
    return np.diff(np.concatenate([np.zeros((1, x.shape[1])), c]), axis=0)


def _quantise_rate(x: np.ndarray, q: float, u: np.ndarray | float) -> np.ndarray:
    """Round rates to the grid ``u + k q`` (``u`` per axis, broadcast over samples)."""
    return np.round((x - u) / q) * q + u


def apply_errors(ideal: ImuSamples, cfg: ImuConfig, errors: ImuErrors | None,
                 rng: np.random.Generator | None) -> ImuSamples:
    """Measured samples: errors (None: none), noise and quantum-grid phase (rng None: none, grid at
    zero), saturation, quantisation."""
    dt = ideal.dt
    inc = ideal.output == "increment"
    g, a = ideal.gyro, ideal.accel
    if errors is not None:
        k = dt if inc else 1.0
        g = g @ errors.M_g.T + errors.gyro_bias * k
        if errors.gyro_gm is not None:
            g = g + errors.gyro_gm * k
        a = a @ errors.M_a.T + errors.accel_bias * k
    if rng is not None:
        sg, sa = noise_sigmas(cfg, ideal.output, dt)
        g = g + rng.normal(0.0, sg, g.shape)
        a = a + rng.normal(0.0, sa, a.shape)
    k = dt if inc else 1.0
    g = np.clip(g, -np.radians(cfg.gyro_range_dps) * k, np.radians(cfg.gyro_range_dps) * k)
    a = np.clip(a, -cfg.accel_range_g * G0 * k, cfg.accel_range_g * G0 * k)
    qg = np.radians(cfg.gyro_resolution_dps) * k
    qa = cfg.accel_resolution_mg * MG * k
    ug = rng.uniform(0.0, qg, 3) if rng is not None and qg > 0 and not inc else 0.0
    ua = rng.uniform(0.0, qa, 3) if rng is not None and qa > 0 and not inc else 0.0
    if qg > 0:
        g = _quantise_carry(g, qg) if inc else _quantise_rate(g, qg, ug)
    if qa > 0:
        a = _quantise_carry(a, qa) if inc else _quantise_rate(a, qa, ua)
    return ImuSamples(ideal.t, g, a, ideal.output, dt)


def simulate_imu(truth: Truth, cfg: ImuConfig, rng: np.random.Generator,
                 with_errors: bool = True) -> tuple[ImuSamples, ImuErrors]:
    """IMU output of a flight: ideal samples, turn-on errors and noise drawn from ``rng``."""
    ideal = ideal_imu(truth, cfg.rate_hz, cfg.output, cfg.sample)
    errors = draw_imu_errors(cfg, rng)
    if with_errors and np.any(np.asarray(cfg.gyro_gm_deg_h) > 0):
        errors.gyro_gm = gauss_markov_drift(ideal.t.size, ideal.dt, np.radians(cfg.gyro_gm_deg_h) / 3600.0,
                                            cfg.gyro_gm_tau_s, rng)
    if not with_errors:
        zero = ImuErrors(*(np.zeros_like(x) for x in (errors.gyro_bias, errors.accel_bias, errors.gyro_scale,
                                                      errors.accel_scale, errors.gyro_misalignment,
                                                      errors.accel_misalignment)))
        return apply_errors(ideal, cfg, None, None), zero
    return apply_errors(ideal, cfg, errors, rng), errors
