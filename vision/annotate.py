"""Annotated frame of the vision front end (like 003 figs. 10-15, 24-27): followed borders,
candidates, inliers of the winning candidate, the fitted conic drawn in *distorted* pixel space
(the cone's rays projected through the camera model, `vision.frontend.conic_polyline`) and the
image point of each vector. Pure: returns a new image array, draws nothing in place.

Colours (BGR, the frame is drawn on as given): followed borders grey, candidates yellow (Earth)
or cyan (Sun/Moon), winner's inliers green / outliers red, fitted conic magenta (Earth) or
orange (Sun/Moon), vector image point white cross with the target's name.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from vision.camera import Camera, project
from vision.image_geometry import conic_polyline
from vision.results import FrameResult

__all__ = ["annotate_frame"]

_CAND = {"earth": (0, 220, 255), "sun": (255, 255, 0), "moon": (255, 200, 120)}
_CONIC = {"earth": (255, 0, 255), "sun": (0, 140, 255), "moon": (0, 200, 255)}


def _polyline(img: np.ndarray, uv: np.ndarray, colour, thickness: int) -> None:
    """Draw the finite runs of uv (k, 2) as polylines (NaN breaks the line)."""
    ok = np.all(np.isfinite(uv), axis=1) & (np.abs(uv) < 1e5).all(axis=1)
    idx = np.flatnonzero(ok)
    if idx.size < 2:
        return
    breaks = np.flatnonzero(np.diff(idx) > 1) + 1
    for run in np.split(idx, breaks):
        if run.size >= 2:
            pts = np.round(uv[run] * 16).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(img, [pts], False, colour, thickness, cv2.LINE_AA, shift=4)


def _dots(img: np.ndarray, uv: np.ndarray, colour, radius: int = 0) -> None:
    """Colour the pixels at uv (and their (2 radius + 1)^2 neighbourhood)."""
    if uv.size == 0:
        return
    u0 = np.rint(uv[:, 0]).astype(np.int64)
    v0 = np.rint(uv[:, 1]).astype(np.int64)
    for du in range(-radius, radius + 1):
        for dv in range(-radius, radius + 1):
            iu = np.clip(u0 + du, 0, img.shape[1] - 1)
            iv = np.clip(v0 + dv, 0, img.shape[0] - 1)
            img[iv, iu] = colour


def annotate_frame(image: np.ndarray, camera: Camera, result: FrameResult,
                   show_borders: bool = True) -> np.ndarray:
    """Return a BGR copy of ``image`` with the front end's work drawn on it (module docstring).

    ``image``: the frame given to `vision.frontend.process_frame` ((H, W, 3) or (H, W) uint8).
    """
    a = np.asarray(image)
    if a.dtype != np.uint8 or a.ndim not in (2, 3):
        raise ValueError(f"annotate_frame: image {a.dtype} {a.shape}; expected a uint8 frame")
    out = cv2.cvtColor(a, cv2.COLOR_GRAY2BGR) if a.ndim == 2 else a[..., :3].copy()
    if out.ndim == 3 and out.shape[2] == 1:
        out = cv2.cvtColor(out, cv2.COLOR_GRAY2BGR)
    thick = max(1, int(round(out.shape[1] / 960)))
    for name, tr in result.targets.items():
        det = tr.detection
        if det is None:
            continue
        if show_borders and det.borders is not None and len(det.borders):
            _dots(out, np.asarray(det.borders.points, dtype=float), (128, 128, 128))
        for c in det.candidates:
            _dots(out, c.points, _CAND.get(name, (255, 255, 255)))
        if tr.points is not None and tr.inlier_mask is not None:
            _dots(out, tr.points[~tr.inlier_mask], (0, 0, 255), thick)
            _dots(out, tr.points[tr.inlier_mask], (0, 255, 0), thick)
        rec = tr.record
        if rec is None:
            continue
        alpha_c = rec.alpha
        if name == "earth" and tr.points is not None:
            # the cone actually fitted (model frame) is drawn through the camera model; for the
            # ellipsoid model draw the camera-frame cone through the inliers (median angle)
            from vision.camera import unproject

            rays = unproject(camera, tr.points[tr.inlier_mask])
            alpha_c = float(np.median(np.arccos(np.clip(rays @ rec.e_c, -1.0, 1.0))))
        _polyline(out, conic_polyline(camera, rec.e_c, alpha_c, 1440), _CONIC.get(name, (255, 255, 255)), thick)
        with np.errstate(invalid="ignore", divide="ignore"):
            uv = project(camera, rec.e_c)
        label = f"{name} {math.degrees(math.sqrt(rec.P_overbound[0, 0])):.2f} deg 1s"
        if np.all(np.isfinite(uv)) and 0 <= uv[0] < out.shape[1] and 0 <= uv[1] < out.shape[0]:
            p = (int(round(uv[0])), int(round(uv[1])))
            cv2.drawMarker(out, p, (255, 255, 255), cv2.MARKER_CROSS, 12 * thick, thick)
            cv2.putText(out, label, (p[0] + 8, p[1] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5 * thick,
                        (255, 255, 255), thick, cv2.LINE_AA)
    y = 20 * thick
    for name, why in result.reasons.items():
        cv2.putText(out, f"{name}: {why}"[:140], (10, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * thick,
                    (255, 255, 255), thick, cv2.LINE_AA)
        y += 18 * thick
    return out
