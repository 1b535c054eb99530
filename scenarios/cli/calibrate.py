"""``horizon-nav calibrate``: camera intrinsics from chessboard images, written as a camera file
(scenarios/config/camera.py).

``--model fisheye`` (default): ``cv2.fisheye.calibrate``; the OpenCV fisheye model
theta_d = theta (1 + d1 theta^2 + ... + d4 theta^8) is 003 eq. (13) with k = [1, d1, .., d4]
(`vision.camera.from_opencv`). ``--model pinhole``: ``cv2.calibrateCamera`` with OpenCV's plumb_bob
distortion [k1, k2, p1, p2, k3], or with ``--rational`` the rational model (8 coefficients), a
`vision.camera.PinholeCamera`. Corners: ``cv2.findChessboardCorners``
refined with ``cv2.cornerSubPix``. The RMS reprojection error over all corners and the error of
each image are reported; images whose board is not found are listed and skipped.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenarios.errors import UserError

NAME = "calibrate"
HELP = "fisheye or pinhole camera calibration from chessboard images -> camera file (TOML)"


def add_arguments(p) -> None:
    p.add_argument("images", nargs="+", metavar="IMAGE", help="chessboard images, all the same size")
    p.add_argument("--board", default="9x6", help="inner corners per row x per column (default 9x6)")
    p.add_argument("--square", type=float, default=0.025, help="square size [m] (default 0.025)")
    p.add_argument("--name", default="", help="camera name written into the file")
    p.add_argument("--model", choices=("fisheye", "pinhole"), default="fisheye",
                   help="camera model: fisheye (OpenCV fisheye / Kannala-Brandt, default) or pinhole "
                        "(OpenCV plumb_bob k1 k2 p1 p2 k3)")
    p.add_argument("--rational", action="store_true",
                   help="pinhole with OpenCV's rational distortion (k1 k2 p1 p2 k3 k4 k5 k6)")
    p.add_argument("-o", "--output", required=True, help="camera file to write (.toml)")


@dataclass
class Calibration:
    """Result of `calibrate_images`: the camera, RMS and per-image reprojection errors [px]."""

    camera: object
    rms_px: float
    per_image_px: dict
    skipped: list


def parse_board(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(text))
    if not m or int(m.group(1)) < 3 or int(m.group(2)) < 3:
        raise UserError(f"--board {text!r}: expected inner corners as COLSxROWS, e.g. 9x6 (each >= 3)")
    return int(m.group(1)), int(m.group(2))


def find_corners(gray: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel inner corners (n, 2) of the chessboard, or None."""
    import cv2

    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, corners = cv2.findChessboardCorners(gray, board, flags=flags)
    if not ok:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    corners = cv2.cornerSubPix(gray, corners.astype(np.float32), (5, 5), (-1, -1), crit)
    return corners.reshape(-1, 2).astype(np.float64)


def calibrate_images(images: dict, board: tuple[int, int], square: float, name: str = "",
                     model: str = "fisheye", rational: bool = False) -> Calibration:
    """Calibrate from ``{label: grey uint8 image}`` (all one size) with the ``model`` ("fisheye" or
    "pinhole"; ``rational``: the pinhole's 8-coefficient distortion). Raises UserError when fewer
    than 3 boards are found or OpenCV cannot converge."""
    if not (math.isfinite(square) and square > 0):
        raise UserError(f"--square {square}: expected the square size in metres (> 0)")
    nx, ny = board
    obj = np.zeros((nx * ny, 3))
    obj[:, :2] = np.mgrid[0:nx, 0:ny].T.reshape(-1, 2) * square
    shape = None
    objp, imgp, labels, skipped = [], [], [], []
    for label, gray in images.items():
        if shape is None:
            shape = gray.shape
        elif gray.shape != shape:
            raise UserError(f"{label}: size {gray.shape[1]}x{gray.shape[0]}, expected "
                            f"{shape[1]}x{shape[0]} like the first image")
        c = find_corners(gray, board)
        if c is None:
            skipped.append(label)
            continue
        objp.append(obj.reshape(1, -1, 3))   # cv2.fisheye wants (1, n, 3) in OpenCV 5
        imgp.append(c.reshape(1, -1, 2))
        labels.append(label)
    if len(labels) < 3:
        raise UserError(f"chessboard {nx}x{ny} found in {len(labels)} of {len(images)} images; "
                        f"need at least 3 (check --board: inner corners, not squares)")
    h, w = shape
    solve = _solve_pinhole if (model == "pinhole" or rational) else _solve_fisheye
    rms, cam, per = solve(objp, imgp, (w, h), name, rational)
    return Calibration(cam, float(rms), dict(zip(labels, per)), skipped)


