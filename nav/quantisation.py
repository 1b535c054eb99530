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

with ``alpha`` the least-squares slope of the measured rate over the window before each sample or
the window after it, whichever is the flatter (:func:`rate_slopes`): a window centred on a sample
just after a sharp manoeuvre (a tip-off, a thruster pulse) carries the manoeuvre's slope into
seconds where the rate holds still and the rounding is a bias. The scale ``c`` follows from
matching a Gauss-Markov process to the sawtooth: the sawtooth's autocorrelation ``1 - 6u + 6u^2``
(``u`` the lag over ``T_q``) starts like ``exp(-6u)`` (c = 6), but its integral is periodic, where
a Gauss-Markov process's random walks; matching the variance of the integrated error (the
attitude error it drives) at lags of 0.1 / 0.25 / 0.5 ``T_q`` gives c = 6.7 / 8.2 / 13.7, and c
grows without bound towards a whole period. The default (:attr:`nav.tuning.Tuning.gyro_gm_quantum_scale`) is set from Monte Carlo
flights (docs/tuning.md "Rate quantisation") and ``horizon-nav tune`` estimates it from a flight.
"""
from __future__ import annotations

import numpy as np

#: the longest correlation time [s]: a rate that holds still keeps its rounding until it moves
TAU_MAX_S = 60.0


def rate_slopes(ts: np.ndarray, w: np.ndarray, window_s: float) -> np.ndarray:
    """Per sample, the flatter of the least-squares slopes of each column of ``w`` (N, k) over
    the samples within ``window_s`` before it and within ``window_s`` after it [unit of w
    per s].

    The slope of a straight-line fit to the ``m + 1`` samples ``i - m .. i`` is ``sum_j (j - m/2)
    w_(i-m+j) / (dt sum_j (j - m/2)^2)`` (``j = 0..m``, a uniform interval ``dt``): one
    convolution gives both sides, the window after sample i being the one before sample i + m.
    Taking the one of smaller magnitude keeps a kink in the rate (a manoeuvre that starts or
    stops) from spreading into the steady side; on a straight line both sides agree. Near the
    ends the window is filled with the end samples (the slope falls towards zero there, which
    makes the correlation time longer, the conservative side).

    Examples
    --------
    A rate that ramps at 0.3 per second and then holds still from t = 5 s:

    >>> ts = np.arange(0.0, 10.0, 0.05)
    >>> w = 0.3 * np.minimum(ts, 5.0)[:, None]
    >>> [round(float(rate_slopes(ts, w, 1.0)[i, 0]), 12) + 0.0 for i in (60, 110)]
    [0.3, 0.0]
    """
    ts = np.asarray(ts, float)
    w = np.asarray(w, float).reshape(len(ts), -1)
    n = len(ts)
    dt = float(np.median(np.diff(ts)))
    m = max(1, int(round(window_s / dt)))
    j = np.arange(m + 1, dtype=float) - 0.5 * m
    kernel = j[::-1] / (dt * np.sum(j * j))
    pad = np.pad(w, ((m, m), (0, 0)), mode="edge")
    out = np.empty_like(w)
    for c in range(w.shape[1]):
        trailing = np.convolve(pad[:, c], kernel, mode="valid")   # [i]: the window ending at sample i
        before, after = trailing[:n], trailing[m:m + n]
        out[:, c] = np.where(np.abs(before) <= np.abs(after), before, after)
    return out


def quantisation_rates(ts: np.ndarray, w: np.ndarray, quantum: float, scale: float,
                       window_s: float) -> np.ndarray:
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
    rate = scale * np.abs(rate_slopes(ts, w, window_s)) / quantum
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
