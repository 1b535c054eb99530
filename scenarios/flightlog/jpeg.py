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

__all__ = ["decode_frame"]


def decode_frame(data: bytes) -> np.ndarray | None:
    """(H, W, 3) uint8 BGR image (OpenCV's channel order) of an encoded frame, None when the bytes
    are not a decodable image. JPEG: `simplejpeg` (libjpeg-turbo); anything else (PNG, ...):
    ``cv2.imdecode``."""
    import simplejpeg
    buf = bytes(data) if not isinstance(data, bytes) else data
    if simplejpeg.is_jpeg(buf):
        try:
            return simplejpeg.decode_jpeg(buf, colorspace="BGR")
        except ValueError:
            pass        # damaged or unusual (e.g. CMYK) JPEG: OpenCV decides
    import cv2
    return cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_COLOR)
