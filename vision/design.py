"""Design analyses of 003: conic visibility (§2.7, figs. 6-7), the spherical-Earth error (§2.8,
fig. 8) and the roll/pitch sensitivity of the horizon measurement (§4, figs. 19-22).

Pure computation (arrays in, arrays out); the plots and CSV files are written by
``scenarios/cli/analyze.py``.

Visibility of the horizon conic (003 §2.7)
------------------------------------------
Circular field of view of full angle gamma; optical axis at angle phi from the nadir e; Earth cone
half-angle alpha (eq. (5)). The projected horizon is an ellipse iff beta = 90 deg - phi > alpha
(eqs. (9)-(11), Table 1: beta = arcsin(e_z) is the nadir's elevation above the image plane), i.e.
iff phi < 90 deg - alpha, and a hyperbola iff phi > 90 deg - alpha. The limb is the circle of
angular radius alpha about e, whose closest point to the axis is |phi - alpha| away, so the
horizon is in view iff |phi - alpha| < gamma/2. Choosing the best phi:

- ellipse: phi < 90 deg - alpha and |phi - alpha| < gamma/2. If alpha < 45 deg, phi = alpha
  works for any gamma; otherwise the best is phi -> 90 deg - alpha, giving
  2 alpha - 90 deg < gamma/2:  **an ellipse can be seen iff gamma > 4 alpha - pi**.
- hyperbola: phi > 90 deg - alpha; if alpha > 45 deg phi = alpha works; otherwise phi ->
  90 deg - alpha gives 90 deg - 2 alpha < gamma/2:  **a hyperbola can be seen iff
  gamma > pi - 4 alpha**.
- the full Earth disc (limb circle inside the FOV): phi + alpha < gamma/2 with phi >= 0:
  **gamma > 2 alpha** (003 §2.7 states this one as we do).

003 §2.7's text swaps the first two ("elliptic ... if gamma > pi - 4 alpha, hyperbolic ... if
gamma > -pi + 4 alpha"). The derivation above is the right one: at low heights alpha -> 90 deg,
where 4 alpha - pi -> pi, so only hyperbolae are visible with any real lens, and at large heights
alpha -> 0, where pi - 4 alpha -> pi, so only ellipses are visible; this also matches 003's own
conclusion that for ATEK (238 km, 94.4 deg) "a focus on hyperbolae would have been sufficient"
(alpha(238 km) = 74.4 deg, 4 alpha - pi = 117.8 deg > 94.4 deg: no ellipse). At every height at
least one of the two is visible (the two thresholds are negatives of each other).

Spherical-Earth error (003 §2.8)
--------------------------------
The direction to the Earth's centre differs from the ellipsoid normal (the direction the
horizon of the locally osculating sphere gives, 003 §2.8) by the angle between the geocentric
and the geodetic vertical, about the East axis: geodetic minus geocentric latitude of the
point, computed from `nav.earth.geodetic_to_ecef`. At h = 0, tan(lat_c) = (1 - e^2) tan(lat),
maximum 0.1924 deg at 45 deg latitude ("about 0.19 deg", 003 fig. 8).

Roll/pitch sensitivity (003 §4)
-------------------------------
Setup of 003 §4: "the vehicle is oriented horizontally and the camera is looking forward in a
horizontal direction", horizon noise R = (1 px)^2, L = 300 px (eq. (36)), d = 0, H = 200 km,
FOV 94.4 deg, "resolution 1080 px". The vehicle is a sounding rocket (docs/conventions.md: body x along
the longitudinal axis, the roll axis) lying horizontally with its nose north; its cameras look out
sideways through the payload skin (ATEK: "on opposite sides of the payload"), so the camera that
looks horizontally forward *for the camera* looks east, perpendicular to the roll axis
(``mounting="side"``, the default; camera z = east, x = south, y = down). Then

- roll (about the longitudinal axis, north: *normal* to the line of sight) moves the nadir towards
  or away from the viewing direction: the horizon shifts up or down in the image;
- pitch (about the lateral axis along the line of sight, east) tilts the horizon in the image;
- yaw (about down, the nadir itself) is unobservable.

A small attitude error psi (NED) rotates the nadir d = [0, 0, 1] by psi x d = [psi_E, -psi_N, 0],
so sigma_roll = sqrt(P_EE) and sigma_pitch = sqrt(P_NN) of the nadir covariance rotated to NED.
``mounting="forward"`` puts the camera on the roll axis instead (an aircraft-like vehicle: camera
z = north, x = east); roll and pitch then exchange their roles (roll tilts, pitch shifts).

Camera model: a *pinhole* (003 §4 evaluates eq. (33), derived for undistorted z = f image-plane
points) with a square N x N sensor (N = 1080) whose FOV spans the N px: f = (N/2) / tan(FOV/2).
fig. 21's "vertical image resolution" suggests N is the vertical size; ``aspect`` = width/height
widens the sensor. The horizon points are the exact projected hyperbola sampled every ``step_px``
along the curve inside the sensor, ordered; the covariance is 003 eq. (33) with eq. (34)-(35)
noise. Three forms:

- ``form="003"`` (default): literally 003 eqs. (22)-(24), (32)-(33): rows p_c = [x_i, y_i, f] in
  pixels, y_j = cos(alpha) |p_j|, g_j = cos(alpha) p_xy/|p| - e_xy;
- ``form="linear"``: the same linear estimator on unit rays (`vision.covariance`, rows
  p/|p|: a re-weighting of the rows by 1/|p|);
- ``form="constrained"``: the unit-norm fit that `vision.nadir` uses by default.

What this reproduces (``horizon-nav analyze sensitivity``), H = 200 km, 1080 px, R = 1 px^2,
L = 300 px, form "003", side mounting: at FOV 94.4 deg, 3 sigma roll 0.958 deg and pitch
0.237 deg. Versus FOV (fig. 20) roll has a clear minimum, at 110.5 deg for the square sensor
(116 deg for a 1920 x 1080 sensor with the FOV across the 1920 px, 128 deg with the FOV across
the diagonal, 118.5 deg with L = 100 px; 003: "about 118 deg"), while pitch changes by only 3 %
from 30 to 170 deg ("the pitch angle is not affected by the FOV"). Why: a pitch rotates the image
about the principal point, i.e. changes the *slope* of the horizon in px per px, which the noisy
pixels determine independently of the focal length; a roll moves the horizon up or down by
f * droll px, and eq. (24)'s unconstrained linear fit cannot separate that shift from a change
of the cone's scale on a nearly straight arc (narrow FOV: error grows) while 1 px means more angle
at wide FOV (error grows again), hence the optimum. The unit-norm fit that `vision.nadir` uses
("constrained") does not have the coupling: its roll error is 0.21 deg (3 sigma) at 94.4 deg and
grows monotonically with the FOV. Height (fig. 19): from 50 to 500 km roll falls by ~10 % and
pitch by a few % ("only a minor influence"). Resolution (fig. 21): both fall roughly as 1/N.
Atmosphere (fig. 22): < 3 % change for d = 0..100 km (the horizon dip changes from 14.2 to
10.0 deg; the residual dependence is that geometry, not the scale).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from nav import earth
from vision.camera import Camera, FisheyeCamera, from_fov, project, unproject_jacobian
from vision.covariance import ar1_toeplitz_apply, direction_covariance
from vision.error_model import camera_keep, trace_limb

__all__ = [
    "visibility_thresholds",
    "visibility_map",
    "earth_alpha",
    "spherical_earth_error",
    "SensitivityCase",
    "PinholeCamera",
    "horizon_points",
    "covariance_003",
    "roll_pitch_sigma",
    "sensitivity_sweep",
    "SENSITIVITY_PARAMS",
    "R_NC_MOUNTING",
]

#: camera frame -> NED on a horizontal vehicle with its nose (body x, the roll axis) north; columns
#: are the camera axes in NED. "side": looking east, perpendicular to the roll axis (a sounding
#: rocket's side-looking cameras, 003 §4 and ATEK; x right = south, y = down, z = east).
#: "forward": looking north along the roll axis (x right = east, y = down, z = north).
R_NC_MOUNTING = {
    "side": np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]),
    "forward": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
}


def earth_alpha(height, atmosphere=0.0, radius: float = earth.R_MEAN) -> np.ndarray:
    """Cone half-angle alpha = arcsin((r + d)/(r + H)) [rad], 003 eq. (5), vectorised."""
    h = np.asarray(height, dtype=float)
    d = np.asarray(atmosphere, dtype=float)
    s = (radius + d) / (radius + h)
    if np.any(~(s > 0.0) | ~(s <= 1.0)):
        raise ValueError(f"earth_alpha: need 0 <= d <= H (atmosphere below the camera); got "
                         f"H = {height!r} m, d = {atmosphere!r} m")
    return np.arcsin(s)


def visibility_thresholds(alpha) -> dict[str, np.ndarray]:
    """Smallest circular FOV gamma [rad] that can show each horizon kind (see module docstring).

    Returns ``{"full": 2 alpha, "ellipse": max(0, 4 alpha - pi), "hyperbola": max(0, pi - 4 alpha)}``;
    the kind is visible iff gamma exceeds the threshold.
    """
    a = np.asarray(alpha, dtype=float)
    return {"full": 2.0 * a, "ellipse": np.maximum(0.0, 4.0 * a - math.pi),
            "hyperbola": np.maximum(0.0, math.pi - 4.0 * a)}


def visibility_map(heights, fovs, atmosphere: float = 0.0,
                   radius: float = earth.R_MEAN) -> dict[str, np.ndarray]:
    """Boolean maps (len(heights), len(fovs)) of "ellipse", "hyperbola", "full" visibility.

    heights [m], fovs [rad] (circular full angle). 003 figs. 6-7.
    """
    alpha = earth_alpha(np.asarray(heights, dtype=float), atmosphere, radius)
    thr = visibility_thresholds(alpha)
    g = np.asarray(fovs, dtype=float)[None, :]
    return {k: g > v[:, None] for k, v in thr.items()}


def spherical_earth_error(lat, height=0.0) -> np.ndarray:
    """Angle between the ellipsoid normal and the direction to the Earth's centre [rad]
    (003 §2.8, fig. 8): geodetic minus geocentric latitude at (lat [rad], height [m]), about East.
    Positive in the northern hemisphere."""
    lat = np.asarray(lat, dtype=float)
    x = earth.geodetic_to_ecef(lat, np.zeros_like(lat), np.broadcast_to(height, lat.shape))
    lat_c = np.arctan2(x[..., 2], np.hypot(x[..., 0], x[..., 1]))
    return lat - lat_c


# ----------------------------------------------------------------------------------------------
# sensitivity


@dataclass(frozen=True)
class PinholeCamera:
    """Ideal pinhole: u = cx + f x/z, v = cy + f y/z (z > 0), width x height px."""

    width: int
    height: int
    f: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, resolution: int, fov_deg: float, aspect: float = 1.0,
                 fov_axis: str = "vertical") -> "PinholeCamera":
        """Sensor round(aspect * resolution) x resolution px; the FOV spans the vertical side
        (``fov_axis="vertical"``, the ``resolution`` px) or the horizontal one."""
        if not 0.0 < fov_deg < 180.0:
            raise ValueError(f"fov_deg = {fov_deg!r}; a pinhole needs 0 < FOV < 180 deg")
        if int(resolution) != resolution or resolution < 2:
            raise ValueError(f"resolution = {resolution!r}; expected an integer >= 2 [px]")
        if not aspect > 0:
            raise ValueError(f"aspect = {aspect!r}; expected width/height > 0")
        w = int(round(aspect * resolution))
        span = {"vertical": resolution, "horizontal": w}.get(fov_axis)
        if span is None:
            raise ValueError(f"fov_axis = {fov_axis!r}; expected 'vertical' or 'horizontal'")
        f = (span / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
        return cls(w, int(resolution), f, (w - 1) / 2.0, (resolution - 1) / 2.0)

    def project(self, rays: np.ndarray) -> np.ndarray:
        r = np.asarray(rays, dtype=float)
        z = r[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.cx + self.f * r[..., 0] / z, self.cy + self.f * r[..., 1] / z], -1)
        uv[z <= 1e-12] = np.nan
        return uv

    def keep(self, uv: np.ndarray) -> np.ndarray:
        u, v = uv[:, 0], uv[:, 1]
        with np.errstate(invalid="ignore"):
            return (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)


SENSITIVITY_PARAMS = ("height", "fov", "resolution", "atmosphere")


@dataclass(frozen=True)
class SensitivityCase:
    """One evaluation of 003 §4 (defaults: 003 §4's baseline).

    height [m], fov_deg [deg] (spanning ``resolution`` px), resolution [px], atmosphere d [m],
    R_px2 [px^2], L_px [px], aspect = width/height of the pinhole sensor, fov_axis = the side
    the FOV spans ("vertical": the ``resolution`` px; "horizontal": the width), step_px [px] spacing of
    the horizon samples, form ("003", "linear" or "constrained"), radius [m] of the sphere.
    ``camera``: a camera model (fisheye or camera-file pinhole) to use instead of the ideal pinhole
    (then fov_deg is its horizontal FOV
    and resolution its height; both rescale it; form must be "linear" or "constrained").
    ``mounting``: "side" (camera perpendicular to the roll axis, 003 §4 / ATEK) or "forward"
    (camera along the roll axis); see the module docstring.
    """

    height: float = 200e3
    fov_deg: float = 94.4
    resolution: int = 1080
    atmosphere: float = 0.0
    R_px2: float = 1.0
    L_px: float = 300.0
    aspect: float = 1.0
    fov_axis: str = "vertical"
    step_px: float = 1.0
    form: str = "003"
    radius: float = earth.R_MEAN
    camera: Camera | None = None
    mounting: str = "side"

    def __post_init__(self):
        if self.mounting not in R_NC_MOUNTING:
            raise ValueError(f"mounting = {self.mounting!r}; expected one of {sorted(R_NC_MOUNTING)}")


def _camera_for(case: SensitivityCase) -> Camera:
    """``case.camera`` rescaled to ``case.resolution`` rows and ``case.fov_deg`` horizontally: a
    fisheye through `from_fov` with its distortion shape; a camera-file pinhole (`vision.pinhole`)
    with its distortion coefficients, the pixel grid scaled and the focal length set by
    tan(FOV/2) as for an undistorted pinhole."""
    cam = case.camera
    s = case.resolution / cam.height
    w = int(round(cam.width * s))
    if isinstance(cam, FisheyeCamera):
        return from_fov(w, int(case.resolution), case.fov_deg, k_shape=cam.k, axis="horizontal",
                        name=cam.name)
    f = (w / 2.0) / math.tan(math.radians(case.fov_deg) / 2.0)
    return type(cam)(w, int(case.resolution), f, f * cam.fy / cam.fx, (cam.cx + 0.5) * s - 0.5,
                     (cam.cy + 0.5) * s - 0.5, cam.dist, name=cam.name)


def horizon_points(case: SensitivityCase, e_c: np.ndarray | None = None):
    """Horizon pixels of the case, ordered, ``step_px`` apart, and what is needed downstream.

    Returns ``(uv (m, 2), camera, alpha)``; camera is a `PinholeCamera` or `FisheyeCamera`.
    """
    e = np.array([0.0, 1.0, 0.0]) if e_c is None else np.asarray(e_c, dtype=float)
    alpha = float(earth_alpha(case.height, case.atmosphere, case.radius))
    if case.camera is None:
        cam = PinholeCamera.from_fov(case.resolution, case.fov_deg, case.aspect, case.fov_axis)
        arcs = trace_limb(e, alpha, cam.project, cam.keep, case.step_px)
    else:
        cam = _camera_for(case)
        arcs = trace_limb(e, alpha, lambda r: project(cam, r), camera_keep(cam, None), case.step_px)
    uv = arcs[0][0] if arcs else np.zeros((0, 2))
    return uv, cam, alpha


def covariance_003(uv: np.ndarray, f: float, cx: float, cy: float, e_c: np.ndarray, alpha: float,
                   R: float, L: float) -> np.ndarray:
    """003 eq. (33) as written, for pinhole pixels: covariance of e^ of eq. (24) (3x3).

    H rows p_j = [u_j - cx, v_j - cy, f] (eq. (22), pixels), g_j = cos(alpha) p_xy/|p| - e_xy
    (eq. (32)), R_i of eqs. (34)-(35) applied in O(m) (`vision.covariance.ar1_toeplitz_apply`):
    P = N^-1 (H^T G R_i G^T H) N^-1, N = H^T H.
    """
    p = np.column_stack([uv[:, 0] - cx, uv[:, 1] - cy, np.full(len(uv), f)])
    norm = np.linalg.norm(p, axis=1)
    e = np.asarray(e_c, dtype=float)
    g = math.cos(alpha) * p[:, :2] / norm[:, None] - e[None, :2]
    AB = np.concatenate([g[:, 0:1] * p, g[:, 1:2] * p], axis=1)
    TAB = ar1_toeplitz_apply(AB, 1.0 - 1.0 / L)
    S = R * (AB[:, :3].T @ TAB[:, :3] + AB[:, 3:].T @ TAB[:, 3:])
    Ni = np.linalg.inv(p.T @ p)
    P = Ni @ (0.5 * (S + S.T)) @ Ni
    return 0.5 * (P + P.T)


def roll_pitch_sigma(case: SensitivityCase) -> tuple[float, float, int]:
    """(sigma_roll, sigma_pitch [rad], m pixels) of 003 §4 for one case (1 sigma).

    NaN, NaN, m when fewer than 10 horizon pixels are in view (e.g. FOV/2 below the horizon dip).
    """
    if case.form not in ("003", "linear", "constrained"):
        raise ValueError(f"form = {case.form!r}; expected '003', 'linear' or 'constrained'")
    e = np.array([0.0, 1.0, 0.0])
    uv, cam, alpha = horizon_points(case, e)
    m = len(uv)
    if m < 10:
        return math.nan, math.nan, m
    if isinstance(cam, PinholeCamera):
        if case.form == "003":
            P = covariance_003(uv, cam.f, cam.cx, cam.cy, e, alpha, case.R_px2, case.L_px)
        else:
            p = np.column_stack([(uv[:, 0] - cam.cx) / cam.f, (uv[:, 1] - cam.cy) / cam.f,
                                 np.ones(m)])
            n = np.linalg.norm(p, axis=1)
            h = p / n[:, None]
            # d(p/|p|)/d(u, v) = (I - h h^T)/|p| d p/d(u, v), d p/d(u, v) = [[1,0],[0,1],[0,0]]/f
            J = (np.eye(3)[None] - h[:, :, None] * h[:, None, :])[:, :, :2] / (n * cam.f)[:, None, None]
            P = direction_covariance(h, J, e, case.R_px2, case.L_px, method=case.form).P_c
    else:
        if case.form == "003":
            raise ValueError("form '003' (eq. (22)-(24) on z = f image points) needs the ideal pinhole "
                             "camera; with a camera file use form 'linear' or 'constrained'")
        rays, J = unproject_jacobian(cam, uv)
        P = direction_covariance(rays, J, e, case.R_px2, case.L_px, method=case.form).P_c
    R_nc = R_NC_MOUNTING[case.mounting]
    P_ned = R_nc @ P @ R_nc.T
    return math.sqrt(P_ned[1, 1]), math.sqrt(P_ned[0, 0]), m


def sensitivity_sweep(param: str, values, base: SensitivityCase = SensitivityCase()) -> dict[str, np.ndarray]:
    """Roll/pitch 1-sigma [rad] over ``values`` of one parameter (003 figs. 19-22).

    param: "height" [m], "fov" [deg], "resolution" [px], "atmosphere" [m]. Returns arrays
    ``value``, ``sigma_roll``, ``sigma_pitch``, ``pixels``.
    """
    field = {"height": "height", "fov": "fov_deg", "resolution": "resolution",
             "atmosphere": "atmosphere"}.get(param)
    if field is None:
        raise ValueError(f"param = {param!r}; expected one of {SENSITIVITY_PARAMS}")
    vals = np.asarray(values, dtype=float)
    out = np.empty((len(vals), 3))
    for i, v in enumerate(vals):  # one covariance per design point (each is O(m) vectorised)
        val = int(round(v)) if field == "resolution" else float(v)
        out[i] = roll_pitch_sigma(replace(base, **{field: val}))
    return {"value": vals, "sigma_roll": out[:, 0], "sigma_pitch": out[:, 1], "pixels": out[:, 2]}
