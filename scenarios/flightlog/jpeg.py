"""Decoding the camera frames of a log: JPEG through libjpeg-turbo (`simplejpeg`), other formats
through OpenCV.

Why not ``cv2.imdecode`` for everything: on the 1920x1080 frames of the logs,
``simplejpeg.decode_jpeg`` decodes in less than half of OpenCV's ``imdecode`` time with
bit-identical pixels (both are libjpeg-turbo with the accurate integer DCT and fancy upsampling;
checked in tests/test_jpeg.py), and decoding is the largest single cost of the replay's vision
stage (docs/performance.md).
"""
from __future__ import annotations

import numpy as np

__all__ = ["decode_frame", "decode_image", "SENSOR_BITS", "to_8bit"]


def decode_frame(data: bytes) -> np.ndarray | None:
    """(H, W, 3) uint8 BGR image (OpenCV's channel order) of an encoded frame, None when the bytes
    are not a decodable image. JPEG: `simplejpeg` (libjpeg-turbo); anything else (PNG, ...):
    ``cv2.imdecode``. Neither applies an EXIF orientation (the pixels as the sensor read them)."""
    import simplejpeg
    buf = bytes(data) if not isinstance(data, bytes) else data
    if simplejpeg.is_jpeg(buf):
        try:
            return simplejpeg.decode_jpeg(buf, colorspace="BGR")
        except ValueError:
            pass        # damaged or unusual (e.g. CMYK) JPEG: OpenCV decides
    import cv2
    return cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)


#: bit depths of sensor data in a 16-bit container, tried in turn (`to_8bit`)
SENSOR_BITS = (10, 12, 14, 16)


def to_8bit(img: np.ndarray, what: str, bits: int | None = None) -> tuple[np.ndarray, int]:
    """(8-bit image, its source's significant bits) of a decoded frame. ``uint8`` passes as it is;
    ``uint16`` (PNG/TIFF of a scientific camera, often 10-14-bit data in a 16-bit container) is
    scaled by ``bits``, ``round(v 255 / (2^bits - 1))``, keeping its tone curve (the front end
    expects frames as cameras encode them). Taking the top byte instead (``v >> 8``) leaves 12-bit
    data at 0-15, a black frame. ``bits`` None: the smallest of `SENSOR_BITS` that holds the
    frame's largest value (a dark frame of a 12-bit camera may then be read as 10-bit data: give
    the camera's depth to scale a sequence alike). ValueError naming ``what`` for other pixel
    types, and for a value that ``bits`` does not hold.

    Examples
    --------
    >>> to_8bit(np.array([[0, 4095]], np.uint16), "f")
    (array([[  0, 255]], dtype=uint8), 12)
    >>> to_8bit(np.array([[0, 1023]], np.uint16), "f", bits=12)
    (array([[ 0, 64]], dtype=uint8), 12)
    """
    if img.dtype == np.uint8:
        return img, 8
    if img.dtype != np.uint16:
        raise ValueError(f"{what}: pixel type {img.dtype}, expected 8- or 16-bit unsigned integers")
    top = int(img.max()) if img.size else 0
    if bits is None:
        bits = next(b for b in SENSOR_BITS if top < 2 ** b)
    elif top >= 2 ** bits:
        raise ValueError(f"{what}: pixel value {top} does not fit the {bits}-bit depth given for the "
                         f"16-bit frames (expected 0..{2 ** bits - 1})")
    out = np.rint(img.astype(np.float32) * np.float32(255.0 / (2 ** bits - 1))).astype(np.uint8)
    return out, bits


def decode_image(data: bytes, what: str, bits: int | None = None) -> tuple[np.ndarray | None, int]:
    """(8-bit frame, its source's significant bits) of an image file's bytes, (None, 0) when they
    are not a decodable image: JPEG as `decode_frame`; anything else (PNG, TIFF, ...) as stored,
    16-bit data scaled by `to_8bit` (``bits``: their depth, None to take it from the frame), an
    alpha channel dropped. Pixels as the sensor gave them:
    an EXIF orientation is not applied (the camera file describes the sensor's rows)."""
    import simplejpeg
    buf = bytes(data) if not isinstance(data, bytes) else data
    if simplejpeg.is_jpeg(buf):
        img = decode_frame(buf)
        return img, (8 if img is not None else 0)
    import cv2
    img = cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None, 0
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    return to_8bit(img, what, bits)
