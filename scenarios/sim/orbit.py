"""A flight that starts in orbit: the initial state and the pointing law of ``[orbit]``.

Frames. The inertial frame i is the Earth-fixed frame e frozen at t = 0 (``R_ei(t)`` turns by
``-Omega_E t`` about z), so the initial position is the same in both, and the e-frame velocity is
``v_e = v_i - Omega_ie x x``. The truth integrator (:mod:`scenarios.sim.truth`) then propagates the
state in e with the same J2 gravity, Coriolis and centrifugal terms as a launched flight; the drag at
500 km (rho ~ 5e-13 kg/m^3, 0.1 m^2 on 120 kg: ~1e-8 m/s^2, under a millimetre over minutes) is
left out (the vehicle's drag areas are not used).

Pointing law. At t = 0 the body axes are::

    x_b = r_hat                                    geocentric zenith
    y_b = cos(psi0) t_hat + sin(psi0) n_hat         t_hat: horizontal along-track, n_hat = r_hat x t_hat
    z_b = x_b x y_b

(``psi0 = yaw_deg``) and the law turns them with the orbit about its normal ``n_hat`` at the mean
motion ``omega_o = |r x v| / r^2`` and about x_b at ``omega_y = yaw_rate_dps``::

    R_ib(t) = Rot(n_hat, omega_o t) R_ib(0) Rot(e_x, omega_y t)

so a side camera of the launch scenarios' mounting (azimuth 90 deg, depression delta) looks delta
below the local horizontal at the limb and sweeps along it. Its body rate and acceleration are
``omega_b(t) = omega_o Rot(e_x, -omega_y t) n_b + omega_y e_x`` (``n_b = R_ib(0)^T n_hat``) and
``domega_b/dt = -omega_y e_x x omega_b``; Euler's equations give the torque that holds the law,
``tau = I domega_b/dt + omega_b x I omega_b`` (the attitude control's, fed to the integrator as a
scheduled body torque). The orbit is not exactly a uniformly turning circle (J2, the choice of
speed), so the zenith drifts slowly from x_b: 0.002 deg over 4 minutes of a circular 500 km orbit.
"""
from __future__ import annotations

import math

import numpy as np

from nav import earth
from nav.rotation import rotvec_to_matrix

__all__ = ["initial_inertial_state", "pointing_law", "pointing_torque", "kepler_position"]


def initial_inertial_state(orbit) -> tuple[np.ndarray, np.ndarray]:
    """Position and inertial velocity (i = e at t = 0) [m, m/s] of an ``OrbitConfig``."""
    lat, lon = math.radians(orbit.lat_deg), math.radians(orbit.lon_deg)
    x = np.asarray(earth.geodetic_to_ecef(lat, lon, orbit.height_m), dtype=float)
    R_en = earth.R_en(lat, lon)
    az, gam = math.radians(orbit.heading_deg), math.radians(orbit.flight_path_deg)
    d_n = np.array([math.cos(gam) * math.cos(az), math.cos(gam) * math.sin(az), -math.sin(gam)])
    speed = orbit.speed_mps if orbit.speed_mps > 0 else math.sqrt(earth.GM / np.linalg.norm(x))
    return x, speed * (R_en @ d_n)


def _frame0(x: np.ndarray, v: np.ndarray, yaw_deg: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(R_ib(0), orbit normal n_hat, mean motion omega_o [rad/s]) of the pointing law."""
    r_hat = x / np.linalg.norm(x)
    t_hat = v - (v @ r_hat) * r_hat
    t_hat /= np.linalg.norm(t_hat)
    n_hat = np.cross(r_hat, t_hat)
    psi = math.radians(yaw_deg)
    y_b = math.cos(psi) * t_hat + math.sin(psi) * n_hat
    R0 = np.column_stack([r_hat, y_b, np.cross(r_hat, y_b)])
    omega_o = float(np.linalg.norm(np.cross(x, v)) / (x @ x))
    return R0, n_hat, omega_o


def pointing_law(orbit, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R_ib`` (N, 3, 3) and the body rate ``omega_ib_b`` (N, 3) [rad/s] of the law at ``t`` [s]."""
    x, v = initial_inertial_state(orbit)
    R0, n_hat, omega_o = _frame0(x, v, orbit.yaw_deg)
    wy = math.radians(orbit.yaw_rate_dps)
    t = np.atleast_1d(np.asarray(t, dtype=float))
    Rn = rotvec_to_matrix(np.outer(omega_o * t, n_hat))
    Rx = rotvec_to_matrix(np.outer(wy * t, [1.0, 0.0, 0.0]))
    n_b = R0.T @ n_hat
    w = omega_o * np.einsum("nji,j->ni", Rx, n_b) + np.array([wy, 0.0, 0.0])
    return Rn @ R0 @ Rx, w


def pointing_torque(orbit, t: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """Body torque (N, 3) [N m] that holds the law: ``I domega/dt + omega x I omega`` (``inertia``
    the full 3x3 tensor)."""
    _, w = pointing_law(orbit, t)
    dw = -math.radians(orbit.yaw_rate_dps) * np.cross([1.0, 0.0, 0.0], w)
    Iw = w @ inertia.T
    return dw @ inertia.T + np.cross(w, Iw)


def kepler_position(x0: np.ndarray, v0: np.ndarray, t: np.ndarray, gm: float = earth.GM) -> np.ndarray:
    """Two-body (point-mass) position (N, 3) at ``t`` [s] from an inertial state, in closed form:
    Kepler's equation solved by Newton for an ellipse, then the Lagrange f and g coefficients."""
    r0 = float(np.linalg.norm(x0))
    a = 1.0 / (2.0 / r0 - (v0 @ v0) / gm)
    if not a > 0:
        raise ValueError("kepler_position: the state is not on an ellipse")
    n = math.sqrt(gm / a**3)
    sig0 = (x0 @ v0) / math.sqrt(gm)
    t = np.atleast_1d(np.asarray(t, dtype=float))
    dE = n * t    # Kepler's equation in the eccentric-anomaly difference dE
    for _ in range(50):
        f = dE - (1 - r0 / a) * np.sin(dE) + sig0 / math.sqrt(a) * (1 - np.cos(dE)) - n * t
        fp = 1 - (1 - r0 / a) * np.cos(dE) + sig0 / math.sqrt(a) * np.sin(dE)
        dE = dE - f / fp
    f_l = 1 - a / r0 * (1 - np.cos(dE))
    g_l = t - (dE - np.sin(dE)) / n
    return f_l[:, None] * x0 + g_l[:, None] * v0
