"""GNSS receiver model: ECEF position and velocity fixes with white noise, latency and outages.

A fix stamped ``t_k = k / rate`` (k >= 0, outside the outage windows and the flight) reports
``x_e(t_k - latency) + n_x`` and ``v_e(t_k - latency) + n_v`` with ``n ~ N(0, sigma^2 I)`` per ECEF axis
(an uncompensated receiver latency: the stamp is late by ``latency``). The reported covariances are
``sigma^2 I``. The truth between its samples is interpolated: position by the cubic Hermite polynomial
through the neighbouring positions and velocities (error ~ dt^4 |jerk| / 384, micrometres at 400 Hz),
velocity linearly (error <= dt^2 |da/dt| / 8, < 1 mm/s for the jerks of a sounding rocket at 400 Hz).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenarios.sim.scenario import GpsConfig
from scenarios.sim.truth import Truth


@dataclass
class GpsFixes:
    """``t`` [s after lift-off] (N,), ``position`` / ``velocity`` (N, 3) ECEF, ``position_cov`` /
    ``velocity_cov`` (3, 3) reported covariances, ``num_satellites``."""
    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    position_cov: np.ndarray
    velocity_cov: np.ndarray
    num_satellites: int


def truth_at(truth: Truth, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (cubic Hermite) and velocity (linear) of the truth at times ``t`` [s]."""
    t = np.asarray(t, dtype=float)
    if np.any(t < truth.t[0] - 1e-12) or np.any(t > truth.t[-1] + 1e-12):
        raise ValueError("truth_at: time outside the simulated flight")
    i = np.clip(np.floor((t - truth.t[0]) / truth.dt).astype(int), 0, len(truth.t) - 2)
    h = truth.dt
    s = ((t - truth.t[i]) / h)[:, None]
    p0, p1, v0, v1 = truth.x_e[i], truth.x_e[i + 1], truth.v_e[i], truth.v_e[i + 1]
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    pos = h00 * p0 + h10 * h * v0 + h01 * p1 + h11 * h * v1
    vel = v0 + s * (v1 - v0)
    return pos, vel


def simulate_gps(truth: Truth, cfg: GpsConfig, rng: np.random.Generator) -> GpsFixes:
    """GPS fixes over the flight (empty when the receiver is disabled)."""
    sp, sv = cfg.position_sigma_m, cfg.velocity_sigma_mps
    cov_p, cov_v = sp**2 * np.eye(3), sv**2 * np.eye(3)
    if not cfg.enabled:
        return GpsFixes(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), cov_p, cov_v, 0)
    n = int(np.floor(truth.t[-1] * cfg.rate_hz + 1e-9)) + 1
    t = np.arange(n) / cfg.rate_hz
    keep = t - cfg.latency_s >= truth.t[0]
    for a, b in cfg.outages_s:
        keep &= ~((t >= a) & (t < b))
    t = t[keep]
    pos, vel = truth_at(truth, t - cfg.latency_s)
    # draw noise for every nominal epoch so that outages do not shift the other fixes' noise
    noise = rng.normal(0.0, 1.0, (n, 6))[keep]
    return GpsFixes(t, pos + sp * noise[:, :3], vel + sv * noise[:, 3:], cov_p, cov_v, cfg.num_satellites)
