"""Benchmark: writing and reading IMU samples of an MCAP flight log (numpy in, numpy out).

Figures:

* ``logs.imu_read_samples_per_s``: ``read_log(path, topics=["/imu"])`` (best of 3). Baseline timed
  in the same run: ``Path.read_bytes()`` of the same file (the floor any reader pays), expressed in
  samples/s. Target: >= 500,000 samples/s, 1,000,000 samples in <= 2 s.
* ``logs.imu_read_ratio_to_raw_bytes``: the read time over the ``Path.read_bytes()`` time (the value
  is itself a ratio; baseline parity, 1.0).
* ``logs.imu_write_samples_per_s``: ``LogWriter.write_imu`` of all samples + ``close`` (best of 2;
  bulk path: Message records as one byte matrix, one zstd call per chunk). Baseline timed in the
  same run: the per-message path of ``mcap.writer.Writer.add_message`` on the first 50,000
  payloads. Target: 1,000,000 samples in <= 1 s on one core.
"""
from __future__ import annotations

import time

import numpy as np

from scenarios.flightlog.reader import read_log
from scenarios.flightlog.writer import LogWriter
from tests.benchmarks.timing import best_of

T0 = 1_560_392_460_000_000_000


def test_bench_imu_read(tmp_path, bench, is_quick):
    n = 200_000 if is_quick else 1_000_000
    rng = np.random.default_rng(0)
    t = T0 + np.arange(n, dtype=np.int64) * 2_500_000  # 400 Hz
    # realistic-looking signals: slow motion + sensor noise (compresses like real IMU data)
    s = np.arange(n) / 400.0
    gyro = np.stack([0.01 * np.sin(0.1 * s), 31.4 + 0 * s, 0.02 * np.cos(0.05 * s)], 1) + 1e-4 * rng.standard_normal((n, 3))
    accel = np.stack([9.0 + 0 * s, 0.1 * np.sin(s), 0.0 * s], 1) + 5e-3 * rng.standard_normal((n, 3))
    path = tmp_path / "bench.mcap"

    def write():
        with LogWriter(path, {"scenario": "", "seed": 0, "liftoff_utc_ns": T0, "kind": "simulated"}) as w:
            w.write_imu(t, gyro, accel)

    t_write, _ = best_of(write, 2)
    t_ref = _mcap_add_message_time(path, 50_000)
    read_log(path, topics=["/imu"])  # warm-up: numba compile/cache load, page cache
    t_read, log = best_of(lambda: read_log(path, topics=["/imu"]), 3)
    assert np.array_equal(log.imu.gyro, gyro) and np.array_equal(log.imu.t_ns, t)
    t_raw, raw = best_of(path.read_bytes, 5)
    mb = len(raw) / 1e6
    rate = n / t_read
    print(f"\nIMU log: {n} samples, {mb:.1f} MB (zstd), write {t_write:.2f} s ({n / t_write:.0f} samples/s), "
          f"read {t_read:.3f} s, raw read_bytes {t_raw:.4f} s ({mb / t_raw:.0f} MB/s)")
    bench("logs.imu_read_samples_per_s", rate, "samples/s", baseline=n / t_raw,
          baseline_name="Path.read_bytes() of the same file, in samples/s, same run", target=500_000.0,
          samples=n, file_mb=mb, read_bytes_mb_per_s=mb / t_raw)
    bench("logs.imu_read_ratio_to_raw_bytes", t_read / t_raw, "ratio", baseline=1.0,
          baseline_name="parity with Path.read_bytes() of the same file, same run (value = read time / read_bytes time)",
          samples=n, read_s=t_read, read_bytes_s=t_raw)
    print(f"mcap Writer.add_message: {50_000 / t_ref:.0f} samples/s (per-message path, 50,000 samples)")
    bench("logs.imu_write_samples_per_s", n / t_write, "samples/s", baseline=50_000 / t_ref,
          baseline_name="mcap Writer.add_message per-message path, first 50,000 samples, same run",
          samples=n, file_mb=mb, write_s=t_write, mcap_add_message_samples_per_s=50_000 / t_ref)


def _mcap_add_message_time(path, k):
    """Seconds for ``mcap.writer.Writer.add_message`` of the first ``k`` IMU messages of ``path``
    (payloads read back, then written one call per message as the writer did before)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer
    with open(path, "rb") as f:
        msgs = []
        for _, ch, m in make_reader(f).iter_messages(log_time_order=False):
            msgs.append((m.log_time, m.data))
            if len(msgs) == k:
                break
    with open(path.with_suffix(".ref.mcap"), "wb") as f:
        tw = time.perf_counter()
        w = Writer(f)
        w.start("ros2", "bench")
        cid = w.register_channel("/imu", "cdr", w.register_schema("sensor_msgs/msg/Imu", "ros2msg", b""))
        for lt, d in msgs:
            w.add_message(cid, lt, d, lt)
        w.finish()
        return time.perf_counter() - tw
