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
  (:func:`nav.error_state.error_dynamics`; the compiled form is
  :func:`nav.error_state.nav_transition`), and the white process noise is added as ``q dt``.
  Effect of this choice: in the coast (rates < 1 deg/s, |f| of a few mg) the attitude moves
  < 0.1 deg in a block, so F is constant to 2e-3 relative and the neglected third-order terms are
  ~1e-9 of the state; on the atek coast (20 Hz IMU, 10 Hz GPS, table 3 tuning) halving the
  interval changes the final attitude sigma by 6e-6 relative and the RMS attitude error by 3e-5
  relative. In spinning or powered flight (3.6 Hz spin: 130 deg per 0.1 s) R_eb varies inside a
  block and the bias / attitude couplings would be misrepresented: use an interval of a few ms
  there (``Tuning.max_cov_interval_s``). The structure is exploited: only the 9 navigation rows
  of Phi are dense (a (9, n) block), constants have identity rows and the Gauss-Markov states
  diagonal ones (:class:`nav.error_state.BlockTransition`).
* A measurement stamped between two IMU samples is compared with the state at the preceding sample
  extrapolated to its time (position to second order, velocity first order, attitude with the
  current rate), so GPS at a time off the IMU grid does not see the vehicle's 1.8 km/s x 50 ms.
* Measurements in each stream must be time ordered; one that is not later than its predecessor in
  the same stream is rejected ("out_of_order"). At each epoch the measurements are checked, gated
  on their own NIS (``tuning.gate_probability``) and the accepted ones applied in one stacked
  Schmidt update (:mod:`nav.updates`, which documents the measurement protocol and how to add a
  measurement).
* After every accepted update the estimated errors are fed back (position, velocity, attitude,
  the estimated IMU errors into the calibration, camera misalignments into the mountings, 003
  eq. (50), camera clock offsets into the stamp correction) and the error state is reset to zero
  (:class:`nav.filter_state.FilterState`, which documents how to add a state).
* Camera clocks (003 §7.3): ``run(..., clock_offset_s=...)`` corrects each camera's stamps by its
  offset; with the tuning's ``camera_clock_offset`` state on, the filter refines the offsets (one
  constant state ``dt_c`` per camera) and reports them in ``NavResult.clock_offset``.

Structure: :func:`run` builds the :class:`nav.filter_state.FilterState`, the measurement sources
and the output buffers, then steps from epoch to epoch: the measurements at the current IMU sample
(:func:`_measure`), then the propagation to the next epoch (one numba kernel for the INS block, its
transition and the covariance, :func:`nav.filter_state.propagate_block`). The per-epoch work is in
numba kernels without n x n temporaries; the covariance checks of GPS fixes and camera vectors are
vectorised over the whole run, and the outputs and the smoother store are preallocated arrays.

Outputs (:class:`NavResult`): the solution at every IMU sample (post-correction at update epochs),
the covariance diagonal at every covariance epoch and the full covariance at measurement epochs,
the unaided INS from the same start, each measurement's innovation, S and NIS (accepted or not),
camera misalignment estimates with their sigma, TRIAD attitudes wherever a horizon and a Sun
vector share a time stamp, and the reject counts by reason.
"""
from __future__ import annotations

import dataclasses

import logging
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from nav import ins
from nav.error_state import BlockTransition, StateLayout, build_layout
from nav.filter_state import FilterState
from nav.imu_errors import ImuCalibration
from nav.quantisation import quantisation_rates
from nav.recovery import MisalignmentReopening, Recovery
from nav.rotation import angle_between, matrix_to_quat, matrix_to_rotvec, triad
from nav.schmidt import symmetrize
from nav.tuning import Tuning
from nav.updates import CameraVectors, EpochStack, GpsFixes, Innovation

__all__ = ["ImuData", "GpsData", "VectorData", "InitialState", "Innovation", "SmootherStore", "NavResult", "run"]

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
    the camera frame and its covariance P_c (003 eq. (33)).

    Optionally, for horizon vectors fitted at an Earth edge height: ``edge_ref_m`` (N,) that
    height [m] and ``dedge_c`` (N, 3) the vector's sensitivity to the true edge height, ``d e_c /
    d h_e`` [1/m] (NaN where unknown): the vector measures ``e_true + dedge_c (h_e - edge_ref_m)``,
    the filter's ``h_e`` state (``Tuning.edge_height``) takes it from there, and ``P_c`` must then
    be the covariance given the height (not the height's uncertainty). With them,
    ``edge_data_m`` (N,) the arc's own edge height [m] and ``edge_data_sigma_m`` (N,) its 1-sigma
    (inf or NaN: none) measure ``h_e`` directly (`vision.edge_height.conditional_on_height`);
    ``edge_ref_sigma_m`` (N,) the 1-sigma of ``edge_ref_m`` the vision had (the covariance without
    the state is ``P_c + edge_ref_sigma_m^2 dedge_c dedge_c^T``; logs keep it)."""
    t_ns: np.ndarray
    camera: np.ndarray
    target: np.ndarray
    e_c: np.ndarray
    P_c: np.ndarray
    dedge_c: np.ndarray | None = None
    edge_ref_m: np.ndarray | None = None
    edge_data_m: np.ndarray | None = None
    edge_data_sigma_m: np.ndarray | None = None
    edge_ref_sigma_m: np.ndarray | None = None


