"""GPS interpolation of the initialisation (nav/initialise.py) against scipy's CubicHermiteSpline."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicHermiteSpline

from nav.initialise import gps_interpolator, hermite
from nav.navigator import GpsData

NS = 1_000_000_000


def _gps(n=60, seed=3):
    """Fixes of a curved ECEF-scale track at uneven intervals (0.1-1.3 s)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.1, 1.3, n))
    x = np.stack([6.4e6 + 1e3 * t ** 1.5, 2e5 * np.sin(0.05 * t), 7e4 * np.cos(0.03 * t)], -1)
    v = np.stack([1.5e3 * t ** 0.5, 1e4 * np.cos(0.05 * t), -2.1e3 * np.sin(0.03 * t)], -1)
    v += rng.normal(0, 5.0, v.shape)     # slopes not the track's exact derivative: a Hermite test
    t_ns = (1_700_000_000 * NS + np.round(t * NS)).astype(np.int64)
    return GpsData(t_ns, x, np.tile(np.eye(3), (n, 1, 1)), v, np.tile(np.eye(3), (n, 1, 1)))


def test_hermite_equals_scipy():
    """Values and derivatives at the knots, between them and at the ends equal scipy's spline to
    1e-9 relative (the float64 rounding of two evaluation orders at 6.4e6 m is ~1e-9 m)."""
    g = _gps()
    t = (g.t_ns - g.t_ns[0]) / NS
    tt = np.concatenate([t, np.random.default_rng(1).uniform(t[0], t[-1], 2000), [t[0], t[-1]]])
    spl = CubicHermiteSpline(t, g.x_e, g.v_e, axis=0)
    val, der = hermite(t, g.x_e, g.v_e, tt)
    np.testing.assert_allclose(val, spl(tt), rtol=0, atol=1e-9 * np.abs(g.x_e).max())
    np.testing.assert_allclose(der, spl(tt, 1), rtol=0, atol=1e-9 * np.abs(g.v_e).max())
    # at the knots the curve passes through the fixes with their velocities
    val, der = hermite(t, g.x_e, g.v_e, t)
    np.testing.assert_allclose(val, g.x_e, rtol=0, atol=1e-8)
    np.testing.assert_allclose(der, g.v_e, rtol=0, atol=1e-8)


def test_gps_interpolator_scalar_vector_and_bounds():
    g = _gps()
    at = gps_interpolator(g)
    t_mid = int(g.t_ns[10] + (g.t_ns[11] - g.t_ns[10]) // 3)
    x, v = at(t_mid)
    assert x.shape == (3,) and v.shape == (3,)
    xs, vs = at(np.array([t_mid, g.t_ns[-1]]))
    assert xs.shape == (2, 3)
    np.testing.assert_array_equal(xs[0], x)
    np.testing.assert_allclose(xs[1], g.x_e[-1], rtol=0, atol=1e-8)
    with pytest.raises(ValueError, match="outside the GPS record"):
        at(g.t_ns[-1] + 1)
    bad = GpsData(g.t_ns[::-1].copy(), g.x_e, g.P_x, g.v_e, g.P_v)
    with pytest.raises(ValueError, match="increasing times"):
        gps_interpolator(bad)
