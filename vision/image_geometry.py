"""Image geometry of fitted cones and of pixels: the conic of a cone drawn through the distorted
camera (003 figs. 15, 27), the search rows a predicted disc can cross (003 §5), the 003 §3.3
sanity check, and the pixel angle (angle of one pixel along the radius) from a per-camera table."""
from __future__ import annotations

import functools
import math

import numba
import numpy as np

from vision.borders import SearchConfig, search_rows
from vision.camera import Camera, FisheyeCamera, project
from vision.covariance import tangent_basis
from vision.nadir import norm3
from vision.oblate import LimbModel
from vision.ransac import pixel_angle

__all__ = ["conic_polyline", "unit_circle", "gate_search_rows", "in_image", "fast_pixel_angle",
           "max_pixel_angle", "pixel_angle_table", "conic_passes_image"]


def conic_polyline(camera: Camera, e_c: np.ndarray, alpha: float, n: int = 720,
                   model: LimbModel | None = None) -> np.ndarray:
    """Pixels (k, 2) of the cone (e, alpha) projected through the distorted camera model (the
    fitted conic drawn in distorted pixel space, 003 figs. 15, 27); NaN where a ray is beyond the
    lens's range or behind the camera. With ``model`` the cone is taken in its fit frame
    (e_c the fit-frame direction) and mapped back into the camera."""
    e = np.asarray(e_c, float)
    rays = math.cos(alpha) * e + math.sin(alpha) * (unit_circle(n) @ tangent_basis(e).T)
    if model is not None and model.kind != "sphere":
        rays = rays @ model.M_inv.T
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        uv = project(camera, rays)
    return uv


@functools.lru_cache(maxsize=8)
def unit_circle(n: int, endpoint: bool = True) -> np.ndarray:
    """(n, 2) [cos psi, sin psi] at ``np.linspace(0, 2 pi, n, endpoint)``, C-contiguous, read-only."""
    psi = np.linspace(0.0, 2 * math.pi, n, endpoint=endpoint)
    c = np.ascontiguousarray(np.stack([np.cos(psi), np.sin(psi)], axis=1))
    c.flags.writeable = False
    return c


def gate_search_rows(camera: Camera, predicted: np.ndarray, angle: float,
                     search: SearchConfig) -> np.ndarray | None:
    """The rows of ``search``'s raster (003 §5) that can meet a body whose whole disc lies within
    ``angle`` [rad] of the ``predicted`` unit direction (gate + largest apparent radius): those
    between the top and bottom of that cap's image (a disc inside the cap crosses the same raster
    rows as before; the frame border is searched as always). None (the whole raster) when the cap
    reaches beyond the lens's range but not wholly; no rows when it lies wholly beyond it.

    The image of a cap inside the lens's range is bounded by the image of its rim (the projection
    is a diffeomorphism there), sampled at 64 points: between samples the rim bulges by
    <= r (1 - cos(pi / 64)) ~ 1e-3 r, r <= 1000 px, inside the 2 px margin.
    """
    rows = search_rows(camera.height, search.line_spacing_px, search.line_offset_px)
    if rows.size == 0 or not 0.0 < angle < math.pi / 2:
        return None
    off_axis = math.acos(max(-1.0, min(1.0, float(predicted[2]))))
    if off_axis - angle > camera.max_theta:
        return rows[:0]
    if off_axis + angle >= camera.max_theta:
        return None
    v = conic_polyline(camera, predicted, angle, 64)[:, 1]
    return rows[(rows >= v.min() - 2.0) & (rows <= v.max() + 2.0)]