@dataclass
class InitialState:
    t_ns: int
    x_e: np.ndarray
    v_e: np.ndarray
    q_eb: np.ndarray
    P0: np.ndarray | None = None  #: optional full initial covariance (layout order)


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
    #: recoveries (:mod:`nav.recovery`), ``(t_ns, reason, details)``: re-initialisations from GPS
    #: after an IMU gap or a divergence (reason ``"imu_gap"``, ``"divergence"``) and re-opened
    #: camera misalignments (``"camera_gated"``, details ``camera`` the camera index)
    recoveries: list = field(default_factory=list)
    #: (K, n) at each covariance epoch, the fed-back estimate of every estimated state beyond dx,
    #: dv, psi in the layout's coordinates (:func:`estimates_from_fed`); 0 for the navigation and
    #: the considered states
    estimates: np.ndarray | None = None
    #: (K, 9, 9) the covariance of dx, dv, psi at each covariance epoch (after any update): the
    #: full navigation block, where ``P_diag`` keeps only the diagonal between updates
    P_nav: np.ndarray | None = None

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


def _events(sources, rejected: Counter):
    """Time-ordered list of (t_ns, source index, measurement index). A measurement not later than
    its predecessor in the same stream (:meth:`stream_keys` of its source) is rejected."""
    ev = []
    for si, src in enumerate(sources):
        keys = src.stream_keys()
        last = {}
        for i, ti in enumerate(src.t_ns.tolist()):
            key = keys[i]
            if key in last and ti <= last[key]:
                rejected[f"{src.name}_out_of_order"] += 1
                log.warning("%s measurement %d at %d ns is not later than its predecessor: rejected", src.name, i, ti)
                continue
            last[key] = ti
            ev.append((ti, si, i))
    ev.sort()
    return ev


def _within(events, t_ns, rejected: Counter):
    """The events inside the run, and the IMU sample at or before each."""
    kept = []
    for e in events:
        if e[0] < t_ns[0]:
            rejected["before_start"] += 1
        elif e[0] > t_ns[-1]:
            rejected["after_end"] += 1
        else:
            kept.append(e)
    ev_t = np.array([e[0] for e in kept], dtype=np.int64)
    return kept, np.searchsorted(t_ns, ev_t, side="right") - 1


