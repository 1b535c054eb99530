"""Edge search: topological border following restricted to the image border, the payload-mask
boundary and a raster of horizontal search lines (003 §3.1, §5; 004 §2.2.3).

What is found
-------------
The *outer borders of the external white components* (the border of a white 8-connected region
against the black 4-connected region around it, for regions that are not inside a hole of another
region: 004 §2.2.3, "if a border is enclosed by another border, this border is not detected") that
touch the image border or the payload mask (003 §3.1: the Earth is never fully inside the image)
or cross one of the search lines (003 §5: ellipses fully inside the image). Small enclosed blobs
(clouds) that neither touch the border nor cross a line are never examined (003 fig. 10). With a
search line on every row the result is exactly OpenCV's ``findContours(RETR_EXTERNAL,
CHAIN_APPROX_NONE)`` (tests/vision_reference.py compares them), which is Suzuki & Abe (1985)
(003 ref. [33]).

Search lines (003 §5): rows spaced ``2 l = 2 b^2 / a = 2 f tan(alpha)`` (`search_line_spacing`),
l the semi-latus rectum of the smallest ellipse to be found, so that every ellipse of at least that
size crosses a line. The integer spacing used is ``floor(2 f tan(alpha))`` (never sparser).

Algorithm
---------
Only the pixels on the seed paths are examined (thresholded on the fly from the colour frame with
`vision.binarize.sum_threshold`; the frame is never binarised as a whole), plus the 8-neighbours
of the pixels of the borders that are followed:

1. Image-border ring, then the mask seeds (`vision.mask`): each white pixel not yet on a followed
   border starts a border; its outward neighbour (virtual frame or mask) is the black start pixel.
2. Each search line, left to right, keeping track of whether the black run the scan is in belongs
   to the background around the external regions (``bg``): it starts true at the frame, is true in
   masked pixels, and at each 1->0 step is set from the mark that border following leaves on a
   border pixel whose right neighbour was examined as black (Suzuki-Abe's ``-NBD`` mark, 003 ref.
   [33] step 3.4(a)): the examined black pixels of a border are 4-connected to its start pixel, so
   the mark is set iff the right neighbour belongs to the background. A 0->1 step with ``bg`` true
   starts an outer border unless the pixel is already on one. Holes and the regions inside holes
   are therefore never followed.
3. Border following is Suzuki & Abe's Algorithm 1, step 3 (the Moore-neighbour following used by
   OpenCV): from the start pixel and its black neighbour, search clockwise for the first white
   neighbour (i1), then repeatedly search counter-clockwise around the current pixel starting next
   to the previous one, until the current pixel is i1 and the next is the start pixel.

Chains run like OpenCV's (counter-clockwise on screen around a white region: white on the left
when walking with v down); with the same start pixel the sequence is identical to OpenCV's.
Pixel coordinates are (u, v), u the column and v the row (OpenCV). Direction codes: 0 = +u (E),
1 = +u+v, 2 = +v (S), 3 = -u+v, 4 = -u (W), 5 = -u-v, 6 = -v (N), 7 = +u-v (clockwise on screen).
"""
from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass

import numba
import numpy as np

from vision.binarize import as_frame, sum_threshold
from vision.mask import PayloadMask

__all__ = [
    "SearchConfig",
    "Borders",
    "SEED_RING",
    "SEED_MASK",
    "SEED_LINE",
    "search_line_spacing",
    "search_rows",
    "find_borders",
]

SEED_RING, SEED_MASK, SEED_LINE = 0, 1, 2

_VISITED = np.uint8(1)   # pixel lies on a followed border
_EAST0 = np.uint8(2)     # ... and its +u neighbour was examined black while following (S-A -NBD)

_DV = np.array([0, 1, 1, 1, 0, -1, -1, -1], np.int64)
_DU = np.array([1, 1, 0, -1, -1, -1, 0, 1], np.int64)
# direction code of the step (dv, du): _DIR[(dv + 1) * 3 + du + 1]
_DIR = np.array([5, 6, 7, 4, -1, 0, 3, 2, 1], np.int64)

# kernel status
_OK, _OVERFLOW, _FULL = 0, 1, 2


