"""Measurement updates of the filter loop: the measurement protocol, GPS position and velocity,
camera vectors, and the gated stacked Schmidt update of one epoch.

The protocol
------------
A measurement source (:class:`GpsFixes`, :class:`CameraVectors`) wraps one input stream and
supplies, for its measurement ``j``:

* ``name`` (``"gps"``, ``"vec"``) and ``t_ns`` (N,), the stamps; ``stream_keys()``: the key of the
  stream each measurement belongs to (each stream must be time ordered; the filter rejects a
  measurement not later than its predecessor in the same stream);
* ``clock_shift(j, st)``: seconds subtracted from the time between the current IMU sample and the
  stamp (a camera clock offset estimate), 0 for GPS;
* ``fill(j, t_ns, at, st, stack)``: the candidate blocks of the measurement, appended to the
  epoch's :class:`EpochStack`: ``stack.reserve(m)`` gives the first of m rows (the source writes
  them whole) of the stacked Jacobian ``stack.H`` (m, n) and innovation ``stack.s``, and the
  diagonal block ``stack.R[o:o + m, o:o + m]`` of the noise (the source writes it whole; the rest
  of those rows of R is zero); ``stack.add(...)`` records each block with its kind, camera,
  dimension and input problem (a reason string, or None). ``at`` is
  ``(f, w, dt_m)``: the IMU sample covering the interval to the stamp and its length [s], from
  which ``st.extrapolate(*at)`` gives the state at the stamp (``x_m, v_m, R_m, w_eb``,
  :func:`nav.filter_state.extrapolate`; a kernel may do it itself, as :func:`gps_fill_kernel`);
  ``st`` is the :class:`nav.filter_state.FilterState` (layout, P, fed-back estimates).

The epoch (:meth:`EpochStack.apply`) then gates every block without an input problem on its own
NIS (its diagonal block of ``S = H P H^T + R`` with the prior P, chi-square gate of its dimension)
and applies the accepted ones in one Schmidt update in Joseph form
(:func:`nav.schmidt.update_kernel`), followed by the feedback. Stacking with a block-diagonal R
is the sequential update of the blocks in exact arithmetic.

Adding a measurement is one source class with these three methods (its rows usually from a
numba kernel like :func:`gps_rows_kernel` or the numpy observation equations of
:mod:`nav.measurements`), its tuning entry in :class:`nav.tuning.Tuning`, and the source added to
the list :func:`nav.navigator.run` builds.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numba as nb
import numpy as np

from nav.earth import OMEGA_E
from nav.ephemeris import moon_position_e, sun_position_e
from nav.filter_state import calibration_into, extrapolate, feedback_kernel
from nav.measurements import (predict_vector, second_order_noise, target_direction_e, vector_covariance_problem,
                              vector_covariance_problems, vector_jacobians, vector_rate)
from nav.rotation import tangent_basis
from nav.schmidt import GATED, NONFINITE, OK, REASONS, chi2_gate, update_kernel

log = logging.getLogger("nav.navigator")   # the run's logger: rejections are part of its report
#: the warning of one rejected measurement block (kind, stamp, reason, NIS): one per gated vector,
#: which a study's terminal filters out by this format (`scenarios.study.edge_mismatch.quiet_filter_log`)
REJECTED_MESSAGE = "%s measurement at %d ns rejected: %s (NIS %.3g)"

NS = 1_000_000_000


@dataclass
class Innovation:
    t_ns: int
    kind: str          #: "gps_pos", "gps_vel", "hor", "sun", "moon", "edge" (a camera's edge height)
    camera: int        #: -1 for GPS
    s: np.ndarray      #: innovation (tangent-plane 2-vector for camera vectors)
    S: np.ndarray      #: predicted innovation covariance
    nis: float
    accepted: bool
    reason: str | None


class EpochStack:
    """The candidate blocks of one epoch, stacked: Jacobian rows ``H`` (rows, n), innovations ``s``,
    noise ``R`` (rows, rows; block diagonal) and, per block, ``(t_ns, kind, camera, first row,
    dimension, problem)``; ``triad``: the horizon / Sun direction pairs of the epoch by stamp, for
    TRIAD."""

    def __init__(self, n: int, gate_probability: float):
        self.H = np.zeros((8, n))
        self.s = np.empty(8)
        self.R = np.zeros((8, 8))
        self.m = 0
        self.blocks = []
        self.triad = {}
        self._p = gate_probability
        self._gates = {}
        self._patterns = {}
        self._views = {}   #: rows -> the first rows of H, s and R (views, reused)
        self._dx = np.empty(n)   #: the correction of the latest update (the caller copies it)
        self.accepted = []       #: indices into ``blocks`` of the blocks the latest apply used

    def reset(self) -> None:
        self.m = 0
        self.blocks = []
        self.triad = {}

    def reserve(self, m: int) -> int:
        """First of ``m`` new rows of ``H``, ``s`` and ``R`` (the source writes them and the
        diagonal block of R whole); the noise between them and the earlier rows is zeroed."""
        o = self.m
        if o + m > self.s.size:
            cap = 2 * (o + m)
            H, s, R = np.zeros((cap, self.H.shape[1])), np.empty(cap), np.zeros((cap, cap))
            H[:o], s[:o], R[:o, :o] = self.H[:o], self.s[:o], self.R[:o, :o]
            self.H, self.s, self.R = H, s, R
            self._views = {}
        if o:
            self.R[o:o + m, :o] = 0.0
            self.R[:o, o:o + m] = 0.0
        self.m = o + m
        return o

    def add(self, t_ns: int, kind: str, camera: int, o: int, dim: int, problem) -> None:
        self.blocks.append((t_ns, kind, camera, o, dim, problem))

    def _view(self, m: int):
        v = self._views[m] = (self.H[:m], self.s[:m], self.R[:m, :m])
        return v

    def _pattern(self, sizes: tuple):
        """For a sequence of block sizes: row offsets (array and list), chi-square gates, and the
        update's work arrays (S, nis, code), reused."""
        pat = self._patterns.get(sizes)
        if pat is None:
            offs = np.zeros(len(sizes) + 1, dtype=np.int64)
            np.cumsum(sizes, out=offs[1:])
            for d in sizes:
                if d not in self._gates:
                    self._gates[d] = chi2_gate(d, self._p)
            m, nb_ = int(offs[-1]), len(sizes)
            pat = self._patterns[sizes] = (offs, offs.tolist(), np.array([self._gates[d] for d in sizes]),
                                           np.empty((m, m)), np.empty(nb_), np.empty(nb_, dtype=np.int64))
        return pat

    def apply(self, st, innovations: list, rejected, t_k: int) -> np.ndarray | None:
        """Gate the blocks, apply the accepted ones (P in place) and feed back: the correction
        ``dx`` when an update was applied, else None. Each block's innovation is appended to
        ``innovations``; rejections are counted in ``rejected`` and logged."""
        good = [b for b in self.blocks if b[5] is None]
        status, dx = GATED, None
        if good:
            status, dx, S_all, offs, code, nis_l = self._update(st, good)
        gi, s_all, append = 0, self.s, innovations.append
        self.accepted = []
        for bi, (t_m, kind, cam, o, dim, bad) in enumerate(self.blocks):
            nis, S = np.nan, None
            if bad is None:
                c, a, b = code[gi], offs[gi], offs[gi + 1]
                if c != NONFINITE:
                    S = S_all[a:b, a:b].copy()
                nis = nis_l[gi]
                if c != OK:
                    bad = REASONS[c]
                gi += 1
            if S is None:
                S = np.full((dim, dim), np.nan)
            append(Innovation(t_m, kind, cam, s_all[o:o + dim].copy(), S, nis, bad is None, bad))
            if bad is None:
                self.accepted.append(bi)
            else:
                rejected[f"{kind}_{bad}"] += 1
                log.warning(REJECTED_MESSAGE, kind, t_m, bad, nis)
        if status == OK:
            return dx
        if good and status != GATED:
            rejected[f"batch_{REASONS[int(status)]}"] += 1
            log.warning("update at %d ns rejected: %s", t_k, REASONS[int(status)])
        return None

    def relinearised(self, st, delta, Rb=None) -> np.ndarray | None:
        """One Gauss-Newton step of the iterated update (Bell & Cathey 1993): the blocks accepted
        by the latest :meth:`apply`, filled again about the current estimate ``x_i`` (rows ``H_i``,
        innovations ``s_i``), applied to the prior that ``st`` holds again with the innovation
        ``s_i + H_i delta``, ``delta`` the correction from the prior to ``x_i`` (error-state
        coordinates), without gating. With the misalignment reset (``Rb``, from
        :meth:`nav.filter_state.FilterState.reset_rotation` at ``x_i``) the rows are first taken
        back to the prior's coordinates of the camera misalignments
        (:meth:`~nav.filter_state.FilterState.reset_columns`), where the prior's covariance holds
        them. Returns the new correction from the prior, or None when the update fails
        (non-finite or S not positive definite)."""
        blocks = [self.blocks[i] for i in self.accepted]
        if not blocks:
            return None
        rows = np.concatenate([np.arange(b[3], b[3] + b[4]) for b in blocks])
        H, R = self.H[rows], self.R[np.ix_(rows, rows)]
        if Rb is not None:
            st.reset_columns(H, Rb)
        s = self.s[rows] + H @ delta
        offs = np.zeros(len(blocks) + 1, dtype=np.int64)
        np.cumsum([b[4] for b in blocks], out=offs[1:])
        m, nb_ = rows.size, len(blocks)
        dx = np.empty(st.n)
        status = update_feedback_kernel(st.P, H, R, s, st.est_mask, offs, np.zeros(nb_), np.empty((m, m)),
                                                 np.empty(nb_), np.empty(nb_, dtype=np.int64), dx, st.nav, st.fed,
                                                 st.fb, st.cal_m, st.affine_estimated)
        return dx if status == OK else None

    def _update(self, st, good):
        """:func:`update_feedback_kernel` on the blocks without input problems."""
        offs, offs_l, gates, S, nis, code = self._pattern(tuple([b[4] for b in good]))
        m = offs_l[-1]
        if m == self.m:
            H, s, R = self._views.get(m) or self._view(m)
        else:
            rows = np.concatenate([np.arange(b[3], b[3] + b[4]) for b in good])
            H, s, R = self.H[rows], self.s[rows], self.R[np.ix_(rows, rows)]
        dx = self._dx
        status = update_feedback_kernel(st.P, H, R, s, st.est_mask, offs, gates, S, nis, code, dx,
                                        st.nav, st.fed, st.fb, st.cal_m, st.affine_estimated)
        return status, dx, S, offs_l, code.tolist(), nis.tolist()


