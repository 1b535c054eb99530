"""Atomic output files (`scenarios.atomic`): the target holds the old or the new content, never
a part, and no temporary file is left."""
from __future__ import annotations

import numpy as np
import pytest

from scenarios.atomic import atomic_output, atomic_savez, atomic_write_bytes


def test_savez_writes_exactly_the_path(tmp_path):
    """``atomic_savez(p)`` writes p itself (np.savez given a name would write its temporary file
    plus ".npz"), the arrays round-trip bit for bit, and the folder holds nothing else."""
    p = tmp_path / "f.npz"
    a = np.random.default_rng(0).normal(size=(4, 3))
    assert atomic_savez(p, a=a, b=np.arange(3)) == p
    with np.load(p) as z:
        assert np.array_equal(z["a"], a) and z["b"].tolist() == [0, 1, 2]
    assert [q.name for q in tmp_path.iterdir()] == ["f.npz"]


def test_a_failed_write_keeps_the_old_file(tmp_path):
    """A writer that raises half-way leaves the previous bytes in place and no temporary file."""
    p = tmp_path / "f.bin"
    atomic_write_bytes(p, b"old")

    def half(tmp):
        with open(tmp, "wb") as f:
            f.write(b"ne")
        raise RuntimeError("interrupted")
    with pytest.raises(RuntimeError):
        atomic_output(p, half)
    assert p.read_bytes() == b"old" and [q.name for q in tmp_path.iterdir()] == ["f.bin"]
