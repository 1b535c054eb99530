"""Benchmark: importing a 1-hour 400 Hz IMU CSV (1.44 M rows; QUICK: 200,000 rows).

Figures:

* ``import.rows_per_s`` -- parse + convert (``tables.read_imu``: pyarrow CSV parse of the 7 mapped
  columns, integer-ns time, deg/s -> rad/s and g -> m/s^2, a signed-permutation axis map), best of
  3. Target: >= 500,000 rows/s. Baseline timed in the same run: the plain ``csv`` module parsing
  the first 100,000 rows into floats (rows/s).
* ``import.parse_time_over_read_bytes`` -- the parse + convert time over ``Path.read_bytes()`` of
  the same file (the floor any reader pays); the value is itself that ratio, so its baseline is
  parity, 1.0.
* ``import.end_to_end_rows_per_s`` -- ``import_flight`` of the same file into an MCAP log (read,
  validate, write). The log writer dominates it (mcap's ``add_message`` costs a few us per
  message), so it is reported separately and has no target here.
"""
from __future__ import annotations

import csv
import time

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv

from scenarios.importer.build import import_flight
from scenarios.importer.mapping import load_mapping
from scenarios.importer.tables import read_imu
from tests.benchmarks.timing import best_of

T0 = 1_560_392_460_000_000_000
G0 = 9.80665


def test_bench_import_imu_csv(tmp_path, bench, is_quick):
    n = 200_000 if is_quick else 1_440_000
    rng = np.random.default_rng(0)
    t = T0 + np.arange(n, dtype=np.int64) * 2_500_000  # 400 Hz
    s = np.arange(n) / 400.0
    w_dps = np.stack([0.5 * np.sin(0.1 * s), 0.3 + 0 * s, 0.2 * np.cos(0.05 * s)], 1) + 0.01 * rng.standard_normal((n, 3))
    f_g = np.stack([1.0 + 0 * s, 0.01 * np.sin(s), 0 * s], 1) + 5e-4 * rng.standard_normal((n, 3))
    path = tmp_path / "imu.csv"
    pcsv.write_csv(pa.table({"t_utc_ns": t, "wx": w_dps[:, 0], "wy": w_dps[:, 1], "wz": w_dps[:, 2],
                             "fx": f_g[:, 0], "fy": f_g[:, 1], "fz": f_g[:, 2]}), path)
    mapping = tmp_path / "m.toml"
    mapping.write_text("""
liftoff_utc = "2019-06-13T02:21:00Z"
[imu]
file = "imu.csv"
time = { column = "t_utc_ns", base = "unix", unit = "ns" }
gyro = { columns = ["wx", "wy", "wz"], unit = "deg/s" }
accel = { columns = ["fx", "fy", "fz"], unit = "g" }
axes = ["+z", "+x", "+y"]
""")
    m = load_mapping(mapping)
    read_imu(m.imu, m.liftoff_ns)  # warm-up: page cache, pyarrow thread pool
    t_parse, imu = best_of(lambda: read_imu(m.imu, m.liftoff_ns), 3)
    # correctness of what was timed: body = sensor (z, x, y), one multiplication per value
    assert np.array_equal(imu.t_ns, t)
    assert np.allclose(imu.gyro, np.radians(w_dps[:, [2, 0, 1]]), rtol=4e-16, atol=0)
    assert np.allclose(imu.accel, f_g[:, [2, 0, 1]] * G0, rtol=4e-16, atol=0)
    rate = n / t_parse
    t_raw, raw = best_of(path.read_bytes, 5)

    def csv_module(k=100_000):
        with open(path, newline="") as fh:
            r = csv.reader(fh)
            next(r)
            out = []
            for i, row in enumerate(r):
                if i >= k:
                    break
                out.append([int(row[0])] + [float(x) for x in row[1:]])
        return len(out)

    t_csv, k = best_of(csv_module, 2)
    csv_rate = k / t_csv
    t_e2e = time.perf_counter()
    res = import_flight(m, tmp_path / "out.mcap")
    t_e2e = time.perf_counter() - t_e2e
    assert res.counts["imu"] == n
    mb = len(raw) / 1e6
    print(f"\nIMU CSV: {n} rows, {mb:.0f} MB; parse+convert {t_parse:.3f} s ({rate:,.0f} rows/s); read_bytes "
          f"{t_raw:.3f} s; csv module {csv_rate:,.0f} rows/s; end-to-end import {t_e2e:.2f} s "
          f"({n / t_e2e:,.0f} rows/s; write {res.timings['write_s']:.2f} s, read {res.timings['imu_read_s']:.2f} s)")
    bench("import.rows_per_s", rate, "rows/s", baseline=csv_rate, rows=n, file_mb=mb,
          baseline_name="plain csv module on the first 100k rows of the same file, same run", target=500_000.0,
          notes="parse+convert (tables.read_imu, pyarrow.csv)")
    bench("import.parse_time_over_read_bytes", t_parse / t_raw, "ratio", baseline=1.0,
          baseline_name="parity with Path.read_bytes() of the same file, same run (value = parse time / read time)",
          rows=n, parse_s=t_parse, read_bytes_s=t_raw)
    bench("import.end_to_end_rows_per_s", n / t_e2e, "rows/s", baseline=rate,
          baseline_name="parse+convert alone (import.rows_per_s), same run", rows=n,
          write_s=res.timings["write_s"],
          notes="import_flight into MCAP (LogWriter dominates)")


