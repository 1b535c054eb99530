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

import numba
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


_NO_FRAME = np.zeros((1, 1), np.bool_)


@numba.njit(cache=True, nogil=True)
def _runs(pts, off, frame, use_frame, h, w):  # pragma: no cover - numba
    """The interior runs of `_pieces`: cumulative arc length cs (n,) [px] along the chain (steps
    of 1 or sqrt 2), run starts rs, ends re (exclusive) and borders rb (the first nr entries)."""
    n = pts.shape[0]
    nb = off.shape[0] - 1
    cs = np.empty(n)
    rs = np.empty(n, np.int64)
    re = np.empty(n, np.int64)
    rb = np.empty(n, np.int64)
    nr = 0
    acc = 0.0
    r2 = math.sqrt(2.0)
    for b in range(nb):
        in_run = False
        for i in range(off[b], off[b + 1]):
            u = pts[i, 0]
            v = pts[i, 1]
            if i > 0:
                acc += r2 if abs(u - pts[i - 1, 0]) + abs(v - pts[i - 1, 1]) == 2 else 1.0
            cs[i] = acc
            if use_frame:
                fr = frame[v, u]
            else:
                fr = u == 0 or v == 0 or u == w - 1 or v == h - 1
            if not fr:
                if not in_run:
                    rs[nr] = i
                    rb[nr] = b
                    in_run = True
            elif in_run:
                re[nr] = i
                nr += 1
                in_run = False
        if in_run:
            re[nr] = off[b + 1]
            nr += 1
    return cs, rs, re, rb, nr


@numba.njit(cache=True, nogil=True)
def _pieces(pts, off, frame, use_frame, h, w, min_length):  # pragma: no cover - numba
    """The candidate pieces of the concatenated border chains, in one pass over the ~10^4 border
    pixels (`_runs`) and one over the runs, instead of a frame lookup, diff, cumsum and shifted
    comparisons over all of them plus a dozen small-array steps.

    A run is a maximal sequence of interior pixels (not on the frame: ``frame[v, u]`` with a mask,
    else the image edge ring) within one border. A run covering its whole border is closed; a
    border's last run ending at the chain end continues with its first run starting at the chain
    start (the chain is a cycle). Returns, for the pieces of at least ``min_length`` pixels in
    chain order: info (k, 7) int64 = start, end (exclusive), start and end of the joined head run
    (-1, -1 if none), border, index of the frame pixel before the start and after the end (-1 for
    a closed piece); the arc length (k,) [px] (steps of 1 or sqrt 2; closed: plus the closing step;
    joined: plus the step across the chain start); and the longest piece (kept or not)."""
    cs, rs, re, rb, nr = _runs(pts, off, frame, use_frame, h, w)
    info = np.empty((nr, 7), np.int64)
    arc = np.empty(nr)
    k = 0
    longest = 0
    r = 0
    while r < nr:
        b = rb[r]
        b0, b1 = off[b], off[b + 1]
        r1 = r
        while r1 < nr and rb[r1] == b:
            r1 += 1                       # runs r .. r1-1 belong to border b
        head = -1
        if r1 - r >= 2 and rs[r] == b0 and re[r1 - 1] == b1:
            head = r                      # joined with the last run
        for q in range(r, r1):
            if q == head:
                continue
            s, e = rs[q], re[q]
            length = e - s
            closed = s == b0 and e == b1
            j = r1 - 1 == q and head >= 0
            if j:
                length += re[head] - rs[head]
            longest = max(longest, length)
            if length < min_length:
                continue
            a = cs[e - 1] - cs[s]
            if closed:
                a += math.hypot(float(pts[s, 0] - pts[e - 1, 0]), float(pts[s, 1] - pts[e - 1, 1]))
                info[k, 0], info[k, 1], info[k, 2], info[k, 3] = s, e, -1, -1
                info[k, 4], info[k, 5], info[k, 6] = b, -1, -1
            else:
                end_idx = e
                if j:
                    s2, e2 = rs[head], re[head]
                    a += (cs[e2 - 1] - cs[s2]) + math.hypot(float(pts[s2, 0] - pts[e - 1, 0]),
                                                             float(pts[s2, 1] - pts[e - 1, 1]))
                    end_idx = e2
                else:
                    s2, e2 = -1, -1
                info[k, 0], info[k, 1], info[k, 2], info[k, 3], info[k, 4] = s, e, s2, e2, b
                info[k, 5] = b1 - 1 if s == b0 else s - 1
                info[k, 6] = b0 if end_idx == b1 else end_idx
            arc[k] = a
            k += 1
        r = r1
    return info[:k], arc[:k], longest


