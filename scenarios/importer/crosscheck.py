"""Physical cross-checks between the sensors of an import: each compares two sensors through the
physics that links them, reports its statistic as an ``info`` finding and, when the sensors
disagree beyond what their noise explains, an ``error`` naming the likely cause.

* **GPS velocity against GPS position** (``gps_velocity``): the displacement over a baseline of
  about ``BASELINE_S`` against the trapezoid integral of the velocities over it, both in ECEF.
  Statistic: the median residual speed ``|dx - int v dt| / T`` [m/s]. A correct receiver gives the
  position noise over the baseline, ``~1.5 sqrt(2) sigma_p / T`` (0.6 m/s for 3 m fixes over 10 s;
  Doppler velocities add centimetres per second); a velocity in the wrong frame (NED read as ECEF),
  positions with latitude and longitude swapped, or angles in radians read as degrees give
  residuals of the order of the speed. Threshold: ``4 sqrt(2) sigma_p / T + 0.05 |dx| / T`` (the
  relative term covers receivers that filter or delay their velocity). Only fixes moving faster
  than 5 m/s count (at rest a frame error is invisible and harmless). The likely cause is found by
  re-reading the columns each way (NED as ECEF and back, lat/lon swapped, angles in radians) and
  naming the reading that fits.
* **specific force magnitude** (``specific_force``): ``|f|`` of the IMU against
  ``|dv/dt - g + 2 Omega x v|`` of the GPS (``nav.earth.gravity_e``) over 1 s intervals where the
  GPS value exceeds 3 m/s^2 (so that its noise, ~0.15 m/s^2 for 0.1 m/s velocities, stays below
  5 %) and the IMU's direction is steady (|mean f| within 2 % of mean |f|). Statistic: the median
  ratio IMU / GPS; a correct accelerometer is within its scale error (< 1 %) of 1, a wrong unit is
  off by 3.3 (ft/s^2), 9.8 (g) or more. Threshold: ratio outside [0.8, 1.25].
* **gyro against the rotation of the specific force** (``gyro_rotation``): the gyros are
  integrated (``nav.ins.propagate``) into an attitude with an arbitrary start; the specific force
  rotated with it must match the GPS specific force up to one constant rotation per 30 s window
  (Wahba's problem, solved by SVD). Statistic: the median over informative windows (the GPS
  specific force or the rotated IMU one turning by more than 10 deg within the window, |f| > 3
  m/s^2, no saturated gyro sample) of the RMS angle between the two after the fit. Correct gyros
  leave the GPS direction noise (~1 deg at 1 g) plus their drift over 30 s (< 0.1 deg for a
  tactical gyro); rad/s read as deg/s freezes the attitude and leaves the vehicle's turn (tens of
  degrees), deg/s read as rad/s spins it 57 times too fast. Threshold: 8 deg.
* **body axes** (``body_axes``): the body frame is x forward (the nose), y right, z down. At rest
  and in flight under load (|f| > 5 m/s^2 on the IMU) the specific force of a vehicle points along
  +x (thrust, a rocket on its rail), -z (the ground's or the wing's reaction) or -x (drag of a
  body moving nose first). Statistic: the mean of the unit specific-force vectors of those samples
  in the body frame; its largest component along +y, -y or +z (with the mean vector longer than
  0.5, i.e. a dominant direction) means the sensor axes differ from the body axes: an error asking
  for ``axes`` when the import has a GPS (a flight to navigate), a warning for an IMU table alone
  (a bench recording may lie on any side).
* **time lag between the IMU and the GPS** (``time_lag``): the same two specific-force
  magnitudes, the IMU's averaged over each GPS interval shifted by a lag ``L``, compared for lags
  within +-``LAG_SEARCH_S``; the lag of the smallest RMS difference is where the GPS stamps put the
  motion that the accelerometer saw. Ignition, burnout and manoeuvres make the RMS rise steeply
  away from the true lag (a 0.2 s shift doubles it on a rocket's boost); a flight without such
  events (a coast alone) leaves it flat, and the check says so instead of guessing. Statistic: the
  lag and the RMS at lag 0 and at the best lag. An offset of ``LAG_ERROR_S`` or more is an error
  (at 1 km/s, 0.1 s is 100 m of position that the filter cannot tell from a correct one, because
  a shifted ballistic arc is still a ballistic arc); its likely cause is named: GPS time read as
  UTC or back (the leap seconds), a time zone, or a receiver latency (``offset_s`` of the GPS time
  table corrects it). Smaller lags above ``LAG_WARN_S`` are a warning.

The checks need the IMU and a GPS with velocities (the GPS-velocity check needs only the GPS);
each reports why it was skipped otherwise.
"""
from __future__ import annotations

