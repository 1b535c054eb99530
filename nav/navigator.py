"""The navigation run: IMU samples and measurements through the INS and the Schmidt-Kalman filter
(003 §6, fig. 29), closed loop, with per-epoch outputs.

Processing
----------
* IMU samples are cleaned first (vectorised): samples whose time does not increase are dropped;
  non-finite and saturated samples (at or beyond the tuning's ranges) are replaced by the last good
  sample; gaps longer than ``tuning.max_imu_gap_s`` are counted (the INS integrates across them
  and the covariance grows with the gap). Each case is counted in ``NavResult.rejected`` and logged.
* The INS (:func:`nav.ins.ins_kernel`) runs over blocks of samples. A block ends at the sample
  at/just before the next measurement or after ``tuning.max_cov_interval_s`` (default 0.1 s: at
  most 10 covariance propagations per second; with 10 Hz GPS every GPS interval is one block).
  Over a block the transition is ``Phi = I + F dt + (F dt)^2/2`` with F evaluated once, with the
  block-mean calibrated specific force and rate and the attitude at the block's end
  (:func:`nav.error_state.error_dynamics`; the fast path is
  :class:`nav.error_state.TransitionBuilder`), and the white process noise is added as
  ``q dt``. Effect of this choice: in the coast (rates < 1 deg/s, |f| of a few mg) the
  attitude moves < 0.1 deg in a block, so F is constant to 2e-3 relative and the neglected
  third-order terms are ~1e-9 of the state; on the atek coast (20 Hz IMU, 10 Hz GPS, table 3
  tuning) 0.05 s instead of 0.1 s changed the final attitude sigma by 6e-6 relative and the RMS
  attitude error by 3e-5 relative, at twice the propagations. In spinning or powered flight
  (3.6 Hz spin: 130 deg per 0.1 s) R_eb varies inside a block and the bias / attitude couplings
  would be misrepresented: use an interval of a few ms there (the tuning's
  ``[filter] max_cov_interval_s``). The structure is exploited: only the 9 navigation rows of Phi
  are dense (a (9, n) block), constants have identity rows and the Gauss-Markov states diagonal
  ones (:class:`nav.error_state.BlockTransition`).
* A measurement stamped between two IMU samples is compared with the state at the preceding sample
  extrapolated to its time (position to second order, velocity first order, attitude with the
  current rate), so GPS at a time off the IMU grid does not see the vehicle's 1.8 km/s x 50 ms.
* Measurements in each stream must be time ordered; one that is not later than its predecessor in
  the same stream is rejected ("out_of_order"). GPS and vectors pass a chi-square gate
  (``tuning.gate_probability``); vectors with an unusable covariance are rejected with the reason
  from :func:`nav.measurements.vector_covariance_problem`.
* After every accepted update the estimated errors are fed back (position, velocity, attitude,
  the estimated IMU errors into the calibration, camera misalignments into the mountings, 003
  eq. (50), camera clock offsets into the stamp correction) and the error state is reset to zero.
* Camera clocks (issue 9, 003 §7.3): ``run(..., clock_offset_s=...)`` corrects each camera's
  stamps by its offset; with the tuning's ``camera_clock_offset`` state on, the filter refines the
  offsets (one constant state ``dt_c`` per camera) and reports them in ``NavResult.clock_offset``.

Speed (issue 7): the per-epoch work is in numba kernels without n x n temporaries: the INS block,
its transition and the covariance propagation in one call (:func:`_propagate_block`); the GPS
rows (:func:`gps_rows_kernel`); the gating of every candidate (its diagonal block of the stacked
``S = H P H^T + R`` with the prior P) and the Schmidt update of the accepted ones together
(:func:`nav.schmidt.update_kernel`, sparse in H); the feedback of x, v, q. GPS position and
velocity of one fix were already applied as one stacked 6-row update (same prior, block-diagonal
R: identical to sequential updates in exact arithmetic); an epoch with a lone GPS fix (90 % of
them at 10 Hz GPS) is one kernel call (:func:`_gps_epoch_kernel`: extrapolation, rows, gated update,
feedback), the others share :func:`_extrapolate` and :func:`_feedback_kernel` with it (bit-identical
to the per-step numpy version on the atek workload). Covariance checks of GPS fixes and camera
vectors are vectorised over the whole run, and the outputs and the smoother store are
preallocated arrays. On the atek 20 Hz replay workload the results agree with the previous
implementation to round-off (attitude 7e-15 rad, covariance diagonal 1.4e-14 relative).

Outputs (:class:`NavResult`): the solution at every IMU sample (post-correction at update epochs),
the covariance diagonal at every covariance epoch and the full covariance at measurement epochs,
the unaided INS from the same start, each measurement's innovation, S and NIS (accepted or not),
camera misalignment estimates with their sigma, TRIAD attitudes wherever a horizon and a Sun
vector share a time stamp, and the reject counts by reason.
"""
from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass

import numba as nb
import numpy as np

from nav import ins
from nav.earth import GM, OMEGA_E
from nav.ephemeris import moon_position_e, sun_position_e
from nav.error_state import (BlockTransition, StateLayout, TransitionBuilder, _nav_transition, build_layout,
                             propagate_covariance)
from nav.imu_errors import GROUP_TO_FIELD, ImuCalibration
from nav.measurements import (predict_vector,
                              tangent_basis, target_direction_e, vector_covariance_problem,
                              vector_covariance_problems,
                              vector_jacobians, vector_rate)
from nav.rotation import angle_between, matrix_to_quat, matrix_to_rotvec, quat_to_matrix, triad
from nav.schmidt import GATED, NONFINITE, OK, REASONS, chi2_gate, symmetrize, update_kernel
from nav.tuning import Tuning

log = logging.getLogger(__name__)

NS = 1_000_000_000


@dataclass
class ImuData:
    """IMU samples: time [int ns UTC], specific force f_b [m/s^2], angular rate omega_ib_b [rad/s].
    ``sample``: "average" (each sample is the mean over the interval ending at its time, as from
    increments / dt) or "point" (instantaneous values); see :func:`nav.ins.ins_kernel`."""
    t_ns: np.ndarray
    f_b: np.ndarray
    w_b: np.ndarray
    sample: str = "average"


@dataclass
class GpsData:
    """GPS fixes: antenna position and velocity in e with covariances (velocity may be None)."""
    t_ns: np.ndarray
    x_e: np.ndarray
    P_x: np.ndarray
    v_e: np.ndarray | None = None
    P_v: np.ndarray | None = None


