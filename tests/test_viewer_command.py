"""The command the summary and the demo print to open a recording runs the viewer this
interpreter installed (a bare ``rerun`` is found only with the venv activated)."""
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