@dataclass(frozen=True)
class SearchConfig:
    """Edge-search options.

    Attributes
    ----------
    line_spacing_px : distance of the horizontal search lines [px] (`search_line_spacing`); None
        searches the image border (and mask boundary) only (003 §3.1).
    line_offset_px : row of the first line; None centres the raster (first row = spacing / 2).
    max_points : limit on the number of followed border pixels (all borders); beyond it the search
        stops and reports an overflow (a frame of noise, not a horizon).
    alpha_min_deg : smallest apparent radius [deg] of the body the lines are spaced for: when
        ``line_spacing_px`` is None, `vision.config.resolve_search_lines` sets it to
        ``2 f tan(alpha_min)`` with the camera's focal length f (003 §5). None: no such spacing.
    """

    line_spacing_px: float | None = None
    line_offset_px: float | None = None
    max_points: int = 2_000_000
    alpha_min_deg: float | None = None

    def __post_init__(self):
        if self.line_spacing_px is not None and not (self.line_spacing_px >= 1.0):
            raise ValueError(f"SearchConfig.line_spacing_px: {self.line_spacing_px}, expected >= 1 px or None")
        if self.max_points < 1:
            raise ValueError(f"SearchConfig.max_points: {self.max_points}, expected >= 1")
        if self.alpha_min_deg is not None and not 0.0 < self.alpha_min_deg < 90.0:
            raise ValueError(f"SearchConfig.alpha_min_deg: {self.alpha_min_deg}, expected 0 < alpha < 90 deg or None")


def search_line_spacing(focal_px: float, alpha: float, scale: float = 1.0) -> float:
    """Search-line distance ``2 l = 2 f tan(alpha)`` [px] (003 §5), times ``scale`` (< 1 for margin,
    e.g. where the lens distortion shrinks the image of the body).

    ``focal_px`` is the focal length in pixels, ``alpha`` the smallest expected apparent half-angle
    [rad] of the body (Sun/Moon with glare, or the Earth cone at the highest altitude).
    """
    if not (focal_px > 0 and 0 < alpha < math.pi / 2 and scale > 0):
        raise ValueError(f"search_line_spacing: focal_px={focal_px}, alpha={alpha}, scale={scale}; "
                         "expected focal_px > 0, 0 < alpha < pi/2, scale > 0")
    return 2.0 * focal_px * math.tan(alpha) * scale


def search_rows(height: int, spacing: float | None, offset: float | None = None) -> np.ndarray:
    """Rows of the search lines: ``offset + k * floor(spacing)`` inside (0, height - 1) (the first
    and last rows belong to the image border). Empty if ``spacing`` is None."""
    if spacing is None:
        return np.zeros(0, np.int64)
    s = max(1, int(math.floor(spacing)))
    o = s // 2 if offset is None else int(round(offset))
    rows = np.arange(o, height, s, dtype=np.int64)
    return rows[(rows > 0) & (rows < height - 1)]


@dataclass(frozen=True, eq=False)
class Borders:
    """Followed outer borders, concatenated.

    Attributes
    ----------
    points : (N, 2) int32 (u, v) of all borders, each border an ordered closed chain (the last
        pixel is 8-adjacent to the first; pixels of one-pixel-wide parts appear twice, as in 003 /
        OpenCV).
    offsets : (n + 1,) int64; border i is ``points[offsets[i]:offsets[i + 1]]``.
    seed : (n,) int8, how the border was found: SEED_RING, SEED_MASK or SEED_LINE.
    rows : search-line rows used.
    shape : (H, W) of the image.
    visited : (H, W) uint8, 1 on the followed border pixels (for annotation; built on first use).
    n_scanned : pixels examined on the seed paths (ring, mask boundary, lines).
    n_followed : neighbour examinations made while following.
    overflow : the search stopped at ``max_points``.
    """

    points: np.ndarray
    offsets: np.ndarray
    seed: np.ndarray
    rows: np.ndarray
    shape: tuple[int, int]
    n_scanned: int = 0
    n_followed: int = 0
    overflow: bool = False

    def __len__(self) -> int:
        return self.offsets.size - 1

    def __getitem__(self, i: int) -> np.ndarray:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"border {i} of {n}")
        i %= n
        return self.points[self.offsets[i]:self.offsets[i + 1]]

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    @property
    def lengths(self) -> np.ndarray:
        return np.diff(self.offsets)

    @functools.cached_property
    def visited(self) -> np.ndarray:
        out = np.zeros(self.shape, np.uint8)
        out[self.points[:, 1], self.points[:, 0]] = 1
        return out


