"""Seeded Suzuki-Abe border following (003 §3.1, §5; 004 §2.2.3) against OpenCV's findContours
(which implements Suzuki & Abe 1985, 003 ref. [33]) as the independent reference."""
import math

import cv2
import numpy as np
import pytest

from vision import mask as vmask
from vision.binarize import binarize
from tests.vision_reference import find_borders_reference
from vision.borders import (SEED_LINE, SEED_MASK, SEED_RING, SearchConfig, find_borders, search_line_spacing,
                            search_rows)


def _sets(borders):
    return sorted((sorted(map(tuple, b.tolist())) for b in borders), key=lambda s: (len(s), s))


def _same_cycle(a, b):
    """a equals b up to the starting point and the direction of travel."""
    a = [tuple(x) for x in a.tolist()]
    b = [tuple(x) for x in b.tolist()]
    if len(a) != len(b):
        return False
    for seq in (b, b[::-1]):
        for s in range(len(seq)):
            if seq[s:] + seq[:s] == a:
                return True
    return False


def _blobs(rng, h, w):
    """Random binary image with structure on several scales (regions, holes, nested islands)."""
    g = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), float(rng.uniform(0.5, 3.0)))
    return (g > np.quantile(g, rng.uniform(0.2, 0.8))).astype(np.uint8)


def test_every_row_searched_equals_opencv_external_contours():
    # with a search line on every row every external component crosses a line: the result must be
    # exactly findContours(RETR_EXTERNAL, CHAIN_APPROX_NONE), same pixels in the same cyclic order
    rng = np.random.default_rng(11)
    n = 0
    for trial in range(150):
        h, w = (int(x) for x in rng.integers(3, 45, 2))
        img = _blobs(rng, h, w) if trial % 2 else (rng.random((h, w)) < rng.uniform(0.2, 0.8)).astype(np.uint8)
        rows = np.arange(h)
        mine = find_borders(img, 1, rows=rows)
        ref = find_borders_reference(img, rows=rows)
        assert _sets(mine) == _sets(ref), f"trial {trial}"
        by_set = {frozenset(map(tuple, b.tolist())): b for b in ref}
        for b in mine:
            assert _same_cycle(b, by_set[frozenset(map(tuple, b.tolist()))])
            n += 1
    assert n > 300


