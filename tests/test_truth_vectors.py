"""Truth vectors (scenarios/sim/truth_vectors.py): covariance from the vision error model, errors
distributed as that covariance, log round trip."""
import math

import numpy as np
import pytest

from scenarios.sim.truth_vectors import camera_truth_vectors
from vision.camera import atek_camera
from vision.error_model import predict_vision

NS = 1_000_000_000


def _geometry(n):
    """A horizon in the lower half of the atek image: nadir 40 deg below the optical axis."""
    e = np.array([0.0, math.sin(math.radians(60)), math.cos(math.radians(60))])
    return np.tile(e, (n, 1)), np.full(n, math.asin(6371e3 / 6601e3))


def test_covariance_is_the_error_model_and_errors_match_it():
    """Frames 200 s apart (10 T_c: independent draws): the reported P_c equals predict_vision's and
    the mean NEES of the errors in the tangent plane is 2 within its 99.9 % band (chi2 with 2n dof)."""
    from scipy.stats import chi2
    cam = atek_camera()
    n = 400
    e, alpha = _geometry(n)
    t = np.arange(n, dtype=np.int64) * 200 * NS
    tv = camera_truth_vectors(cam, 1, t, e, e, alpha, np.ones(n, bool), np.zeros(n, bool), 1.5e11, seed=3)
    assert len(tv) == n and set(tv.target) == {"earth"}
    P = predict_vision(cam, e[0], alpha[0]).covariance.P_c
    np.testing.assert_allclose(tv.P_c[0], P, rtol=1e-12)
    d = tv.e_c - tv.e_true
    Pi = np.linalg.pinv(P, rcond=1e-9)
    nees = np.einsum("ki,ij,kj->k", d, Pi, d)
    lo, hi = chi2.ppf([0.0005, 0.9995], 2 * n) / n
    assert lo < nees.mean() < hi
    nav = tv.vector_data()
    assert set(nav.target) == {"hor"} and set(nav.camera) == {0}


def test_time_correlation():
    """1 s apart: successive errors correlate with exp(-1/20) (003 §6.3); 5 % tolerance for 2000 samples."""
    cam = atek_camera()
    n = 2000
    e, alpha = _geometry(n)
    t = np.arange(n, dtype=np.int64) * NS
    tv = camera_truth_vectors(cam, 2, t, e, e, alpha, np.ones(n, bool), np.zeros(n, bool), 1.5e11, seed=5)
    d = tv.e_c - tv.e_true
    u = d @ np.linalg.svd(d, full_matrices=False)[2][0]
    r = np.corrcoef(u[:-1], u[1:])[0, 1]
    assert r == pytest.approx(math.exp(-1 / 20), abs=0.05)


def test_short_arc_gives_no_vector_and_is_counted():
    """A horizon outside the image gives no vector; the reason is counted."""
    cam = atek_camera()
    e = np.array([[0.0, 0.0, -1.0]])  # Earth behind the camera
    tv = camera_truth_vectors(cam, 1, np.array([0]), e, e, np.array([0.3]), np.array([True]), np.array([False]), 1.5e11)
    assert len(tv) == 0 and sum(tv.skipped.values()) == 1