@dataclass
class VectorData:
    """Camera direction vectors: camera index, target ("hor", "sun", "moon"), unit vector e_c in
    the camera frame and its covariance P_c (003 eq. (33))."""
    t_ns: np.ndarray
    camera: np.ndarray
    target: np.ndarray
    e_c: np.ndarray
    P_c: np.ndarray


@dataclass
class InitialState:
    t_ns: int
    x_e: np.ndarray
    v_e: np.ndarray
    q_eb: np.ndarray
    P0: np.ndarray | None = None  #: optional full initial covariance (layout order)


@dataclass
class Innovation:
    t_ns: int
    kind: str          #: "gps_pos", "gps_vel", "hor", "sun", "moon"
    camera: int        #: -1 for GPS
    s: np.ndarray      #: innovation (tangent-plane 2-vector for camera vectors)
    S: np.ndarray      #: predicted innovation covariance
    nis: float
    accepted: bool
    reason: str | None


@dataclass
class SmootherStore:
    """What the RTS smoother needs, per covariance epoch k (k = 0 is the start), as arrays. The
    posterior covariance at an update epoch is not copied: it is row ``post[k]`` of
    ``NavResult.P_full``."""
    idx: np.ndarray       #: (K,) IMU sample index of the epoch
    A: np.ndarray         #: (K, 9, n) navigation rows of the transition from k-1 to k (k = 0: unused)
    d: np.ndarray         #: (K, n) diagonal of the other rows of that transition
    P_prior: np.ndarray   #: (K, n, n) covariance after the propagation to k (k = 0: the initial one)
    post: np.ndarray      #: (K,) row of NavResult.P_full with the posterior at k; -1: no update (= P_prior)
    dx: np.ndarray        #: (K, n) correction fed back at the epoch (zero where none)

    def transition(self, k: int) -> BlockTransition:
        """The transition from epoch k-1 to k (k >= 1)."""
        return BlockTransition(self.A[k], self.d[k])


@dataclass
class NavResult:
    layout: StateLayout
    t_ns: np.ndarray          #: IMU sample times (after cleaning)
    x_e: np.ndarray
    v_e: np.ndarray
    q_eb: np.ndarray
    cov_t_ns: np.ndarray      #: covariance epochs
    cov_idx: np.ndarray       #: IMU sample index of each covariance epoch
    P_diag: np.ndarray        #: (K, n) covariance diagonal at each epoch (after any update)
    meas_t_ns: np.ndarray     #: epochs with at least one accepted update
    P_full: np.ndarray        #: (M, n, n) full covariance after the updates at meas_t_ns
    unaided_x_e: np.ndarray
    unaided_v_e: np.ndarray
    unaided_q_eb: np.ndarray
    innovations: list
    misalignment_t_ns: np.ndarray
    misalignment: np.ndarray  #: (M, n_cam, 3) accumulated psi_c estimate (b-frame rotation vector)
    misalignment_sigma: np.ndarray
    triad_t_ns: np.ndarray
    triad_q_eb: np.ndarray
    rejected: dict
    calibration: ImuCalibration
    R_bc: np.ndarray          #: final mounting estimates
    store: SmootherStore | None
    #: (M, n_cam) camera clock offset in use at misalignment_t_ns [s] (camera clock minus IMU time:
    #: the initial ``clock_offset_s`` plus the filter's estimate when the dt_c state is modelled)
    clock_offset: np.ndarray | None = None
    #: (M, n_cam) its 1-sigma [s] (0 where the offset is not a filter state)
    clock_offset_sigma: np.ndarray | None = None

    def nis(self, kind: str) -> np.ndarray:
        return np.array([i.nis for i in self.innovations if i.kind == kind and i.accepted])


def _clean_imu(imu: ImuData, tuning: Tuning, rejected: Counter):
    t = np.asarray(imu.t_ns, dtype=np.int64)
    f = np.array(imu.f_b, dtype=float)
    w = np.array(imu.w_b, dtype=float)
    if t.ndim != 1 or f.shape != (t.size, 3) or w.shape != (t.size, 3):
        raise ValueError(f"imu: expected t_ns (N,), f_b and w_b (N, 3); got {t.shape}, {f.shape}, {w.shape}")
    # drop samples whose time is not later than the running maximum
    keep = np.ones(t.size, bool)
    if t.size > 1:
        runmax = np.maximum.accumulate(t)
        keep[1:] = t[1:] > runmax[:-1]
    if (~keep).sum():
        rejected["imu_time_not_increasing"] += int((~keep).sum())
        log.warning("IMU: %d samples dropped whose time stamp does not increase", (~keep).sum())
    t, f, w = t[keep], f[keep], w[keep]
    bad_nf = ~(np.all(np.isfinite(f), axis=1) & np.all(np.isfinite(w), axis=1))
    with np.errstate(invalid="ignore"):
        bad_sat = ~bad_nf & ((np.max(np.abs(w), axis=1) >= tuning.gyro_range)
                             | (np.max(np.abs(f), axis=1) >= tuning.accel_range))
    for name, m in (("imu_nonfinite", bad_nf), ("imu_saturated", bad_sat)):
        if m.any():
            rejected[name] += int(m.sum())
            log.warning("IMU: %d %s samples replaced by the last good sample", m.sum(), name[4:])
    bad = bad_nf | bad_sat
    if bad.any():
        good_idx = np.where(~bad, np.arange(t.size), -1)
        good_idx = np.maximum.accumulate(good_idx)
        first_good = np.flatnonzero(~bad)
        if first_good.size == 0:
            raise ValueError("imu: no finite, unsaturated sample")
        good_idx[good_idx < 0] = first_good[0]
        f, w = f[good_idx], w[good_idx]
    gaps = np.diff(t) > tuning.max_imu_gap_s * NS
    if gaps.any():
        rejected["imu_time_gap"] += int(gaps.sum())
        log.warning("IMU: %d time gaps longer than %.3g s", gaps.sum(), tuning.max_imu_gap_s)
    return t, np.ascontiguousarray(f), np.ascontiguousarray(w)