import numpy as np

from nav import earth, ins, timescales
from nav.rotation import angle_between

BASELINE_S = 10.0
MOVING_MPS = 5.0
F_MIN = 3.0
WINDOW_S = 30.0
GYRO_FIT_MAX_DEG = 8.0
FORCE_RATIO = (0.8, 1.25)
LAG_SEARCH_S = 30.0
LAG_ERROR_S = 0.1
LAG_WARN_S = 0.03
#: the RMS one second away from the best lag must exceed the best by this factor for the lag to count
LAG_CONTRAST = 1.2


def _baselines(t_s: np.ndarray, T: float):
    """Index pairs (i, j) with t_j - t_i the first step >= T (no larger than 2 T: no gaps)."""
    j = np.searchsorted(t_s, t_s + T, side="left")
    i = np.flatnonzero(j < len(t_s))
    j = j[i]
    ok = (t_s[j] - t_s[i]) <= 2.0 * T
    return i[ok], j[ok]


def _velocity_residual(t_s, x, v, T):
    i, j = _baselines(t_s, T)
    if i.size == 0:
        return None
    dt = np.diff(t_s)[:, None]
    C = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (v[1:] + v[:-1]) * dt, axis=0)])
    span = (t_s[j] - t_s[i])[:, None]
    dx = (x[j] - x[i]) / span
    iv = (C[j] - C[i]) / span
    moving = np.linalg.norm(dx, axis=1) > MOVING_MPS
    if moving.sum() < 3:
        return None
    e = np.linalg.norm(dx - iv, axis=1)[moving]
    s = np.linalg.norm(dx, axis=1)[moving]
    return float(np.median(e)), float(np.median(s)), float(np.median(span))


def _sigma_p(gps) -> float:
    P = np.asarray(gps.position_cov)
    tr = np.trace(P, axis1=1, axis2=2) / 3.0 if P.size else np.zeros(0)
    tr = tr[np.isfinite(tr) & (tr > 0)]
    return float(np.sqrt(np.median(tr))) if tr.size else 10.0


def check_gps_velocity(report, gps, spec) -> None:
    """GPS velocity against the derivative of the positions (module docstring)."""
    if not gps.has_velocity:
        report.add("info", "gps", "gps_velocity", "position-only fixes: velocity check skipped")
        return
    t = (gps.t_ns - gps.t_ns[0]) / 1e9
    r = _velocity_residual(t, gps.position, gps.velocity, BASELINE_S)
    if r is None:
        report.add("info", "gps", "gps_velocity", f"fewer than 3 baselines of {BASELINE_S:g} s moving faster than "
                                                  f"{MOVING_MPS:g} m/s: velocity check skipped")
        return
    e, s, T = r
    sp = _sigma_p(gps)
    thr = 4.0 * np.sqrt(2.0) * sp / T + 0.05 * s
    stat = (f"|dx - int v dt| / T = {e:.3g} m/s (median over {T:.3g} s baselines, median speed {s:.4g} m/s; "
            f"threshold {thr:.3g} m/s)")
    if e <= thr:
        report.add("info", "gps", "gps_velocity", stat)
        return
    k = _best_scale(t, gps.position, gps.velocity, T)
    rk = _velocity_residual(t, gps.position, gps.velocity * k, T) if np.isfinite(k) and k > 0 else None
    if rk is not None and rk[0] <= 4.0 * np.sqrt(2.0) * sp / T + 0.05 * rk[1]:
        # the directions agree, only the magnitudes differ: a unit (the velocity_consistency
        # warning of validate says so too); the filter's gate rejects such velocities
        report.add("warning", "gps", "gps_velocity", f"{stat}: the velocities point the right way but are "
                                                     f"{1 / k:.4g} x the position rate: check the velocity unit")
        return
    cause = _velocity_cause(gps, spec, t, T, thr)
    report.add("error", "gps", "gps_velocity", f"the velocities disagree with the positions: {stat}; {cause}")


