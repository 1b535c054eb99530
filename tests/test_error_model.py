"""Tests of the vision error model (vision/error_model.py).

Truths used: the cone geometry itself (every predicted pixel must unproject onto the cone,
003 eq. (3)); a closed form for the limb length of an on-axis disc in an equidistant camera
(r = f alpha); a dense brute-force trace of the cone; Monte Carlo of the actual estimators of
`vision.nadir` on pixels perturbed by correlated noise (003 eqs. (34)-(35)); and the closed-form
statistics of a first-order Gauss-Markov sequence (003 eqs. (41)-(45)).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from vision.camera import atek_camera, from_fov, project, unproject
from vision.error_model import (HORIZON_NOISE, SUN_NOISE, bloomed_alpha, cone_rays,
                                draw_vector_errors, linear_recurrence, predict_vision,
                                predicted_covariance, predicted_limb_pixels, psd_sqrt)
from vision.nadir import direction_and_radius, horizon_alpha, nadir_from_horizon

CAM = atek_camera()
R_EARTH = 6371.0e3


def _direction(off_deg: float, az_deg: float) -> np.ndarray:
    o, a = math.radians(off_deg), math.radians(az_deg)
    return np.array([math.sin(o) * math.cos(a), math.sin(o) * math.sin(a), math.cos(o)])


def _dense_visible_length(cam, e, alpha, mask=None) -> float:
    """Brute force: 400k uniform cone samples, polyline length of the longest visible run."""
    phi = np.linspace(0.0, 2 * math.pi, 400001)[:-1]
    uv = project(cam, cone_rays(e, alpha, phi))
    ok = (np.all(np.isfinite(uv), 1) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= cam.width - 0.5)
          & (uv[:, 1] >= -0.5) & (uv[:, 1] <= cam.height - 0.5))
    if mask is not None:
        iu = np.clip(np.rint(np.nan_to_num(uv[:, 0])), 0, cam.width - 1).astype(int)
        iv = np.clip(np.rint(np.nan_to_num(uv[:, 1])), 0, cam.height - 1).astype(int)
        ok &= ~mask[iv, iu]
    k = int(np.argmin(ok))
    uv, ok = np.roll(uv, -k, 0), np.roll(ok, -k)
    idx = np.nonzero(ok)[0]
    best = 0.0
    for run in np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1):
        q = uv[run]
        best = max(best, float(np.linalg.norm(np.diff(q, axis=0), axis=1).sum()))
    return best


GEOMS = [(H, off, az) for H in (60e3, 238e3, 800e3) for off, az in ((60, 70), (80, 200), (100, 300))]


@pytest.mark.parametrize("H, off, az", GEOMS)
def test_limb_pixels_on_cone_ordered_inside(H, off, az):
    alpha = horizon_alpha(H, R_EARTH)
    e = _direction(off, az)
    uv = predicted_limb_pixels(CAM, e, alpha)
    assert len(uv) > 200
    # inside the image (pixel edges)
    assert uv[:, 0].min() >= -0.5 and uv[:, 0].max() <= CAM.width - 0.5
    assert uv[:, 1].min() >= -0.5 and uv[:, 1].max() <= CAM.height - 0.5
    # exactly on the cone: unprojection is exact to ~1e-12 rad (camera tests), so 1e-9 rad
    ang = np.arccos(np.clip(unproject(CAM, uv) @ e, -1, 1))
    assert np.abs(ang - alpha).max() < 1e-9
    # ordered, 1 px apart: chords of a curve sampled at equal chord length on a polyline of
    # step/4 chords differ from 1 px by the curvature sagitta, far below 1 %
    s = np.linalg.norm(np.diff(uv, axis=0), axis=1)
    assert s.min() > 0.99 and s.max() < 1.01
    # total length agrees with a dense brute-force trace to within one sample (+ 0.1 %)
    L = _dense_visible_length(CAM, e, alpha)
    assert abs(s.sum() - L) < 1.0 + 1e-3 * L


def test_closed_limb_of_an_on_axis_disc():
    # Equidistant camera (r_d = theta): a disc of half-angle alpha on the optical axis images as a
    # circle of radius f alpha about the principal point; circumference 2 pi f alpha.
    cam = from_fov(1001, 801, 60.0)
    alpha = math.radians(4.0)
    arcs = predicted_limb_pixels(cam, np.array([0.0, 0, 1]), alpha, arcs="all")
    assert len(arcs) == 1
    uv = arcs[0]
    r = np.hypot(uv[:, 0] - cam.cx, uv[:, 1] - cam.cy)
    assert np.abs(r - cam.fx * alpha).max() < 1e-9 * cam.fx
    circ = 2 * math.pi * cam.fx * alpha
    assert abs(len(uv) - circ) <= 1.0  # one sample per px, closed curve
    # closed: last sample ~1 px from the first
    assert 0.5 <= np.linalg.norm(uv[-1] - uv[0]) <= 1.5


def test_mask_splits_and_hides():
    alpha = horizon_alpha(238e3, R_EARTH)
    e = _direction(80, 90)  # nadir "down" in the image: hyperbola across the full width
    full = predicted_limb_pixels(CAM, e, alpha, arcs="all")
    assert len(full) == 1
    mask = np.zeros((CAM.height, CAM.width), bool)
    mask[:, 1200:1400] = True  # a payload strut across the image
    arcs = predicted_limb_pixels(CAM, e, alpha, mask=mask, arcs="all")
    assert len(arcs) == 2
    for uv in arcs:
        iu = np.rint(uv[:, 0]).astype(int)
        assert not np.any((iu >= 1200) & (iu < 1400))
    longest = predicted_limb_pixels(CAM, e, alpha, mask=mask)
    assert len(longest) == max(len(a) for a in arcs)
    assert abs(len(longest) - _dense_visible_length(CAM, e, alpha, mask)) < 2.0
    # hidden completely
    mask[:] = True
    pred = predict_vision(CAM, e, alpha, mask=mask)
    assert pred.covariance is None and "mask" in pred.reason
    with pytest.raises(ValueError, match="mask"):
        predicted_limb_pixels(CAM, e, alpha, mask=np.zeros((10, 10), bool))


def test_none_with_reasons():
    alpha = horizon_alpha(238e3, R_EARTH)
    # nadir straight ahead at 20 deg: the limb (75 deg away) is outside a 94 deg FOV
    pred = predict_vision(CAM, _direction(20, 0), alpha)
    assert pred.covariance is None and "no part" in pred.reason
    assert predicted_covariance(CAM, _direction(20, 0), alpha) is None
    # a tiny Sun (0.267 deg, no bloom) is ~2 pi 5 px = 33 px around: below a 50 px minimum
    a = bloomed_alpha(math.radians(0.267), 1.0)
    pred = predict_vision(CAM, _direction(10, 0), a, *SUN_NOISE, method="free-alpha", min_pixels=50)
    assert pred.covariance is None and "minimum 50" in pred.reason and 25 < len(pred.pixels) < 45
    with pytest.raises(ValueError, match="alpha"):
        predict_vision(CAM, _direction(10, 0), 2.0)
    with pytest.raises(ValueError, match="method"):
        predict_vision(CAM, _direction(80, 0), alpha, method="magic")


def _ar1(rng, shape, rho):
    """Stationary unit-variance AR(1) along axis 1 (003 eq. (34): correlation rho^|j-k|)."""
    w = rng.standard_normal(shape)
    w[:, 1:] *= math.sqrt(1 - rho * rho)
    return lfilter([1.0], [1.0, -rho], w, axis=1)


@pytest.mark.parametrize("body", ["earth", "sun"])
def test_predicted_covariance_matches_estimator(body):
    # The prediction (eq. (33) via vision.covariance on the predicted arc) against the sample
    # covariance of the actual estimator on the same arc with correlated pixel noise (R, L of
    # 003 eqs. (36)/(38)). Bound: N = 400 trials -> relative standard error of a variance
    # sqrt(2/N) = 7 %; 4 sigma = 28 %, plus a few % linearisation -> 30 %.
    rng = np.random.default_rng(5)
    if body == "earth":
        e = _direction(75, 110)
        alpha = horizon_alpha(238e3, R_EARTH)
        (R, L), method = HORIZON_NOISE, "constrained"
    else:
        e = _direction(35, 20)
        alpha = bloomed_alpha(math.radians(0.267), 8.0)
        (R, L), method = SUN_NOISE, "free-alpha"
    pred = predict_vision(CAM, e, alpha, R, L, method=method)
    assert pred.covariance is not None, pred.reason
    uv = pred.pixels
    N = 400
    rho = 1 - 1 / L
    du = math.sqrt(R) * _ar1(rng, (N, len(uv)), rho)
    dv = math.sqrt(R) * _ar1(rng, (N, len(uv)), rho)
    errs = np.empty((N, 3))
    for i in range(N):  # one estimator call per trial (the thing being checked)
        rays = unproject(CAM, uv + np.stack([du[i], dv[i]], 1))
        fit = nadir_from_horizon(rays, alpha) if body == "earth" else direction_and_radius(rays)
        errs[i] = fit.e_c - e
    S = errs.T @ errs / N
    w, V = np.linalg.eigh(pred.covariance.P_c)
    for k in (1, 2):
        v = V[:, k]
        assert v @ S @ v == pytest.approx(w[k], rel=0.3), (body, k, v @ S @ v, w[k])
    assert pred.covariance.lambda_max == pytest.approx(w[2])
    print(f"\n{body}: {len(uv)} px, predicted sigma_max {math.degrees(math.sqrt(w[2])):.4f} deg, "
          f"sampled {math.degrees(math.sqrt(V[:, 2] @ S @ V[:, 2])):.4f} deg")


def test_linear_recurrence_against_loop():
    rng = np.random.default_rng(0)
    a = np.concatenate([[0.0], rng.uniform(0, 1, 999)])
    a[500] = 0.0
    b = rng.standard_normal((1000, 4, 3))
    ref = np.empty_like(b)
    prev = np.zeros((4, 3))
    for k in range(1000):  # reference loop
        prev = a[k] * prev + b[k]
        ref[k] = prev
    assert np.allclose(linear_recurrence(a, b), ref, rtol=1e-12, atol=1e-12)


def _random_tangent_cov(rng, e, s1, s2):
    T = np.linalg.svd(np.eye(3) - np.outer(e, e))[0][:, :2]
    Q = np.linalg.qr(rng.standard_normal((2, 2)))[0]
    M = T @ Q
    return M @ np.diag([s1 ** 2, s2 ** 2]) @ M.T


@pytest.mark.parametrize("fraction", [1.0, 0.3])
def test_drawn_errors_have_the_predicted_covariance(fraction):
    # Chi-square bound: Mahalanobis distances of N independent 2-D tangent errors sum to
    # chi^2(2N); mean 2N, sd 2 sqrt(N); accept |sum - 2N| < 4 sd. Normalising to unit length
    # changes errors of 1e-3 rad by ~1e-6 relative: negligible.
    rng = np.random.default_rng(2)
    K, runs = 5, 4000
    e = np.array([_direction(30 + 10 * k, 40 * k) for k in range(K)])
    P = np.array([_random_tangent_cov(rng, e[k], 2e-3, 0.5e-3) for k in range(K)])
    t = np.array([0.0, 0.2, 0.4, 5.0, 30.0])
    out = draw_vector_errors(e, P, t, rng, gm_fraction=fraction, runs=runs)
    assert out.e_meas.shape == (runs, K, 3) and out.P_report.shape == (K, 3, 3)
    assert np.allclose(np.linalg.norm(out.e_meas, axis=-1), 1.0)
    assert np.allclose(out.P_report, P)
    for k in range(K):
        d = out.e_meas[:, k] - e[k]
        Tb = np.linalg.svd(np.eye(3) - np.outer(e[k], e[k]))[0][:, :2]
        y = d @ Tb
        Pi = np.linalg.inv(Tb.T @ P[k] @ Tb)
        chi2 = float(np.einsum("ri,ij,rj->", y, Pi, y))
        assert abs(chi2 - 2 * runs) < 4 * 2 * math.sqrt(runs), (k, chi2)
        assert np.abs(d @ e[k]).max() < 1e-4  # tangent: radial part only second order


@pytest.mark.parametrize("transition", ["exact", "eq42"])
def test_gauss_markov_autocorrelation(transition):
    # Correlation between epoch 0 and epoch k over independent runs: for Gauss-Markov with
    # stationary start, rho_k = exp(-tau/T_c) ("exact") or (1 - dt/T_c)^k (003 eq. (42)).
    # Sample correlation over n = 3 x 20000 pairs has sd <= (1 - rho^2)/sqrt(n) <= 0.0041;
    # bound 0.02 (~5 sd).
    rng = np.random.default_rng(3)
    T_c, runs = 20.0, 20000
    t = np.concatenate([np.arange(0.0, 10.0, 1.0), np.arange(10.0, 70.0, 2.5)])  # irregular steps
    K = len(t)
    e = np.tile([0.0, 0.0, 1.0], (K, 1))
    sig = 1e-3
    out = draw_vector_errors(e, sig ** 2 * np.eye(3), t, rng, T_c=T_c, transition=transition,
                             runs=runs)
    z = out.zeta  # (runs, K, 3)
    var0 = np.mean(z[:, 0] ** 2)
    assert var0 == pytest.approx(sig ** 2, rel=0.03)  # 3 x 20000 samples: rel sd 0.6 %
    for k in (1, 5, 10, 14, 20, K - 1):
        r = float(np.mean(z[:, 0] * z[:, k]) / np.sqrt(var0 * np.mean(z[:, k] ** 2)))
        if transition == "exact":
            expect = math.exp(-(t[k] - t[0]) / T_c)
        else:
            expect = float(np.prod(1 - np.diff(t[:k + 1]) / T_c))
        assert abs(r - expect) < 0.02, (k, r, expect)
    assert np.all(out.white == 0.0)


def test_gm_fraction_splits_correlation():
    # With a fraction f in the Gauss-Markov part, lag-k correlation of the total error is
    # f exp(-tau/T_c) and the lag-0 variance is still P. Same sampling bound as above.
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 41.0, 1.0)
    e = np.tile([0.0, 0.0, 1.0], (len(t), 1))
    f = 0.6
    out = draw_vector_errors(e, np.eye(3) * 1e-6, t, rng, gm_fraction=f, runs=20000)
    err = out.zeta + out.white
    for k in (1, 10, 40):
        r = float(np.mean(err[:, 0] * err[:, k]) / np.sqrt(np.mean(err[:, 0] ** 2) * np.mean(err[:, k] ** 2)))
        assert abs(r - f * math.exp(-t[k] / 20.0)) < 0.02


def test_draw_bad_input():
    rng = np.random.default_rng(0)
    e = np.tile([0.0, 0, 1], (3, 1))
    with pytest.raises(ValueError, match="t_s"):
        draw_vector_errors(e, np.eye(3), [0, 2, 1], rng)
    with pytest.raises(ValueError, match="dt < T_c"):
        draw_vector_errors(e, np.eye(3), [0, 30, 31], rng, transition="eq42")
    with pytest.raises(ValueError, match="gm_fraction"):
        draw_vector_errors(e, np.eye(3), [0, 1, 2], rng, gm_fraction=1.5)
    with pytest.raises(ValueError, match="P"):
        draw_vector_errors(e, np.eye(2), [0, 1, 2], rng)


def test_psd_sqrt():
    rng = np.random.default_rng(1)
    A = rng.standard_normal((4, 3, 2))
    P = A @ np.swapaxes(A, -1, -2)  # rank 2
    S = psd_sqrt(P)
    assert np.allclose(S @ S, P, atol=1e-12) and np.allclose(S, np.swapaxes(S, -1, -2))
