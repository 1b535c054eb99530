"""Camera files (TOML): load and save `vision.camera.FisheyeCamera` intrinsics.

Format (one ``[camera]`` table; see scenarios/library/cameras/atek_gopro.toml)::

    [camera]
    name = "atek_gopro"            # optional label
    model = "fisheye-odd-poly"     # 003 eq. (13): r_d = k1 theta + k2 theta^3 + ... + k5 theta^9
    width = 1920                   # px
    height = 1080                  # px
    fx = 1110.178                  # px
    fy = 1110.178                  # px
    cx = 959.5                     # px, OpenCV convention (centre of top-left pixel = 0)
    cy = 539.5                     # px
    k = [1.0, 0.08, -0.01, 0.0, 0.0]   # or: opencv_D = [d1, d2, d3, d4]  (k = [1, d1..d4])

Errors name the file and the key (`scenarios.errors.UserError`).
"""
from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path
from typing import Any

from scenarios.errors import UserError
from scenarios.atomic import atomic_write_text
from vision.camera import FisheyeCamera, camera_from_dict, camera_to_dict

__all__ = ["load_camera", "save_camera", "dumps_camera", "payload_mask_from_image", "read_payload_mask"]


def load_camera(path: str | os.PathLike) -> FisheyeCamera:
    """Read a camera file; UserError naming the file (and key) on any problem."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise UserError(f"{p}: camera file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{p}: not valid TOML ({exc})") from None
    except OSError as exc:
        raise UserError(f"{p}: cannot read camera file ({exc.strerror})") from None
    if "camera" not in doc:
        raise UserError(f"{p}: missing table [camera]")
    try:
        return camera_from_dict(doc["camera"], where=f"{p} [camera]")
    except ValueError as exc:
        raise UserError(str(exc)) from None


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"cannot write non-finite number {v} to a camera file")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"unsupported TOML value {v!r}")


def dumps_camera(camera: FisheyeCamera, comment: str = "") -> str:
    """TOML text of a camera file (floats written with repr: round-trips exactly)."""
    lines = [f"# {ln}" for ln in comment.splitlines()] if comment else []
    lines.append("[camera]")
    lines += [f"{k} = {_toml_value(v)}" for k, v in camera_to_dict(camera).items()]
    return "\n".join(lines) + "\n"


def save_camera(camera: FisheyeCamera, path: str | os.PathLike, comment: str = "") -> None:
    """Write a camera file atomically (temporary file + rename)."""
    atomic_write_text(path, dumps_camera(camera, comment))


def payload_mask_from_image(data: bytes, camera: FisheyeCamera | None, where: str,
                            expected: str = "the camera's"):
    """(H, W) bool payload mask (non-zero = payload, ignored by the edge search, 003 §3.1) from an
    encoded image (PNG, JPEG, ...), checked against ``camera``'s size when given; UserError
    ``"{where}: ..."`` for bytes that are not an image or an image of another size."""
    import cv2
    import numpy as np
    m = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE) if data else None
    if m is None:
        raise UserError(f"{where}: not a readable image")
    if camera is not None and m.shape != (camera.height, camera.width):
        raise UserError(f"{where}: {m.shape[1]}x{m.shape[0]} px, expected {expected} "
                        f"{camera.width}x{camera.height}")
    return m > 0


def read_payload_mask(path: str | os.PathLike, camera: FisheyeCamera | None, where: str,
                      expected: str = "the camera's"):
    """:func:`payload_mask_from_image` of an image file (a missing file is "not a readable image")."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        data = b""
    return payload_mask_from_image(data, camera, where, expected)