def _best_scale(t, x, v, T) -> float:
    """Least-squares factor k of the velocity integrals onto the displacements (module docstring)."""
    i, j = _baselines(t, T)
    if i.size == 0:
        return float("nan")
    dt = np.diff(t)[:, None]
    C = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (v[1:] + v[:-1]) * dt, axis=0)])
    a, b = x[j] - x[i], C[j] - C[i]
    den = float(np.sum(b * b))
    return float(np.sum(a * b) / den) if den > 0 else float("nan")


def _velocity_cause(gps, spec, t, T, thr) -> str:
    x, v = gps.position, gps.velocity
    lat, lon, h = earth.ecef_to_geodetic(x)
    R = earth.R_en(lat, lon)
    tries = []
    if spec is not None and spec.velocity_frame == "ecef":
        tries.append(("NED velocities declared as frame = 'ecef': set velocity frame = 'ned'",
                      x, np.einsum("nij,nj->ni", R, v)))
    if spec is not None and spec.velocity_frame == "ned":
        v_n = np.einsum("nji,nj->ni", R, v)
        tries.append(("ECEF velocities declared as frame = 'ned': set velocity frame = 'ecef'", x, v_n))
    if spec is not None and spec.position_frame == "geodetic":
        v_raw = np.einsum("nji,nj->ni", R, v) if spec.velocity_frame == "ned" else None
        xs = earth.geodetic_to_ecef(lon, lat, h)
        if v_raw is not None:
            tries.append((f"latitude and longitude swapped: the columns {list(spec.position[:2])} hold "
                          f"[longitude, latitude]; swap them in [gps.position]", xs,
                          np.einsum("nij,nj->ni", earth.R_en(lon, lat), v_raw)))
        else:
            tries.append((f"latitude and longitude swapped: swap {list(spec.position[:2])} in [gps.position]",
                          xs, v))
        if spec.angle_factor != 1.0:
            k = 1.0 / spec.angle_factor
            la, lo = lat * k, lon * k
            if np.all(np.abs(la) <= np.pi / 2):
                xr = earth.geodetic_to_ecef(la, lo, h)
                vr = np.einsum("nij,nj->ni", earth.R_en(la, lo), v_raw) if v_raw is not None else v
                tries.append(("latitude and longitude in radians declared as degrees: set angle_unit = 'rad'", xr, vr))
    for text, xx, vv in tries:
        r = _velocity_residual(t, xx, vv, T)
        if r is not None and r[0] <= thr:
            return f"likely cause: {text}"
    dx = np.linalg.norm(np.diff(x, axis=0), axis=1)
    ratio = np.median(np.linalg.norm(v, axis=1)[1:][dx > 0] / (dx[dx > 0] / np.diff(t)[dx > 0]))
    if np.isfinite(ratio) and not 0.5 < ratio < 2.0:
        return (f"|v| is {ratio:.3g} x |dx/dt|: likely cause: the velocity unit or the time unit of [gps] "
                "(or the position unit)")
    return "likely cause: the frame of [gps.velocity] (ecef / ned) or the order of the position columns"


# ------------------------------------------------------------------------------------------------
def _imu_rates(imu):
    if imu.output == "increment":
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.nan_to_num(imu.gyro / imu.dt[:, None]), np.nan_to_num(imu.accel / imu.dt[:, None])
    return imu.gyro, imu.accel


