"""Benchmark harness: every benchmark records figures through the ``bench`` fixture and the
session writes them to ``bench.json`` (atomically) as a list of records
``{"name", "value", "unit", "baseline", "baseline_name", "ratio", "cores", ...}`` sorted by name.

``ratio`` is always ``value / baseline``, computed here; ``baseline_name`` says what the baseline
is (a figure measured in the same run, an acceptance target, parity 1.0). A record without a
meaningful baseline has ``baseline``, ``baseline_name`` and ``ratio`` all ``None``. The schema is
described in docs/performance.md.

``HORIZON_NAV_BENCH_QUICK=1`` (``make bench QUICK=1``) asks benchmarks for a smaller version.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

from scenarios.atomic import atomic_write_text

_RESULTS: list[dict] = []
BENCH_FILE = Path(os.environ.get("HORIZON_NAV_BENCH_FILE", "bench.json"))


def quick() -> bool:
    return os.environ.get("HORIZON_NAV_BENCH_QUICK", "") not in ("", "0")


def make_record(name: str, value: float, unit: str, baseline: float | None = None,
                baseline_name: str | None = None, **extra) -> dict:
    """One bench.json record: ``ratio = value / baseline``.

    Parameters
    ----------
    name, value, unit
        The figure.
    baseline
        The reference figure ``value`` is compared with, in the same unit (a figure timed in the
        same run, an acceptance target, 1.0 for a value that is itself a ratio), or ``None``.
    baseline_name
        What the baseline is; required with a baseline, forbidden without one.
    **extra
        Further keys kept in the record (notes, counts, per-stage figures); ``ratio`` is not
        one of them, since it is always computed here.

    Raises
    ------
    TypeError
        On a ``ratio`` argument, or a baseline without a name (or a name without a baseline).
    ValueError
        On a zero baseline.
    """
    if "ratio" in extra:
        raise TypeError("bench(): ratio is computed as value / baseline; pass baseline and baseline_name")
    if (baseline is None) != (baseline_name is None):
        raise TypeError(f"bench({name!r}): baseline and baseline_name go together")
    if baseline is not None and not isinstance(baseline_name, str):
        raise TypeError(f"bench({name!r}): baseline_name must be a string")
    if baseline is not None and float(baseline) == 0.0:
        raise ValueError(f"bench({name!r}): zero baseline")
    value = float(value)
    base = None if baseline is None else float(baseline)
    row = {"name": name, "value": value, "unit": unit, "baseline": base, "baseline_name": baseline_name,
           "ratio": None if base is None else value / base}
    row.update(extra)
    row.setdefault("cores", os.cpu_count())
    return row


def record_problems(rows: list) -> list[str]:
    """What is wrong with bench.json records ``rows``: each must carry ``name``, ``value``, ``unit``,
    ``baseline``, ``baseline_name`` and ``ratio``, with a named baseline and ``ratio == value /
    baseline`` (to the last bit; NaN where value or baseline is NaN), or no baseline, no name and no
    ratio. An empty list means the records are sound."""
    bad = []
    for r in rows:
        name = r.get("name", "?")
        missing = [k for k in ("name", "value", "unit", "baseline", "baseline_name", "ratio") if k not in r]
        if missing:
            bad.append(f"{name}: missing {missing}")
            continue
        base, ratio = r["baseline"], r["ratio"]
        if base is None:
            if r["baseline_name"] is not None or ratio is not None:
                bad.append(f"{name}: no baseline, yet baseline_name {r['baseline_name']!r} / ratio {ratio!r}")
            continue
        if not isinstance(r["baseline_name"], str) or not r["baseline_name"]:
            bad.append(f"{name}: baseline {base!r} without a baseline_name")
        want = float(r["value"]) / float(base)
        if ratio is None or not (ratio == want or (math.isnan(want) and math.isnan(ratio))):
            bad.append(f"{name}: ratio {ratio!r} != value / baseline = {want!r}")
    return bad


class Recorder:
    def __call__(self, name: str, value: float, unit: str, baseline: float | None = None,
                 baseline_name: str | None = None, **extra) -> dict:
        """Record one figure (see :func:`make_record`); a second record of ``name`` replaces the first."""
        row = make_record(name, value, unit, baseline, baseline_name, **extra)
        _RESULTS[:] = [r for r in _RESULTS if r["name"] != name]
        _RESULTS.append(row)
        print(f"\nBENCH {name} = {row['value']:.6g} {unit}"
              + ("" if row["baseline"] is None else
                 f" (baseline {row['baseline']:.6g}: {baseline_name}; ratio {row['ratio']:.4g})"))
        return row


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
    if BENCH_FILE.exists():  # keep figures of benchmarks not run this time (sound records only)
        try:
            old = [r for r in json.loads(BENCH_FILE.read_text()) if isinstance(r, dict) and not record_problems([r])]
        except (json.JSONDecodeError, OSError):
            old = []
    names = {r["name"] for r in _RESULTS}
    rows = [r for r in old if r.get("name") not in names] + _RESULTS
    atomic_write_text(BENCH_FILE, json.dumps(sorted(rows, key=lambda r: r["name"]), indent=1))