def test_sparse_lines_and_masks_equal_filtered_opencv():
    # sparse search rows and payload masks attached to the image edge: the borders found are the
    # external contours that touch the image border or the mask or have a pixel on a search row
    rng = np.random.default_rng(12)
    for trial in range(200):
        h, w = (int(x) for x in rng.integers(5, 50, 2))
        img = _blobs(rng, h, w)
        rows = np.sort(rng.choice(h, int(rng.integers(0, h // 2 + 1)), replace=False))
        m = None
        if trial % 2:
            k = int(rng.integers(1, max(2, w // 3)))
            mm = np.zeros((h, w), bool)
            [lambda: mm.__setitem__((slice(None), slice(0, k)), True),
             lambda: mm.__setitem__((slice(None), slice(w - k, None)), True),
             lambda: mm.__setitem__((slice(int(rng.integers(0, h)), None), slice(int(rng.integers(0, w)), None)),
                                    True)][trial % 3]()
            m = vmask.from_binary(mm)
        mine = find_borders(img * 255, 1, mask=m, rows=rows)
        ref = find_borders_reference(img, mask=m, rows=rows)
        assert _sets(mine) == _sets(ref), f"trial {trial}"


def test_colour_frame_thresholded_on_the_fly_equals_binarised():
    rng = np.random.default_rng(13)
    img = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    img = cv2.GaussianBlur(img, (0, 0), 2.0)
    rows = search_rows(60, 7)
    for t in (90.0, 127.4, 140.0):
        a = find_borders(img, t, rows=rows)
        b = find_borders(binarize(img, t), 1, rows=rows)
        assert _sets(a) == _sets(b) and len(a) > 0


def test_non_contiguous_and_grey_frames():
    rng = np.random.default_rng(14)
    img = cv2.GaussianBlur(rng.integers(0, 256, (81, 121, 3), dtype=np.uint8), (0, 0), 2.0)
    rows = search_rows(81, 5)
    ref = find_borders(np.ascontiguousarray(img[::2, ::-1]), 128, rows=rows[rows < 41])
    assert len(ref) > 0
    assert _sets(find_borders(img[::2, ::-1], 128, rows=rows[rows < 41])) == _sets(ref)
    grey = np.ascontiguousarray(img[:, :, 0])
    assert _sets(find_borders(grey, 128, rows=rows)) == _sets(find_borders(grey[:, :, None], 128, rows=rows))
    with pytest.raises(ValueError, match="threshold"):
        find_borders(grey, -1.0)


def _disc(h, w, cu, cv, r):
    vv, uu = np.mgrid[0:h, 0:w]
    return ((uu - cu) ** 2 + (vv - cv) ** 2 <= r * r).astype(np.uint8)


def test_enclosed_disc_found_only_via_a_search_line():
    h, w = 120, 160
    img = _disc(h, w, 70.3, 55.8, 9.5)
    assert len(find_borders(img, 1)) == 0                      # border only: not examined at all
    # lines 2 f tan(alpha) apart with f tan(alpha) = the disc radius: the disc must be crossed
    # whatever the raster offset (003 §5)
    spacing = search_line_spacing(focal_px=950.0, alpha=math.atan(9.5 / 950.0))
    assert spacing == pytest.approx(19.0)
    ref = find_borders_reference(img, rows=np.arange(h))
    for offset in range(int(spacing)):
        b = find_borders(img, 1, config=SearchConfig(line_spacing_px=spacing, line_offset_px=offset))
        assert len(b) == 1 and b.seed[0] == SEED_LINE
        assert _sets(b) == _sets(ref)
        # only the seed lines and the followed border were examined
        assert b.n_scanned == 2 * (h + w) - 4 + b.rows.size * w
        assert np.count_nonzero(b.visited) == len(set(map(tuple, b[0].tolist())))


def test_search_rows_cover_every_window():
    for spacing in (1.0, 2.5, 8.4, 19.0, 50.0):
        rows = search_rows(1080, spacing)
        s = int(math.floor(spacing))
        # every window of s consecutive interior rows contains a search row
        inside = np.zeros(1080, bool)
        inside[rows] = True
        c = np.convolve(inside[1:-1].astype(int), np.ones(s, int), mode="valid")
        assert c.min() >= 1, spacing
    assert search_rows(1080, None).size == 0
    with pytest.raises(ValueError, match="alpha"):
        search_line_spacing(900.0, 0.0)


def test_clouds_inside_and_holes_are_ignored():
    # Earth = lower half; dark holes (cloud-free sea) inside it, a bright cloud inside one hole,
    # small bright blobs in space: only the Earth's outer border is followed, even where search
    # lines cross the holes, the nested cloud and the blobs... except blobs that a line crosses
    h, w = 200, 300
    img = np.zeros((h, w), np.uint8)
    img[100:] = 1
    img[140:170, 50:120] = 0              # hole
    img[150:160, 70:90] = 1               # cloud inside the hole (nested: not external)
    img[30:36, 40:46] = 1                 # blob in space, between lines
    img[60:70, 200:215] = 1               # blob in space crossed by the line at row 64
    rows = np.array([64, 155])
    b = find_borders(img, 1, rows=rows)
    ref = find_borders_reference(img, rows=rows)
    assert _sets(b) == _sets(ref)
    assert len(b) == 2 and sorted(b.seed.tolist()) == [SEED_RING, SEED_LINE]
    pix = set(map(tuple, b.points.tolist()))
    assert (50, 155) not in pix and (70, 155) not in pix      # hole and nested cloud not followed
    assert not b.visited[140:170, 50:120].any()               # nor even touched
    assert not b.visited[30:36, 40:46].any()


def test_region_touching_only_the_mask_is_found():
    h, w = 60, 80
    m = np.zeros((h, w), bool)
    m[:, 60:] = True                      # payload on the right
    img = np.zeros((h, w), np.uint8)
    img[20:40, 45:] = 1                   # region reaching into the payload only
    pm = vmask.from_binary(m)
    b = find_borders(img, 1, mask=pm)
    assert len(b) == 1 and b.seed[0] == SEED_MASK
    assert b.points[:, 0].max() == 59     # followed along the mask, never into it
    assert len(find_borders(img, 1)) == 1 and find_borders(img, 1).seed[0] == SEED_RING


def test_overflow_and_bad_input():
    img = np.zeros((50, 50), np.uint8)
    img[10:40, :] = 1
    b = find_borders(img, 1, config=SearchConfig(max_points=20))
    assert b.overflow
    with pytest.raises(ValueError, match="rows"):
        find_borders(img, 1, rows=[0, 50])
    with pytest.raises(ValueError, match="differs from the payload mask"):
        find_borders(img, 1, mask=vmask.no_mask((40, 50)))
    with pytest.raises(ValueError, match="line_spacing_px"):
        SearchConfig(line_spacing_px=0.5)


def test_repeated_searches_start_from_clean_marks():
    # find_borders keeps its (H, W) mark array between calls and clears the marks it set: a search
    # after one on another frame (or one that overflowed) must equal a search on a fresh array.
    h, w = 120, 160
    a = _disc(h, w, 0.0, 60.0, 50.0)             # touches the left border
    b = _disc(h, w, 159.0, 30.0, 40.0)           # touches the right border
    rows = np.arange(0, h, 7)
    fresh = find_borders(b, 1, rows=rows)
    find_borders(a, 1, rows=rows)
    assert find_borders(a, 1, config=SearchConfig(max_points=10)).overflow
    again = find_borders(b, 1, rows=rows)
    assert _sets(again) == _sets(fresh) == _sets(find_borders_reference(b, rows=rows))
    assert np.array_equal(again.visited, fresh.visited)
