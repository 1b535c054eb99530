import sys, time, math, dataclasses, numpy as np
sys.path.insert(0, '.')
from tests.benchmarks import test_bench_vision as B
from scenarios.flightlog.jpeg import decode_frame
from scenarios.config.vision import load_vision_config
from vision import mask as vmask
from scenarios.sim import render
from vision.moon import seed_threshold, moon_detection
from vision.binarize import brightness_histogram, as_frame
from vision.candidates import detect
fl, recs = B._flight()
cam = fl.cameras[0].camera
mask = vmask.from_binary(render.payload_mask(cam, render.DEFAULT_PAYLOAD_MASK))
cfg = load_vision_config(camera=cam)
n=0
for r, jpg, tr in B._frames("disturbed", range(61, 431, 30), fl, recs):
    a = as_frame(decode_frame(jpg)); hist = brightness_histogram(a, 8)
    row=[]
    for pct in (50, 5):
        tc = dataclasses.replace(cfg.moon, phase=dataclasses.replace(cfg.moon.phase, seed_percentile=pct))
        t = seed_threshold(hist, 3, tc)
        dc = moon_detection(tc, cam, math.radians(0.259), t)
        t0=time.perf_counter(); det = detect(a, dc, mask, hist=hist); dt=time.perf_counter()-t0
        row.append(f"p{pct}: t={t:.0f} cands={len(det.candidates)} {1e3*dt:.1f}ms")
    print(" | ".join(row))