def _gps_force(gps, t_s, T=1.0):
    """GPS specific force in e at the mid-points of 1 s baselines: dv/dt - g + 2 Omega x v."""
    i, j = _baselines(t_s, T)
    span = (t_s[j] - t_s[i])[:, None]
    a = (gps.velocity[j] - gps.velocity[i]) / span
    xm = 0.5 * (gps.position[i] + gps.position[j])
    vm = 0.5 * (gps.velocity[i] + gps.velocity[j])
    f = a - earth.gravity_e(xm) + 2.0 * np.cross(earth.OMEGA_IE_E, vm)
    return i, j, f


def _interval_sums(t_imu, y, a, b):
    """Means of the rows of ``y`` with stamps in [a, b) per interval (cumulative sums)."""
    C = np.concatenate([np.zeros((1,) + y.shape[1:]), np.cumsum(y, axis=0)])
    ia = np.searchsorted(t_imu, a, side="left")
    ib = np.searchsorted(t_imu, b, side="left")
    n = (ib - ia).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (C[ib] - C[ia]) / n.reshape((-1,) + (1,) * (y.ndim - 1)), n


def check_specific_force(report, imu, gps) -> None:
    """IMU |f| against the GPS specific force (module docstring)."""
    if gps is None or not gps.has_velocity or len(gps.t_ns) < 3:
        report.add("info", "imu", "specific_force", "no GPS velocities: specific-force check skipped")
        return
    t0 = int(gps.t_ns[0])
    tg = (gps.t_ns - t0) / 1e9
    ti = (imu.t_ns - t0) / 1e9
    i, j, fg = _gps_force(gps, tg)
    w, f = _imu_rates(imu)
    mean_f, n = _interval_sums(ti, f, tg[i], tg[j])
    mean_abs, _ = _interval_sums(ti, np.linalg.norm(f, axis=1), tg[i], tg[j])
    g_abs = np.linalg.norm(fg, axis=1)
    steady = np.linalg.norm(mean_f, axis=1) > 0.98 * mean_abs
    use = (n >= 2) & (g_abs > F_MIN) & steady
    if use.sum() < 3:
        report.add("info", "imu", "specific_force", f"fewer than 3 s with a GPS specific force above {F_MIN:g} m/s^2: "
                                                    "specific-force check skipped")
        return
    ratio = float(np.median(mean_abs[use] / g_abs[use]))
    stat = (f"|f| IMU / GPS = {ratio:.4g} (median over {int(use.sum())} 1 s intervals; accepted "
            f"{FORCE_RATIO[0]:g} to {FORCE_RATIO[1]:g})")
    if FORCE_RATIO[0] <= ratio <= FORCE_RATIO[1]:
        report.add("info", "imu", "specific_force", stat)
        return
    report.add("error", "imu", "specific_force", f"the accelerometer disagrees with the GPS acceleration: {stat}; "
                                                 f"likely cause: the unit of [imu.accel] (the values need a factor "
                                                 f"{1 / ratio:.3g})")


