"""Initial attitude: TRIAD back-propagated with the gyros (003 §7.4), in-motion alignment from
GPS and the IMU, a rocket's launcher, or roll / pitch / heading.

TRIAD (:func:`triad_initialise`).

003 initialises the coast at T+60 s although the first epoch with both an Earth-nadir and a Sun
vector is T+171 s (the gyros saturated during the spinning ascent, so the attitude cannot be
carried from lift-off). The TRIAD attitude (Black 1964, 003 ref. [4]) at that epoch is
back-propagated to the start by integrating the gyro samples backwards with RK4
(:func:`nav.ins.propagate` with ``backward=True``). Position and velocity come from GPS (a cubic
Hermite interpolation of the fixes, which uses the fixes' velocities). The initial attitude
covariance is 2 deg (1 sigma) per axis as in 003 §7.4, covering the TRIAD error and the
back-propagation drift.

Without camera vectors (every function pure; the attitude error covariance ``P_psi`` is that of
the filter's psi in e, ``R_true = exp([psi x]) R_est``):

* :func:`euler_to_q_eb` / :func:`q_eb_to_euler`: roll, pitch, heading in the local NED frame
  (z-y-x: heading about down, pitch, roll about the body x; docs/conventions.md) at a position;
* :func:`launcher_alignment`: a rocket on the rail, body x along the rail from its azimuth and
  elevation, roll given or from the accelerometer at rest;
* :func:`in_motion_alignment` / :func:`aligned_initial_state`: the in-motion (optimisation-based)
  coarse alignment over a window of GPS and IMU data (Wahba's problem, below).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nav import ins
from nav.earth import OMEGA_E, OMEGA_IE_E, R_en, ecef_to_geodetic, gravitation_e, gravity_e
from nav.ephemeris import sun_position_e
from nav.measurements import target_direction_e
from nav.navigator import NS, GpsData, ImuData, InitialState, VectorData
from nav.rotation import euler_zyx_deg, matrix_to_quat, quat_to_matrix, triad

#: 003 §7.4: initial attitude uncertainty per axis (1 sigma).
INIT_ATT_SIGMA = math.radians(2.0)


@dataclass
class TriadInit:
    initial: InitialState   #: state at the start time (attitude back-propagated)
    t_triad_ns: int         #: epoch of the TRIAD solution
    q_eb_triad: np.ndarray  #: TRIAD attitude at that epoch
    cameras: tuple          #: (camera of the nadir vector, camera of the Sun vector)
    att_sigma: float        #: 1-sigma initial attitude error per axis [rad]


def hermite(t: np.ndarray, y: np.ndarray, dydt: np.ndarray, tt: np.ndarray):
    """Piecewise cubic Hermite interpolation: the values and derivatives at ``tt`` of the cubics
    through ``(t_i, y_i)`` with slopes ``dydt_i`` (rows), on the interval of each ``tt`` (the end
    intervals beyond the knots). The same curve as ``scipy.interpolate.CubicHermiteSpline``
    (tests/test_initialise.py); written out because importing scipy.interpolate would cost several
    times what the whole evaluation takes, on every replay's critical path (docs/performance.md).

    With ``h = t_{i+1} - t_i``, ``s = (tt - t_i) / h`` the Hermite basis gives
    ``y = (1 + 2s)(1 - s)^2 y_i + s(1 - s)^2 h m_i + s^2(3 - 2s) y_{i+1} + s^2(s - 1) h m_{i+1}``.
    """
    i = np.clip(np.searchsorted(t, tt, side="right") - 1, 0, t.size - 2)
    h = (t[i + 1] - t[i])[:, None]
    s = ((tt - t[i])[:, None]) / h
    y0, y1, m0, m1 = y[i], y[i + 1], dydt[i], dydt[i + 1]
    u = 1.0 - s
    val = (1 + 2 * s) * u * u * y0 + s * u * u * h * m0 + s * s * (3 - 2 * s) * y1 + s * s * (s - 1) * h * m1
    der = 6 * s * u * (y1 - y0) / h + u * (1 - 3 * s) * m0 + s * (3 * s - 2) * m1
    return val, der


def position_slopes(t: np.ndarray, x: np.ndarray, half_window_s: float = 1.0) -> np.ndarray:
    """Velocity of position-only fixes: at each fix the slope of the least-squares line through
    the fixes within ``half_window_s`` on either side (``t`` [s] increasing, ``x`` (N, 3)). On a
    symmetric window the slope is the derivative of any quadratic (constant acceleration) exactly,
    and the fix noise sigma enters as about ``sigma sqrt(12 / n) / (2 half_window_s)`` for n fixes
    in the window (1.1 m/s for 3 m fixes at 10 Hz and 1 s); at the ends the window is one-sided."""
    lo = np.searchsorted(t, t - half_window_s, side="left")
    hi = np.searchsorted(t, t + half_window_s, side="right")
    tc = t - t[0]
    xc = x - x[0]
    c = lambda y: np.concatenate([np.zeros((1,) + y.shape[1:]), np.cumsum(y, axis=0)])  # noqa: E731
    S1, St, Stt = c(np.ones_like(tc)), c(tc), c(tc * tc)
    Sx, Stx = c(xc), c(tc[:, None] * xc)
    n, st, stt = S1[hi] - S1[lo], St[hi] - St[lo], Stt[hi] - Stt[lo]
    sx, stx = Sx[hi] - Sx[lo], Stx[hi] - Stx[lo]
    den = (n * stt - st * st)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, (n[:, None] * stx - st[:, None] * sx) / den, 0.0)


def gps_velocity_sigma(gps: GpsData, t_ns: int, half_window_s: float = 1.0) -> float | None:
    """1-sigma [m/s] (the largest axis) of the velocity :func:`gps_interpolator` gives at ``t_ns``
    when the fixes there carry no velocity, else None (the fixes' own velocity covariance holds).
    The velocity is then the slope of :func:`position_slopes` at the nearest fix: a least-squares
    line through the n fixes within ``half_window_s``, whose slope has the variance
    ``sigma_p^2 / sum (t_i - mean t)^2`` with ``sigma_p^2`` the fixes' mean variance (largest
    axis): 1.1 m/s for 3 m fixes at 10 Hz and 1 s, 2.9 m/s on the one-sided window at an end of
    the record, where the slope is also off by the acceleration times ``half_window_s / 2``
    (not included: the vehicle is usually at rest there)."""
    t = (np.asarray(gps.t_ns, np.int64) - int(gps.t_ns[0])) / NS
    j = int(np.argmin(np.abs(t - (int(t_ns) - int(gps.t_ns[0])) / NS)))   # the nearest fix
    if gps.v_e is not None and not np.all(np.isnan(np.asarray(gps.v_e, float)[j])):
        return None
    w = np.abs(t - t[j]) <= half_window_s
    spread = float(np.sum((t[w] - t[w].mean()) ** 2))
    var_p = np.diagonal(np.asarray(gps.P_x, float)[w], axis1=1, axis2=2).mean(axis=0).max()
    return float(np.sqrt(var_p / spread)) if spread > 0 else float("inf")


def gps_interpolator(gps: GpsData):
    """Position and velocity at any time inside the GPS record: cubic Hermite splines of the
    positions with the velocities as derivatives (velocity is its derivative, :func:`hermite`).
    Position-only fixes (``v_e`` None, or NaN rows) take :func:`position_slopes` as velocities."""
    t = (np.asarray(gps.t_ns, np.int64) - int(gps.t_ns[0])) / NS
    if t.size < 2 or np.any(np.diff(t) <= 0):
        raise ValueError("gps: the interpolation needs at least two fixes at increasing times")
    x = np.asarray(gps.x_e, float)
    if gps.v_e is None:
        v = position_slopes(t, x)
    else:
        v = np.asarray(gps.v_e, float)
        none = np.all(np.isnan(v), axis=1)
        if none.any():
            v = np.where(none[:, None], position_slopes(t, x), v)

    def at(t_ns):
        tt = (np.asarray(t_ns, np.int64) - int(gps.t_ns[0])) / NS
        if np.any(tt < t[0]) or np.any(tt > t[-1]):
            raise ValueError("t_ns: outside the GPS record; cannot interpolate position there")
        val, der = hermite(t, x, v, np.atleast_1d(tt))
        return (val, der) if np.ndim(tt) else (val[0], der[0])
    return at


def first_triad_epoch(vectors: VectorData, not_before_ns: int | None = None):
    """Earliest time stamp with both a 'hor' and a 'sun' vector (any cameras); returns
    (t_ns, index of hor, index of sun) preferring both from the same camera."""
    t = np.asarray(vectors.t_ns, np.int64)
    tg = np.asarray(vectors.target)
    cam = np.asarray(vectors.camera)
    order = np.argsort(t, kind="stable")
    for tt in np.unique(t[order]):
        if not_before_ns is not None and tt < not_before_ns:
            continue
        m = t == tt
        ih = np.flatnonzero(m & (tg == "hor"))
        isun = np.flatnonzero(m & (tg == "sun"))
        if ih.size and isun.size:
            for a in ih:
                for b in isun:
                    if cam[a] == cam[b]:
                        return int(tt), int(a), int(b)
            return int(tt), int(ih[0]), int(isun[0])
    raise ValueError("vectors: no epoch with both an Earth-nadir ('hor') and a Sun vector; TRIAD needs both")


def triad_initialise(imu: ImuData, gps: GpsData, vectors: VectorData, R_bc, t_start_ns: int, *,
                     not_before_ns: int | None = None) -> TriadInit:
    """TRIAD at the first epoch with both vectors, back-propagated to ``t_start_ns`` (003 §7.4).

    Parameters
    ----------
    imu : ImuData
        Must cover ``t_start_ns`` to the TRIAD epoch with unsaturated gyro samples.
    gps : GpsData
        Position and velocity (with velocities) covering both times.
    vectors : VectorData
    R_bc : sequence of (3, 3) nominal camera mountings.
    t_start_ns : int
        Start of the navigation (snapped to the IMU sample at or after it).
    not_before_ns : int, optional
        Ignore vector epochs before this time (003 discards camera 1's horizon before T+171 s).
    """
    t_tri, ih, isun = first_triad_epoch(vectors, not_before_ns)
    t_imu = np.asarray(imu.t_ns, np.int64)
    i0 = int(np.searchsorted(t_imu, t_start_ns, side="left"))
    i1 = int(np.searchsorted(t_imu, t_tri, side="right")) - 1
    if i0 >= t_imu.size or i1 <= i0:
        raise ValueError("t_start_ns: the start must lie before the TRIAD epoch, inside the IMU record")
    at = gps_interpolator(gps)
    x_tri, v_tri = at(t_imu[i1])
    sun = sun_position_e(t_tri)
    e_b = [np.asarray(R_bc[int(vectors.camera[i])], float) @ np.asarray(vectors.e_c[i], float) for i in (ih, isun)]
    u_hor = target_direction_e("hor", x_tri)
    u_sun = target_direction_e("sun", x_tri, sun)
    R_eb = triad(e_b[0], e_b[1], u_hor, u_sun)
    q_tri = matrix_to_quat(R_eb)
    sl = slice(i0, i1 + 1)
    ts = (t_imu[sl] - t_imu[i0]) / NS
    _, _, Q = ins.propagate(x_tri, v_tri, q_tri, ts, imu.f_b[sl], imu.w_b[sl], backward=True,
                             sample=getattr(imu, "sample", "average"))
    x0, v0 = at(t_imu[i0])
    init = InitialState(int(t_imu[i0]), x0, v0, Q[0])
    return TriadInit(init, t_tri, q_tri, (int(vectors.camera[ih]), int(vectors.camera[isun])), INIT_ATT_SIGMA)


@dataclass
class Alignment:
    """An attitude from an alignment: ``q_eb`` (body to e, scalar last) at ``t_ns`` and the 3x3
    covariance ``P_psi`` [rad^2] of its error psi in e (the filter's attitude error)."""
    t_ns: int | None
    q_eb: np.ndarray
    P_psi: np.ndarray
    method: str

    @property
    def att_sigma(self) -> float:
        """The largest 1-sigma attitude error over all axes [rad]."""
        return float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (self.P_psi + self.P_psi.T)).max(), 0.0)))


