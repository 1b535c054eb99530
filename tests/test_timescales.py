"""Time scales against astropy (independent implementation of the same IERS table) and identities."""

import numpy as np
import pytest

from nav import timescales as T


def test_parse_format_round_trip():
    t = T.parse_utc("2019-06-13T02:21:00.123456789Z")
    assert t == 1560392460_123456789
    assert T.format_utc(t, digits=9) == "2019-06-13T02:21:00.123456789Z"
    assert T.parse_utc("2019-06-13T04:21:00+02:00") == T.parse_utc("2019-06-13T02:21:00Z")


@pytest.mark.parametrize("text,expected", [
    ("1980-01-06T00:00:00Z", 19), ("2017-01-01T00:00:00Z", 37), ("2016-12-31T23:59:59Z", 36),
    ("1972-01-01T00:00:00Z", 10), ("2026-12-31T23:59:59Z", 37)])
def test_tai_minus_utc_table(text, expected):
    assert int(T.tai_minus_utc_s(T.parse_utc(text))) == expected


def test_against_astropy(astropy_offline):
    from astropy.time import Time

    rng = np.random.default_rng(1)
    t = rng.integers(T.parse_utc("1972-01-02T00:00:00Z"), T.parse_utc("2026-12-30T00:00:00Z"), 500)
    a = Time(t // T.NS_PER_S, format="unix", scale="utc")
    # astropy's TAI-UTC (from its own bundled leap-second table) must equal ours to the second.
    ours = T.tai_minus_utc_s(t // T.NS_PER_S * T.NS_PER_S)
    theirs = np.round((a.tai.mjd - a.utc.mjd) * 86400.0)
    np.testing.assert_array_equal(ours, theirs)
    # GPS seconds since 1980-01-06: astropy's "gps" format counts TAI - 19 s.
    gps = T.utc_to_gps_ns(t // T.NS_PER_S * T.NS_PER_S) / 1e9
    np.testing.assert_allclose(gps, a.gps, atol=1e-6)


def test_round_trips_and_offsets():
    t = np.array([T.parse_utc("2019-06-13T02:21:00Z"), T.parse_utc("1999-01-01T00:00:00Z")])
    np.testing.assert_array_equal(T.tai_to_utc_ns(T.utc_to_tai_ns(t)), t)
    np.testing.assert_array_equal(T.tt_to_utc_ns(T.utc_to_tt_ns(t)), t)
    np.testing.assert_array_equal(T.gps_to_utc_ns(T.utc_to_gps_ns(t)), t)
    assert T.utc_to_tt_ns(t[0]) - t[0] == (37 * T.NS_PER_S + 32_184_000_000)
    # GPS week 2057, 2019-06-13 is Thursday: 4 days + 02:21:18 (18 s GPS-UTC) into the week.
    w, s = 2057, 4 * 86400 + 2 * 3600 + 21 * 60 + 18.0
    assert int(T.gps_week_seconds_to_utc_ns(w, s)) == t[0]


def test_leap_second_instant_maps_to_midnight():
    # 2016-12-31T23:59:60 UTC = TAI 2017-01-01T00:00:36; Unix time cannot name it.
    leap_tai = T.utc_to_tai_ns(T.parse_utc("2017-01-01T00:00:00Z")) - T.NS_PER_S // 2
    assert int(T.tai_to_utc_ns(leap_tai)) == T.parse_utc("2017-01-01T00:00:00Z")


def test_bad_input_names_argument():
    with pytest.raises(ValueError, match="utc_ns.*before 1972"):
        T.utc_to_tai_ns(T.parse_utc("1971-06-01T00:00:00Z"))
    with pytest.raises(ValueError, match="utc_ns.*after the leap-second table"):
        T.utc_to_tai_ns(T.parse_utc("2031-06-01T00:00:00Z"))
    assert T.utc_to_tai_ns(T.parse_utc("2031-06-01T00:00:00Z"), beyond_table="hold") > 0
    with pytest.raises(ValueError, match="utc_ns.*NaN"):
        T.utc_to_tai_ns(np.array([np.nan]))
    with pytest.raises(ValueError, match="ISO-8601"):
        T.parse_utc("13/06/2019")
    with pytest.raises(ValueError, match="seconds"):
        T.gps_week_seconds_to_utc_ns(2057, 700000.0)
