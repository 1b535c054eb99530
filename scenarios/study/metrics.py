"""Study metrics: NEES / NIS with chi-square bands, RMS error versus predicted sigma per state group,
camera-misalignment convergence.

Definitions (Bar-Shalom, Li & Kirubarajan 2001, §5.4; the tests of tests/test_navigator.py):

* NEES of a state group at epoch k: ``eps_k = e_k^T P_k^-1 e_k`` with the true error ``e_k``
  (truth minus estimate) and the filter's covariance block ``P_k``; for a consistent filter
  ``eps_k ~ chi2(d)``, d = 3 per group.
* Monte Carlo average over N runs: ``N * mean(eps_k) ~ chi2(N d)``, so the two-sided 95 % band of
  the average is ``[chi2.ppf(0.025, N d) / N, chi2.ppf(0.975, N d) / N]`` (:func:`mean_band`).
  A variant is *consistent* for a group when the time average of its MC-averaged NEES lies inside
  the band of one epoch (the runs are independent, the epochs of a run are not, so the epoch band
  is the honest one; averaging over time only narrows the spread).
* NIS: ``s^T S^-1 s`` of each accepted innovation (d = 3 for GPS position / velocity, 2 for camera
  vectors in the tangent plane); the band of a mean of m values is ``chi2(m d) / m`` likewise.
* RMS error versus predicted sigma: ``sqrt(mean |e_k|^2)`` against ``sqrt(mean trace P_k)`` over
  the window; their ratio is 1 for a consistent filter.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from nav.rotation import matrix_to_rotvec, quat_to_matrix

GROUPS = {"pos": ("dx", 1.0, "m"), "vel": ("dv", 1.0, "m/s"), "att": ("psi", np.degrees(1.0), "deg")}
NIS_DOF = {"gps_pos": 3, "gps_vel": 3, "hor": 2, "sun": 2, "moon": 2, "edge": 1}
CONVERGED_3SIGMA_DEG = 0.5  #: misalignment "converged" once its largest 3-sigma axis stays below this


def mean_band(dof_total, count, p: float = 0.95):
    """Two-sided ``p`` band of the mean of ``count`` values whose sum is chi2(``dof_total``)."""
    dof_total = np.asarray(dof_total, float)
    count = np.asarray(count, float)
    a = (1.0 - p) / 2.0
    return chi2.ppf(a, dof_total) / count, chi2.ppf(1.0 - a, dof_total) / count


def attitude_errors(q_est, q_true) -> np.ndarray:
    """psi (in e) from the estimated to the true attitude (docs/conventions.md "Rotations")."""
    return matrix_to_rotvec(quat_to_matrix(q_true) @ np.swapaxes(quat_to_matrix(q_est), -1, -2))


def nees(err: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``e_k^T P_k^-1 e_k`` for (K, d) errors and (K, d, d) covariances (Cholesky solve)."""
    L = np.linalg.cholesky(P)
    z = np.linalg.solve(L, err[..., None])[..., 0]
    return np.sum(z * z, axis=-1)


def first_in_bins(t_s: np.ndarray, width: float = 1.0) -> np.ndarray:
    """Indices of the first epoch in each ``width``-second bin (t_s increasing)."""
    b = np.floor(t_s / width + 1e-9).astype(np.int64)
    return np.flatnonzero(np.r_[True, b[1:] != b[:-1]]) if b.size else np.zeros(0, int)


def bin_means(t_s: np.ndarray, v: np.ndarray, width: float = 1.0):
    """(bin start [s], mean, count) of the values in each occupied ``width``-second bin."""
    if t_s.size == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0, int)
    b = np.floor(t_s / width + 1e-9).astype(np.int64)
    u, inv, cnt = np.unique(b, return_inverse=True, return_counts=True)
    s = np.bincount(inv, weights=v)
    return u * width, s / cnt, cnt