def _initial_covariance(layout: StateLayout, init: InitialState, n_cam: int, clock_offset_s, clock_offset_sigma_s):
    """P0 (``init.P0`` or the layout's, with the clock offset sigmas) and the clock offsets."""
    n = layout.n
    P = layout.initial_covariance() if init.P0 is None else symmetrize(np.asarray(init.P0, float))
    if P.shape != (n, n):
        raise ValueError(f"init.P0: expected ({n}, {n}) for this layout, got {P.shape}")
    clk0 = np.zeros(n_cam) if clock_offset_s is None else np.asarray(clock_offset_s, float).reshape(-1)
    if clk0.shape != (n_cam,) or not np.all(np.isfinite(clk0)):
        raise ValueError(f"clock_offset_s: expected {n_cam} finite offsets [s] (one per camera), "
                         f"got {clock_offset_s!r}")
    if clock_offset_sigma_s is not None:
        sig0 = np.asarray(clock_offset_sigma_s, float).reshape(-1)
        if sig0.shape != (n_cam,) or not np.all(np.isfinite(sig0)) or np.any(sig0 <= 0):
            raise ValueError(f"clock_offset_sigma_s: expected {n_cam} positive sigmas [s], "
                             f"got {clock_offset_sigma_s!r}")
        for c in range(n_cam):
            nm = layout.clock_name(c)
            if layout.has(nm) and init.P0 is None:
                P[layout[nm], layout[nm]] = sig0[c] ** 2
    return P, clk0


def _corrected_stamps(vectors: VectorData | None, clk0: np.ndarray) -> VectorData | None:
    """Vector stamps minus their camera's clock offset (unknown cameras unchanged)."""
    if vectors is None or not np.any(clk0 != 0):
        return vectors
    cam_idx = np.asarray(vectors.camera)
    known = (cam_idx >= 0) & (cam_idx < clk0.size)
    shift = np.zeros(cam_idx.size, dtype=np.int64)
    shift[known] = np.round(clk0[cam_idx[known].astype(int)] * NS).astype(np.int64)
    return dataclasses.replace(vectors, t_ns=np.asarray(vectors.t_ns, dtype=np.int64) - shift)


def initial_edge_heights(vectors: VectorData | None, n_cam: int) -> np.ndarray:
    """Per camera, the edge height [m] of its first horizon vector with a sensitivity
    (``VectorData.edge_ref_m``): the start of the filter's ``h_e`` (0 where there is none)."""
    out = np.zeros(n_cam)
    if vectors is None or vectors.dedge_c is None or vectors.edge_ref_m is None:
        return out
    cam, ref = np.asarray(vectors.camera), np.asarray(vectors.edge_ref_m, float)
    ok = np.all(np.isfinite(np.asarray(vectors.dedge_c, float)), axis=1) & np.isfinite(ref)
    for c in range(n_cam):
        j = np.flatnonzero(ok & (cam == c))
        if j.size:
            out[c] = ref[j[np.argmin(np.asarray(vectors.t_ns)[j])]]
    return out