def _solve_fisheye(objp, imgp, size, name, _rational):
    """cv2.fisheye.calibrate: (RMS, camera, per-image RMS) [px]."""
    import cv2

    from vision.camera import from_opencv

    flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW  # OpenCV 5: fisheye flags live in cv2
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-10)
    try:
        rms, K, D, rvecs, tvecs = cv2.fisheye.calibrate(objp, imgp, size, np.eye(3), np.zeros(4),
                                                        flags=flags, criteria=crit)
    except cv2.error as exc:
        raise UserError(f"cv2.fisheye.calibrate failed ({str(exc).strip().splitlines()[-1]}); "
                        f"add views that cover the image corners") from None
    per = [_rms(cv2.fisheye.projectPoints(o, rv, tv, K, D)[0], ip) for o, ip, rv, tv in zip(objp, imgp, rvecs, tvecs)]
    return rms, from_opencv(K, D.ravel(), size[0], size[1], name=name), per


def _solve_pinhole(objp, imgp, size, name, rational):
    """cv2.calibrateCamera (plumb_bob, or rational with ``rational``): (RMS, camera, per-image RMS)."""
    import cv2

    from vision.camera import from_opencv

    flags = cv2.CALIB_RATIONAL_MODEL if rational else 0
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    objs = [o.reshape(-1, 3).astype(np.float32) for o in objp]
    imgs = [ip.reshape(-1, 2).astype(np.float32) for ip in imgp]
    try:
        rms, K, D, rvecs, tvecs = cv2.calibrateCamera(objs, imgs, size, None, None, flags=flags, criteria=crit)
    except cv2.error as exc:
        raise UserError(f"cv2.calibrateCamera failed ({str(exc).strip().splitlines()[-1]}); "
                        f"add views that cover the image corners") from None
    D = D.ravel()[: 8 if rational else 5]
    per = [_rms(cv2.projectPoints(o, rv, tv, K, D)[0], ip) for o, ip, rv, tv in zip(objs, imgs, rvecs, tvecs)]
    try:
        cam = from_opencv(K, D, size[0], size[1], name=name, model="pinhole")
    except ValueError as exc:
        raise UserError(f"calibrated pinhole model is not usable: {exc}; add views that cover the image "
                        f"corners") from None
    return rms, cam, per


def _rms(proj, ip) -> float:
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - ip.reshape(-1, 2)) ** 2, axis=1))))


def run(args) -> int:
    import cv2

    from scenarios.config.camera import save_camera
    from vision.camera import describe

    board = parse_board(args.board)
    imgs = {}
    for path in args.images:
        p = Path(path)
        if not p.is_file():
            raise UserError(f"{path}: image file not found")
        # as stored, like horizon-nav vision and the replay: an EXIF orientation is not applied
        g = cv2.imdecode(np.fromfile(p, dtype=np.uint8), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
        if g is None:
            raise UserError(f"{path}: not an image OpenCV can decode")
        imgs[str(path)] = g
    out = Path(args.output)
    if out.suffix.lower() != ".toml":
        raise UserError(f"-o {args.output}: expected a .toml camera file")
    cal = calibrate_images(imgs, board, args.square, args.name or out.stem, args.model, args.rational)
    c = cal.camera
    how = "cv2.fisheye" if c.model == "fisheye" else f"cv2.calibrateCamera, {'rational' if args.rational else 'plumb_bob'}"
    comment = (f"calibrated with horizon-nav calibrate ({how}) from {len(cal.per_image_px)} images, "
               f"board {board[0]}x{board[1]}, square {args.square} m\nRMS reprojection error {cal.rms_px:.4f} px")
    save_camera(c, out, comment)
    for lab, e in cal.per_image_px.items():
        print(f"  {lab}: {e:.4f} px")
    for lab in cal.skipped:
        print(f"  {lab}: board not found, skipped")
    coeffs = f"k {list(c.k)}" if c.model == "fisheye" else f"opencv_D {list(c.dist)}"
    print(f"{out}: fx {c.fx:.3f} fy {c.fy:.3f} cx {c.cx:.3f} cy {c.cy:.3f} px, {coeffs}, "
          f"RMS reprojection error {cal.rms_px:.4f} px over {len(cal.per_image_px)} images")
    print(describe(c))
    return 0
