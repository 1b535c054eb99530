"""``horizon-nav simulate``: the log it writes (read back), atomic writing, errors, and the truth plot."""
import subprocess
import sys

import numpy as np
import pytest

from scenarios import cli
from scenarios.scenario import load_scenario
from scenarios.simulate import simulate_flight


@pytest.fixture(scope="module")
def log_path(tmp_path_factory):
    out = tmp_path_factory.mktemp("logs") / "atek.mcap"
    assert cli.main(["simulate", "atek", "-o", str(out), "--seed", "5", "--duration", "70", "--quiet"]) == 0
    return out


def test_log_contents(log_path):
    from scenarios.log_reader import read_log
    assert log_path.exists()
    assert [p.name for p in log_path.parent.iterdir()] == ["atek.mcap"]  # no temp file left behind
    log = read_log(log_path)
    info = log.info
    assert info["seed"] == "5" and "name = \"atek\"" in info["scenario"] and info["kind"] == "simulated"
    assert "software_version" in info
    topics = {t.topic for t in log.topics} if not isinstance(log.topics, dict) else set(log.topics)
    for t in ("/imu", "/gps", "/truth/state", "/tf_static", "/camera_1/camera_info", "/camera_2/truth"):
        assert t in topics, t
    # the logged IMU equals a fresh simulation with the same seed (deterministic draws)
    fl = simulate_flight(load_scenario("atek"), seed=5, duration=70.0)
    np.testing.assert_allclose(log.imu.t_ns, fl.to_ns(fl.imu.t))
    assert len(log.imu.t_ns) == 70 * 20 and len(log.gps.t_ns) == 701
    cams = log.cameras
    assert set(cams) == {1, 2}


def test_cli_errors_are_one_line(tmp_path):
    bad = tmp_path / "broken.toml"
    bad.write_text("name = 'x'\n[imu\n")
    for args in (["no-such-scenario"], [str(bad)]):
        r = subprocess.run([sys.executable, "-m", "scenarios.cli", "simulate", *args, "-o",
                            str(tmp_path / "o.mcap"), "--quiet"], capture_output=True, text=True)
        assert r.returncode == 2 and "Traceback" not in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "broken.toml" in r.stderr and "malformed TOML" in r.stderr
    assert not (tmp_path / "o.mcap").exists()


def test_render_hook_is_explicit():
    with pytest.raises(ValueError, match="no-images"):
        simulate_flight(load_scenario("atek"), 0, 1.0, render_images=True)


def test_plot_truth_png(tmp_path):
    out = tmp_path / "truth.png"
    assert cli.main(["plot-truth", "atek", "-o", str(out), "--duration", "120"]) == 0
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
