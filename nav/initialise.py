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
from scipy.interpolate import CubicHermiteSpline

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


def gps_interpolator(gps: GpsData):
    """Position and velocity at any time inside the GPS record: cubic Hermite splines of the
    positions with the velocities as derivatives (velocity is its derivative)."""
    t = (np.asarray(gps.t_ns, np.int64) - int(gps.t_ns[0])) / NS
    if gps.v_e is None:
        raise ValueError("gps: the initialisation needs GPS velocities")
    spl = CubicHermiteSpline(t, np.asarray(gps.x_e, float), np.asarray(gps.v_e, float), axis=0)

    def at(t_ns):
        tt = (np.asarray(t_ns, np.int64) - int(gps.t_ns[0])) / NS
        if np.any(tt < t[0]) or np.any(tt > t[-1]):
            raise ValueError("t_ns: outside the GPS record; cannot interpolate position there")
        return spl(tt), spl(tt, 1)
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
