"""Renderer speed: one 1920x1080 ATEK frame (stand-in pose: Esrange, 230 km, 20 deg below the
horizon, Sun in view) on one core, against JPEG-encoding the same frame (in-run baseline)."""
import time

import cv2
import numba
import numpy as np

from nav import ephemeris, timescales
from scenarios.sim import render
from tests.poses import pose
from vision.camera import atek_camera


def test_render_frame_speed(bench, is_quick):
    threads = numba.get_num_threads()
    cv_threads = cv2.getNumThreads()
    numba.set_num_threads(1)
    cv2.setNumThreads(1)
    try:
        cam = atek_camera()
        t = timescales.parse_utc("2019-06-13T02:24:40Z")
        sun, moon = ephemeris.sun_position_e(t), ephemeris.moon_position_e(t)
        R, x = pose(60.0)  # Sun in the upper part of the image, Earth in the lower half
        opts = render.RenderOptions()
        fr = render.render_frame(cam, R, x, sun, moon, seed=0, options=opts)  # compile, caches
        n = 3 if is_quick else 10
        ts, js = [], []
        for i in range(n):
            t0 = time.perf_counter()
            fr = render.render_frame(cam, R, x, sun, moon, seed=i + 1, cloud_seed=0, options=opts)
            ts.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            jpg = render.encode_jpeg(fr.image, opts.jpeg_quality)
            js.append(time.perf_counter() - t0)
        ms = 1e3 * float(np.median(ts))
        jpeg_ms = 1e3 * float(np.median(js))
        assert len(jpg) > 10_000 and fr.image.shape == (1080, 1920, 3)
        bench("render.ms_per_frame", ms, "ms", baseline=jpeg_ms,
              baseline_name="JPEG encode of the same frame, same run", target=150.0,
              notes="1920x1080, 1 thread, default options")
        bench("render.ratio_to_jpeg_encode", ms / jpeg_ms, "ratio", baseline=1.0,
              baseline_name="parity with the JPEG encode of the same frame, same run (value = render / encode)",
              jpeg_encode_ms=jpeg_ms)
        # the ATEK flight: two cameras at 1 Hz over the simulated duration, render + encode
        frames = 2 * 600
        bench("render.atek_flight_estimate_s", frames * (ms + jpeg_ms) / 1e3, "s", baseline=300.0,
              baseline_name="goal 300 s", notes=f"{frames} frames x (render + JPEG) on one core")
    finally:
        numba.set_num_threads(threads)
        cv2.setNumThreads(cv_threads)
