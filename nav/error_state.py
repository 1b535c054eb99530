"""Error-state layout of the navigation filter, built from the tuning: 003 eq. (46), generalised.

Order (groups switched ``"off"`` in the tuning are left out)::

    dx_e, dv_e, psi | b_f, b_w, s_f, m_f, s_w, m_w, n_w | g_w | psi_c[k] for each camera k
                    | dt_c[k] for each camera k | zeta[k, target] for each camera k and target
                    | h_e[k] for each camera k

* ``dx_e, dv_e`` true minus estimated position and velocity in e [m, m/s];
* ``psi`` attitude error in e, from the estimated to the true attitude (docs/conventions.md "Rotations");
* ``b_f, b_w`` residual accelerometer / gyro bias (measurement minus truth after calibration);
* ``s_f, s_w`` residual scale factors, ``m_f, m_w`` residual small-angle misalignments, ``n_w``
  the gyro triad's residual non-orthogonality (group ``gyro_nonorthogonality``, the symmetric
  off-diagonal part of its axis misalignment; sensitivities in :mod:`nav.imu_errors`);
* ``g_w`` Gauss-Markov gyro error [rad/s] (group ``gyro_gm``): a first-order process of
  correlation time ``Tuning.gyro_gm_tau_s`` that enters the attitude error as the bias does;
* ``psi_c`` camera misalignment in b, ``R_bc_true = (I + [psi_c x]) R_bc_nominal`` (003 eq. (50));
* ``dt_c`` camera clock offset error [s], true minus estimated offset (one state per camera,
  :mod:`nav.clock_offset`; a constant: identity transition);
* ``zeta`` Gauss-Markov vector errors of 003 eqs. (41)-(45), in the camera frame;
* ``h_e`` the effective height of the camera's Earth edge [m] (``d`` of 003 eq. (5)), true minus
  estimated: a constant, or a first-order Gauss-Markov process of correlation time
  ``Tuning.edge_height_tau_s`` (:mod:`nav.updates` ``CameraVectors`` gives its column).

Every group has 3 components except ``dt_c`` and ``h_e`` (1).

The navigation block (dx, dv, psi) is always estimated; every other group is estimated or
considered (Schmidt-Kalman) as the tuning says.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from nav._kernels import skew
from nav.imu_errors import nonorthogonality_jacobian
from nav.tuning import Tuning

#: number of leading states (dx, dv, psi) whose transition rows are dense; the others are diagonal
N_NAV = 9
IMU_GROUPS = ("accel_bias", "gyro_bias", "accel_scale", "accel_misalignment", "gyro_scale", "gyro_misalignment",
              "gyro_nonorthogonality")
#: the groups whose first column :func:`nav_transition` takes: the IMU groups and the Gauss-Markov gyro error
TRANSITION_GROUPS = IMU_GROUPS + ("gyro_gm",)
N_TRANSITION = len(TRANSITION_GROUPS)


@dataclass(frozen=True)
class Group:
    name: str
    slice: slice
    estimated: bool
    sigma0: float | tuple    #: initial 1-sigma, one value or one per state


@dataclass(frozen=True)
class StateLayout:
    """Named groups with their slices. ``groups`` keeps the order of the state vector."""
    groups: tuple
    n_cameras: int
    targets: tuple

    @property
    def n(self) -> int:
        return self.groups[-1].slice.stop

    def __getitem__(self, name: str) -> slice:
        for g in self.groups:
            if g.name == name:
                return g.slice
        raise KeyError(f"state group {name!r} not in the layout; have {[g.name for g in self.groups]}")

    def has(self, name: str) -> bool:
        return any(g.name == name for g in self.groups)

    def get(self, name: str):
        return self[name] if self.has(name) else None

    @property
    def estimated_mask(self) -> np.ndarray:
        """Boolean (n,): True for estimated states, False for considered ones."""
        m = np.zeros(self.n, dtype=bool)
        for g in self.groups:
            m[g.slice] = g.estimated
        return m

    def initial_covariance(self) -> np.ndarray:
        """Diagonal P0 from every group's sigma0."""
        d = np.zeros(self.n)
        for g in self.groups:
            d[g.slice] = np.asarray(g.sigma0, float) ** 2
        return np.diag(d)

    def zeta_name(self, camera: int, target: str) -> str:
        return f"zeta_{target}_{camera}"

    def cam_name(self, camera: int) -> str:
        return f"psi_c_{camera}"

    def clock_name(self, camera: int) -> str:
        return f"dt_c_{camera}"

    def edge_name(self, camera: int) -> str:
        return f"h_e_{camera}"


