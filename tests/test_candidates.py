"""Splitting borders into edge candidates (003 fig. 11, §5) and the detection stage `detect`.

Truth: synthetic images whose edge pixels are known in closed form. For an 8-connected white
region the outer-border pixels are the white pixels with a black 4-neighbour (Suzuki & Abe 1985,
003 ref. [33]); the candidates are those not on the frame (8-adjacent to the outside)."""
import math

import numpy as np
import pytest

from vision import mask as vmask
from vision.binarize import BinarizeConfig
from vision.borders import SearchConfig, find_borders
from vision.candidates import DetectionConfig, detect, split_borders

H, W = 240, 320


def _edge_truth(binary, mask=None):
    """White pixels with a black (or masked, or outside) 4-neighbour, minus frame pixels."""
    b = binary.astype(bool)
    if mask is not None:
        b &= ~mask
    p = np.pad(b, 1, constant_values=False)
    black4 = ~p[:-2, 1:-1] | ~p[2:, 1:-1] | ~p[1:-1, :-2] | ~p[1:-1, 2:]
    edge = b & black4 & ~vmask.frame_pixels(b.shape, mask)
    v, u = np.nonzero(edge)
    return set(zip(u.tolist(), v.tolist()))


def _colour(binary, lo=10, hi=180):
    img = np.where(binary[..., None].astype(bool), hi, lo).astype(np.uint8)
    return np.repeat(img, 3, axis=2)


def _pixels(cands):
    return set(map(tuple, np.concatenate([c.points for c in cands]).astype(int).tolist()))


def test_half_plane_gives_one_horizon_from_left_to_right():
    img = np.zeros((H, W), np.uint8)
    img[130:] = 1
    d = detect(_colour(img), DetectionConfig(BinarizeConfig(threshold=100)))
    assert d.ok and d.reason == ""
    (c,) = d.candidates
    assert c.points.dtype == np.float64 and c.points.shape == (W - 2, 2)
    np.testing.assert_array_equal(c.points[:, 1], 130.0)
    assert sorted(c.points[:, 0]) == list(range(1, W - 1))
    assert c.edges == {"left", "right"} and not c.closed and c.touches_border
    assert c.arc_length == pytest.approx(W - 3)


def test_large_circle_crossing_the_image_edges():
    # the Earth from low altitude: a disc centred below the image, crossing left and right
    vv, uu = np.mgrid[0:H, 0:W]
    cu, cv, r = 150.3, 700.0, 560.0
    img = ((uu - cu) ** 2 + (vv - cv) ** 2 <= r * r).astype(np.uint8)
    d = detect(_colour(img))
    (c,) = d.candidates
    assert _pixels([c]) == _edge_truth(img)
    assert c.edges == {"left", "right"}
    # every candidate pixel lies on the circle to within the pixel quantisation (1 px)
    dist = np.hypot(c.points[:, 0] - cu, c.points[:, 1] - cv) - r
    assert np.all((dist <= 0) & (dist > -1.0))
    # ordered: consecutive pixels are 8-neighbours
    assert np.abs(np.diff(c.points, axis=0)).max() == 1.0


def test_circle_through_a_corner_and_one_through_top_and_bottom():
    vv, uu = np.mgrid[0:H, 0:W]
    img = ((uu + 20.0) ** 2 + (vv + 30.0) ** 2 <= 150.0 ** 2).astype(np.uint8)   # top-left corner
    (c,) = detect(_colour(img)).candidates
    assert c.edges == {"top", "left"}
    assert _pixels([c]) == _edge_truth(img)
    img = ((uu + 400.0) ** 2 + (vv - 120.0) ** 2 <= 600.0 ** 2).astype(np.uint8)  # left part
    (c,) = detect(_colour(img)).candidates
    assert c.edges == {"top", "bottom"}


