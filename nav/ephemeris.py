"""Earth orientation and the Sun and Moon in the Earth-fixed frame e.

Built on ERFA (``pyerfa``: the SOFA routines astropy uses), not on a hand-written series:

* celestial (GCRS) -> terrestrial rotation: IAU 2000B precession-nutation (1 mas agreement with
  2000A, far inside the 0.001 deg asked for) and the Earth rotation angle, ``erfa.c2t00b``; polar
  motion is ignored (< 0.5 arcsec, docs/conventions.md "Frames"); UT1 - UTC defaults to 0 (the Earth
  rotation angle is then off by up to 0.9 s of rotation, about 0.004 deg) and can be passed;
* Sun: Earth's heliocentric and barycentric position and velocity from ``erfa.epv00`` (VSOP2000
  fit, a few km); the geocentric apparent direction includes annual aberration (about 20 arcsec,
  ``erfa.ab``) because that is what a camera on the vehicle sees; the Sun's light-time motion
  (< 0.01 arcsec) is neglected;
* Moon: ``erfa.moon98`` (Meeus' ELP truncation, about 10 arcsec in longitude), geocentric GCRS.

003 eq. (39) needs ``X_e``, the Sun position in e; directions from a point on or above the Earth
take the parallax into account (:func:`sun_direction_e`, :func:`moon_direction_e`), which is about
1 deg for the Moon seen from 250 km above Esrange and 0.0016 deg for the Sun.
"""
from __future__ import annotations

import erfa
import numpy as np

from nav.checks import as_finite, as_vectors, unit
from nav.timescales import NS_PER_S, as_time_ns, ns_to_jd, utc_to_tt_ns

#: Astronomical unit [m] (IAU 2012).
AU = 149_597_870_700.0
#: Speed of light [m/s].
C_LIGHT = 299_792_458.0


def _times(utc_ns, dut1_s, beyond_table):
    t = as_time_ns(utc_ns, "utc_ns")
    tt = utc_to_tt_ns(t, beyond_table=beyond_table)
    dut1 = as_finite(dut1_s, "dut1_s")
    if np.any(np.abs(dut1) > 0.9):
        raise ValueError("dut1_s: UT1 - UTC is kept within 0.9 s by the IERS; got a larger value")
    ut1 = t + np.round(dut1 * NS_PER_S).astype(np.int64)
    return ns_to_jd(tt), ns_to_jd(ut1)


def c2e_matrix(utc_ns, *, dut1_s=0.0, beyond_table: str = "raise") -> np.ndarray:
    """Rotation ``R_ei`` from the celestial frame i (GCRS) into e (ITRS without polar motion).

    Parameters
    ----------
    utc_ns : int or int array
        UTC, ns since the Unix epoch.
    dut1_s : float
        UT1 - UTC [s] (IERS Bulletin A); 0 if unknown.
    beyond_table : {"raise", "hold"}
        What to do after the leap-second table (see :mod:`nav.timescales`).
    """
    (tt1, tt2), (ut1, ut2) = _times(utc_ns, dut1_s, beyond_table)
    return erfa.c2t00b(tt1, tt2, ut1, ut2, 0.0, 0.0)


#: Many epochs (a camera's frames): the Sun is evaluated at nodes this far apart in TT and
#: interpolated linearly (:func:`sun_position_i`).
SUN_NODE_STEP_S = 60.0


