"""A navigation solution as a pandas DataFrame, one row per covariance epoch (as pyins returns its
trajectories: a time index and geodetic position, NED velocity and Euler angles as columns).

Columns:

* ``t_ns`` (int64, UTC ns since the Unix epoch, the exact stamp; the index is the same instant as
  a UTC ``DatetimeIndex`` named ``time``), ``t_plus_s`` (seconds after lift-off, or after the
  first IMU sample when the log has no lift-off time);
* ``lat``, ``lon`` [deg], ``height`` [m above the WGS-84 ellipsoid];
* ``x``, ``y``, ``z`` [m] and ``vx``, ``vy``, ``vz`` [m/s]: ECEF position and velocity;
* ``VN``, ``VE``, ``VD`` [m/s]: velocity in the local north-east-down frame;
* ``roll``, ``pitch``, ``heading`` [deg]: the body's z-y-x Euler angles from north-east-down
  (heading in [0, 360));
* 1-sigma: ``x_sd``, ``y_sd``, ``z_sd`` [m], ``vx_sd``, ``vy_sd``, ``vz_sd`` [m/s] and
  ``psi_x_sd``, ``psi_y_sd``, ``psi_z_sd`` [deg] (attitude error about the ECEF axes), and the
  totals ``pos_sd``, ``vel_sd``, ``att_sd`` (root of the trace of each 3x3 block). The filter keeps
  the covariance diagonal in the ECEF error state (003 §6.1) between updates, so the 1-sigma
  columns are those axes; the totals do not depend on the axes.
"""
from __future__ import annotations

import numpy as np

from nav import earth
from nav.rotation import euler_zyx_deg, quat_to_matrix


def solution_frame(t_ns, t_plus_s, x_e, v_e, q_eb, P_diag, layout):
    """The DataFrame of the module docstring from epochs ``t_ns`` (K,), mission times ``t_plus_s``,
    ECEF position/velocity (K, 3), attitude quaternions q_eb (K, 4) and the error-state
    covariance diagonal ``P_diag`` (K, n) laid out by ``layout`` (:class:`nav.error_state.StateLayout`)."""
    import pandas as pd
    t_ns = np.asarray(t_ns, np.int64)
    x_e, v_e = np.asarray(x_e, float), np.asarray(v_e, float)
    lat, lon, h = earth.ecef_to_geodetic(x_e)
    R_en = earth.R_en(lat, lon)
    R_ne = np.swapaxes(R_en, -1, -2)
    v_n = np.einsum("kij,kj->ki", R_ne, v_e)
    roll, pitch, heading = euler_zyx_deg(R_ne @ quat_to_matrix(np.asarray(q_eb, float)))
    sd = np.sqrt(np.asarray(P_diag, float))
    cols = {"t_ns": t_ns, "t_plus_s": np.asarray(t_plus_s, float), "lat": np.degrees(lat), "lon": np.degrees(lon),
            "height": h}
    for i, a in enumerate("xyz"):
        cols[a] = x_e[:, i]
    for i, a in enumerate("xyz"):
        cols["v" + a] = v_e[:, i]
    for i, a in enumerate(("VN", "VE", "VD")):
        cols[a] = v_n[:, i]
    cols.update(roll=roll, pitch=pitch, heading=heading)
    blocks = (("dx", "{}_sd", "pos_sd", 1.0), ("dv", "v{}_sd", "vel_sd", 1.0), ("psi", "psi_{}_sd", "att_sd", 180 / np.pi))
    for group, name, total, scale in blocks:
        s = sd[:, layout[group]] * scale
        for i, a in enumerate("xyz"):
            cols[name.format(a)] = s[:, i]
        cols[total] = np.sqrt(np.sum(s ** 2, axis=1))
    index = pd.DatetimeIndex(pd.to_datetime(t_ns, unit="ns", utc=True), name="time")
    return pd.DataFrame(cols, index=index)
