"""Binarisation of a camera frame: mean-RGB threshold, brightness gate, static/dynamic/Otsu
threshold (003 §3.1, §5; 004 §2.2.1-2.2.2).

Brightness
----------
The brightness of a pixel is the arithmetic mean of its channels (003 §3.1; 004 eq. (2.1))::

    b(i) = (c_0 + c_1 + c_2) / 3

It does not depend on the channel order, so BGR frames (as ``cv2.imdecode`` returns JPEGs) and RGB
frames give the same result. A pixel is white (1) iff ``b(i) >= t`` (004 §2.2.2, method 1); with
integer channel values that is exactly ``c_0 + c_1 + c_2 >= ceil(3 t)`` (`sum_threshold`), which is
what every kernel here and in `vision.borders` compares, so no rounding enters the decision.

Frames are ``uint8`` arrays, ``(H, W, 3)`` colour or ``(H, W)`` grey (a binary image is a grey image
with values 0/1 or 0/255, binarised with ``t = 1``). The threshold is in mean-brightness units
[0, 255]. The Earth and the Sun use different thresholds (003 §5): one `BinarizeConfig` per target.

Threshold methods (`resolve_threshold`)
---------------------------------------
- ``"static"``: ``t = threshold`` (004 §2.2.2, method 1).
- ``"dynamic"``: ``t = factor * b_s``, ``b_s`` the mean frame brightness (004 §2.2.2, method 2,
  eq. (2.2)).
- ``"otsu"``: Otsu's between-class-variance maximum of the brightness histogram restricted to
  ``otsu_range`` (a dynamic threshold that does not depend on how much of the frame is Earth).
The result is clipped to ``[threshold_min, threshold_max]``.

Brightness gate (`brightness_gate`, 004 §2.2.1, eq. (2.3)): frames whose mean brightness ``b_s``
is outside ``[gate_min, gate_max]`` are not worth processing. 004 averages a random fraction of the
pixels; here a regular grid of every ``sample_step``-th row and column is used (deterministic, the
same estimate of the mean for frames without structure on the scale of the step).

Full-frame binarisation (`binarize`) is only needed for annotation and the OpenCV reference path:
the edge search (`vision.borders`) thresholds the pixels it examines on the fly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

__all__ = [
    "BinarizeConfig",
    "GateResult",
    "as_frame",
    "sum_threshold",
    "pixel_brightness",
    "brightness_histogram",
    "frame_brightness",
    "brightness_gate",
    "otsu_threshold",
    "resolve_threshold",
    "binarize",
]

_METHODS = ("static", "dynamic", "otsu")


@dataclass(frozen=True)
class BinarizeConfig:
    """Threshold and brightness gate of one target (Earth or Sun), mean-brightness units [0, 255].

    Attributes
    ----------
    threshold : static threshold t (004 §2.2.2, method 1). 004 uses 80 for the Earth.
    method : "static", "dynamic" (t = factor * b_s, 004 §2.2.2 method 2) or "otsu".
    factor : dynamic threshold factor b_factor (004 §2.2.2).
    otsu_range : (lo, hi) brightness range in which the Otsu threshold is sought.
    threshold_min, threshold_max : clip of the resolved threshold (dynamic/Otsu).
    gate_min, gate_max : brightness gate [b_min, b_max] (004 eq. (2.3)); the defaults accept all.
    sample_step : grid step of the pixels sampled for b_s and the histogram (004 eq. (2.2)).
    """

    threshold: float = 80.0
    method: str = "static"
    factor: float = 1.0
    otsu_range: tuple[float, float] = (0.0, 255.0)
    threshold_min: float = 1.0
    threshold_max: float = 255.0
    gate_min: float = 0.0
    gate_max: float = 255.0
    sample_step: int = 8

    def __post_init__(self):
        if self.method not in _METHODS:
            raise ValueError(f"BinarizeConfig.method: {self.method!r}, expected one of {_METHODS}")
        if not (0.0 <= self.threshold <= 255.0):
            raise ValueError(f"BinarizeConfig.threshold: {self.threshold}, expected 0..255 (mean of RGB)")
        lo, hi = self.otsu_range
        if not (0.0 <= lo < hi <= 255.0):
            raise ValueError(f"BinarizeConfig.otsu_range: {self.otsu_range}, expected 0 <= lo < hi <= 255")
        if not (0.0 <= self.threshold_min <= self.threshold_max <= 255.0):
            raise ValueError("BinarizeConfig.threshold_min/threshold_max: "
                             f"{self.threshold_min}/{self.threshold_max}, expected 0 <= min <= max <= 255")
        if not (0.0 <= self.gate_min <= self.gate_max <= 255.0):
            raise ValueError(f"BinarizeConfig.gate_min/gate_max: {self.gate_min}/{self.gate_max}, "
                             "expected 0 <= min <= max <= 255")
        if self.factor <= 0.0:
            raise ValueError(f"BinarizeConfig.factor: {self.factor}, expected > 0")
        if int(self.sample_step) != self.sample_step or self.sample_step < 1:
            raise ValueError(f"BinarizeConfig.sample_step: {self.sample_step}, expected an integer >= 1")


@dataclass(frozen=True)
class GateResult:
    """Outcome of the brightness gate (004 eq. (2.3)): ``brightness`` is b_s [0, 255]."""

    accepted: bool
    brightness: float
    reason: str = ""


def as_frame(image, expected_shape: tuple[int, int] | None = None, name: str = "image") -> np.ndarray:
    """Validate a frame and return it as a ``(H, W, C)`` uint8 array (a view, C = 1 or 3).

    Raises ValueError naming what was wrong: dtype other than uint8, not (H, W) / (H, W, 3)
    (or (H, W, 1)), smaller than 3x3, or (H, W) different from ``expected_shape``.
    """
    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise ValueError(f"{name}: dtype {a.dtype}, expected uint8 (8-bit frame as decoded by OpenCV)")
    if a.ndim == 2:
        a = a[:, :, None]
    elif not (a.ndim == 3 and a.shape[2] in (1, 3)):
        raise ValueError(f"{name}: shape {a.shape}, expected (H, W) grey or (H, W, 3) BGR/RGB")
    h, w = a.shape[:2]
    if h < 3 or w < 3:
        raise ValueError(f"{name}: shape {a.shape}, expected at least 3x3 pixels")
    if expected_shape is not None and (h, w) != tuple(expected_shape):
        raise ValueError(f"{name}: size {w}x{h} (WxH), expected {expected_shape[1]}x{expected_shape[0]} "
                         "(the camera's image size)")
    return a


def sum_threshold(threshold: float, channels: int) -> int:
    """Integer threshold on the channel sum: ``mean >= t  <=>  sum >= ceil(C t)`` (exact)."""
    return int(math.ceil(round(channels * float(threshold), 9)))


def pixel_brightness(image) -> np.ndarray:
    """Mean of the channels per pixel (003 §3.1, 004 eq. (2.1)), float64 (H, W). Reference
    implementation (numpy); the kernels never build this array."""
    a = as_frame(image)
    return a.mean(axis=2, dtype=np.float64)


@numba.njit(cache=True, nogil=True)
def _histogram(img, step):  # pragma: no cover - numba
    h, w, nc = img.shape
    hist = np.zeros(255 * nc + 1, np.int64)
    for v in range(step // 2, h, step):
        for u in range(step // 2, w, step):
            s = 0
            for c in range(nc):
                s += img[v, u, c]
            hist[s] += 1
    return hist


def brightness_histogram(image, sample_step: int = 8) -> np.ndarray:
    """Histogram of the channel *sums* (length 255 C + 1) over the grid of every ``sample_step``-th
    row and column (starting at step // 2). Bin k holds pixels of brightness k / C."""
    a = as_frame(image)
    return _histogram(a, int(sample_step))


def frame_brightness(image, sample_step: int = 8) -> float:
    """Mean frame brightness b_s over the sample grid (004 eq. (2.2)), [0, 255]."""
    a = as_frame(image)
    hist = _histogram(a, int(sample_step))
    return _hist_mean(hist, a.shape[2])


def _hist_mean(hist: np.ndarray, channels: int) -> float:
    return float(np.dot(hist, np.arange(hist.size)) / (hist.sum() * channels))


def brightness_gate(image, config: BinarizeConfig, hist: np.ndarray | None = None) -> GateResult:
    """004 eq. (2.3): accept iff gate_min <= b_s <= gate_max; the reason names the failed bound."""
    a = as_frame(image)
    if hist is None:
        hist = _histogram(a, int(config.sample_step))
    b = _hist_mean(hist, a.shape[2])
    if b < config.gate_min:
        return GateResult(False, b, f"frame too dark: mean brightness {b:.1f} < gate_min {config.gate_min:g}")
    if b > config.gate_max:
        return GateResult(False, b, f"frame too bright: mean brightness {b:.1f} > gate_max {config.gate_max:g}")
    return GateResult(True, b)


def otsu_threshold(hist: np.ndarray, channels: int = 1, lo: float = 0.0, hi: float = 255.0) -> float:
    """Otsu's threshold of a channel-sum histogram restricted to brightness [lo, hi].

    Maximises the between-class variance ``w0 w1 (mu0 - mu1)^2`` over the split bins; returns the
    brightness t (mean units) such that the upper class is ``b >= t``. If the range holds fewer than
    two distinct occupied bins, returns the midpoint of the range.
    """
    hist = np.asarray(hist, dtype=np.float64)
    k = np.arange(hist.size, dtype=np.float64)
    i0 = int(math.ceil(lo * channels))
    i1 = int(math.floor(hi * channels)) + 1
    hh = hist[i0:i1]
    kk = k[i0:i1]
    n = hh.sum()
    if n <= 0 or np.count_nonzero(hh) < 2:
        return 0.5 * (lo + hi)
    w0 = np.cumsum(hh)[:-1]                # class 0: bins i0 .. i0+j
    m0 = np.cumsum(hh * kk)[:-1]
    w1 = n - w0
    m1 = (hh * kk).sum() - m0
    with np.errstate(divide="ignore", invalid="ignore"):
        var = np.where((w0 > 0) & (w1 > 0), w0 * w1 * (m0 / w0 - m1 / w1) ** 2, -1.0)
    j = int(np.argmax(var))
    # upper class starts at the next occupied-or-not bin after j
    return float(kk[j + 1] / channels)


def resolve_threshold(image, config: BinarizeConfig, hist: np.ndarray | None = None) -> float:
    """The threshold t [0, 255] for this frame by ``config.method`` (see the module docstring)."""
    if config.method == "static":
        return float(config.threshold)
    a = as_frame(image)
    if hist is None:
        hist = _histogram(a, int(config.sample_step))
    if config.method == "dynamic":
        t = config.factor * _hist_mean(hist, a.shape[2])
    else:
        t = otsu_threshold(hist, a.shape[2], *config.otsu_range)
    return float(min(max(t, config.threshold_min), config.threshold_max))


@numba.njit(cache=True, nogil=True)
def _binarize(img, tsum, mask, has_mask):  # pragma: no cover - numba
    h, w, nc = img.shape
    out = np.empty((h, w), np.uint8)
    for v in range(h):
        for u in range(w):
            s = 0
            for c in range(nc):
                s += img[v, u, c]
            out[v, u] = 1 if s >= tsum else 0
            if has_mask and mask[v, u]:
                out[v, u] = 0
    return out


def binarize(image, threshold: float, mask: np.ndarray | None = None) -> np.ndarray:
    """Binary image (H, W) uint8 in {0, 1}: 1 iff mean of channels >= threshold (003 §3.1).

    ``mask`` (H, W) bool, True = payload: those pixels are set to 0 (ignored, 003 fig. 10).
    """
    a = as_frame(image)
    if mask is None:
        m, has = np.zeros((1, 1), np.bool_), False
    else:
        m = np.asarray(mask, dtype=np.bool_)
        if m.shape != a.shape[:2]:
            raise ValueError(f"mask: shape {m.shape}, expected the image size {a.shape[:2]}")
        has = True
    return _binarize(a, sum_threshold(threshold, a.shape[2]), m, has)
