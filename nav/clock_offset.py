"""Initial estimate of a camera's clock offset against the IMU time base (003 §7.3).

003 §7.3: the ATEK cameras' clocks could not be synchronised with the system time. The offset is
defined as in the simulator (``scenarios/sim/simulate.py``): a frame taken at IMU time ``t`` is
stamped ``t + tau``, so the frame stamped ``s`` was taken at ``s - tau``.

Method: rotation changes
------------------------
The gyros give the body attitude relative to an inertial frame, ``R_ib(t)`` (integrated here from
``R_ib(t_0) = I``; the unknown absolute attitude ``M`` cancels). A target fixed in inertial space
(the Sun; the Moon to 0.5 deg/h) seen at frames ``i`` and ``j`` of the same camera satisfies::

    e_c(t_j) = R_bc^T R_ib(t_j - tau)^T R_ib(t_i - tau) R_bc e_c(t_i)          (1)

(003 eq. (39) written twice, the inertial direction eliminated). For each candidate ``tau`` the
pairs (i, j) of one stream with ``0 < t_j - t_i <= max_pair_s`` give residuals
``r_ij = e_c(t_j) - prediction`` (a near-tangent 3-vector, ``|r| ~ angle``). The Earth nadir moves
in inertial space with the vehicle (about ``|v_inertial| / r``, 0.016 deg/s on the ATEK coast): if
GPS positions and an approximate attitude ``q_eb0`` at the first IMU sample are given, (1) is
corrected by the rotation taking the inertial nadir at ``t_i - tau`` to the one at ``t_j - tau``
(needs the absolute attitude, but only to first order: a few degrees of error in ``q_eb0``
change a 0.016 deg correction by < 0.001 deg); otherwise that motion is left as noise.

Sensitivity to the mounting: with ``R_bc`` wrong by a small rotation ``E``, (1) predicts with
``E^T R_rel E`` instead of ``R_rel``, an error of ~|E| x the pair's rotation angle: first order
in the mounting error but scaled by the small pair rotation (see "Mounting" below for why it is
still fitted).

Observability: if the body rate is constant, ``R_ib(t_j - tau)^T R_ib(t_i - tau)`` does not depend
on tau at all (a time shift is a constant rotation, absorbed by ``M``): tau is seen only through
the *changes* of the body rate between ``t_i`` and ``t_j`` (RCS pulses, nutation).

Search (robust to gaps and outliers)
------------------------------------
1. Coarse grid over ``search_s`` (step ``grid_step_s``); pairs are formed only within
   ``max_pair_s`` (gaps just remove pairs) and only from frames whose shifted times stay inside
   the IMU span for every candidate, so every candidate sees the same pairs.
2. Noise scale ``k``: 1 with the given covariances (floored by the data's typical level), else
   the typical level (median over the grid of the median residual; the median of a chi-square
   with 2 dof is 2 ln 2); not the least median of squares (see the code for why).
   A truncated quadratic cost ``sum min(z^2, c^2)`` (``z = |r| / (k sigma_p)``, ``c^2`` the 99.9 %
   chi-square(2) point) on the grid picks the global minimum.
3. Inliers (``z^2 < c^2``) at that point; golden-section search of the weighted least-squares
   cost in the bracket of +-1 grid step; inliers re-selected and the search repeated once.
4. Uncertainty: Gauss-Newton curvature ``sigma^2 = k_post^2 / sum |dr/dtau|^2 / sigma_p^2`` with
   the posterior reduced chi-square ``k_post^2`` and ``dr/dtau`` the profile derivative (psi_c
   re-fitted), times :data:`SIGMA_INFLATION` (calibrated by Monte Carlo, see there). A block
   bootstrap does not fit this problem: the information sits in a few RCS pulses, so resamples
   that miss them give a standard deviation 3-8x too large, and a MAD 3x too small.

Mounting: with 1 deg mounting errors the pure rotation-change prediction (1) is off by
~1 deg x the pair's rotation (0.03 deg for 2 s at 0.9 deg/s: as large as the vision noise) and
biased tau by several ms on the atek coast; so a mounting correction psi_c (3 parameters,
003 eq. (50)) is fitted jointly, linear at each tau (``fit_mounting``; its estimate is returned).
Caveat: with psi_c free, a mounting rotation trades against tau where the body cones (rate
vector turning at Omega: ``psi_c = -Omega dtau`` mimics the shift), so pairs that straddle rate
changes carry the information and must not be discarded as outliers (step 2). The fitted psi_c
is a rough by-product only (tests: 15-21 % of a 1.5-3 deg misalignment; much worse with gaps).

Per-pair sigma: ``sigma_p^2 = (tr P_c,i + tr P_c,j) / 2`` (per axis of the difference) if
covariances are given, else 1 (the robust scale ``k`` then carries the units).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nav.earth import OMEGA_E
from nav.rotation import quat_multiply, quat_to_matrix, rotvec_to_matrix, rotvec_to_quat

NS = 1_000_000_000
CHI2_2_999 = -2.0 * math.log(1e-3)  #: 99.9 % point of chi-square(2): 13.8
MEDIAN_CHI2_2 = 2.0 * math.log(2.0)  #: median of chi-square(2)
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
#: curvature sigma -> reported sigma; measured: 20 simulated atek coasts (table-3 IMU, 0.05 deg
#: Gauss-Markov + 0.02 deg white vector errors, offsets -1.7 / +0.8 s) gave error RMS / mean
#: curvature sigma = 5.9 / 4.7 ms and 4.9 / 3.8 ms (1.25, 1.28): pairs share frames and the
#: gyro errors (0.03 deg/s quantisation at 20 Hz) enter the prediction, neither of which the
#: curvature sees.
SIGMA_INFLATION = 1.3


@dataclass
class ClockOffsetEstimate:
    """Result of :func:`estimate_clock_offset`.

    Attributes
    ----------
    tau_s : float
        Camera clock minus IMU time [s] (a frame taken at IMU time t is stamped t + tau).
    sigma_s : float
        1-sigma uncertainty [s]: ``sigma_inflation * sigma_curvature_s``.
    sigma_curvature_s : float
        From the curvature of the cost with the posterior noise scale.
    grid_s, cost : (G,) arrays
        The coarse grid and its truncated robust cost (for plots / diagnostics).
    n_pairs, n_inliers : int
    rms_residual_rad : float
        RMS angular residual of the inlier pairs at ``tau_s``.
    scale : float
        Posterior noise scale ``k_post`` (1 = the given covariances explain the residuals).
    psi_c : (3,)
        Mounting correction fitted with tau (b frame, 003 eq. (50)); zeros if not fitted.
    """
    tau_s: float
    sigma_s: float
    sigma_curvature_s: float
    grid_s: np.ndarray
    cost: np.ndarray
    n_pairs: int
    n_inliers: int
    rms_residual_rad: float
    scale: float
    psi_c: np.ndarray


class GyroAttitude:
    """Body attitude relative to inertial space from the gyros alone, ``R_ib(t)`` with
    ``R_ib(t_0) = I``, at any time inside the IMU span.

    ``sample="average"``: the rate of sample k+1 is the mean over (t_k, t_{k+1}] (increments / dt);
    ``"point"``: instantaneous rates, the interval uses their mean (and linear interpolation inside
    it). The cumulative product of the per-interval rotations is a parallel prefix scan
    (Hillis-Steele, log2(N) vectorised quaternion products).
    """

    def __init__(self, t_ns, w_b, sample: str = "average"):
        t_ns = np.asarray(t_ns, dtype=np.int64)
        w = np.asarray(w_b, float)
        if t_ns.ndim != 1 or w.shape != (t_ns.size, 3) or t_ns.size < 2:
            raise ValueError(f"imu: expected t_ns (N,) with N >= 2 and w_b (N, 3); got {t_ns.shape}, {w.shape}")
        if np.any(np.diff(t_ns) <= 0):
            raise ValueError("imu.t_ns: sample times must increase")
        if not np.all(np.isfinite(w)):
            raise ValueError("imu.w_b: non-finite rates (clean the samples first)")
        if sample not in ("average", "point"):
            raise ValueError(f"sample: expected 'average' or 'point', got {sample!r}")
        self.t0_ns = int(t_ns[0])
        self.t = (t_ns - t_ns[0]).astype(float) / NS
        self.w = w
        self.sample = sample
        h = np.diff(self.t)
        w_int = w[1:] if sample == "average" else 0.5 * (w[:-1] + w[1:])
        inc = rotvec_to_quat(w_int * h[:, None])
        q = np.concatenate([[[0.0, 0.0, 0.0, 1.0]], inc])
        s = 1
        while s < q.shape[0]:
            q[s:] = quat_multiply(q[:-s], q[s:])
            s *= 2
        self.q = q / np.linalg.norm(q, axis=1, keepdims=True)

    @property
    def span_s(self):
        return self.t[0], self.t[-1]

    def rate(self, t_s) -> np.ndarray:
        """Body rate omega_ib_b at times ``t_s`` [s since the first IMU sample]."""
        t_s = np.asarray(t_s, float)
        k = np.clip(np.searchsorted(self.t, t_s, side="right") - 1, 0, self.t.size - 2)
        if self.sample == "average":
            return self.w[k + 1]
        a = ((t_s - self.t[k]) / (self.t[k + 1] - self.t[k]))[..., None]
        return (1 - a) * self.w[k] + a * self.w[k + 1]

    def matrix(self, t_s) -> np.ndarray:
        """``R_ib`` at times ``t_s`` [s since the first IMU sample]; (..., 3, 3)."""
        t_s = np.asarray(t_s, float)
        k = np.clip(np.searchsorted(self.t, t_s, side="right") - 1, 0, self.t.size - 2)
        d = (t_s - self.t[k])[..., None]
        if self.sample == "average":
            phi = self.w[k + 1] * d
        else:
            h = (self.t[k + 1] - self.t[k])[..., None]
            phi = self.w[k] * d + (self.w[k + 1] - self.w[k]) * d ** 2 / (2 * h)
        return quat_to_matrix(quat_multiply(self.q[k], rotvec_to_quat(phi)))


class _PairProblem:
    """Pairs (i, j) of one camera and their prediction (1) as a function of tau."""

    def __init__(self, gyro: GyroAttitude, t_s, target, e_c, P_c, R_bc, search, max_pair_s,
                 nadir_e0=None, fit_mounting=True):
        self.gyro = gyro
        self.fit_mounting = fit_mounting
        self.R_bc = R_bc
        lo, hi = gyro.span_s
        # frames whose shifted times stay inside the IMU span for every candidate tau
        ok = (t_s - search[1] >= lo) & (t_s - search[0] <= hi)
        ii, jj = [], []
        for tg in np.unique(target):
            idx = np.flatnonzero(ok & (target == tg))
            idx = idx[np.argsort(t_s[idx], kind="stable")]
            ts = t_s[idx]
            for lag in range(1, idx.size):
                d = ts[lag:] - ts[:-lag]
                m = (d > 0) & (d <= max_pair_s)
                if not m.any():
                    break
                ii.append(idx[:-lag][m]); jj.append(idx[lag:][m])
        self.i = np.concatenate(ii) if ii else np.zeros(0, int)
        self.j = np.concatenate(jj) if jj else np.zeros(0, int)
        o = np.argsort(t_s[self.i], kind="stable")
        self.i, self.j = self.i[o], self.j[o]
        self.ti, self.tj = t_s[self.i], t_s[self.j]
        used, inv = np.unique(np.concatenate([self.i, self.j]), return_inverse=True)
        self.tf = t_s[used]
        self.fi, self.fj = inv[:self.i.size], inv[self.i.size:]
        self.ei_c = e_c[self.i]
        self.ej = e_c[self.j]
        if P_c is None:
            self.sig2 = np.ones(self.i.size)
        else:
            tr = np.trace(P_c, axis1=1, axis2=2)
            self.sig2 = 0.5 * (tr[self.i] + tr[self.j])
        self.is_nadir = np.asarray(target)[self.i] == "hor"
        self.nadir_e0 = nadir_e0       # callable t_s -> (inertial nadir in e0, M = R_e0 b0) or None

    def relative(self, tau: float) -> np.ndarray:
        """Body-frame rotation of each pair, ``A = R_ib(t_j - tau)^T Q_ij R_ib(t_i - tau)`` (P, 3, 3),
        with ``Q_ij`` the nadir's inertial motion (identity without the nadir model), so that
        (1) reads ``e_c(t_j) = R_bc^T A R_bc e_c(t_i)``."""
        R = self.gyro.matrix(self.tf - tau)            # once per frame, not per pair
        Ri, Rj = R[self.fi], R[self.fj]
        if self.nadir_e0 is not None and self.is_nadir.any():
            M = self.nadir_e0.M
            m = self.is_nadir
            u = self.nadir_e0(self.tf - tau)
            Q = M.T @ _rotation_between(u[self.fi[m]], u[self.fj[m]]) @ M   # in the b frame at t_0
            Ri = Ri.copy()
            Ri[m] = Q @ Ri[m]
        return np.swapaxes(Rj, 1, 2) @ Ri

    def predict(self, tau: float, psi=None) -> np.ndarray:
        """Prediction (1) of e_c(t_j); ``psi`` a mounting correction in b,
        ``R_bc = exp([psi x]) R_bc_nominal`` (003 eq. (50))."""
        R_bc = self.R_bc if psi is None else rotvec_to_matrix(psi) @ self.R_bc
        return np.einsum("kij,kj->ki", self.relative(tau), self.ei_c @ R_bc.T) @ R_bc

    def residual(self, tau: float, psi=None) -> np.ndarray:
        return self.ej - self.predict(tau, psi)

    def fitted(self, tau: float, mask=None, k2=None):
        """Residuals at ``tau`` after fitting the mounting correction psi (one Gauss-Newton step
        from psi = 0, exact to ~|psi|^2 x the pair rotation, 1e-5 rad for 1 deg and 3 deg; robust:
        all pairs, then those with ``|r|^2 / sigma_p^2 < c^2 k2`` (``k2`` the noise scale, default
        from the median); or the given inlier ``mask``).
        Returns (residual (P, 3), r2 = |r|^2 / sigma_p^2 (P,), psi (3,))."""
        A = self.relative(tau)
        bv = self.ei_c @ self.R_bc.T                               # R_bc e_i
        Ab = np.einsum("kij,kj->ki", A, bv)
        r = self.ej - Ab @ self.R_bc
        w = 1.0 / self.sig2
        psi = np.zeros(3)
        if not self.fit_mounting:
            return r, np.sum(r ** 2, 1) * w, psi
        # d/dpsi of R_bc^T E^T A E b at psi = 0 (E = exp([psi x])): R_bc^T ([A b x] - A [b x])
        J = self.R_bc.T @ (_skew_rows(Ab) - A @ _skew_rows(bv))
        fixed = mask is not None
        mask = np.ones(r.shape[0], bool) if mask is None else mask
        for _pass in range(1 if fixed else 2):
            ww = w * mask
            Am = np.einsum("k,kia,kib->ab", ww, J, J)
            bm = np.einsum("k,kia,ki->a", ww, J, r)
            try:
                psi = np.linalg.solve(Am + 1e-12 * np.trace(Am) * np.eye(3), bm)
            except np.linalg.LinAlgError:
                psi = np.zeros(3)
            r_lin = r - J @ psi
            r2 = np.sum(r_lin ** 2, 1) * w
            kk = max(np.median(r2) / MEDIAN_CHI2_2, 1e-300) if k2 is None else k2
            mask = r2 / kk < CHI2_2_999
        return r_lin, r2, psi


def _skew_rows(v):
    z = np.zeros(v.shape[0])
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], 1), np.stack([v[:, 2], z, -v[:, 0]], 1),
                     np.stack([-v[:, 1], v[:, 0], z], 1)], 1)


def _rotation_between(a, b):
    """Minimal rotations (P, 3, 3) taking unit vectors ``a`` to ``b`` (rows; Rodrigues)."""
    ax = np.cross(a, b)
    s = np.linalg.norm(ax, axis=-1)
    c = np.sum(a * b, axis=-1)
    k = np.divide(ax, s[:, None], out=np.zeros_like(ax), where=s[:, None] > 0)
    K = _skew_rows(k)
    return np.eye(3) + s[:, None, None] * K + (1 - c)[:, None, None] * (K @ K)


class _NadirE0:
    """Inertial nadir (in the e frame frozen at the first IMU sample, e0) from GPS positions, and
    the absolute attitude ``M = R_e0 b(t_0)``."""

    def __init__(self, gps_t_s, gps_x_e, q_eb0):
        from scipy.interpolate import make_interp_spline
        o = np.argsort(gps_t_s)
        self.spl = make_interp_spline(gps_t_s[o], gps_x_e[o], k=min(3, o.size - 1))
        self.M = quat_to_matrix(np.asarray(q_eb0, float))

    def __call__(self, t_s):
        x = self.spl(t_s)
        a = OMEGA_E * t_s
        c, s = np.cos(a), np.sin(a)
        # R_e0e(t) = Rz(+Omega t): e rotates eastwards relative to the inertial frame e0
        u = -x / np.linalg.norm(x, axis=1, keepdims=True)
        return np.stack([c * u[:, 0] - s * u[:, 1], s * u[:, 0] + c * u[:, 1], u[:, 2]], axis=1)


def _golden(f, a, b, tol):
    c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
    fc, fd = f(c), f(d)
    while b - a > tol:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - _GOLDEN * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + _GOLDEN * (b - a)
            fd = f(d)
    return 0.5 * (a + b)


def estimate_clock_offset(imu_t_ns, w_b, vec_t_ns, target, e_c, R_bc, *, sample: str = "average",
                          P_c=None, search_s=(-2.0, 2.0), grid_step_s: float = 0.02,
                          max_pair_s: float = 2.0, gps_t_ns=None, gps_x_e=None, q_eb0=None,
                          fit_mounting: bool = True, sigma_inflation: float = SIGMA_INFLATION,
                          tol_s: float = 1e-4) -> ClockOffsetEstimate:
    """Clock offset of one camera from its vectors and the gyros (see the module docstring).

    Parameters
    ----------
    imu_t_ns, w_b : (N,), (N, 3)
        IMU times [int ns] and rates omega_ib_b [rad/s] (cleaned: increasing, finite).
    vec_t_ns, target, e_c : (K,), (K,), (K, 3)
        This camera's vector stamps on the camera clock [int ns], targets ("hor", "sun", "moon")
        and unit vectors in the camera frame.
    R_bc : (3, 3)
        Nominal mounting (known to ~1 deg is enough).
    sample : "average" or "point"
        IMU sample type (:class:`nav.navigator.ImuData`).
    P_c : (K, 3, 3), optional
        Vector covariances (003 eq. (33)); weights only, their overall scale is estimated.
    search_s : (lo, hi)
        Range of candidate offsets [s].
    grid_step_s : float
        Coarse grid step [s]; must be below the time scale of the body-rate changes.
    max_pair_s : float
        Longest frame separation in a pair [s].
    gps_t_ns, gps_x_e, q_eb0 : optional
        GPS times and positions in e, and the approximate attitude at the first IMU sample: with
        all three the nadir's motion is modelled.
    fit_mounting : bool
        Fit a mounting correction psi_c with tau (default; see the module docstring).
    sigma_inflation : float
        Factor from the curvature sigma to the reported ``sigma_s`` (module docstring, step 4).
    tol_s : float
        Golden-section tolerance [s].
    """
    lo, hi = (float(search_s[0]), float(search_s[1]))
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"search_s: expected (lo, hi) with lo < hi, got {search_s!r}")
    if not grid_step_s > 0 or not max_pair_s > 0:
        raise ValueError(f"grid_step_s and max_pair_s: expected > 0, got {grid_step_s}, {max_pair_s}")
    gyro = GyroAttitude(imu_t_ns, w_b, sample)
    vt, e, tg, Pc = _usable_vectors(vec_t_ns, target, e_c, P_c)
    t_s = (vt - gyro.t0_ns).astype(float) / NS
    nadir = None
    if gps_t_ns is not None and gps_x_e is not None and q_eb0 is not None:
        gt = (np.asarray(gps_t_ns, dtype=np.int64) - gyro.t0_ns).astype(float) / NS
        gx = np.asarray(gps_x_e, float)
        if gx.shape != (gt.size, 3) or gt.size < 2:
            raise ValueError(f"gps: expected t (M,) and x_e (M, 3) with M >= 2; got {gt.shape}, {gx.shape}")
        nadir = _NadirE0(gt, gx, q_eb0)
    prob = _PairProblem(gyro, t_s, tg, e, Pc, np.asarray(R_bc, float), (lo, hi), max_pair_s, nadir, fit_mounting)
    n_p = prob.i.size
    if n_p < 3:
        raise ValueError(f"vectors: only {n_p} frame pairs within {max_pair_s} s inside the IMU span for "
                         f"offsets {lo}..{hi} s; need at least 3")
    grid = np.arange(lo, hi + 0.5 * grid_step_s, grid_step_s)
    # 2. noise scale: the given covariances (floored by the data), else the typical level of the
    # residuals over the grid. Not the least median of squares: the information on tau sits in
    # the minority of pairs that straddle a body-rate change, which a median-based scale at the
    # best candidate would throw out as outliers (the majority fits any tau when psi_c is free).
    r2u = np.array([np.sum(prob.residual(tau) ** 2, 1) / prob.sig2 for tau in grid])
    k2 = float(np.median(np.median(r2u, axis=1))) / MEDIAN_CHI2_2
    k2 = max(k2, 1.0) if Pc is not None else max(k2, 1e-300)
    r2 = np.array([prob.fitted(tau, k2=k2)[1] for tau in grid])
    cost = np.minimum(r2 / k2, CHI2_2_999).sum(axis=1)
    g0 = int(np.argmin(cost))
    tau = float(grid[g0])
    inl = r2[g0] / k2 < CHI2_2_999

    def wls(tt, mask):
        return float(np.sum(prob.fitted(tt, mask)[1][mask]))

    for _ in range(2):
        tau = _golden(lambda tt: wls(tt, inl), tau - grid_step_s, tau + grid_step_s, tol_s)
        r0, r2_now, psi = prob.fitted(tau, inl)
        inl = r2_now / k2 < CHI2_2_999
    sig_curv, n_in, rms, kpost2, psi = _curvature_sigma(prob, tau, inl, fit_mounting)
    return ClockOffsetEstimate(tau, sigma_inflation * sig_curv, sig_curv, grid, cost, n_p, n_in, rms,
                               math.sqrt(kpost2), psi)


def _usable_vectors(vec_t_ns, target, e_c, P_c):
    """The vectors with a finite direction (and covariance), normalised: (t_ns, e, target, P_c)."""
    vt = np.asarray(vec_t_ns, dtype=np.int64)
    e = np.asarray(e_c, float)
    tg = np.asarray(target).astype(str)
    if e.shape != (vt.size, 3) or tg.shape != (vt.size,):
        raise ValueError(f"vectors: expected t (K,), target (K,), e_c (K, 3); got {vt.shape}, {tg.shape}, {e.shape}")
    Pc = None if P_c is None else np.asarray(P_c, float)
    if Pc is not None and Pc.shape != (vt.size, 3, 3):
        raise ValueError(f"P_c: expected ({vt.size}, 3, 3), got {Pc.shape}")
    nrm = np.linalg.norm(e, axis=1)
    good = np.isfinite(nrm) & (nrm > 0)
    if Pc is not None:
        good &= np.all(np.isfinite(Pc), axis=(1, 2))
    vt, e, tg = vt[good], e[good] / nrm[good, None], tg[good]
    if Pc is not None:
        Pc = Pc[good]
    return vt, e, tg, Pc


def _curvature_sigma(prob, tau: float, inl, fit_mounting: bool):
    """Step 4 of the module docstring, linearised about tau with psi re-fitted (the profile
    derivative): (curvature sigma, inliers, RMS residual, posterior reduced chi-square, psi)."""
    r0, r2_now, psi = prob.fitted(tau, inl)
    h = 1e-3
    g = (prob.fitted(tau + h, inl)[0] - prob.fitted(tau - h, inl)[0]) / (2 * h)
    w = inl / prob.sig2
    n_in = int(inl.sum())
    info = float(np.sum(w * np.sum(g ** 2, 1)))
    kpost2 = float(np.sum(w * np.sum(r0 ** 2, 1)) / max(2 * n_in - 1 - (3 if fit_mounting else 0), 1))
    sig_curv = math.sqrt(kpost2 / info) if info > 0 else math.inf
    rms = float(np.sqrt(np.mean(np.sum(r0[inl] ** 2, 1)))) if n_in else math.nan
    return sig_curv, n_in, rms, kpost2, psi


def estimate_camera_offsets(imu, vectors, R_bc, *, gps=None, q_eb0=None, **kw) -> list:
    """:func:`estimate_clock_offset` for every camera index 0..len(R_bc)-1 of a
    :class:`nav.navigator.VectorData` (``imu`` an :class:`nav.navigator.ImuData`, ``gps`` an
    optional :class:`nav.navigator.GpsData`); a camera without enough pairs gives None."""
    out = []
    cam = np.asarray(vectors.camera)
    for c in range(len(R_bc)):
        m = cam == c
        if m.sum() < 2:
            out.append(None)
            continue
        try:
            out.append(estimate_clock_offset(
                imu.t_ns, imu.w_b, np.asarray(vectors.t_ns)[m], np.asarray(vectors.target)[m],
                np.asarray(vectors.e_c)[m], R_bc[c], sample=imu.sample,
                P_c=None if vectors.P_c is None else np.asarray(vectors.P_c)[m],
                gps_t_ns=None if gps is None else gps.t_ns, gps_x_e=None if gps is None else gps.x_e,
                q_eb0=q_eb0, **kw))
        except ValueError as err:
            if "frame pairs" not in str(err):
                raise
            out.append(None)
    return out