@nb.njit(cache=True)
def update_feedback_kernel(P, H, R, s, est, offs, gates, S, nis, code, dx, nav, fed, fb, cal_m, affine):
    """The gated stacked Schmidt update (:func:`nav.schmidt.update_kernel`, arguments as there)
    and, when it is applied, the feedback of ``dx`` (:func:`nav.filter_state.feedback_kernel`)
    with the INS calibration ``cal_m`` refreshed from the fed-back IMU errors when they changed
    (:func:`nav.filter_state.calibration_into`; its A matrices only when ``affine``: scale factors
    or misalignments estimated). Returns the status."""
    status = update_kernel(P, H, R, s, est, offs, gates, S, nis, code, dx)
    if status == OK and feedback_kernel(dx, nav, fed, fb):
        calibration_into(fed, fb, cal_m, affine)
    return status


class GpsFixes:
    """GPS antenna fixes: a position block ``"gps_pos"`` and, with velocities, a velocity block
    ``"gps_vel"`` per fix (3 rows each, :func:`gps_rows_kernel`; noise the fix's covariances).
    A fix whose velocity is NaN in all three components is a position-only fix (no velocity
    block), as is every fix of ``GpsData(v_e=None)``. Input problems: :func:`cov3_problems` of
    each block. ``noise_scale`` multiplies the 1-sigma of both covariances (``Tuning.gps_noise_scale``)."""
    name = "gps"

    def __init__(self, gps, lever_b, layout, noise_scale: float = 1.0):
        self.t_ns = np.asarray(gps.t_ns, dtype=np.int64)
        self.x = np.ascontiguousarray(gps.x_e, float)
        v = None if gps.v_e is None else np.ascontiguousarray(gps.v_e, float)
        self.with_v = (np.zeros(self.t_ns.size, bool) if v is None
                       else ~np.all(np.isnan(v.reshape(self.t_ns.size, 3)), axis=1))
        self.has_v = bool(self.with_v.any())
        self.v = v if self.has_v else self.x
        k2 = float(noise_scale) ** 2
        self.P_x = np.ascontiguousarray(gps.P_x, float) * k2
        self.P_v = np.ascontiguousarray(gps.P_v, float) * k2 if self.has_v else self.P_x
        self.bad_x = list(cov3_problems(self.x, self.P_x))
        self.bad_v = list(cov3_problems(self.v, self.P_v)) if self.has_v else None
        self.with_v_l = self.with_v.tolist()
        self.lever = np.asarray(lever_b, float)
        self.cols = np.array([layout["dx"].start, layout["dv"].start, layout["psi"].start], np.int64)

    def stream_keys(self):
        return [0] * self.t_ns.size

    def clock_shift(self, j: int, st) -> float:
        return 0.0

    def fill(self, j: int, t_m: int, at, st, stack: EpochStack) -> None:
        has_v = self.with_v_l[j]
        o = stack.reserve(6 if has_v else 3)
        f, w, dt_m = at
        gps_fill_kernel(st.nav, f, w, dt_m, self.lever, self.x, self.v, self.P_x, self.P_v, j, has_v,
                        self.cols, stack.H, stack.s, stack.R, o)
        stack.add(t_m, "gps_pos", -1, o, 3, self.bad_x[j])
        if has_v:
            stack.add(t_m, "gps_vel", -1, o + 3, 3, self.bad_v[j])