def build_layout(tuning: Tuning, n_cameras: int) -> StateLayout:
    """State layout for ``n_cameras`` cameras (0 allowed: GPS/INS only)."""
    if n_cameras < 0:
        raise ValueError(f"n_cameras: expected >= 0, got {n_cameras}")
    groups = []
    i = 0

    def add(name, est, sigma, size=3):
        nonlocal i
        groups.append(Group(name, slice(i, i + size), est, float(sigma) if np.ndim(sigma) == 0 else tuple(sigma)))
        i += size

    add("dx", True, tuning.init_pos_sigma)
    add("dv", True, tuning.init_vel_sigma)
    add("psi", True, tuning.init_att_sigma)
    for name in IMU_GROUPS:
        g = getattr(tuning, name)
        if g.on:
            add(name, g.estimated, g.sigma)
    if tuning.gyro_gm.on:
        add("gyro_gm", tuning.gyro_gm.estimated, tuple(tuning.gyro_gm_sigmas()))
    if n_cameras:
        if tuning.camera_misalignment.on:
            for k in range(n_cameras):
                add(f"psi_c_{k}", tuning.camera_misalignment.estimated, tuning.camera_misalignment.sigma)
        if tuning.camera_clock_offset.on:
            for k in range(n_cameras):
                add(f"dt_c_{k}", tuning.camera_clock_offset.estimated, tuning.camera_clock_offset.sigma, size=1)
        if tuning.vector_gm_mode != "off":
            for k in range(n_cameras):
                for t in tuning.targets:
                    add(f"zeta_{t}_{k}", tuning.vector_gm_mode == "E", tuning.gm_default_sigma)
        if tuning.edge_height.on:
            for k in range(n_cameras):
                add(f"h_e_{k}", tuning.edge_height.estimated, tuning.edge_height.sigma, size=1)
    return StateLayout(tuple(groups), n_cameras, tuple(tuning.targets))


def gravity_gradient(x_e) -> np.ndarray:
    """d g_e / d x_e: point-mass gravitation gradient ``GM/r^3 (3 u u^T - I)`` plus the centrifugal
    term ``diag(w^2, w^2, 0)`` (the J2 part changes it by 0.1 %, below what the filter resolves)."""
    from nav.earth import GM, OMEGA_E
    x = np.asarray(x_e, float)
    r = np.linalg.norm(x)
    u = x / r
    return GM / r ** 3 * (3.0 * np.outer(u, u) - np.eye(3)) + np.diag([OMEGA_E ** 2, OMEGA_E ** 2, 0.0])


