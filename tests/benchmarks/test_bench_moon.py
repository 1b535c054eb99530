"""The Moon (vision/moon.py) on rendered frames (tests/moon_frames.py: 20-100 % lit, 8-60 px across,
limb signal 0.04-2 of full scale, noise, JPEG): found fraction, direction RMS and 3-sigma
containment with the replay's prior (the Sun's direction and the Moon's apparent radius), with the
Sun only, with the radius only, and without any prior; through a rectilinear (pinhole-shaped)
lens beside; the fixed-threshold full-disc fit (``moon.phase.aware = false``) on the same frames
for comparison; the Moon above the Earth's limb in frames exposed for the Earth; and the cost of
enabling the Moon on an ATEK Earth + Sun frame. QUICK: 60 frames instead of 200."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from tests.benchmarks.timing import median_ms
from tests.moon_frames import moon_over_earth, moon_set
from vision.config import FramePrior, VisionConfig
from vision.frontend import process_frame
from vision.image_geometry import fast_pixel_angle


def _moon_only(aware: bool = True) -> VisionConfig:
    c = VisionConfig()
    moon = dataclasses.replace(c.moon, enabled=True, phase=dataclasses.replace(c.moon.phase, aware=aware))
    return dataclasses.replace(c, earth=dataclasses.replace(c.earth, enabled=False),
                               sun=dataclasses.replace(c.sun, enabled=False), moon=moon)


def _run(frames, cfg, prior: str):
    err, sig, ms = [], [], []
    for f in frames:
        kw = {"ephemeris": dict(sun_c=f.sun_c, moon_alpha=f.alpha), "sun": dict(sun_c=f.sun_c),
              "radius": dict(moon_alpha=f.alpha), "none": {}}[prior]
        res = process_frame(f.image, f.camera, cfg, prior=FramePrior(**kw) if kw else None)
        ms.append(1e3 * res.timings["total"])
        rec = res.record("moon")
        if rec is not None:
            err.append(math.degrees(math.acos(min(1.0, float(rec.e_c @ f.moon_c)))))
            sig.append(rec.sigma_deg)
    err, sig = np.asarray(err), np.asarray(sig)
    return dict(found=err.size / len(frames), rms=float(np.sqrt(np.mean(err**2))) if err.size else math.nan,
                contained=float(np.mean(err < 3 * sig)) if err.size else math.nan,
                p95=float(np.percentile(err, 95)) if err.size else math.nan, ms=float(np.median(ms)))


def _atek_cost(bench):
    """Median process_frame time of an ATEK Earth + Sun frame with and without the Moon enabled."""
    import numba

    from nav import ephemeris
    from scenarios.config.vision import load_vision_config
    from scenarios.flightlog.jpeg import decode_frame
    from scenarios.sim import render
    from tests.benchmarks.test_bench_vision import _flight, _frames, _full_prior
    from vision import mask as vmask

    numba.set_num_threads(1)
    fl, recs = _flight()
    cam = fl.cameras[0].camera
    mask = vmask.from_binary(render.payload_mask(cam, render.DEFAULT_PAYLOAD_MASK))
    cfg = load_vision_config(camera=cam)
    on = dataclasses.replace(cfg, moon=dataclasses.replace(cfg.moon, enabled=True))
    for r, jpg, _ in _frames("disturbed", range(61, 200, 3), fl, recs):
        img, prior = decode_frame(jpg), _full_prior(r, r.R_ec)
        if process_frame(img, cam, cfg, mask=mask, prior=prior).record("sun") is not None:
            break
    t_off = median_ms(lambda: process_frame(img, cam, cfg, mask=mask, prior=prior), 20)
    t_on = median_ms(lambda: process_frame(img, cam, on, mask=mask, prior=prior), 20)
    moon_c = r.R_ec.T @ ephemeris.moon_direction_e(r.t_ns, r.x_e)
    gated = dataclasses.replace(prior, moon_c=moon_c)
    t_gated = median_ms(lambda: process_frame(img, cam, on, mask=mask, prior=gated), 20)
    bench("vision.moon_enabled_ms_per_frame", t_on, "ms", baseline=t_off,
          baseline_name="the same ATEK Earth + Sun frame with the Moon off, same run",
          with_predicted_moon_ms=t_gated,
          note="1920x1080, full prior; without a predicted Moon direction the whole frame is searched")


def test_bench_moon(bench, is_quick):
    frames = moon_set(60 if is_quick else 200, seed=7)
    out = {p: _run(frames, _moon_only(), p) for p in ("ephemeris", "sun", "radius", "none")}
    old = _run(frames, _moon_only(aware=False), "ephemeris")
    rect = _run(moon_set(30 if is_quick else 100, seed=8, lens="rectilinear"), _moon_only(), "ephemeris")
    for p, o in out.items():
        print(f"\n[moon, prior {p}] found {o['found']:.3f} RMS {o['rms']:.4f} deg p95 {o['p95']:.4f} "
              f"3-sigma containment {o['contained']:.3f} median {o['ms']:.2f} ms")
    print(f"\n[moon, full-disc path] found {old['found']:.3f} RMS {old['rms']:.4f}")
    pa = float(np.median([math.degrees(float(fast_pixel_angle(f.camera, np.array([[f.camera.cx, f.camera.cy]]))[0]))
                          for f in frames]))
    e = out["ephemeris"]
    bench("vision.moon_rms_deg", e["rms"], "deg", baseline=0.02, baseline_name="acceptance target 0.02 deg",
          sun_only_rms=out["sun"]["rms"], radius_only_rms=out["radius"]["rms"], no_prior_rms=out["none"]["rms"],
          median_pixel_deg=pa,
          p95=e["p95"], n=len(frames), rectilinear_rms=rect["rms"], rectilinear_found=rect["found"],
          rectilinear_contained=rect["contained"],
          note="prior: Sun direction and apparent radius (the replay's); equidistant lens, rectilinear beside")
    bench("vision.moon_found_fraction", e["found"], "fraction", baseline=0.95,
          baseline_name="acceptance target 0.95", full_disc_path_found=old["found"],
          sun_only_found=out["sun"]["found"], no_prior_found=out["none"]["found"], n=len(frames))
    bench("vision.moon_cov_3sigma_containment", e["contained"], "fraction", baseline=0.97,
          baseline_name="acceptance target 0.97", sun_only=out["sun"]["contained"],
          radius_only=out["radius"]["contained"],
          no_prior=out["none"]["contained"])
    bench("vision.moon_ms_per_frame", e["ms"], "ms", note="400x300 Moon frames, Moon only")
    rng = np.random.default_rng(3)
    over = [moon_over_earth(rng, rng.uniform(8, 60), rng.uniform(0.2, 1.0), seed=i) for i in range(20 if is_quick else 60)]
    oe = _run(over, _moon_only(), "ephemeris")
    print(f"\n[moon over the Earth] found {oe['found']:.3f} RMS {oe['rms']:.4f} contained {oe['contained']:.3f}")
    bench("vision.moon_over_earth_found_fraction", oe["found"], "fraction", baseline=0.95,
          baseline_name="acceptance target 0.95", rms_deg=oe["rms"], contained=oe["contained"], n=len(over),
          note="rectilinear lens at the horizon from 500 km, auto exposure set by the Earth, Moon above the limb")
    _atek_cost(bench)
    assert e["found"] > 0.5
