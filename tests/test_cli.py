"""The console script: help, version, clean one-line errors."""
import subprocess
import sys

import pytest

from scenarios import cli


def test_help_lists_subcommands(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for cmd in ("analyze", "demo", "ephem"):
        assert cmd in out


def test_version(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--version"])
    assert "horizon-nav" in capsys.readouterr().out


def test_user_error_is_one_line_without_traceback():
    r = subprocess.run([sys.executable, "-m", "scenarios.cli", "ephem", "--time", "yesterday"],
                       capture_output=True, text=True)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert "ISO-8601" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_ephem_json(capsys):
    import json
    assert cli.main(["ephem", "--json", "--height", "250000"]) == 0
    res = json.loads(capsys.readouterr().out)
    # ATEK lift-off: the midnight Sun is low in the north-east at Esrange in June.
    assert 0 < res["sun"]["elevation_deg"] < 20 and 0 < res["sun"]["azimuth_deg"] < 90
    assert 0.5 < res["moon"]["parallax_deg"] < 1.2