def _events(gps: GpsData | None, vec: VectorData | None, rejected: Counter):
    """Time-ordered list of (t_ns, kind, index). A stream is GPS, or one (camera, target) pair of
    the vectors; a sample not later than its predecessor in the same stream is rejected."""
    ev = []
    for kind, data in (("gps", gps), ("vec", vec)):
        if data is None:
            continue
        t = np.asarray(data.t_ns, dtype=np.int64)
        keys = (np.zeros(t.size, int) if kind == "gps"
                else [(int(c), str(g)) for c, g in zip(data.camera, data.target)])
        last = {}
        for i, ti in enumerate(t):
            key = keys[i]
            if key in last and ti <= last[key]:
                rejected[f"{kind}_out_of_order"] += 1
                log.warning("%s measurement %d at %d ns is not later than its predecessor: rejected", kind, i, ti)
                continue
            last[key] = ti
            ev.append((int(ti), 0 if kind == "gps" else 1, i))
    ev.sort()
    return ev


def run(imu: ImuData, init: InitialState, tuning: Tuning, *, gps: GpsData | None = None,
        vectors: VectorData | None = None, R_bc=(), lever_b=(0.0, 0.0, 0.0),
        store_for_smoother: bool = True, unaided: bool = True, clock_offset_s=None,
        clock_offset_sigma_s=None) -> NavResult:
    """Run the integrated navigation from ``init.t_ns`` to the last IMU sample.

    Parameters
    ----------
    imu : ImuData
    init : InitialState
        Initial x_e, v_e, q_eb (e.g. GPS and :func:`nav.initialise.triad_initialise`).
    tuning : Tuning
    gps, vectors : optional measurement streams.
    R_bc : sequence of (3, 3)
        Nominal camera mountings, one per camera index used in ``vectors``.
    lever_b : (3,)
        GPS antenna position in b relative to the IMU [m].
    store_for_smoother : bool
        Keep what :func:`nav.smoother.rts_smooth` needs (:class:`SmootherStore`: the prior
        covariance, the (9, n) transition rows and the fed-back correction per covariance epoch,
        about 20 KB per epoch for 45 states; posteriors are shared with ``P_full``).
    clock_offset_s : sequence of float, optional
        Per camera, the offset of its clock against the IMU time base [s] (a frame taken at IMU
        time t is stamped t + offset; e.g. from :func:`nav.clock_offset.estimate_camera_offsets`).
        Vector stamps are corrected by it before anything else. With the tuning's
        ``camera_clock_offset`` state on, the filter refines it: the state ``dt_c`` (true minus
        estimated offset) enters every vector of that camera through ``H = -de_c/dt``
        (:func:`nav.measurements.vector_rate`) and its estimate is fed back into the stamp
        correction (later vectors are predicted at ``stamp - offset``).
    clock_offset_sigma_s : sequence of float, optional
        Per camera, the initial 1-sigma of the offset [s] (e.g. the estimate's ``sigma_s``);
        default the tuning's ``camera_clock_offset`` sigma.
    """
    rejected: Counter = Counter()
    t_all, f_all, w_all = _clean_imu(imu, tuning, rejected)
    i_start = int(np.searchsorted(t_all, init.t_ns, side="left"))
    if i_start >= t_all.size - 1:
        raise ValueError("init.t_ns: the start time is at or after the last IMU sample")
    t_ns = t_all[i_start:]
    f_b, w_b = f_all[i_start:], w_all[i_start:]
    if t_ns[0] != init.t_ns:
        raise ValueError(f"init.t_ns: must coincide with an IMU sample time (nearest is {t_ns[0]})")
    N = t_ns.size
    ts = (t_ns - t_ns[0]).astype(np.float64) / NS
    R_bc_nom = [np.asarray(R, float) for R in R_bc]
    n_cam = len(R_bc_nom)
    R_bc_est = [R.copy() for R in R_bc_nom]
    layout = build_layout(tuning, n_cam)
    n = layout.n
    est_mask = layout.estimated_mask
    P = layout.initial_covariance() if init.P0 is None else symmetrize(np.asarray(init.P0, float))
    if P.shape != (n, n):
        raise ValueError(f"init.P0: expected ({n}, {n}) for this layout, got {P.shape}")
    clk0 = np.zeros(n_cam) if clock_offset_s is None else np.asarray(clock_offset_s, float).reshape(-1)
    if clk0.shape != (n_cam,) or not np.all(np.isfinite(clk0)):
        raise ValueError(f"clock_offset_s: expected {n_cam} finite offsets [s] (one per camera), got {clock_offset_s!r}")
    clk_names = [layout.clock_name(c) if layout.has(layout.clock_name(c)) else None for c in range(n_cam)]
    if clock_offset_sigma_s is not None:
        sig0 = np.asarray(clock_offset_sigma_s, float).reshape(-1)
        if sig0.shape != (n_cam,) or not np.all(np.isfinite(sig0)) or np.any(sig0 <= 0):
            raise ValueError(f"clock_offset_sigma_s: expected {n_cam} positive sigmas [s], got {clock_offset_sigma_s!r}")
        for c, nm in enumerate(clk_names):
            if nm is not None and init.P0 is None:
                P[layout[nm], layout[nm]] = sig0[c] ** 2
    clk_hat = np.zeros(n_cam)   # filter estimate of the offset beyond clk0 (fed back)
    if vectors is not None and np.any(clk0 != 0):
        cam_idx = np.asarray(vectors.camera)
        known = (cam_idx >= 0) & (cam_idx < n_cam)
        shift = np.zeros(cam_idx.size, dtype=np.int64)
        shift[known] = np.round(clk0[cam_idx[known].astype(int)] * NS).astype(np.int64)
        vectors = VectorData(np.asarray(vectors.t_ns, dtype=np.int64) - shift, vectors.camera, vectors.target,
                             vectors.e_c, vectors.P_c)
    tc = tuning.correlation_time_s
    zeta_groups = [g for g in layout.groups if g.name.startswith("zeta_")]
    nz = len(zeta_groups)
    zeta_start = np.array([g.slice.start for g in zeta_groups], dtype=np.int64)
    # latest P_c and the fed-back estimate of every zeta group: one array each, a view per group
    P_c_arr = np.tile(np.eye(3) * tuning.gm_default_sigma ** 2, (nz, 1, 1))
    zeta_arr = np.zeros((nz, 3))
    P_c_latest = {g.name: P_c_arr[i] for i, g in enumerate(zeta_groups)}
    zeta_hat = {g.name: zeta_arr[i] for i, g in enumerate(zeta_groups)}
    last_seen = {}
    lever = np.asarray(lever_b, float)

    events = _events(gps, vectors, rejected)
    # measurements outside the run
    kept = []
    for e in events:
        if e[0] < t_ns[0]:
            rejected["before_start"] += 1
        elif e[0] > t_ns[-1]:
            rejected["after_end"] += 1
        else:
            kept.append(e)
    events = kept
    ev_t = np.array([e[0] for e in events], dtype=np.int64)
    ev_idx = np.searchsorted(t_ns, ev_t, side="right") - 1  # sample at or before the measurement
    gps_bad = _gps_problems(gps) if gps is not None else None
    vec_bad = _vector_problems(vectors) if vectors is not None else None
    gps_R6 = None
    if gps is not None and gps.v_e is not None and len(gps.t_ns):
        # block-diagonal noise of the stacked position + velocity update, every fix at once
        gps_R6 = np.zeros((len(gps.t_ns), 6, 6))
        gps_R6[:, :3, :3] = np.asarray(gps.P_x, float)
        gps_R6[:, 3:, 3:] = np.asarray(gps.P_v, float)

    # Sun / Moon positions for all vector measurements at once
    body_pos = {}
    if vectors is not None and len(vectors.t_ns):
        vt = np.asarray(vectors.t_ns, dtype=np.int64)
        tg = np.asarray(vectors.target)
        for name, fn in (("sun", sun_position_e), ("moon", moon_position_e)):
            m = tg == name
            if m.any():
                pos = np.full((vt.size, 3), np.nan)
                pos[m] = fn(vt[m])
                body_pos[name] = pos

    # calibration fields and camera mountings: rows of one array each (views), corrected in place
    # by the feedback kernel
    cal_arr = np.zeros((len(_CAL_FIELDS), 3))
    cal = ImuCalibration(**{nm: cal_arr[i] for i, nm in enumerate(_CAL_FIELDS)})
    R_bc_arr = np.array(R_bc_est, float).reshape(n_cam, 3, 3)
    R_bc_est = list(R_bc_arr)
    X = np.empty((N, 3)); V = np.empty((N, 3)); Q = np.empty((N, 4))
    x = np.asarray(init.x_e, float).copy(); v = np.asarray(init.v_e, float).copy()
    q = matrix_to_quat(quat_to_matrix(init.q_eb)).copy()
    stats = np.empty(6)
    max_block = max(1, int(round(tuning.max_cov_interval_s / max(np.median(np.diff(ts)), 1e-9))))
    qa2, qg2 = tuning.accel_white ** 2, tuning.gyro_white ** 2
    iv, ip = layout["dv"], layout["psi"]
    builder = TransitionBuilder(layout, tc)
    Qd_rate = np.zeros(n)
    Qd_rate[iv] = qa2
    Qd_rate[ip] = qg2
    gate2 = chi2_gate(2, tuning.gate_probability)
    gate3 = chi2_gate(3, tuning.gate_probability)
    offs_gps, gates_gps = np.array([0, 3, 6], dtype=np.int64), np.array([gate3, gate3])
    fb_idx = _feedback_arrays(_feedback_plan(layout), [g.name for g in zeta_groups])
    affine_estimated = any(g.estimated and g.name in ("accel_scale", "accel_misalignment", "gyro_scale",
                                                     "gyro_misalignment") for g in layout.groups)
    gps_H = (layout["dx"].start, layout["dv"].start, layout["psi"].start)
    work = np.empty((n, n))
    A_blk, d_blk = np.empty((9, n)), np.empty(n)   # the block transition when nothing is stored

    # Output buffers sized by an upper bound (np.empty: pages never written are never committed):
    # covariance epochs <= 1 (start) + full-length blocks + blocks ending at a measurement sample
    # + the last block; update epochs <= distinct measurement samples.
    n_ev_idx = int(np.unique(ev_idx).size)
    K_max = 2 + (N - 1) // max_block + n_ev_idx
    M_max = max(n_ev_idx, 1)
    cov_idx = np.empty(K_max, dtype=np.int64)
    P_diag = np.empty((K_max, n))
    P_full = np.empty((M_max, n, n))
    meas_t = np.empty(M_max, dtype=np.int64)
    R_bc_hist = np.empty((M_max, n_cam, 3, 3))
    clk_t = np.empty((M_max, n_cam))
    kc = 0   # covariance epochs so far
    mc = 0   # update epochs so far
    tri_t, tri_in = [], []
    innovations = []
    if store_for_smoother:
        st_A = np.empty((K_max, 9, n)); st_d = np.empty((K_max, n))
        st_P = np.empty((K_max, n, n)); st_post = np.full(K_max, -1, dtype=np.int64)
        st_dx = np.zeros((K_max, n))
        st_A[0] = 0.0; st_d[0] = 1.0
    cov_idx[0] = 0
    P_diag[0] = P.diagonal()
    if store_for_smoother:
        st_P[0] = P
    kc = 1

    A_f, b_f, A_w, b_w = cal.matrices()
    if imu.sample not in ("point", "average"):
        raise ValueError(f"imu.sample: expected 'point' or 'average', got {imu.sample!r}")
    avg = imu.sample == "average"
    # per-event lookups as Python scalars / preconverted arrays (the loop runs once per event)
    n_events = len(events)
    ev_idx_l = ev_idx.tolist()
    t_l = t_ns.tolist()
    vec_cam_l = np.asarray(vectors.camera).astype(np.int64).tolist() if vectors is not None else []
    gps_has_v = gps is not None and gps.v_e is not None
    gps_m = 6 if gps_has_v else 3
    gps_H = np.asarray(gps_H, np.int64)
    if gps is not None:
        gps_x = np.ascontiguousarray(gps.x_e, float)
        gps_Px = np.asarray(gps.P_x, float)
        gps_v = np.ascontiguousarray(gps.v_e, float) if gps_has_v else gps_x
        gps_Pv = np.asarray(gps.P_v, float) if gps_has_v else None
        gps_bad_l = [list(b) for b in gps_bad]
    gps_fast = gps_R6 is not None
    nis2, code2, upd_dx = np.empty(2), np.empty(2, dtype=np.int64), np.empty(n)
    k = 0
    e_ptr = 0
    X[0] = x; V[0] = v; Q[0] = q
    while True:
        # measurements at the current sample: each is checked and gated on its own (its NIS with
        # the prior P), then all accepted ones are applied in one Schmidt update
        updated = False
        group_vecs = {}
        cands = []
        ej = events[e_ptr][2] if e_ptr < n_events else -1
        if (gps_fast and e_ptr < n_events and ev_idx_l[e_ptr] == k and events[e_ptr][1] == 0
                and (e_ptr + 1 == n_events or ev_idx_l[e_ptr + 1] != k)
                and gps_bad_l[0][ej] is None and gps_bad_l[1][ej] is None):
            # the common epoch, a lone GPS fix (position and velocity, usable covariances): the
            # extrapolation, rows, gated update and feedback in one kernel call; the same
            # operations as the general path below (stacked update, identical results)
            t_m = events[e_ptr][0]
            e_ptr += 1
            kk = min(k + 1, N - 1) if avg else k
            s6 = np.empty(6)
            S6 = np.empty((6, 6))
            status, changed = _gps_epoch_kernel(
                x, v, q, f_b[kk], w_b[kk], (t_m - t_l[k]) / NS, OMEGA_E, lever, gps_x[ej], gps_v[ej], gps_H,
                P, gps_R6[ej], est_mask, offs_gps, gates_gps, s6, S6, nis2, code2, upd_dx,
                cal_arr, R_bc_arr, zeta_arr, clk_hat, *fb_idx)
            for b, (kind, o0) in enumerate((("gps_pos", 0), ("gps_vel", 3))):
                c_b = int(code2[b])
                nis = float(nis2[b])
                S = S6[o0:o0 + 3, o0:o0 + 3].copy() if c_b != NONFINITE else np.full((3, 3), np.nan)
                bad = None if c_b == OK else REASONS[c_b]
                innovations.append(Innovation(t_m, kind, -1, s6[o0:o0 + 3], S, nis, bad is None, bad))
                if bad is not None:
                    rejected[f"{kind}_{bad}"] += 1
                    log.warning("%s measurement at %d ns rejected: %s (NIS %.3g)", kind, t_m, bad, nis)
            if status == OK:
                updated = True
                if changed:
                    if affine_estimated:
                        A_f, b_f, A_w, b_w = cal.matrices()
                    else:  # only biases estimated: A stays the identity
                        b_f, b_w = cal.b_f.copy(), cal.b_w.copy()
            elif status != GATED:
                rejected[f"batch_{REASONS[int(status)]}"] += 1
                log.warning("update at %d ns rejected: %s", t_l[k], REASONS[int(status)])
        else:
            while e_ptr < n_events and ev_idx_l[e_ptr] == k:
                t_m, kind, j = events[e_ptr]
                dt_m = (t_m - t_l[k]) / NS
                if kind == 1 and clk_names and 0 <= vec_cam_l[j] < n_cam:
                    dt_m -= clk_hat[vec_cam_l[j]]
                e_ptr += 1
                kk = min(k + 1, N - 1) if avg else k  # the sample covering (t_k, t_m]
                x_m, v_m, R_m, w_eb = _extrapolate(x, v, q, f_b[kk], w_b[kk], dt_m, OMEGA_E)
                if kind == 0:
                    H6 = np.zeros((gps_m, n))
                    s6 = np.empty(gps_m)
                    gps_rows_kernel(x_m, v_m, R_m, w_eb, lever, gps_x[j], gps_v[j], gps_has_v, gps_H, H6, s6)
                    new_c = [("gps_pos", -1, H6[:3], gps_Px[j], s6[:3], gps_bad_l[0][j])]
                    if gps_has_v:
                        new_c.append(("gps_vel", -1, H6[3:], gps_Pv[j], s6[3:], gps_bad_l[1][j]))
                    gps_stack = (H6, s6, j)
                else:
                    new_c, P = _vector_rows(vectors, j, x_m, R_m, R_bc_est, layout, P, body_pos, P_c_latest,
                                            last_seen, zeta_hat, tuning, t_m, group_vecs, v_m, w_eb, vec_bad)
                cands.extend((t_m,) + c for c in new_c)
            if cands:
                good = [c for c in cands if c[6] is None]
                if len(good) == 2 and len(cands) == 2 and cands[0][1] == "gps_pos" and cands[1][1] == "gps_vel":
                    # the common epoch: one GPS fix, position and velocity (stacked when built)
                    H_all, s_all, R_all = gps_stack[0], gps_stack[1], gps_R6[gps_stack[2]]
                    offs, gates = offs_gps, gates_gps
                    m = 6
                elif good:
                    sizes = [c[5].size for c in good]
                    offs = np.zeros(len(good) + 1, dtype=np.int64)
                    np.cumsum(sizes, out=offs[1:])
                    m = int(offs[-1])
                    H_all = np.vstack([c[3] for c in good]) if len(good) > 1 else good[0][3]
                    s_all = np.concatenate([c[5] for c in good]) if len(good) > 1 else good[0][5]
                    R_all = np.zeros((m, m))
                    for i, c in enumerate(good):
                        R_all[offs[i]:offs[i + 1], offs[i]:offs[i + 1]] = c[4]
                    gates = np.array([gate3 if d == 3 else gate2 for d in sizes])
                if good:
                    S_all = np.empty((m, m)); nis_all = np.empty(len(good))
                    code = np.empty(len(good), dtype=np.int64); upd_dx = np.empty(n)
                    status = update_kernel(P, np.ascontiguousarray(H_all), R_all, np.ascontiguousarray(s_all, float),
                                           est_mask, offs, gates, S_all, nis_all, code, upd_dx)
                gi = 0
                if good:
                    offs_l, code_l, nis_l = offs.tolist(), code.tolist(), nis_all.tolist()
                for t_m, kind, cam, H, R, s_, bad in cands:
                    nis = np.nan
                    S = None
                    if bad is None:
                        o0, o1 = offs_l[gi], offs_l[gi + 1]
                        if code_l[gi] != NONFINITE:
                            S = S_all[o0:o1, o0:o1].copy()
                        nis = nis_l[gi]
                        if code_l[gi] != OK:
                            bad = REASONS[code_l[gi]]
                        gi += 1
                    if S is None:
                        S = np.full(R.shape, np.nan)
                    innovations.append(Innovation(t_m, kind, cam, s_, S, nis, bad is None, bad))
                    if bad is not None:
                        rejected[f"{kind}_{bad}"] += 1
                        log.warning("%s measurement at %d ns rejected: %s (NIS %.3g)", kind, t_m, bad, nis)
                if good and status == OK:
                    updated = True
                    changed = _feedback_kernel(upd_dx, x, v, q, cal_arr, R_bc_arr, zeta_arr, clk_hat, *fb_idx)
                    if changed:
                        if affine_estimated:
                            A_f, b_f, A_w, b_w = cal.matrices()
                        else:  # only biases estimated: A stays the identity
                            b_f, b_w = cal.b_f.copy(), cal.b_w.copy()
                elif good and status != GATED:
                    rejected[f"batch_{REASONS[int(status)]}"] += 1
                    log.warning("update at %d ns rejected: %s", t_ns[k], REASONS[int(status)])
        for tm, vecs in group_vecs.items():
            if "hor" in vecs and "sun" in vecs:
                tri_t.append(tm)
                tri_in.append((vecs["hor"][0], vecs["sun"][0], vecs["hor"][1], vecs["sun"][1]))
        if updated:
            X[k] = x; V[k] = v; Q[k] = q
            P_diag[kc - 1] = P.diagonal()
            meas_t[mc] = t_l[k]
            P_full[mc] = P
            if n_cam:
                R_bc_hist[mc] = R_bc_arr
                clk_t[mc] = clk0 + clk_hat
            if store_for_smoother:
                st_post[kc - 1] = mc
                st_dx[kc - 1] = upd_dx
            mc += 1
        if k >= N - 1:
            break
        # next block
        k_end = min(k + max_block, N - 1)
        if e_ptr < n_events:
            k_end = min(k_end, max(ev_idx_l[e_ptr], k + 1))
        if store_for_smoother:
            A_blk, d_blk = st_A[kc], st_d[kc]
        _propagate_block(x, v, q, ts, f_b, w_b, k, k_end, A_f, b_f, A_w, b_w, X, V, Q, stats, avg,
                         builder.cols, OMEGA_E, GM, builder.zeta, tc, Qd_rate, zeta_start, P_c_arr, zeta_arr,
                         P, work, A_blk, d_blk)
        k = k_end
        cov_idx[kc] = k
        P_diag[kc] = P.diagonal()
        if store_for_smoother:
            st_P[kc] = P
        kc += 1

    if unaided:
        UX, UV, UQ = ins.propagate(init.x_e, init.v_e, init.q_eb, ts, f_b, w_b, sample=imu.sample)
    else:
        UX = UV = UQ = np.empty((0, 3))
    for reason, cnt in sorted(rejected.items()):
        log.info("rejected %s: %d", reason, cnt)
    cov_idx = cov_idx[:kc]
    P_full = P_full[:mc]
    store = None
    if store_for_smoother:
        store = SmootherStore(cov_idx, st_A[:kc], st_d[:kc], st_P[:kc], st_post[:kc], st_dx[:kc])
    tri_q = np.empty((0, 4))
    if tri_in:
        a = [np.array([r[i] for r in tri_in]) for i in range(4)]
        # pairs closer than 1 deg to parallel are left out (TRIAD is ill-conditioned there)
        ang = angle_between(a[0], a[1])
        ok = np.minimum(ang, np.pi - ang) > np.radians(1.0)
        tri_t = np.array(tri_t, dtype=np.int64)[ok]
        tri_q = matrix_to_quat(triad(*(x[ok] for x in a))) if ok.any() else tri_q
    # camera misalignment estimates, their sigma and the clock offsets at the update epochs (only
    # where there are cameras, as before)
    mc_cam = mc if n_cam else 0
    mis = (matrix_to_rotvec(R_bc_hist[:mc_cam] @ np.swapaxes(np.array(R_bc_nom, float), -1, -2)[None])
           if mc_cam else np.zeros((0, n_cam, 3)))
    mis_sig = np.zeros((mc_cam, n_cam, 3))
    clk_sig = np.zeros((mc_cam, n_cam))
    for c in range(n_cam):
        if layout.has(f"psi_c_{c}"):
            sl = layout[f"psi_c_{c}"]
            mis_sig[:, c] = np.sqrt(np.diagonal(P_full[:mc_cam, sl, sl], axis1=1, axis2=2))
        if clk_names[c] is not None:
            i_c = layout[clk_names[c]].start
            clk_sig[:, c] = np.sqrt(P_full[:mc_cam, i_c, i_c])
    return NavResult(
        layout=layout, t_ns=t_ns, x_e=X, v_e=V, q_eb=Q, cov_t_ns=t_ns[cov_idx], cov_idx=cov_idx,
        P_diag=P_diag[:kc], meas_t_ns=meas_t[:mc], P_full=P_full,
        unaided_x_e=UX, unaided_v_e=UV, unaided_q_eb=UQ,
        innovations=innovations, misalignment_t_ns=meas_t[:mc_cam].copy(),
        misalignment=mis.reshape(mc_cam, n_cam, 3), misalignment_sigma=mis_sig,
        triad_t_ns=np.array(tri_t, dtype=np.int64), triad_q_eb=np.array(tri_q).reshape(-1, 4),
        rejected=dict(rejected), calibration=cal, R_bc=np.array(R_bc_est, float).reshape(n_cam, 3, 3), store=store,
        clock_offset=clk_t[:mc_cam].copy(), clock_offset_sigma=clk_sig)


