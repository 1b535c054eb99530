"""A navigation solution as table columns, one row per covariance epoch: the one column builder
behind ``Solution.to_frame`` / ``Smoothed.to_frame`` (pandas, as pyins returns its trajectories: a
time index and geodetic position, NED velocity and Euler angles as columns) and behind
``horizon-nav export SOLUTION.mcap`` (CSV and Parquet, scenarios/importer/export.py).

Columns (docs/replay.md "Exporting a solution" has the same list):

* time: ``time_utc`` (ISO-8601 UTC text in CSV, a UTC timestamp in Parquet; in the DataFrame it is
  the ``DatetimeIndex`` named ``time``), ``t_ns`` (int64 ns since the Unix epoch, UTC: the log's
  exact stamp), ``t_plus_s`` (seconds after lift-off, or after the mission-time origin the
  solution names when the log has no lift-off time);
* ``lat``, ``lon`` [deg], ``height`` [m above the WGS-84 ellipsoid] (geodetic, ``nav.earth``);
* ``x``, ``y``, ``z`` [m] and ``vx``, ``vy``, ``vz`` [m/s]: ECEF position and velocity;
* ``VN``, ``VE``, ``VD`` [m/s]: velocity in the local north-east-down frame;
* ``qx``, ``qy``, ``qz``, ``qw``: the attitude quaternion q_eb (body to ECEF, scalar last,
  docs/conventions.md);
* ``roll``, ``pitch``, ``heading`` [deg]: the body's z-y-x Euler angles from north-east-down
  (:func:`nav.rotation.euler_zyx_deg`, heading in [0, 360));
* 1-sigma of the navigation errors in ECEF: ``x_sd``, ``y_sd``, ``z_sd`` [m], ``vx_sd``,
  ``vy_sd``, ``vz_sd`` [m/s], ``psi_x_sd``, ``psi_y_sd``, ``psi_z_sd`` [deg] (attitude error psi
  about the ECEF axes, docs/conventions.md), and the totals ``pos_sd``, ``vel_sd``, ``att_sd``
  (root of the trace of each 3x3 block: they do not depend on the axes);
* 1-sigma in north-east-down: ``N_sd``, ``E_sd``, ``D_sd`` [m], ``VN_sd``, ``VE_sd``, ``VD_sd``
  [m/s] (the 3x3 blocks rotated, ``R_ne P R_en``) and ``roll_sd``, ``pitch_sd``, ``heading_sd``
  [deg] (the psi block through the Jacobian of the Euler angles, :func:`euler_jacobian`); these
  need the full 3x3 blocks: exported from a solution log without them (metadata
  ``nav_covariance`` other than ``"full"``), they are NaN at the epochs whose block is diagonal;
* every other estimated state, by its name in the solution (``accel_bias_x`` [m/s^2],
  ``gyro_bias_x``, ``gyro_gm_x`` [rad/s], ``accel_scale_x``, ``gyro_scale_x`` [-], ``accel_misalignment_x``,
  ``gyro_misalignment_x`` [rad], ``psi_c_<k>_x`` [rad] (camera k's misalignment rotation vector,
  003 eq. (50)), ``dt_c_<k>`` [s] (camera clock offset refinement), ``zeta_<target>_<k>_x``
  [unit-vector units], ``h_e_<k>`` [m] (camera k's Earth edge height)): the estimate at the
  epoch, and ``<name>_sd`` its 1-sigma.
"""
from __future__ import annotations

import numpy as np

from nav import earth
from nav.rotation import euler_zyx_deg, quat_to_matrix

NAV = 9   #: dx, dv, psi: the navigation block at the head of every layout
_DEG = 180.0 / np.pi


def euler_jacobian(R_nb) -> np.ndarray:
    """(..., 3, 3) d(roll, pitch, heading) / d(delta) [rad/rad] for a small rotation ``delta`` in n
    applied on the left, ``R_nb' = exp([delta x]) R_nb`` (the psi convention of
    docs/conventions.md, rotated into n), z-y-x angles: ``d roll = (c_h d_N + s_h d_E) / c_p``,
    ``d pitch = -s_h d_N + c_h d_E``, ``d heading = t_p (c_h d_N + s_h d_E) + d_D``."""
    roll, pitch, heading = (np.radians(a) for a in euler_zyx_deg(R_nb))
    ch, sh, cp, tp = np.cos(heading), np.sin(heading), np.cos(pitch), np.tan(pitch)
    J = np.zeros(np.shape(heading) + (3, 3))
    J[..., 0, 0], J[..., 0, 1] = ch / cp, sh / cp
    J[..., 1, 0], J[..., 1, 1] = -sh, ch
    J[..., 2, 0], J[..., 2, 1], J[..., 2, 2] = ch * tp, sh * tp, 1.0
    return J


def _sd_of(C) -> np.ndarray:
    return np.sqrt(np.clip(np.diagonal(C, axis1=-2, axis2=-1), 0.0, None))