class _Recorder:
    """Output buffers of a run, sized by an upper bound (np.empty: pages never written are never
    committed): covariance epochs <= 1 (start) + full-length blocks + blocks ending at a
    measurement sample + the last block; update epochs <= distinct measurement samples."""

    def __init__(self, st: FilterState, N: int, max_block: int, ev_idx, store: bool):
        n, n_cam = st.n, st.R_bc.shape[0]
        n_ev_idx = int(np.unique(ev_idx).size)
        K_max = 2 + (N - 1) // max_block + n_ev_idx
        M_max = max(n_ev_idx, 1)
        self.traj = np.empty((N, 10))
        self.cov_idx = np.empty(K_max, dtype=np.int64)
        self.P_diag = np.empty((K_max, n))
        self.P_full = np.empty((M_max, n, n))
        self.meas_t = np.empty(M_max, dtype=np.int64)
        self.R_bc_hist = np.empty((M_max, n_cam, 3, 3))
        self.fed = np.empty((K_max, st.fed.size))   # the fed-back estimates at each covariance epoch
        self.P_nav = np.empty((K_max, 9, 9))          # and the navigation block of P
        self.clk_t = np.empty((M_max, n_cam))
        self.kc, self.mc = 1, 0   # covariance and update epochs so far
        self.tri_t, self.tri_in, self.innovations = [], [], []
        self.store, self.n_cam = store, n_cam
        self.A, self.d = np.empty((9, n)), np.empty(n)   # the block transition when nothing is stored
        if store:
            self.st_A, self.st_d = np.empty((K_max, 9, n)), np.empty((K_max, n))
            self.st_P, self.st_post = np.empty((K_max, n, n)), np.full(K_max, -1, dtype=np.int64)
            self.st_dx = np.zeros((K_max, n))
            self.st_A[0], self.st_d[0], self.st_P[0] = 0.0, 1.0, st.P
        self.cov_idx[0] = 0
        self.P_diag[0] = st.P.diagonal()
        self.fed[0] = st.fed
        self.P_nav[0] = st.P[:9, :9]
        self.traj[0] = st.nav

    def transition(self):
        """Where the next block's transition goes: (9, n) rows and (n,) diagonal."""
        return (self.st_A[self.kc], self.st_d[self.kc]) if self.store else (self.A, self.d)

    def covariance_epoch(self, k: int, st: FilterState) -> None:
        self.cov_idx[self.kc] = k
        self.P_diag[self.kc] = st.P.diagonal()
        self.fed[self.kc] = st.fed
        self.P_nav[self.kc] = st.P[:9, :9]
        if self.store:
            self.st_P[self.kc] = st.P
        self.kc += 1

    def update_epoch(self, k: int, t: int, st: FilterState, dx) -> None:
        """The posterior at an epoch with an applied update."""
        kc, mc = self.kc, self.mc
        self.traj[k] = st.nav
        self.P_diag[kc - 1] = st.P.diagonal()
        self.fed[kc - 1] = st.fed
        self.P_nav[kc - 1] = st.P[:9, :9]
        self.meas_t[mc] = t
        self.P_full[mc] = st.P
        if self.n_cam:
            self.R_bc_hist[mc] = st.R_bc
            self.clk_t[mc] = st.clk0 + st.clk_hat
        if self.store:
            self.st_post[kc - 1] = mc
            self.st_dx[kc - 1] = dx
        self.mc += 1

    def restart(self, k: int, st: FilterState) -> None:
        """A re-initialised state at sample k (:mod:`nav.recovery`): the solution there, and the
        inflated covariance as the epoch's prior (the smoother's gain into it is then small, so the
        segments before and after are smoothed almost independently)."""
        self.traj[k] = st.nav
        self.P_diag[self.kc - 1] = st.P.diagonal()
        self.fed[self.kc - 1] = st.fed
        self.P_nav[self.kc - 1] = st.P[:9, :9]
        if self.store:
            self.st_P[self.kc - 1] = st.P

    def triad_pairs(self, pairs: dict) -> None:
        for tm, vecs in pairs.items():
            if "hor" in vecs and "sun" in vecs:
                self.tri_t.append(tm)
                self.tri_in.append((vecs["hor"][0], vecs["sun"][0], vecs["hor"][1], vecs["sun"][1]))

    def smoother_store(self) -> SmootherStore | None:
        kc = self.kc
        if not self.store:
            return None
        return SmootherStore(self.cov_idx[:kc], self.st_A[:kc], self.st_d[:kc], self.st_P[:kc], self.st_post[:kc],
                             self.st_dx[:kc])


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
    t_ns, f_b, w_b = _imu_window(imu, init, tuning, rejected)
    R_bc_nom = np.array([np.asarray(R, float) for R in R_bc], float).reshape(len(R_bc), 3, 3)
    layout = build_layout(tuning, len(R_bc))
    P, clk0 = _initial_covariance(layout, init, len(R_bc), clock_offset_s, clock_offset_sigma_s)
    st = FilterState(layout, tuning, init.x_e, init.v_e, init.q_eb, P, R_bc_nom, clk0,
                     initial_edge_heights(vectors, len(R_bc)))
    vectors = _corrected_stamps(vectors, clk0)
    sources = []
    if gps is not None:
        sources.append(GpsFixes(gps, lever_b, layout, tuning.gps_noise_scale))
    if vectors is not None:
        sources.append(CameraVectors(vectors, layout, tuning, len(R_bc)))
    events, ev_idx = _within(_events(sources, rejected), t_ns, rejected)
    ts = (t_ns - t_ns[0]).astype(np.float64) / NS
    max_block = max(1, int(round(tuning.max_cov_interval_s / max(np.median(np.diff(ts)), 1e-9))))
    rec = _Recorder(st, t_ns.size, max_block, ev_idx, store_for_smoother)
    if imu.sample not in ("point", "average"):
        raise ValueError(f"imu.sample: expected 'point' or 'average', got {imu.sample!r}")
    fw = np.empty((t_ns.size, 2, 3))
    fw[:, 0], fw[:, 1] = f_b, w_b
    if layout.has("gyro_gm") and tuning.gyro_gm_quantum > 0:
        st.follow_rates(quantisation_rates(ts, w_b, tuning.gyro_gm_quantum, tuning.gyro_gm_quantum_scale,
                                           tuning.gyro_gm_quantum_window_s))
    rcv = Recovery(ts, t_ns, tuning, sources)
    reo = MisalignmentReopening(tuning, layout, len(R_bc), rcv.events)
    loop = _Loop(st, rec, sources, events, ev_idx.tolist(), t_ns, ts, fw, imu.sample == "average", rejected, rcv,
                 reo)
    loop.run(max_block)
    if unaided:
        UX, UV, UQ = ins.propagate(init.x_e, init.v_e, init.q_eb, ts, f_b, w_b, sample=imu.sample)
    else:
        UX = UV = UQ = np.empty((0, 3))
    for reason, cnt in sorted(rejected.items()):
        log.info("rejected %s: %d", reason, cnt)
    return _result(st, rec, t_ns, R_bc_nom, (UX, UV, UQ), rejected, rcv.events)