def error_dynamics(layout: StateLayout, x_e, R_eb, f_b, w_b, tc: float, tau_edge: float = 0.0,
                   tau_gyro=0.0) -> np.ndarray:
    """Continuous-time error dynamics F (n, n) of the e-frame mechanisation (:mod:`nav.ins`)::

        d(dx)/dt  = dv
        d(dv)/dt  = G dx - 2 [w_ie x] dv - [(R_eb f_b) x] psi - R_eb delta_f
        d(psi)/dt = -[w_ie x] psi - R_eb (delta_w + g_w)
        d(g_w)/dt = -g_w / tau_gyro       (Gauss-Markov gyro error, when in the layout; per body
                                           axis, ``tau_gyro`` a scalar or (3,))
        d(zeta)/dt = -zeta / T_c          (003 §6.3)
        d(h_e)/dt  = -h_e / tau_edge      (a constant when tau_edge is 0)

    with ``delta_f = b_f + diag(f_b) s_f + [f_b x] m_f`` (and the same for the gyro, which also has
    ``N(w_b) n_w``, :mod:`nav.imu_errors`); constants (biases, scale factors, misalignments, psi_c) have zero rows.
    """
    from nav.earth import OMEGA_IE_E
    n = layout.n
    F = np.zeros((n, n))
    ix, iv, ip = layout["dx"], layout["dv"], layout["psi"]
    W = skew(OMEGA_IE_E)
    F[ix, iv] = np.eye(3)
    F[iv, ix] = gravity_gradient(x_e)
    F[iv, iv] = -2.0 * W
    F[iv, ip] = -skew(np.asarray(R_eb @ f_b, float))
    F[ip, ip] = -W
    sens = {"accel_bias": (iv, np.eye(3)), "accel_scale": (iv, np.diag(f_b)),
            "accel_misalignment": (iv, skew(np.asarray(f_b, float))), "gyro_bias": (ip, np.eye(3)),
            "gyro_scale": (ip, np.diag(w_b)), "gyro_misalignment": (ip, skew(np.asarray(w_b, float))),
            "gyro_nonorthogonality": (ip, nonorthogonality_jacobian(w_b))}
    for name, (row, S) in sens.items():
        if layout.has(name):
            F[row, layout[name]] = -R_eb @ S
    if layout.has("gyro_gm"):
        F[ip, layout["gyro_gm"]] = -R_eb
        F[layout["gyro_gm"], layout["gyro_gm"]] = -np.diag(1.0 / gyro_gm_taus(tau_gyro))
    for g in layout.groups:
        if g.name.startswith("zeta_"):
            F[g.slice, g.slice] = -np.eye(3) / tc
        elif g.name.startswith("h_e_") and tau_edge > 0:
            F[g.slice, g.slice] = -1.0 / tau_edge
    return F


def discrete_transition(layout: StateLayout, F: np.ndarray, dt: float) -> np.ndarray:
    """Phi = exp(F dt) to second order, ``I + F dt + (F dt)^2 / 2``, over the navigation rows; the
    diagonal Gauss-Markov entries use the exact ``exp(-dt/T_c)`` (003 eq. (42) is its first-order
    form). Constants keep identity rows."""
    n = layout.n
    Fd = F * dt
    Phi = np.eye(n)
    m = N_NAV
    Phi[:m] += Fd[:m] + 0.5 * (Fd[:m] @ Fd)
    for g in layout.groups:
        if g.name.startswith(("zeta_", "h_e_", "gyro_gm")):
            d = np.exp(np.diag(Fd[g.slice, g.slice]))
            Phi[g.slice, g.slice] = np.diag(d)
    return Phi


@dataclass
class BlockTransition:
    """Transition over one covariance block in the structured form the filter uses:
    rows 0..8 (dx, dv, psi) are ``A`` (9, n); every other row is diagonal with entry ``d[i]``
    (1 for constants, ``exp(-dt/T_c)`` for Gauss-Markov states)."""
    A: np.ndarray
    d: np.ndarray

    def full(self) -> np.ndarray:
        Phi = np.diag(self.d)
        Phi[:9] = self.A
        return Phi

    def apply(self, P: np.ndarray) -> np.ndarray:
        """``Phi P Phi^T`` exploiting the structure (2 products of (9, n) x (n, n))."""
        M = P * self.d[:, None]
        M[:9] = self.A @ P
        out = M * self.d[None, :]
        out[:, :9] = M @ self.A.T
        return out