def _feedback_plan(layout):
    """(kind, slice, extra) of every estimated group beyond dx, dv, psi that :func:`_feedback`
    corrects: "imu" (ImuCalibration field name), "cam" (camera index), "zeta" (group name),
    "clk" (camera index)."""
    plan = []
    for g in layout.groups:
        if not g.estimated or g.name in ("dx", "dv", "psi"):
            continue
        if g.name in GROUP_TO_FIELD:
            plan.append(("imu", g.slice, GROUP_TO_FIELD[g.name]))
        elif g.name.startswith("psi_c_"):
            plan.append(("cam", g.slice, int(g.name[6:])))
        elif g.name.startswith("zeta_"):
            plan.append(("zeta", g.slice, g.name))
        elif g.name.startswith("dt_c_"):
            plan.append(("clk", g.slice, int(g.name[5:])))
    return plan


@nb.njit(cache=True)
def _propagate_block(x, v, q, ts, f_b, w_b, k, k_end, A_f, b_f, A_w, b_w, X, V, Q, stats, avg,
                     cols, W, GM, zeta_mask, tc, Qd_rate, zeta_start, P_c_arr, zeta_arr, P, work, A_out, d_out):
    """One covariance block from sample k to k_end in one call: the INS (:func:`nav.ins.ins_kernel`,
    x, v, q updated in place), the block transition (:class:`nav.error_state.TransitionBuilder`,
    written into ``A_out`` (9, n) and ``d_out`` (n,)), the covariance propagation with white and
    Gauss-Markov process noise (:func:`nav.error_state.propagate_covariance`, P in place; 003
    eqs. (41)-(45): ``P_zeta += (1 - phi^2) P_c``) and the decay of the zeta estimates."""
    ins.ins_kernel(x, v, q, ts, f_b, w_b, k, k_end, A_f, b_f, A_w, b_w, X, V, Q, stats, avg)
    dt = ts[k_end] - ts[k]
    n = P.shape[0]
    A = _nav_transition(x, ins.quat_to_R(q), stats[:3].copy(), stats[3:].copy(), dt, cols, n, W, GM)
    phi = np.exp(-dt / tc)
    for i in range(9):
        for j in range(n):
            A_out[i, j] = A[i, j]
    for i in range(n):
        d_out[i] = phi if zeta_mask[i] else 1.0
    propagate_covariance(P, A_out, d_out, Qd_rate * dt, zeta_start, P_c_arr, 1.0 - phi * phi, work)
    for i in range(zeta_arr.shape[0]):
        for j in range(3):
            zeta_arr[i, j] *= phi