def _lag_rms(ti, f_abs, a, b, g_abs, lags):
    """RMS over the GPS intervals [a, b) of (IMU mean |f| over [a + L, b + L)) - |f_GPS|, per lag L,
    with the IMU's |f| integrated as means over the preceding sample interval (the import's default
    ``imu_sample``; point samples shift the lag by half a sample, below ``LAG_WARN_S`` from 20 Hz on)
    and interpolated, so that the RMS is continuous in L (not stepped at the sample spacing); NaN
    where fewer than half the intervals lie inside the IMU record."""
    I = np.concatenate([[0.0], np.cumsum(f_abs[1:] * np.diff(ti))])
    out = np.full(len(lags), np.nan)
    for k, L in enumerate(lags):  # a few hundred lags, each vectorised over the intervals
        m = (a + L >= ti[0]) & (b + L <= ti[-1])
        if m.sum() >= max(10, len(a) // 2):
            r = (np.interp(b[m] + L, ti, I) - np.interp(a[m] + L, ti, I)) / (b[m] - a[m]) - g_abs[m]
            out[k] = np.sqrt(np.mean(r * r))
    return out


def _best_lag(ti, f_abs, a, b, g_abs):
    """Lag of the smallest RMS (0.2 s grid over +-LAG_SEARCH_S, then 0.01 s around it) and the RMS
    curve's values at 0, at the best lag and one second either side of it."""
    coarse = np.arange(-LAG_SEARCH_S, LAG_SEARCH_S + 1e-9, 0.2)
    r = _lag_rms(ti, f_abs, a, b, g_abs, coarse)
    if np.all(np.isnan(r)):
        return None
    c = coarse[int(np.nanargmin(r))]
    fine = np.round(np.arange(c - 0.3, c + 0.3 + 1e-9, 0.01), 2)
    rf = _lag_rms(ti, f_abs, a, b, g_abs, fine)
    lag = float(fine[int(np.nanargmin(rf))])
    r0, rb, rm, rp = _lag_rms(ti, f_abs, a, b, g_abs, [0.0, lag, lag - 1.0, lag + 1.0])
    return lag, r0, rb, np.nanmin([rm, rp])


def _lag_cause(offset_s: float, t_ns: int) -> str:
    gps_utc = float(timescales.tai_minus_utc_s(np.array([t_ns]), beyond_table="hold")[0]) - 19.0
    if abs(abs(offset_s) - gps_utc) < 0.5:
        cause = f"GPS time read as UTC or UTC as GPS time (GPS - UTC = {gps_utc:.0f} s then)"
    else:
        cause = "a receiver latency or a clock offset between the recorders"
    return f"{cause}; offset_s = {-offset_s:.3f} in [gps.time] corrects it"


def check_time_lag(report, imu, gps) -> None:
    """Time offset of the GPS stamps against the IMU's from the specific force (module docstring)."""
    if not gps.has_velocity or len(gps.t_ns) < 3:
        report.add("info", "gps", "time_lag", "no GPS velocities: time-lag check skipped")
        return
    t0 = int(gps.t_ns[0])
    tg = (gps.t_ns - t0) / 1e9
    i, j, fg = _gps_force(gps, tg)
    _, f = _imu_rates(imu)
    found = _best_lag((imu.t_ns - t0) / 1e9, np.linalg.norm(f, axis=1), tg[i], tg[j], np.linalg.norm(fg, axis=1))
    if found is None or not found[3] > LAG_CONTRAST * found[2]:
        report.add("info", "gps", "time_lag", "the specific force does not change enough (no boost, burnout or "
                                              "manoeuvre in the record): time-lag check skipped")
        return
    lag, r0, rb, _ = found
    offset = -lag
    stat = (f"GPS stamps {offset:+.2f} s off the IMU's (|f| RMS difference {r0:.3g} m/s^2 at lag 0, "
            f"{rb:.3g} at the best lag; accepted below {LAG_WARN_S:g} s)")
    if abs(offset) < LAG_WARN_S:
        report.add("info", "gps", "time_lag", stat)
    elif abs(offset) < LAG_ERROR_S:
        report.add("warning", "gps", "time_lag", f"{stat}; likely cause: {_lag_cause(offset, t0)}")
    else:
        report.add("error", "gps", "time_lag", f"the GPS and IMU clocks disagree: {stat}; likely cause: "
                                               f"{_lag_cause(offset, t0)}")


def _saturated(w, rate_hz, declared=None) -> np.ndarray:
    """Samples of any axis on a flat top at its largest magnitude or at the declared range
    (the saturation criterion of :mod:`.validate`)."""
    from .validate import _runs
    min_run = max(5, int(round(0.25 * rate_hz)))
    out = np.zeros(len(w), bool)
    for k in range(w.shape[1]):
        a = np.abs(w[:, k])
        m = a.max() if len(a) else 0.0
        if m <= 0:
            continue
        at = a >= m * (1.0 - 1e-9)
        if declared is not None:
            at |= a >= declared * (1.0 - 1e-6)
        runs = _runs(at)
        if declared is not None or (len(runs) and runs.max() >= min_run):
            out |= at
    return out


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R(q) v`` row by row for quaternions [x, y, z, w] (scalar last, as :func:`nav.rotation.quat_to_matrix`),
    without forming the (N, 3, 3) matrices: ``v + 2 w (u x v) + 2 u x (u x v)``."""
    u, w = q[:, :3], q[:, 3:4]
    c = np.cross(u, v)
    return v + 2.0 * w * c + 2.0 * np.cross(u, c)


def check_gyro_rotation(report, imu, gps, rate_hz, *, diagnose: bool = True) -> None:
    """Gyro-integrated specific force against the GPS specific force (module docstring)."""
    if gps is None or not gps.has_velocity or len(gps.t_ns) < 3 or len(imu.t_ns) < 3:
        report.add("info", "imu", "gyro_rotation", "no GPS velocities: gyro rotation check skipped")
        return
    t0 = int(gps.t_ns[0])
    tg = (gps.t_ns - t0) / 1e9
    ti = (imu.t_ns - t0) / 1e9
    w, f = _imu_rates(imu)
    _, _, Q = ins.propagate(gps.position[0], gps.velocity[0], np.array([0.0, 0.0, 0.0, 1.0]), ti, f, w,
                            sample="average" if imu.output == "increment" else "point")
    f_rot = _rotate(Q, f)
    i, j, fg = _gps_force(gps, tg)
    fi, n = _interval_sums(ti, f_rot, tg[i], tg[j])
    sat = _saturated(w, rate_hz, imu.gyro_range / imu.dt.mean() if (imu.output == "increment" and imu.gyro_range)
                     else imu.gyro_range)
    nsat, _ = _interval_sums(ti, sat.astype(float), tg[i] - 1.0, tg[j] + 1.0)
    tm = 0.5 * (tg[i] + tg[j])
    ok = (n >= 2) & (np.linalg.norm(fg, axis=1) > F_MIN) & (np.linalg.norm(fi, axis=1) > F_MIN) & (nsat == 0)
    res, turns = [], []
    for k in np.unique(np.floor(tm[ok] / WINDOW_S)):
        sel = ok & (np.floor(tm / WINDOW_S) == k)
        if sel.sum() < 5:
            continue
        a = fg[sel] / np.linalg.norm(fg[sel], axis=1, keepdims=True)
        b = fi[sel] / np.linalg.norm(fi[sel], axis=1, keepdims=True)
        turn = np.degrees(max(angle_between(a, a.mean(0)).max(), angle_between(b, b.mean(0)).max()))
        if turn < 10.0:
            continue
        U, _, Vt = np.linalg.svd(a.T @ b)
        C = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        res.append(float(np.sqrt(np.mean(np.degrees(angle_between(a, b @ C.T)) ** 2))))
        turns.append(turn)
    if not res:
        report.add("info", "imu", "gyro_rotation", f"no {WINDOW_S:g} s window where the specific force turns by more "
                                                   "than 10 deg: gyro rotation check skipped")
        return
    med = float(np.median(res))
    stat = (f"RMS angle between the GPS specific force and the gyro-rotated accelerometer after one rotation per "
            f"{WINDOW_S:g} s = {med:.3g} deg (median over {len(res)} windows turning by up to {max(turns):.3g} deg; "
            f"threshold {GYRO_FIT_MAX_DEG:g} deg)")
    if med <= GYRO_FIT_MAX_DEG or not diagnose:
        report.add("info" if med <= GYRO_FIT_MAX_DEG else "error", "imu", "gyro_rotation", stat)
        return
    cause = _gyro_cause(imu, gps, rate_hz)
    report.add("error", "imu", "gyro_rotation", f"the gyros disagree with the rotation the GPS and accelerometer "
                                                f"show: {stat}; likely cause: {cause}")


def _gyro_cause(imu, gps, rate_hz) -> str:
    from dataclasses import replace
    from .validate import Report
    for k, text in ((np.pi / 180.0, "the gyro is in deg/s but declared rad/s: set [imu.gyro] unit = 'deg/s'"),
                    (180.0 / np.pi, "the gyro is in rad/s but declared deg/s: set [imu.gyro] unit = 'rad/s'")):
        rep = Report()
        check_gyro_rotation(rep, replace(imu, gyro=imu.gyro * k), gps, rate_hz, diagnose=False)
        if not rep.errors and any(f.check == "gyro_rotation" and "skipped" not in f.message for f in rep.findings):
            return text
    return "the unit of [imu.gyro] or its axes ([imu] axes apply to the gyro and the accelerometer alike)"


# ------------------------------------------------------------------------------------------------
_AXES = ("+x", "+y", "+z", "-x", "-y", "-z")
_ALLOWED = {"+x", "-z", "-x"}


def check_body_axes(report, imu, flight: bool = True) -> None:
    """Dominant specific-force direction in the body frame (module docstring). ``flight``: the
    record comes with GPS, i.e. from a vehicle that the filter will navigate; an IMU table alone
    (a bench or lab recording lying on any side) gets a warning instead of an error."""
    _, f = _imu_rates(imu)
    mag = np.linalg.norm(f, axis=1)
    load = mag > 5.0
    if load.sum() < 10:
        report.add("info", "imu", "body_axes", "fewer than 10 samples with |f| > 5 m/s^2: body axes check skipped")
        return
    u = (f[load] / mag[load, None]).mean(axis=0)
    L = float(np.linalg.norm(u))
    k = int(np.argmax(np.abs(u)))
    name = ("+" if u[k] > 0 else "-") + "xyz"[k]
    stat = (f"mean unit specific force in the body frame = [{u[0]:.3f}, {u[1]:.3f}, {u[2]:.3f}] over "
            f"{int(load.sum())} samples with |f| > 5 m/s^2 (dominant {name})")
    if L < 0.5 or name in _ALLOWED:
        report.add("info", "imu", "body_axes", stat + ("" if L >= 0.5 else ": no dominant direction"))
        return
    report.add("error" if flight else "warning", "imu", "body_axes", f"{stat}: at rest or under load the specific force points along +x "
                                            "(thrust), -z (ground or lift) or -x (drag) of the body frame (x forward, "
                                            f"y right, z down), not {name}; likely cause: the sensor axes differ "
                                            "from the body axes: set [imu] axes (e.g. axes = [\"+z\", \"-x\", \"-y\"] "
                                            "for a sensor with x left, y up, z forward)")


def cross_check(report, imu, gps, gps_spec=None, rate_hz=None) -> None:
    """Every cross-check that the inputs allow (module docstring). The IMU checks against the GPS
    run only when the GPS velocities agree with the positions (they are the reference). A rest
    period found by the accelerometer-unit check (:mod:`.validate`) whose level the GPS specific
    force contradicts was no rest (a gyro reading too small looks quiet): that error becomes a
    warning, the cross-checks name the cause."""
    gps_ok = True
    if gps is not None and len(gps.t_ns) > 2:
        n = len(report.errors)
        check_gps_velocity(report, gps, gps_spec)
        gps_ok = len(report.errors) == n
    if imu is None or len(imu.t_ns) <= 2:
        return
    rate = rate_hz or 1.0 / np.median(np.diff(imu.t_ns) / 1e9)
    check_body_axes(report, imu, flight=gps is not None)
    if gps is not None and gps_ok:
        check_specific_force(report, imu, gps)
        if not any(f.check == "specific_force" and f.level == "error" for f in report.findings):
            check_time_lag(report, imu, gps)
        check_gyro_rotation(report, imu, gps, rate)
        sf = [f for f in report.findings if f.check == "specific_force"]
        if sf and sf[-1].level == "info" and "skipped" not in sf[-1].message:
            for f in report.findings:
                if f.check == "accel_units" and f.level == "error":
                    f.level = "warning"
                    f.message += " (the GPS specific force agrees with the accelerometer: not a rest period)"