@nb.njit(cache=True)
def nav_transition(x, R, f, w, dt, cols, n, W, GM, tau_w):
    """Rows 0..8 of Phi = I + F dt + (F dt)^2/2 (see :func:`error_dynamics`); ``cols`` (8,) holds
    the first column of accel_bias, gyro_bias, accel_scale, accel_misalignment, gyro_scale,
    gyro_misalignment, gyro_nonorthogonality and the Gauss-Markov gyro error gyro_gm (-1: absent;
    ``TRANSITION_GROUPS``),
    ``tau_w`` (3,) the latter's correlation time per body axis [s]. The (F dt)^2/2 term is the
    product over the navigation columns plus, for gyro_gm, ``-R dt (-dt / tau_w) / 2`` (its own decay)."""
    F = np.zeros((9, n))
    r2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
    r = np.sqrt(r2)
    k = GM / (r2 * r)
    for i in range(3):
        F[i, 3 + i] = 1.0
        for j in range(3):
            F[3 + i, j] = k * (3.0 * x[i] * x[j] / r2 - (1.0 if i == j else 0.0))
    F[3, 0] += W * W
    F[4, 1] += W * W
    # -2 [w_ie x] and -[w_ie x] with w_ie = [0, 0, W]
    F[3, 4] = 2.0 * W
    F[4, 3] = -2.0 * W
    F[6, 7] = W
    F[7, 6] = -W
    fe = R @ f
    F[3, 7] = fe[2]; F[3, 8] = -fe[1]
    F[4, 6] = -fe[2]; F[4, 8] = fe[0]
    F[5, 6] = fe[1]; F[5, 7] = -fe[0]
    for g in range(8):
        c = cols[g]
        if c < 0:
            continue
        row = 3 if (g == 0 or g == 2 or g == 3) else 6
        v = f if row == 3 else w
        # -R K: K = [v x] (misalignments) or N(w) (non-orthogonality, nonorthogonality_jacobian)
        K = skew(v) if g != 6 else np.array([[0.0, v[2], v[1]], [v[2], 0.0, v[0]], [v[1], v[0], 0.0]])
        for i in range(3):
            for j in range(3):
                if g <= 1 or g == 7:
                    val = -R[i, j]
                elif g == 2 or g == 4:
                    val = -R[i, j] * v[j]
                else:
                    val = 0.0
                    for m in range(3):
                        val -= R[i, m] * K[m, j]
                F[row + i, c + j] = val
    Fd = F * dt
    A = Fd + 0.5 * (np.ascontiguousarray(Fd[:, :9]) @ Fd)
    for i in range(9):
        A[i, i] += 1.0
    c = cols[7]
    if c >= 0:
        for j in range(3):
            k2 = 0.5 * dt * dt / tau_w[j]
            for i in range(3):
                A[6 + i, c + j] += k2 * R[i, j]
    return A


class TransitionBuilder:
    """Builds :class:`BlockTransition` for a layout with the compiled :func:`nav_transition` (the
    filter's form of :func:`error_dynamics` + :func:`discrete_transition`; tests check they agree)."""

    def __init__(self, layout: StateLayout, tc: float, tau_edge: float = 0.0, tau_gyro=0.0):
        self.n = layout.n
        self.layout = layout
        self.tc, self.tau_edge, self.tau_gyro = tc, tau_edge, gyro_gm_taus(tau_gyro)
        self.edge = edge_gm_indices(layout, tau_edge)
        self.gyro = gyro_gm_indices(layout)
        self.cols = transition_columns(layout)
        self.zeta = np.zeros(self.n, bool)
        for g in layout.groups:
            if g.name.startswith("zeta_"):
                self.zeta[g.slice] = True

    def __call__(self, x_e, R_eb, f_b, w_b, dt) -> BlockTransition:
        from nav.earth import GM, OMEGA_E
        A = nav_transition(np.asarray(x_e, float), np.ascontiguousarray(R_eb), np.asarray(f_b, float),
                            np.asarray(w_b, float), float(dt), self.cols, self.n, OMEGA_E, GM, self.tau_gyro)
        d = np.ones(self.n)
        d[self.zeta] = np.exp(-dt / self.tc)
        if self.edge.size:
            d[self.edge] = np.exp(-dt / self.tau_edge)
        if self.gyro.size:
            d[self.gyro] = np.exp(-dt / self.tau_gyro)
        return BlockTransition(A, d)