@numba.njit(cache=True, nogil=True)
def _value(img, pen, v, u):  # pragma: no cover - numba
    """Channel sum of (v, u) minus 1024 on masked pixels (so < 0: outside); -1 outside the image.

    The mask enters as arithmetic on ``pen`` (uint8 0/1, zeros without a mask): a
    data-dependent branch on the mask here makes numba/LLVM keep the call out of line (10x
    slower scans)."""
    h, w, nc = img.shape
    if v < 0 or u < 0 or v >= h or u >= w:
        return np.int64(-1)
    s = np.int64(0)
    for c in range(nc):
        s += np.int64(img[v, u, c])
    return s - np.int64(1024) * np.int64(pen[v, u])


@numba.njit(cache=True, nogil=True)
def _grow(buf, n):  # pragma: no cover - numba
    new = np.empty((2 * buf.shape[0], 2), buf.dtype)
    new[:n] = buf[:n]
    return new


@numba.njit(cache=True, nogil=True)
def _follow(img, tsum, pen, state, v0, u0, d0, buf, n, max_points, counts):  # pragma: no cover
    """Suzuki-Abe border following (003 ref. [33], Algorithm 1 step 3) from white (v0, u0) whose
    neighbour in direction d0 is black. Appends (u, v) to buf from n; returns (buf, n, status).
    The steps run in `_follow_steps` until the border closes or ``buf`` is full; then ``buf`` is
    grown here and the steps resume (a conditional ``buf = _grow(buf, n)`` inside the step loop
    makes ``buf`` a loop-carried array: numba then pays an atomic incref/decref pair per border
    pixel, ~10 % of a frame's time)."""
    nf = 0
    # (3.1) clockwise from d0: the first white neighbour i1
    d1 = -1
    for k in range(8):
        d = (d0 + k) & 7
        nf += 1
        if _value(img, pen, v0 + _DV[d], u0 + _DU[d]) >= tsum:
            d1 = d
            break
    if d1 < 0:  # isolated pixel
        counts[1] += nf
        if n >= max_points:
            return buf, n, _OVERFLOW
        if n >= buf.shape[0]:
            buf = _grow(buf, n)
        buf[n, 0] = u0
        buf[n, 1] = v0
        state[v0, u0] |= _VISITED | _EAST0
        return buf, n + 1, _OK
    v1 = v0 + _DV[d1]
    u1 = u0 + _DU[d1]
    # (i2, j2), (i3, j3), n, examinations: carried between calls of the steps
    walk = np.array([v1, u1, v0, u0, n, nf], np.int64)
    while True:
        status = _follow_steps(img, tsum, pen, state, v0, u0, v1, u1, buf, max_points, walk)
        if status != _FULL:
            counts[1] += walk[5]
            return buf, walk[4], status
        buf = _grow(buf, walk[4])


@numba.njit(cache=True, nogil=True)
def _follow_steps(img, tsum, pen, state, v0, u0, v1, u1, buf, max_points, walk):  # pragma: no cover
    """Steps (3.3)-(3.5) of `_follow` from the position in ``walk`` = [pv, pu, cv, cu, n, nf]
    (updated on return) until the border closes (_OK), ``max_points`` (_OVERFLOW) or ``buf``
    has no room for the next pixel (_FULL)."""
    pv, pu, cv, cu, n, nf = walk[0], walk[1], walk[2], walk[3], walk[4], walk[5]
    cap = buf.shape[0]
    status = _OK
    while True:
        if n >= cap and n < max_points:
            status = _FULL
            break
        # (3.3) counter-clockwise around (cv, cu) from the element after (pv, pu)
        dp = _DIR[(pv - cv + 1) * 3 + (pu - cu + 1)]
        east0 = False
        nv, nu = pv, pu
        for k in range(1, 9):
            d = (dp - k) & 7
            nf += 1
            tv = cv + _DV[d]
            tu = cu + _DU[d]
            if _value(img, pen, tv, tu) >= tsum:
                nv, nu = tv, tu
                break
            if d == 0:
                east0 = True
        # (3.4) record and mark
        if n >= max_points:
            status = _OVERFLOW
            break
        buf[n, 0] = cu
        buf[n, 1] = cv
        n += 1
        st = state[cv, cu] | _VISITED
        if east0:
            st |= _EAST0
        state[cv, cu] = st
        # (3.5) closed?
        if nv == v0 and nu == u0 and cv == v1 and cu == u1:
            break
        pv, pu = cv, cu
        cv, cu = nv, nu
    walk[0], walk[1], walk[2], walk[3], walk[4], walk[5] = pv, pu, cv, cu, n, nf
    return status