@nb.njit(cache=True)
def _feedback_nav(x, v, q, dx):
    """In place: ``x += dx``, ``v += dv``, ``R_eb <- exp([psi x]) R_eb`` (as a quaternion)."""
    for i in range(3):
        x[i] += dx[i]
        v[i] += dx[3 + i]
    qn = ins.R_to_quat(ins.rotvec_to_R(dx[6:9].copy()) @ ins.quat_to_R(q))
    for i in range(4):
        q[i] = qn[i]


_CAL_FIELDS = ("b_f", "b_w", "s_f", "m_f", "s_w", "m_w")  #: ImuCalibration fields, rows of the feedback's array


def _feedback_arrays(plan, zeta_names):
    """:func:`_feedback_plan` as the index arrays of :func:`_feedback_kernel`: (k, 2) int64 rows
    ``(target row, first state index)`` for the IMU-error groups (row in ``_CAL_FIELDS``), camera
    misalignments (camera), zeta groups (row in ``zeta_names``) and clock offsets (camera)."""
    rows = {"imu": [], "cam": [], "zeta": [], "clk": []}
    for kind, sl, extra in plan:
        r = (_CAL_FIELDS.index(extra) if kind == "imu" else zeta_names.index(extra) if kind == "zeta" else int(extra))
        rows[kind].append((r, sl.start))
    return tuple(np.array(rows[k], dtype=np.int64).reshape(-1, 2) for k in ("imu", "cam", "zeta", "clk"))


