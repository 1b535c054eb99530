"""vision.limb_offset: the per-camera limb edge height offset and the re-weighted limb-edge fits."""
import math

import numpy as np
import pytest

from vision.config import EdgeHeightOptions
from vision.limb_offset import LimbEdge, apply_limb_offset, estimate_limb_offset, refine_limb_height
from vision.results import VectorRecord

E0 = np.array([0.0, 0.0, 1.0])
A = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])   # tangent basis at E0


def _posterior(L_d, b_d, m, s):
    """Linear-Gaussian posterior of x = (tangent offsets [rad], height [m]) with data information
    L_d, b_d and the height prior N(m, s^2): (x, C)."""
    L = L_d + np.diag([0.0, 0.0, 1.0 / s**2])
    C = np.linalg.inv(L)
    return C @ (b_d + np.array([0.0, 0.0, m / s**2])), C


def _record(x, C, camera=1):
    e = E0 + A @ x[:2]
    e /= np.linalg.norm(e)
    P = A @ C[:2, :2] @ A.T
    return VectorRecord(0, camera, "earth", e, P, np.eye(3) * np.linalg.eigvalsh(P)[-1], 0.0, 100, 100, "ellipse",
                        0.3, "ellipsoid", float(x[2]), math.sqrt(C[2, 2]))


def _problem(seed=1):
    """A direction-and-height fit whose arc constrains the height to ~10 km and ties the tangent
    offsets to it (the tilt of a partial arc), truth h = 18 km."""
    rng = np.random.default_rng(seed)
    # tangent columns ~1.4e7 per rad (1-sigma ~1e-4 rad), the first one sharing the height
    # column's mean (a partial arc: tilt and height trade off)
    H = np.column_stack([(rng.normal(size=40) + 0.8) * 1.4e7, rng.normal(size=40) * 1.4e7,
                         rng.normal(size=40) * 0.5 + 1.0])
    r = 1e4**2 * 40 / np.sum(H[:, 2] ** 2)       # height sigma ~10 km from the data alone
    x_true = np.array([2e-4, -1e-4, 18e3])
    z = H @ x_true + rng.normal(size=40) * math.sqrt(r)
    return H.T @ H / r, H.T @ z / r


def test_reweighting_equals_the_fit_with_the_tight_prior():
    """Replacing the wide prior N(18.3 km, 20 km) by N(18.3 km, hypot(sigma_b, sigma_l)) on the
    stored fit gives the posterior a fit with the tight prior gives (exact in the linear
    Gaussian problem: height and its sigma to rounding; the direction to second order in the
    tangent offsets ~1e-4 rad, hence 1e-6 rad; the covariance to 1e-3 of its largest entry: the
    projection on the moved vector's tangent plane changes entries by |P| |e - E0| ~ 1e-4 |P|)."""
    L_d, b_d = _problem()
    x1, C1 = _posterior(L_d, b_d, 18.3e3, 20e3)
    off = estimate_limb_offset([], 1, EdgeHeightOptions())   # not learned: nothing applied
    assert not off.applied and off.frames == 0
    from vision.limb_offset import LimbOffset
    off = LimbOffset(1, -500.0, 600.0, 40, 0.1, True)
    ed = LimbEdge(18.3e3, 20e3, 300.0, math.nan, math.inf, A @ C1[:2, 2])
    rec2 = apply_limb_offset(_record(x1, C1), ed, off)
    x2, C2 = _posterior(L_d, b_d, 18.3e3, math.hypot(600.0, 300.0))
    ref = _record(x2, C2)
    assert rec2.edge_height_m == pytest.approx(x2[2], abs=1e-6)
    assert rec2.edge_height_sigma_m == pytest.approx(math.sqrt(C2[2, 2]), rel=1e-9)
    assert np.linalg.norm(rec2.e_c - ref.e_c) < 1e-6
    assert abs(np.linalg.norm(rec2.e_c) - 1.0) < 1e-12
    assert np.allclose(rec2.P_c, ref.P_c, rtol=0, atol=1e-3 * np.abs(ref.P_c).max())
    # the tight prior moved the height and the direction (the test is not vacuous)
    assert abs(x2[2] - x1[2]) > 100.0 and np.linalg.norm(rec2.e_c - _record(x1, C1).e_c) > 1e-5


def test_not_tighter_or_other_camera_leaves_the_record():
    L_d, b_d = _problem()
    x1, C1 = _posterior(L_d, b_d, 18.3e3, 20e3)
    from vision.limb_offset import LimbOffset
    rec = _record(x1, C1)
    ed = LimbEdge(18.3e3, 20e3, 300.0, 17e3, 1e4, A @ C1[:2, 2])
    assert apply_limb_offset(rec, ed, LimbOffset(1, 0.0, 30e3, 40, 0.1, True)) is rec   # wider than the prior
    assert apply_limb_offset(rec, ed, LimbOffset(2, 0.0, 600.0, 40, 0.1, True)) is rec
    assert apply_limb_offset(rec, None, LimbOffset(1, 0.0, 600.0, 40, 0.1, True)) is rec
    assert apply_limb_offset(rec, ed, LimbOffset(1, 0.0, 600.0, 40, 0.1, False)) is rec


@pytest.mark.parametrize("bias_m, n, applied", [(0.0, 150, True), (-15e3, 150, False), (13e3, 150, False),
                                                (0.0, 40, False), (-12e3, 6, False)])
def test_offset_is_the_weighted_mean_and_gates_a_mismatched_limb(bias_m, n, applied):
    """The offset is the inverse-variance mean of (arc's own height - prior mean) (closed form,
    np.average) with sigma 1/sqrt(sum w) (scatter below the sigmas); 150 frames of 10 km arcs give
    sigma ~0.8 km: a 13-15 km offset (the mismatched renders) is > 3 sigma away from 0, a matched
    limb (offset 0, drawn scatter 0.5 km: chi2/dof << 1 as on rendered frames) is inside. With 40
    frames (sigma ~1.6 km, 3 sigma 4.8 km > offset_resolution_m) or 6 (a -12 km offset within 3
    sigma of 0) the flight cannot vouch for the model: nothing is applied."""
    rng = np.random.default_rng(3)
    s = rng.uniform(9e3, 11e3, n)
    d = bias_m + rng.normal(size=n) * 500.0
    fits = [(_record(np.array([0.0, 0.0, 18.3e3 + di]), np.eye(3)), LimbEdge(18.3e3, 20e3, 300.0, 18.3e3 + di, si,
             np.zeros(3))) for di, si in zip(d, s)]
    fits.append((_record(np.zeros(3), np.eye(3), camera=2), None))
    _, offs = refine_limb_height(fits, EdgeHeightOptions())
    assert [o.camera for o in offs] == [1, 2]
    o = offs[0]
    assert o.offset_m == pytest.approx(np.average(d, weights=1 / s**2), rel=1e-12)
    assert o.sigma_m == pytest.approx(1 / math.sqrt(np.sum(1 / s**2)), rel=1e-12)
    assert o.frames == n and o.applied is applied
    assert offs[1].frames == 0 and not offs[1].applied and math.isnan(offs[1].offset_m)
    assert ("applied" if applied else "not applied") in o.describe()