@nb.njit(cache=True)
def gps_fill_kernel(nav, f, w, dt_m, lever, X, V, P_x, P_v, j, has_v, cols, H, s, R, o):
    """:func:`nav.filter_state.extrapolate` to the time of fix ``j``, then :func:`gps_rows_kernel`
    into the rows ``o..o+m`` of ``H`` (zeroed first) and ``s``, and the fix's covariances
    ``P_x[j]``, ``P_v[j]`` into the diagonal blocks of ``R`` there (m = 6 with ``has_v``, else 3).
    ``X``, ``V``: the fixes' positions and velocities."""
    x_m, v_m, R_m, w_eb = extrapolate(nav, f, w, dt_m, OMEGA_E)
    m = 6 if has_v else 3
    Hm = H[o:o + m]
    Hm[:, :] = 0.0
    gps_rows_kernel(x_m, v_m, R_m, w_eb, lever, X[j], V[j], has_v, cols, Hm, s[o:o + m])
    for r in range(m):
        for c in range(m):
            R[o + r, o + c] = 0.0
    for r in range(3):
        for c in range(3):
            R[o + r, o + c] = P_x[j, r, c]
            if has_v:
                R[o + 3 + r, o + 3 + c] = P_v[j, r, c]


@nb.njit(cache=True)
def gps_rows_kernel(x_m, v_m, R_m, w_eb, lever, xg, vg, has_v, cols, H, s):
    """GPS antenna position (and velocity) innovations and Jacobians (:func:`nav.measurements.gps_position`,
    :func:`nav.measurements.gps_velocity`) written into ``s`` (3 or 6,) and the zero-initialised
    ``H`` (3 or 6, n); ``cols`` = first index of dx, dv, psi."""
    ix, iv, ip = cols[0], cols[1], cols[2]
    r = R_m @ lever
    for i in range(3):
        s[i] = xg[i] - (x_m[i] + r[i])
        H[i, ix + i] = 1.0
    _lever_rows(r, ip, 0, H)
    if has_v:
        wl = np.empty(3)
        wl[0] = w_eb[1] * lever[2] - w_eb[2] * lever[1]
        wl[1] = w_eb[2] * lever[0] - w_eb[0] * lever[2]
        wl[2] = w_eb[0] * lever[1] - w_eb[1] * lever[0]
        u = R_m @ wl
        for i in range(3):
            s[3 + i] = vg[i] - (v_m[i] + u[i])
            H[3 + i, iv + i] = 1.0
        _lever_rows(u, ip, 3, H)


