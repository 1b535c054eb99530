"""Benchmark: reading IMU samples from an MCAP flight log into numpy.

Baseline timed in the same run: ``Path.read_bytes()`` of the same file (the floor any reader pays).
Figures: samples/s of ``read_log(path, topics=["/imu"])`` (best of a few runs) and the ratio of its
time to the raw read. Target (issue 3): >= 500,000 samples/s, 1,000,000 samples in <= 2 s on one core.
"""
from __future__ import annotations

import time

import numpy as np

from scenarios.log_reader import read_log
from scenarios.log_writer import LogWriter

T0 = 1_560_392_460_000_000_000


def _best(fn, runs):
    best = np.inf
    out = None
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def test_bench_imu_read(tmp_path, bench, is_quick):
    n = 200_000 if is_quick else 1_000_000
    rng = np.random.default_rng(0)
    t = T0 + np.arange(n, dtype=np.int64) * 2_500_000  # 400 Hz
    # realistic-looking signals: slow motion + sensor noise (compresses like real IMU data)
    s = np.arange(n) / 400.0
    gyro = np.stack([0.01 * np.sin(0.1 * s), 31.4 + 0 * s, 0.02 * np.cos(0.05 * s)], 1) + 1e-4 * rng.standard_normal((n, 3))
    accel = np.stack([9.0 + 0 * s, 0.1 * np.sin(s), 0.0 * s], 1) + 5e-3 * rng.standard_normal((n, 3))
    path = tmp_path / "bench.mcap"
    tw = time.perf_counter()
    with LogWriter(path, {"scenario": "", "seed": 0, "liftoff_utc_ns": T0, "kind": "simulated"}) as w:
        w.write_imu(t, gyro, accel)
    t_write = time.perf_counter() - tw
    read_log(path, topics=["/imu"])  # warm-up: numba compile/cache load, page cache
    t_read, log = _best(lambda: read_log(path, topics=["/imu"]), 3)
    assert np.array_equal(log.imu.gyro, gyro) and np.array_equal(log.imu.t_ns, t)
    t_raw, raw = _best(path.read_bytes, 5)
    mb = len(raw) / 1e6
    rate = n / t_read
    print(f"\nIMU log: {n} samples, {mb:.1f} MB (zstd), write {t_write:.2f} s ({n / t_write:.0f} samples/s), "
          f"read {t_read:.3f} s, raw read_bytes {t_raw:.4f} s ({mb / t_raw:.0f} MB/s)")
    bench("logs.imu_read_samples_per_s", rate, "samples/s", baseline=mb / t_raw, ratio=t_read / t_raw,
          notes="baseline = Path.read_bytes() of the same file in MB/s; ratio = t_read / t_raw",
          samples=n, file_mb=mb)
    bench("logs.imu_read_ratio_to_raw_bytes", t_read / t_raw, "ratio", baseline=t_raw, ratio=t_read / t_raw,
          samples=n)
    bench("logs.imu_write_samples_per_s", n / t_write, "samples/s", samples=n)