@nb.njit(cache=True)
def _feedback_kernel(dx, x, v, q, cal_arr, R_bc_arr, zeta_arr, clk_hat, fb_imu, fb_cam, fb_zeta, fb_clk):
    """Closed-loop correction of the nominal state with the estimated errors ``dx``, in place:
    x, v, q (:func:`_feedback_nav`), the IMU calibration (``cal_arr`` rows += dx), the camera
    mountings ``R_bc <- exp([psi_c x]) R_bc`` (003 eq. (50)), the Gauss-Markov estimates and the
    camera clock offsets (stamp correction: t = stamp - offset); index arrays from
    :func:`_feedback_arrays`. Returns whether the IMU calibration changed."""
    _feedback_nav(x, v, q, dx)
    for r in range(fb_imu.shape[0]):
        row, st = fb_imu[r, 0], fb_imu[r, 1]
        for i in range(3):
            cal_arr[row, i] += dx[st + i]
    for r in range(fb_cam.shape[0]):
        c, st = fb_cam[r, 0], fb_cam[r, 1]
        Rn = ins.rotvec_to_R(dx[st:st + 3].copy()) @ R_bc_arr[c]
        for i in range(3):
            for j in range(3):
                R_bc_arr[c, i, j] = Rn[i, j]
    for r in range(fb_zeta.shape[0]):
        row, st = fb_zeta[r, 0], fb_zeta[r, 1]
        for i in range(3):
            zeta_arr[row, i] += dx[st + i]
    for r in range(fb_clk.shape[0]):
        clk_hat[fb_clk[r, 0]] += dx[fb_clk[r, 1]]
    return fb_imu.shape[0] > 0


