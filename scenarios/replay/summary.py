"""Replay summary: per measurement source the offered / used / rejected counts with reasons, the
NIS mean against its band and the gaps, IMU gaps, recoveries and input warnings (from the
verdict's statistics, :mod:`scenarios.replay.verdict`), final camera misalignments with 3 sigma,
the Earth edge height of each camera with the filter's ``h_e`` state (smoothed, with its sigma),
errors against truth when the log has it, and the verdict as the last line."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from nav.rotation import matrix_to_rotvec, quat_to_matrix
from nav.schmidt import chi2_gate
from scenarios.replay.verdict import DOF

NS = 1_000_000_000


def attitude_error(q_est, q_true) -> np.ndarray:
    """psi (in e) from estimated to true attitude (docs/conventions.md), per sample [rad]."""
    return matrix_to_rotvec(quat_to_matrix(q_true) @ np.swapaxes(quat_to_matrix(q_est), -1, -2))


def _camera_lines(inp) -> dict:
    """camera_<k> -> one line with the model and field of view (`vision.camera.describe`)."""
    from vision.camera import describe

    cams = getattr(inp, "cameras", {}) or {}
    return {f"camera_{k}": describe(c.camera) for k, c in cams.items() if getattr(c, "camera", None) is not None}


def summarize(rr) -> dict:
    """Figures of a :class:`scenarios.replay.pipeline.ReplayResult` as a JSON-ready dict."""
    res, inp, cams = rr.nav, rr.inputs, rr.cam_numbers
    out: dict = {"log": str(inp.path), "solution": str(rr.solution_path), "rrd": str(rr.rrd_path) if rr.rrd_path else None,
                 "vision": rr.vision_mode, "init": rr.init_method,
                 "window_tplus_s": [float(inp.mission_time(res.t_ns[0])), float(inp.mission_time(res.t_ns[-1]))],
                 "timings_s": {k: round(v, 3) for k, v in rr.timings.items()}, "notes": list(rr.messages),
                 "cameras": _camera_lines(inp)}
    verdict = rr.verdict
    st = verdict.statistics if verdict is not None else {}
    out["measurements"] = {k: {"used": d["accepted"], "rejected": dict(d["rejected"])}
                           for k, d in st.get("sensors", {}).items()}
    other = {k: v for k, v in res.rejected.items() if not any(k.startswith(p) for p in ("gps_pos_", "gps_vel_", "hor_", "sun_", "moon_"))}
    out["other_rejections"] = other
    nis = {}
    for kind, dof in DOF.items():
        v = res.nis(kind)
        if v.size:
            lo, hi = chi2_gate(dof, 0.025), chi2_gate(dof, 0.975)
            nis[kind] = {"n": int(v.size), "mean": float(v.mean()), "dof": dof,
                         "inside95": float(np.mean((v > lo) & (v < hi)))}
    out["nis"] = nis
    mis = {}
    if len(res.misalignment_t_ns):
        for c, k in enumerate(cams):
            mis[f"camera_{k}"] = {"psi_c_deg": np.degrees(res.misalignment[-1, c]).round(4).tolist(),
                                  "3sigma_deg": np.degrees(3 * res.misalignment_sigma[-1, c]).round(4).tolist()}
    out["misalignment_final"] = mis
    edge = edge_heights(res, getattr(rr, "smooth", None), cams, getattr(rr, "vectors", None))
    if edge:
        out["edge_height"] = edge
    sig = np.sqrt(res.P_diag[-1])
    lay = res.layout
    out["final_3sigma"] = {"att_deg": float(np.degrees(3 * sig[lay["psi"]].max())),
                           "pos_m": float(3 * sig[lay["dx"]].max()), "vel_mps": float(3 * sig[lay["dv"]].max())}
    if inp.truth is not None:
        out["truth"] = truth_errors(rr)
    ve = vector_errors(rr)
    if ve:
        out["vector_errors"] = ve
    if verdict is not None:
        empty = {"sensors": {}, "imu_gaps": None, "recoveries": [], "gps_steps": [], "position_sigma_m": None,
                 "tail_from_tplus_s": None, "imu_ends_before_gps_s": 0.0, "warnings": list(getattr(inp, "notes", [])),
                 "truncated": False, "misalignment_beyond_prior": []}
        out.update({k: st.get(k, v) for k, v in empty.items()})
        out["verdict"] = verdict.to_dict()
    return out


def edge_heights(res, smooth, cams, vectors=None) -> dict:
    """camera_<k> -> the Earth edge height [km] of the estimated ``h_e`` state: the smoother's
    post-flight value and sigma at the start (a constant state: the same over the flight; None
    without a smoother) and the forward filter's final value and sigma. Cameras none of whose
    ``vectors`` (when given) carry a sensitivity ``dedge_c`` are left out: the state had no
    measurement."""
    lay, out = res.layout, {}
    if res.estimates is None:
        return out
    seen = None
    if vectors is not None:
        g = getattr(vectors, "dedge_c", None)
        ok = np.zeros(len(vectors.t_ns), bool) if g is None else np.all(np.isfinite(g), axis=1)
        seen = set(np.asarray(vectors.camera)[ok].tolist())
    for c, k in enumerate(cams):
        name = lay.edge_name(c)
        if not lay.has(name) or not next(g for g in lay.groups if g.name == name).estimated:
            continue
        if seen is not None and c not in seen:
            continue
        i = lay[name].start
        d = {"forward_km": float(res.estimates[-1, i] / 1e3), "forward_sigma_km": float(np.sqrt(res.P_diag[-1, i]) / 1e3),
             "smoothed_km": None, "smoothed_sigma_km": None}
        if smooth is not None and smooth.estimates is not None:
            d["smoothed_km"] = float(smooth.estimates[0, i] / 1e3)
            d["smoothed_sigma_km"] = float(np.sqrt(smooth.P[0, i]) / 1e3)
        out[f"camera_{k}"] = d
    return out


TRUTH_FIELD = {"hor": "nadir_c", "sun": "sun_c", "moon": "moon_c"}


def vector_errors(rr) -> dict:
    """Angles [deg] between the vectors given to the filter and the simulator's per-frame truth
    (``/camera_<k>/truth``, true camera frame, same stamp), per camera and target: n, mean, RMS,
    median, 95th percentile, max, and the mean error vector's angle (the bias; the rest is scatter).
    Empty without camera truth. For image vectors these are the front end's vectors after the
    geocentric correction (:func:`scenarios.replay.vision_worker.geocentric_correction`). With an
    estimated edge-height state, ``camera_<k>/earth*`` holds the Earth vectors with a sensitivity
    moved to the smoothed height (:func:`_at_learned_height`)."""
    v = rr.vectors
    out: dict = {}
    if v is None or not len(v.t_ns):
        return out
    for c, k in enumerate(rr.cam_numbers):
        ct = rr.inputs.cameras[k].truth
        if ct is None:
            continue
        for tgt in np.unique(v.target):
            m = (v.camera == c) & (v.target == tgt)
            field = TRUTH_FIELD.get(str(tgt))
            if not m.any() or field is None:
                continue
            j = np.searchsorted(ct["t_ns"], v.t_ns[m])
            ok = j < ct["t_ns"].size
            ok[ok] = ct["t_ns"][j[ok]] == v.t_ns[m][ok]
            if not ok.any():
                continue
            e = v.e_c[m][ok]
            tr = ct[field][j[ok]]
            name = {"hor": "earth"}.get(str(tgt), str(tgt))
            out[f"camera_{k}/{name}"] = _angle_stats(e, tr, int((~ok).sum()))
            moved = _at_learned_height(rr, c, m, ok, e)
            if moved is not None:
                out[f"camera_{k}/{name}*"] = _angle_stats(moved[0], tr[moved[1]], 0)
    return out


def _angle_stats(e, tr, unmatched: int) -> dict:
    """n, mean, RMS, median, 95th percentile, max [deg] of the angles between the rows of ``e``
    and ``tr``, and the angle of their mean difference (the bias)."""
    a = np.degrees(np.arccos(np.clip(np.sum(e * tr, axis=1), -1.0, 1.0)))
    return {"n": int(a.size), "unmatched": unmatched, "mean_deg": float(a.mean()), "rms_deg": float(np.sqrt(np.mean(a ** 2))),
            "median_deg": float(np.median(a)), "p95_deg": float(np.percentile(a, 95)), "max_deg": float(a.max()),
            "bias_deg": float(np.degrees(np.linalg.norm(np.mean(e - tr, axis=0))))}


def _at_learned_height(rr, c: int, m, ok, e):
    """The horizon vectors of camera index ``c`` (rows ``m`` of the vectors, ``ok`` of them matched,
    directions ``e``) with a sensitivity moved to the smoothed edge height of the camera's
    ``h_e`` state, ``e - dedge_c (h - edge_ref_m)`` (the vectors' value at the learned height),
    and the mask of ``e``'s rows they are; None without a sensitivity or an estimated state."""
    v, smooth, lay = rr.vectors, getattr(rr, "smooth", None), rr.nav.layout
    g = getattr(v, "dedge_c", None)
    name = lay.edge_name(c)
    if g is None or smooth is None or smooth.estimates is None or not lay.has(name):
        return None
    g, ref = np.asarray(g, float)[m][ok], np.asarray(v.edge_ref_m, float)[m][ok]
    has = np.all(np.isfinite(g), axis=1) & np.isfinite(ref)
    if not has.any():
        return None
    h = float(smooth.estimates[0, lay[name].start])
    e2 = e[has] - g[has] * (h - ref[has])[:, None]
    return e2 / np.linalg.norm(e2, axis=1, keepdims=True), has


def truth_errors(rr) -> dict:
    """Errors against /truth/state at the solution epochs that have a truth sample (the IMU rate
    truth of simulated logs: every epoch). Attitude RMS over the aided phase (from the first
    vector measurement; the whole run when there are none)."""
    res, tr = rr.nav, rr.inputs.truth
    out = {}
    vt = [i.t_ns for i in res.innovations if i.kind in ("hor", "sun", "moon")]
    t_aid = min(vt) if vt else int(res.t_ns[0])
    for name, t, x, v, q, P in (("forward", res.t_ns, res.x_e, res.v_e, res.q_eb, None),
                                ("smoothed", None if rr.smooth is None else rr.smooth.t_ns,
                                 None if rr.smooth is None else rr.smooth.x_e,
                                 None if rr.smooth is None else rr.smooth.v_e,
                                 None if rr.smooth is None else rr.smooth.q_eb, None),
                                ("unaided", res.t_ns if len(res.unaided_q_eb) else None, res.unaided_x_e,
                                 res.unaided_v_e, res.unaided_q_eb, None)):
        if t is None:
            continue
        j = np.searchsorted(tr.t_ns, t)
        ok = (j < tr.t_ns.size)
        ok[ok] = tr.t_ns[j[ok]] == t[ok]
        if not ok.any():
            continue
        jj = j[ok]
        psi = attitude_error(q[ok], tr.q_eb[jj])
        dpos = np.linalg.norm(x[ok] - tr.x_e[jj], axis=1)
        dvel = np.linalg.norm(v[ok] - tr.v_e[jj], axis=1)
        aided = t[ok] >= t_aid
        a = np.degrees(np.linalg.norm(psi, axis=1))
        out[name] = {"att_rms_deg": float(np.sqrt(np.mean(a[aided] ** 2))) if aided.any() else float("nan"),
                     "att_max_deg": float(a[aided].max()) if aided.any() else float("nan"),
                     "att_final_deg": float(a[-1]), "pos_rms_m": float(np.sqrt(np.mean(dpos ** 2))),
                     "pos_max_m": float(dpos.max()), "vel_rms_mps": float(np.sqrt(np.mean(dvel ** 2))),
                     "vel_max_mps": float(dvel.max())}
    if "forward" in out:
        # final error inside the final 3 sigma (per axis)?
        j = int(np.searchsorted(tr.t_ns, res.cov_t_ns[-1]))
        if j < tr.t_ns.size and tr.t_ns[j] == res.cov_t_ns[-1]:
            psi = attitude_error(res.q_eb[res.cov_idx[-1]], tr.q_eb[j])
            s3 = 3 * np.sqrt(res.P_diag[-1, res.layout["psi"]])
            out["forward"]["att_final_inside_3sigma"] = bool(np.all(np.abs(psi) < s3))
    out["aided_from_tplus_s"] = float(rr.inputs.mission_time(t_aid))
    return out


def format_table(s: dict) -> str:
    """The summary as printed by ``horizon-nav replay``."""
    L = []
    w0, w1 = s["window_tplus_s"]
    L.append(f"replay of {s['log']}: T+{w0:.1f} .. T+{w1:.1f} s, vision from {s['vision']}, init {s['init']}")
    for n in s["notes"]:
        L.append(f"  note: {n}")
    for k, line in s.get("cameras", {}).items():
        L.append(f"  {k}: {line}")
    for w in s.get("warnings", []):
        L.append(f"  WARNING: {w}")
    L += sensor_table(s)
    if s["other_rejections"]:
        L.append("other: " + ", ".join(f"{k}: {v}" for k, v in s["other_rejections"].items()))
    if s["misalignment_final"]:
        L.append("")
        L.append("camera misalignment (final, b frame) [deg]      3 sigma [deg]")
        for k, d in s["misalignment_final"].items():
            L.append(f"{k:<10} [{', '.join(f'{x:+.3f}' for x in d['psi_c_deg'])}]   "
                     f"[{', '.join(f'{x:.3f}' for x in d['3sigma_deg'])}]")
    if s.get("edge_height"):
        L.append("")
        L.append("Earth edge height [km]    smoothed   1 sigma    forward (end)   1 sigma")
        for k, d in s["edge_height"].items():
            sm = (f"{d['smoothed_km']:>9.2f} {d['smoothed_sigma_km']:>9.2f}" if d["smoothed_km"] is not None
                  else f"{'-':>9} {'-':>9}")
            L.append(f"{k:<24} {sm}    {d['forward_km']:>9.2f} {d['forward_sigma_km']:>9.2f}")
    f3 = s["final_3sigma"]
    L.append("")
    L.append(f"final 3 sigma: attitude {f3['att_deg']:.3f} deg, position {f3['pos_m']:.2f} m, velocity {f3['vel_mps']:.3f} m/s")
    if "truth" in s:
        t = s["truth"]
        L.append("")
        L.append(f"errors against truth (attitude over the aided phase from T+{t['aided_from_tplus_s']:.0f} s):")
        L.append(f"{'solution':<10} {'att RMS':>9} {'att max':>9} {'att end':>9} {'pos RMS':>9} {'pos max':>9} {'vel RMS':>9}")
        L.append(f"{'':<10} {'[deg]':>9} {'[deg]':>9} {'[deg]':>9} {'[m]':>9} {'[m]':>9} {'[m/s]':>9}")
        for name in ("forward", "smoothed", "unaided"):
            if name in t:
                d = t[name]
                L.append(f"{name:<10} {d['att_rms_deg']:>9.4f} {d['att_max_deg']:>9.4f} {d['att_final_deg']:>9.4f} "
                         f"{d['pos_rms_m']:>9.2f} {d['pos_max_m']:>9.2f} {d['vel_rms_mps']:>9.3f}")
        if "att_final_inside_3sigma" in t.get("forward", {}):
            L.append(f"final attitude error inside its 3 sigma (per axis): {t['forward']['att_final_inside_3sigma']}")
    if s.get("vector_errors"):
        L.append("")
        L.append("vectors given to the filter against the camera truth (/camera_<k>/truth) [deg]:")
        L.append(f"{'vector':<16} {'n':>5} {'mean':>7} {'RMS':>7} {'median':>7} {'95%':>7} {'max':>7} {'bias':>7}")
        for k, d in s["vector_errors"].items():
            L.append(f"{k:<16} {d['n']:>5} {d['mean_deg']:>7.3f} {d['rms_deg']:>7.3f} {d['median_deg']:>7.3f} "
                     f"{d['p95_deg']:>7.3f} {d['max_deg']:>7.3f} {d['bias_deg']:>7.3f}")
        if any(k.endswith("*") for k in s["vector_errors"]):
            L.append("  * the Earth vectors with a sensitivity, moved to the smoothed edge height")
    L.append("")
    L.append("time per stage [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in s["timings_s"].items()))
    L.append(f"solution: {s['solution']}" + (f"   recording: {s['rrd']}  (open with: {viewer_command(s['rrd'])})" if s["rrd"] else ""))
    if "verdict" in s:
        L += verdict_lines(s["verdict"])
    return "\n".join(L)


def sensor_table(s: dict) -> list:
    """Lines of the per-sensor table: offered / used / rejected with the main reasons, the mean NIS
    of the accepted measurements against the 95 % band of the mean (``chi2(N m) / N``), the gaps
    between offered measurements; then IMU gaps, recoveries, GPS track steps."""
    L = ["", f"{'measurement':<16} {'offered':>7} {'used':>6} {'rej.':>5} {'NIS mean':>8} {'95% band':>12} "
         f"{'gaps':>4} {'longest':>8}  rejected because"]
    for src, d in s.get("sensors", {}).items():
        n = d["nis"]
        band = f"{n['band95'][0]:.2f}..{n['band95'][1]:.2f}" if n else ""
        why = ", ".join(f"{k}: {v}" for k, v in list(d["rejected"].items())[:3])
        if d.get("non_finite"):
            why += ("; " if why else "") + f"{d['non_finite']} non-finite (missing, not counted)"
        g = d["gaps"]
        mean = f"{n['mean']:.2f}" if n else "-"
        L.append(f"{src:<16} {d['offered']:>7} {d['accepted']:>6} {d['offered'] - d['accepted']:>5} {mean:>8} {band:>12} "
                 f"{g['count']:>4} {g['longest_s']:>7.1f}s  {why}")
    g = s.get("imu_gaps")
    if g is not None:
        L.append(f"IMU gaps over {g['threshold_s']:g} s: {g['count']}" + (f", longest {g['longest_s']:.2f} s" if g["count"] else ""))
    rec = s.get("recoveries", [])
    L.append("recoveries: " + (", ".join(f"T+{r['tplus_s']:.1f} s {r['reason']}"
                                         + (f" ({r['details']['camera_name']})" if "camera_name" in r["details"] else "")
                                         for r in rec) if rec else "none"))
    if s.get("gps_steps"):
        L.append(f"GPS track steps its velocity does not explain: {len(s['gps_steps'])} (" + ", ".join(
            f"{p['size_m']:.0f} m at T+{p['tplus_s']:.1f} s" for p in s["gps_steps"][:3]) + ")")
    return L


def verdict_lines(v: dict) -> list:
    """The verdict as the summary's last lines: notes, with FAILED the findings that alone would
    make it DEGRADED, then ``verdict: STATUS: reasons``."""
    L = [""] + [f"  note: {n}" for n in v["notes"]] + [f"  also: {r}" for r in v.get("also", [])]
    L.append(f"verdict: {v['status']}" + (f": {'; '.join(v['reasons'])}" if v["reasons"] else ""))
    return L


def viewer_command(rrd) -> str:
    """The shell command that opens the recording ``rrd`` with the Rerun viewer this interpreter
    has installed (``rerun`` beside ``sys.executable``, e.g. ``.venv/bin/rerun``; the bare name when
    it is not there), paths relative to the working directory where they are below it."""
    exe = Path(sys.executable).parent / ("rerun.exe" if os.name == "nt" else "rerun")
    if not exe.exists():
        return f"rerun {rrd}"
    try:
        cmd = os.path.relpath(exe)
    except ValueError:      # another drive
        cmd = str(exe)
    if not cmd.startswith((".", os.sep)):
        cmd = os.path.join(".", cmd)   # a bare relative name would be looked up on PATH
    return f"{cmd} {rrd}"


__all__ = ["summarize", "format_table", "sensor_table", "verdict_lines", "truth_errors", "vector_errors", "attitude_error", "viewer_command"]
