"""RTS smoother (nav/smoother.py): filterpy on a linear toy, and better than the filter on a coast."""
import numpy as np
from filterpy.kalman import KalmanFilter

from nav.navigator import run
from nav.smoother import rts, rts_smooth
from nav.tuning import Tuning
from tests.test_navigator import attitude_errors, perturbed_init, synthetic_coast


def test_rts_matches_filterpy_on_linear_toy():
    """Constant-acceleration toy: our RTS equals filterpy's rts_smoother to machine precision
    (both are the same algebra; the tolerance is a few ulps of the state magnitude)."""
    rng = np.random.default_rng(0)
    dt = 0.1
    F = np.array([[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]])
    kf = KalmanFilter(dim_x=3, dim_z=1)
    kf.F = F
    kf.H = np.array([[1.0, 0, 0]])
    kf.R *= 0.5
    kf.Q = np.diag([1e-4, 1e-3, 1e-2])
    kf.P *= 10
    zs = np.cumsum(np.cumsum(rng.normal(0, 0.1, 200))) * dt + rng.normal(0, 0.7, 200)
    mu, cov, mu_p, cov_p = kf.batch_filter(zs)
    xs_ref, Ps_ref, _, _ = kf.rts_smoother(mu, cov)
    # filterpy's batch_filter predicts then updates: prior[k] is the prediction for epoch k and
    # Fs[k] maps k to k+1
    xs, Ps = rts(mu[:, :, 0], cov, mu_p[:, :, 0], cov_p, [F] * len(zs))
    # filterpy inverts P_prior explicitly where we solve: the two round-offs differ by
    # cond(P_prior) * eps per step, which accumulates to ~1e-13 of the covariance scale
    np.testing.assert_allclose(xs, xs_ref[:, :, 0], rtol=0, atol=1e-12 * np.abs(xs_ref).max())
    np.testing.assert_allclose(Ps, Ps_ref, rtol=0, atol=1e-12 * np.abs(Ps_ref).max())


def test_smoother_beats_filter_on_coast():
    """Synthetic coast with table-3 errors and a perturbed start: the smoothed RMS attitude error
    over the run is below the forward filter's (the early epochs gain most), and the smoothed
    errors lie within 3.5 sigma of the smoothed covariance at >= 99 % of the epochs per axis."""
    tun = Tuning()
    syn = synthetic_coast(7, duration=90)
    init = perturbed_init(syn, np.random.default_rng(8), tun)
    res = run(syn.imu, init, tun, gps=syn.gps, vectors=syn.vectors, R_bc=syn.R_bc_nominal)
    sm = rts_smooth(res)
    psi_f = attitude_errors(res.q_eb[sm.idx], syn.truth_q[sm.idx])
    psi_s = attitude_errors(sm.q_eb, syn.truth_q[sm.idx])
    rms_f = np.sqrt(np.mean(np.sum(psi_f ** 2, 1)))
    rms_s = np.sqrt(np.mean(np.sum(psi_s ** 2, 1)))
    assert rms_s < 0.7 * rms_f
    sig = np.sqrt(sm.P[:, res.layout["psi"]])
    assert np.mean(np.abs(psi_s) < 3.5 * sig) > 0.99
    pos_s = np.linalg.norm(sm.x_e - syn.truth_x[sm.idx], axis=1)
    pos_f = np.linalg.norm(res.x_e[sm.idx] - syn.truth_x[sm.idx], axis=1)
    assert np.sqrt(np.mean(pos_s ** 2)) < np.sqrt(np.mean(pos_f ** 2))


def test_rts_kernel_equals_numpy_recursion():
    """The numba backward pass equals the recursion over the estimated states written with numpy
    on the same store (synthetic coast, 45 states): smoothed errors to 1e-10 of their scale and
    variances to 1e-8 relative (P_prior's condition number reaches ~1e10 here, so two correct
    solvers differ by up to ~cond * eps in the gain)."""
    tun = Tuning()
    syn = synthetic_coast(3, duration=30)
    res = run(syn.imu, syn.init, tun, gps=syn.gps, vectors=syn.vectors, R_bc=syn.R_bc_nominal)
    sm = rts_smooth(res)
    st = res.store
    est = res.layout.estimated_mask
    post = lambda k: res.P_full[st.post[k]] if st.post[k] >= 0 else st.P_prior[k]
    K, n = st.P_prior.shape[:2]
    e = np.flatnonzero(est)
    ee = np.ix_(e, e)
    d = np.zeros((K, n)); Pd = np.zeros((K, n)); Pn = np.zeros((K, 9, 9))
    Ps = post(K - 1)[ee]; Pd[-1] = np.diag(post(K - 1)); Pn[-1] = Ps[:9, :9]
    for k in range(K - 2, -1, -1):
        Phi = st.transition(k + 1).full()[ee]
        M = Phi @ post(k)[ee] @ Phi.T
        lam, V = np.linalg.eigh(st.P_prior[k + 1][ee] - M)
        Pp = M + (V * np.maximum(lam, 0)) @ V.T
        C = post(k)[ee] @ Phi.T @ np.linalg.inv(Pp)
        d[k, e] = C @ (d[k + 1, e] + st.dx[k + 1, e])
        Ps = post(k)[ee] + C @ (Ps - Pp) @ C.T
        Pd[k] = np.diag(post(k)); Pd[k, e] = np.diag(Ps); Pn[k] = Ps[:9, :9]
    scale = np.abs(d).max(axis=0)
    assert np.all(np.abs(sm.d - d) <= 1e-10 * scale + 1e-300)
    np.testing.assert_allclose(sm.P, Pd, rtol=1e-8)
    # the navigation block: its diagonal is Pd's; off-diagonal terms to 1e-8 of the diagonal scale
    sc = np.sqrt(np.einsum("kii,kjj->kij", Pn, Pn))
    assert np.all(np.abs(sm.P_nav - Pn) <= 1e-8 * sc)