def _R_nb(roll, pitch, heading):
    """z-y-x rotation from body to NED [rad]: ``Rz(heading) Ry(pitch) Rx(roll)``."""
    cr, sr, cp, sp, ch, sh = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(heading), np.sin(heading)
    return np.array([[ch * cp, ch * sp * sr - sh * cr, ch * sp * cr + sh * sr],
                     [sh * cp, sh * sp * sr + ch * cr, sh * sp * cr - ch * sr],
                     [-sp, cp * sr, cp * cr]])


def _R_en_at(x_e):
    lat, lon, _ = ecef_to_geodetic(np.asarray(x_e, float))
    return R_en(lat, lon)


def euler_to_q_eb(roll_deg: float, pitch_deg: float, heading_deg: float, x_e) -> np.ndarray:
    """q_eb (scalar last) of a body with roll, pitch and heading [deg] in the NED frame at ``x_e``
    (ECEF [m]; geodetic latitude and longitude from it): ``R_eb = R_en Rz(heading) Ry(pitch) Rx(roll)``."""
    r, p, h = np.radians([roll_deg, pitch_deg, heading_deg])
    return matrix_to_quat(_R_en_at(x_e) @ _R_nb(r, p, h))


def q_eb_to_euler(q_eb, x_e) -> tuple[float, float, float]:
    """Roll, pitch, heading [deg] in NED at ``x_e`` of the attitude ``q_eb`` (inverse of
    :func:`euler_to_q_eb`; heading in [0, 360))."""
    return tuple(float(a) for a in euler_zyx_deg(_R_en_at(x_e).T @ quat_to_matrix(q_eb)))