@numba.njit(cache=True, nogil=True)
def _search(img, tsum, pen, state, seed_v, seed_u, seed_d, rows, max_points, follow):  # pragma: no cover
    """The search of `find_borders` with the all-zero (H, W) ``state`` (the marks of border
    following); the marks are cleared again before returning, so that the caller can keep the
    array for the next frame instead of allocating and zeroing 2 MB per call."""
    pts, offsets, kinds, counts, status = _search_marked(img, tsum, pen, state, seed_v, seed_u, seed_d, rows,
                                                         max_points, follow)
    for i in range(pts.shape[0]):
        state[pts[i, 1], pts[i, 0]] = 0
    return pts, offsets, kinds, counts, status


@numba.njit(cache=True, nogil=True)
def _search_marked(img, tsum, pen, state, seed_v, seed_u, seed_d, rows, max_points, follow):  # pragma: no cover
    h, w, nc = img.shape
    buf = np.empty((4096, 2), np.int32)
    offsets = np.zeros(64, np.int64)
    kinds = np.zeros(64, np.int8)
    nb = 0
    n = 0
    counts = np.zeros(2, np.int64)   # [scanned, followed]
    status = _OK
    # seed paths: ring (clockwise from the top-left corner), mask boundary
    nring = 2 * (w + h) - 4
    for k in range(nring + seed_v.shape[0]):
        if k < w:
            v, u, d = 0, k, 6
        elif k < w + h - 1:
            v, u, d = k - w + 1, w - 1, 0
        elif k < 2 * w + h - 2:
            v, u, d = h - 1, w - 1 - (k - (w + h - 1)) - 1, 2
        elif k < nring:
            v, u, d = h - 2 - (k - (2 * w + h - 2)), 0, 4
        else:
            v, u, d = seed_v[k - nring], seed_u[k - nring], seed_d[k - nring]
        counts[0] += 1
        if state[v, u] & _VISITED:
            continue
        if _value(img, pen, v, u) < tsum:
            continue
        if not follow:
            continue
        start = n
        buf, n, status = _follow(img, tsum, pen, state, v, u, d, buf, n, max_points, counts)
        if nb + 1 >= offsets.shape[0]:
            offsets = np.concatenate((offsets, np.zeros(offsets.shape[0], np.int64)))
            kinds = np.concatenate((kinds, np.zeros(kinds.shape[0], np.int8)))
        offsets[nb] = start
        kinds[nb] = 0 if k < nring else 1
        nb += 1
        offsets[nb] = n
        if status != _OK:
            return buf[:n], offsets[:nb + 1], kinds[:nb], counts, status
    # search lines, left to right, tracking whether the black run is the background (bg)
    for r in range(rows.shape[0]):
        v = rows[r]
        counts[0] += w
        u, bg, prev = 0, True, False
        while True:
            u, bg = _scan_row(img, tsum, pen, state, v, u, bg, prev)
            if u >= w:
                break
            if follow:
                start = n
                buf, n, status = _follow(img, tsum, pen, state, v, u, 4, buf, n, max_points, counts)
                if nb + 1 >= offsets.shape[0]:
                    offsets = np.concatenate((offsets, np.zeros(offsets.shape[0], np.int64)))
                    kinds = np.concatenate((kinds, np.zeros(kinds.shape[0], np.int8)))
                offsets[nb] = start
                kinds[nb] = 2
                nb += 1
                offsets[nb] = n
                if status != _OK:
                    return buf[:n], offsets[:nb + 1], kinds[:nb], counts, status
            u += 1
            prev = True
    return buf[:n], offsets[:nb + 1], kinds[:nb], counts, status