def sun_position_i(utc_ns, *, beyond_table: str = "raise") -> np.ndarray:
    """Apparent geocentric Sun position in GCRS [m], with annual aberration applied.

    ``erfa.epv00`` is costly per epoch (tens of microseconds), so when there are more than twice
    as many epochs as :data:`SUN_NODE_STEP_S` nodes over their span, the position is evaluated at
    the nodes (in TT, so a leap second inside the span is no jump) and interpolated linearly: the
    error is at most ``|p''| h^2 / 8`` = 5.9e-3 m/s^2 (the Sun's geocentric acceleration) x
    (60 s)^2 / 8 = 2.7 m, 1.8e-11 rad of direction (tests/test_ephemeris.py)."""
    t = as_time_ns(utc_ns, "utc_ns")
    tt = np.asarray(utc_to_tt_ns(t, beyond_table=beyond_table), np.int64)
    flat = tt.reshape(-1)
    if flat.size > 2:
        t0 = int(flat.min())
        span = int(flat.max()) - t0
        n = int(span // int(SUN_NODE_STEP_S * NS_PER_S)) + 2
        if flat.size > 2 * n:
            nodes = t0 + np.round(np.linspace(0.0, span, n)).astype(np.int64)
            p = _sun_apparent_i(nodes)
            x, xp = (flat - t0).astype(np.float64), (nodes - t0).astype(np.float64)
            out = np.stack([np.interp(x, xp, p[:, i]) for i in range(3)], axis=-1)
            return out.reshape(tt.shape + (3,))
    return _sun_apparent_i(tt)


def _sun_apparent_i(tt_ns) -> np.ndarray:
    """:func:`sun_position_i` at TT epochs [ns], evaluated at each one."""
    tt1, tt2 = ns_to_jd(tt_ns)
    # TDB - TT < 2 ms: the Sun moves 2e-8 deg in that time, so TT stands in for TDB.
    pvh, pvb = erfa.epv00(tt1, tt2)
    p_sun = -pvh["p"]  # Earth -> Sun, au
    dist = np.linalg.norm(p_sun, axis=-1)
    v = pvb["v"] * (AU / 86400.0) / C_LIGHT  # Earth's barycentric velocity in units of c
    bm1 = np.sqrt(1.0 - np.sum(v * v, axis=-1))
    direction = erfa.ab(p_sun / dist[..., None], v, dist, bm1)
    return direction * (dist * AU)[..., None]


def moon_position_i(utc_ns, *, beyond_table: str = "raise") -> np.ndarray:
    """Geocentric Moon position in GCRS [m] (``erfa.moon98``, geometric)."""
    t = as_time_ns(utc_ns, "utc_ns")
    tt1, tt2 = ns_to_jd(utc_to_tt_ns(t, beyond_table=beyond_table))
    return erfa.moon98(tt1, tt2)["p"] * AU


def sun_position_e(utc_ns, *, dut1_s=0.0, beyond_table: str = "raise") -> np.ndarray:
    """Apparent geocentric Sun position ``X_e`` in e [m] (003 eq. (39))."""
    R = c2e_matrix(utc_ns, dut1_s=dut1_s, beyond_table=beyond_table)
    return np.einsum("...ij,...j->...i", R, sun_position_i(utc_ns, beyond_table=beyond_table))


def moon_position_e(utc_ns, *, dut1_s=0.0, beyond_table: str = "raise") -> np.ndarray:
    """Geocentric Moon position in e [m]."""
    R = c2e_matrix(utc_ns, dut1_s=dut1_s, beyond_table=beyond_table)
    return np.einsum("...ij,...j->...i", R, moon_position_i(utc_ns, beyond_table=beyond_table))


def _direction_from(target_e, x_e) -> np.ndarray:
    x = as_vectors(x_e, "x_e")
    return unit(target_e - x, "direction")


def sun_direction_e(utc_ns, x_e, *, dut1_s=0.0, beyond_table: str = "raise") -> np.ndarray:
    """Unit vector from the ECEF point ``x_e`` to the Sun, in e (003 eq. (39), second line)."""
    return _direction_from(sun_position_e(utc_ns, dut1_s=dut1_s, beyond_table=beyond_table), x_e)


def moon_direction_e(utc_ns, x_e, *, dut1_s=0.0, beyond_table: str = "raise") -> np.ndarray:
    """Unit vector from the ECEF point ``x_e`` to the Moon, in e (topocentric: parallax included;
    the diurnal aberration of the observer's 0.5 km/s, < 0.0002 deg, is neglected)."""
    return _direction_from(moon_position_e(utc_ns, dut1_s=dut1_s, beyond_table=beyond_table), x_e)


#: Mean radii [m] for apparent angular sizes.
SUN_RADIUS = 695_700_000.0
MOON_RADIUS = 1_737_400.0


def apparent_radius(target_e, x_e, radius: float) -> np.ndarray:
    """Apparent angular radius [rad] of a sphere of ``radius`` at ``target_e`` seen from ``x_e``
    (the cone half-angle alpha of 003 eq. (5) for that body)."""
    d = np.linalg.norm(as_vectors(target_e, "target_e") - as_vectors(x_e, "x_e"), axis=-1)
    return np.arcsin(np.clip(radius / d, -1.0, 1.0))
