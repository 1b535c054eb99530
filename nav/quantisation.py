"""The rounding of a rate gyro's output as a Gauss-Markov rate error that follows the rates.

A rate output rounded to a grid of step ``q`` carries the error ``e = Q(w) - w``. Over flights
(the grid's phase against the true zero rate is arbitrary) ``e`` is uniform on [-q/2, q/2), of
variance ``q^2 / 12``. Within a flight it is a deterministic function of the rate: while the rate
changes by ``alpha`` per second, ``e`` is a sawtooth of period ``T_q = q / |alpha|``; while the
rate holds still, ``e`` is a constant, a bias until the rate moves again. A stationary model
cannot hold both: the time scale of the error follows the motion. The filter's Gauss-Markov gyro
error ``g_w`` (:mod:`nav.error_state`) then takes, per body axis, the stationary sigma
``q / sqrt(12)`` and the correlation time

    tau(t) = q / (c |alpha(t)|),  bounded to [dt, TAU_MAX_S],

with ``alpha`` the least-squares slope of the measured rate over a window centred on each sample
(:func:`rate_slopes`). The scale ``c`` follows from matching a Gauss-Markov process to the
sawtooth: the sawtooth's autocorrelation ``1 - 6u + 6u^2`` (``u`` the lag over ``T_q``) starts
like ``exp(-6u)`` (c = 6), but its integral is periodic, where a Gauss-Markov process's random
walks; matching the variance of the integrated error (the attitude error it drives) at lags of
0.1 / 0.25 / 0.5 ``T_q`` gives c = 6.7 / 8.2 / 13.7, and c grows without bound towards a whole
period. The default (:attr:`nav.tuning.Tuning.gyro_gm_quantum_scale`) is set from Monte Carlo
flights (docs/tuning.md "Rate quantisation") and ``horizon-nav tune`` estimates it from a flight.
"""
from __future__ import annotations

import numpy as np

#: the longest correlation time [s]: a rate that holds still keeps its rounding until it moves
TAU_MAX_S = 60.0


def rate_slopes(ts: np.ndarray, w: np.ndarray, half_window_s: float) -> np.ndarray:
    """Least-squares slope of each column of ``w`` (N, k) over the samples within
    ``half_window_s`` of each sample [unit of w per s].

    The slope of a straight-line fit to the ``2 m + 1`` samples centred on sample ``i`` is
    ``sum_j j w_(i+j) / (dt sum_j j^2)`` (``j = -m..m``, a uniform interval ``dt``): a
    convolution. Near the ends the window is filled with the end samples (the slope falls towards
    zero there, which makes the correlation time longer, the conservative side).

    Examples
    --------
    >>> ts = np.arange(0.0, 10.0, 0.05)
    >>> round(float(rate_slopes(ts, 0.3 * ts[:, None], 1.0)[100, 0]), 12)
    0.3
    """
    ts = np.asarray(ts, float)
    w = np.asarray(w, float).reshape(len(ts), -1)
    dt = float(np.median(np.diff(ts)))
    m = max(1, int(round(half_window_s / dt)))
    j = np.arange(-m, m + 1, dtype=float)
    kernel = j[::-1] / (dt * np.sum(j * j))
    pad = np.pad(w, ((m, m), (0, 0)), mode="edge")
    return np.stack([np.convolve(pad[:, c], kernel, mode="valid") for c in range(w.shape[1])], axis=1)


def quantisation_rates(ts: np.ndarray, w: np.ndarray, quantum: float, scale: float,
                       half_window_s: float) -> np.ndarray:
    """Per sample and body axis, ``1 / tau`` [1/s] of the rounding error of a rate output of step
    ``quantum`` [rad/s] (module docstring): ``c |alpha| / q``, bounded to ``[1 / TAU_MAX_S,
    1 / dt]``. ``ts`` (N,) [s], ``w`` (N, 3) the measured rates [rad/s].

    Examples
    --------
    A rate that changes by one quantum every 2 s has ``T_q = 2 s``; with c = 24 its error
    decorrelates at 12 / s:

    >>> ts = np.arange(0.0, 20.0, 0.05)
    >>> w = np.repeat((0.001 * ts / 2.0)[:, None], 3, axis=1)
    >>> round(float(quantisation_rates(ts, w, 0.001, 24.0, 2.0)[200, 0]), 6)
    12.0
    """
    dt = float(np.median(np.diff(ts)))
    rate = scale * np.abs(rate_slopes(ts, w, half_window_s)) / quantum
    return np.clip(rate, 1.0 / TAU_MAX_S, 1.0 / dt)


def cumulative_rates(rates: np.ndarray) -> np.ndarray:
    """(N + 1, 3) running sums of ``rates`` (N, 3) from zero, for :func:`block_rates`."""
    rates = np.asarray(rates, float)
    return np.concatenate([np.zeros((1, rates.shape[1])), np.cumsum(rates, axis=0)])


def block_rates(cumulative: np.ndarray, k: int, k_end: int) -> np.ndarray:
    """The mean ``1 / tau`` (3,) over the sample intervals from k to k_end (each interval at its
    first sample's value), from the running sums of :func:`cumulative_rates`: ``exp(-dt mean)``
    is the exact decay over the block of a process whose rate is constant within each interval."""
    n = max(k_end - k, 1)
    return (cumulative[k + n] - cumulative[k]) / n
