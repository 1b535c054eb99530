"""scenarios.flightlog.jpeg.decode_frame: the same pixels as cv2.imdecode (the reference) for the renderer's
JPEGs, grey JPEGs and PNGs; None for bytes that are not an image or a truncated JPEG."""
import cv2
import numpy as np

from scenarios.flightlog.jpeg import decode_frame


def _img(seed=0, h=96, w=160):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    base = np.stack([(x * 255 // w), (y * 255 // h), ((x + y) * 255 // (w + h))], -1).astype(np.uint8)
    return np.clip(base + rng.integers(0, 40, base.shape), 0, 255).astype(np.uint8)


def test_jpeg_decodes_bit_identical_to_opencv():
    for q in (50, 90, 100):
        for seed in range(3):
            ok, jpg = cv2.imencode(".jpg", _img(seed), [cv2.IMWRITE_JPEG_QUALITY, q])
            ref = cv2.imdecode(jpg, cv2.IMREAD_COLOR)
            got = decode_frame(jpg.tobytes())
            assert got.dtype == np.uint8 and got.shape == ref.shape
            np.testing.assert_array_equal(got, ref)


def test_grey_jpeg_png_and_bad_bytes():
    ok, grey = cv2.imencode(".jpg", _img(1)[..., 0])
    np.testing.assert_array_equal(decode_frame(grey.tobytes()), cv2.imdecode(grey, cv2.IMREAD_COLOR))
    ok, png = cv2.imencode(".png", _img(2))
    np.testing.assert_array_equal(decode_frame(png.tobytes()), _img(2))
    assert decode_frame(b"not an image") is None
    ok, jpg = cv2.imencode(".jpg", _img(3))
    assert decode_frame(jpg.tobytes()[:20]) is None
