"""Benchmark harness: every benchmark records figures through the ``bench`` fixture and the
session writes them to ``bench.json`` (atomically) as a list of
``{"name", "value", "unit", "baseline", "ratio"}``.

``HORIZON_NAV_BENCH_QUICK=1`` (``make bench QUICK=1``) asks benchmarks for a smaller version.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from scenarios.atomic import atomic_write_text

_RESULTS: list[dict] = []
BENCH_FILE = Path(os.environ.get("HORIZON_NAV_BENCH_FILE", "bench.json"))


def quick() -> bool:
    return os.environ.get("HORIZON_NAV_BENCH_QUICK", "") not in ("", "0")


class Recorder:
    def __call__(self, name: str, value: float, unit: str, baseline: float | None = None,
                 ratio: float | None = None, **extra) -> None:
        """Record one figure. ``baseline`` is the in-run reference figure, ``ratio`` value/baseline
        (or the ratio the issue names); extra keys (cores, notes) are kept alongside."""
        row = {"name": name, "value": float(value), "unit": unit,
               "baseline": None if baseline is None else float(baseline),
               "ratio": None if ratio is None else float(ratio)}
        row.update(extra)
        row.setdefault("cores", os.cpu_count())
        _RESULTS[:] = [r for r in _RESULTS if r["name"] != name]
        _RESULTS.append(row)
        print(f"\nBENCH {name} = {value:.6g} {unit}"
              + (f" (baseline {baseline:.6g}, ratio {ratio:.4g})" if baseline is not None and ratio is not None else ""))


@pytest.fixture(scope="session")
def bench() -> Recorder:
    return Recorder()


@pytest.fixture(scope="session")
def is_quick() -> bool:
    return quick()


def pytest_sessionfinish(session, exitstatus):
    if not _RESULTS:
        return
    old = []
    if BENCH_FILE.exists():  # keep figures of benchmarks not run this time
        try:
            old = [r for r in json.loads(BENCH_FILE.read_text()) if isinstance(r, dict)]
        except (json.JSONDecodeError, OSError):
            old = []
    names = {r["name"] for r in _RESULTS}
    rows = [r for r in old if r.get("name") not in names] + _RESULTS
    atomic_write_text(BENCH_FILE, json.dumps(sorted(rows, key=lambda r: r["name"]), indent=1))