@nb.njit(cache=True)
def _lever_rows(r, ip, row, H):
    """``-[r x]`` into the attitude columns ``ip..ip+2`` of rows ``row..row+2`` of H."""
    H[row, ip + 1] = r[2]; H[row, ip + 2] = -r[1]
    H[row + 1, ip + 0] = -r[2]; H[row + 1, ip + 2] = r[0]
    H[row + 2, ip + 0] = r[1]; H[row + 2, ip + 1] = -r[0]


class CameraVectors:
    """Camera direction vectors: one 2-row block per vector in the plane tangent to the predicted
    vector (:mod:`nav.measurements`; kind = the target, camera = its index), with the clock offset
    and Gauss-Markov columns where the layout has them. The noise is the target's white noise
    (:meth:`nav.tuning.Tuning.vector_white_for`) and the vision's P_c times the square of the
    camera's and target's covariance scale (:meth:`nav.tuning.Tuning.vector_cov_scale_for`). Input problems:
    unknown camera, target not modelled, non-finite vector,
    :func:`nav.measurements.vector_covariance_problem`."""
    name = "vec"

    def __init__(self, vec, layout, tuning, n_cam: int):
        self.t_ns = np.asarray(vec.t_ns, dtype=np.int64)
        self.camera = np.asarray(vec.camera).astype(np.int64).tolist()
        self.target = [str(g) for g in vec.target]
        self.e_c, self.P_c = vec.e_c, vec.P_c
        self.layout, self.tuning, self.n_cam = layout, tuning, n_cam
        self.white2 = {t: tuning.vector_white_for(t) ** 2 for t in set(self.target)}
        self.pc_scale2 = {(c, t): tuning.vector_cov_scale_for(t, c) ** 2 for c, t in set(zip(self.camera, self.target))}
        self.problems = vector_problems(vec)
        dedge, ref = getattr(vec, "dedge_c", None), getattr(vec, "edge_ref_m", None)
        self.edge = None
        if dedge is not None and ref is not None and any(layout.has(layout.edge_name(c)) for c in range(n_cam)):
            self.edge = (np.asarray(dedge, float).reshape(-1, 3), np.asarray(ref, float).reshape(-1))
        data, data_sd = getattr(vec, "edge_data_m", None), getattr(vec, "edge_data_sigma_m", None)
        self.edge_data = None
        if self.edge is not None and data is not None and data_sd is not None:
            self.edge_data = (np.asarray(data, float).reshape(-1), np.asarray(data_sd, float).reshape(-1))
        self.body_pos = {}
        tg = np.asarray(vec.target)
        for name, fn in (("sun", sun_position_e), ("moon", moon_position_e)):
            mask = tg == name
            if self.t_ns.size and mask.any():
                pos = np.full((self.t_ns.size, 3), np.nan)
                pos[mask] = fn(self.t_ns[mask])
                self.body_pos[name] = pos

    def stream_keys(self):
        return list(zip(self.camera, self.target))

    def clock_shift(self, j: int, st) -> float:
        c = self.camera[j]
        return st.clk_hat[c] if self.n_cam and 0 <= c < self.n_cam else 0.0

    def _problem(self, j: int):
        """``(e_c normalised, P_c, None)`` or ``(None, None, reason)``."""
        if not (0 <= self.camera[j] < self.n_cam):
            return None, None, "unknown camera"
        if self.target[j] not in self.layout.targets:
            return None, None, "target not modelled"
        e_c = np.asarray(self.e_c[j], float)
        P_c = np.asarray(self.P_c[j], float)
        nrm = np.linalg.norm(e_c) if np.all(np.isfinite(e_c)) else np.nan
        if not np.isfinite(nrm) or nrm == 0:
            return None, None, "non-finite vector"
        e_c = e_c / nrm
        bad = self.problems[j] if self.problems is not None else vector_covariance_problem(P_c, e_c)
        k2 = self.pc_scale2[(self.camera[j], self.target[j])]
        return e_c, (P_c * k2 if k2 != 1.0 else P_c), bad

    def fill(self, j: int, t_m: int, at, st, stack: EpochStack) -> None:
        cam, target = self.camera[j], self.target[j]
        o = stack.reserve(2)
        e_c, P_c, bad = self._problem(j)
        if bad:
            stack.H[o:o + 2] = 0.0
            stack.s[o:o + 2] = np.nan
            stack.R[o:o + 2, o:o + 2] = np.eye(2)
            stack.add(t_m, target, cam, o, 2, bad)
            return
        x_m, v_m, R_m, w_eb = st.extrapolate(*at)
        lay, n = self.layout, st.n
        R_bc = st.R_bc[cam]
        tpos = self.body_pos[target][j] if target in self.body_pos else None
        u_e = target_direction_e(target, x_m, tpos)
        zname = lay.zeta_name(cam, target)
        has_z = lay.has(zname)
        pred = predict_vector(u_e, R_m, R_bc)
        if has_z:
            pred = pred + st.zeta[st.zeta_index[zname]]
        edge = self._edge_column(j, cam, st) if self.edge is not None else None
        if edge is not None:
            pred = pred + edge[1]
        T = tangent_basis(pred)
        H_dx, H_psi, H_psic = vector_jacobians(target, x_m, u_e, R_m, R_bc, tpos)
        H3 = np.zeros((3, n))
        H3[:, lay["dx"]] = H_dx
        H3[:, lay["psi"]] = H_psi
        if lay.has(lay.cam_name(cam)):
            H3[:, lay[lay.cam_name(cam)]] = H_psic
        if lay.has(lay.clock_name(cam)):
            # the frame was taken at stamp - offset_true = t_est - dt_c: e_true = e(t_est) - de_c/dt dt_c
            H3[:, lay[lay.clock_name(cam)].start] = -vector_rate(target, x_m, v_m, u_e, R_m, R_bc, w_eb, tpos)
        if edge is not None:
            H3[:, edge[0]] = self.edge[0][j]
        R3 = self.white2[target] * np.eye(3)
        R2 = self._second_order(st, cam, u_e, R_m, R_bc, T) if self.tuning.second_order_noise else 0.0
        if has_z:
            H3[:, lay[zname]] = np.eye(3)
            self._restart_zeta(st, zname, t_m, P_c)
        else:
            R3 = R3 + 0.5 * (P_c + P_c.T)
        stack.triad.setdefault(t_m, {})[target] = (R_bc @ e_c, u_e)
        stack.H[o:o + 2] = T.T @ H3
        stack.s[o:o + 2] = T.T @ (e_c - pred)
        stack.R[o:o + 2, o:o + 2] = T.T @ R3 @ T + R2
        stack.add(t_m, target, cam, o, 2, None)
        if edge is not None and self.edge_data is not None:
            self._fill_height(j, t_m, cam, edge[0], st, stack)

    def _fill_height(self, j: int, t_m: int, cam: int, col: int, st, stack: EpochStack) -> None:
        """The arc's own edge height (``VectorData.edge_data_m``, 1-sigma ``edge_data_sigma_m``)
        as a measurement of the camera's ``h_e`` (state index ``col``): a 1-row block of kind
        ``"edge"``, independent of the direction given the height (the two factors of the arc's
        joint fit, `vision.edge_height.conditional_on_height`). None where the arc does not
        constrain the height (sigma not finite)."""
        h, sd = self.edge_data[0][j], self.edge_data[1][j]
        if not (np.isfinite(h) and np.isfinite(sd) and sd > 0):
            return
        o = stack.reserve(1)
        stack.H[o] = 0.0
        stack.H[o, col] = 1.0
        stack.s[o] = h - st.edge_hat[cam]
        stack.R[o, o] = sd * sd
        stack.add(t_m, "edge", cam, o, 1, None)

    def _second_order(self, st, cam: int, u_e, R_m, R_bc, T) -> np.ndarray:
        """The noise of the terms quadratic in psi and the camera's psi_c (when it is a state) with
        the prior covariance (:func:`nav.measurements.second_order_noise`), in the tangent plane."""
        lay = self.layout
        idx = list(range(lay["psi"].start, lay["psi"].stop))
        if lay.has(lay.cam_name(cam)):
            sl = lay[lay.cam_name(cam)]
            idx += list(range(sl.start, sl.stop))
        return second_order_noise(st.P[np.ix_(idx, idx)], u_e, R_m, R_bc, T)

    def _edge_column(self, j: int, cam: int, st):
        """``(state index of h_e, dedge_c (h_hat - edge_ref_m))`` for vector j, or None when the
        layout has no ``h_e`` for its camera or the vector no finite sensitivity."""
        name = self.layout.edge_name(cam)
        g, ref = self.edge[0][j], self.edge[1][j]
        if not self.layout.has(name) or not (np.all(np.isfinite(g)) and np.isfinite(ref)):
            return None
        return self.layout[name].start, g * (st.edge_hat[cam] - ref)

    def _restart_zeta(self, st, zname: str, t_m: int, P_c) -> None:
        """Quasi-stationary P_c of 003 eq. (44): a first (or stale, > 3 T_c) sighting restarts the
        Gauss-Markov process at this measurement's covariance (P in place, estimate zero); later
        ones set the driving noise (eq. (45)). A floor of (1e-6)^2 keeps P positive definite
        along the vector, where P_c is singular."""
        sl = self.layout[zname]
        i = st.zeta_index[zname]
        P_c_model = 0.5 * (P_c + P_c.T) + (1e-6) ** 2 * np.eye(3)
        if zname not in st.last_seen or (t_m - st.last_seen[zname]) > 3 * self.tuning.correlation_time_s * NS:
            st.P[sl, :] = 0.0
            st.P[:, sl] = 0.0
            st.P[sl, sl] = P_c_model
            st.zeta[i] = 0.0
        st.P_c[i] = P_c_model
        st.last_seen[zname] = t_m


