"""Validation report of an import: sample rates, gaps, stamp order, saturation, unit plausibility.

Checks (thresholds in ``mapping.Checks``, overridable in the mapping's ``[checks]`` table):

* **rates and gaps** (every stream): median step and rate, jitter (std of the steps / median), gaps
  (steps > ``gap_factor`` x median: count, the longest ones with their T+), stamps that were out of
  order or repeated (when the table asked to sort them).
* **saturation** (IMU, per axis): the samples at the largest magnitude of the axis form flat tops
  -- runs of >= max(5 samples, 0.25 s) at exactly that magnitude (a clipped, then quantised output
  is constant) -- or reach the declared ``gyro_range`` / ``accel_range``. A warning: the ATEK gyros
  saturate during the spin (003 §7), and the filter starts after it.
* **gyro units**: |w| above ``gyro_max_rad_s`` (60 rad/s: beyond any sounding-rocket spin) in more
  than 0.1 % of the samples, or the quietest tenth of the record (10th percentile of |w|: pad and
  coast) above ``gyro_quiet_max_rad_s`` (5 rad/s), is what deg/s read as rad/s looks like
  (x 57.3): error.
* **accelerometer units**: at rest (1 s windows with the gyro quiet, |w| < 0.1 rad/s, and every
  accelerometer axis steady to 2 % of |f|, |f| > 0.3 m/s^2 to exclude free fall) |f| must be about
  g: between ``accel_rest_min`` and ``accel_rest_max``. |f| ~ 1 means g declared as m/s^2, ~96
  m/s^2 declared as g, ~9.8e3 mg declared as m/s^2: error. Without a rest period (>= 3 windows)
  the check is skipped and says so.
* **GPS**: geodetic heights outside [``height_min_m``, ``height_max_m``], speeds above
  ``speed_max_mps`` (errors: wrong length or velocity unit), and the velocity magnitude against the
  rate of change of the positions while moving (ratio outside [0.5, 2]: warning, unit or frame of
  the velocity columns).

Findings are ``info`` / ``warning`` / ``error``; the import stops on errors unless told to go on
(``--force`` or ``errors_fatal = false``).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from nav import earth
from nav.timescales import format_utc
from scenarios.atomic import atomic_output, atomic_write_text

from .mapping import Checks
from .units import G0


@dataclass
class Finding:
    level: str  # "info", "warning", "error"
    stream: str
    check: str
    message: str


@dataclass
class StreamStats:
    name: str
    samples: int
    t_first: str
    t_last: str
    t_first_s: float  # T+ [s]
    t_last_s: float
    rate_hz: float
    step_median_s: float
    step_min_s: float
    step_max_s: float
    jitter: float  # std(step) / median(step)
    gaps: int
    longest_gaps: list = field(default_factory=list)  # [(T+ start [s], length [s])]


@dataclass
class Report:
    streams: dict = field(default_factory=dict)
    findings: list = field(default_factory=list)
    liftoff_ns: int = 0
    times: dict = field(default_factory=dict, repr=False)  # stream -> stamps, for T+ in messages

    def add(self, level, stream, check, message) -> None:
        self.findings.append(Finding(level, stream, check, message))

    @property
    def errors(self) -> list[Finding]:
        return [f for f in self.findings if f.level == "error"]

    @property
    def warnings(self) -> list[Finding]:
        return [f for f in self.findings if f.level == "warning"]

    def text(self) -> str:
        lines = ["stream      samples    T+ first    T+ last     rate [Hz]  jitter   gaps"]
        for s in self.streams.values():
            lines.append(f"{s.name:<11} {s.samples:>8d}  {s.t_first_s:>9.3f}  {s.t_last_s:>9.3f}  {s.rate_hz:>10.4g}"
                         f"  {s.jitter:>6.2g}  {s.gaps:>5d}")
        for f in self.findings:
            lines.append(f"{f.level.upper():<8} {f.stream}: {f.message}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"liftoff_utc": format_utc(self.liftoff_ns), "streams": {k: asdict(v) for k, v in self.streams.items()},
                "findings": [asdict(f) for f in self.findings],
                "errors": len(self.errors), "warnings": len(self.warnings)}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)


# ------------------------------------------------------------------------------------------------
def time_stats(report: Report, name: str, t_ns: np.ndarray, checks: Checks) -> StreamStats | None:
    """Rates, jitter and gaps of one stream (stamps sorted, int64 ns)."""
    n = len(t_ns)
    if n == 0:
        report.add("warning", name, "empty", "no samples")
        return None
    tp = (t_ns - report.liftoff_ns) / 1e9
    d = np.diff(t_ns) / 1e9
    med = float(np.median(d)) if n > 1 else 0.0
    gaps = np.flatnonzero(d > checks.gap_factor * med) if n > 1 else np.zeros(0, int)
    longest = gaps[np.argsort(-d[gaps], kind="stable")][:5] if len(gaps) else []
    st = StreamStats(name, n, format_utc(int(t_ns[0])), format_utc(int(t_ns[-1])), float(tp[0]), float(tp[-1]),
                     1.0 / med if med > 0 else 0.0, med, float(d.min()) if n > 1 else 0.0,
                     float(d.max()) if n > 1 else 0.0, float(np.std(d) / med) if med > 0 else 0.0, len(gaps),
                     [(float(tp[i]), float(d[i])) for i in longest])
    report.streams[name] = st
    if len(gaps):
        g = ", ".join(f"T+{a:.3f} s ({b:.3f} s)" for a, b in st.longest_gaps)
        report.add("warning", name, "gaps", f"{len(gaps)} gap(s) longer than {checks.gap_factor:g} x the median "
                                            f"step {med * 1e3:.3g} ms; longest: {g}")
    return st


def _runs(mask: np.ndarray) -> np.ndarray:
    """Lengths of the runs of True in a 1-D bool array."""
    if not mask.any():
        return np.zeros(0, int)
    m = np.r_[False, mask, False].astype(np.int8)
    d = np.diff(m)
    return np.flatnonzero(d == -1) - np.flatnonzero(d == 1)


def check_saturation(report: Report, stream: str, what: str, x: np.ndarray, rate_hz: float,
                     declared: float | None, unit: str, scale: float, floor: float = 0.0) -> None:
    """Flat tops at the largest magnitude of each axis (above ``floor``, entered and left at one
    resolution step per sample or more), or samples at the declared range."""
    axes = "xyz"
    min_run = max(5, int(round(0.25 * rate_hz)))
    for j in range(x.shape[1]):
        a = np.abs(x[:, j])
        if declared is not None:
            at = a >= declared * (1.0 - 1e-6)
            if at.any():
                report.add("warning", stream, "saturation",
                           f"{what} {axes[j]}: {int(at.sum())} samples ({at.mean():.2%}) at the declared range "
                           f"{declared / scale:g} {unit}; first at T+{_tplus(report, stream, int(np.argmax(at))):.3f} s")
                continue
        m = a.max() if len(a) else 0.0
        if m <= floor:
            continue
        at = a >= m * (1.0 - 1e-9)
        runs = _runs(at)
        if len(runs) and runs.max() >= min_run and _steep_flat_top(a, at, min_run):
            report.add("warning", stream, "saturation",
                       f"{what} {axes[j]}: flat-topped at |{axes[j]}| = {m / scale:.6g} {unit} for {int(at.sum())} "
                       f"samples ({at.sum() / rate_hz:.2f} s, longest run {int(runs.max())}); "
                       f"first at T+{_tplus(report, stream, int(np.argmax(at))):.3f} s: sensor saturated (clipped)")


def _steep_flat_top(a: np.ndarray, at: np.ndarray, n: int) -> bool:
    """Whether the magnitude ``a`` enters and leaves a run of ``at`` (at least ``n`` long; a run at
    the record's start or end has one side) at one resolution step per sample or more, averaged over
    the ``n`` samples beside the run. A clipped signal is cut while it still changes; a quantised
    rate that changes by less than one step per sample on either side of its top holds that value
    for seconds (a slow peak, a rate that steps and then stays) and is not clipping. The resolution
    is the smallest non-zero change between samples."""
    d = np.abs(np.diff(a))
    if not (d > 0).any():
        return True
    q = d[d > 0].min()
    m = np.r_[False, at, False].astype(np.int8)
    starts, ends = np.flatnonzero(np.diff(m) == 1), np.flatnonzero(np.diff(m) == -1)
    for s, e in zip(starts, ends):
        if e - s < n:
            continue
        sides = [x for x in (d[max(0, s - n):s], d[e - 1:e - 1 + n]) if len(x)]
        if all(x.mean() >= q for x in sides):
            return True
    return False


def _tplus(report: Report, stream: str, i: int) -> float:
    t = report.times.get(stream)
    return float((t[i] - report.liftoff_ns) / 1e9) if t is not None else float("nan")


def check_gyro_units(report: Report, w: np.ndarray, unit: str, checks: Checks) -> None:
    mag = np.linalg.norm(w, axis=1)
    p10 = float(np.percentile(mag, 10))
    big = mag > checks.gyro_max_rad_s
    hint = (f"this looks like deg/s declared as {unit!r} (deg/s read as rad/s is 57.3 x too large); "
            "check [imu.gyro] unit")
    if big.mean() > 1e-3:
        report.add("error", "imu", "gyro_units",
                   f"|w| exceeds {checks.gyro_max_rad_s:g} rad/s in {big.mean():.1%} of the samples (max "
                   f"{mag.max():.4g} rad/s = {mag.max() / (2 * np.pi):.3g} rev/s): {hint}")
    elif p10 > checks.gyro_quiet_max_rad_s:
        report.add("error", "imu", "gyro_units",
                   f"the quietest tenth of the record still turns at |w| >= {p10:.4g} rad/s (10th percentile; "
                   f"a coast or the pad is below ~0.1 rad/s): {hint}")
    else:
        report.add("info", "imu", "gyro_units", f"|w|: 10th percentile {p10:.3g} rad/s, max {mag.max():.4g} rad/s "
                                                f"(plausible in rad/s)")


def rest_windows(w: np.ndarray, f: np.ndarray, rate_hz: float) -> np.ndarray:
    """Mean |f| of the 1 s windows where the vehicle is at rest (module docstring)."""
    m = max(5, int(round(rate_hz)))
    nw = len(f) // m
    if nw == 0:
        return np.zeros(0)
    fw = f[: nw * m].reshape(nw, m, 3)
    ww = np.linalg.norm(w[: nw * m], axis=1).reshape(nw, m)
    mean = fw.mean(axis=1)
    level = np.linalg.norm(mean, axis=1)
    steady = fw.std(axis=1).max(axis=1) < 0.02 * level
    quiet = ww.mean(axis=1) < 0.1
    return level[steady & quiet & (level > 0.3)]


def check_accel_units(report: Report, w: np.ndarray, f: np.ndarray, rate_hz: float, unit: str, checks: Checks) -> None:
    lv = rest_windows(w, f, rate_hz)
    if len(lv) < 3:
        report.add("info", "imu", "accel_units", "no rest period found (>= 3 s steady, gyro quiet): accelerometer "
                                                 "unit check skipped")
        return
    L = float(np.median(lv))
    lo, hi = checks.accel_rest_min, checks.accel_rest_max
    if lo <= L <= hi:
        report.add("info", "imu", "accel_units", f"|f| at rest = {L:.4g} m/s^2 over {len(lv)} s (plausible)")
        return
    guesses = [("g", G0), ("mg", 1e-3 * G0), ("m/s^2", 1.0), ("ft/s^2", 0.3048)]
    fits = [name for name, k in guesses if lo <= L * k / _factor_of(unit) <= hi and name != unit]
    hint = f"; it looks like {fits[0]!r} declared as {unit!r}" if fits else ""
    report.add("error", "imu", "accel_units", f"|f| at rest = {L:.4g} m/s^2 over {len(lv)} s, expected about "
                                              f"{G0:.2f} (between {lo:g} and {hi:g}){hint}; check [imu.accel] unit")


def _factor_of(unit: str) -> float:
    from .units import ACCEL, VELOCITY, normalise
    return ACCEL.get(normalise(unit), VELOCITY.get(normalise(unit), 1.0))


def check_imu(report: Report, imu, gyro_unit: str, accel_unit: str, checks: Checks) -> None:
    """Every IMU check; ``imu`` a ``tables.ImuData``."""
    report.times["imu"] = imu.t_ns
    st = time_stats(report, "imu", imu.t_ns, checks)
    if st is None:
        return
    if imu.order.sorted:
        report.add("warning", "imu", "order", f"stamps sorted: {imu.order.out_of_order} went back, "
                                              f"{imu.order.duplicates} duplicates dropped (first at {imu.order.first_row})")
    inc = imu.output == "increment"
    dt = imu.dt[:, None] if inc else 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.nan_to_num(imu.gyro / dt)
        f = np.nan_to_num(imu.accel / dt)
    rate = st.rate_hz or 1.0
    gr = imu.gyro_range / imu.dt.mean() if (inc and imu.gyro_range) else imu.gyro_range
    ar = imu.accel_range / imu.dt.mean() if (inc and imu.accel_range) else imu.accel_range
    check_saturation(report, "imu", "gyro", w, rate, gr, "deg/s", np.pi / 180.0, checks.saturation_gyro_min_rad_s)
    check_saturation(report, "imu", "accel", f, rate, ar, "m/s^2", 1.0, checks.saturation_accel_min)
    check_gyro_units(report, w, gyro_unit, checks)
    check_accel_units(report, w, f, rate, accel_unit, checks)


def check_gps(report: Report, gps, checks: Checks) -> None:
    report.times["gps"] = gps.t_ns
    st = time_stats(report, "gps", gps.t_ns, checks)
    if st is None:
        return
    if gps.sigma_default:
        report.add("warning", "gps", "sigma", f"uncertainties from defaults: {gps.sigma_default}; give "
                                              "position_sigma / velocity_sigma columns when the receiver logs them")
    if gps.dropped_rows:
        report.add("info", "gps", "no_fix", f"{gps.dropped_rows} row(s) without a position (no fix) dropped")
    if gps.order.sorted:
        report.add("warning", "gps", "order", f"stamps sorted: {gps.order.out_of_order} went back, "
                                              f"{gps.order.duplicates} duplicates dropped")
    r = np.linalg.norm(gps.position, axis=1)
    if np.any(r < 1e5):
        i = int(np.argmax(r < 1e5))
        report.add("error", "gps", "height", f"position {r[i]:.4g} m from the Earth's centre at T+"
                                             f"{_tplus(report, 'gps', i):.3f} s: not an ECEF position in metres "
                                             "(unit km? geodetic columns declared as ECEF?)")
        return
    _, _, h = earth.ecef_to_geodetic(gps.position)
    bad = (h < checks.height_min_m) | (h > checks.height_max_m)
    if bad.any():
        i = int(np.argmax(bad))
        report.add("error", "gps", "height", f"{int(bad.sum())} fix(es) at implausible heights, first {h[i] / 1e3:.4g} km "
                                             f"at T+{_tplus(report, 'gps', i):.3f} s (allowed {checks.height_min_m / 1e3:g} "
                                             f"to {checks.height_max_m / 1e3:g} km): check the position unit and frame")
    else:
        report.add("info", "gps", "height", f"heights {h.min() / 1e3:.4g} to {h.max() / 1e3:.4g} km")
    if not gps.has_velocity:
        return
    s = np.linalg.norm(gps.velocity, axis=1)
    if np.any(s > checks.speed_max_mps):
        i = int(np.argmax(s > checks.speed_max_mps))
        report.add("error", "gps", "speed", f"{int((s > checks.speed_max_mps).sum())} fix(es) faster than "
                                            f"{checks.speed_max_mps:g} m/s, first {s[i]:.4g} m/s at T+"
                                            f"{_tplus(report, 'gps', i):.3f} s: check the velocity unit")
    if len(gps.t_ns) > 2:
        dt = np.diff(gps.t_ns) / 1e9
        pr = np.linalg.norm(np.diff(gps.position, axis=0), axis=1) / dt
        vm = 0.5 * (s[1:] + s[:-1])
        moving = (pr > 20.0) & (dt < 5.0)
        if moving.sum() >= 3:
            ratio = float(np.median(vm[moving] / pr[moving]))
            lvl = "info" if 0.5 <= ratio <= 2.0 else "warning"
            report.add(lvl, "gps", "velocity_consistency",
                       f"|v| / |dx/dt| = {ratio:.4g} (median over {int(moving.sum())} moving steps)"
                       + ("" if lvl == "info" else ": the velocity columns disagree with the positions "
                                                   "(unit or frame of [gps.velocity]?)"))


def check_footage(report: Report, fp, checks: Checks) -> None:
    name = f"camera_{fp.k}"
    report.times[name] = fp.t_ns
    time_stats(report, name, fp.t_ns, checks)
    for note in fp.notes:
        report.add("info", name, "footage", note)


def check_overlap(report: Report, streams: dict) -> None:
    """GPS / camera stamps outside the IMU's time span: a warning, an error when none is inside."""
    imu = streams.get("imu")
    if imu is None or not len(imu):
        return
    for name, t in streams.items():
        if name == "imu" or not len(t):
            continue
        out = (t < imu[0]) | (t > imu[-1])
        if out.all() and len(imu) > 1:
            report.add("error", name, "overlap", f"all {len(t)} stamps lie outside the IMU record "
                                                 f"(T+{(imu[0] - report.liftoff_ns) / 1e9:.3f} to "
                                                 f"T+{(imu[-1] - report.liftoff_ns) / 1e9:.3f} s; first stamp T+"
                                                 f"{(t[0] - report.liftoff_ns) / 1e9:.6g} s): check the time base, "
                                                 "unit and start of this stream")
        elif out.any():
            report.add("warning", name, "overlap", f"{int(out.sum())} of {len(t)} stamps lie outside the IMU record "
                                                   f"(T+{(imu[0] - report.liftoff_ns) / 1e9:.3f} to "
                                                   f"T+{(imu[-1] - report.liftoff_ns) / 1e9:.3f} s)")


def save_report(report: Report, out_dir: Path, imu=None, gps=None, footages=()) -> tuple[Path, Path]:
    """Write ``report.json`` and ``report.png`` (IMU rates, specific force, step sizes, GPS height and
    speed, camera frame stamps against T+) into ``out_dir``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    js = atomic_write_text(out_dir / "report.json", report.to_json())
    fig, ax = plt.subplots(4, 1, figsize=(11, 11), sharex=True)
    t0 = report.liftoff_ns
    if imu is not None and len(imu.t_ns):
        s = max(1, len(imu.t_ns) // 20000)
        tp = (imu.t_ns[::s] - t0) / 1e9
        dt = imu.dt[::s, None] if imu.output == "increment" else 1.0
        ax[0].plot(tp, np.degrees(imu.gyro[::s] / dt), lw=0.6)
        ax[0].set_ylabel("gyro [deg/s]")
        ax[0].legend(["x", "y", "z"], loc="upper right")
        ax[1].plot(tp, imu.accel[::s] / dt, lw=0.6)
        ax[1].set_ylabel("accel [m/s^2]")
        d = np.diff(imu.t_ns) / 1e6
        ax[2].plot((imu.t_ns[1:] - t0) / 1e9, d, ".", ms=1, label="IMU")
    if gps is not None and len(gps.t_ns):
        d = np.diff(gps.t_ns) / 1e6
        ax[2].plot((gps.t_ns[1:] - t0) / 1e9, d, ".", ms=2, label="GPS")
        _, _, h = earth.ecef_to_geodetic(gps.position) if np.all(np.linalg.norm(gps.position, axis=1) > 1e5) \
            else (None, None, np.full(len(gps.t_ns), np.nan))
        tg = (gps.t_ns - t0) / 1e9
        ax[3].plot(tg, h / 1e3, label="GPS height [km]")
        if gps.has_velocity:
            ax[3].plot(tg, np.linalg.norm(gps.velocity, axis=1) / 1e3 * 100, label="GPS speed [km/s] x 100")
    for fp in footages:
        tf = (fp.t_ns - t0) / 1e9
        ax[3].plot(tf, np.full(len(tf), -5.0 * fp.k), "|", ms=6, label=f"camera {fp.k} frames")
    ax[2].set_ylabel("step [ms]")
    ax[2].set_yscale("log")
    ax[2].legend(loc="upper right")
    ax[3].legend(loc="upper right")
    ax[3].set_xlabel("T+ [s]")
    for f in report.findings:
        if f.level != "info":
            ax[0].set_title(f"{len(report.errors)} error(s), {len(report.warnings)} warning(s): see report.json",
                            color="red" if report.errors else "darkorange")
    fig.tight_layout()
    png = atomic_output(out_dir / "report.png", lambda tmp: fig.savefig(tmp, dpi=90, format="png"))
    plt.close(fig)
    return js, png


def validate(imu=None, gps=None, footages=(), *, checks: Checks = Checks(), liftoff_ns: int = 0,
             gyro_unit: str = "rad/s", accel_unit: str = "m/s^2", gps_spec=None) -> Report:
    """The report of one import (arrays already converted to SI, body / ECEF frames), with the
    physical cross-checks between the sensors (:mod:`.crosscheck`; ``gps_spec``: the mapping's
    ``[gps]``, to name the likely cause of a failure)."""
    rep = Report(liftoff_ns=int(liftoff_ns))
    streams = {}
    if imu is not None:
        check_imu(rep, imu, gyro_unit, accel_unit, checks)
        streams["imu"] = imu.t_ns
    if gps is not None:
        check_gps(rep, gps, checks)
        streams["gps"] = gps.t_ns
    for fp in footages:
        check_footage(rep, fp, checks)
        streams[f"camera_{fp.k}"] = fp.t_ns
    check_overlap(rep, streams)
    from .crosscheck import cross_check
    cross_check(rep, imu, gps, gps_spec, rep.streams["imu"].rate_hz if "imu" in rep.streams else None)
    return rep
