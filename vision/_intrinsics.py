"""What every camera model shares: the checked intrinsics (image size, focal lengths, principal
point) and the camera matrix K."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Intrinsics", "check_intrinsics"]


@dataclass(frozen=True)
class Intrinsics:
    """Base of the camera dataclasses: image size [px], focal lengths [px], principal point [px]
    (OpenCV convention), and the fields each model derives in its ``__post_init__``: ``max_theta``
    [rad] (largest angle off the axis the model represents), ``max_radius`` (its distorted
    normalised radius), ``fov_theta`` [rad] (largest angle seen in the image) and the parameter
    array of the numba kernels. The subclasses add their coefficients and ``name``."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    max_theta: float = field(init=False, repr=False, compare=False)
    max_radius: float = field(init=False, repr=False, compare=False)
    fov_theta: float = field(init=False, repr=False, compare=False)
    _prm: np.ndarray = field(init=False, repr=False, compare=False)

    @property
    def K(self) -> np.ndarray:
        """3x3 camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


def check_intrinsics(cam: Any) -> str:
    """Validate and normalise width, height (positive integers), fx, fy (> 0), cx, cy (finite, inside
    the image: pixel edges -0.5 .. size - 0.5) of a camera dataclass in place; returns its label for
    error messages. ValueError naming the key otherwise."""
    label = f"camera {cam.name!r}" if cam.name else "camera"
    for nm in ("width", "height"):
        v = getattr(cam, nm)
        if isinstance(v, bool) or int(v) != v or v <= 0:
            raise ValueError(f"{label}: {nm} must be a positive integer, got {v!r}")
        object.__setattr__(cam, nm, int(v))
    for nm in ("fx", "fy", "cx", "cy"):
        v = float(getattr(cam, nm))
        if not math.isfinite(v):
            raise ValueError(f"{label}: {nm} must be finite, got {v!r}")
        object.__setattr__(cam, nm, v)
    if cam.fx <= 0 or cam.fy <= 0:
        raise ValueError(f"{label}: fx and fy must be positive, got fx={cam.fx}, fy={cam.fy}")
    for nm, size in (("cx", cam.width), ("cy", cam.height)):
        if not -0.5 <= getattr(cam, nm) <= size - 0.5:
            raise ValueError(f"{label}: principal point {nm} = {getattr(cam, nm)} lies outside the "
                             f"{cam.width}x{cam.height} image; expected -0.5 <= {nm} <= {size - 0.5}")
    return label
