"""One study run: simulate -> vectors from truth plus the vision error model -> filter -> smoother
-> metrics.

Deterministic: the same (scenario, tuning, run config, seed) gives the same numbers bit for bit,
in any process, in any order. The random streams are those of :mod:`scenarios.sim.simulate` (IMU 1,
GPS 2, camera k 100 + k: one per sensor) plus, here, the vector errors of camera k and target j
(``VECTOR_STREAM + 10 k + j``), their white part (``WHITE_STREAM + 10 k + j``) and the initial
error (``INIT_STREAM``).

What the filter is told matches what is drawn (a consistency study tests a *matched* filter):
each vector carries the P_c its error was drawn with (the Gauss-Markov part, considered by the
filter's zeta states with the same T_c), plus white noise of ``run.white_sigma`` per tangent axis,
by default the tuning's ``vector_white`` (003 eq. (49)'s Q_tuning, which the filter adds to every
vector); the initial errors are drawn with the ``run.init_*`` sigmas (the study files set them
equal to the tuning's).

Caches (per process; a worker keeps them across runs):

* the truth trajectory per scenario (only the parts that shape it: launch, vehicle, spin, RCS,
  disturbances, simulation settings) and end time: it is deterministic, only the sensors depend on
  the seed;
* the predicted vision covariance per frame, camera and target (003 eq. (33) for the longest
  visible limb arc with the pixel noise of eqs. (34)-(38), :func:`vision.error_model.predict_vision`),
  computed once per scenario variant with the *nominal* camera mounting. A run's true mounting is
  misaligned by ~1 deg (003 eq. (50)), which moves the limb by ~1 % of the image; the cached P is
  re-projected onto the tangent plane of the run's true direction, ``P = T P_nom T``,
  ``T = I - e e^T`` (P_c has no component along e). Frames whose nominal arc is too short give
  no vector.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from nav.ephemeris import SUN_RADIUS, sun_position_e
from nav.navigator import GpsData, ImuData, InitialState, VectorData, run
from nav.rotation import matrix_to_quat, quat_to_matrix, rotvec_to_matrix, tangent_bases
from scenarios.sim import simulate as S
from scenarios.study.metrics import run_metrics
from scenarios.study.studyfile import RunConfig, RunSpec
from vision.error_model import HORIZON_NOISE, SUN_NOISE, bloomed_alpha, draw_vector_errors, predict_vision

VECTOR_STREAM, INIT_STREAM, WHITE_STREAM = 300, 400, 500
TARGETS = ("hor", "sun")

_TRUTH: dict = {}
_COV: dict = {}


@dataclass
class RunOutput:
    """Metrics (name -> value), series (quantity, t_s, value, dof) and the wall time of one run."""
    spec: RunSpec
    metrics: dict
    series: list
    elapsed_s: float


def _truth_key(sc, t_end: float) -> str:
    parts = [sc.launch, sc.vehicle, sc.spin, sc.rcs, sc.disturbance, sc.simulation]
    return repr([dataclasses.asdict(p) for p in parts]) + f"|{sc.orbit!r}|{t_end!r}"   # orbit: None for a launch


def cached_truth(sc, t_end: float):
    """The truth of ``sc`` up to ``t_end`` (computed once per process and truth-shaping settings)."""
    from scenarios.sim.truth import simulate_truth
    key = _truth_key(sc, t_end)
    if key not in _TRUTH:
        if len(_TRUTH) >= 4:
            _TRUTH.pop(next(iter(_TRUTH)))
        _TRUTH[key] = simulate_truth(sc, t_end)
    return _TRUTH[key]


def _nominal_covariances(sc, truth, ci: int, cam_cfg, cam_truth_nominal, cam_model, rc: RunConfig):
    """Per frame and target: P_c (3, 3) predicted for the nominal mounting, NaN where no vector."""
    key = (_truth_key(sc, rc.t_end_s), repr(dataclasses.asdict(cam_cfg)), rc.sun_bloom, rc.min_pixels,
           rc.t_start_s, rc.t_end_s)
    if key in _COV:
        return _COV[key]
    ct = cam_truth_nominal
    out = {}
    in_win = (ct.t >= rc.t_start_s - 1e-9) & (ct.t <= rc.t_end_s + 1e-9)
    for target in TARGETS:
        P = np.full((ct.t.size, 3, 3), np.nan)
        if target == "hor":
            vis, vec = ct.horizon_visible & in_win, ct.nadir_c
        else:
            vis, vec = ct.sun_in_view & in_win, ct.sun_c
        for i in np.flatnonzero(vis):
            if target == "hor":
                pred = predict_vision(cam_model, vec[i], float(ct.alpha[i]), *HORIZON_NOISE, min_pixels=rc.min_pixels)
            else:
                x = truth.x_e[int(round(ct.t[i] / truth.dt))]
                dist = np.linalg.norm(sun_position_e(truth.liftoff_ns + int(round(ct.t[i] * 1e9))) - x)
                a = bloomed_alpha(math.asin(SUN_RADIUS / dist), rc.sun_bloom)
                pred = predict_vision(cam_model, vec[i], a, *SUN_NOISE, method="free-alpha",
                                      min_pixels=rc.min_pixels)
            if pred.covariance is not None:
                P[i] = pred.covariance.P_c
        out[target] = P
    if len(_COV) >= 16:
        _COV.pop(next(iter(_COV)))
    _COV[key] = out
    return out


def _add_white(e: np.ndarray, sigma: float, rng) -> np.ndarray:
    """Unit vectors ``e`` (K, 3) plus white noise of ``sigma`` per tangent axis, renormalised (the
    noise the filter's ``vector_white`` describes: ``R = sigma^2 I`` projected on the tangent plane)."""
    if sigma <= 0 or e.shape[0] == 0:
        return e
    T = tangent_bases(e, unit=True)
    w = rng.standard_normal((e.shape[0], 2)) * sigma
    v = e + w[:, :1] * T[:, :, 0] + w[:, 1:] * T[:, :, 1]
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def white_sigma(rc: RunConfig, tun) -> float:
    """White vector noise drawn per tangent axis: ``rc.white_sigma``, or the tuning's ``vector_white``
    when negative (matched)."""
    return float(tun.vector_white) if rc.white_sigma < 0 else float(rc.white_sigma)


def simulated_vectors(sc, truth, cams, seed: int, rc: RunConfig, targets=TARGETS, white: float = 0.0) -> VectorData:
    """Vectors from truth plus the vision error model (see the module docstring) for every camera
    of the run (``cams`` from :func:`scenarios.sim.simulate.simulate_cameras`), plus white noise of
    ``white`` per tangent axis (own random stream, so the Gauss-Markov draws do not depend on it)."""
    from scenarios.sim import camera_geometry as cg
    from nav import ephemeris
    rows_t, rows_c, rows_g, rows_e, rows_P = [], [], [], [], []
    for ci, (cfg, cam) in enumerate(zip(sc.cameras, cams)):
        ct = cam.truth
        # nominal-mount truth for the covariance cache (same frames)
        key = (_truth_key(sc, rc.t_end_s), repr(dataclasses.asdict(cfg)), rc.sun_bloom, rc.min_pixels,
               rc.t_start_s, rc.t_end_s)
        if key not in _COV:
            idx = np.round(ct.t / truth.dt).astype(int)
            _, _, h = truth.geodetic()
            t_ns = truth.liftoff_ns + np.round(ct.t * 1e9).astype(np.int64)
            x = truth.x_e[idx]
            ct_nom = cg.camera_truth(cam.camera, cam.R_bc_nominal, ct.t, x, h[idx], truth.q_eb[idx],
                                     ephemeris.sun_direction_e(t_ns, x), ephemeris.moon_direction_e(t_ns, x),
                                     radial_b=cg.radial_of(cfg.azimuth_deg), mask_deg=cfg.mask_deg,
                                     atmosphere_m=sc.simulation.horizon_atmosphere_m)
        else:
            ct_nom = None
        Pnom = _nominal_covariances(sc, truth, ci, cfg, ct_nom, cam.camera, rc)
        for j, target in enumerate(TARGETS):
            if target not in targets:
                continue
            vis = ct.horizon_visible if target == "hor" else ct.sun_in_view
            vec = ct.nadir_c if target == "hor" else ct.sun_c
            ok = vis & np.all(np.isfinite(Pnom[target]), axis=(1, 2))
            ii = np.flatnonzero(ok)
            if ii.size == 0:
                continue
            e = vec[ii] / np.linalg.norm(vec[ii], axis=1, keepdims=True)
            T = np.eye(3) - e[:, :, None] * e[:, None, :]
            P = T @ Pnom[target][ii] @ T
            rng = S.rng_for(seed, VECTOR_STREAM + 10 * cam.k + j)
            drawn = draw_vector_errors(e, rc.error_scale ** 2 * P, ct.t[ii], rng, T_c=rc.correlation_time_s,
                                       gm_fraction=rc.gm_fraction)
            rows_t.append(cam.t_ns[ii]); rows_c.append(np.full(ii.size, ci)); rows_g.append(np.full(ii.size, target))
            e_meas = _add_white(drawn.e_meas, white, S.rng_for(seed, WHITE_STREAM + 10 * cam.k + j))
            rows_e.append(e_meas); rows_P.append(rc.report_scale ** 2 * P)
    if not rows_t:
        return VectorData(np.zeros(0, np.int64), np.zeros(0, int), np.zeros(0, "<U3"), np.zeros((0, 3)),
                          np.zeros((0, 3, 3)))
    t = np.concatenate(rows_t)
    o = np.argsort(t, kind="stable")
    return VectorData(t[o], np.concatenate(rows_c)[o], np.concatenate(rows_g)[o], np.concatenate(rows_e)[o],
                      np.concatenate(rows_P)[o])


def exact_vectors(sc, truth, cams, seed: int, rc: RunConfig, targets=TARGETS, white: float = 0.0) -> VectorData:
    """Vectors from :func:`scenarios.sim.truth_vectors.flight_truth_vectors` (covariance predicted per
    run for the true mounting), restricted to the window; ``error_scale`` scales the drawn error
    (``e_true + s (e_meas - e_true)``, renormalised) and ``report_scale`` the reported P."""
    from scenarios.sim.truth_vectors import flight_truth_vectors
    fl = S.FlightData(sc, seed, rc.t_end_s, truth, None, None, None, cams)
    edge = {} if rc.edge_ref_m < 0 else {"edge_ref_m": rc.edge_ref_m}
    tv = flight_truth_vectors(fl, seed, **edge, targets=tuple({"hor": "earth", "sun": "sun"}[t] for t in targets if t in TARGETS),
                              sun_bloom=rc.sun_bloom, gm_fraction=rc.gm_fraction, T_c=rc.correlation_time_s,
                              min_pixels=rc.min_pixels)
    vd = tv.vector_data([c.k for c in cams])
    t_s = (vd.t_ns - truth.liftoff_ns) / 1e9
    m = (t_s >= rc.t_start_s - 1e-9) & (t_s <= rc.t_end_s + 1e-9)
    e_true = tv.e_true[np.isin(tv.camera, [c.k for c in cams])][m]
    e = e_true + rc.error_scale * (vd.e_c[m] - e_true)
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    e = _add_white(e, white, S.rng_for(seed, WHITE_STREAM))
    return VectorData(vd.t_ns[m], vd.camera[m], vd.target[m], e, rc.report_scale ** 2 * vd.P_c[m],
                      None if vd.dedge_c is None else vd.dedge_c[m], None if vd.edge_ref_m is None else vd.edge_ref_m[m])


def run_one(cfg: dict, spec: RunSpec, metrics=("nees", "nis", "rms", "misalignment", "smoother")) -> RunOutput:
    """One run of a study variant ``cfg`` (``{"scenario", "tuning", "run"}``) with ``spec.seed``."""
    from nav.smoother import rts_smooth
    t_wall = time.perf_counter()
    sc, tun, rc = cfg["scenario"], cfg["tuning"], cfg["run"]
    seed = int(spec.seed)
    tr = cached_truth(sc, rc.t_end_s)
    imu, _ = S.simulate_imu(tr, sc.imu, S.rng_for(seed, S.STREAM_IMU))
    g, a = imu.gyro, imu.accel
    if imu.output == "increment":
        g, a = g / imu.dt, a / imu.dt
    sample = "average" if (imu.output == "increment" or sc.imu.sample == "average") else "point"
    keep = imu.t <= rc.t_end_s + 1e-9
    t_imu_ns = tr.liftoff_ns + np.round(imu.t[keep] * 1e9).astype(np.int64)
    imu_data = ImuData(t_imu_ns, a[keep], g[keep], sample)
    start = int(np.searchsorted(imu.t[keep], rc.t_start_s - 1e-9))
    truth_idx = np.round(imu.t[keep] / tr.dt).astype(int)
    gps = None
    if sc.gps.enabled:
        gp = S.simulate_gps(tr, sc.gps, S.rng_for(seed, S.STREAM_GPS))
        m = (gp.t >= imu.t[start] - 1e-9) & (gp.t <= rc.t_end_s + 1e-9)
        if m.any():
            n = int(m.sum())
            gps = GpsData(tr.liftoff_ns + np.round(gp.t[m] * 1e9).astype(np.int64), gp.position[m],
                          np.tile(gp.position_cov, (n, 1, 1)), gp.velocity[m], np.tile(gp.velocity_cov, (n, 1, 1)))
    vectors, R_bc, psi_c = None, [], np.zeros((0, 3))
    if rc.vectors == "truth" and sc.cameras:
        cams = S.simulate_cameras(sc, tr, seed)
        if rc.vector_model == "exact":
            vectors = exact_vectors(sc, tr, cams, seed, rc, tuple(tun.targets), white_sigma(rc, tun))
        else:
            vectors = simulated_vectors(sc, tr, cams, seed, rc, tuple(tun.targets), white_sigma(rc, tun))
        R_bc = [c.R_bc_nominal for c in cams]
        psi_c = np.array([c.psi_c for c in cams])
    i0 = truth_idx[start]
    x0, v0, q0 = tr.x_e[i0].copy(), tr.v_e[i0].copy(), tr.q_eb[i0].copy()
    if rc.init == "perturbed":
        rng = S.rng_for(seed, INIT_STREAM)
        dpsi = rng.normal(0.0, math.radians(rc.init_att_sigma_deg), 3)
        x0 = x0 - rng.normal(0.0, rc.init_pos_sigma_m, 3)
        v0 = v0 - rng.normal(0.0, rc.init_vel_sigma_mps, 3)
        q0 = matrix_to_quat(rotvec_to_matrix(-dpsi) @ quat_to_matrix(q0))
    init = InitialState(int(t_imu_ns[start]), x0, v0, q0)
    want_smooth = rc.smoother and "smoother" in metrics
    res = run(imu_data, init, tun, gps=gps, vectors=vectors, R_bc=R_bc, store_for_smoother=want_smooth,
              unaided=False)
    sm = rts_smooth(res) if want_smooth else None
    res.store = None
    out, series = run_metrics(res, tr, truth_idx[start:], tr.liftoff_ns, (rc.window_start_s, rc.t_end_s), psi_c,
                              metrics, sm, edge_truth_m=sc.simulation.horizon_atmosphere_m)
    out["n_vectors"] = float(0 if vectors is None else len(vectors.t_ns))
    return RunOutput(spec, out, series, time.perf_counter() - t_wall)
