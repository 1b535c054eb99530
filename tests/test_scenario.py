"""Scenario files: the library loads, and bad input gives a clear UserError naming file and key."""
import pytest

from scenarios import cli
from scenarios.errors import UserError
from scenarios.sim.scenario import LIBRARY_DIR, library, library_names, load_scenario

ATEK_TEXT = (LIBRARY_DIR / "atek.toml").read_text()


def test_library_lists_and_loads_every_scenario():
    names = library_names()
    assert {"atek", "atek-nav-grade", "high-apogee"} <= set(names)
    for name, desc in library():
        assert desc and "\n" not in desc
        sc = load_scenario(name)
        assert sc.name == name and sc.toml_text


def test_atek_facts():
    sc = load_scenario("atek")
    assert sc.launch.time_utc == "2019-06-13T02:21:00Z"
    assert abs(sc.launch.lat_deg - 67.89) < 0.01 and abs(sc.launch.lon_deg - 21.10) < 0.01
    assert (sc.imu.rate_hz, sc.imu.gyro_range_dps, sc.imu.gyro_resolution_dps) == (20.0, 1000.0, 0.03)
    assert len(sc.cameras) == 2 and {c.depression_deg for c in sc.cameras} == {20.0}
    assert abs(sc.cameras[0].azimuth_deg - sc.cameras[1].azimuth_deg) == 180.0  # opposite sides
    ng = load_scenario("atek-nav-grade")
    assert ng.imu.rate_hz == 400.0 and ng.imu.gyro_range_dps == 2000.0


def _write(tmp_path, text, name="bad.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("edit, expect", [
    (lambda s: s.replace("rate_hz = 20.0", "rate_hz = 20.0\nrate_hz_typo = 3"), "imu.rate_hz_typo"),
    (lambda s: s.replace("rate_hz = 20.0", 'rate_hz = "fast"'), "imu.rate_hz"),
    (lambda s: s.replace("rate_hz = 20.0", "rate_hz = -20.0"), "imu.rate_hz"),
    (lambda s: s.replace("rate_hz = 20.0", "rate_hz = 7.0"), "must divide"),
    (lambda s: s.replace('output = "rate"', 'output = "degrees"'), "imu.output"),
    (lambda s: s.replace("tipoff_dps = [0.3, -4.56, -2.06]", "tipoff_dps = [0.3, -4.56]"), "spin.tipoff_dps"),
    (lambda s: s.replace("enabled = true", "enabled = 1", 1), "rcs.enabled"),
    (lambda s: s.replace('intrinsics = "atek_gopro"', 'intrinsics = "no_such_camera"', 1), "cameras[0].intrinsics"),
    (lambda s: s.replace('time_utc = "2019-06-13T02:21:00Z"', 'time_utc = "yesterday"'), "launch.time_utc"),
    (lambda s: s.replace("[gps]", "[gpss]"), "gpss"),
    (lambda s: s.replace("propellant_kg = 620.0", "propellant_kg = -1.0"), "vehicle.stages[0].propellant_kg"),
    (lambda s: s + "\n[imu\n", "not valid TOML"),
])
def test_bad_input_names_file_and_key(tmp_path, edit, expect):
    p = _write(tmp_path, edit(ATEK_TEXT))
    with pytest.raises(UserError) as e:
        load_scenario(p)
    msg = str(e.value)
    assert str(p) in msg and expect in msg, msg


def test_unknown_scenario_name():
    with pytest.raises(UserError, match="not a library scenario.*atek"):
        load_scenario("no-such-flight")


def test_cli_prints_one_line_without_traceback(tmp_path, capsys):
    p = _write(tmp_path, ATEK_TEXT.replace("[imu]", "[imu]\nbogus = 1"))
    assert cli.main(["simulate", str(p), "-o", str(tmp_path / "x.mcap"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "imu.bogus" in err and str(p) in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.mcap").exists()


def test_scenarios_command_lists_library(capsys):
    assert cli.main(["scenarios"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert any(line.startswith("atek ") and "238 km" in line for line in out)
    assert len(out) == len(library_names())
