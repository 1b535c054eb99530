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