def launcher_alignment(azimuth_deg: float, elevation_deg: float, x_e, *, roll_deg: float | None = None,
                       f_b=None, t_ns: int | None = None, rail_sigma_deg: float = 0.1,
                       roll_sigma_deg: float = 2.0, accel_sigma: float = 2e-3 * 9.80665) -> Alignment:
    """Attitude of a rocket on its launcher: body x along the rail (``azimuth_deg`` from north,
    ``elevation_deg`` above the horizon, at ``x_e``), the roll about it either given (``roll_deg``,
    the z-y-x roll of heading = azimuth, pitch = elevation) or from the accelerometer at rest:
    ``f_b`` (3,) or (N, 3), averaged, matched against ``-gravity`` by TRIAD with the rail axis as
    the exact (primary) vector.

    Covariance (in b, then rotated into e): ``rail_sigma_deg`` about the two axes across the rail;
    about the rail ``roll_sigma_deg`` for a given roll, else the accelerometer error
    ``accel_sigma`` [m/s^2] (default a 2 mg bias) over the part of gravity across the rail,
    ``accel_sigma / (g sin(angle of rail and vertical))`` (a vertical rail leaves roll unobservable:
    TRIAD raises below 1 deg).
    """
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    R_en_ = _R_en_at(x_e)
    if roll_deg is not None:
        R_eb = R_en_ @ _R_nb(math.radians(roll_deg), el, az)
        s_roll = math.radians(roll_sigma_deg)
        method = "launcher"
    elif f_b is not None:
        f = np.asarray(f_b, float).reshape(-1, 3).mean(axis=0)
        rail_e = R_en_ @ np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])
        g_e = gravity_e(np.asarray(x_e, float))
        R_eb = triad(np.array([1.0, 0.0, 0.0]), f, rail_e, -g_e)
        across = np.linalg.norm(np.cross(rail_e, g_e))
        s_roll = accel_sigma / across
        method = "launcher+accelerometer"
    else:
        raise ValueError("launcher_alignment: give roll_deg or the accelerometer samples f_b at rest")
    s_rail = math.radians(rail_sigma_deg)
    P_b = np.diag([s_roll ** 2, s_rail ** 2, s_rail ** 2])
    return Alignment(t_ns, matrix_to_quat(R_eb), R_eb @ P_b @ R_eb.T, method)


