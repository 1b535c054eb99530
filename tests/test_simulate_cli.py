"""``horizon-nav simulate``: the log it writes (read back), atomic writing, errors, and the truth plot."""
import subprocess
import sys

import numpy as np
import pytest

from scenarios import cli
from scenarios.sim.scenario import load_scenario
from scenarios.sim.simulate import simulate_flight


@pytest.fixture(scope="module")
def log_path(tmp_path_factory):
    out = tmp_path_factory.mktemp("logs") / "atek.mcap"
    assert cli.main(["simulate", "atek", "-o", str(out), "--seed", "5", "--duration", "70", "--no-images", "--quiet"]) == 0
    return out


def test_log_contents(log_path):
    from scenarios.flightlog.reader import read_log
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
    assert "broken.toml" in r.stderr and "not valid TOML" in r.stderr
    assert not (tmp_path / "o.mcap").exists()


def test_plot_truth_png(tmp_path):
    out = tmp_path / "truth.png"
    assert cli.main(["plot-truth", "atek", "-o", str(out), "--duration", "120"]) == 0
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000


def test_simulate_writes_rendered_images(tmp_path):
    import cv2

    from scenarios.flightlog.reader import read_log
    out = tmp_path / "img.mcap"
    assert cli.main(["simulate", "atek", "-o", str(out), "--duration", "61.5", "--quiet",
                     "--jpeg-quality", "70"]) == 0
    log = read_log(out)
    for k in (1, 2):
        ims = log.cameras[k].images
        # cameras run in the coast from T+60 at 1 Hz: T+60 and T+61
        assert len(ims) == 2
        np.testing.assert_array_equal(ims.t_ns, log.cameras[k].truth.t_ns)
        img = cv2.imdecode(np.frombuffer(bytes(ims[0]), np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (1080, 1920, 3)
