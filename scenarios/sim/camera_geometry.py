"""Per-frame camera truth: mounting, nadir / Sun / Moon vectors, horizon visibility, conic type.

Mounting (003 §7.1: "two cameras on opposite sides of the payload, looking downwards at 20 deg").
For a camera at azimuth ``a`` about x_b (from +y_b towards +z_b) with the radial direction
``r = [0, cos a, sin a]``, depression ``delta`` and roll ``rho``::

    z_c = cos(delta) r - sin(delta) x_b        optical axis: radial, tilted towards the tail
    y_c = -(sin(delta) r + cos(delta) x_b)     image "down" points aft (to the Earth when the nose is up)
    x_c = y_c x z_c                            image right

then rotated by ``rho`` about z_c. The true mount is ``R_bc = exp([psi_c x]) R_bc_nominal`` with the
misalignment ``psi_c`` drawn per axis (003 eq. (50), docs/conventions.md "Rotations"). With the nose near the
zenith during the coast and 20 deg depression, each optical axis points about 20 deg below the local
horizontal; the horizon dips 15 deg at 230 km, so it crosses the image (003 figs. 9, 36).

Horizon truth (003 §2.3-2.6): nadir ``e_c = R_ce (-x_e / |x_e|)`` (eq. (1), (2)); Earth cone
half-angle ``alpha = arcsin((r + d) / (r + H))`` (eq. (5)) with ``r + H = |x_e|``, ``r = |x_e| - h``
(the geocentric radius of the ellipsoid below the camera) and ``d`` the effective atmosphere thickness;
a ray ``p`` sees the Earth when ``p . e_c > cos(alpha) |p|`` (eq. (3)). A grid of pixel rays
(through :func:`vision.camera.unproject`) is tested against the cone: the horizon is visible when the
unmasked grid holds both Earth and space rays; the Earth fraction is the share of Earth rays. The conic
type follows the discriminant ``Delta = sin^2(alpha) - e_z^2`` (eqs. (9)-(11)): hyperbola for
Delta > 0, ellipse otherwise ("" when the horizon is not in the image).

Payload mask: the payload's side wall is the plane through the camera perpendicular to ``r``; a ray
whose body direction makes less than ``mask_deg`` with that plane (``d_b . r < sin(mask_deg)``) sees
the structure, not the scene.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav.rotation import quat_to_matrix, rotvec_to_matrix
from vision.camera import FisheyeCamera, project, unproject


def mount_rotation(azimuth_deg: float, depression_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """Nominal ``R_bc`` (camera -> body) of a side-looking camera (see the module docstring)."""
    a, d, r = np.radians([azimuth_deg, depression_deg, roll_deg])
    radial = np.array([0.0, np.cos(a), np.sin(a)])
    xb = np.array([1.0, 0.0, 0.0])
    z = np.cos(d) * radial - np.sin(d) * xb
    y = -(np.sin(d) * radial + np.cos(d) * xb)
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=-1)
    Rz = np.array([[np.cos(r), -np.sin(r), 0.0], [np.sin(r), np.cos(r), 0.0], [0.0, 0.0, 1.0]])
    return R @ Rz


def radial_of(azimuth_deg: float) -> np.ndarray:
    a = np.radians(azimuth_deg)
    return np.array([0.0, np.cos(a), np.sin(a)])


def grid_rays(camera: FisheyeCamera, step_px: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (G, 3) of a pixel grid every ``step_px`` plus the image border pixels, and a flag
    (G,) that is True for the interior grid points (used for the Earth fraction)."""
    us = np.arange(step_px / 2, camera.width, step_px)
    vs = np.arange(step_px / 2, camera.height, step_px)
    U, V = np.meshgrid(us, vs)
    interior = np.stack([U.ravel(), V.ravel()], axis=-1)
    bu = np.arange(0.0, camera.width, step_px / 2)
    bv = np.arange(0.0, camera.height, step_px / 2)
    w, h = camera.width - 1.0, camera.height - 1.0
    border = np.concatenate([np.stack([bu, np.zeros_like(bu)], -1), np.stack([bu, np.full_like(bu, h)], -1),
                             np.stack([np.zeros_like(bv), bv], -1), np.stack([np.full_like(bv, w), bv], -1)])
    uv = np.concatenate([interior, border])
    rays = unproject(camera, uv)
    flag = np.r_[np.ones(len(interior), bool), np.zeros(len(border), bool)]
    ok = np.all(np.isfinite(rays), axis=-1)
    return rays[ok], flag[ok]