def vector_problems(vec):
    """Covariance problems of every camera vector at once (:func:`nav.measurements.vector_covariance_problems`
    on the normalised vectors), or None when the arrays are not (N, 3, 3) / (N, 3) (then each
    vector is checked on its own)."""
    P_c = np.asarray(vec.P_c, float)
    e_c = np.asarray(vec.e_c, float)
    N = e_c.shape[0] if e_c.ndim else 0
    if N == 0 or P_c.shape != (N, 3, 3) or e_c.shape != (N, 3):
        return None
    with np.errstate(invalid="ignore", divide="ignore"):
        e = e_c / np.linalg.norm(e_c, axis=1, keepdims=True)
    return vector_covariance_problems(P_c, e)


def cov3_problems(z, R):
    """Per row, why a 3-vector ``z`` (N, 3) with covariance ``R`` (N, 3, 3) is unusable, or None:
    "non-finite", "non-symmetric covariance" (1e-9 relative), "covariance not positive definite"."""
    N = z.shape[0]
    out = np.full(N, None, dtype=object)
    if N == 0:
        return out
    fin = np.all(np.isfinite(z), axis=1) & np.all(np.isfinite(R), axis=(1, 2))
    out[~fin] = "non-finite"
    with np.errstate(invalid="ignore"):
        scale = np.maximum(np.max(np.abs(R), axis=(1, 2)), 1e-300)
        asym = fin & (np.max(np.abs(R - np.swapaxes(R, 1, 2)), axis=(1, 2)) > 1e-9 * scale)
    out[asym] = "non-symmetric covariance"
    ok = np.flatnonzero(fin & ~asym)
    if ok.size:
        U, inv = np.unique(R[ok].reshape(-1, 9), axis=0, return_inverse=True)
        U = U.reshape(-1, 3, 3)
        try:
            np.linalg.cholesky(U)
            pd = np.ones(len(U), bool)
        except np.linalg.LinAlgError:
            pd = np.array([_positive_definite(u) for u in U])
        out[ok[~pd[inv.reshape(-1)]]] = "covariance not positive definite"
    return out


def _positive_definite(R) -> bool:
    try:
        np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        return False
    return True