def test_mask_covering_part_of_the_edge_splits_the_horizon():
    # payload from the top edge down through the horizon in the middle (003 fig. 10-11)
    img = np.zeros((H, W), np.uint8)
    img[130:] = 1
    m = np.zeros((H, W), bool)
    m[:180, 140:190] = True
    pm = vmask.from_binary(m)
    d = detect(_colour(img), mask=pm)
    assert [c.edges for c in sorted(d.candidates, key=lambda c: c.points[0, 0])] == \
        [{"left", "mask"}, {"mask", "right"}]
    assert _pixels(d.candidates) == _edge_truth(img, m)
    for c in d.candidates:                 # nothing on or next to the mask
        assert not pm.frame[c.points[:, 1].astype(int), c.points[:, 0].astype(int)].any()
    # a payload along the right edge: the horizon ends at the mask, not at the right border
    m2 = np.zeros((H, W), bool)
    m2[:, W - 60:] = True
    (c,) = detect(_colour(img), mask=vmask.from_polygons((H, W), [[(W - 60, 0), (W - 1, 0), (W - 1, H - 1),
                                                                   (W - 60, H - 1)]])).candidates
    assert c.edges == {"left", "mask"} and c.points[:, 0].max() == W - 62


def test_sun_disc_inside_the_image_is_one_closed_candidate():
    vv, uu = np.mgrid[0:H, 0:W]
    img = np.zeros((H, W, 3), np.uint8) + 15
    sun = (uu - 200.4) ** 2 + (vv - 90.7) ** 2 <= 12.0 ** 2
    img[sun] = 255
    earth = vv >= 200
    img[earth] = 140                       # Earth: below the Sun threshold
    sun_cfg = DetectionConfig(BinarizeConfig(threshold=240),
                              SearchConfig(line_spacing_px=search_spacing_for_radius(12.0)))
    d = detect(img, sun_cfg)
    (c,) = d.candidates
    assert c.closed and c.start_edge is None and c.end_edge is None and not c.touches_border
    assert _pixels([c]) == _edge_truth(sun)
    dist = np.hypot(c.points[:, 0] - 200.4, c.points[:, 1] - 90.7)
    assert np.all((dist <= 12.0) & (dist > 11.0))
    assert c.arc_length == pytest.approx(2 * math.pi * 12.0, rel=0.1)   # digital circle perimeter
    # the Earth threshold sees both; the Earth's candidate touches left/right
    d = detect(img, DetectionConfig(BinarizeConfig(threshold=100)))
    assert [c.edges for c in d.candidates] == [{"left", "right"}]       # Sun not on a line: ignored


def search_spacing_for_radius(r):
    from vision.borders import search_line_spacing
    return search_line_spacing(1000.0, math.atan(r / 1000.0))


def test_clouds_are_ignored():
    # small enclosed blobs (clouds) not touching the border: ignored (003 fig. 10)
    img = np.zeros((H, W), np.uint8)
    img[150:] = 1
    rng = np.random.default_rng(5)
    for _ in range(15):
        u0, v0 = int(rng.integers(5, W - 15)), int(rng.integers(5, 130))
        img[v0:v0 + 6, u0:u0 + 8] = 1
    for _ in range(15):                     # dark holes in the Earth
        u0, v0 = int(rng.integers(5, W - 15)), int(rng.integers(160, H - 10))
        img[v0:v0 + 5, u0:u0 + 7] = 0
    (c,) = detect(_colour(img)).candidates
    np.testing.assert_array_equal(c.points[:, 1], 150.0)


def test_split_keeps_min_length_and_returns_borders():
    img = np.zeros((H, W), np.uint8)
    img[130:] = 1
    img[:8, 100:110] = 1                    # bump on the top edge: interior 7 + 8 + 7 px (v = 0 is frame)
    b = find_borders(_colour(img), 100)
    assert len(b) == 2
    assert [c.n_pixels for c in split_borders(b, min_length=5)] == [22, W - 2]
    assert [c.n_pixels for c in split_borders(b, min_length=30)] == [W - 2]
    d = detect(_colour(img), DetectionConfig(min_length=30))
    assert d.borders is not None and len(d.borders) == 2 and len(d.candidates) == 1
    with pytest.raises(ValueError, match="min_length"):
        split_borders(b, min_length=0)


def test_border_starting_mid_candidate_is_joined_across_the_chain_start():
    # a region touching only the top edge, whose chain starts on the edge: its interior piece is
    # one candidate even though the chain wraps around (the join across the chain start)
    vv, uu = np.mgrid[0:H, 0:W]
    img = ((uu - 160.0) ** 2 + (vv + 40.0) ** 2 <= 100.0 ** 2).astype(np.uint8)
    (c,) = detect(_colour(img)).candidates
    assert c.edges == {"top"}
    assert np.abs(np.diff(c.points, axis=0)).max() == 1.0   # contiguous in order
    assert _pixels([c]) == _edge_truth(img)