@dataclass
class CameraTruth:
    """Truth of one camera at its frame times ``t`` [s after lift-off] (true capture times).

    ``nadir_c``, ``sun_c``, ``moon_c`` (N, 3) unit vectors in c; ``alpha`` (N,) Earth-cone half-angle
    [rad]; ``horizon_visible``, ``sun_in_view``, ``moon_in_view`` (N,) bool; ``conic_type`` (N,) str;
    ``earth_fraction`` (N,); ``sun_uv`` (N, 2) pixel of the Sun (NaN outside the lens range).
    """
    t: np.ndarray
    nadir_c: np.ndarray
    sun_c: np.ndarray
    moon_c: np.ndarray
    alpha: np.ndarray
    horizon_visible: np.ndarray
    conic_type: np.ndarray
    sun_in_view: np.ndarray
    moon_in_view: np.ndarray
    earth_fraction: np.ndarray
    sun_uv: np.ndarray


def _in_image(camera: FisheyeCamera, uv: np.ndarray) -> np.ndarray:
    u, v = uv[..., 0], uv[..., 1]
    with np.errstate(invalid="ignore"):
        return (np.isfinite(u) & np.isfinite(v) & (u >= -0.5) & (u <= camera.width - 0.5)
                & (v >= -0.5) & (v <= camera.height - 0.5))


def camera_truth(camera: FisheyeCamera, R_bc: np.ndarray, t: np.ndarray, x_e: np.ndarray, h: np.ndarray,
                 q_eb: np.ndarray, sun_dir_e: np.ndarray, moon_dir_e: np.ndarray, *,
                 radial_b: np.ndarray, atmosphere_m: float = 0.0, mask_deg: float = 0.0,
                 step_px: float = 20.0) -> CameraTruth:
    """Per-frame truth for one camera (all inputs at the frame times; see the module docstring).

    ``R_bc`` true mount (3, 3); ``x_e`` (N, 3); ``h`` (N,) geodetic height [m]; ``q_eb`` (N, 4);
    ``sun_dir_e``, ``moon_dir_e`` (N, 3) unit vectors from the camera; ``radial_b`` the outward
    normal of the payload wall at the camera (for the mask).
    """
    R_eb = quat_to_matrix(q_eb)
    R_ce = np.swapaxes(R_eb @ R_bc, -1, -2)  # (N, 3, 3)
    r = np.linalg.norm(x_e, axis=-1)
    nadir_c = np.einsum("nij,nj->ni", R_ce, -x_e / r[:, None])
    sun_c = np.einsum("nij,nj->ni", R_ce, sun_dir_e)
    moon_c = np.einsum("nij,nj->ni", R_ce, moon_dir_e)
    alpha = np.arcsin(np.clip((r - h + atmosphere_m) / r, -1.0, 1.0))
    rays, interior = grid_rays(camera, step_px)
    rays_b = rays @ R_bc.T
    visible = rays_b @ radial_b >= np.sin(np.radians(mask_deg))
    rays, interior = rays[visible], interior[visible]
    earth = (nadir_c @ rays.T) > np.cos(alpha)[:, None]  # (N, G), 003 eq. (3)
    any_earth, any_space = earth.any(axis=1), (~earth).any(axis=1)
    horizon = any_earth & any_space
    n_int = max(int(interior.sum()), 1)
    frac = earth[:, interior].sum(axis=1) / n_int
    delta = np.sin(alpha) ** 2 - nadir_c[:, 2] ** 2  # 003 eq. (9)
    conic = np.where(horizon, np.where(delta > 0, "hyperbola", "ellipse"), "")

    def in_view(d_c):
        uv = project(camera, d_c)
        d_b = d_c @ R_bc.T
        return _in_image(camera, uv) & (d_b @ radial_b >= np.sin(np.radians(mask_deg))), uv

    sun_in, sun_uv = in_view(sun_c)
    moon_in, _ = in_view(moon_c)
    return CameraTruth(np.asarray(t, float), nadir_c, sun_c, moon_c, alpha, horizon, conic.astype(str),
                       sun_in, moon_in, frac, sun_uv)


def true_mount(azimuth_deg: float, depression_deg: float, roll_deg: float, psi_c: np.ndarray) -> np.ndarray:
    """``R_bc_true = exp([psi_c x]) R_bc_nominal`` (003 eq. (50))."""
    return rotvec_to_matrix(psi_c) @ mount_rotation(azimuth_deg, depression_deg, roll_deg)