@nb.njit(cache=True)
def _extrapolate(x, v, q, f, w, dt_m, W):
    """The state at a measurement ``dt_m`` seconds after the current sample (x, v, q there):
    position to second order, velocity to first order with gravity and Coriolis, attitude with the
    current rate (f, w: the IMU sample covering the interval, as measured). Returns
    ``(x_m, v_m, R_m, w_eb)``, ``w_eb`` the body rate against e (for the GPS lever arm)."""
    R_eb = ins.quat_to_R(q)
    w_eb = w - R_eb[2] * W
    if dt_m == 0.0:
        return x.copy(), v.copy(), R_eb, w_eb
    g0, g1, g2 = ins._gravity(x[0], x[1], x[2])
    g = np.array([g0, g1, g2])
    cor = np.array([v[1], -v[0], 0.0])
    acc = R_eb @ f + g + (2 * W) * cor
    x_m = x + v * dt_m + (0.5 * acc) * dt_m ** 2
    v_m = v + acc * dt_m
    R_m = R_eb @ ins.rotvec_to_R(w_eb * dt_m)
    return x_m, v_m, R_m, w_eb


@nb.njit(cache=True)
def _gps_epoch_kernel(x, v, q, f, w, dt_m, W, lever, xg, vg, cols, P, R6, est, offs, gates, s, S, nis, code, dx,
                      cal_arr, R_bc_arr, zeta_arr, clk_hat, fb_imu, fb_cam, fb_zeta, fb_clk):
    """A lone GPS fix at the current sample in one call: :func:`_extrapolate` to its time,
    :func:`gps_rows_kernel` (position and velocity rows), the gated stacked Schmidt update
    (:func:`nav.schmidt.update_kernel`, P in place; ``s``, ``S``, ``nis``, ``code``, ``dx`` out)
    and, if applied, :func:`_feedback_kernel`. Returns ``(status, calibration changed)``."""
    x_m, v_m, R_m, w_eb = _extrapolate(x, v, q, f, w, dt_m, W)
    H = np.zeros((6, P.shape[0]))
    gps_rows_kernel(x_m, v_m, R_m, w_eb, lever, xg, vg, True, cols, H, s)
    status = update_kernel(P, H, R6, s, est, offs, gates, S, nis, code, dx)
    changed = False
    if status == OK:
        changed = _feedback_kernel(dx, x, v, q, cal_arr, R_bc_arr, zeta_arr, clk_hat, fb_imu, fb_cam, fb_zeta, fb_clk)
    return status, changed


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
    # -[r x]
    H[0, ip + 1] = r[2]; H[0, ip + 2] = -r[1]
    H[1, ip + 0] = -r[2]; H[1, ip + 2] = r[0]
    H[2, ip + 0] = r[1]; H[2, ip + 1] = -r[0]
    if has_v:
        wl = np.empty(3)
        wl[0] = w_eb[1] * lever[2] - w_eb[2] * lever[1]
        wl[1] = w_eb[2] * lever[0] - w_eb[0] * lever[2]
        wl[2] = w_eb[0] * lever[1] - w_eb[1] * lever[0]
        u = R_m @ wl
        for i in range(3):
            s[3 + i] = vg[i] - (v_m[i] + u[i])
            H[3 + i, iv + i] = 1.0
        H[3, ip + 1] = u[2]; H[3, ip + 2] = -u[1]
        H[4, ip + 0] = -u[2]; H[4, ip + 2] = u[0]
        H[5, ip + 0] = u[1]; H[5, ip + 1] = -u[0]