def solution_columns(t_ns, t_plus_s, x_e, v_e, q_eb, variances, names, state=None, P_nav=None) -> dict:
    """The columns of the module docstring (``time_utc`` excepted) as a dict of (K,) arrays.

    Parameters
    ----------
    t_ns : (K,) int64 epochs; t_plus_s : (K,) mission times [s].
    x_e, v_e : (K, 3) ECEF position and velocity; q_eb : (K, 4) attitude (scalar last).
    variances : (K, m) variances of the states ``names`` (m names, the first 9 ``dx_x`` ..
        ``psi_z``: :func:`scenarios.replay.solution_log.state_names`).
    state : (K, m) estimates of the states (the first 9 are not read), or None (no estimated
        states beyond navigation are reported then).
    P_nav : (K, 9, 9) covariance of dx, dv, psi, or None: the NED and Euler sigmas are NaN where
        it is None or NaN.
    """
    t_ns = np.asarray(t_ns, np.int64)
    x_e, v_e = np.asarray(x_e, float), np.asarray(v_e, float)
    lat, lon, h = earth.ecef_to_geodetic(x_e)
    R_ne = np.swapaxes(earth.R_en(lat, lon), -1, -2)
    R_nb = R_ne @ quat_to_matrix(np.asarray(q_eb, float))
    v_n = np.einsum("kij,kj->ki", R_ne, v_e)
    roll, pitch, heading = euler_zyx_deg(R_nb)
    cols = {"t_ns": t_ns, "t_plus_s": np.asarray(t_plus_s, float), "lat": np.degrees(lat), "lon": np.degrees(lon),
            "height": h}
    cols.update({a: x_e[:, i] for i, a in enumerate("xyz")})
    cols.update({"v" + a: v_e[:, i] for i, a in enumerate("xyz")})
    cols.update({a: v_n[:, i] for i, a in enumerate(("VN", "VE", "VD"))})
    q = np.asarray(q_eb, float)
    cols.update({"q" + a: q[:, i] for i, a in enumerate("xyzw")})
    cols.update(roll=roll, pitch=pitch, heading=heading)
    sd = np.sqrt(np.clip(np.asarray(variances, float), 0.0, None))
    blocks = (("{}_sd", "pos_sd", 1.0), ("v{}_sd", "vel_sd", 1.0), ("psi_{}_sd", "att_sd", _DEG))
    for b, (name, total, scale) in enumerate(blocks):
        s = sd[:, 3 * b:3 * b + 3] * scale
        cols.update({name.format(a): s[:, i] for i, a in enumerate("xyz")})
        cols[total] = np.sqrt(np.sum(s ** 2, axis=1))
    cols.update(_ned_sigmas(R_ne, R_nb, P_nav, len(t_ns)))
    if state is not None:
        st = np.asarray(state, float)
        for j in range(NAV, len(names)):
            cols[names[j]] = st[:, j]
            cols[names[j] + "_sd"] = sd[:, j]
    return cols


def _ned_sigmas(R_ne, R_nb, P_nav, K: int) -> dict:
    """North-east-down position and velocity sigmas and roll/pitch/heading sigmas from the 9x9
    navigation blocks (NaN without them, or where a block is NaN)."""
    names = ("N_sd", "E_sd", "D_sd", "VN_sd", "VE_sd", "VD_sd", "roll_sd", "pitch_sd", "heading_sd")
    out = np.full((K, 9), np.nan)
    if P_nav is not None:
        P = np.asarray(P_nav, float)
        for b in range(2):
            blk = P[:, 3 * b:3 * b + 3, 3 * b:3 * b + 3]
            out[:, 3 * b:3 * b + 3] = _sd_of(R_ne @ blk @ np.swapaxes(R_ne, -1, -2))
        J = euler_jacobian(R_nb) @ R_ne
        out[:, 6:9] = _sd_of(J @ P[:, 6:9, 6:9] @ np.swapaxes(J, -1, -2)) * _DEG
    return {nm: out[:, i] for i, nm in enumerate(names)}


def solution_frame(cols: dict):
    """The pandas DataFrame of ``cols`` (:func:`solution_columns`) with the UTC ``DatetimeIndex``
    ``time``."""
    import pandas as pd
    index = pd.DatetimeIndex(pd.to_datetime(cols["t_ns"], unit="ns", utc=True), name="time")
    return pd.DataFrame(cols, index=index)


def forward_columns(res, t_plus_s, cam_numbers=()) -> dict:
    """:func:`solution_columns` of a forward run (:class:`nav.navigator.NavResult`) at its
    covariance epochs, with the states the solution log reports (``solution_log.reported_groups``)."""
    from scenarios.replay.solution_log import reported_groups, state_names
    groups = reported_groups(res.layout)
    idx = np.concatenate([np.arange(res.layout.n)[g.slice] for g in groups])
    ci = res.cov_idx
    est = None if res.estimates is None else res.estimates[:, idx]
    return solution_columns(res.cov_t_ns, t_plus_s, res.x_e[ci], res.v_e[ci], res.q_eb[ci], res.P_diag[:, idx],
                            state_names(groups, cam_numbers), est, res.P_nav)


def smoothed_columns(sm, layout, t_plus_s, cam_numbers=()) -> dict:
    """:func:`solution_columns` of a :class:`nav.smoother.SmoothResult` (the same states as
    :func:`forward_columns`)."""
    from scenarios.replay.solution_log import reported_groups, state_names
    groups = reported_groups(layout)
    idx = np.concatenate([np.arange(layout.n)[g.slice] for g in groups])
    est = None if sm.estimates is None else sm.estimates[:, idx]
    return solution_columns(sm.t_ns, t_plus_s, sm.x_e, sm.v_e, sm.q_eb, sm.P[:, idx], state_names(groups, cam_numbers),
                            est, sm.P_nav)
