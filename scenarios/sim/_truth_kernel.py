"""Numba hot loop of the 6-DOF truth: fixed-step RK4 of the rigid-body equations in e.

Only the loop lives here; the model is assembled in :mod:`scenarios.sim.truth` (which documents it).
State ``y`` (19): x_e (3) [m], v_e (3) [m/s], q_eb (4, scalar-last), omega_ib_b (3) [rad/s],
integral of omega_ib_b dt (3) [rad], integral of the specific force f_b dt (3) [m/s].

Schedule table ``sv`` (rows at times ``st``, linear in between, a repeated time is a jump; at a jump
the later row applies): columns ``C_*`` below.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from nav._kernels import gravity, quat_to_R_into
from nav.earth import A, B, E2, EP2, OMEGA_E

C_THRUST, C_MASS, C_CDA = 0, 1, 2
C_IXX, C_IYY, C_IZZ, C_IXY, C_IXZ, C_IYZ = 3, 4, 5, 6, 7, 8
C_SPIN_TARGET, C_SPIN_GAIN, C_WEATHERCOCK, C_RCS = 9, 10, 11, 12
C_TORQUE = 13  # 13, 14, 15: extra body torque (tip-off) [N m]
C_DISTURB = 16
N_COLS = 17
N_STATE = 19


@njit(cache=True)
def _interp_row(t, st, sv, out):
    n = st.shape[0]
    # last index i with st[i] <= t (side='right' - 1)
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) // 2
        if st[mid] <= t:
            lo = mid + 1
        else:
            hi = mid
    i = lo - 1
    if i < 0:
        i = 0
    if i >= n - 1:
        for c in range(sv.shape[1]):
            out[c] = sv[n - 1, c]
        return
    dt = st[i + 1] - st[i]
    w = 0.0 if dt <= 0.0 else (t - st[i]) / dt
    if w < 0.0:
        w = 0.0
    for c in range(sv.shape[1]):
        out[c] = sv[i, c] + w * (sv[i + 1, c] - sv[i, c])


@njit(cache=True)
def height(x):
    """Geodetic height [m], one Bowring step (error < 1 mm below 1000 km)."""
    p = math.sqrt(x[0] * x[0] + x[1] * x[1])
    u = math.atan2(x[2] * A, p * B)
    su, cu = math.sin(u), math.cos(u)
    lat = math.atan2(x[2] + EP2 * B * su * su * su, p - E2 * A * cu * cu * cu)
    sl, cl = math.sin(lat), math.cos(lat)
    return p * cl + x[2] * sl - A * math.sqrt(1.0 - E2 * sl * sl)


@njit(cache=True)
def _inv3(M, Minv):
    a, b, c = M[0, 0], M[0, 1], M[0, 2]
    d, e, f = M[1, 0], M[1, 1], M[1, 2]
    g, h, i = M[2, 0], M[2, 1], M[2, 2]
    co0 = e * i - f * h
    co1 = f * g - d * i
    co2 = d * h - e * g
    det = a * co0 + b * co1 + c * co2
    Minv[0, 0] = co0 / det
    Minv[1, 0] = co1 / det
    Minv[2, 0] = co2 / det
    Minv[0, 1] = (c * h - b * i) / det
    Minv[1, 1] = (a * i - c * g) / det
    Minv[2, 1] = (b * g - a * h) / det
    Minv[0, 2] = (b * f - c * e) / det
    Minv[1, 2] = (c * d - a * f) / det
    Minv[2, 2] = (a * e - b * d) / det


@njit(cache=True)
def deriv(t, y, s, st, sv, rho_step, logrho, rcs_torque, rcs_force, dist, prm, dy, f_b):
    """dy/dt and the specific force f_b (b frame) at (t, y) with RCS switch state ``s`` (3, +-1/0).

    ``prm``: [weathercock_min_speed]. ``dist``: rows constant, amplitude, period (3 each).
    """
    row = np.empty(N_COLS)
    _interp_row(t, st, sv, row)
    R = np.empty((3, 3))
    quat_to_R_into(y[6:10], R, False)
    x = y[0:3]
    v = y[3:6]
    w = y[10:13]
    m = row[C_MASS]
    # --- forces: drag (no wind: the air moves with e), thrust along x_b, RCS ---
    h = height(x)
    rho = 0.0
    if h < 0.0:
        rho = math.exp(logrho[0])
    else:
        k = h / rho_step
        i = int(k)
        if i >= logrho.shape[0] - 1:
            rho = math.exp(logrho[logrho.shape[0] - 1])
        else:
            a = k - i
            rho = math.exp(logrho[i] + a * (logrho[i + 1] - logrho[i]))
    vn = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    kd = -0.5 * rho * vn * row[C_CDA] / m
    # f_b = R^T (kd v) + thrust + rcs
    for j in range(3):
        f_b[j] = kd * (R[0, j] * v[0] + R[1, j] * v[1] + R[2, j] * v[2])
    f_b[0] += row[C_THRUST] / m
    if row[C_RCS] > 0.5:
        for i in range(3):
            if s[i] != 0:
                for j in range(3):
                    f_b[j] += s[i] * rcs_force[i, j]
    g = np.empty(3)
    g[0], g[1], g[2] = gravity(x[0], x[1], x[2])
    # a_e = R f_b + g - 2 Omega x v ; Omega = (0, 0, OMEGA_E)
    for j in range(3):
        dy[j] = v[j]
        dy[3 + j] = R[j, 0] * f_b[0] + R[j, 1] * f_b[1] + R[j, 2] * f_b[2] + g[j]
    dy[3] += 2.0 * OMEGA_E * v[1]
    dy[4] -= 2.0 * OMEGA_E * v[0]
    # --- rotation: I dw/dt = tau - w x (I w) ---
    Im = np.empty((3, 3))
    Im[0, 0], Im[1, 1], Im[2, 2] = row[C_IXX], row[C_IYY], row[C_IZZ]
    Im[0, 1] = Im[1, 0] = -row[C_IXY]
    Im[0, 2] = Im[2, 0] = -row[C_IXZ]
    Im[1, 2] = Im[2, 1] = -row[C_IYZ]
    Iw = np.empty(3)
    for j in range(3):
        Iw[j] = Im[j, 0] * w[0] + Im[j, 1] * w[1] + Im[j, 2] * w[2]
    gyro = np.empty(3)
    gyro[0] = w[1] * Iw[2] - w[2] * Iw[1]
    gyro[1] = w[2] * Iw[0] - w[0] * Iw[2]
    gyro[2] = w[0] * Iw[1] - w[1] * Iw[0]
    tau = np.empty(3)
    for j in range(3):
        tau[j] = row[C_TORQUE + j]
    if row[C_SPIN_GAIN] > 0.0:
        tau[0] += row[C_IXX] * row[C_SPIN_GAIN] * (row[C_SPIN_TARGET] - w[0])
    wn = row[C_WEATHERCOCK]
    if wn > 0.0 and vn > prm[0]:
        # air-relative velocity direction in b; e = x_b x v_b (rotation that turns x_b onto v)
        vb1 = (R[0, 1] * v[0] + R[1, 1] * v[1] + R[2, 1] * v[2]) / vn
        vb2 = (R[0, 2] * v[0] + R[1, 2] * v[1] + R[2, 2] * v[2]) / vn
        tau[1] += gyro[1] + row[C_IYY] * (wn * wn * (-vb2) - 2.0 * wn * w[1])
        tau[2] += gyro[2] + row[C_IZZ] * (wn * wn * vb1 - 2.0 * wn * w[2])
    if row[C_RCS] > 0.5:
        for j in range(3):
            tau[j] += s[j] * rcs_torque[j]
    if row[C_DISTURB] > 0.5:
        for j in range(3):
            tau[j] += dist[0, j] + dist[1, j] * math.sin(2.0 * math.pi * t / dist[2, j])
    Iinv = np.empty((3, 3))
    _inv3(Im, Iinv)
    for j in range(3):
        acc = 0.0
        for k2 in range(3):
            acc += Iinv[j, k2] * (tau[k2] - gyro[k2])
        dy[10 + j] = acc
    # --- attitude kinematics: dq/dt = 1/2 q (x) [w_eb, 0], w_eb = w_ib - R^T Omega ---
    web0 = w[0] - R[2, 0] * OMEGA_E
    web1 = w[1] - R[2, 1] * OMEGA_E
    web2 = w[2] - R[2, 2] * OMEGA_E
    qx, qy, qz, qw = y[6], y[7], y[8], y[9]
    dy[6] = 0.5 * (qw * web0 + qy * web2 - qz * web1)
    dy[7] = 0.5 * (qw * web1 + qz * web0 - qx * web2)
    dy[8] = 0.5 * (qw * web2 + qx * web1 - qy * web0)
    dy[9] = -0.5 * (qx * web0 + qy * web1 + qz * web2)
    for j in range(3):
        dy[13 + j] = w[j]
        dy[16 + j] = f_b[j]


@njit(cache=True)
def integrate(y0, dt, n_out, substeps, st, sv, rho_step, logrho, rcs_torque, rcs_force, rcs_thr,
              dist, prm, Y, F, S):
    """RK4 with step ``dt`` from t = 0; stores every ``substeps`` steps into Y (n_out+1, 19),
    F (n_out+1, 3) (specific force, right limit) and S (n_out+1, 3) (RCS switch state).

    ``rcs_thr`` = [threshold, release] [rad/s]. The RCS switches are decided at the start of each
    step from the current body rates (bang-bang with hysteresis) and held over the step.
    """
    y = y0.copy()
    s = np.zeros(3, dtype=np.int8)
    k1 = np.empty(N_STATE)
    k2 = np.empty(N_STATE)
    k3 = np.empty(N_STATE)
    k4 = np.empty(N_STATE)
    tmp = np.empty(N_STATE)
    fb = np.empty(3)
    row = np.empty(N_COLS)
    for k in range(n_out + 1):
        for sub in range(substeps):
            t = (k * substeps + sub) * dt
            _interp_row(t, st, sv, row)
            if row[C_RCS] > 0.5:
                for i in range(3):
                    wi = y[10 + i]
                    if s[i] == 0:
                        if abs(wi) > rcs_thr[0]:
                            s[i] = -1 if wi > 0 else 1
                    elif s[i] * wi > -rcs_thr[1]:
                        s[i] = 0
            else:
                s[:] = 0
            if sub == 0:
                deriv(t, y, s, st, sv, rho_step, logrho, rcs_torque, rcs_force, dist, prm, k1, fb)
                for j in range(N_STATE):
                    Y[k, j] = y[j]
                for j in range(3):
                    F[k, j] = fb[j]
                    S[k, j] = s[j]
                if k == n_out:
                    return
            else:
                deriv(t, y, s, st, sv, rho_step, logrho, rcs_torque, rcs_force, dist, prm, k1, fb)
            for j in range(N_STATE):
                tmp[j] = y[j] + 0.5 * dt * k1[j]
            deriv(t + 0.5 * dt, tmp, s, st, sv, rho_step, logrho, rcs_torque, rcs_force, dist, prm, k2, fb)
            for j in range(N_STATE):
                tmp[j] = y[j] + 0.5 * dt * k2[j]
            deriv(t + 0.5 * dt, tmp, s, st, sv, rho_step, logrho, rcs_torque, rcs_force, dist, prm, k3, fb)
            for j in range(N_STATE):
                tmp[j] = y[j] + dt * k3[j]
            deriv(t + dt, tmp, s, st, sv, rho_step, logrho, rcs_torque, rcs_force, dist, prm, k4, fb)
            for j in range(N_STATE):
                y[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
            qn = math.sqrt(y[6] * y[6] + y[7] * y[7] + y[8] * y[8] + y[9] * y[9])
            for j in range(6, 10):
                y[j] /= qn
