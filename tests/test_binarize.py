"""Binarisation (003 §3.1; 004 §2.2.1-2.2.2) against numpy / OpenCV references."""
import cv2
import numpy as np
import pytest

from vision.binarize import (BinarizeConfig, as_frame, binarize, brightness_gate, brightness_histogram,
                             frame_brightness, otsu_threshold, pixel_brightness, resolve_threshold,
                             sum_threshold)


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def test_sum_threshold_is_exact_for_every_sum():
    # mean >= t  <=>  sum >= ceil(3 t): checked on every possible channel sum, integer and
    # fractional thresholds (incl. ones whose 3 t is not exact in binary floating point)
    s = np.arange(0, 766)
    for t in np.concatenate([np.arange(0, 256, 1.0), [0.1, 80.4, 80.33333333333333, 100 / 3, 254.9]]):
        T = sum_threshold(t, 3)
        np.testing.assert_array_equal(s >= T, s / 3.0 >= t - 1e-12, err_msg=f"t={t}")


def test_binarize_equals_mean_of_rgb(rng):
    img = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    for t in (0.0, 1.0, 80.0, 80.4, 127.5, 255.0):
        ref = (img.astype(np.float64).mean(axis=2) >= t - 1e-12).astype(np.uint8)
        np.testing.assert_array_equal(binarize(img, t), ref)
        np.testing.assert_array_equal(binarize(img, t), (pixel_brightness(img) >= t - 1e-12))


def test_binarize_independent_of_channel_order_and_grey(rng):
    img = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    np.testing.assert_array_equal(binarize(img, 90), binarize(img[:, :, ::-1].copy(), 90))
    grey = rng.integers(0, 256, (20, 30), dtype=np.uint8)
    np.testing.assert_array_equal(binarize(grey, 90), (grey >= 90).astype(np.uint8))


def test_binarize_mask_sets_black(rng):
    img = np.full((10, 12, 3), 200, np.uint8)
    m = np.zeros((10, 12), bool)
    m[:, 9:] = True
    b = binarize(img, 100, m)
    assert b[:, :9].all() and not b[:, 9:].any()
    with pytest.raises(ValueError, match="mask"):
        binarize(img, 100, np.zeros((9, 12), bool))


def test_histogram_and_frame_brightness_match_numpy(rng):
    img = rng.integers(0, 256, (101, 77, 3), dtype=np.uint8)
    for step in (1, 4, 8):
        sub = img[step // 2::step, step // 2::step].astype(np.int64)
        ref = np.bincount(sub.sum(axis=2).ravel(), minlength=766)
        np.testing.assert_array_equal(brightness_histogram(img, step), ref)
        assert frame_brightness(img, step) == pytest.approx(sub.mean(), rel=1e-12)


def test_gate_rejects_dark_and_bright_frames_with_reason():
    cfg = BinarizeConfig(gate_min=5.0, gate_max=250.0)
    black = np.zeros((40, 60, 3), np.uint8)
    white = np.full((40, 60, 3), 255, np.uint8)
    mid = np.full((40, 60, 3), 100, np.uint8)
    g = brightness_gate(black, cfg)
    assert not g.accepted and "too dark" in g.reason and g.brightness == 0.0
    g = brightness_gate(white, cfg)
    assert not g.accepted and "too bright" in g.reason and g.brightness == 255.0
    g = brightness_gate(mid, cfg)
    assert g.accepted and g.reason == "" and g.brightness == 100.0


def test_otsu_matches_opencv():
    # bimodal grey image; OpenCV's Otsu returns T with "white = value > T", ours t with ">= t"
    rng = np.random.default_rng(3)
    a = np.concatenate([rng.normal(40, 10, 3000), rng.normal(170, 15, 2000)])
    grey = np.clip(a, 0, 255).astype(np.uint8).reshape(50, 100)
    T, _ = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    t = otsu_threshold(brightness_histogram(grey, 1), 1)
    assert t == T + 1
    # restricted range: the same modes, range excluding nothing relevant gives the same split
    assert otsu_threshold(brightness_histogram(grey, 1), 1, 5.0, 250.0) == pytest.approx(t, abs=1.0)


def test_resolve_threshold_methods():
    img = np.zeros((40, 40, 3), np.uint8)
    img[:20] = 200
    img[20:] = 20
    assert resolve_threshold(img, BinarizeConfig(threshold=77)) == 77.0
    # dynamic: factor * b_s (004 §2.2.2): b_s = 110 over the grid
    t = resolve_threshold(img, BinarizeConfig(method="dynamic", factor=1.5, sample_step=2))
    assert t == pytest.approx(1.5 * 110.0)
    t = resolve_threshold(img, BinarizeConfig(method="otsu", sample_step=2))
    assert 20 < t <= 200
    t = resolve_threshold(img, BinarizeConfig(method="dynamic", factor=5.0, threshold_max=240))
    assert t == 240.0


def test_bad_frames_and_configs_raise_clear_errors():
    with pytest.raises(ValueError, match="dtype float64, expected uint8"):
        as_frame(np.zeros((10, 10, 3)))
    with pytest.raises(ValueError, match=r"\(H, W\) grey or \(H, W, 3\)"):
        as_frame(np.zeros((10, 10, 4), np.uint8))
    with pytest.raises(ValueError, match="at least 3x3"):
        as_frame(np.zeros((2, 10), np.uint8))
    with pytest.raises(ValueError, match="size 1280x720 .* expected 1920x1080"):
        as_frame(np.zeros((720, 1280, 3), np.uint8), expected_shape=(1080, 1920))
    with pytest.raises(ValueError, match="method"):
        BinarizeConfig(method="adaptive")
    with pytest.raises(ValueError, match="threshold"):
        BinarizeConfig(threshold=300)
    with pytest.raises(ValueError, match="gate_min"):
        BinarizeConfig(gate_min=200, gate_max=100)