def _Rz(theta):
    """(N, 3, 3) rotations by ``theta`` about z (the Earth's rotation over ``theta / OMEGA_E``)."""
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros((np.size(theta), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def _body_integral(imu: ImuData, i0: int, i1: int, x0):
    """Times [s from sample i0] and ``alpha(t) = int C(tau) f_b dtau`` at the IMU samples i0..i1,
    ``C = R_b0b`` the body attitude against its own at i0 in inertial space (from the gyros:
    :func:`nav.ins.propagate` from the identity gives ``R_eb = Rz(-W t) C``)."""
    sl = slice(i0, i1 + 1)
    t = (np.asarray(imu.t_ns[sl], np.int64) - int(imu.t_ns[i0])) / NS
    f = np.asarray(imu.f_b[sl], float)
    sample = getattr(imu, "sample", "average")
    _, _, Q = ins.propagate(x0, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), t, f, imu.w_b[sl], sample=sample)
    C = _Rz(OMEGA_E * t) @ quat_to_matrix(Q)
    dt = np.diff(t)[:, None]
    if sample == "average":   # sample k is the mean over (t_k-1, t_k]
        inc = np.einsum("nij,nj->ni", 0.5 * (C[:-1] + C[1:]), f[1:]) * dt
    else:
        Cf = np.einsum("nij,nj->ni", C, f)
        inc = 0.5 * (Cf[:-1] + Cf[1:]) * dt
    return t, np.concatenate([np.zeros((1, 3)), np.cumsum(inc, axis=0)])


def _inertial_integral(tj, xj, vj, x0, v0):
    """``beta(t_j) = pdot(t_j) - pdot(0) - int G dt`` in the inertial frame equal to e at time 0
    (``pdot = Rz(W t) (v_e + W x x_e)``, G the gravitation, trapezoid over the fixes)."""
    R = _Rz(OMEGA_E * tj)
    pdot = np.einsum("nij,nj->ni", R, vj + np.cross(OMEGA_IE_E, xj))
    pdot0 = v0 + np.cross(OMEGA_IE_E, x0)
    G = np.concatenate([gravitation_e(x0)[None], np.einsum("nij,nj->ni", R, gravitation_e(xj))])
    tt = np.concatenate([[0.0], tj])
    intG = np.cumsum(0.5 * (G[:-1] + G[1:]) * np.diff(tt)[:, None], axis=0)
    return pdot - pdot0 - intG


def in_motion_alignment(imu: ImuData, gps: GpsData, t_start_ns: int, *, window_s: float = 60.0) -> Alignment:
    """In-motion coarse alignment: the attitude at ``t_start_ns`` (snapped to the IMU sample at or
    after it) from GPS position and velocity and the IMU over the following ``window_s`` seconds.

    With the inertial frame equal to e at the start and ``C(t)`` the body's rotation since the start
    from the gyros, the specific force integrates to the GPS velocity change:
    ``R_eb(t0) alpha(t) = beta(t)``, ``alpha = int C f_b dt`` (IMU), ``beta`` = the inertial velocity
    change minus the integrated gravitation (GPS; :func:`_inertial_integral`). Gravity alone fixes
    the level; the heading comes from the horizontal velocity changes (turns, speed changes, a
    gravity turn). ``R_eb(t0)`` is the solution of Wahba's problem over every fix in the window,
    by SVD (Markley 1988; the same minimiser as Davenport's q-method).

    The covariance is the least-squares one, ``s^2 (sum |b|^2 I - b b^T)^-1`` with ``s^2`` the
    residual variance, times the number of fixes (the residuals of integrated quantities are
    correlated over the window, so the fixes are not independent). A window without a change of
    direction (straight, unaccelerated flight) leaves the heading unobservable: ``att_sigma`` is then
    large and the caller should not use the result. The GPS lever arm is neglected (its velocity
    ``omega x l`` is small against the velocity changes). The IMU samples must be unsaturated.
    """
    t_imu = np.asarray(imu.t_ns, np.int64)
    i0 = int(np.searchsorted(t_imu, t_start_ns, side="left"))
    i1 = int(np.searchsorted(t_imu, t_imu[min(i0, t_imu.size - 1)] + int(window_s * NS), side="right")) - 1
    if i0 >= t_imu.size or i1 <= i0:
        raise ValueError("t_start_ns: no IMU samples in the alignment window")
    at = gps_interpolator(gps)
    x0, v0 = at(t_imu[i0])
    g_t = np.asarray(gps.t_ns, np.int64)
    use = (g_t > t_imu[i0]) & (g_t <= t_imu[i1]) & np.all(np.isfinite(gps.v_e), axis=1) & np.all(np.isfinite(gps.x_e), axis=1)
    if use.sum() < 3:
        raise ValueError("gps: fewer than 3 fixes with velocity in the alignment window")
    tj = (g_t[use] - t_imu[i0]) / NS
    beta = _inertial_integral(tj, np.asarray(gps.x_e, float)[use], np.asarray(gps.v_e, float)[use], x0, v0)
    t, a = _body_integral(imu, i0, i1, x0)
    alpha = np.stack([np.interp(tj, t, a[:, i]) for i in range(3)], axis=1)
    U, _, Vt = np.linalg.svd(beta.T @ alpha)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U) * np.linalg.det(Vt)]) @ Vt
    res = beta - alpha @ R.T
    n = tj.size
    s2 = float(np.sum(res * res)) / max(3 * n - 3, 1)
    info = np.sum(beta * beta) * np.eye(3) - beta.T @ beta
    P = s2 * n * np.linalg.pinv(info)
    return Alignment(int(t_imu[i0]), matrix_to_quat(R), 0.5 * (P + P.T), "in-motion")


