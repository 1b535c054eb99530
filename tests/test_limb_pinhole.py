"""The limb edge on a narrow pinhole camera in orbit (scenarios/library/pinhole-orbit.toml: a 25 deg
pinhole, 1280x960, 0.02 deg per pixel, at 500 km with the Sun ~75 deg above the limb's tangent
points): the fraction-of-peak crossing must not be taken from a maximum on the Earth's disc.

With the Sun that high the limb's own maximum is a flat top a few km above the surface (eq. (4)
of `vision.limb`), and the sunlit clouds just beyond the horizon are brighter: the detector's
maximum is then a cloud, the crossing of half of it lies 3-18 km low, on one part of the arc only,
and the refit on that part turns the nadir by 1.2-1.4 deg (measured on the scenario's frames). The
flank width test (`vision.limb_refit._flank_width_ok`) rejects those profiles."""
from __future__ import annotations

import math

import numpy as np
import pytest

from vision.limb import flank_rise_height, sun_path_ratio


def _crossing_u(c: float, level: float) -> float:
    """u on the small-u side of the maximum of ``g(u) = (1 - e^-u) e^(-c u)`` where g = level x
    max g (bisection in u on [1e-9, u*])."""
    us = math.log((1.0 + c) / c)
    gmax = -math.expm1(-us) * math.exp(-c * us)
    lo, hi = 1e-9, us
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if -math.expm1(-mid) * math.exp(-c * mid) > level * gmax:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("el_deg", [90.0, 45.0, 20.0, 8.0, 2.0, 0.0])
def test_flank_rise_height_closed_form(el_deg):
    """``H ln(u_0.8 / u_0.5)`` from a direct bisection on eq. (4) with c = `sun_path_ratio`;
    tolerance 5 m: the table's linear interpolation over its ln c step of 0.025."""
    mu = math.sin(math.radians(el_deg))
    c = float(sun_path_ratio(np.array([mu]))[0])
    want = 8000.0 * math.log(_crossing_u(c, 0.8) / _crossing_u(c, 0.5))
    got = float(flank_rise_height(np.array([mu]), 0.5, 0.8, 8000.0)[0])
    assert abs(got - want) < 5.0, (got, want)


def test_surface_ratio_closed_form():
    """`vision.limb.surface_ratio` with the Sun overhead against eq. (4) in closed form: u at the
    surface ``A = u_0.5(c) exp(h_f / H)`` (the overhead crossing at h_f = 18.3 km), the maximum
    at ``u* = ln((1 + c)/c)``, ratio ``g(A) / g(u*)``; tolerance 1e-4, the 50 m grid of the
    maximum on a flat top. `resolved_sun_sine` is where the ratio meets 1 - min_drop."""
    from vision.limb import resolved_sun_sine, surface_ratio

    c = float(sun_path_ratio(np.array([1.0]))[0])
    A = _crossing_u(c, 0.5) * math.exp(18300.0 / 8000.0)
    us = math.log((1.0 + c) / c)
    g = lambda u: -math.expm1(-u) * math.exp(-c * u)   # noqa: E731
    assert abs(float(surface_ratio(np.array([1.0]))[0]) - g(A) / g(us)) < 1e-4
    mu = resolved_sun_sine(0.5, 8000.0, 18300.0, 0.15)
    assert 0.0 < mu < 1.0 and abs(float(surface_ratio(np.array([mu]))[0]) - 0.85) < 1e-6


