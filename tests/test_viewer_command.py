"""What the replay tells a first-time user: the command that opens a recording runs the viewer
this interpreter installed (a bare ``rerun`` is found only with the venv activated), and the first
run says that it compiles its kernels once."""
import os
import shlex
import sys
from pathlib import Path

from scenarios.replay.summary import viewer_command


def test_viewer_command_names_the_installed_viewer(tmp_path, monkeypatch):
    exe = Path(sys.executable).parent / "rerun"
    cmd = shlex.split(viewer_command("logs/atek.rrd"))
    assert cmd[-1] == "logs/atek.rrd"
    if exe.exists():
        assert os.path.samefile(cmd[0], exe) and os.access(cmd[0], os.X_OK)
        monkeypatch.chdir(tmp_path)      # relative to the working directory, never a bare name
        first = shlex.split(viewer_command("x.rrd"))[0]
        assert first.startswith((".", os.sep)) and os.path.samefile(first, exe)
    else:
        assert cmd[0] == "rerun"


def test_first_run_is_recognised_by_the_numba_cache(tmp_path, monkeypatch):
    """The replay says that it compiles its kernels once exactly when numba's cache index of the
    filter's and the front end's kernels is missing."""
    from scenarios.cli.replay import CACHE_MARKERS, kernels_cached
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    assert not kernels_cached(tmp_path)
    for pkg, stem in CACHE_MARKERS:
        d = tmp_path / pkg / "__pycache__"
        d.mkdir(parents=True)
        assert not kernels_cached(tmp_path) or pkg == CACHE_MARKERS[-1][0]
        (d / f"{stem}x-1.py311.nbi").write_bytes(b"")
    assert kernels_cached(tmp_path)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "elsewhere"))
    assert kernels_cached(tmp_path / "empty")     # a cache elsewhere: nothing is claimed
