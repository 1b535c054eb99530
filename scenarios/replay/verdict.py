"""The verdict of a forward solution: per-sensor statistics and the rules that make the run OK,
DEGRADED or FAILED (docs/replay.md "Verdict" lists the rules and why the thresholds are what
they are).

:func:`statistics` collects, from the filter's own record (``NavResult.innovations``,
``NavResult.recoveries``, the covariance) and from the inputs (the reader's warnings, the GPS
track, the IMU time stamps):

* per measurement source (``gps/position``, ``gps/velocity``, ``camera_<k>/earth|sun|moon``):
  offered, accepted and rejected counts with the reasons, the mean NIS of the accepted
  measurements against the 95 % band of the mean of N chi-square values of dimension m
  (``chi2(N m) / N``), the same over the flight's last part (the *tail*), and the gaps between
  the offered measurements;
* IMU gaps (steps longer than ``Tuning.max_imu_gap_s``), the recoveries, steps in the GPS track
  that its own velocity does not explain, the largest position sigma, and the input warnings
  (the log reader's, truncation included, IMU samples the filter replaced, and a tuning that
  contradicts itself, `nav.tuning.consistency_warnings`);
* the cameras whose final misalignment estimate lies beyond ``MISALIGNMENT_PRIOR_SIGMAS`` of its
  prior (a mounting the camera file does not describe).

:func:`judge` turns them into a :class:`Verdict`. The design goal: no wrong trajectory leaves
with OK or DEGRADED (exit code 0); a run is FAILED when the filter's statistics show that its
solution and its measurements disagree and the disagreement was not resolved. What the
statistics cannot show (a GPS track wrong as a whole in a way IMU and GPS agree on) is listed in
docs/replay.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nav.schmidt import chi2_gate
from scenarios.replay.solution_log import source_name

NS = 1_000_000_000
DOF = {"gps_pos": 3, "gps_vel": 3, "hor": 2, "sun": 2, "moon": 2, "edge": 1}
GPS_KINDS = ("gps_pos", "gps_vel")
CAMERA_RECOVERY = "camera_gated"   #: the recovery reason of a re-opened camera misalignment (nav.recovery)
#: rejection reasons of rows that hold no measurement (NaN: a receiver's "no fix" row, a frame
#: without a vector): counted as missing, not as offered and rejected; their time is a gap
MISSING = ("non-finite", "non-finite vector", "non-finite covariance")

#: exit codes of ``horizon-nav replay`` (2 is refused input, scenarios.cli._main)
EXIT_OK, EXIT_FAILED, EXIT_DEGRADED_STRICT = 0, 3, 4

# Thresholds (docs/replay.md "Verdict" gives the reasoning)
REJECTED_FAIL = 0.5         #: share of GPS blocks (position or velocity) rejected over the flight -> FAILED
GPS_REJECTED_DEGRADED = 0.05    #: share of GPS blocks rejected over the flight -> DEGRADED
TAIL_S, TAIL_SHARE = 30.0, 0.2  #: the tail: the last max(TAIL_S, TAIL_SHARE x window) of the flight
TAIL_MIN_FIXES = 10         #: the tail holds at least this many offered GPS fixes (earlier ones added)
TAIL_REJECTED_FAIL = 0.5    #: share of GPS blocks rejected in the tail -> FAILED
AFTER_RECOVERY_FAIL = 0.25  #: share of GPS blocks rejected after the last recovery -> FAILED
DIVERGENCES_FAIL = 2        #: divergence recoveries in one flight -> FAILED
NIS_GROSS_P = 1e-6          #: one-sided probability of the gross NIS limit of a consistent filter
NIS_GROSS_FACTOR = 2.0      #: ... and at least this multiple of m (the mean's expectation)
NIS_DEGRADED_FACTOR = 1.25  #: a mean above the 95 % band and above this multiple of m -> DEGRADED
NIS_GPS_LOW_FACTOR = 0.1    #: a GPS NIS mean below this multiple of m (and its band) -> DEGRADED
VISION_REJECTED_DEGRADED = 0.2  #: share of a camera target's vectors rejected -> DEGRADED
VISION_REJECTED_FAIL, VISION_MIN = 0.5, 20  #: share of all camera vectors (at least VISION_MIN) rejected -> FAILED
GPS_OUTAGE_DEGRADED_S = 10.0    #: a GPS outage longer than this -> DEGRADED
IMU_SHORT_DEGRADED_S = 5.0      #: the log's GPS goes on this long after its IMU record -> DEGRADED
POS_SIGMA_FAIL_M = 100.0    #: position 1 sigma (largest axis) at the end of the flight above this -> FAILED
STEP_SIGMAS = 6.0           #: a GPS step: the track's residual beyond this many of its sigmas per axis
STEP_JERK = 1000.0          #: jerk allowance [m/s^3] of the trapezoidal track prediction (position + velocity)
STEP_ACCEL = 200.0          #: acceleration allowance [m/s^2] of the linear prediction (position only)
STEP_MAX_DT_S = 2.0         #: pairs of fixes further apart are not compared
STEP_BEFORE_RECOVERY_S = 30.0   #: a step this long before a divergence recovery is what it followed
MISALIGNMENT_PRIOR_SIGMAS = 3.0  #: an estimated camera misalignment beyond this many prior sigmas on an axis -> DEGRADED


@dataclass
class Verdict:
    """OK, DEGRADED or FAILED with the reasons (``reasons``: what made the status; ``also``: with
    FAILED, the DEGRADED findings; ``notes``: observations that do not change it) and the
    statistics it was judged on (:func:`statistics`)."""

    status: str
    reasons: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    statistics: dict = field(default_factory=dict)
    also: list = field(default_factory=list)    #: with FAILED: what alone would make the run DEGRADED

    def exit_code(self, strict: bool = False) -> int:
        """0 for OK and DEGRADED, 3 for FAILED; with ``strict`` DEGRADED gives 4."""
        if self.status == "FAILED":
            return EXIT_FAILED
        if self.status == "DEGRADED" and strict:
            return EXIT_DEGRADED_STRICT
        return EXIT_OK

    def line(self) -> str:
        """One line: ``verdict: FAILED: reason; reason``."""
        return f"verdict: {self.status}" + (": " + "; ".join(self.reasons) if self.reasons else "")

    def to_dict(self) -> dict:
        return {"status": self.status, "reasons": list(self.reasons), "also": list(self.also),
                "notes": list(self.notes)}

    def metadata(self) -> dict:
        """The solution log's metadata record ``horizon-nav.verdict`` (str values; the lists as
        JSON)."""
        import json
        return {"status": self.status, "reasons": json.dumps(self.reasons), "also": json.dumps(self.also),
                "notes": json.dumps(self.notes)}

    def __repr__(self) -> str:
        return f"Verdict({self.line().removeprefix('verdict: ')})"


def mean_band(n: int, dof: int, probability: float = 0.95) -> tuple:
    """The central ``probability`` band of the mean of ``n`` chi-square values with ``dof``
    degrees of freedom: ``chi2.ppf((1 -+ p) / 2, n dof) / n``."""
    a = 0.5 * (1.0 - probability)
    return chi2_gate(n * dof, a) / n, chi2_gate(n * dof, 1.0 - a) / n


def gross_limit(n: int, dof: int) -> float:
    """The NIS mean above which a filter is grossly inconsistent: beyond the chi-square quantile
    of probability 1 - NIS_GROSS_P of the mean of n values and at least NIS_GROSS_FACTOR x dof."""
    return max(chi2_gate(n * dof, 1.0 - NIS_GROSS_P) / n, NIS_GROSS_FACTOR * dof)


def _records(innovations, cam_numbers):
    """Per source name: kind, stamps, accepted flags, NIS, reasons (arrays; one pass) and the
    count of non-finite measurements (NaN rows: missing, not offered; :data:`MISSING`)."""
    rec: dict = {}
    for i in innovations:
        src = source_name(i.kind, i.camera, cam_numbers)
        d = rec.setdefault(src, {"kind": i.kind, "t": [], "ok": [], "nis": [], "why": [], "missing": 0})
        if i.reason in MISSING:
            d["missing"] += 1
            continue
        d["t"].append(i.t_ns)
        d["ok"].append(i.accepted)
        d["nis"].append(i.nis)
        d["why"].append(i.reason)
    for d in rec.values():
        d["t"] = np.asarray(d["t"], np.int64)
        d["ok"] = np.asarray(d["ok"], bool)
        d["nis"] = np.asarray(d["nis"], float)
    return rec


def _nis(nis: np.ndarray, dof: int) -> dict | None:
    if not nis.size:
        return None
    lo, hi = mean_band(nis.size, dof)
    one = (chi2_gate(dof, 0.025), chi2_gate(dof, 0.975))
    return {"n": int(nis.size), "mean": float(nis.mean()), "band95": [lo, hi],
            "gross_limit": gross_limit(nis.size, dof),
            "inside95": float(np.mean((nis > one[0]) & (nis < one[1])))}


def gaps(t_ns, a: int, b: int, threshold_s: float) -> dict:
    """Intervals between the stamps ``t_ns`` (and from ``a`` to the first, from the last to ``b``)
    longer than ``threshold_s``: count, longest [s] and where it starts [ns]."""
    t = np.unique(np.asarray(t_ns, np.int64))
    edges = np.concatenate([[a], t, [b]]) if t.size else np.array([a, b], np.int64)
    d = np.diff(edges) / NS
    big = np.flatnonzero(d > threshold_s)
    if not big.size:
        return {"threshold_s": threshold_s, "count": 0, "longest_s": 0.0, "longest_from_ns": None}
    j = big[np.argmax(d[big])]
    return {"threshold_s": threshold_s, "count": int(big.size), "longest_s": float(d[j]),
            "longest_from_ns": int(edges[j])}


def _gap_threshold(t_ns, floor_s: float) -> float:
    t = np.unique(np.asarray(t_ns, np.int64))
    med = float(np.median(np.diff(t))) / NS if t.size > 2 else 0.0
    return max(floor_s, 5.0 * med)


def gps_steps(gps) -> list:
    """Steps of the GPS track that its velocity does not explain: for consecutive fixes less than
    STEP_MAX_DT_S apart, the residual of the trapezoidal prediction ``x_i - x_{i-1} - (v_i +
    v_{i-1}) dt / 2`` (position-only fixes: of the linear prediction from the two fixes before)
    beyond STEP_SIGMAS of its sigma per axis (from the fixes' covariances, plus a jerk or
    acceleration allowance): for white fixes the squared ratio is chi-square with 3 degrees of
    freedom, exceeded at 6 sigma with probability 7.5e-8 per pair.
    Returns ``[(t_ns, size_m, sigmas)]`` at the fix after the step."""
    if gps is None or len(gps.t_ns) < 3:
        return []
    t = np.asarray(gps.t_ns, np.int64)
    x = np.asarray(gps.x_e, float)
    trP = np.trace(np.asarray(gps.P_x, float), axis1=1, axis2=2)
    dt = np.diff(t) / NS
    has_v = gps.v_e is not None and gps.P_v is not None
    v = np.asarray(gps.v_e, float) if has_v else np.full_like(x, np.nan)
    trV = np.trace(np.asarray(gps.P_v, float), axis1=1, axis2=2) if has_v else np.full(t.size, np.nan)
    with np.errstate(invalid="ignore"):
        res = x[1:] - x[:-1] - 0.5 * (v[1:] + v[:-1]) * dt[:, None]
        var = (trP[1:] + trP[:-1] + 0.25 * dt ** 2 * (trV[1:] + trV[:-1])) / 3.0 + (STEP_JERK * dt ** 3 / 12.0) ** 2
        # position only: x_i - x_{i-1} - r (x_{i-1} - x_{i-2}), r = dt_i / dt_{i-1}
        dt_prev = np.concatenate([[np.nan], dt[:-1]])
        r = dt / dt_prev
        xm2 = np.vstack([np.full((1, 3), np.nan), x[:-2]])
        res_p = x[1:] - x[:-1] - r[:, None] * (x[:-1] - xm2)
        var_p = ((trP[1:] + (1 + r) ** 2 * trP[:-1] + r ** 2 * np.concatenate([[np.nan], trP[:-2]])) / 3.0
                 + (STEP_ACCEL * dt * (dt + dt_prev) / 2.0) ** 2)
        use_v = np.all(np.isfinite(res), axis=1) & np.isfinite(var)
        res = np.where(use_v[:, None], res, res_p)
        var = np.where(use_v, var, var_p)
        size = np.linalg.norm(res, axis=1)
        k = size / np.sqrt(var)       # in sigmas per axis: k^2 is chi-square(3) for white fixes
        hit = np.isfinite(k) & (k > STEP_SIGMAS) & (dt <= STEP_MAX_DT_S)
    return [(int(t[i + 1]), float(size[i]), float(k[i])) for i in np.flatnonzero(hit)]


def _share_rejected(recs, kinds, t0: int) -> tuple:
    """Offered and rejected GPS blocks of ``kinds`` stamped at or after ``t0``."""
    n = r = 0
    for d in recs.values():
        if d["kind"] in kinds:
            m = d["t"] >= t0
            n += int(m.sum())
            r += int((~d["ok"][m]).sum())
    return n, r


def _tail_start(recs, a: int, b: int) -> int:
    """Start of the tail (module constants): the last max(TAIL_S, TAIL_SHARE x window), moved back
    to hold at least TAIL_MIN_FIXES offered GPS fixes."""
    t0 = b - int(max(TAIL_S, TAIL_SHARE * (b - a) / NS) * NS)
    fixes = np.unique(np.concatenate([d["t"] for d in recs.values() if d["kind"] in GPS_KINDS] or [np.empty(0, np.int64)]))
    if fixes.size >= TAIL_MIN_FIXES:
        t0 = min(t0, int(fixes[-TAIL_MIN_FIXES]))
    return max(a, t0)


def _source_stats(d: dict, t_tail: int, a: int, b: int) -> dict:
    dof = DOF[d["kind"]]
    why: dict = {}
    for w, ok in zip(d["why"], d["ok"]):
        if not ok:
            why[w or "?"] = why.get(w or "?", 0) + 1
    n = int(d["t"].size)
    tail = d["t"] >= t_tail
    floor = 2.0 if d["kind"] in GPS_KINDS else 5.0
    return {"kind": d["kind"], "dof": dof, "offered": n, "accepted": int(d["ok"].sum()), "non_finite": d["missing"],
            "rejected": dict(sorted(why.items(), key=lambda kv: -kv[1])),
            "rejected_share": float(np.mean(~d["ok"])) if n else 0.0,
            "nis": _nis(d["nis"][d["ok"]], dof),
            "tail": {"offered": int(tail.sum()), "rejected_share": float(np.mean(~d["ok"][tail])) if tail.any() else 0.0,
                     "nis": _nis(d["nis"][d["ok"] & tail], dof)},
            "gaps": gaps(d["t"], a, b, _gap_threshold(d["t"], floor))}


def statistics(res, inputs, gps, tuning, cam_numbers) -> dict:
    """The figures :func:`judge` reads (module docstring), JSON-ready.

    Parameters
    ----------
    res : nav.navigator.NavResult
    inputs : scenarios.replay.inputs.ReplayInputs (its ``notes``: the log reader's warnings)
    gps : nav.navigator.GpsData or None, the fixes offered to the filter
    tuning : nav.tuning.Tuning
    cam_numbers : camera numbers of the filter's camera indices
    """
    from nav.recovery import gap_threshold_s
    from nav.tuning import consistency_warnings
    a, b = int(res.t_ns[0]), int(res.t_ns[-1])
    tp = inputs.mission_time
    recs = _records(res.innovations, cam_numbers)
    t_tail = _tail_start(recs, a, b)
    sensors = {src: _source_stats(d, t_tail, a, b) for src, d in sorted(recs.items())}
    imu_gap = gaps(res.t_ns, a, b, tuning.max_imu_gap_s)
    imu_gap["recovery_threshold_s"] = gap_threshold_s((res.t_ns - a) / NS, tuning)
    warnings = list(getattr(inputs, "notes", [])) + consistency_warnings(tuning)
    for k, what in (("imu_nonfinite", "non-finite"), ("imu_saturated", "saturated"),
                    ("imu_time_not_increasing", "not increasing in time")):
        if res.rejected.get(k):
            warnings.append(f"IMU: {res.rejected[k]} samples {what}, replaced by the last good sample or dropped")
    recs_out = recovery_rows(res.recoveries, cam_numbers, tp)
    t_rec = max((r["t_ns"] for r in _reinitialisations(recs_out)), default=None)
    after = _share_rejected(recs, GPS_KINDS, t_rec + 1) if t_rec is not None else (0, 0)
    pos_sig = np.sqrt(res.P_diag[:, res.layout["dx"]]).max(axis=1)
    gps_n, gps_r = _share_rejected(recs, GPS_KINDS, a)
    return {"window_ns": [a, b], "window_tplus_s": [float(tp(a)), float(tp(b))],
            "tail_from_ns": t_tail, "tail_from_tplus_s": float(tp(t_tail)),
            "sensors": sensors,
            "gps_offered_blocks": gps_n, "gps_rejected_blocks": gps_r,
            "imu_gaps": imu_gap, "recoveries": recs_out,
            "after_last_recovery": {"offered": after[0], "rejected": after[1]},
            "gps_steps": [{"t_ns": t, "tplus_s": float(tp(t)), "size_m": s, "sigmas": k} for t, s, k in gps_steps(gps)],
            "position_sigma_m": {"final": float(pos_sig[-1]), "max": float(pos_sig.max()),
                                 "max_tplus_s": float(tp(res.cov_t_ns[int(np.argmax(pos_sig))]))},
            "imu_ends_before_gps_s": _imu_short(inputs, b),
            "warnings": warnings,
            "truncated": any("truncated" in w or "damaged" in w for w in warnings),
            "misalignment_beyond_prior": _beyond_prior(res, tuning, cam_numbers)}


def _beyond_prior(res, tuning, cam_numbers) -> list:
    """The cameras whose final estimated misalignment lies beyond ``MISALIGNMENT_PRIOR_SIGMAS``
    of its prior (``camera_misalignment.sigma``) on a body axis: ``{camera, psi_c_deg,
    prior_sigma_deg}``. The filter's misalignment is a small-angle state about the camera file's
    mounting, so an estimate that far out says the mounting or the estimate is wrong."""
    g = tuning.camera_misalignment
    if not (g.estimated and len(res.misalignment_t_ns)):
        return []
    lim = MISALIGNMENT_PRIOR_SIGMAS * g.sigma
    return [{"camera": _camera_name(c, cam_numbers),
             "psi_c_deg": np.degrees(res.misalignment[-1, c]).round(3).tolist(),
             "prior_sigma_deg": float(np.degrees(g.sigma))}
            for c in range(res.misalignment.shape[1]) if np.any(np.abs(res.misalignment[-1, c]) > lim)]


def _imu_short(inputs, b: int) -> float:
    """Seconds by which the log's GPS goes on after its IMU record when the solution ends with
    the IMU record (0 when it does not, or when the window ends earlier)."""
    imu, gps = getattr(inputs, "imu", None), getattr(inputs, "gps", None)
    if imu is None or gps is None or not len(gps.t_ns) or b < int(imu.t_ns[-1]):
        return 0.0
    return max(0.0, float(int(gps.t_ns[-1]) - int(imu.t_ns[-1])) / NS)



def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def recovery_rows(recoveries, cam_numbers, tp=lambda t_ns: float("nan")) -> list:
    """``NavResult.recoveries`` as JSON-ready rows ``{t_ns, tplus_s, reason, details}`` (``tp``:
    stamp to T+ seconds); a re-opened camera's details gain its ``camera_name``."""
    rows = [{"t_ns": int(t), "tplus_s": float(tp(t)), "reason": r,
             "details": {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in det.items()}}
            for t, r, det in recoveries]
    for r in rows:
        if r["reason"] == CAMERA_RECOVERY:
            r["details"]["camera_name"] = _camera_name(r["details"]["camera"], cam_numbers)
    return rows


def _reinitialisations(rows: list) -> list:
    """The rows of :func:`recovery_rows` that re-initialised the state from GPS (an IMU gap or a
    divergence), not the re-opened camera misalignments."""
    return [r for r in rows if r["reason"] != CAMERA_RECOVERY]


def _camera_name(c: int, cam_numbers) -> str:
    """``camera_<k>``, the log's name of the filter's camera index ``c``."""
    return source_name("hor", c, cam_numbers).split("/")[0]


def recovery_text(r: dict) -> str:
    """One recovery row (:func:`recovery_rows`) in words, without its time."""
    d = r["details"]
    if r["reason"] == CAMERA_RECOVERY:
        return f"{d['camera_name']}: misalignment re-opened after {d['gated_vectors']} of its vectors in a row were gated"
    what = f"{d['gap_s']:.1f} s IMU gap" if "gap_s" in d else f"{d.get('gated_fixes', '?')} gated GPS fixes"
    return (f"re-initialised from GPS ({r['reason']}: {what}; position moved "
            f"{d.get('position_jump_m', float('nan')):.1f} m)")


def _failed(s: dict) -> list:
    """The FAILED rules (docs/replay.md "Verdict"), each a reason string."""
    out = []
    sens = s["sensors"]
    offered = sum(d["offered"] for d in sens.values())
    if not offered:
        return ["no measurement offered to the filter: the solution is free-inertial"]
    if not sum(d["accepted"] for d in sens.values()):
        return [f"none of the {offered} measurements accepted: the solution is free-inertial"]
    tail = f"the last part of the flight (from T+{s['tail_from_tplus_s']:.1f} s)"
    for src, d in sens.items():
        if d["kind"] not in GPS_KINDS:
            continue
        why = ", ".join(f"{k}: {v}" for k, v in d["rejected"].items())
        if d["rejected_share"] > REJECTED_FAIL:
            out.append(f"{src}: {_pct(d['rejected_share'])} of {d['offered']} fixes rejected ({why})")
        elif d["tail"]["offered"] and d["tail"]["rejected_share"] > TAIL_REJECTED_FAIL:
            out.append(f"{src}: {_pct(d['tail']['rejected_share'])} of the {d['tail']['offered']} fixes of {tail} "
                       "rejected: the filter did not recover")
        nt = d["tail"]["nis"]
        if nt and nt["mean"] > nt["gross_limit"]:
            out.append(f"{src}: NIS mean {nt['mean']:.2f} over {tail} ({nt['n']} fixes), 95 % band "
                       f"{nt['band95'][0]:.2f}..{nt['band95'][1]:.2f}, gross limit {nt['gross_limit']:.2f}: the "
                       "solution and the fixes disagree")
    ar = s["after_last_recovery"]
    if ar["offered"] >= TAIL_MIN_FIXES and ar["rejected"] > AFTER_RECOVERY_FAIL * ar["offered"]:
        last = _reinitialisations(s["recoveries"])[-1]
        out.append(f"GPS rejections continue after the last recovery (T+{last['tplus_s']:.1f} s): "
                   f"{ar['rejected']} of {ar['offered']} blocks")
    div = [r for r in s["recoveries"] if r["reason"] == "divergence"]
    if len(div) >= DIVERGENCES_FAIL:
        out.append(f"the filter diverged {len(div)} times (re-initialised at "
                   + ", ".join(f"T+{r['tplus_s']:.1f}" for r in div[:3]) + (", ..." if len(div) > 3 else "")
                   + " s): the IMU and the GPS disagree")
    followed = {}
    for r in div:
        for p in s["gps_steps"]:
            if 0 <= r["t_ns"] - p["t_ns"] <= STEP_BEFORE_RECOVERY_S * NS:
                followed.setdefault(p["t_ns"], (p, r))
    if followed:
        p, r = max(followed.values(), key=lambda pr: pr[0]["size_m"])
        more = f" ({len(followed) - 1} more such steps)" if len(followed) > 1 else ""
        out.append(f"the GPS track steps by {p['size_m']:.0f} m at T+{p['tplus_s']:.1f} s ({p['sigmas']:.0f} sigma; "
                   f"its velocity does not explain it) and the filter re-initialised onto the fixes after it at "
                   f"T+{r['tplus_s']:.1f} s{more}: the fixes before or after the step are wrong")
    vis = [d for d in sens.values() if d["kind"] not in GPS_KINDS]
    n_vis, a_vis = sum(d["offered"] for d in vis), sum(d["accepted"] for d in vis)
    if n_vis >= VISION_MIN and n_vis - a_vis > VISION_REJECTED_FAIL * n_vis:
        out.append(f"{n_vis - a_vis} of {n_vis} camera vectors rejected: the attitude and the cameras disagree")
    ps = s["position_sigma_m"]
    if ps["final"] > POS_SIGMA_FAIL_M:
        out.append(f"position sigma at the end {ps['final']:.0f} m (> {POS_SIGMA_FAIL_M:.0f} m): the position is not "
                   "observed")
    return out


def _degraded(s: dict) -> tuple:
    """The DEGRADED rules (docs/replay.md "Verdict"): (reasons, notes)."""
    out, notes = [], []
    if s["truncated"]:
        out.append("input truncated: " + next(w for w in s["warnings"] if "truncated" in w or "damaged" in w))
    other = [w for w in s["warnings"] if "truncated" not in w and "damaged" not in w]
    if other:
        out.append(f"{len(other)} input warning(s): " + other[0] + (" ..." if len(other) > 1 else ""))
    rec = _reinitialisations(s["recoveries"])
    for r in rec[:3]:
        out.append(f"{recovery_text(r)} at T+{r['tplus_s']:.1f} s")
    if len(rec) > 3:
        out.append(f"{len(rec) - 3} more re-initialisations, the last at T+{rec[-1]['tplus_s']:.1f} s")
    cams = {}
    for r in s["recoveries"]:
        if r["reason"] == CAMERA_RECOVERY:
            cams.setdefault(r["details"]["camera_name"], []).append(r)
    for rs in cams.values():
        out.append(f"{recovery_text(rs[0])} at T+{rs[0]['tplus_s']:.1f} s"
                   + (f" ({len(rs)} times, the last at T+{rs[-1]['tplus_s']:.1f} s)" if len(rs) > 1 else "")
                   + ": its vectors and its misalignment estimate disagreed (an early gross vector, or a mounting the "
                   "camera file does not describe)")
    for m in s.get("misalignment_beyond_prior", []):
        out.append(f"{m['camera']}: misalignment estimated {m['psi_c_deg']} deg (body axes), beyond "
                   f"{MISALIGNMENT_PRIOR_SIGMAS:g} sigma of its {m['prior_sigma_deg']:g} deg prior: the camera file's "
                   "mounting may be off by more than the filter's small-angle misalignment holds")
    if s.get("imu_ends_before_gps_s", 0.0) > IMU_SHORT_DEGRADED_S:
        out.append(f"the IMU record ends {s['imu_ends_before_gps_s']:.1f} s before the GPS record: the solution stops "
                   "with the IMU")
    g = s["imu_gaps"]
    if g["count"]:
        out.append(f"{g['count']} IMU gap(s) over {g['threshold_s']:g} s, longest {g['longest_s']:.2f} s")
    for src, d in s["sensors"].items():
        gps = d["kind"] in GPS_KINDS
        if gps and d["rejected_share"] > GPS_REJECTED_DEGRADED:
            out.append(f"{src}: {_pct(d['rejected_share'])} of {d['offered']} fixes rejected")
        if not gps and d["rejected_share"] > VISION_REJECTED_DEGRADED:
            out.append(f"{src}: {_pct(d['rejected_share'])} of {d['offered']} vectors rejected")
        n = d["nis"]
        if n and n["mean"] > max(n["band95"][1], NIS_DEGRADED_FACTOR * d["dof"]):
            out.append(f"{src}: NIS mean {n['mean']:.2f} above its 95 % band {n['band95'][0]:.2f}..{n['band95'][1]:.2f}"
                       ": the covariance is optimistic")
        elif n and n["mean"] > n["band95"][1]:
            notes.append(f"{src}: NIS mean {n['mean']:.2f} slightly above its 95 % band "
                         f"{n['band95'][0]:.2f}..{n['band95'][1]:.2f}")
        elif n and gps and n["mean"] < min(n["band95"][0], NIS_GPS_LOW_FACTOR * d["dof"]):
            out.append(f"{src}: NIS mean {n['mean']:.3g} far below its 95 % band {n['band95'][0]:.2f}.."
                       f"{n['band95'][1]:.2f}: the fixes' sigmas overstate their errors (units?), the GPS is "
                       "under-weighted")
        elif n and n["mean"] < n["band95"][0]:
            notes.append(f"{src}: NIS mean {n['mean']:.2f} below its 95 % band {n['band95'][0]:.2f}..{n['band95'][1]:.2f}"
                         ": the covariance is conservative")
        if gps and d["gaps"]["longest_s"] > GPS_OUTAGE_DEGRADED_S and src == "gps/position":
            out.append(f"GPS outage of {d['gaps']['longest_s']:.1f} s")
    steps = s["gps_steps"]
    if steps:
        p = max(steps, key=lambda p: p["size_m"])
        out.append(f"{len(steps)} step(s) in the GPS track its velocity does not explain (largest {p['size_m']:.0f} m at "
                   f"T+{p['tplus_s']:.1f} s)")
    return out, notes


def judge(stats: dict) -> Verdict:
    """The verdict from :func:`statistics`: FAILED when a FAILED rule holds, else DEGRADED when a
    DEGRADED rule holds, else OK (docs/replay.md "Verdict")."""
    failed = _failed(stats)
    degraded, notes = _degraded(stats)
    if failed:
        return Verdict("FAILED", failed, notes, stats, degraded)
    return Verdict("DEGRADED" if degraded else "OK", degraded, notes, stats)


def assess(solution) -> Verdict:
    """The verdict of a :class:`scenarios.replay.steps.Solution`. Never raises: a solution whose
    statistics cannot be computed is FAILED, with the error as the reason (no verdict, no
    success)."""
    from nav.tuning import Tuning
    fl = solution.flight
    try:
        return judge(statistics(solution.nav, fl.inputs, fl.gps, solution.tuning or Tuning(), fl.cam_numbers))
    except Exception as e:  # noqa: BLE001 - reported as the verdict's reason
        return Verdict("FAILED", [f"the verdict could not be computed ({type(e).__name__}: {e})"])


__all__ = ["Verdict", "statistics", "judge", "assess", "mean_band", "gross_limit", "gps_steps", "gaps",
           "EXIT_OK", "EXIT_FAILED", "EXIT_DEGRADED_STRICT"]
