"""bench.json records: ``ratio`` is ``value / baseline`` for every record, and every baseline is
named (tests/benchmarks/conftest.py; schema in docs/performance.md)."""
import json
import math
import os
from pathlib import Path

import pytest

from tests.benchmarks.conftest import make_record, record_problems


def test_ratio_is_value_over_baseline():
    r = make_record("x.speed", 3.0, "ms", 4.0, "JPEG decode of the same frame, same run", n=5)
    assert r["ratio"] == 3.0 / 4.0 and r["baseline"] == 4.0 and r["n"] == 5
    assert r["baseline_name"] == "JPEG decode of the same frame, same run"
    assert record_problems([r]) == []


def test_no_baseline_no_ratio():
    r = make_record("x.rate", 0.25, "fraction")
    assert r["baseline"] is None and r["baseline_name"] is None and r["ratio"] is None
    assert record_problems([r]) == []


def test_nan_value_keeps_the_rule():
    r = make_record("x.rms", math.nan, "deg", 0.02, "target 0.02 deg")
    assert math.isnan(r["ratio"]) and record_problems([r]) == []


@pytest.mark.parametrize("kw", [
    {"baseline": 2.0},                                   # baseline without a name
    {"baseline_name": "real time"},                      # name without a baseline
    {"baseline": 2.0, "baseline_name": "t", "ratio": 0.5},   # a ratio of the caller's own
])
def test_recorder_rejects(kw):
    with pytest.raises(TypeError):
        make_record("x", 1.0, "s", **kw)


def test_zero_baseline_rejected():
    with pytest.raises(ValueError):
        make_record("x", 1.0, "s", 0.0, "nothing")


def test_problems_found():
    good = make_record("a", 6.0, "x", 2.0, "b")
    assert record_problems([dict(good, ratio=6.0)])                # ratio = value, not value / baseline
    assert record_problems([dict(good, baseline_name=None)])       # unnamed baseline
    assert record_problems([dict(good, baseline=None)])            # ratio without a baseline
    assert record_problems([{k: v for k, v in good.items() if k != "baseline_name"}])


def test_bench_file_records():
    """The records of a bench.json that ``make bench`` wrote, named by HORIZON_NAV_BENCH_FILE
    (``HORIZON_NAV_BENCH_FILE=bench.json pytest tests/test_bench_records.py``)."""
    path = os.environ.get("HORIZON_NAV_BENCH_FILE")
    if not path or not Path(path).is_file():
        pytest.skip("HORIZON_NAV_BENCH_FILE names no file")
    path = Path(path)
    rows = json.loads(path.read_text())
    assert rows and record_problems(rows) == []