def _imu_window(imu: ImuData, init: InitialState, tuning: Tuning, rejected: Counter):
    """The cleaned IMU samples from the start time on: (t_ns, f_b, w_b)."""
    t_all, f_all, w_all = _clean_imu(imu, tuning, rejected)
    i_start = int(np.searchsorted(t_all, init.t_ns, side="left"))
    if i_start >= t_all.size - 1:
        raise ValueError("init.t_ns: the start time is at or after the last IMU sample")
    t_ns = t_all[i_start:]
    if t_ns[0] != init.t_ns:
        raise ValueError(f"init.t_ns: must coincide with an IMU sample time (nearest is {t_ns[0]})")
    return t_ns, f_all[i_start:], w_all[i_start:]


class _Loop:
    """The epoch loop: the measurements at the current sample, then the propagation to the next
    epoch (the next measurement's sample or ``max_block`` samples on, whichever comes first)."""

    def __init__(self, st, rec, sources, events, ev_idx, t_ns, ts, fw, avg, rejected, rcv, reo):
        self.st, self.rec, self.sources, self.events, self.ev_idx = st, rec, sources, events, ev_idx
        self.rcv, self.reo = rcv, reo
        self.t_l, self.t_ns, self.ts, self.fw, self.avg, self.rejected = t_ns.tolist(), t_ns, ts, fw, avg, rejected
        self.stack = EpochStack(st.n, st.tuning.gate_probability)

    def run(self, max_block: int) -> None:
        st, rec, N = self.st, self.rec, self.t_ns.size
        k = e_ptr = 0
        while True:
            e_ptr, dx = self.measure(k, e_ptr)
            if dx is not None:
                rec.update_epoch(k, self.t_l[k], st, dx)
            if self.reo.due:
                self.reo.reopen(st, self.t_l[k])
            if k >= N - 1:
                break
            k_end = min(k + max_block, N - 1)
            if e_ptr < len(self.events):
                k_end = min(k_end, max(self.ev_idx[e_ptr], k + 1))
            A_out, d_out = rec.transition()
            st.propagate(self.ts, self.fw, rec.traj, k, k_end, self.avg, A_out, d_out)
            k = k_end
            rec.covariance_epoch(k, st)
            if k >= self.rcv.next_gap:
                self.rcv.passed(k)

    def measure(self, k: int, e_ptr: int):
        """Every measurement at sample k: extrapolated state, candidate blocks from its source,
        then the gated stacked update and feedback (:meth:`nav.updates.EpochStack.apply`).
        Returns the next event and the fed-back correction (None: no update applied)."""
        ev, ev_idx = self.events, self.ev_idx
        n_ev = len(ev)
        if e_ptr >= n_ev or ev_idx[e_ptr] != k:
            return e_ptr, None
        st, stack, rcv, sources, t_k = self.st, self.stack, self.rcv, self.sources, self.t_l[k]
        innovations = self.rec.innovations
        stack.reset()
        kk = min(k + 1, self.t_ns.size - 1) if self.avg else k  # the sample covering (t_k, t_m]
        f, w = self.fw[kk]
        e0, n0 = e_ptr, len(innovations)
        if rcv.pending is not None:
            self.recover(k, kk, e0, True)
        while e_ptr < n_ev and ev_idx[e_ptr] == k:
            t_m, si, j = ev[e_ptr]
            e_ptr += 1
            src = sources[si]
            src.fill(j, t_m, (f, w, (t_m - t_k) / NS - src.clock_shift(j, st)), st, stack)
        tun = st.tuning
        prior = (st.snapshot() if tun.first_update_iterations and st.attitude_sigma() > tun.first_update_att_sigma
                 and any(b[1] in ("hor", "sun", "moon") for b in stack.blocks) else None)
        dx = stack.apply(st, innovations, self.rejected, t_k)
        if prior is not None and dx is not None:
            dx = self.relinearise(k, kk, e0, e_ptr, prior, dx)
        if dx is not None and tun.misalignment_reset:
            st.reset_rotations(dx)
        if stack.triad:
            self.rec.triad_pairs(stack.triad)
        if rcv.watch and rcv.diverged(self.rejected, innovations, n0):
            self.recover(k, kk, e0, False)
        if self.reo.on:
            self.reo.count(innovations, n0)
        return e_ptr, dx

    def relinearise(self, k: int, kk: int, e0: int, e1: int, prior, dx):
        """The iterated update of the epoch at sample k (an iterated EKF): the measurements of
        events ``e0..e1`` linearised again about the updated state, ``first_update_iterations``
        times (:meth:`nav.updates.EpochStack.relinearised`); the state ends at the last
        successful iterate. Returns its correction from the prior."""
        st, stack, t_k = self.st, self.stack, self.t_l[k]
        f, w = self.fw[kk]
        for _ in range(st.tuning.first_update_iterations):
            delta, post = dx.copy(), st.snapshot()
            stack.reset()
            for t_m, si, j in self.events[e0:e1]:
                src = self.sources[si]
                src.fill(j, t_m, (f, w, (t_m - t_k) / NS - src.clock_shift(j, st)), st, stack)
            Rb = st.reset_rotation(delta) if st.tuning.misalignment_reset else None
            st.restore(prior)
            new = stack.relinearised(st, delta, Rb)
            if new is None:
                st.restore(post)
                return delta
            dx = new
        return dx

    def recover(self, k: int, kk: int, e0: int, gap: bool):
        """A re-initialisation at the epoch of sample k (:class:`nav.recovery.Recovery`): before
        its measurements for a pending gap (``gap``), after them for a divergence. A
        re-initialised state is recorded at k."""
        e1 = e0
        while e1 < len(self.events) and self.ev_idx[e1] == k:
            e1 += 1
        evs, t_k, f, w = self.events[e0:e1], self.t_l[k], self.fw[kk, 0], self.fw[kk, 1]

        def at(t_m):
            return f, w, (t_m - t_k) / NS
        done = self.rcv.before(at, evs, self.st) if gap else self.rcv.after(evs, at, self.st)
        if done:
            self.rec.restart(k, self.st)


