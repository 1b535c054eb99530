"""Vision: camera frames in, Earth-nadir, Sun and Moon direction vectors with covariances out
(003 §3, §5). Pure computation: arrays in and out, no I/O, no global state.

`process_frame` runs the whole front end on one decoded frame with a `VisionConfig` (defaults
in the dataclasses of `vision.config`) and an optional `FramePrior`, and returns a `FrameResult`
holding one `VectorRecord` per target found. Module map: `camera` (fisheye model, 003 eqs.
(13)-(16)), `mask` (payload mask); detection: `binarize` (gate, threshold), `borders` (edge
search), `candidates` (edge pieces); fitting: `nadir` (cone fits), `ransac`, `oblate` (limb
models: sphere, ellipsoid), `conic` (the general conic fit, a baseline), `fitting` (the front
end's fits), `scoring` (one candidate's tests), `probes` and `image_geometry` (image checks around
a fitted cone); `limb` and `limb_refit` (the exposure-invariant limb edge); `covariance` (003 eqs.
(33)-(38)); `edge_height` (the edge height fitted with the nadir); `frontend` (the pipeline),
`config`, `results`; `error_model` and `design` (predicted
vision errors, camera design studies); `annotate` (drawing results); `_kernels` (compiled helpers
shared by the modules). The names below are imported on first use.
"""
from __future__ import annotations

import importlib

__all__ = ["process_frame", "default_config", "resolve_search_lines", "TARGETS", "VisionConfig", "TargetConfig",
           "ScoringOptions", "RansacOptions", "SideCheckOptions", "FitOptions", "LimbOptions", "FlankOptions",
           "CalibrationOptions", "EdgeHeightOptions", "FramePrior", "VectorRecord", "CandidateResult", "TargetResult",
           "FrameResult", "FisheyeCamera", "EquidistantCamera", "PinholeCamera", "PayloadMask", "conic_polyline"]

_HOME = {"process_frame": "frontend", "conic_polyline": "image_geometry", "FisheyeCamera": "camera",
         "EquidistantCamera": "camera", "PinholeCamera": "camera",
         "PayloadMask": "mask", "VectorRecord": "results", "CandidateResult": "results",
         "TargetResult": "results", "FrameResult": "results"}


def __getattr__(name: str):
    if name not in __all__:
        raise AttributeError(f"module 'vision' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"vision.{_HOME.get(name, 'config')}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