def test_bench_import_plausibility(tmp_path, bench, is_quick):
    """``import.plausibility_s``: a fresh ``horizon-nav import`` process refusing a 10-million-row
    IMU CSV (QUICK: 1 million) whose Unix-millisecond stamps are declared as seconds: wall time of
    the whole command (interpreter start, imports, the time probe, the one-line error), with the
    refusal inside the process and the peak RSS of the child as extra fields. Target: 10 s."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from scenarios.errors import UserError

    n = 1_000_000 if is_quick else 10_000_000
    t_ms = 1_560_392_460_000 + np.arange(n, dtype=np.int64) * 5  # 200 Hz, Unix ms
    path = tmp_path / "imu.csv"
    c = pa.array(np.full(n, 0.01))
    pcsv.write_csv(pa.table({"t": t_ms, "wx": c, "wy": c, "wz": c, "fx": c, "fy": c, "fz": c}), path)
    mapping = tmp_path / "m.toml"
    mapping.write_text("""
liftoff_utc = "2019-06-13T02:21:00Z"
[imu]
file = "imu.csv"
time = { column = "t", base = "unix", unit = "s" }
gyro = { columns = ["wx", "wy", "wz"], unit = "rad/s" }
accel = { columns = ["fx", "fy", "fz"], unit = "m/s^2" }
""")
    out = tmp_path / "out.mcap"
    t = time.perf_counter()
    try:
        import_flight(mapping, out)
        raise AssertionError("the wrong time unit was not refused")
    except UserError as exc:
        msg = str(exc)
    t_in = time.perf_counter() - t
    assert "unit = 'ms' would give" in msg and not out.exists()
    code = ("import json, resource, subprocess, sys, time\n"
            "t = time.perf_counter()\n"
            f"p = subprocess.run([sys.executable, '-m', 'scenarios.cli', 'import', {str(mapping)!r}, '-o', "
            f"{str(out)!r}], capture_output=True, text=True)\n"
            "print(json.dumps({'rc': p.returncode, 'err': p.stderr, 'wall': time.perf_counter() - t,\n"
            "                  'rss_mb': resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}))\n")
    root = Path(__file__).resolve().parents[2]
    r = json.loads(subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True,
                                  check=True).stdout)
    assert r["rc"] == 2 and r["err"].count("\n") == 1 and not out.exists()
    mb = path.stat().st_size / 1e6
    print(f"\n{n} rows ({mb:.0f} MB): refused in {t_in:.3f} s in-process, {r['wall']:.2f} s as a command, "
          f"peak RSS {r['rss_mb']:.0f} MB: {r['err'].strip()}")
    bench("import.plausibility_s", r["wall"], "s", baseline=10.0, baseline_name="target 10 s", rows=n,
          file_mb=mb, in_process_s=t_in, peak_rss_mb=r["rss_mb"],
          notes="horizon-nav import refusing Unix ms declared as s (time probe before any read)")