def _split(borders: Borders, mask: PayloadMask | None, min_length: int):
    """Candidates and the length of the longest interior piece (kept or not): the pieces from
    `_pieces` (one numba pass over the concatenated chains), made into `Candidate` objects."""
    h, w = borders.shape
    pts = borders.points
    off = borders.offsets
    nb = len(borders)
    if nb == 0 or pts.shape[0] == 0:
        return [], 0
    if mask is not None and mask.has_mask:
        mask.check(borders.shape)
        frame, use_frame = mask.frame, True
    else:
        frame, use_frame = _NO_FRAME, False
    info, arc, longest = _pieces(pts, off, frame, use_frame, h, w, min_length)
    if info.shape[0] == 0:
        return [], int(longest)
    fp = pts.astype(np.float64)
    fp.flags.writeable = False
    out: list[Candidate] = []
    for k in range(info.shape[0]):
        s, e, s2, e2, bi, ib, ia = (int(x) for x in info[k])
        if ib < 0:
            out.append(Candidate(fp[s:e], bi, True, None, None, float(arc[k])))
            continue
        if s2 >= 0:
            p = np.concatenate((fp[s:e], fp[s2:e2]))
            p.flags.writeable = False
        else:
            p = fp[s:e]
        out.append(Candidate(p, bi, False, _edge_name(int(pts[ib, 0]), int(pts[ib, 1]), h, w),
                             _edge_name(int(pts[ia, 0]), int(pts[ia, 1]), h, w), float(arc[k])))
    return out, int(longest)


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
           expected_shape: tuple[int, int] | None = None, hist: np.ndarray | None = None,
           rows: np.ndarray | None = None) -> Detection:
    """Detection stage for one target: frame -> brightness gate -> threshold -> edge search ->
    candidates (003 §3.1, §5; 004 §2.2.1-2.2.3).

    Parameters
    ----------
    image : (H, W, 3) BGR/RGB or (H, W) uint8 frame as decoded (distorted; no undistortion here).
    config : per-target configuration (the Earth and the Sun use different thresholds, 003 §5).
    mask : payload mask of the camera, or None.
    expected_shape : (H, W) the camera delivers; a frame of another size raises ValueError.
    hist : ``brightness_histogram(image, config.binarize.sample_step)`` of this frame if already
        computed (the Earth and Sun detections of one frame share it: it reads ~0.8 MB of the
        frame), else None.
    rows : search-line rows to scan instead of ``config.search``'s raster (e.g. the rows of that
        raster that can meet a body near its predicted direction), or None.
    """
    a = as_frame(image, expected_shape)
    if mask is not None:
        mask.check(a.shape)
    bc = config.binarize
    if hist is None:
        hist = brightness_histogram(a, bc.sample_step)
    elif hist.shape != (255 * a.shape[2] + 1,):
        raise ValueError(f"hist: shape {hist.shape}, expected ({255 * a.shape[2] + 1},) "
                         f"(brightness_histogram of this {a.shape[2]}-channel frame)")
    gate = brightness_gate(a, bc, hist)
    if not gate.accepted:
        return Detection([], None, float("nan"), gate.brightness, gate.reason)
    t = resolve_threshold(a, bc, hist)
    borders = find_borders(a, t, mask, config.search, rows=rows)
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
