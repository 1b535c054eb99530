"""RK4 strapdown inertial navigation in the Earth-fixed frame e (003 §6.1, fig. 29).

State: position ``x_e`` [m], velocity ``v_e`` [m/s] (both relative to e, expressed in e) and the
attitude quaternion ``q_eb`` (scalar-last). The e-frame mechanisation (Groves 2013, §5.4, 003
ref. [15])::

    dx_e/dt  = v_e
    dv_e/dt  = R_eb f_b + g_e(x_e) - 2 [omega_ie x] v_e        (g_e: J2 gravitation + centrifugal)
    dq_eb/dt = 1/2 q_eb * [omega_eb_b, 0],  omega_eb_b = omega_ib_b - R_eb^T omega_ie

IMU samples are specific force ``f_b`` and angular rate ``omega_ib_b``, either instantaneous
values at the sample times ("point": interpolated linearly, the RK4 midpoint stage uses the mean of
the two samples) or means over the preceding sample interval ("average": the rate output of an
integrating IMU, or increments divided by the interval; held constant over that interval). One
RK4 step spans one sample interval. The same step run with a negative
time step integrates backwards (003 §7.4 back-propagation): pass the samples in reverse order.

A stationary IMU on the rotating Earth measures ``f_b = -R_eb^T g_e`` and
``omega_ib_b = R_eb^T omega_ie``; with these every derivative above is zero, so the mechanisation
holds position and attitude to round-off (tests/test_ins.py).

The sample loop is a numba kernel (:func:`ins_kernel`) that also applies the in-flight
calibration ``A (x_meas - b)`` of :mod:`nav.imu_errors` so no per-sample array is allocated.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from nav import earth
from nav._kernels import gravity, quat_to_R_into
from nav.checks import as_vectors
from nav.imu_errors import ImuCalibration
from nav.rotation import quat_normalize

_W = earth.OMEGA_E


@nb.njit(cache=True)
def _deriv(x, v, q, fb, wb, R, dx, dv, dq):
    quat_to_R_into(q, R, True)
    # omega_eb_b = omega_ib_b - R^T omega_ie (omega_ie = [0, 0, W])
    w0 = wb[0] - R[2, 0] * _W
    w1 = wb[1] - R[2, 1] * _W
    w2 = wb[2] - R[2, 2] * _W
    g0, g1, g2 = gravity(x[0], x[1], x[2])
    for i in range(3):
        dx[i] = v[i]
        dv[i] = R[i, 0] * fb[0] + R[i, 1] * fb[1] + R[i, 2] * fb[2]
    dv[0] += g0 + 2.0 * _W * v[1]
    dv[1] += g1 - 2.0 * _W * v[0]
    dv[2] += g2
    # q * [w, 0] (scalar-last Hamilton product), times 1/2
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    dq[0] = 0.5 * (qw * w0 + qy * w2 - qz * w1)
    dq[1] = 0.5 * (qw * w1 + qz * w0 - qx * w2)
    dq[2] = 0.5 * (qw * w2 + qx * w1 - qy * w0)
    dq[3] = 0.5 * (-qx * w0 - qy * w1 - qz * w2)


@nb.njit(cache=True)
def _calibrate(raw, c, out):
    """``A (raw - b)`` with ``c`` (4, 3): rows 0..2 A, row 3 b."""
    for i in range(3):
        out[i] = c[i, 0] * (raw[0] - c[3, 0]) + c[i, 1] * (raw[1] - c[3, 1]) + c[i, 2] * (raw[2] - c[3, 2])


@nb.njit(cache=True)
def _stage(x, v, q, c, kx, kv, kq, xs, vs, qs):
    """The state of an RK4 stage, ``(xs, vs, qs) = (x, v, q) + c k``."""
    for j in range(3):
        xs[j] = x[j] + c * kx[j]; vs[j] = v[j] + c * kv[j]
    for j in range(4):
        qs[j] = q[j] + c * kq[j]


@nb.njit(cache=True)
def ins_kernel(nav, t, fw, i0, i1, cal_m, traj, stats, average=False):
    """Integrate from sample ``i0`` to ``i1`` (inclusive; ``i1 < i0`` runs backwards).

    ``nav`` (10,) holds x_e, v_e, q_eb at ``t[i0]`` and is updated in place to ``t[i1]``; the
    state at every sample from i0 to i1 is written into the rows of ``traj`` (N, 10) (indexed like
    ``t``). ``fw`` (N, 2, 3): specific force and angular rate of each sample. ``stats`` (6,)
    receives the mean calibrated specific force and angular rate over the interval (used for the
    covariance transition). Samples are calibrated with ``A (raw - b)``, ``cal_m`` (2, 4, 3) holding
    A (rows 0..2) and b (row 3) of the accelerometers and the gyros.

    ``average=False``: samples are instantaneous values, interpolated linearly within a step.
    ``average=True``: sample k is the mean over (t[k-1], t[k]] (rate output of an integrating IMU,
    or increments divided by the interval) and is held over that step.
    """
    step = 1 if i1 >= i0 else -1
    x, v, q = nav[0:3], nav[3:6], nav[6:10]
    cf, cw = cal_m[0], cal_m[1]
    R = np.empty((3, 3))
    fa = np.empty(3); fb_ = np.empty(3); fm = np.empty(3)
    wa = np.empty(3); wb_ = np.empty(3); wm = np.empty(3)
    k1x = np.empty(3); k1v = np.empty(3); k1q = np.empty(4)
    k2x = np.empty(3); k2v = np.empty(3); k2q = np.empty(4)
    k3x = np.empty(3); k3v = np.empty(3); k3q = np.empty(4)
    k4x = np.empty(3); k4v = np.empty(3); k4q = np.empty(4)
    xs = np.empty(3); vs = np.empty(3); qs = np.empty(4)
    for j in range(6):
        stats[j] = 0.0
    for j in range(10):
        traj[i0, j] = nav[j]
    i = i0
    nsum = 0
    _calibrate(fw[i0, 0], cf, fa)
    _calibrate(fw[i0, 1], cw, wa)
    while i != i1:
        k = i + step
        h = t[k] - t[i]
        if average:
            m = k if k > i else i
            _calibrate(fw[m, 0], cf, fb_)
            _calibrate(fw[m, 1], cw, wb_)
            for j in range(3):
                fa[j] = fb_[j]; wa[j] = wb_[j]
        else:
            _calibrate(fw[k, 0], cf, fb_)
            _calibrate(fw[k, 1], cw, wb_)
        for j in range(3):
            fm[j] = 0.5 * (fa[j] + fb_[j])
            wm[j] = 0.5 * (wa[j] + wb_[j])
            stats[j] += fm[j]
            stats[3 + j] += wm[j]
        nsum += 1
        _deriv(x, v, q, fa, wa, R, k1x, k1v, k1q)
        _stage(x, v, q, 0.5 * h, k1x, k1v, k1q, xs, vs, qs)
        _deriv(xs, vs, qs, fm, wm, R, k2x, k2v, k2q)
        _stage(x, v, q, 0.5 * h, k2x, k2v, k2q, xs, vs, qs)
        _deriv(xs, vs, qs, fm, wm, R, k3x, k3v, k3q)
        _stage(x, v, q, h, k3x, k3v, k3q, xs, vs, qs)
        _deriv(xs, vs, qs, fb_, wb_, R, k4x, k4v, k4q)
        for j in range(3):
            x[j] += h / 6.0 * (k1x[j] + 2.0 * k2x[j] + 2.0 * k3x[j] + k4x[j])
            v[j] += h / 6.0 * (k1v[j] + 2.0 * k2v[j] + 2.0 * k3v[j] + k4v[j])
        nq = 0.0
        for j in range(4):
            q[j] += h / 6.0 * (k1q[j] + 2.0 * k2q[j] + 2.0 * k3q[j] + k4q[j])
            nq += q[j] * q[j]
        nq = math.sqrt(nq)
        for j in range(4):
            q[j] /= nq
        for j in range(3):
            fa[j] = fb_[j]; wa[j] = wb_[j]
        for j in range(10):
            traj[k, j] = nav[j]
        i = k
    if nsum > 0:
        for j in range(6):
            stats[j] /= nsum
    else:
        for j in range(3):
            stats[j] = fa[j]; stats[3 + j] = wa[j]


def _check_imu(t_s, f_b, w_b):
    t = np.ascontiguousarray(np.asarray(t_s, dtype=np.float64))
    if t.ndim != 1 or t.size < 1:
        raise ValueError(f"t_s: expected a 1-D array of sample times, got shape {t.shape}")
    f = np.ascontiguousarray(as_vectors(f_b, "f_b"))
    w = np.ascontiguousarray(as_vectors(w_b, "w_b"))
    if f.shape != (t.size, 3) or w.shape != (t.size, 3):
        raise ValueError(f"f_b, w_b: expected shape ({t.size}, 3) to match t_s, got {f.shape}, {w.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("t_s: contains NaN or inf")
    return t, f, w


def propagate(x0, v0, q0, t_s, f_b, w_b, *, backward: bool = False, calibration: ImuCalibration | None = None,
              sample: str = "point"):
    """Unaided strapdown solution over all samples.

    Parameters
    ----------
    x0, v0, q0 : (3,), (3,), (4,)
        State at ``t_s[0]`` (forward) or at ``t_s[-1]`` (``backward=True``).
    t_s : (N,) float
        Sample times [s] (any origin), strictly increasing.
    f_b, w_b : (N, 3)
        Specific force [m/s^2] and angular rate omega_ib_b [rad/s] at the sample times.
    backward : bool
        Integrate from the last sample back to the first (003 §7.4).
    calibration : ImuCalibration, optional
        Applied to every sample (default: none).
    sample : {"point", "average"}
        Instantaneous samples (linear interpolation) or interval means held over the preceding
        interval (see :func:`ins_kernel`).

    Returns
    -------
    X, V, Q : (N, 3), (N, 3), (N, 4)
        Position, velocity, quaternion q_eb at every sample time.
    """
    t, f, w = _check_imu(t_s, f_b, w_b)
    if t.size > 1 and not np.all(np.diff(t) > 0):
        raise ValueError("t_s: sample times must be strictly increasing")
    cal = calibration or ImuCalibration()
    cal_m = np.empty((2, 4, 3))
    cal_m[0, :3], cal_m[0, 3], cal_m[1, :3], cal_m[1, 3] = cal.matrices()
    nav = np.concatenate([as_vectors(x0, "x0").astype(float), as_vectors(v0, "v0").astype(float), quat_normalize(q0)])
    N = t.size
    fw = np.empty((N, 2, 3))
    fw[:, 0], fw[:, 1] = f, w
    traj = np.empty((N, 10))
    i0, i1 = (N - 1, 0) if backward else (0, N - 1)
    if sample not in ("point", "average"):
        raise ValueError(f"sample: expected 'point' or 'average', got {sample!r}")
    ins_kernel(nav, t, fw, i0, i1, cal_m, traj, np.empty(6), sample == "average")
    return (np.ascontiguousarray(traj[:, 0:3]), np.ascontiguousarray(traj[:, 3:6]),
            np.ascontiguousarray(traj[:, 6:10]))


def stationary_imu(x_e, q_eb):
    """Error-free IMU readings (f_b, omega_ib_b) of a body at rest in e at ``x_e`` with ``q_eb``."""
    from nav.rotation import quat_to_matrix
    R = quat_to_matrix(q_eb)
    g = earth.gravity_e(x_e)
    return -R.T @ g, R.T @ earth.OMEGA_IE_E
