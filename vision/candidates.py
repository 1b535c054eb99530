"""Horizon / Sun / Moon edge candidates from the followed borders (003 §3.1 fig. 11, §5 fig. 25;
004 §2.2.1-2.2.3), and the whole detection stage from a decoded frame (`detect`).

Splitting (003 fig. 11)
-----------------------
A followed outer border of a white region that touches the image edge runs partly along the
edge (where the region is cut by the image) and partly through the interior (where it is the
horizon, a cloud-bank boundary, glare...). Every border pixel on the *frame* (8-adjacent to the
outside: the virtual frame around the image or a payload-mask pixel, `vision.mask.frame_pixels`)
is removed; each maximal run of consecutive interior pixels (cyclically along the border) is one
candidate. A border without any frame pixel (a Sun, Moon or Earth ellipse fully inside the image)
is one closed candidate. Candidates with fewer than ``min_length`` pixels are dropped.

Each candidate carries its ordered pixels as an (m, 2) float64 array of (u, v) (OpenCV pixel
convention), whether it is closed, and for an open candidate which part of the frame each end
meets ("top", "right", "bottom", "left" image border, or "mask"), judged from the frame pixel just
before the first and just after the last candidate pixel along the border.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vision.binarize import BinarizeConfig, as_frame, brightness_gate, brightness_histogram, resolve_threshold
from vision.borders import Borders, SearchConfig, find_borders
from vision.mask import PayloadMask

__all__ = [
    "Candidate",
    "DetectionConfig",
    "Detection",
    "split_borders",
    "detect",
    "EDGES",
]

EDGES = ("top", "right", "bottom", "left", "mask")


@dataclass(frozen=True, eq=False)
class Candidate:
    """One edge candidate.

    Attributes
    ----------
    points : (m, 2) float64 (u, v), ordered along the border.
    border : index of the border it comes from (`vision.borders.Borders`).
    closed : the whole border, fully inside the image (ellipse; Sun / Moon / high-altitude Earth).
    start_edge, end_edge : part of the frame met before the first / after the last pixel
        ("top", "right", "bottom", "left", "mask"); None for a closed candidate.
    arc_length : length of the pixel chain [px] (steps of 1 or sqrt(2); closed: including the
        step from the last to the first pixel).
    """

    points: np.ndarray = field(repr=False)
    border: int
    closed: bool
    start_edge: str | None
    end_edge: str | None
    arc_length: float

    @property
    def n_pixels(self) -> int:
        return int(self.points.shape[0])

    @property
    def touches_border(self) -> bool:
        """True if the candidate ends at the image border or the mask (not closed)."""
        return not self.closed

    @property
    def edges(self) -> frozenset:
        """The parts of the frame the candidate's ends meet (empty when closed)."""
        return frozenset(e for e in (self.start_edge, self.end_edge) if e is not None)


def _edge_name(u: int, v: int, h: int, w: int) -> str:
    """Part of the frame a frame pixel belongs to: top, bottom, left, right (corners in that
    order), else the mask."""
    if v == 0:
        return "top"
    if v == h - 1:
        return "bottom"
    if u == 0:
        return "left"
    if u == w - 1:
        return "right"
    return "mask"


def _split(borders: Borders, mask: PayloadMask | None, min_length: int):
    """Candidates and the length of the longest interior piece (kept or not). Vectorised over all
    borders: runs of interior pixels are found on the concatenated chains, then the first and last
    run of a border are joined when they meet across the chain's start (it is a closed cycle)."""
    h, w = borders.shape
    pts = borders.points
    off = borders.offsets
    nb = len(borders)
    if nb == 0 or pts.shape[0] == 0:
        return [], 0
    u, v = pts[:, 0], pts[:, 1]
    if mask is not None and mask.has_mask:
        mask.check(borders.shape)
        fr = mask.frame[v, u]
    else:
        fr = (u == 0) | (v == 0) | (u == w - 1) | (v == h - 1)
    inner = ~fr
    n = pts.shape[0]
    first = np.zeros(n, np.bool_)
    first[off[:-1]] = True
    last = np.zeros(n, np.bool_)
    last[off[1:] - 1] = True
    prev_inner = np.concatenate(([False], inner[:-1])) & ~first
    next_inner = np.concatenate((inner[1:], [False])) & ~last
    rs = np.flatnonzero(inner & ~prev_inner)            # run starts
    re = np.flatnonzero(inner & ~next_inner) + 1        # run ends (exclusive)
    if rs.size == 0:
        return [], 0
    rb = np.searchsorted(off, rs, side="right") - 1     # border of each run
    b0, b1 = off[rb], off[rb + 1]
    closed = (rs == b0) & (re == b1)                     # the whole border is interior
    # join a border's last run (ending at b1) with its first run (starting at b0) across the wrap
    starts_at_b0 = (rs == b0) & ~closed
    ends_at_b1 = (re == b1) & ~closed
    tail = np.flatnonzero(ends_at_b1)                    # the run just before index tail+1 ...
    head_of = {int(rb[i]): i for i in np.flatnonzero(starts_at_b0)}
    length = (re - rs).astype(np.int64)
    joined = np.full(rs.size, -1, np.int64)              # run i continues with run joined[i]
    drop = np.zeros(rs.size, np.bool_)
    for i in tail:
        j = head_of.get(int(rb[i]))
        if j is not None:
            joined[i] = j
            length[i] += length[j]
            drop[j] = True
    longest = int(length[~drop].max()) if (~drop).any() else 0
    keep = np.flatnonzero(~drop & (length >= min_length))
    if keep.size == 0:
        return [], longest
    # step lengths along the chains (1 or sqrt 2), cumulative for arc lengths
    fp = pts.astype(np.float64)
    fp.flags.writeable = False
    step = np.zeros(n)
    step[1:] = np.where(np.abs(np.diff(pts, axis=0)).sum(axis=1) == 2, math.sqrt(2.0), 1.0)
    cs = np.cumsum(step)
    out: list[Candidate] = []
    ks = keep
    s0, e0, bb0, bb1 = rs[ks], re[ks], b0[ks], b1[ks]
    # frame pixel before the start / after the end, cyclically within the border
    jn = joined[ks]
    end_idx = np.where(jn >= 0, re[np.maximum(jn, 0)], e0)   # joined: ends where the head run ends
    before = np.where(s0 == bb0, bb1 - 1, s0 - 1)
    after = np.where(end_idx == bb1, bb0, end_idx)
    for k, i in enumerate(ks):
        s, e, bi = int(rs[i]), int(re[i]), int(rb[i])
        if closed[i]:
            p = fp[s:e]
            arc = float(cs[e - 1] - cs[s]) + float(math.hypot(*(p[0] - p[-1])))
            out.append(Candidate(p, bi, True, None, None, arc))
            continue
        arc = float(cs[e - 1] - cs[s])
        j = int(joined[i])
        if j >= 0:
            s2, e2 = int(rs[j]), int(re[j])
            p = np.concatenate((fp[s:e], fp[s2:e2]))
            p.flags.writeable = False
            arc += float(cs[e2 - 1] - cs[s2]) + float(math.hypot(*(fp[s2] - fp[e - 1])))
        else:
            p = fp[s:e]
        qb, qa = pts[before[k]], pts[after[k]]
        out.append(Candidate(p, bi, False, _edge_name(int(qb[0]), int(qb[1]), h, w),
                             _edge_name(int(qa[0]), int(qa[1]), h, w), arc))
    return out, longest


