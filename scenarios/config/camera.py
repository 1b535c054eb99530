"""Camera files: load and save `vision.camera` intrinsics (every camera model).

Three formats, chosen by the file name and its first line:

- ``.toml``: horizon-nav's own format, one ``[camera]`` table (see
  scenarios/library/cameras/atek_gopro.toml and pinhole_25deg.toml; docs/cameras.md)::

    [camera]
    name = "atek_gopro"            # optional label
    model = "fisheye"              # "fisheye" (default when absent), "pinhole" or "equidistant"
    width = 1920                   # px
    height = 1080                  # px
    fx = 1110.178                  # px
    fy = 1110.178                  # px
    cx = 959.5                     # px, OpenCV convention (centre of top-left pixel = 0)
    cy = 539.5                     # px
    k = [1.0, 0.08, -0.01, 0.0, 0.0]   # fisheye: or opencv_D = [d1, d2, d3, d4] (k = [1, d1..d4])
    # pinhole: opencv_D = [k1, k2, p1, p2[, k3[, k4, k5, k6]]]; equidistant: no coefficients

  ``k = [1.0]`` is the equidistant fisheye r = f theta, not a distortion-free pinhole.
- ``.yaml`` / ``.yml``: ROS ``CameraInfo`` as ``camera_calibration`` writes it (image_width,
  image_height, camera_name, camera_matrix {rows, cols, data}, distortion_model plumb_bob |
  rational_polynomial | equidistant, distortion_coefficients, rectification_matrix,
  projection_matrix), or an OpenCV ``cv2.FileStorage`` file (a ``%YAML`` first line or ``!!opencv-matrix`` nodes).
- ``.xml`` (or a YAML file with ``%YAML`` directive or ``!!opencv-matrix`` nodes): OpenCV ``cv2.FileStorage`` as its calibration samples write
  it: camera_matrix, distortion_coefficients, image_width, image_height, and ``fisheye_model: 1``
  (or ``distortion_model: "fisheye"``) for the fisheye model.

Errors name the file and the key (`scenarios.errors.UserError`).
"""
from __future__ import annotations

import math
import os
from scenarios.config.toml_file import parse_toml
from pathlib import Path
from typing import Any

from scenarios.errors import UserError
from scenarios.atomic import atomic_write_text
from vision.camera import Camera, camera_from_dict, camera_to_dict, from_camera_info

__all__ = ["load_camera", "save_camera", "dumps_camera", "payload_mask_from_image", "read_payload_mask"]