def aligned_initial_state(imu: ImuData, gps: GpsData, t_start_ns: int, *, window_s: float = 60.0,
                          at_end: bool = False) -> tuple[InitialState, Alignment]:
    """An :class:`nav.navigator.InitialState` without a given attitude: :func:`in_motion_alignment`
    over ``window_s`` from ``t_start_ns``, position and velocity from GPS (:func:`gps_interpolator`).
    ``at_end``: the state at the window's last IMU sample instead, the attitude carried there by
    the INS (:func:`nav.ins.propagate`; its drift over the window is not added to ``P_psi``)."""
    al = in_motion_alignment(imu, gps, t_start_ns, window_s=window_s)
    at = gps_interpolator(gps)
    x0, v0 = at(al.t_ns)
    if not at_end:
        return InitialState(al.t_ns, x0, v0, al.q_eb), al
    t_imu = np.asarray(imu.t_ns, np.int64)
    i0 = int(np.searchsorted(t_imu, al.t_ns))
    i1 = int(np.searchsorted(t_imu, al.t_ns + int(window_s * NS), side="right")) - 1
    sl = slice(i0, i1 + 1)
    _, _, Q = ins.propagate(x0, v0, al.q_eb, (t_imu[sl] - t_imu[i0]) / NS, imu.f_b[sl], imu.w_b[sl],
                            sample=getattr(imu, "sample", "average"))
    x1, v1 = at(t_imu[i1])
    end = Alignment(int(t_imu[i1]), Q[-1], al.P_psi, "in-motion, carried by the INS")
    return InitialState(int(t_imu[i1]), x1, v1, Q[-1]), end