def transition_columns(layout: StateLayout) -> np.ndarray:
    """(8,) int64 first column of each of ``TRANSITION_GROUPS`` (-1: absent), as
    :func:`nav_transition` reads them."""
    return np.array([layout[nm].start if layout.has(nm) else -1 for nm in TRANSITION_GROUPS], dtype=np.int64)


def gyro_gm_taus(tau) -> np.ndarray:
    """(3,) correlation times of the Gauss-Markov gyro error per body axis [s] from a scalar or
    three values (:attr:`nav.tuning.Tuning.gyro_gm_tau_s`); inf where 0 (unused, no state)."""
    t = np.broadcast_to(np.asarray(tau, float), (3,)).copy()
    t[t == 0.0] = np.inf
    return t


def gyro_gm_indices(layout: StateLayout) -> np.ndarray:
    """State indices (3,) of the Gauss-Markov gyro error ``g_w`` (empty when not in the layout)."""
    if not layout.has("gyro_gm"):
        return np.zeros(0, np.int64)
    return np.arange(layout["gyro_gm"].start, layout["gyro_gm"].stop, dtype=np.int64)


def edge_gm_indices(layout: StateLayout, tau_edge: float) -> np.ndarray:
    """State indices of the Gauss-Markov edge heights ``h_e`` (empty when they are constants,
    ``tau_edge`` 0, or not in the layout)."""
    if not tau_edge > 0:
        return np.zeros(0, np.int64)
    return np.array([g.slice.start for g in layout.groups if g.name.startswith("h_e_")], np.int64)


@nb.njit(cache=True)
def propagate_covariance(P, A, d, q_add, zeta_start, P_c, gm_add, work):
    """In place: ``P <- sym(Phi P Phi^T + diag(q_add) + gm_add P_c[g] on each zeta block)``.

    The same arithmetic as :meth:`BlockTransition.apply` followed by the white process noise
    ``q dt`` and the Gauss-Markov driving noise ``(1 - phi^2) P_c`` of 003 eqs. (43)-(45) (the
    filter's propagation, :mod:`nav.navigator`), without n x n temporaries: ``work`` (n, n) is
    scratch, and the products run over the non-zero columns of A only (the columns of psi_c,
    dt_c and zeta are zero).

    Parameters
    ----------
    P : (n, n) covariance, overwritten; A : (9, n) navigation rows of Phi; d : (n,) diagonal of
    the other rows; q_add : (n,) added to the diagonal; zeta_start : (nz,) int64 first index of
    each zeta group; P_c : (nz, 3, 3) their latest P_c; gm_add : ``1 - phi^2``; work : (n, n).
    """
    n = P.shape[0]
    cols = np.empty(n, np.int64)
    nc = 0
    for j in range(n):
        for i in range(9):
            if A[i, j] != 0.0:
                cols[nc] = j
                nc += 1
                break
    M = work
    # M = Phi P: rows 0..8 are A P, the others d_i P_i
    for i in range(9):
        for j in range(n):
            M[i, j] = 0.0
        for q in range(nc):
            c = cols[q]
            a = A[i, c]
            for j in range(n):
                M[i, j] += a * P[c, j]
    for i in range(9, n):
        di = d[i]
        for j in range(n):
            M[i, j] = P[i, j] * di
    # P = M Phi^T: columns 0..8 are M A^T, the others M_j d_j
    for i in range(n):
        for j in range(9):
            a = 0.0
            for q in range(nc):
                c = cols[q]
                a += M[i, c] * A[j, c]
            P[i, j] = a
        for j in range(9, n):
            P[i, j] = M[i, j] * d[j]
    for i in range(n):
        P[i, i] += q_add[i]
    for g in range(zeta_start.size):
        o = zeta_start[g]
        for i in range(3):
            for j in range(3):
                P[o + i, o + j] += gm_add * P_c[g, i, j]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v