def in_image(camera: Camera, uv: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return (np.isfinite(uv).all(axis=-1) & (uv[..., 0] >= -0.5) & (uv[..., 0] <= camera.width - 0.5)
                & (uv[..., 1] >= -0.5) & (uv[..., 1] <= camera.height - 0.5))


_PIXEL_ANGLE_CACHE: dict = {}


def fast_pixel_angle(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """`vision.ransac.pixel_angle` through a per-camera table over the distorted radius (the exact
    function is evaluated once per camera on 256 radii; linear interpolation between them, as
    ``np.interp`` on the table, `_interp_uniform`). Models without radial symmetry (the pinhole
    with tangential distortion or fx != fy): the exact function."""
    uv = np.asarray(uv, dtype=float)
    if not isinstance(camera, FisheyeCamera):
        return pixel_angle(camera, uv)
    q, pa, _ = pixel_angle_table(camera)
    out = _interp_uniform(np.ascontiguousarray(uv.reshape(-1, 2)), camera.cx, camera.cy, camera.fx, camera.fy,
                          q[-1] / (q.size - 1), pa)
    return out.reshape(uv.shape[:-1])


@numba.njit(cache=True)
def _interp_uniform(uv, cx, cy, fx, fy, dq, tab):  # pragma: no cover - numba
    """``np.interp(r, q, tab)`` of the distorted radii r of pixels uv (n, 2) on the uniform grid
    q_j = j dq (end values beyond it): one pass instead of ~8 array operations per call."""
    n = uv.shape[0]
    out = np.empty(n)
    last = tab.shape[0] - 1
    for i in range(n):
        r = math.hypot((uv[i, 0] - cx) / fx, (uv[i, 1] - cy) / fy)
        x = r / dq
        if not x < last:                  # also NaN pixels: np.interp gives NaN for NaN
            out[i] = tab[last] if x >= last else math.nan
            continue
        j = int(x)
        out[i] = tab[j] + (tab[j + 1] - tab[j]) * (x - j)
    return out


def max_pixel_angle(camera: Camera) -> float:
    """The largest `fast_pixel_angle` in the image (its table's largest entry: interpolation between
    entries cannot exceed it)."""
    return pixel_angle_table(camera)[2]


def pixel_angle_table(camera: Camera):
    """(radii, pixel angles, largest pixel angle) of `fast_pixel_angle`, cached per camera. For
    models other than the fisheye the radii and angles are None and the largest angle is taken
    over a 65x65 grid of the image (pixel edges included)."""
    key = (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, tuple(camera.k)) \
        if isinstance(camera, FisheyeCamera) else camera
    tab = _PIXEL_ANGLE_CACHE.get(key)
    if tab is None and not isinstance(camera, FisheyeCamera):
        gv, gu = np.meshgrid(np.linspace(-0.5, camera.height - 0.5, 65), np.linspace(-0.5, camera.width - 0.5, 65))
        tab = (None, None, float(np.max(pixel_angle(camera, np.stack([gu, gv], axis=-1)))))
        _PIXEL_ANGLE_CACHE[key] = tab
    elif tab is None:
        corners = np.array([[-0.5, -0.5], [camera.width - 0.5, camera.height - 0.5],
                            [-0.5, camera.height - 0.5], [camera.width - 0.5, -0.5]])
        rmax = float(np.max(np.hypot((corners[:, 0] - camera.cx) / camera.fx,
                                     (corners[:, 1] - camera.cy) / camera.fy)))
        rmax = min(rmax, camera.max_radius) if math.isfinite(camera.max_radius) else rmax
        q = np.linspace(0.0, rmax, 256)
        uvq = np.stack([camera.cx + q * camera.fx, np.full_like(q, camera.cy)], axis=-1)
        pa = pixel_angle(camera, uvq)
        tab = (q, pa, float(np.max(pa)))
        _PIXEL_ANGLE_CACHE[key] = tab
    return tab



def conic_passes_image(camera: Camera, e_fit: np.ndarray, alpha: float, model: LimbModel | None,
                        H_inl: np.ndarray) -> bool:
    """003 §3.3 sanity check: does the cone (e_fit, alpha) of the fit frame project into the image?

    First the one cone ray nearest the mean inlier ray (the usual case: the inliers lie on the
    conic, inside the image; one projection), else 90 rays around the whole cone."""
    e = np.asarray(e_fit, dtype=float)
    r = H_inl.sum(axis=0) if H_inl.shape[0] else e
    t = r - (r @ e) * e
    nt = norm3(t)
    if nt > 1e-12:
        p = math.cos(alpha) * e + (math.sin(alpha) / nt) * t
        if model is not None and model.kind != "sphere":
            p = model.M_inv @ p
        u, v = project(camera, p[None, :])[0].tolist()   # NaN (beyond the lens's range) fails
        if -0.5 <= u <= camera.width - 0.5 and -0.5 <= v <= camera.height - 0.5:
            return True
    return bool(np.any(in_image(camera, conic_polyline(camera, e, alpha, 90, model))))
