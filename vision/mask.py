"""Payload mask: image regions the edge search ignores (003 §3.1, figs. 10-11).

The payload (the rocket's skin, antennas) seen by a camera is set to be ignored: masked pixels
count as black *and* as outside the image. A white region bounded by the mask is therefore
followed along the mask like along the image edge, and the border is split there into horizon
candidates (003 fig. 11), exactly like at the image edge.

`PayloadMask` precomputes, once per camera:

- ``mask``: (H, W) bool, True = payload (ignored).
- ``frame``: (H, W) bool, True where a pixel is 8-adjacent to the outside, i.e. to the virtual
  frame around the image (the first and last rows and columns) or to a masked pixel. Border
  pixels on the frame are cut out of the candidates (`vision.candidates`).
- ``seeds``: the unmasked pixels with a masked 4-neighbour, with the direction of that neighbour
  (0 = +u, 2 = +v, 4 = -u, 6 = -v; the 8-direction code of `vision.borders`): the edge search
  examines them like the image-border pixels, so a region that touches only the mask is found.

The mask is meant to cover regions connected to the image edge (the payload enters the field of
view from the side). An island of masked pixels inside a white region behaves like a hole: the
border around it lies entirely on the frame and yields no candidate.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["PayloadMask", "from_binary", "from_polygons", "no_mask", "frame_pixels"]


def _check_shape(shape) -> tuple[int, int]:
    try:
        h, w = (int(s) for s in shape)
    except (TypeError, ValueError):
        raise ValueError(f"shape: {shape!r}, expected (height, width)") from None
    if h < 3 or w < 3:
        raise ValueError(f"shape: {shape!r}, expected at least 3x3 pixels")
    return h, w


def frame_pixels(shape, mask: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: pixels 8-adjacent to the outside (image edge ring, or a masked pixel)."""
    h, w = _check_shape(shape)
    fr = np.zeros((h, w), np.bool_)
    fr[0, :] = fr[-1, :] = fr[:, 0] = fr[:, -1] = True
    if mask is not None:
        m8 = mask.astype(np.uint8)
        dil = cv2.dilate(m8, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
        fr |= dil.astype(np.bool_) & ~mask
        fr &= ~mask
    return fr


@dataclass(frozen=True, eq=False)
class PayloadMask:
    """Precomputed payload mask of one camera (see the module docstring)."""

    mask: np.ndarray
    frame: np.ndarray = field(repr=False)
    seed_v: np.ndarray = field(repr=False)
    seed_u: np.ndarray = field(repr=False)
    seed_d: np.ndarray = field(repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        return self.mask.shape

    @property
    def penalty(self) -> np.ndarray:
        """The mask as uint8 0/1 (a view), as the edge-search kernel reads it."""
        return self.mask.view(np.uint8)

    @property
    def has_mask(self) -> bool:
        return bool(self.seed_v.size) or bool(self.mask.any())

    def check(self, shape, name: str = "image") -> None:
        """Raise ValueError if ``shape`` (H, W) differs from the mask's."""
        if tuple(shape[:2]) != self.shape:
            raise ValueError(f"{name}: size {shape[1]}x{shape[0]} (WxH) differs from the payload mask's "
                             f"{self.shape[1]}x{self.shape[0]}")


def from_binary(mask_image, shape=None) -> PayloadMask:
    """Payload mask from an (H, W) image: nonzero = payload (ignored). ``shape`` checks the size."""
    m = np.asarray(mask_image)
    if m.ndim != 2:
        raise ValueError(f"mask image: shape {m.shape}, expected (H, W) with nonzero = payload")
    if shape is not None and m.shape != tuple(shape):
        raise ValueError(f"mask image: shape {m.shape}, expected {tuple(shape)} (the camera's image size)")
    _check_shape(m.shape)
    m = np.ascontiguousarray(m != 0)
    frame = frame_pixels(m.shape, m)
    # unmasked pixels with a masked 4-neighbour, direction code of that neighbour (+u, +v, -u, -v)
    vs, us, ds = [], [], []
    pad = np.pad(m, 1, constant_values=False)
    h, w = m.shape
    for code, (dv, du) in ((0, (0, 1)), (2, (1, 0)), (4, (0, -1)), (6, (-1, 0))):
        nb = pad[1 + dv:1 + dv + h, 1 + du:1 + du + w]
        sel = nb & ~m
        v, u = np.nonzero(sel)
        vs.append(v), us.append(u), ds.append(np.full(v.size, code, np.int64))
    v = np.concatenate(vs)
    u = np.concatenate(us)
    d = np.concatenate(ds)
    # one seed per pixel (the first direction found), in raster order
    key = v.astype(np.int64) * w + u
    key, first = np.unique(key, return_index=True)
    return PayloadMask(m, frame, v[first].astype(np.int64), u[first].astype(np.int64),
                       d[first].astype(np.int64))


def from_polygons(shape, polygons) -> PayloadMask:
    """Payload mask of the union of filled polygons, each an (n, 2) array of (u, v) pixel vertices
    (OpenCV convention; vertices are rounded to whole pixels)."""
    h, w = _check_shape(shape)
    m = np.zeros((h, w), np.uint8)
    pts = []
    for k, p in enumerate(polygons):
        p = np.asarray(p, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3:
            raise ValueError(f"polygon {k}: shape {p.shape}, expected (n >= 3, 2) vertices (u, v)")
        pts.append(np.round(p).astype(np.int32).reshape(-1, 1, 2))
    if pts:
        cv2.fillPoly(m, pts, 1)
    return from_binary(m)


def no_mask(shape) -> PayloadMask:
    """An empty payload mask (nothing ignored) of the given (H, W)."""
    h, w = _check_shape(shape)
    return from_binary(np.zeros((h, w), np.bool_))