def _vector_problems(vec):
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


def _gps_problems(gps):
    """Per fix, why its position (and velocity) with covariance is unusable, or None
    (vectorised form of :func:`_cov3_problem`): ``(pos_reasons, vel_reasons)``."""
    out = [_cov3_problems(np.asarray(gps.x_e, float), np.asarray(gps.P_x, float))]
    if gps.v_e is not None:
        out.append(_cov3_problems(np.asarray(gps.v_e, float), np.asarray(gps.P_v, float)))
    return out


def _cov3_problems(z, R):
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
            pd = np.array([_cov3_problem(np.zeros(3), u) is None for u in U])
        out[ok[~pd[inv.reshape(-1)]]] = "covariance not positive definite"
    return out


_COV_OK: dict = {}


def _cov3_problem(z, R):
    key = R.tobytes()
    if key in _COV_OK:  # the same covariance was checked before (GPS repeats it every fix)
        return None if np.all(np.isfinite(z)) else "non-finite"
    if not (np.all(np.isfinite(z)) and np.all(np.isfinite(R))):
        return "non-finite"
    if np.max(np.abs(R - R.T)) > 1e-9 * max(np.max(np.abs(R)), 1e-300):
        return "non-symmetric covariance"
    try:
        np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        return "covariance not positive definite"
    if len(_COV_OK) < 1000:
        _COV_OK[key] = True
    return None


def _vector_rows(vec, j, x_m, R_m, R_bc_est, layout, P, body_pos, P_c_latest, last_seen, zeta_hat,
                 tuning, t_m, group_vecs, v_m=None, w_eb=None, vec_bad=None):
    """Candidate 2-row tangent-plane measurement of one camera vector, and P (with the
    Gauss-Markov block restarted at a first or stale sighting). ``vec_bad``: the covariance
    problems of all vectors, precomputed (:func:`_vector_problems`), or None."""
    cam = int(vec.camera[j])
    target = str(vec.target[j])
    n = layout.n
    nan = (np.full((2, n), np.nan), np.eye(2), np.full(2, np.nan))
    if not (0 <= cam < len(R_bc_est)):
        return [(target, cam) + nan + ("unknown camera",)], P
    if target not in layout.targets:
        return [(target, cam) + nan + ("target not modelled",)], P
    e_c = np.asarray(vec.e_c[j], float)
    P_c = np.asarray(vec.P_c[j], float)
    nrm = np.linalg.norm(e_c) if np.all(np.isfinite(e_c)) else np.nan
    if not np.isfinite(nrm) or nrm == 0:
        return [(target, cam) + nan + ("non-finite vector",)], P
    e_c = e_c / nrm
    bad = vec_bad[j] if vec_bad is not None else vector_covariance_problem(P_c, e_c)
    if bad:
        return [(target, cam) + nan + (bad,)], P
    P_c = 0.5 * (P_c + P_c.T)
    R_bc = R_bc_est[cam]
    tpos = body_pos[target][j] if target in body_pos else None
    u_e = target_direction_e(target, x_m, tpos)
    zname = layout.zeta_name(cam, target)
    has_z = layout.has(zname)
    pred = predict_vector(u_e, R_m, R_bc)
    if has_z:
        pred = pred + zeta_hat[zname]
    T = tangent_basis(pred)
    H_dx, H_psi, H_psic = vector_jacobians(target, x_m, u_e, R_m, R_bc, tpos)
    H3 = np.zeros((3, n))
    H3[:, layout["dx"]] = H_dx
    H3[:, layout["psi"]] = H_psi
    cname = layout.cam_name(cam)
    if layout.has(cname):
        H3[:, layout[cname]] = H_psic
    tname = layout.clock_name(cam)
    if layout.has(tname):
        # the frame was taken at stamp - offset_true = t_est - dt_c: e_true = e(t_est) - de_c/dt dt_c
        H3[:, layout[tname].start] = -vector_rate(target, x_m, v_m, u_e, R_m, R_bc, w_eb, tpos)
    R3 = tuning.vector_white ** 2 * np.eye(3)
    if has_z:
        sl = layout[zname]
        H3[:, sl] = np.eye(3)
        # quasi-stationary P_c of 003 eq. (44): a first (or stale, > 3 T_c) sighting restarts the
        # process at this measurement's covariance; later ones set the driving noise (eq. (45)).
        # A floor of (1e-6)^2 keeps P positive definite along the vector, where P_c is singular.
        P_c_model = P_c + (1e-6) ** 2 * np.eye(3)
        if zname not in last_seen or (t_m - last_seen[zname]) > 3 * tuning.correlation_time_s * NS:
            P = P.copy()
            P[sl, :] = 0.0
            P[:, sl] = 0.0
            P[sl, sl] = P_c_model
            zeta_hat[zname][:] = 0.0
        P_c_latest[zname][:] = P_c_model
        last_seen[zname] = t_m
    else:
        R3 = R3 + P_c
    group_vecs.setdefault(t_m, {})[target] = (R_bc @ e_c, u_e)
    return [(target, cam, T.T @ H3, T.T @ R3 @ T, T.T @ (e_c - pred), None)], P
