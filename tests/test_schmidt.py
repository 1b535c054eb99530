"""Schmidt-Kalman core (nav/schmidt.py): identities and a Monte Carlo of the consider covariance."""
import numpy as np
import pytest

from nav.schmidt import chi2_gate, schmidt_update

rng = np.random.default_rng(1)


def _spd(n, scale=1.0):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T + n * np.eye(n))


def test_all_estimated_equals_kalman():
    """With every state estimated the update is the optimal Kalman update: P+ = (I - KH) P."""
    P = _spd(6)
    H = rng.normal(size=(3, 6))
    R = _spd(3, 0.1)
    s = rng.normal(size=3)
    r = schmidt_update(P, H, R, s, np.ones(6, bool))
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    np.testing.assert_allclose(r.P, (np.eye(6) - K @ H) @ P, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(r.dx, K @ s, rtol=1e-12)
    S = H @ P @ H.T + R
    assert r.nis == pytest.approx(s @ np.linalg.solve(S, s), rel=1e-12)


def test_considered_rows_untouched_and_joseph():
    """Considered states: zero correction, unchanged own covariance block, Joseph form for the
    rest (compared with the textbook Joseph expression)."""
    P = _spd(6)
    H = rng.normal(size=(2, 6))
    R = _spd(2, 0.1)
    est = np.array([1, 1, 1, 0, 0, 1], bool)
    r = schmidt_update(P, H, R, rng.normal(size=2), est)
    assert np.all(r.dx[~est] == 0)
    np.testing.assert_allclose(r.P[np.ix_(~est, ~est)], P[np.ix_(~est, ~est)], rtol=1e-12)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    K[~est] = 0
    I_KH = np.eye(6) - K @ H
    np.testing.assert_allclose(r.P, I_KH @ P @ I_KH.T + K @ R @ K.T, rtol=1e-10, atol=1e-12)
    assert np.array_equal(r.P, r.P.T)
    assert np.linalg.eigvalsh(r.P)[0] > 0


def test_schmidt_covariance_matches_monte_carlo():
    """The Schmidt covariance is the true covariance of its (suboptimal) estimate: 20000 draws,
    errors' sample covariance within 5 % (sampling error of a variance with 20000 samples is
    1 %) on the diagonal."""
    n = 4
    P = _spd(n)
    H = rng.normal(size=(2, n))
    R = _spd(2, 0.5)
    est = np.array([1, 1, 0, 0], bool)
    r0 = schmidt_update(P, H, R, np.zeros(2), est)
    Ks = np.stack([schmidt_update(P, H, R, e, est).dx for e in np.eye(2)], axis=1)
    Lp, Lr = np.linalg.cholesky(P), np.linalg.cholesky(R)
    N = 20000
    x = rng.normal(size=(N, n)) @ Lp.T
    z = x @ H.T + rng.normal(size=(N, 2)) @ Lr.T
    err = x - z @ Ks.T
    C = err.T @ err / N
    np.testing.assert_allclose(np.diag(C), np.diag(r0.P), rtol=0.05)


def test_gate_and_bad_input():
    P = _spd(3)
    H = np.eye(3)
    R = np.eye(3)
    g = chi2_gate(3, 0.999)
    assert g == pytest.approx(16.266, rel=1e-3)
    r = schmidt_update(P, H, R, np.array([1e3, 0, 0]), np.ones(3, bool), gate=g)
    assert not r.accepted and r.reason == "chi-square gate" and r.P is P
    r = schmidt_update(P, H, R, np.array([np.nan, 0, 0]), np.ones(3, bool))
    assert not r.accepted and "non-finite" in r.reason
    r = schmidt_update(P, H, -10 * np.eye(3) * np.abs(P).max(), np.zeros(3), np.ones(3, bool))
    assert not r.accepted and "positive definite" in r.reason


def test_update_kernel_blocks_equal_textbook_joseph():
    """Several blocks at once (issue 7): each block's NIS is the one of its own update with the
    prior, a gated block is left out, and the accepted blocks together give the textbook Joseph
    form with the Schmidt gain (n = 12, H sparse); agreement to round-off (1e-12 of |P|)."""
    from nav.schmidt import GATED, OK, update_kernel
    n = 12
    P = _spd(n)
    est = np.ones(n, bool); est[[4, 9, 10]] = False
    H = np.zeros((7, n))
    H[0:3, 0:3] = np.eye(3); H[0:3, 6:9] = rng.normal(size=(3, 3))     # like a GPS position
    H[3:5, [1, 4, 9]] = rng.normal(size=(2, 3))                         # a 2-row vector
    H[5:7, [2, 5, 10]] = rng.normal(size=(2, 3))                        # an outlier
    R = np.zeros((7, 7)); R[:3, :3] = _spd(3, 0.1); R[3:5, 3:5] = _spd(2, 0.1); R[5:, 5:] = _spd(2, 0.1)
    s = rng.normal(size=7); s[5:] = 1e3
    offs = np.array([0, 3, 5, 7]); gates = np.full(3, chi2_gate(3, 0.999))
    S = np.empty((7, 7)); nis = np.empty(3); code = np.empty(3, np.int64); dx = np.empty(n)
    Pn = P.copy()
    assert update_kernel(Pn, H, R, s, est, offs, gates, S, nis, code, dx) == OK
    assert list(code) == [OK, OK, GATED]
    for b in range(3):
        sl = slice(offs[b], offs[b + 1])
        Sb = H[sl] @ P @ H[sl].T + R[sl, sl]
        assert nis[b] == pytest.approx(s[sl] @ np.linalg.solve(Sb, s[sl]), rel=1e-10)
        np.testing.assert_allclose(S[sl, sl], Sb, rtol=1e-12)
    Ha, Ra, sa = H[:5], R[:5, :5], s[:5]
    K = P @ Ha.T @ np.linalg.inv(Ha @ P @ Ha.T + Ra)
    K[~est] = 0
    I_KH = np.eye(n) - K @ Ha
    np.testing.assert_allclose(Pn, I_KH @ P @ I_KH.T + K @ Ra @ K.T, rtol=0, atol=1e-12 * np.abs(P).max())
    np.testing.assert_allclose(dx, K @ sa, rtol=1e-10, atol=1e-14)
    assert np.array_equal(Pn, Pn.T)


def test_update_kernel_stacked_equals_sequential():
    """GPS position and velocity stacked in one 6-row update equal two sequential 3-row updates
    when everything is estimated (block-diagonal R: the Kalman update is exact in sequence);
    round-off only (1e-10 relative, the sequential path recomputes S from the updated P)."""
    n = 9
    P = _spd(n)
    H = np.zeros((6, n)); H[:3, :3] = np.eye(3); H[3:, 3:6] = np.eye(3); H[:, 6:] = rng.normal(size=(6, 3))
    R = np.zeros((6, 6)); R[:3, :3] = _spd(3, 0.5); R[3:, 3:] = _spd(3, 0.01)
    s = rng.normal(size=6)
    est = np.ones(n, bool)
    both = schmidt_update(P, H, R, s, est)
    a = schmidt_update(P, H[:3], R[:3, :3], s[:3], est)
    b = schmidt_update(a.P, H[3:], R[3:, 3:], s[3:] - H[3:] @ a.dx, est)
    np.testing.assert_allclose(both.P, b.P, rtol=1e-10, atol=1e-12 * np.abs(P).max())
    np.testing.assert_allclose(both.dx, a.dx + b.dx, rtol=1e-10)
