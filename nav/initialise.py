"""Initial attitude from TRIAD, back-propagated with the gyros (003 §7.4).

003 initialises the coast at T+60 s although the first epoch with both an Earth-nadir and a Sun
vector is T+171 s (the gyros saturated during the spinning ascent, so the attitude cannot be
carried from lift-off). The TRIAD attitude (Black 1964, 003 ref. [4]) at that epoch is
back-propagated to the start by integrating the gyro samples backwards with RK4
(:func:`nav.ins.propagate` with ``backward=True``). Position and velocity come from GPS (a cubic
Hermite interpolation of the fixes, which uses the fixes' velocities). The initial attitude
covariance is 2 deg (1 sigma) per axis as in 003 §7.4, covering the TRIAD error and the
back-propagation drift.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nav import ins
from nav.ephemeris import sun_position_e
from nav.measurements import target_direction_e
from nav.navigator import NS, GpsData, ImuData, InitialState, VectorData
from nav.rotation import matrix_to_quat, triad

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


def gps_interpolator(gps: GpsData):
    """Position and velocity at any time inside the GPS record: cubic Hermite splines of the
    positions with the velocities as derivatives (velocity is its derivative, :func:`hermite`)."""
    t = (np.asarray(gps.t_ns, np.int64) - int(gps.t_ns[0])) / NS
    if gps.v_e is None:
        raise ValueError("gps: the initialisation needs GPS velocities")
    if t.size < 2 or np.any(np.diff(t) <= 0):
        raise ValueError("gps: the interpolation needs at least two fixes at increasing times")
    x = np.asarray(gps.x_e, float)
    v = np.asarray(gps.v_e, float)

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
