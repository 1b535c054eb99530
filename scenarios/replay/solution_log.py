"""The solution log ``FLIGHT.solution.mcap`` (docs/replay.md, docs/log-format.md).

Topics, same message conventions as the input log:

* ``/nav/forward``: the filter at every covariance epoch (0.1 s) — position, velocity, q_eb and
  the covariance of the reported states (``state_names``: ``dx_x..psi_z`` in e, then every
  estimated group of the layout in its order: IMU errors ``accel_bias_x`` .., camera
  misalignments ``psi_c_<k>_x`` .., clock offsets ``dt_c_<k>``, estimated vector errors
  ``zeta_<target>_<k>_x`` .., Earth edge heights ``h_e_<k>`` [m], k the camera number; :func:`reported_groups`, :func:`state_names`); ``state`` holds the
  estimates at the epoch (``NavResult.estimates``: the accumulated IMU-error calibration, the
  misalignment rotation vectors, ...; the fed-back navigation errors are 0). At update epochs the
  covariance is the full posterior, between them the full 9x9 block of dx, dv, psi
  (``NavResult.P_nav``) and the diagonal of the rest (what the run keeps).
* ``/nav/smoothed``: the RTS smoother at the same epochs with the same ``state_names`` and
  ``state`` (``SmoothResult.estimates``); covariance: the 9x9 navigation block
  (``SmoothResult.P_nav``) and the diagonal of the rest.
* metadata (:func:`log_metadata`): ``mission_time_origin_ns`` and ``nav_covariance = "full"``.
* ``/nav/ins_unaided``: the free-inertial solution from the same initial state (no covariance:
  0x0; the reader takes the 1x1 NaN placeholder of other solution logs as the same).
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

def log_metadata(inputs) -> dict:
    """The solution log's own metadata keys: ``mission_time_origin_ns`` (the T+ origin of the
    input log: lift-off, else its first IMU sample) and ``nav_covariance = "full"`` (the 9x9
    navigation block of /nav/forward and /nav/smoothed is the full covariance at every epoch)."""
    origin = inputs.liftoff_ns if inputs.liftoff_ns is not None else int(inputs.imu.t_ns[0])
    return {"mission_time_origin_ns": str(int(origin)), "nav_covariance": "full"}


def reported_groups(layout) -> list:
    """State groups written with the solution: the navigation errors and every estimated group
    (IMU errors, camera misalignments, clock offsets, estimated vector errors, edge heights), in
    layout order."""
    return [g for g in layout.groups if g.name in ("dx", "dv", "psi") or g.estimated]


def _camera_group_name(name: str, cam_numbers) -> str:
    """A per-camera group's name with the camera's number k instead of its index in the replay's
    camera list (``psi_c_0`` -> ``psi_c_1`` for camera 1)."""
    head, _, tail = name.rpartition("_")
    if head.startswith(("psi_c", "dt_c", "zeta_", "h_e")) and tail.isdigit():
        i = int(tail)
        return f"{head}_{cam_numbers[i] if i < len(cam_numbers) else i}"
    return name


def state_names(groups, cam_numbers=()) -> list:
    """One name per state: ``<group>_x``, ``_y``, ``_z`` for a 3-vector group, the group's name for
    a scalar one (``dt_c_<k>``), ``<group>_<i>`` otherwise; per-camera groups carry the camera
    number k (``psi_c_<k>``)."""
    names = []
    for g in groups:
        size = g.slice.stop - g.slice.start
        nm = _camera_group_name(g.name, cam_numbers)
        if size == 3:
            names += [f"{nm}_{a}" for a in "xyz"]
        elif size == 1:
            names.append(nm)
        else:
            names += [f"{nm}_{i}" for i in range(size)]
    return names


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
                            np.asarray(vectors.P_c)[m], **_edge_columns(vectors, m))


def _edge_columns(vectors, m) -> dict:
    """The DirectionVector edge-height fields of the vectors ``m`` (empty without a sensitivity)."""
    if getattr(vectors, "dedge_c", None) is None:
        return {}
    out = {"edge_sensitivity": np.asarray(vectors.dedge_c, float)[m], "edge_height": np.asarray(vectors.edge_ref_m, float)[m]}
    for key, name in (("edge_height_sigma", "edge_ref_sigma_m"), ("edge_height_arc", "edge_data_m"),
                      ("edge_height_arc_sigma", "edge_data_sigma_m")):
        a = getattr(vectors, name, None)
        if a is not None:
            out[key] = np.asarray(a, float)[m]
    return out


def write_solution(w, res, smooth, cam_numbers, *, vectors=None) -> None:
    """Write a NavResult (and optional SmoothResult) into an open LogWriter (module docstring)."""
    groups = reported_groups(res.layout)
    idx = np.concatenate([np.arange(res.layout.n)[g.slice] for g in groups])
    names = state_names(groups, cam_numbers)
    ci = res.cov_idx
    K = len(ci)
    m = idx.size
    if res.estimates is None:
        raise ValueError("res: a NavResult without the per-epoch estimates (NavResult.estimates)")
    cov = np.zeros((K, m, m))
    cov[:, np.arange(m), np.arange(m)] = res.P_diag[:, idx]
    cov[:, :9, :9] = res.P_nav
    pos = np.searchsorted(res.meas_t_ns, res.cov_t_ns)
    hit = (pos < len(res.meas_t_ns)) & (res.meas_t_ns[np.minimum(pos, max(len(res.meas_t_ns) - 1, 0))] == res.cov_t_ns) \
        if len(res.meas_t_ns) else np.zeros(K, bool)
    if hit.any():
        cov[hit] = res.P_full[pos[hit][:, None, None], idx[None, :, None], idx[None, None, :]]  # one gather
    w.write_nav("/nav/forward", res.cov_t_ns, res.x_e[ci], res.v_e[ci], res.q_eb[ci], cov,
                state=res.estimates[:, idx], state_names=names)
    if smooth is not None:
        sc = np.zeros((len(smooth.t_ns), m, m))
        sc[:, np.arange(m), np.arange(m)] = smooth.P[:, idx]
        sc[:, :9, :9] = smooth.P_nav
        w.write_nav("/nav/smoothed", smooth.t_ns, smooth.x_e, smooth.v_e, smooth.q_eb, sc,
                    state=smooth.estimates[:, idx], state_names=names)
    if len(res.unaided_q_eb):
        w.write_nav("/nav/ins_unaided", res.cov_t_ns, res.unaided_x_e[ci], res.unaided_v_e[ci], res.unaided_q_eb[ci],
                    np.zeros((K, 0, 0)))   # no covariance
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
