"""The solution log ``FLIGHT.solution.mcap`` (docs/replay.md, docs/log-format.md).

Topics, same message conventions as the input log:

* ``/nav/forward``: the filter at every covariance epoch (0.1 s) — position, velocity, q_eb and
  the covariance of the reported states (``state_names``: ``dx_x..psi_z`` in e, then the estimated
  IMU errors and camera misalignments ``psi_c_k``); ``state`` holds the estimated parameters
  (accumulated IMU-error calibration and camera misalignment rotation vectors, the fed-back
  navigation errors are 0). At update epochs the block is the full posterior covariance, between
  them its diagonal (what the filter keeps).
* ``/nav/smoothed``: the RTS smoother at the same epochs (covariance diagonal).
* ``/nav/ins_unaided``: the free-inertial solution from the same initial state (no covariance: a
  1x1 NaN, since ``scenarios.flightlog.reader`` cannot reshape an empty one).
* ``/nav/measurements``: every measurement offered to the filter (``gps/position``,
  ``gps/velocity``, ``camera_<k>/earth``, ``camera_<k>/sun``) with its innovation, predicted
  innovation covariance S, NIS, used or the reason it was rejected; and the TRIAD attitudes
  (source ``triad``, ``used`` false, reason "TRIAD attitude, not a filter input"; innovation =
  TRIAD minus forward solution, a rotation vector in e [rad], 003 fig. 44).
* ``/camera_<k>/vectors``: the vectors the filter was given (DirectionVector).
"""
from __future__ import annotations

import numpy as np

from nav.rotation import matrix_to_rotvec, quat_to_matrix

NAV_NAMES = [f"{g}_{a}" for g in ("dx", "dv", "psi") for a in "xyz"]
_FIELD = {"accel_bias": "b_f", "gyro_bias": "b_w"}


def reported_groups(layout) -> list:
    """State groups written with the solution: navigation, estimated IMU errors, camera misalignments."""
    return [g for g in layout.groups if g.name in ("dx", "dv", "psi") or (g.estimated and not g.name.startswith("zeta_"))]


def source_name(kind: str, camera: int, cam_numbers) -> str:
    if kind == "gps_pos":
        return "gps/position"
    if kind == "gps_vel":
        return "gps/velocity"
    target = {"hor": "earth"}.get(kind, kind)
    k = cam_numbers[camera] if 0 <= camera < len(cam_numbers) else camera
    return f"camera_{k}/{target}"


def write_vectors(w, vectors, cam_numbers, extra: dict | None = None) -> None:
    """``/camera_<k>/vectors`` from a nav VectorData (camera index -> number via ``cam_numbers``)."""
    if vectors is None or len(vectors.t_ns) == 0:
        return
    tg = np.array([{"hor": "earth"}.get(str(t), str(t)) for t in vectors.target])
    for i, k in enumerate(cam_numbers):
        m = np.asarray(vectors.camera) == i
        if m.any():
            w.write_vectors(int(k), np.asarray(vectors.t_ns)[m], list(tg[m]), np.asarray(vectors.e_c)[m],
                            np.asarray(vectors.P_c)[m])


def write_solution(w, res, smooth, cam_numbers, *, vectors=None) -> None:
    """Write a NavResult (and optional SmoothResult) into an open LogWriter."""
    lay = res.layout
    groups = reported_groups(lay)
    idx = np.concatenate([np.arange(lay.n)[g.slice] for g in groups])
    names = NAV_NAMES + [f"{g.name}_{a}" for g in groups[3:] for a in "xyz"]
    ci = res.cov_idx
    K = len(ci)
    m = idx.size
    cov = np.zeros((K, m, m))
    cov[:, np.arange(m), np.arange(m)] = res.P_diag[:, idx]
    pos = np.searchsorted(res.meas_t_ns, res.cov_t_ns)
    hit = (pos < len(res.meas_t_ns)) & (res.meas_t_ns[np.minimum(pos, max(len(res.meas_t_ns) - 1, 0))] == res.cov_t_ns) \
        if len(res.meas_t_ns) else np.zeros(K, bool)
    if hit.any():
        cov[hit] = res.P_full[pos[hit][:, None, None], idx[None, :, None], idx[None, None, :]]  # one gather
    # estimated parameters: calibration now (final) is all NavResult keeps for the IMU errors;
    # misalignments are kept per update epoch
    state = np.zeros((K, m))
    off = 9
    for g in groups[3:]:
        if g.name.startswith("psi_c_") and len(res.misalignment_t_ns):
            c = int(g.name[6:])
            j = np.clip(np.searchsorted(res.misalignment_t_ns, res.cov_t_ns, side="right") - 1, 0, None)
            val = res.misalignment[j, c]
            val[res.cov_t_ns < res.misalignment_t_ns[0]] = 0.0
            state[:, off:off + 3] = val
        elif g.name in _FIELD:
            state[:, off:off + 3] = getattr(res.calibration, _FIELD[g.name])
        off += 3
    w.write_nav("/nav/forward", res.cov_t_ns, res.x_e[ci], res.v_e[ci], res.q_eb[ci], cov, state=state,
                state_names=names)
    if smooth is not None:
        sc = np.zeros((len(smooth.t_ns), m, m))
        sc[:, np.arange(m), np.arange(m)] = smooth.P[:, idx]
        w.write_nav("/nav/smoothed", smooth.t_ns, smooth.x_e, smooth.v_e, smooth.q_eb, sc, state_names=names)
    if len(res.unaided_q_eb):
        w.write_nav("/nav/ins_unaided", res.cov_t_ns, res.unaided_x_e[ci], res.unaided_v_e[ci], res.unaided_q_eb[ci],
                    np.full((K, 1), np.nan))  # no covariance (1x1 NaN: the reader cannot take 0x0)
    inn = res.innovations
    if inn:
        w.write_measurement(np.array([i.t_ns for i in inn], np.int64),
                            [source_name(i.kind, i.camera, cam_numbers) for i in inn],
                            np.array([i.accepted for i in inn]), [i.reason or "" for i in inn],
                            [np.asarray(i.s, float) for i in inn], [np.asarray(i.S, float) for i in inn],
                            np.array([i.nis for i in inn], float))
    if len(res.triad_t_ns):
        j = np.clip(np.searchsorted(res.t_ns, res.triad_t_ns), 0, len(res.t_ns) - 1)
        d = matrix_to_rotvec(quat_to_matrix(res.triad_q_eb) @ np.swapaxes(quat_to_matrix(res.q_eb[j]), -1, -2))
        n = len(j)
        w.write_measurement(res.triad_t_ns + 0, ["triad"] * n, np.zeros(n, bool),
                            ["TRIAD attitude, not a filter input"] * n, d, np.zeros((n, 9)), np.full(n, np.nan))
    write_vectors(w, vectors, cam_numbers)