def split_borders(borders: Borders, mask: PayloadMask | None = None, min_length: int = 20) -> list[Candidate]:
    """Split followed borders into candidates where they run along the image edge or the payload
    mask (003 fig. 11); drop those with fewer than ``min_length`` pixels. See the module docstring."""
    if min_length < 1:
        raise ValueError(f"min_length: {min_length}, expected >= 1 pixel")
    return _split(borders, mask, int(min_length))[0]


@dataclass(frozen=True)
class DetectionConfig:
    """Detection of one target (Earth or Sun): threshold/gate, edge search, minimum length [px]."""

    binarize: BinarizeConfig = BinarizeConfig()
    search: SearchConfig = SearchConfig()
    min_length: int = 20

    def __post_init__(self):
        if self.min_length < 1:
            raise ValueError(f"DetectionConfig.min_length: {self.min_length}, expected >= 1 pixel")


@dataclass(frozen=True, eq=False)
class Detection:
    """Result of `detect`.

    Attributes
    ----------
    candidates : the edge candidates (may be empty).
    borders : the followed borders (for annotation), None if the frame was gated out.
    threshold : the threshold used [0, 255] (NaN if gated out).
    brightness : mean frame brightness b_s [0, 255] (004 eq. (2.2)).
    reason : why there is no candidate ("" when there are candidates).
    """

    candidates: list
    borders: Borders | None
    threshold: float
    brightness: float
    reason: str = ""

    @property
    def ok(self) -> bool:
        return bool(self.candidates)


def detect(image, config: DetectionConfig = DetectionConfig(), mask: PayloadMask | None = None,
           expected_shape: tuple[int, int] | None = None) -> Detection:
    """Detection stage for one target: frame -> brightness gate -> threshold -> edge search ->
    candidates (003 §3.1, §5; 004 §2.2.1-2.2.3).

    Parameters
    ----------
    image : (H, W, 3) BGR/RGB or (H, W) uint8 frame as decoded (distorted; no undistortion here).
    config : per-target configuration (the Earth and the Sun use different thresholds, 003 §5).
    mask : payload mask of the camera, or None.
    expected_shape : (H, W) the camera delivers; a frame of another size raises ValueError.
    """
    a = as_frame(image, expected_shape)
    if mask is not None:
        mask.check(a.shape)
    bc = config.binarize
    hist = brightness_histogram(a, bc.sample_step)
    gate = brightness_gate(a, bc, hist)
    if not gate.accepted:
        return Detection([], None, float("nan"), gate.brightness, gate.reason)
    t = resolve_threshold(a, bc, hist)
    borders = find_borders(a, t, mask, config.search)
    if borders.overflow:
        return Detection([], borders, t, gate.brightness,
                         f"edge search stopped after {config.search.max_points} border pixels "
                         f"(SearchConfig.max_points): frame too noisy at threshold {t:g}")
    cands, longest = _split(borders, mask, config.min_length)
    reason = ""
    if not cands:
        where = "the image border" + (", the payload-mask boundary" if mask is not None and mask.has_mask else "") \
            + (" or the search lines" if borders.rows.size else "")
        if len(borders) == 0:
            reason = f"no white pixel (mean brightness >= {t:g}) on {where}"
        elif longest == 0:
            reason = (f"all {len(borders)} borders run along the image border"
                      + (" or the mask" if mask is not None and mask.has_mask else "") + " only")
        else:
            reason = (f"no candidate of >= {config.min_length} pixels "
                      f"(longest interior piece: {longest} pixels, {len(borders)} borders)")
    return Detection(cands, borders, t, gate.brightness, reason)
