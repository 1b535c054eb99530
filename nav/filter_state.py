"""The state of the filter loop between epochs and its two kernels: propagation and feedback.

:class:`FilterState` holds everything the closed-loop Schmidt-Kalman filter (003 §6) carries from
one epoch to the next: the nominal navigation state (x_e, v_e, q_eb), the error covariance P,
and the estimates fed back into the nominal models (IMU calibration, camera mountings,
Gauss-Markov vector errors zeta and their latest P_c, camera clock offsets). The numeric arrays
are packed so that the kernels take a few arrays instead of one argument per quantity:

* ``nav`` (10,): x_e, v_e, q_eb (``x``, ``v``, ``q`` are views of it);
* ``fed`` (flat): every fed-back estimate, viewed as ``cal_arr`` (7, 3) (the
  :class:`nav.imu_errors.ImuCalibration` fields, in ``CAL_FIELDS`` order), ``R_bc`` (cameras, 3, 3),
  ``zeta`` (groups, 3), ``clk_hat`` (cameras,), ``edge_hat`` (cameras,), the Earth edge
  heights [m], and with the Gauss-Markov gyro error in the layout ``gw_hat`` (3,) [rad/s];
* ``fb`` (k, 3) int64: the feedback table, one row ``(operation, offset in fed, first state index)``
  per estimated group (:func:`feedback_table`);
* ``cal_m`` (2, 4, 3): the calibration the INS applies, ``A (x - b)``: rows 0..2 of ``[0]`` are
  A_f and row 3 is b_f, ``[1]`` the same for the gyro, whose row 3 is ``b_w + gw_hat``
  (:func:`biases_into_calibration`);
* ``model`` (3 + n,): omega_ie, GM, T_c and the white process-noise rate of every state;
  ``gm_idx`` (8 + groups,) int64: the first column of the seven IMU error groups and of the
  Gauss-Markov gyro error (-1: absent, as :func:`nav.error_state.nav_transition` reads them) and
  of every zeta group.

A new state group is a group in :func:`nav.error_state.build_layout` (with its tuning entry), its
columns in the transition if it is not a constant, and a feedback row in :func:`feedback_table`.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from nav import ins
from nav._kernels import R_to_quat, gravity, quat_to_R, rotvec_to_R
from nav.earth import GM, OMEGA_E
from nav.error_state import (N_TRANSITION, StateLayout, edge_gm_indices, gyro_gm_indices, gyro_gm_taus, nav_transition, propagate_covariance,
                             transition_columns)
from nav.imu_errors import GROUP_TO_FIELD, ImuCalibration, affine_into
from nav.quantisation import block_rates, cumulative_rates
from nav.rotation import matrix_to_quat, quat_to_matrix
from nav.tuning import Tuning

CAL_FIELDS = ("b_f", "b_w", "s_f", "m_f", "s_w", "m_w", "n_w")  #: ImuCalibration fields, rows of ``cal_arr``
N_CAL = 3 * len(CAL_FIELDS)  #: length of the calibration at the start of ``fed``
#: rows of the scale factors, misalignments and non-orthogonality in ``cal_arr`` (:func:`calibration_into`)
_S_F, _M_F, _S_W, _M_W, _N_W = (CAL_FIELDS.index(k) for k in ("s_f", "m_f", "s_w", "m_w", "n_w"))
#: feedback operations: add 3 values, rotate a 3x3, add 1 value, add 3 values into the gyro's error
FB_ADD3, FB_ROTATE, FB_ADD1, FB_GYRO = 0, 1, 2, 3
_AFFINE = ("accel_scale", "accel_misalignment", "gyro_scale", "gyro_misalignment", "gyro_nonorthogonality")


def feedback_table(layout: StateLayout, n_cam: int, zeta_names: list) -> np.ndarray:
    """(k, 3) int64 rows ``(operation, offset in fed, first state index)`` of every estimated group
    beyond dx, dv, psi: the IMU error groups add into their calibration field, a camera
    misalignment rotates its mounting ``R_bc <- exp([psi_c x]) R_bc`` (003 eq. (50)), a zeta group
    adds into its estimate, a clock offset into the camera's offset, an edge height into the
    camera's height and the Gauss-Markov gyro error into ``gw_hat``, which the INS subtracts with
    the gyro bias (layout of ``fed`` as in the module docstring)."""
    o_cam, o_zeta = N_CAL, N_CAL + 9 * n_cam
    o_clk = o_zeta + 3 * len(zeta_names)
    o_edge = o_clk + n_cam
    rows = []
    for g in layout.groups:
        if not g.estimated or g.name in ("dx", "dv", "psi"):
            continue
        if g.name in GROUP_TO_FIELD:
            rows.append((FB_ADD3, 3 * CAL_FIELDS.index(GROUP_TO_FIELD[g.name]), g.slice.start))
        elif g.name.startswith("psi_c_"):
            rows.append((FB_ROTATE, o_cam + 9 * int(g.name[6:]), g.slice.start))
        elif g.name.startswith("zeta_"):
            rows.append((FB_ADD3, o_zeta + 3 * zeta_names.index(g.name), g.slice.start))
        elif g.name.startswith("dt_c_"):
            rows.append((FB_ADD1, o_clk + int(g.name[5:]), g.slice.start))
        elif g.name.startswith("h_e_"):
            rows.append((FB_ADD1, o_edge + int(g.name[4:]), g.slice.start))
        elif g.name == "gyro_gm":
            rows.append((FB_GYRO, o_edge + n_cam, g.slice.start))
    return np.array(rows, dtype=np.int64).reshape(-1, 3)


class FilterState:
    """Nominal state, covariance and fed-back estimates of a run (module docstring).

    Parameters
    ----------
    layout : StateLayout
    tuning : Tuning
    x_e, v_e, q_eb : initial nominal state.
    P : (n, n) initial covariance (owned: updated in place).
    R_bc : (cameras, 3, 3) nominal camera mountings.
    clk0 : (cameras,) camera clock offsets the stamps were corrected by [s].
    edge0 : (cameras,) initial Earth edge heights [m] (the mean of their Gauss-Markov process);
        default 0.
    """

    def __init__(self, layout: StateLayout, tuning: Tuning, x_e, v_e, q_eb, P: np.ndarray, R_bc: np.ndarray,
                 clk0: np.ndarray, edge0=None):
        self.layout, self.tuning, self.n = layout, tuning, layout.n
        self.est_mask = layout.estimated_mask
        self.P = P
        self.nav = np.empty(10)
        self.x, self.v, self.q = self.nav[0:3], self.nav[3:6], self.nav[6:10]
        self.x[:] = np.asarray(x_e, float)
        self.v[:] = np.asarray(v_e, float)
        self.q[:] = matrix_to_quat(quat_to_matrix(q_eb))
        n_cam = R_bc.shape[0]
        zeta_groups = [g for g in layout.groups if g.name.startswith("zeta_")]
        nz = len(zeta_groups)
        self.gyro_gm = gyro_gm_indices(layout)
        self.gyro_tau = gyro_gm_taus(tuning.gyro_gm_tau_s)
        #: (1 / tau, sigma^2) per Gauss-Markov gyro state (:meth:`_gyro_decay`)
        self.gyro_decay = (1.0 / self.gyro_tau, tuning.gyro_gm_sigmas() ** 2)
        #: (N + 1, 3) running sums of 1 / tau per IMU sample of a rate-following gyro error
        #: (:meth:`follow_rates`)
        self.gyro_rates = None
        self.fed = np.zeros(N_CAL + 9 * n_cam + 3 * nz + 2 * n_cam + self.gyro_gm.size)
        self.cal_arr = self.fed[:N_CAL].reshape(len(CAL_FIELDS), 3)
        self.R_bc = self.fed[N_CAL:N_CAL + 9 * n_cam].reshape(n_cam, 3, 3)
        self.R_bc[:] = R_bc
        self.zeta = self.fed[N_CAL + 9 * n_cam:N_CAL + 9 * n_cam + 3 * nz].reshape(nz, 3)
        o_clk = N_CAL + 9 * n_cam + 3 * nz
        self.clk_hat = self.fed[o_clk:o_clk + n_cam]
        self.clk0 = clk0
        self.edge_hat = self.fed[o_clk + n_cam:o_clk + 2 * n_cam]
        self.gw_hat = self.fed[o_clk + 2 * n_cam:]
        self.edge0 = np.zeros(n_cam) if edge0 is None else np.asarray(edge0, float).reshape(n_cam)
        self.edge_hat[:] = self.edge0
        self.edge_gm = edge_gm_indices(layout, tuning.edge_height_tau_s)
        self.edge_gm_cams = np.array([int(g.name[4:]) for g in layout.groups if g.name.startswith("h_e_")]
                                     if self.edge_gm.size else [], np.int64)
        ne = self.edge_gm.size
        self.edge_decay = (np.full(ne, 1.0 / tuning.edge_height_tau_s if ne else 0.0),
                           np.full(ne, tuning.edge_height.sigma ** 2))
        self.calibration = ImuCalibration(**{nm: self.cal_arr[i] for i, nm in enumerate(CAL_FIELDS)})
        self.zeta_index = {g.name: i for i, g in enumerate(zeta_groups)}
        self.P_c = np.tile(np.eye(3) * tuning.gm_default_sigma ** 2, (nz, 1, 1))
        self.last_seen = {}   #: zeta group -> time of its latest sighting [ns]
        self.fb = feedback_table(layout, n_cam, [g.name for g in zeta_groups])
        self.affine_estimated = any(g.estimated and g.name in _AFFINE for g in layout.groups)
        self.cal_m = np.empty((2, 4, 3))
        self._set_calibration(True)
        #: first index of every estimated camera misalignment (:meth:`reset_rotations`)
        self.rot_starts = np.array([g.slice.start for g in layout.groups
                                    if g.estimated and g.name.startswith("psi_c_")], np.int64)
        self.model = np.zeros(3 + self.n)
        self.model[:3] = (OMEGA_E, GM, tuning.correlation_time_s)
        self.model[3 + layout["dv"].start:3 + layout["dv"].stop] = tuning.accel_white ** 2
        self.model[3 + layout["psi"].start:3 + layout["psi"].stop] = tuning.gyro_white ** 2
        self.gm_idx = np.concatenate([transition_columns(layout),
                                      np.array([g.slice.start for g in zeta_groups], dtype=np.int64)])

    def _set_calibration(self, affine: bool) -> None:
        """Refresh ``cal_m`` from the calibration estimate (:func:`calibration_into`)."""
        calibration_into(self.fed, self.fb, self.cal_m, affine)

    def follow_rates(self, rates: np.ndarray) -> None:
        """Give the Gauss-Markov gyro error a correlation time per IMU sample: ``rates`` (N, 3)
        ``1 / tau`` [1/s] on the samples :meth:`propagate` indexes (the rounding of a rate
        output, :func:`nav.quantisation.quantisation_rates`)."""
        self.gyro_rates = cumulative_rates(rates)

    def propagate(self, ts, fw, traj, k: int, k_end: int, avg: bool, A_out, d_out) -> None:
        """The INS and the covariance from IMU sample k to k_end (:func:`propagate_block`)."""
        if self.gyro_rates is not None and self.gyro_gm.size:
            r = block_rates(self.gyro_rates, k, k_end)
            self.gyro_tau = 1.0 / r
            self.gyro_decay = (r, self.gyro_decay[1])
        propagate_block(self.nav, self.cal_m, ts, fw, traj, k, k_end, avg, self.model, self.gm_idx, self.P_c,
                        self.zeta, self.P, A_out, d_out, self.gyro_tau)
        if self.edge_gm.size:
            self._edge_decay(ts[k_end] - ts[k], d_out)
        if self.gyro_gm.size:
            self._gyro_decay(ts[k_end] - ts[k], d_out)

    def _gyro_decay(self, dt: float, d_out) -> None:
        """The Gauss-Markov gyro error over ``dt`` [s] (:func:`gm_decay_kernel`; its columns in the
        attitude rows are the kernel's); the fed-back estimate decays by phi and the INS applies it."""
        gm_decay_kernel(self.P, self.gyro_gm, dt, *self.gyro_decay, d_out)
        self.gw_hat *= d_out[self.gyro_gm]
        biases_into_calibration(self.fed, self.fb, self.cal_m)

    def _edge_decay(self, dt: float, d_out) -> None:
        """The Gauss-Markov edge heights over ``dt`` [s] (:func:`gm_decay_kernel`); the estimates relax
        towards their initial values."""
        gm_decay_kernel(self.P, self.edge_gm, dt, *self.edge_decay, d_out)
        cams = self.edge_gm_cams
        self.edge_hat[cams] = self.edge0[cams] + d_out[self.edge_gm] * (self.edge_hat[cams] - self.edge0[cams])

    def snapshot(self):
        """Copies of what an update changes: covariance, nominal state, fed-back estimates."""
        return self.P.copy(), self.nav.copy(), self.fed.copy()

    def restore(self, snap) -> None:
        """Back to a :meth:`snapshot` (in place: the views into ``nav`` and ``fed`` stay valid)."""
        self.P[:], self.nav[:], self.fed[:] = snap
        self._set_calibration(True)

    def reset_rotations(self, dx) -> None:
        """The covariance of the estimated camera misalignments after the feedback of ``dx`` (called
        after :func:`feedback_kernel`, ``nav`` holding the corrected attitude).

        The vectors measure the camera's attitude error, in b ``phi = R_eb^T psi + psi_c``
        (:func:`nav.measurements.vector_jacobians`), and leave its complement, the attitude /
        misalignment split, to the vehicle's turning. The feedback ``R_eb <- exp([d x]) R_eb``
        turns b's view of e: ``R_eb_new^T = exp(-[b x]) R_eb^T`` with ``b = R_eb^T d``.
        Transforming each estimated ``psi_c`` by ``G = exp(-[b x])`` carries what the vectors told
        about ``phi`` over to the new estimate exactly, ``R_eb_new^T psi + G psi_c = exp(-[b x])
        (R_eb^T psi + psi_c)``, and keeps the directions the vectors leave unobserved where they
        were. Without it a correction of degrees turns a well-known ``phi`` into a poorly known
        direction, and the filter reads the change as information about the split.

        ``psi`` is left as it is, and so is ``psi_c`` under its own correction ``d_c``. Composing
        the rotations exactly would map them by ``I + 1/2 [d x]`` and ``I + 1/2 [d_c x]``, which
        turn those unobserved directions by half of each correction; a first-order filter then
        gains the same spurious information about the split (the observability-constrained EKF's
        argument: Huang, Mourikis and Roumeliotis 2010, IEEE T-RO 26(5)). docs/tuning.md "A
        consistent start" gives the measured comparison. ``P <- G P G^T`` with ``G`` on each
        estimated ``psi_c``, I elsewhere."""
        reset_rotations_kernel(self.P, self.rot_starts, self.reset_rotation(dx))

    def reset_rotation(self, dx) -> np.ndarray:
        """``G = exp(-[b x])`` of :meth:`reset_rotations` for the correction ``dx`` (``nav``
        holding the corrected attitude): ``b = R_eb^T d``."""
        b = quat_to_R(self.nav[6:10]).T @ np.asarray(dx[self.layout["psi"]], float)
        return rotvec_to_R(-b)

    def reset_columns(self, H: np.ndarray, Rb: np.ndarray) -> None:
        """Rows ``H`` linearised about a state corrected by some ``dx`` re-expressed in the error
        coordinates before it, in place: each estimated ``psi_c``'s columns times ``Rb``, the map
        ``G`` of :meth:`reset_rotations` for that ``dx`` (``psi_c`` after = G ``psi_c`` before)."""
        for s in self.rot_starts:
            H[:, s:s + 3] = H[:, s:s + 3] @ Rb

    def attitude_sigma(self) -> float:
        """Largest per-axis 1-sigma of the attitude error psi [rad]."""
        i = self.layout["psi"].start
        return float(np.sqrt(np.max(np.diagonal(self.P)[i:i + 3])))

    def extrapolate(self, f, w, dt_m):
        """The state ``dt_m`` seconds after the current sample (:func:`extrapolate`)."""
        return extrapolate(self.nav, f, w, dt_m, OMEGA_E)


@nb.njit(cache=True)
def propagate_block(nav, cal_m, ts, fw, traj, k, k_end, avg, model, gm_idx, P_c, zeta, P, A_out, d_out, tau_w):
    """One covariance block from sample k to k_end: the INS (:func:`nav.ins.ins_kernel`; ``nav``
    updated in place, the states written into ``traj`` (N, 10) rows x, v, q), the block transition
    (:func:`nav.error_state.nav_transition` into ``A_out`` (9, n); ``d_out`` (n,) the diagonal of
    the other rows), the covariance propagation with white and Gauss-Markov process noise
    (:func:`nav.error_state.propagate_covariance`, P in place; 003 eqs. (41)-(45):
    ``P_zeta += (1 - phi^2) P_c``) and the decay of the zeta estimates. Packed arguments: module
    docstring; ``fw`` (N, 2, 3) the measured specific force and rate of each sample; ``tau_w``
    the correlation time of the Gauss-Markov gyro error (read only when it is in ``gm_idx``)."""
    x, q = nav[0:3], nav[6:10]
    stats = np.empty(6)
    ins.ins_kernel(nav, ts, fw, k, k_end, cal_m, traj, stats, avg)
    dt = ts[k_end] - ts[k]
    n = P.shape[0]
    A = nav_transition(x, quat_to_R(q), stats[:3].copy(), stats[3:].copy(), dt, gm_idx[:N_TRANSITION], n,
                       model[0], model[1], tau_w)
    phi = np.exp(-dt / model[2])
    for i in range(9):
        for j in range(n):
            A_out[i, j] = A[i, j]
    for i in range(n):
        d_out[i] = 1.0
    zeta_start = gm_idx[N_TRANSITION:]
    for g in range(zeta_start.size):
        for i in range(3):
            d_out[zeta_start[g] + i] = phi
    propagate_covariance(P, A_out, d_out, model[3:] * dt, zeta_start, P_c, 1.0 - phi * phi, np.empty((n, n)))
    for i in range(zeta.shape[0]):
        for j in range(3):
            zeta[i, j] *= phi


@nb.njit(cache=True)
def feedback_kernel(dx, nav, fed, fb):
    """Closed-loop correction of the nominal state with the estimated errors ``dx``, in place:
    ``x += dx``, ``v += dv``, ``R_eb <- exp([psi x]) R_eb`` (as a quaternion), then every row of
    the feedback table ``fb`` (:func:`feedback_table`) on ``fed``. Returns whether the IMU
    calibration (the first ``N_CAL`` values of ``fed``) changed."""
    for i in range(3):
        nav[i] += dx[i]
        nav[3 + i] += dx[3 + i]
    qn = R_to_quat(rotvec_to_R(dx[6:9].copy()) @ quat_to_R(nav[6:10]))
    for i in range(4):
        nav[6 + i] = qn[i]
    changed = False
    for r in range(fb.shape[0]):
        op, o, st = fb[r, 0], fb[r, 1], fb[r, 2]
        if op == FB_ADD3 or op == FB_GYRO:
            for i in range(3):
                fed[o + i] += dx[st + i]
            changed = changed or o < N_CAL or op == FB_GYRO
        elif op == FB_ROTATE:
            R = np.empty((3, 3))
            for i in range(3):
                for j in range(3):
                    R[i, j] = fed[o + 3 * i + j]
            Rn = rotvec_to_R(dx[st:st + 3].copy()) @ R
            for i in range(3):
                for j in range(3):
                    fed[o + 3 * i + j] = Rn[i, j]
        else:
            fed[o] += dx[st]
    return changed


@nb.njit(cache=True)
def gm_decay_kernel(P, idx, dt, rate, var, d_out):
    """First-order Gauss-Markov states ``idx`` over ``dt`` [s], each with its ``rate = 1 / tau``
    [1/s] and stationary variance ``var``: their rows of Phi are ``phi e_i``, ``phi = exp(-dt /
    tau)`` (the block's propagation left them at identity), so ``Phi P Phi^T`` is the block's
    result with those rows and columns scaled by phi (in place), plus the driving noise
    ``(1 - phi^2) var`` on the diagonal (the exact discrete form of the PSD ``2 var / tau``);
    ``d_out[idx] = phi``."""
    n = P.shape[0]
    for m in range(idx.size):
        i = idx[m]
        phi = np.exp(-dt * rate[m])
        for j in range(n):
            P[i, j] *= phi
            P[j, i] *= phi
        d_out[i] = phi
    for m in range(idx.size):
        i = idx[m]
        P[i, i] += (1.0 - d_out[i] * d_out[i]) * var[m]


@nb.njit(cache=True)
def calibration_into(fed, fb, cal_m, affine):
    """``cal_m`` from the fed-back estimates (``fed`` starts with the rows of :data:`CAL_FIELDS`):
    when ``affine``, the matrices A of :meth:`nav.imu_errors.ImuCalibration.matrices`
    (:func:`nav.imu_errors.affine_into`; otherwise A stays as it is, no scale factor or
    misalignment being estimated), and the biases (:func:`biases_into_calibration`)."""
    if affine:
        ca = fed[:N_CAL].reshape((N_CAL // 3, 3))
        affine_into(ca[_S_F], ca[_M_F], ca[_S_W], ca[_M_W], ca[_N_W], cal_m)
    biases_into_calibration(fed, fb, cal_m)


@nb.njit(cache=True)
def biases_into_calibration(fed, fb, cal_m):
    """Row 3 of ``cal_m`` from the fed-back estimates: ``b_f``, and ``b_w`` plus the Gauss-Markov
    gyro error where the feedback table ``fb`` has one (the INS subtracts both)."""
    for i in range(3):
        cal_m[0, 3, i] = fed[i]
        cal_m[1, 3, i] = fed[3 + i]
    for r in range(fb.shape[0]):
        if fb[r, 0] == FB_GYRO:
            for i in range(3):
                cal_m[1, 3, i] += fed[fb[r, 1] + i]


@nb.njit(cache=True)
def extrapolate(nav, f, w, dt_m, W):
    """The state at a measurement ``dt_m`` seconds after the current sample (``nav``: x, v, q
    there): position to second order, velocity to first order with gravity and Coriolis, attitude
    with the current rate (f, w: the IMU sample covering the interval, as measured). Returns
    ``(x_m, v_m, R_m, w_eb)``, ``w_eb`` the body rate against e (for the GPS lever arm)."""
    x, v = nav[0:3], nav[3:6]
    R_eb = quat_to_R(nav[6:10])
    w_eb = w - R_eb[2] * W
    if dt_m == 0.0:
        return x.copy(), v.copy(), R_eb, w_eb
    g0, g1, g2 = gravity(x[0], x[1], x[2])
    g = np.array([g0, g1, g2])
    cor = np.array([v[1], -v[0], 0.0])
    acc = R_eb @ f + g + (2 * W) * cor
    x_m = x + v * dt_m + (0.5 * acc) * dt_m ** 2
    v_m = v + acc * dt_m
    R_m = R_eb @ rotvec_to_R(w_eb * dt_m)
    return x_m, v_m, R_m, w_eb


@nb.njit(cache=True)
def reset_rotations_kernel(P, starts, G):
    """``P <- G P G^T`` in place for ``G`` (3, 3) on the 3-blocks at ``starts`` and I elsewhere
    (:meth:`FilterState.reset_rotations`): the block's columns, then its rows, then the mirror of
    the block's rows into its columns (symmetry kept exactly)."""
    n = P.shape[0]
    tmp = np.empty((n, 3))
    for b in range(starts.size):
        s = starts[b]
        for i in range(n):
            for j in range(3):
                tmp[i, j] = P[i, s] * G[j, 0] + P[i, s + 1] * G[j, 1] + P[i, s + 2] * G[j, 2]
        for i in range(n):
            for j in range(3):
                P[i, s + j] = tmp[i, j]
        for j in range(n):
            for i in range(3):
                tmp[j, i] = G[i, 0] * P[s, j] + G[i, 1] * P[s + 1, j] + G[i, 2] * P[s + 2, j]
        for j in range(n):
            for i in range(3):
                P[s + i, j] = tmp[j, i]
                P[j, s + i] = tmp[j, i]