def test_chain_starting_inside_a_candidate_is_joined():
    # a chain may start at an interior pixel (line seed); the pieces at both ends of the chain are
    # one candidate across the wrap: the same candidate as for the chain started on the frame
    import dataclasses
    img = np.zeros((H, W), np.uint8)
    img[130:] = 1
    b = find_borders(_colour(img), 100)
    (ref,) = split_borders(b)
    for shift in (1, 57, 200, W - 3):
        k = int(np.flatnonzero((b.points[:, 1] == 130) & (b.points[:, 0] > 0) & (b.points[:, 0] < W - 1))[0])
        rolled = dataclasses.replace(b, points=np.roll(b.points, -(k + shift), axis=0))
        assert 0 < rolled.points[0, 0] < W - 1 and rolled.points[0, 1] == 130   # starts inside
        (c,) = split_borders(rolled)
        assert c.n_pixels == ref.n_pixels and c.edges == {"left", "right"}
        assert c.arc_length == pytest.approx(ref.arc_length)
        assert _same_cycle_open(c.points, ref.points)


def _same_cycle_open(a, b):
    return np.array_equal(a, b) or np.array_equal(a, b[::-1])


def test_noise_black_and_white_frames_give_no_candidates_with_a_reason():
    rng = np.random.default_rng(9)
    noise = np.clip(rng.normal(12, 5, (H, W, 3)), 0, 255).astype(np.uint8)
    salt = rng.random((H, W)) < 0.002
    noise[salt] = 255                        # isolated hot pixels
    cfg = DetectionConfig(BinarizeConfig(threshold=100), SearchConfig(line_spacing_px=10))
    d = detect(noise, cfg)
    assert not d.ok and "no candidate of >= 20 pixels" in d.reason
    d = detect(np.clip(rng.normal(12, 5, (H, W, 3)), 0, 255).astype(np.uint8), cfg)
    assert not d.ok and d.reason.startswith("no white pixel") and "search lines" in d.reason
    black = np.zeros((H, W, 3), np.uint8)
    white = np.full((H, W, 3), 255, np.uint8)
    assert detect(black).reason.startswith("no white pixel")
    assert "along the image border" in detect(white).reason
    gated = DetectionConfig(BinarizeConfig(gate_min=5, gate_max=250))
    d = detect(black, gated)
    assert not d.ok and "too dark" in d.reason and d.borders is None and math.isnan(d.threshold)
    assert "too bright" in detect(white, gated).reason
    # a frame of noise at the threshold: the search stops at max_points, with a reason
    grey = rng.integers(95, 106, (H, W, 3), dtype=np.uint8)
    d = detect(grey, DetectionConfig(search=SearchConfig(max_points=500)))
    assert not d.ok and "max_points" in d.reason


def test_wrong_image_size_is_a_clear_error():
    img = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(ValueError, match=rf"size {W}x{H} \(WxH\), expected 1920x1080"):
        detect(img, expected_shape=(1080, 1920))
    with pytest.raises(ValueError, match="differs from the payload mask"):
        detect(img, mask=vmask.no_mask((1080, 1920)))
    with pytest.raises(ValueError, match="polygon 0"):
        vmask.from_polygons((H, W), [[(0, 0), (1, 1)]])


def test_shared_histogram_gives_the_same_detection():
    # detect(..., hist=) with the frame's histogram (shared by the Earth and Sun detections of a
    # frame) is the same detection as computing it inside; a histogram of the wrong length is refused
    from vision.binarize import brightness_histogram
    vv, uu = np.mgrid[0:H, 0:W]
    img = _colour(((uu - 150.3) ** 2 + (vv - 700.0) ** 2 <= 560.0 ** 2).astype(np.uint8))
    cfg = DetectionConfig(BinarizeConfig(threshold=100, gate_min=20.0))
    a = detect(img, cfg)
    b = detect(img, cfg, hist=brightness_histogram(img, cfg.binarize.sample_step))
    assert a.brightness == b.brightness and a.threshold == b.threshold and len(a.candidates) == len(b.candidates) == 1
    assert np.array_equal(a.candidates[0].points, b.candidates[0].points)
    with pytest.raises(ValueError, match="hist: shape"):
        detect(img, cfg, hist=np.zeros(256, np.int64))