def _triad_attitudes(rec: _Recorder):
    """TRIAD attitudes of the horizon / Sun pairs; pairs closer than 1 deg to parallel are left
    out (TRIAD is ill-conditioned there)."""
    tri_t, tri_q = rec.tri_t, np.empty((0, 4))
    if rec.tri_in:
        a = [np.array([r[i] for r in rec.tri_in]) for i in range(4)]
        ang = angle_between(a[0], a[1])
        ok = np.minimum(ang, np.pi - ang) > np.radians(1.0)
        tri_t = np.array(tri_t, dtype=np.int64)[ok]
        tri_q = matrix_to_quat(triad(*(x[ok] for x in a))) if ok.any() else tri_q
    return np.array(tri_t, dtype=np.int64), np.array(tri_q).reshape(-1, 4)


def _camera_outputs(st: FilterState, rec: _Recorder, R_bc_nom):
    """Camera misalignment estimates, their sigma and the clock offsets with their sigma at the
    update epochs (empty without cameras)."""
    layout, n_cam, P_full = st.layout, R_bc_nom.shape[0], rec.P_full[:rec.mc]
    mc_cam = rec.mc if n_cam else 0
    mis = (matrix_to_rotvec(rec.R_bc_hist[:mc_cam] @ np.swapaxes(R_bc_nom, -1, -2)[None])
           if mc_cam else np.zeros((0, n_cam, 3)))
    mis_sig = np.zeros((mc_cam, n_cam, 3))
    clk_sig = np.zeros((mc_cam, n_cam))
    for c in range(n_cam):
        if layout.has(layout.cam_name(c)):
            sl = layout[layout.cam_name(c)]
            mis_sig[:, c] = np.sqrt(np.diagonal(P_full[:mc_cam, sl, sl], axis1=1, axis2=2))
        if layout.has(layout.clock_name(c)):
            i_c = layout[layout.clock_name(c)].start
            clk_sig[:, c] = np.sqrt(P_full[:mc_cam, i_c, i_c])
    return mc_cam, mis.reshape(mc_cam, n_cam, 3), mis_sig, rec.clk_t[:mc_cam].copy(), clk_sig