@numba.njit(cache=True, nogil=True)
def _scan_row(img, tsum, pen, state, v, u, bg, prev):  # pragma: no cover - numba
    """Scan row v from column u (``bg``, ``prev`` = state left of u) to the next pixel that starts
    an external outer border not yet followed; returns (its column or W, bg there). Kept apart
    from `_search` so that this hot loop carries no array references (numba refcounting). The
    row is indexed through row views (0 <= u < W: no bounds tests), and the black runs of a
    colour frame, most of a Sun search row, are skipped in a loop of their own (~25 % faster
    than the per-pixel steps with a channel loop of unknown length)."""
    w = img.shape[1]
    nc = img.shape[2]
    row = img[v]
    prow = pen[v]
    srow = state[v]
    while u < w:
        if not prev and nc == 3:
            # black run of a colour frame: skip its unmasked black pixels (nothing changes there)
            while u < w and prow[u] == 0 and np.int64(row[u, 0]) + np.int64(row[u, 1]) + np.int64(row[u, 2]) < tsum:
                u += 1
            if u >= w:
                break
        if prow[u]:              # masked: outside, like the frame
            bg = True
            prev = False
        else:
            val = np.int64(0)
            for c in range(nc):
                val += np.int64(row[u, c])
            cur = val >= tsum
            if cur and not prev:
                if bg and (srow[u] & _VISITED) == 0:
                    return u, bg
            elif prev and not cur:
                bg = (srow[u - 1] & _EAST0) != 0
            prev = cur
        u += 1
    return w, bg


@functools.lru_cache(maxsize=4)
def _zero_penalty(shape: tuple[int, int]) -> np.ndarray:
    # a real C-contiguous array (not a stride-0 view) so that the kernel compiles once
    return np.zeros(shape, np.uint8)


def _mask_arrays(mask: PayloadMask | None, shape):
    z = np.zeros(0, np.int64)
    if mask is not None:
        mask.check(shape)
    if mask is None or not mask.has_mask:
        return _zero_penalty(tuple(shape)), z, z, z
    return np.ascontiguousarray(mask.penalty), mask.seed_v, mask.seed_u, mask.seed_d


def find_borders(image, threshold: float, mask: PayloadMask | None = None,
                 config: SearchConfig = SearchConfig(), rows: np.ndarray | None = None,
                 _follow_borders: bool = True) -> Borders:
    """Outer borders of the white regions touching the image border / mask or crossing a search line.

    Parameters
    ----------
    image : (H, W, 3) or (H, W) uint8 frame (BGR or RGB: the mean does not depend on the order).
    threshold : mean-brightness threshold t [0, 255]; white iff mean of channels >= t
        (`vision.binarize`). For a binary 0/1 or 0/255 image use 1.
    mask : payload mask (`vision.mask.PayloadMask`) of the same size, or None.
    config : search options; ``rows`` (explicit search rows) overrides ``config.line_spacing_px``.

    Returns
    -------
    Borders ; ``overflow`` is set if more than ``config.max_points`` border pixels were followed.
    """
    a = np.ascontiguousarray(as_frame(image))   # views (crops, flips) are copied: one kernel
    h, w = a.shape[:2]
    pen, sv, su, sd = _mask_arrays(mask, (h, w))
    if rows is None:
        rows = search_rows(h, config.line_spacing_px, config.line_offset_px)
    else:
        rows = np.asarray(rows, dtype=np.int64).ravel()
        if rows.size and (rows.min() < 0 or rows.max() >= h):
            raise ValueError(f"rows: values {rows.min()}..{rows.max()}, expected 0..{h - 1}")
    if not (0.0 <= threshold <= 255.0):
        raise ValueError(f"threshold: {threshold}, expected 0..255 (mean of the channels)")
    tsum = sum_threshold(threshold, a.shape[2])
    state = _take_state(h, w)
    pts, offs, kinds, counts, status = _search(
        a, tsum, pen, state, sv, su, sd, rows, int(config.max_points), bool(_follow_borders))
    _STATE.array = state     # cleared by the kernel: reused next call (not after an exception)
    return Borders(pts, offs.copy(), kinds.copy(), rows, (h, w),
                   int(counts[0]), int(counts[1]), status == _OVERFLOW)


_STATE = threading.local()


def _take_state(h: int, w: int) -> np.ndarray:
    """The all-zero (h, w) uint8 mark array of this thread (taken, so a nested or failed call
    gets a fresh one)."""
    st = getattr(_STATE, "array", None)
    _STATE.array = None
    if st is None or st.shape != (h, w):
        st = np.zeros((h, w), np.uint8)
    return st