def load_camera(path: str | os.PathLike) -> Camera:
    """Read a camera file (TOML, ROS CameraInfo YAML or OpenCV FileStorage YAML/XML); UserError
    naming the file (and key) on any problem."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise UserError(f"{p}: camera file not found") from None
    except OSError as exc:
        raise UserError(f"{p}: cannot read camera file ({exc.strerror})") from None
    suffix = p.suffix.lower()
    if suffix == ".xml" or data.lstrip().startswith(b"%YAML") or b"!!opencv-matrix" in data:
        return _load_opencv(p)
    if suffix in (".yaml", ".yml"):
        return _load_ros(p, data)
    if suffix not in (".toml", ""):
        raise UserError(f"{p}: unknown camera file type {suffix!r}; expected .toml, .yaml/.yml (ROS "
                        f"CameraInfo or OpenCV) or .xml (OpenCV)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UserError(f"{p}: not valid TOML (not UTF-8 text: {exc.reason} at byte {exc.start})") from None
    doc = parse_toml(text, str(p))
    if "camera" not in doc:
        raise UserError(f"{p}: missing table [camera]")
    try:
        return camera_from_dict(doc["camera"], where=f"{p} [camera]")
    except ValueError as exc:
        raise UserError(str(exc)) from None


def _ros_matrix(doc: dict, key: str, shape: tuple[int, int] | None, p: Path) -> list[float]:
    """data of a ROS {rows, cols, data} matrix, checked against rows x cols (and ``shape``)."""
    m = doc.get(key)
    if not isinstance(m, dict) or not isinstance(m.get("data"), list):
        raise UserError(f"{p}: key {key!r} missing or not a {{rows, cols, data}} matrix")
    data = m["data"]
    rows, cols = m.get("rows"), m.get("cols")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in data) or \
            not isinstance(rows, int) or not isinstance(cols, int) or rows * cols != len(data) or \
            (shape is not None and (rows, cols) != shape):
        raise UserError(f"{p}: key {key!r}: rows {rows!r} x cols {cols!r} with {len(data)} numbers in data; "
                        f"expected {'%dx%d' % shape if shape else 'rows x cols'} numbers")
    return [float(v) for v in data]


def _load_ros(p: Path, data: bytes) -> Camera:
    """ROS CameraInfo YAML (camera_calibration's ost.yaml)."""
    import yaml

    try:
        doc = yaml.safe_load(data)
    except yaml.YAMLError as exc:
        raise UserError(f"{p}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise UserError(f"{p}: expected a ROS CameraInfo YAML mapping (image_width, camera_matrix, ...)")
    for key in ("image_width", "image_height"):
        if isinstance(doc.get(key), bool) or not isinstance(doc.get(key), int) or doc[key] <= 0:
            raise UserError(f"{p}: key {key!r} = {doc.get(key)!r}; expected a positive integer")
    model = doc.get("distortion_model")
    info = {"width": doc["image_width"], "height": doc["image_height"], "distortion_model": model,
            "K": _ros_matrix(doc, "camera_matrix", (3, 3), p),
            "D": _ros_matrix(doc, "distortion_coefficients", None, p)}
    if "rectification_matrix" in doc:
        info["R"] = _ros_matrix(doc, "rectification_matrix", (3, 3), p)
    if "projection_matrix" in doc:
        _ros_matrix(doc, "projection_matrix", (3, 4), p)
    name = doc.get("camera_name", "")
    return _checked(p, lambda: from_camera_info(info, name=str(name or "")), {
        "takes": "distortion_coefficients", "is not supported": "distortion_model",
        "R must": "rectification_matrix", "skew": "camera_matrix", "dist =": "distortion_coefficients",
        "k =": "distortion_coefficients", "principal point": "camera_matrix", "fx": "camera_matrix",
        "width": "image_width", "height": "image_height"})


def _checked(p: Path, make, keys: dict[str, str]) -> Camera:
    """make(); a ValueError becomes a UserError naming the file and the file's key that the message
    concerns (the first of ``keys`` found in it)."""
    try:
        return make()
    except ValueError as exc:
        msg = str(exc)
        key = next((v for k, v in keys.items() if k in msg), None)
        raise UserError(f"{p}: " + (f"key {key!r}: " if key else "") + msg) from None


def _load_opencv(p: Path) -> Camera:
    """OpenCV FileStorage (YAML or XML) as the calibration samples write it."""
    import cv2

    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise UserError(f"{p}: not a readable OpenCV FileStorage file ({str(exc).strip().splitlines()[-1]})") from None
    if not fs.isOpened():
        raise UserError(f"{p}: not a readable OpenCV FileStorage file")
    try:
        vals: dict[str, Any] = {}
        for key in ("image_width", "image_height"):
            node = fs.getNode(key)
            v = node.real() if node.isInt() or node.isReal() else math.nan
            if not (v == int(v) if math.isfinite(v) else False) or v <= 0:
                raise UserError(f"{p}: key {key!r} missing or not a positive integer")
            vals[key] = int(v)
        for key in ("camera_matrix", "distortion_coefficients"):
            m = fs.getNode(key).mat() if not fs.getNode(key).empty() else None
            if m is None:
                raise UserError(f"{p}: key {key!r} missing or not an opencv-matrix")
            vals[key] = m
        kind = fs.getNode("distortion_model").string() if fs.getNode("distortion_model").isString() else ""
        fish = fs.getNode("fisheye_model")
        fisheye = kind == "fisheye" or (not fish.empty() and fish.real() != 0)
    finally:
        fs.release()
    if vals["camera_matrix"].shape != (3, 3):
        raise UserError(f"{p}: key 'camera_matrix' has shape {vals['camera_matrix'].shape}; expected 3x3")
    from vision.camera import from_opencv

    return _checked(p, lambda: from_opencv(vals["camera_matrix"], vals["distortion_coefficients"].ravel(),
                                           vals["image_width"], vals["image_height"], name=p.stem,
                                           model="fisheye" if fisheye else "pinhole"),
                    {"distortion coefficients": "distortion_coefficients", "dist =": "distortion_coefficients",
                     "k =": "distortion_coefficients", "skew": "camera_matrix", "principal point": "camera_matrix",
                     "fx": "camera_matrix", "width": "image_width", "height": "image_height"})


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


def dumps_camera(camera: Camera, comment: str = "") -> str:
    """TOML text of a camera file (floats written with repr: round-trips exactly)."""
    lines = [f"# {ln}" for ln in comment.splitlines()] if comment else []
    lines.append("[camera]")
    lines += [f"{k} = {_toml_value(v)}" for k, v in camera_to_dict(camera).items()]
    return "\n".join(lines) + "\n"


def save_camera(camera: Camera, path: str | os.PathLike, comment: str = "") -> None:
    """Write a camera file atomically (temporary file + rename)."""
    atomic_write_text(path, dumps_camera(camera, comment))


def payload_mask_from_image(data: bytes, camera: Camera | None, where: str,
                            expected: str = "the camera's"):
    """(H, W) bool payload mask (non-zero = payload, ignored by the edge search, 003 §3.1) from an
    encoded image (PNG, JPEG, ...), checked against ``camera``'s size when given; UserError
    ``"{where}: ..."`` for bytes that are not an image or an image of another size."""
    import cv2
    import numpy as np
    m = (cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
         if data else None)    # as stored, as the frames are read
    if m is None:
        raise UserError(f"{where}: not a readable image")
    if camera is not None and m.shape != (camera.height, camera.width):
        raise UserError(f"{where}: {m.shape[1]}x{m.shape[0]} px, expected {expected} "
                        f"{camera.width}x{camera.height}")
    return m > 0


def read_payload_mask(path: str | os.PathLike, camera: Camera | None, where: str,
                      expected: str = "the camera's"):
    """:func:`payload_mask_from_image` of an image file (a missing file is "not a readable image")."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        data = b""
    return payload_mask_from_image(data, camera, where, expected)