def _result(st: FilterState, rec: _Recorder, t_ns, R_bc_nom, unaided, rejected, recoveries) -> NavResult:
    kc, mc = rec.kc, rec.mc
    cov_idx = rec.cov_idx[:kc]
    tri_t, tri_q = _triad_attitudes(rec)
    mc_cam, mis, mis_sig, clk, clk_sig = _camera_outputs(st, rec, R_bc_nom)
    traj = rec.traj
    return NavResult(
        layout=st.layout, t_ns=t_ns, x_e=np.ascontiguousarray(traj[:, 0:3]), v_e=np.ascontiguousarray(traj[:, 3:6]),
        q_eb=np.ascontiguousarray(traj[:, 6:10]), cov_t_ns=t_ns[cov_idx], cov_idx=cov_idx,
        P_diag=rec.P_diag[:kc], meas_t_ns=rec.meas_t[:mc], P_full=rec.P_full[:mc],
        unaided_x_e=unaided[0], unaided_v_e=unaided[1], unaided_q_eb=unaided[2],
        innovations=rec.innovations, misalignment_t_ns=rec.meas_t[:mc_cam].copy(),
        misalignment=mis, misalignment_sigma=mis_sig, triad_t_ns=tri_t, triad_q_eb=tri_q,
        rejected=dict(rejected), calibration=st.calibration, R_bc=st.R_bc.copy(), store=rec.smoother_store(),
        clock_offset=clk, clock_offset_sigma=clk_sig, recoveries=list(recoveries),
        estimates=estimates_from_fed(st.layout, st.fb, rec.fed[:kc], R_bc_nom), P_nav=rec.P_nav[:kc])


def estimates_from_fed(layout: StateLayout, fb: np.ndarray, fed: np.ndarray, R_bc_nom: np.ndarray) -> np.ndarray:
    """(K, n) estimates in the layout's coordinates from the fed-back arrays ``fed`` (K, m) laid
    out as ``FilterState.fed``, through the feedback table ``fb``
    (:func:`nav.filter_state.feedback_table`): an additive group (IMU errors into the calibration,
    the Gauss-Markov gyro error, zeta, clock offsets) is its accumulated value, a camera misalignment the rotation vector of
    ``R_bc R_bc_nom^T`` (003 eq. (50) composes the corrections as rotations). Navigation and
    considered states are 0."""
    from nav.filter_state import FB_ADD1, FB_ADD3, FB_GYRO, FB_ROTATE, N_CAL
    K = fed.shape[0]
    out = np.zeros((K, layout.n))
    for op, off, col in fb.tolist():
        if op in (FB_ADD3, FB_GYRO):
            out[:, col:col + 3] = fed[:, off:off + 3]
        elif op == FB_ADD1:
            out[:, col] = fed[:, off]
        elif op == FB_ROTATE:
            c = (off - N_CAL) // 9
            R = fed[:, off:off + 9].reshape(K, 3, 3)
            out[:, col:col + 3] = matrix_to_rotvec(R @ R_bc_nom[c].T)
    return out
