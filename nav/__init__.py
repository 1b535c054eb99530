"""Navigation: Earth, time and ephemeris models, strapdown INS, error-state filter, smoother.

Pure computation: arrays in, arrays out; no file or network I/O, no global state.

Map of the modules. Models: :mod:`nav.earth` (WGS-84, gravity), :mod:`nav.timescales` (UTC, TAI,
TT, GPS time as int64 ns), :mod:`nav.ephemeris` (Sun and Moon), :mod:`nav.rotation` (rotation
matrices, quaternions, TRIAD). The filter (003 §6): :mod:`nav.tuning` (its configuration, one
dataclass with the defaults of 003 table 3), :mod:`nav.error_state` (state layout, error
dynamics, covariance propagation), :mod:`nav.imu_errors` and :mod:`nav.gauss_markov` (error
models), :mod:`nav.ins` (strapdown mechanisation), :mod:`nav.measurements` (observation
equations), :mod:`nav.schmidt` (Schmidt-Kalman update), :mod:`nav.filter_state` (the state the
loop carries), :mod:`nav.updates` (the measurement protocol: GPS, camera vectors),
:mod:`nav.navigator` (the run: :func:`run` and its inputs and result), :mod:`nav.smoother` (RTS).
Around it: :mod:`nav.initialise` (TRIAD start attitude), :mod:`nav.clock_offset` (camera clock
offsets). ``nav._kernels`` holds the compiled helpers the kernels share.

The names below are importable from ``nav`` directly; each is loaded on first use, so
``import nav`` stays cheap.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "run": "nav.navigator", "NavResult": "nav.navigator", "ImuData": "nav.navigator",
    "GpsData": "nav.navigator", "VectorData": "nav.navigator", "InitialState": "nav.navigator",
    "Innovation": "nav.navigator", "SmootherStore": "nav.navigator",
    "rts_smooth": "nav.smoother", "SmoothResult": "nav.smoother",
    "Tuning": "nav.tuning", "StateGroupTuning": "nav.tuning", "tuning_from_dict": "nav.tuning",
    "tuning_from_toml": "nav.tuning",
    "StateLayout": "nav.error_state", "build_layout": "nav.error_state",
    "ImuCalibration": "nav.imu_errors",
    "triad_initialise": "nav.initialise", "TriadInit": "nav.initialise",
    "estimate_camera_offsets": "nav.clock_offset", "estimate_clock_offset": "nav.clock_offset",
    "ClockOffsetEstimate": "nav.clock_offset",
    "schmidt_update": "nav.schmidt", "chi2_gate": "nav.schmidt",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'nav' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


def __dir__():
    return sorted(set(globals()) | set(__all__))