def test_profile_rise_on_a_ramp():
    """The profile kernel's rise (`vision.limb._profile_crossings`) on a noise-free ramp: linear
    brightness 0 at x = 10 rising to its peak 0.8 at x = 30, then a drop to 0.24 (the surface);
    the 50 % crossing lies 10 px and the 80 % level 16 px from the edge pixel at x = 10: a rise
    of 6 px. Tolerance 0.1 px: the 8-bit rounding of the tone curve (at most half a level, 0.7 %
    of the brightness at 168/255, 0.07 px on this 0.04-per-px slope)."""
    from vision.limb import LimbEdgeConfig, _profile_crossings

    x = np.arange(64, dtype=float)
    lin = 0.8 * np.where(x < 10, 0.0, np.where(x <= 30, (x - 10) / 20.0, 0.3))   # peak below the clip level
    row = np.round(255.0 * lin ** (1 / 2.2)).astype(np.uint8)
    img = np.repeat(np.repeat(row[None, :, None], 9, axis=0), 3, axis=2)
    sc, ok, rise = _profile_crossings(img, np.array([[10.0, 4.0]]), np.array([[1.0, 0.0]]),
                                      np.arange(-6, 41, dtype=float), LimbEdgeConfig(), upper=0.8)
    assert ok[0] and abs(sc[0] - 10.0) < 0.1 and abs(rise[0] - 6.0) < 0.1, (sc, rise)


@pytest.fixture(scope="module")
def orbit_frames():
    """The scenario's first 12 s at one frame every 4 s (4 frames), simulated and rendered as
    ``horizon-nav simulate`` does: [(jpeg, R_ec, x_e, t_ns)]."""
    from scenarios.sim.render import flight_frame_truths, render_flight_images, scenario_render_options
    from scenarios.sim.simulate import simulate_flight
    from scenarios.study.orbit_mismatch import orbit_scenario

    sc = orbit_scenario(duration_s=12.0, rate_hz=0.25)
    fl = simulate_flight(sc, 0)
    recs = flight_frame_truths(fl)
    jpgs = [jpg for _, _, jpg in render_flight_images(fl, options=scenario_render_options(sc), progress=False)]
    assert len(jpgs) == len(recs) >= 3
    return [(j, r.R_ec, r.x_e, r.t_ns) for j, r in zip(jpgs, recs)]


def _run(frames, config):
    """(path, nadir error [deg] against the geocentric nadir, 3-sigma bound [deg]) per frame, with
    the replay's prior (position, attitude, predicted Sun)."""
    from nav import ephemeris
    from scenarios.config.camera import load_camera
    from scenarios.flightlog.jpeg import decode_frame
    from vision.frontend import FramePrior, process_frame

    cam = load_camera("scenarios/library/cameras/pinhole_25deg.toml")
    out = []
    for jpg, R_ec, x_e, t_ns in frames:
        prior = FramePrior(x_e, R_ec, sun_c=R_ec.T @ ephemeris.sun_direction_e(t_ns, x_e))
        res = process_frame(decode_frame(jpg), cam, config, prior=prior, rng=np.random.default_rng(0))
        rec = res.record("earth")
        assert rec is not None, res.reasons
        e_true = R_ec.T @ (-np.asarray(x_e) / np.linalg.norm(x_e))
        err = math.degrees(math.acos(min(1.0, float(rec.e_c @ e_true))))
        out.append((res.targets["earth"].limb_path, err, 3.0 * rec.sigma_deg))
    return out


def test_pinhole_orbit_limb_edge_error(orbit_frames):
    """The default front end with the Moon (scenarios/library/vision/moon.toml) on the rendered
    frames: every nadir within 0.5 deg of the truth (issue 22's acceptance for narrow pinholes in
    orbit; the threshold edge alone is 0.52 deg off here, its 15 km prior against the rendered
    37 km at 0.0227 deg/km) and inside its own 3 sigma. Without the flank width test the same
    frames give 1.2-1.4 deg on the limb path: checked here too, so that the frames still show
    the case the test is about."""
    import dataclasses

    from scenarios.config.vision import load_vision_config

    cfg = load_vision_config("scenarios/library/vision/moon.toml")
    got = _run(orbit_frames, cfg)
    for path, err, s3 in got:
        assert err <= 0.5 and err <= s3, got
    off = dataclasses.replace(cfg, earth=dataclasses.replace(
        cfg.earth, limb=dataclasses.replace(cfg.earth.limb, flank_width_max=0.0)))
    assert max(err for path, err, _ in _run(orbit_frames, off) if path == "limb") > 1.0