def run_metrics(res, truth, truth_idx, liftoff_ns: int, window: tuple, psi_c_true, which=("nees", "nis", "rms", "misalignment"),
                smooth=None, edge_truth_m: float = float("nan")):
    """Scalar metrics and time series of one run.

    Parameters
    ----------
    res : nav.navigator.NavResult
    truth : scenarios.sim.truth.Truth; ``truth_idx`` the truth index of every IMU sample of ``res``.
    window : (t0, t1) mission time [s] the metrics average over.
    psi_c_true : (n_cam, 3) true camera misalignments [rad] (003 eq. (50)).
    smooth : nav.smoother.SmoothResult or None.
    edge_truth_m : true Earth edge height [m] of every camera, for the smoothed edge-height states
        (:func:`edge_metrics`).

    Returns
    -------
    metrics : dict name -> float
    series : list of (quantity, t_s (n,), value (n,), dof (n,)) binned at 1 s (NEES: the first
        epoch of each second; NIS: the mean of the second, dof = count * d).
    """
    t0, t1 = window
    lay = res.layout
    out, series = {}, []
    t_meas = (res.meas_t_ns - liftoff_ns) / 1e9
    mi = np.searchsorted(res.t_ns, res.meas_t_ns)
    w = (t_meas >= t0 - 1e-9) & (t_meas <= t1 + 1e-9)
    mi, tw, Pw = mi[w], t_meas[w], res.P_full[w]
    ti = truth_idx[mi]
    err = {"pos": truth.x_e[ti] - res.x_e[mi], "vel": truth.v_e[ti] - res.v_e[mi],
           "att": attitude_errors(res.q_eb[mi], truth.q_eb[ti])}
    first = first_in_bins(tw)
    for g, (lname, scale, unit) in GROUPS.items():
        if not tw.size:
            break
        sl = lay[lname]
        P = Pw[:, sl, sl]
        e = err[g]
        eps = nees(e, P)
        sig = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
        if "nees" in which:
            out[f"nees_{g}"] = float(eps.mean())
            series.append((f"nees_{g}", tw[first], eps[first], np.full(first.size, 3.0)))
        if "rms" in which:
            rms = float(np.sqrt(np.mean(np.sum(e ** 2, 1))) * scale)
            sg = float(np.sqrt(np.mean(np.sum(sig ** 2, 1))) * scale)
            out[f"rms_{g}_{unit.replace('/', '_')}"] = rms
            out[f"sigma_{g}_{unit.replace('/', '_')}"] = sg
            out[f"ratio_{g}"] = rms / sg if sg > 0 else np.nan
            out[f"inside3_{g}"] = float(np.mean(np.abs(e) < 3 * sig))
            series.append((f"err_{g}_{unit.replace('/', '_')}", tw[first], np.linalg.norm(e[first], axis=1) * scale,
                           np.zeros(first.size)))
            series.append((f"sigma_{g}_{unit.replace('/', '_')}", tw[first],
                           np.linalg.norm(sig[first], axis=1) * scale, np.zeros(first.size)))
    if "rms" in which and tw.size:
        out["att_err_final_deg"] = float(np.degrees(np.linalg.norm(err["att"][-1])))
        out["att_3sigma_final_deg"] = float(3 * np.degrees(np.sqrt(np.diag(Pw[-1])[lay["psi"]].max())))
    if "nis" in which:
        kinds = {}
        for inn in res.innovations:
            if inn.accepted:
                kinds.setdefault(inn.kind, ([], []))
                kinds[inn.kind][0].append((inn.t_ns - liftoff_ns) / 1e9)
                kinds[inn.kind][1].append(inn.nis)
        for kind, (tt, vv) in sorted(kinds.items()):
            tt, vv = np.asarray(tt), np.asarray(vv)
            m = (tt >= t0 - 1e-9) & (tt <= t1 + 1e-9)
            if not m.any():
                continue
            out[f"nis_{kind}"] = float(vv[m].mean())
            out[f"nis_count_{kind}"] = float(m.sum())
            tb, mb, cb = bin_means(tt[m], vv[m])
            series.append((f"nis_{kind}", tb, mb, cb * float(NIS_DOF.get(kind, 2))))
        out["rejected"] = float(sum(v for k, v in res.rejected.items()
                                    if not k.startswith(("before_start", "after_end"))))
    if "misalignment" in which and len(res.misalignment_t_ns) and np.size(psi_c_true):
        tm = (res.misalignment_t_ns - liftoff_ns) / 1e9
        for c in range(res.misalignment.shape[1]):
            cname = lay.cam_name(c)
            grp = next((g for g in lay.groups if g.name == cname), None)
            if grp is None or not grp.estimated:
                continue
            e = psi_c_true[c] - res.misalignment[:, c]
            s = res.misalignment_sigma[:, c]
            out[f"psi_c{c}_err_final_deg"] = float(np.degrees(np.linalg.norm(e[-1])))
            out[f"psi_c{c}_3sigma_final_deg"] = float(3 * np.degrees(s[-1].max()))
            big = np.flatnonzero(3 * np.degrees(s.max(1)) >= CONVERGED_3SIGMA_DEG)
            conv = np.nan if (big.size and big[-1] == len(tm) - 1) else (tm[big[-1] + 1] if big.size else tm[0])
            out[f"psi_c{c}_converged_t_s"] = float(conv)
            # NEES of the misalignment where the full covariance is known (the update epochs)
            k = np.searchsorted(res.meas_t_ns, res.misalignment_t_ns)
            ok = (k < len(res.meas_t_ns)) & (res.meas_t_ns[np.minimum(k, len(res.meas_t_ns) - 1)] == res.misalignment_t_ns)
            sl = lay[cname]
            inw = ok & (tm >= t0 - 1e-9) & (tm <= t1 + 1e-9)
            if inw.any():
                eps = nees(e[inw], res.P_full[k[inw]][:, sl, sl])
                out[f"nees_psi_c{c}"] = float(eps.mean())
                f = first_in_bins(tm[inw])
                series.append((f"nees_psi_c{c}", tm[inw][f], eps[f], np.full(f.size, 3.0)))
            f = first_in_bins(tm)
            series.append((f"err_psi_c{c}_deg", tm[f], np.degrees(np.linalg.norm(e[f], axis=1)), np.zeros(f.size)))
            series.append((f"sigma3_psi_c{c}_deg", tm[f], 3 * np.degrees(s[f].max(1)), np.zeros(f.size)))
    if smooth is not None:
        ts = (smooth.t_ns - liftoff_ns) / 1e9
        m = (ts >= t0 - 1e-9) & (ts <= t1 + 1e-9)
        ti = truth_idx[smooth.idx[m]]
        ea = attitude_errors(smooth.q_eb[m], truth.q_eb[ti])
        ep = truth.x_e[ti] - smooth.x_e[m]
        sa = np.sqrt(smooth.P[m][:, lay["psi"]])
        sp = np.sqrt(smooth.P[m][:, lay["dx"]])
        out["rms_att_smoothed_deg"] = float(np.degrees(np.sqrt(np.mean(np.sum(ea ** 2, 1)))))
        out["sigma_att_smoothed_deg"] = float(np.degrees(np.sqrt(np.mean(np.sum(sa ** 2, 1)))))
        out["rms_pos_smoothed_m"] = float(np.sqrt(np.mean(np.sum(ep ** 2, 1))))
        out["sigma_pos_smoothed_m"] = float(np.sqrt(np.mean(np.sum(sp ** 2, 1))))
        out["inside3_att_smoothed"] = float(np.mean(np.abs(ea) < 3 * sa))
        out.update(edge_metrics(smooth, lay, m, edge_truth_m))
    return out, series


def edge_metrics(smooth, lay, m: np.ndarray, edge_truth_m: float) -> dict:
    """Smoothed edge height of each camera's ``h_e_c`` state against the true edge height over the
    epochs ``m``: worst and RMS error [km], the final value and its 1-sigma [km]; empty without
    the states or their estimates."""
    names = [g.name for g in lay.groups if g.name.startswith("h_e_")]
    if not names or smooth.estimates is None or not np.isfinite(edge_truth_m):
        return {}
    out = {}
    for name in names:
        c, i = name[len("h_e_"):], lay[name].start
        err = (smooth.estimates[m, i] - edge_truth_m) / 1e3
        out[f"edge_err_max_km_c{c}"] = float(np.max(np.abs(err)))
        out[f"edge_err_rms_km_c{c}"] = float(np.sqrt(np.mean(err ** 2)))
        out[f"edge_final_km_c{c}"] = float(smooth.estimates[m, i][-1] / 1e3)
        out[f"edge_sigma_final_km_c{c}"] = float(np.sqrt(smooth.P[m, i][-1]) / 1e3)
    return out
