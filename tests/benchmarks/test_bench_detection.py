"""Detection stage (003 §3.1, §5) on a 1920x1080 frame: per-stage medians against the JPEG decode
of the same frame (baseline) and against the OpenCV full-frame path (binarise + findContours).

Proposed location: tests/benchmarks/test_bench_detection.py (uses the `bench` fixture)."""
import math

import cv2
import numpy as np

from vision import mask as vmask
from vision.binarize import BinarizeConfig, binarize, brightness_gate, brightness_histogram, resolve_threshold
from tests.benchmarks.timing import median_ms
from tests.vision_reference import find_borders_reference
from vision.borders import SearchConfig, find_borders, search_line_spacing
from vision.candidates import DetectionConfig, detect, split_borders



def _frame(h=1080, w=1920, seed=0):
    """Distortion-free stand-in: Earth disc crossing the image with cloud texture (bright clouds,
    dark sea), a Sun with glare, sensor noise. BGR uint8."""
    rng = np.random.default_rng(seed)
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
    earth = np.hypot(uu - 900.0, vv - 2600.0) < 2000.0
    n = cv2.resize(cv2.GaussianBlur(rng.random((h // 8, w // 8)).astype(np.float32), (0, 0), 2), (w, h))
    n = (n - n.mean()) / n.std()
    bright = np.where(earth, np.where(n > 0.3, 160.0, 60.0), 0.0).astype(np.float32)
    img = 8.0 + bright[..., None] * np.array([1.0, 0.9, 0.8], np.float32)
    s = np.hypot(uu - 400.0, vv - 250.0)
    img += (np.where(s < 25, 250.0, 0.0) + 120.0 * np.exp(-s / 60.0))[..., None]
    img += rng.normal(0, 3, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_bench_detection(bench, is_quick):
    cv2.setNumThreads(1)
    n = 20 if is_quick else 200
    img = _frame()
    h, w = img.shape[:2]
    mask = vmask.from_polygons((h, w), [[(1800, 1079), (1919, 700), (1919, 1079)]])
    ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    t_dec = median_ms(lambda: cv2.imdecode(jpg, cv2.IMREAD_COLOR), max(10, n // 5))
    bench("detection.jpeg_decode_1080p", t_dec, "ms")
    f_px = 960.0 / math.tan(math.radians(47.2))           # ATEK: 1920 px over 94.4 deg
    targets = {
        "earth": DetectionConfig(BinarizeConfig(threshold=100.0), SearchConfig(), 20),
        "sun": DetectionConfig(BinarizeConfig(threshold=240.0),
                               SearchConfig(line_spacing_px=search_line_spacing(f_px, math.radians(0.54))), 20),
    }
    total = 0.0
    for name, cfg in targets.items():
        bc = cfg.binarize
        hist = brightness_histogram(img, bc.sample_step)
        t = resolve_threshold(img, bc, hist)
        t_thr = median_ms(lambda: (brightness_gate(img, bc, brightness_histogram(img, bc.sample_step)),
                                    resolve_threshold(img, bc, hist)), n)
        t_seed = median_ms(lambda: find_borders(img, t, mask, cfg.search, _follow_borders=False), n)
        t_search = median_ms(lambda: find_borders(img, t, mask, cfg.search), n)
        borders = find_borders(img, t, mask, cfg.search)
        t_split = median_ms(lambda: split_borders(borders, mask, cfg.min_length), n)
        t_det = median_ms(lambda: detect(img, cfg, mask), n)
        binary = binarize(img, t, mask.mask)
        t_bin = median_ms(lambda: binarize(img, t, mask.mask), max(10, n // 5))
        t_cv = median_ms(lambda: find_borders_reference(binary, mask, borders.rows), max(10, n // 5))
        ref = find_borders_reference(binary, mask, borders.rows)
        assert {frozenset(map(tuple, b.tolist())) for b in borders} == \
            {frozenset(map(tuple, b.tolist())) for b in ref}
        bench(f"detection.{name}.gate_threshold", t_thr, "ms")
        bench(f"detection.{name}.seed_scan", t_seed, "ms", n_scanned=borders.n_scanned)
        bench(f"detection.{name}.follow", max(t_search - t_seed, 0.0), "ms", n_points=int(borders.points.shape[0]))
        bench(f"detection.{name}.split", t_split, "ms", n_candidates=len(split_borders(borders, mask, 20)))
        bench(f"detection.{name}.detect_total", t_det, "ms", baseline=t_dec,
              baseline_name="JPEG decode of the same frame, same run")
        bench(f"detection.{name}.opencv_full_frame", t_bin + t_cv, "ms", baseline=t_det,
              baseline_name="detect_total of the same frame, same run", notes="binarise whole frame + findContours(RETR_EXTERNAL)")
        total += t_det
    bench("detection.earth_plus_sun", total, "ms", baseline=t_dec,
          baseline_name="JPEG decode of the same frame, same run")
