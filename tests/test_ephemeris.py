"""Sun and Moon in e against astropy (bundled, offline Earth-orientation data; ITRS frame).

We use UT1 = UTC (dut1_s = 0) against astropy's IERS-based UT1: the Earth rotation angle then
differs by |UT1 - UTC| < 0.9 s, i.e. up to 0.0038 deg of rotation about the pole; that is why the
Sun bound is 0.005 deg. The Moon model (erfa.moon98, Meeus) is good to about 10 arcsec; bound 0.05 deg.
"""
import numpy as np
import pytest

from nav import earth, ephemeris as E, timescales as T


def _random_epochs(n=240, seed=3):
    rng = np.random.default_rng(seed)
    lo, hi = T.parse_utc("1990-01-01T00:00:00Z"), T.parse_utc("2050-01-01T00:00:00Z")
    return np.sort(rng.integers(lo, hi, n)) // T.NS_PER_S * T.NS_PER_S


def _angle_deg(a, b):
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def _astropy_itrs(body, t_ns, location=None):
    import astropy.units as u
    from astropy.coordinates import ITRS, get_body, get_sun
    from astropy.time import Time

    at = Time(t_ns / 1e9, format="unix", scale="utc")
    c = get_sun(at) if body == "sun" else get_body(body, at)
    frame = ITRS(obstime=at) if location is None else ITRS(obstime=at, location=location)
    return np.asarray(c.transform_to(frame).cartesian.xyz.to(u.m).value).T


def test_sun_direction_against_astropy(astropy_offline):
    t = _random_epochs()
    ours = E.sun_position_e(t, beyond_table="hold")
    ref = _astropy_itrs("sun", t)
    err = _angle_deg(ours, ref)
    print(f"Sun, {t.size} epochs 1990-2050, UT1=UTC: worst {err.max():.5f} deg at "
          f"{T.format_utc(t[np.argmax(err)])}, RMS {np.sqrt(np.mean(err**2)):.5f} deg")
    assert err.max() <= 0.005
    # distance: VSOP-fit Earth orbit, 1e-7 relative
    np.testing.assert_allclose(np.linalg.norm(ours, axis=-1), np.linalg.norm(ref, axis=-1), rtol=1e-6)


def test_moon_direction_against_astropy(astropy_offline):
    t = _random_epochs(seed=4)
    err = _angle_deg(E.moon_position_e(t, beyond_table="hold"), _astropy_itrs("moon", t))
    print(f"Moon geocentric, {t.size} epochs: worst {err.max():.5f} deg, RMS {np.sqrt(np.mean(err**2)):.5f} deg")
    assert err.max() <= 0.05


def test_topocentric_moon_from_250km_above_esrange(astropy_offline):
    import astropy.units as u
    from astropy.coordinates import EarthLocation

    lat, lon, h = np.deg2rad(67.89), np.deg2rad(21.10), 250e3
    x = earth.geodetic_to_ecef(lat, lon, h)
    loc = EarthLocation.from_geocentric(*x, unit=u.m)
    t = _random_epochs(n=40, seed=5)
    t = t[t < T.LEAP_TABLE_EXPIRES]
    ours = E.moon_direction_e(t, x)
    ref = _astropy_itrs("moon", t, location=loc)  # topocentric ITRS: vector from loc
    err = _angle_deg(ours, ref)
    parallax = _angle_deg(ours, E.moon_position_e(t))
    print(f"Moon from 250 km above Esrange: parallax {parallax.min():.2f}-{parallax.max():.2f} deg, "
          f"worst error {err.max():.5f} deg")
    assert parallax.max() > 0.5  # the test really exercises the parallax
    assert err.max() <= 0.05


def test_sun_direction_from_a_point_includes_parallax():
    t = T.parse_utc("2019-06-13T02:21:00Z")
    x = earth.geodetic_to_ecef(np.deg2rad(67.89), np.deg2rad(21.1), 238e3)
    d = E.sun_direction_e(t, x)
    X = E.sun_position_e(t)
    np.testing.assert_allclose(np.linalg.norm(d), 1.0, rtol=1e-15)
    # law of sines in the triangle Earth centre - point - Sun: sin(parallax) = |x X| / (|X| |X - x|)
    expected = np.degrees(np.arcsin(np.linalg.norm(np.cross(x, X)) / (np.linalg.norm(X) * np.linalg.norm(X - x))))
    assert abs(_angle_deg(d, X) - expected) < 1e-10


def test_c2e_is_rotation_and_earth_rotates():
    t = np.array([T.parse_utc("2019-06-13T02:21:00Z")]) + np.array([0, 3600 * T.NS_PER_S])
    R = E.c2e_matrix(t)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), (2, 3, 3)), atol=1e-14)
    # One hour apart the frames differ by ~ omega_E * 3600 s about the pole (precession negligible).
    dR = R[1] @ R[0].T
    angle = np.arccos((np.trace(dR) - 1) / 2)
    assert abs(angle - earth.OMEGA_E * 3600) < 1e-6


def test_bad_input():
    with pytest.raises(ValueError, match="utc_ns"):
        E.sun_position_e(np.array([1.5e18, np.nan]))
    with pytest.raises(ValueError, match="before 1972"):
        E.sun_position_e(0)
    with pytest.raises(ValueError, match="x_e.*shape"):
        E.sun_direction_e(T.parse_utc("2019-06-13T02:21:00Z"), np.zeros(2))


def test_sun_interpolated_between_nodes_for_many_epochs():
    """Dense epochs (a 30 frames/s camera over 10 min, and the same across the leap second at the
    end of 2016) go through nodes 60 s apart in TT and linear interpolation: against the series at
    every epoch the error stays within the bound |p''| h^2 / 8 = 2.7 m (5.9e-3 m/s^2, h = 60 s),
    asserted <= 5 m (1.8e-11 rad at 1 au is far below the 0.005 deg of the Sun tests)."""
    for start in ("2019-06-13T02:21:00Z", "2016-12-31T23:55:00Z"):
        t = T.parse_utc(start) + np.arange(18000) * (T.NS_PER_S // 30)
        assert t.size > 2 * (int(600 // E.SUN_NODE_STEP_S) + 2)          # the interpolated path
        got = E.sun_position_i(t)
        ref = E._sun_apparent_i(T.utc_to_tt_ns(t))                       # every epoch
        err = np.linalg.norm(got - ref, axis=-1)
        print(f"{start}: worst {err.max():.3f} m over {t.size} epochs")
        assert err.max() <= 5.0 and err[0] < 1e-3 and err[-1] < 1e-3     # the end nodes are exact
    # no more epochs than twice the nodes: evaluated directly (the same numbers)
    t = T.parse_utc("2019-06-13T02:21:00Z") + np.arange(9) * 30 * T.NS_PER_S   # 9 epochs, 6 nodes
    np.testing.assert_array_equal(E.sun_position_i(t), E._sun_apparent_i(T.utc_to_tt_ns(t)))
