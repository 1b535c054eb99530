"""Importing real flights (scenarios/importer, docs/import.md).

Truth: a simulated ATEK flight (120 s, scenarios.sim.simulate) written as a log, exported to CSV +
image folders + videos, re-imported. Tolerances:

* CSV text written with the shortest round-trip float representation (Arrow, like ``repr``) and
  integer-ns times reads back bit-identical: asserted with ``array_equal``.
* A unit factor is one float multiplication each way (x * (180/pi) then * (pi/180)): at most a few
  ulp, asserted at 4e-16 relative per component (plus 1e-300 absolute for exact zeros).
* A rotation matrix for the axes: a 3-term dot product, error <= ~3 ulp of |v|: 1e-15 |v|.
* Geodetic GPS: ECEF -> (lat, lon, h) -> ECEF through nav.earth (Bowring to 1e-15 rad): 1e-6 m;
  NED velocities: two rotations, 1e-9 m/s.
* Images from a JPEG folder: byte-identical. Video: re-encoded by OpenCV's mp4v (MPEG-4 part 2,
  default bitrate) and then JPEG (quality 95): PSNR measured 39.4-41.0 dB on the rendered frames
  (printed by test_round_trip_video_psnr); asserted >= 30 dB (a margin for other FFmpeg builds).
"""
from __future__ import annotations

from pathlib import Path

import re

import cv2

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv
import pytest

from nav import earth
from nav.timescales import format_utc, utc_to_gps_ns
from scenarios.cli import main
from scenarios.cli.simulate import write_log
from scenarios.errors import UserError
from scenarios.importer.build import ValidationFailed, import_flight
from scenarios.importer.export import export_log
from scenarios.importer.footage import check_jpeg, jpeg_structure
from scenarios.importer.mapping import load_mapping
from scenarios.flightlog.reader import read_log
from scenarios.flightlog.writer import LogWriter
from scenarios.sim.render import (DEFAULT_PAYLOAD_MASK, RenderOptions, flight_frame_truths, payload_mask,
                              render_flight_frames)
from scenarios.sim.scenario import load_scenario
from scenarios.sim.simulate import simulate_flight

T0 = 1_560_392_460_000_000_000  # 2019-06-13T02:21:00Z
G0 = 9.80665


def synthetic_jpeg(w, h, i, quality=90) -> bytes:
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.stack([xx * 255 // w, yy * 255 // h, np.full_like(xx, 40 * i)], -1).astype(np.uint8)
    cv2.circle(img, (w // 3 + 50 * i, h // 2), h // 6, (255, 255, 255), -1)
    ok, b = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return b.tobytes()


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """Simulated 120 s ATEK flight with 4 rendered frames per camera (T+60..63; coarse cloud map to
    keep it fast), its log and its export."""
    d = tmp_path_factory.mktemp("import")
    fl = simulate_flight(load_scenario("atek"), 3, 120.0)
    recs = flight_frame_truths(fl)
    sel = [r for i in range(len(fl.cameras)) for r in [q for q in recs if q.camera_index == i][:4]]
    frames = render_flight_frames([c.camera for c in fl.cameras], sel, seed=3, progress=False,
                                  options=RenderOptions(cloud_map_size=128))
    masks = {c.k: payload_mask(c.camera, DEFAULT_PAYLOAD_MASK) for c in fl.cameras}
    log = write_log(fl, d / "sim.mcap", images=((fl.cameras[i].k, t, b) for i, t, b in frames), masks=masks)
    exp = export_log(log, d / "exp")
    return {"dir": d, "log": log, "exp": exp, "flight": fl, "orig": read_log(log)}


def _csv(path, cols):
    pcsv.write_csv(pa.table(cols), path)


def _mapping(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------------------------
# round trip
def test_round_trip_tables_and_image_folder_are_exact(flight):
    d = flight["dir"]
    res = import_flight(flight["exp"].files["mapping"], d / "back.mcap", report_dir=d / "report")
    a, b = flight["orig"], read_log(d / "back.mcap")
    assert np.array_equal(a.imu.t_ns, b.imu.t_ns)
    assert np.array_equal(a.imu.gyro, b.imu.gyro) and np.array_equal(a.imu.accel, b.imu.accel)
    for f in ("t_ns", "position", "velocity", "position_covariance", "velocity_covariance", "num_satellites"):
        assert np.array_equal(getattr(a.gps, f), getattr(b.gps, f)), f
    assert b.info["kind"] == "real" and int(b.info["liftoff_utc_ns"]) == T0 and b.complete
    for k, ca in a.cameras.items():
        cb = b.cameras[k]
        assert np.array_equal(ca.images.t_ns, cb.images.t_ns)
        assert all(x == y for x, y in zip(ca.images, cb.images)) and len(cb.images) == 4  # byte-identical
        assert np.array_equal(ca.info.k, cb.info.k) and np.array_equal(ca.info.d, cb.info.d)
        assert np.array_equal(a.tf_static[f"camera_{k}"].q, b.tf_static[f"camera_{k}"].q)
        ma, mb = (cv2.imdecode(np.frombuffer(x.other[f"/camera_{k}/payload_mask"][1][0], np.uint8),
                               cv2.IMREAD_GRAYSCALE) for x in (a, b))
        assert np.array_equal(ma, mb) and 0.01 < (mb > 0).mean() < 0.2   # the payload mask, exactly
    assert res.counts == {"imu": 2400, "gps": 1201, "camera_1": 4, "camera_2": 4}
    # report: files written; the spin saturates gyro x at 1000 deg/s (range, quantised to 0.03)
    assert (d / "report" / "report.json").exists() and (d / "report" / "report.png").stat().st_size > 10_000
    sat = [f for f in res.report.findings if f.check == "saturation"]
    assert len(sat) == 1 and "gyro x" in sat[0].message, [f.message for f in sat]
    # the clipped value is the 1000 deg/s range on the 0.03 deg/s grid: within one quantum of it
    top = float(re.search(r"= ([0-9.]+) deg/s", sat[0].message).group(1))
    assert 1000.0 - 0.03 <= top <= 1000.0, top
    assert not res.report.errors


def test_round_trip_video_psnr(flight):
    d = flight["dir"]
    import_flight(flight["exp"].files["mapping_video"], d / "video.mcap")
    a, b = flight["orig"], read_log(d / "video.mcap")
    psnr = []
    for k, ca in a.cameras.items():
        cb = b.cameras[k]
        assert np.array_equal(ca.images.t_ns, cb.images.t_ns) and len(cb.images) == 4
        for x, y in zip(ca.images, cb.images):
            ia = cv2.imdecode(np.frombuffer(x, np.uint8), cv2.IMREAD_COLOR).astype(float)
            ib = cv2.imdecode(np.frombuffer(y, np.uint8), cv2.IMREAD_COLOR).astype(float)
            psnr.append(10 * np.log10(255.0 ** 2 / np.mean((ia - ib) ** 2)))
    print(f"\nvideo round trip PSNR: min {min(psnr):.2f} dB, max {max(psnr):.2f} dB")
    assert min(psnr) >= 30.0


def test_round_trip_through_units_axes_and_time_bases(flight, tmp_path):
    """The exported data rewritten as a sensor would log it: gyro in deg/s, accel in g, sensor axes
    (body x = sensor +z, y = -x, z = -y), T+ seconds; GPS geodetic in deg with NED velocities and
    ISO-8601 stamps; a second IMU copy through a general rotation matrix."""
    a = flight["orig"]
    t, w, f = a.imu.t_ns, a.imu.gyro, a.imu.accel
    # sensor frame: v_s = R_sb v_b with R_bs rows = body axes in sensor coordinates
    R_bs = np.array([[0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0]])
    ws, fs = w @ R_bs, f @ R_bs  # v_s = R_bs^T v_b  (row vectors)
    tplus = (t - T0) / 1e9
    _csv(tmp_path / "imu.csv", {"T+ [s]": tplus, "wx": np.degrees(ws[:, 0]), "wy": np.degrees(ws[:, 1]),
                                "wz": np.degrees(ws[:, 2]), "fx": fs[:, 0] / G0, "fy": fs[:, 1] / G0, "fz": fs[:, 2] / G0})
    ang = np.radians(30.0)
    R2 = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1.0]])  # R_bs
    w2, f2 = w @ R2, f @ R2
    _csv(tmp_path / "imu2.csv", {"t": t, "gx": w2[:, 0], "gy": w2[:, 1], "gz": w2[:, 2],
                                 "ax": f2[:, 0], "ay": f2[:, 1], "az": f2[:, 2]})
    g = a.gps
    lat, lon, h = earth.ecef_to_geodetic(g.position)
    vn = np.einsum("nji,nj->ni", earth.R_en(lat, lon), g.velocity)  # R_ne v_e
    _csv(tmp_path / "gps.csv", {"time": [format_utc(int(x), 9) for x in g.t_ns], "lat": np.degrees(lat),
                                "lon": np.degrees(lon), "alt_km": h / 1e3, "vn": vn[:, 0], "ve": vn[:, 1], "vd": vn[:, 2]})
    m = _mapping(tmp_path / "m.toml", """
liftoff_utc = "2019-06-13T02:21:00Z"
[imu]
file = "imu.csv"
time = { column = "T+ [s]", base = "mission", unit = "s" }
gyro = { columns = ["wx", "wy", "wz"], unit = "deg/s" }
accel = { columns = ["fx", "fy", "fz"], unit = "g" }
axes = ["+z", "-x", "-y"]
[gps]
file = "gps.csv"
time = { column = "time", base = "iso" }
position = { frame = "geodetic", columns = ["lat", "lon", "alt_km"], angle_unit = "deg", unit = "km" }
velocity = { frame = "ned", columns = ["vn", "ve", "vd"], unit = "m/s" }
position_sigma = { value = 3.0, unit = "m" }
""")
    import_flight(m, tmp_path / "conv.mcap")
    b = read_log(tmp_path / "conv.mcap")
    assert np.array_equal(b.imu.t_ns, t)  # T+ float seconds with repr -> ns exactly
    assert np.all(np.abs(b.imu.gyro - w) <= 4e-16 * np.abs(w) + 1e-300)
    assert np.all(np.abs(b.imu.accel - f) <= 4e-16 * np.abs(f) + 1e-300)
    assert np.array_equal(b.gps.t_ns, g.t_ns)
    assert np.max(np.abs(b.gps.position - g.position)) < 1e-6
    assert np.max(np.abs(b.gps.velocity - g.velocity)) < 1e-9
    # sigma 3 m in NED -> ECEF: R diag(9) R^T = 9 I
    assert np.allclose(b.gps.position_covariance, 9.0 * np.eye(3), atol=1e-14)
    m2 = _mapping(tmp_path / "m2.toml", """
liftoff_utc = "2019-06-13T02:21:00Z"
[imu]
file = "imu2.csv"
time = { column = "t", base = "unix", unit = "ns" }
gyro = { columns = ["gx", "gy", "gz"], unit = "rad/s" }
accel = { columns = ["ax", "ay", "az"], unit = "m/s^2" }
axes = { matrix = [[0.8660254037844387, -0.49999999999999994, 0.0], [0.49999999999999994, 0.8660254037844387, 0.0], [0.0, 0.0, 1.0]] }
""")
    import_flight(m2, tmp_path / "rot.mcap")
    c = read_log(tmp_path / "rot.mcap")
    assert np.all(np.abs(c.imu.gyro - w) <= 1e-15 * np.linalg.norm(w, axis=1, keepdims=True) + 1e-300)
    assert np.all(np.abs(c.imu.accel - f) <= 1e-15 * np.linalg.norm(f, axis=1, keepdims=True) + 1e-300)


def test_increment_imu_and_gps_week_time(tmp_path):
    """Increment output with a dt column, stamps as GPS week + seconds of week (independent truth:
    nav.timescales.utc_to_gps_ns), round trip through export."""
    n = 400
    t = T0 + np.arange(1, n + 1, dtype=np.int64) * 2_500_000
    rng = np.random.default_rng(1)
    da, dv = rng.normal(0, 1e-4, (n, 3)), rng.normal(0, 1e-3, (n, 3)) + [0.0245, 0, 0]
    with LogWriter(tmp_path / "inc.mcap", {"scenario": "", "seed": 0, "liftoff_utc_ns": T0, "kind": "simulated"}) as w:
        w.write_imu_increment(t, da, dv, 0.0025)
    exp = export_log(tmp_path / "inc.mcap", tmp_path / "exp")
    import_flight(exp.files["mapping"], tmp_path / "back.mcap")
    b = read_log(tmp_path / "back.mcap")
    s = b.imu_increment
    assert np.array_equal(s.t_ns, t) and np.array_equal(s.delta_angle, da) and np.array_equal(s.delta_velocity, dv)
    assert np.array_equal(s.dt, np.full(n, 0.0025))
    gps = utc_to_gps_ns(t)
    week, sow = np.divmod(gps, 604800 * 10**9)
    _csv(tmp_path / "gw.csv", {"week": week, "sow": sow / 1e9, "dax": da[:, 0], "day": da[:, 1], "daz": da[:, 2],
                               "dvx": dv[:, 0], "dvy": dv[:, 1], "dvz": dv[:, 2]})
    m = _mapping(tmp_path / "gw.toml", """
liftoff_utc = "2019-06-13T02:21:00Z"
[imu]
file = "gw.csv"
sample = "increment"
time = { column = "sow", base = "gps_week", week_column = "week" }
gyro = { columns = ["dax", "day", "daz"], unit = "rad" }
accel = { columns = ["dvx", "dvy", "dvz"], unit = "m/s" }
""")
    import_flight(m, tmp_path / "gw.mcap")
    s = read_log(tmp_path / "gw.mcap").imu_increment
    assert np.array_equal(s.t_ns, t)  # sow < 604800 s in float64: 1e-10 s resolution, rounds to the ns
    assert np.allclose(s.dt, 0.0025, rtol=0, atol=1e-15)  # from the stamps (first: the median step)


# ------------------------------------------------------------------------------------------------
# unit plausibility
def _imu_mapping(tmp_path, gyro_unit, accel_unit, name="m.toml", extra=""):
    return _mapping(tmp_path / name, f"""
liftoff_utc = "2019-06-13T02:21:00Z"
[imu]
file = "imu.csv"
time = {{ column = "t", base = "mission", unit = "s" }}
gyro = {{ columns = ["gx", "gy", "gz"], unit = "{gyro_unit}" }}
accel = {{ columns = ["ax", "ay", "az"], unit = "{accel_unit}" }}
{extra}""")


def test_gyro_in_deg_s_declared_rad_s_is_caught(flight, tmp_path):
    a = flight["orig"]
    wd = np.degrees(a.imu.gyro)
    _csv(tmp_path / "imu.csv", {"t": (a.imu.t_ns - T0) / 1e9, "gx": wd[:, 0], "gy": wd[:, 1], "gz": wd[:, 2],
                                "ax": a.imu.accel[:, 0], "ay": a.imu.accel[:, 1], "az": a.imu.accel[:, 2]})
    with pytest.raises(ValidationFailed, match="gyro_units.*deg/s declared as 'rad/s'") as ei:
        import_flight(_imu_mapping(tmp_path, "rad/s", "m/s^2"), tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists() and not list(tmp_path.glob(".out.mcap*"))
    assert [f.check for f in ei.value.report.errors] == ["gyro_units"]
    # declared right: no error
    res = import_flight(_imu_mapping(tmp_path, "deg/s", "m/s^2", "ok.toml"), tmp_path / "ok.mcap")
    assert not res.report.errors


def test_gyro_coast_in_deg_s_caught_by_quiet_percentile(tmp_path):
    """A spinning coast (20 deg/s about x, no spin-up in the record): deg/s read as rad/s gives a
    quiet tenth of ~20 'rad/s'."""
    n = 2000
    rng = np.random.default_rng(2)
    wd = np.column_stack([np.full(n, 20.0), rng.normal(0, 0.5, n), rng.normal(0, 0.5, n)])
    _csv(tmp_path / "imu.csv", {"t": np.arange(n) / 20.0 + 70.0, "gx": wd[:, 0], "gy": wd[:, 1], "gz": wd[:, 2],
                                "ax": rng.normal(0, 0.02, n), "ay": rng.normal(0, 0.02, n), "az": rng.normal(0, 0.02, n)})
    with pytest.raises(ValidationFailed, match="quietest tenth"):
        import_flight(_imu_mapping(tmp_path, "rad/s", "m/s^2"), tmp_path / "o.mcap")


def _pad_then_coast(tmp_path, accel_scale):
    """60 s on the pad (|f| = g along x, gyro noise 1e-4 rad/s) then 60 s of free fall, 100 Hz."""
    n = 12000
    rng = np.random.default_rng(3)
    f = np.zeros((n, 3))
    f[:6000, 0] = G0
    f += rng.normal(0, 0.01, (n, 3))
    w = rng.normal(0, 1e-4, (n, 3))
    f = f / accel_scale
    _csv(tmp_path / "imu.csv", {"t": np.arange(n) / 100.0 - 60.0, "gx": w[:, 0], "gy": w[:, 1], "gz": w[:, 2],
                                "ax": f[:, 0], "ay": f[:, 1], "az": f[:, 2]})


def test_accel_in_g_declared_m_s2_is_caught(tmp_path):
    _pad_then_coast(tmp_path, G0)  # file in g
    with pytest.raises(ValidationFailed, match="accel_units.*1 m/s\\^2.*looks like 'g' declared as 'm/s\\^2'"):
        import_flight(_imu_mapping(tmp_path, "rad/s", "m/s^2"), tmp_path / "o.mcap")
    res = import_flight(_imu_mapping(tmp_path, "rad/s", "g", "ok.toml"), tmp_path / "ok.mcap")
    acc = [f for f in res.report.findings if f.check == "accel_units"]
    assert acc[0].level == "info" and "plausible" in acc[0].message


def test_accel_in_m_s2_declared_g_is_caught(tmp_path):
    _pad_then_coast(tmp_path, 1.0)  # file in m/s^2
    with pytest.raises(ValidationFailed, match="looks like 'm/s\\^2' declared as 'g'"):
        import_flight(_imu_mapping(tmp_path, "rad/s", "g"), tmp_path / "o.mcap")
    # --force writes it anyway
    res = import_flight(_imu_mapping(tmp_path, "rad/s", "g"), tmp_path / "o.mcap", force=True)
    assert res.report.errors and read_log(tmp_path / "o.mcap").complete


def test_gps_implausible_heights_and_velocity_units(flight, tmp_path):
    g = flight["orig"].gps
    _csv(tmp_path / "gps.csv", {"t": g.t_ns, "x": g.position[:, 0] / 1e3, "y": g.position[:, 1] / 1e3,
                                "z": g.position[:, 2] / 1e3, "vx": g.velocity[:, 0] / 1e3,
                                "vy": g.velocity[:, 1] / 1e3, "vz": g.velocity[:, 2] / 1e3})
    text = """
liftoff_utc = "2019-06-13T02:21:00Z"
[gps]
file = "gps.csv"
time = {{ column = "t", base = "unix", unit = "ns" }}
position = {{ frame = "ecef", columns = ["x", "y", "z"], unit = "{pu}" }}
velocity = {{ frame = "ecef", columns = ["vx", "vy", "vz"], unit = "{vu}" }}
"""
    with pytest.raises(ValidationFailed, match="not an ECEF position in metres"):
        import_flight(_mapping(tmp_path / "a.toml", text.format(pu="m", vu="km/s")), tmp_path / "o.mcap")
    res = import_flight(_mapping(tmp_path / "b.toml", text.format(pu="km", vu="m/s")), tmp_path / "o.mcap")
    v = [f for f in res.report.findings if f.check == "velocity_consistency"][0]
    assert v.level == "warning" and "0.000998" in v.message
    res = import_flight(_mapping(tmp_path / "c.toml", text.format(pu="km", vu="km/s")), tmp_path / "o.mcap")
    assert not res.report.warnings or all(f.check != "velocity_consistency" for f in res.report.warnings)


# ------------------------------------------------------------------------------------------------
# bad input
def _small_imu(tmp_path, t=None, header=("t", "gx", "gy", "gz", "ax", "ay", "az"), rows=None):
    t = np.arange(50) / 20.0 if t is None else t
    lines = [",".join(header)]
    for i, ti in enumerate(t):
        lines.append(rows[i] if rows and i in rows else f"{float(ti)!r},0.001,0.002,0.003,0.01,0.02,0.03")
    (tmp_path / "imu.csv").write_text("\n".join(lines) + "\n")


def test_missing_column_names_file_and_column(tmp_path):
    _small_imu(tmp_path, header=("t", "gx", "gy", "gz", "ax", "ay", "acc_z"))
    with pytest.raises(UserError, match=r"imu\.csv: missing column\(s\) \['az'\].*the file has"):
        import_flight(_imu_mapping(tmp_path, "rad/s", "m/s^2"), tmp_path / "o.mcap")


def test_non_monotonic_time_names_row_and_sort_option(tmp_path):
    t = np.arange(50) / 20.0
    t[30], t[31] = t[31], t[30]
    _small_imu(tmp_path, t)
    with pytest.raises(UserError, match=r"imu\.csv: time stamps are not increasing.*row 32 \(line 33\) goes back"):
        import_flight(_imu_mapping(tmp_path, "rad/s", "m/s^2"), tmp_path / "o.mcap")
    assert not (tmp_path / "o.mcap").exists()
    m = _mapping(tmp_path / "s.toml", (tmp_path / "m.toml").read_text().replace("[imu]", '[imu]\nunsorted = "sort"'))
    res = import_flight(m, tmp_path / "o.mcap")
    assert np.array_equal(read_log(tmp_path / "o.mcap").imu.t_ns, T0 + np.round(np.arange(50) / 20.0 * 1e9).astype(np.int64))
    assert any(f.check == "order" for f in res.report.warnings)


def test_bad_cell_names_column_and_row(tmp_path):
    _small_imu(tmp_path, rows={7: "0.35,0.001,abc,0.003,0.01,0.02,0.03"})
    with pytest.raises(UserError, match=r"imu\.csv: column 'gy' row 8 \(line 9\): 'abc' is not a number"):
        import_flight(_imu_mapping(tmp_path, "rad/s", "m/s^2"), tmp_path / "o.mcap")
    _small_imu(tmp_path, rows={9: "0.45,0.001,,0.003,0.01,0.02,0.03"})
    with pytest.raises(UserError, match=r"column 'gy' row 10 \(line 11\): empty or NaN"):
        import_flight(_imu_mapping(tmp_path, "rad/s", "m/s^2"), tmp_path / "o.mcap")


def test_mixed_units_in_column_names(tmp_path):
    _small_imu(tmp_path, header=("t", "gx [deg/s]", "gy [rad/s]", "gz [deg/s]", "ax", "ay", "az"))
    m = _mapping(tmp_path / "m.toml", """
liftoff_utc = "2019-06-13T02:21:00Z"
[imu]
file = "imu.csv"
time = { column = "t", base = "mission", unit = "s" }
gyro = { columns = ["gx [deg/s]", "gy [rad/s]", "gz [deg/s]"], unit = "deg/s" }
accel = { columns = ["ax", "ay", "az"], unit = "m/s^2" }
""")
    with pytest.raises(UserError, match=r"m\.toml: imu\.gyro: mixed units.*'gy \[rad/s\]' \(rad/s\)"):
        load_mapping(m)
    m.write_text(m.read_text().replace("gy [rad/s]", "gy [deg/s]").replace('unit = "deg/s"', 'unit = "rad/s"'))
    with pytest.raises(UserError, match=r"column 'gx \[deg/s\]' states unit deg/s but the mapping declares unit = 'rad/s'"):
        load_mapping(m)
    m.write_text(m.read_text().replace('unit = "rad/s"', 'unit = "deg/s"').replace('unit = "m/s^2"', 'unit = "deg/s"'))
    with pytest.raises(UserError, match=r"imu\.accel: unit 'deg/s' is not a unit of acceleration \('deg/s' is a unit of angular rate\)"):
        load_mapping(m)


def test_mapping_errors_name_key(tmp_path):
    _small_imu(tmp_path)
    m = _imu_mapping(tmp_path, "rad/s", "m/s^2", extra='axes = ["+x", "+y", "-z"]\n')
    with pytest.raises(UserError, match=r"\[imu\.axes\]: axes = .* is a reflection"):
        load_mapping(m)
    m = _imu_mapping(tmp_path, "rad/s", "m/s^2", extra='gyro_rnage = 10.0\n')
    with pytest.raises(UserError, match=r"m\.toml \[imu\]: unknown key\(s\) \['gyro_rnage'\]"):
        load_mapping(m)


def _camera_file(tmp_path, w=64, h=48):
    (tmp_path / "cam.toml").write_text(f"""[camera]
width = {w}
height = {h}
fx = 40.0
fy = 40.0
cx = {(w - 1) / 2}
cy = {(h - 1) / 2}
k = [1.0, 0.05]
""")


def _camera_mapping(tmp_path, footage: str) -> Path:
    return _mapping(tmp_path / "c.toml", f"""
liftoff_utc = "2019-06-13T02:21:00Z"
[imu]
file = "imu.csv"
time = {{ column = "t", base = "mission", unit = "s" }}
gyro = {{ columns = ["gx", "gy", "gz"], unit = "rad/s" }}
accel = {{ columns = ["ax", "ay", "az"], unit = "m/s^2" }}
[[cameras]]
camera_file = "cam.toml"
mount = {{ azimuth_deg = 90.0, depression_deg = 20.0 }}
[cameras.footage]
{footage}
""")


def test_payload_mask_of_the_wrong_size_names_the_key(tmp_path):
    _camera_file(tmp_path)
    _small_imu(tmp_path)
    m = _camera_mapping(tmp_path, 'images = "frames"\nstart_s = 0.0\nrate_hz = 1.0')
    m.write_text(m.read_text().replace('camera_file = "cam.toml"', 'camera_file = "cam.toml"\npayload_mask = "mask.png"'))
    (tmp_path / "frames").mkdir()
    cv2.imwrite(str(tmp_path / "frames" / "f0.jpg"), np.zeros((48, 64, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "mask.png"), np.zeros((10, 10), np.uint8))
    with pytest.raises(UserError, match=r"payload_mask: .*mask.png: 10x10 px, expected the camera file's 64x48"):
        import_flight(m, tmp_path / "o.mcap")


def test_video_shorter_than_declared_and_keep_partial(tmp_path):
    _small_imu(tmp_path, np.arange(200) / 20.0)  # 10 s of IMU
    _camera_file(tmp_path)
    vw = cv2.VideoWriter(str(tmp_path / "v.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 1.0, (64, 48))
    for i in range(3):
        vw.write(cv2.imdecode(np.frombuffer(synthetic_jpeg(64, 48, i), np.uint8), cv2.IMREAD_COLOR))
    vw.release()
    m = _camera_mapping(tmp_path, 'video = "v.avi"\nstart_s = 0.0\nrate_hz = 1.0\nduration_s = 8.0')
    with pytest.raises(UserError, match=r"v\.avi: the video has 3 frames but the mapping declares duration_s = 8\.0"):
        import_flight(m, tmp_path / "o.mcap")
    assert not (tmp_path / "o.mcap").exists()
    # the container's count is right but a frame cannot be decoded: found while writing
    m = _camera_mapping(tmp_path, 'video = "v.avi"\nstart_s = 0.0\nrate_hz = 1.0')
    res = import_flight(m, tmp_path / "ok.mcap")
    assert res.counts["camera_1"] == 3
    b = read_log(tmp_path / "ok.mcap")
    assert np.array_equal(b.cameras[1].images.t_ns, T0 + np.arange(3) * 10**9)


def test_corrupted_frame_in_image_folder(tmp_path):
    _small_imu(tmp_path, np.arange(200) / 20.0)
    _camera_file(tmp_path)
    (tmp_path / "img").mkdir()
    for i in range(6):
        (tmp_path / "img" / f"f_{i:03d}.jpg").write_bytes(synthetic_jpeg(64, 48, i))
    bad = synthetic_jpeg(64, 48, 4)
    (tmp_path / "img" / "f_004.jpg").write_bytes(bad[:-50])  # truncated in the scan data
    m = _camera_mapping(tmp_path, 'images = "img"\nstart_s = 0.5\nrate_hz = 1.0')
    with pytest.raises(UserError, match=r"f_004\.jpg \(camera 1, .*\): truncated JPEG.*nothing written"):
        import_flight(m, tmp_path / "o.mcap")
    assert not (tmp_path / "o.mcap").exists() and not list(tmp_path.glob(".o.mcap*"))
    with pytest.raises(UserError, match="partial log kept"):
        import_flight(m, tmp_path / "o.mcap", keep_partial=True, window_s=2.0)
    p = read_log(tmp_path / "o.mcap")
    assert p.complete is False
    assert len(p.cameras[1].images) == 4 and len(p.imu.t_ns) >= 80  # every good frame, IMU to the failing window
    # wrong image size
    (tmp_path / "img" / "f_004.jpg").write_bytes(synthetic_jpeg(80, 48, 4))
    with pytest.raises(UserError, match=r"f_004\.jpg.*image is 80x48 px but the camera file says 64x48"):
        import_flight(m, tmp_path / "o2.mcap")


def test_image_folder_time_from_file_names_and_png_reencoded(tmp_path):
    _small_imu(tmp_path, np.arange(200) / 20.0)
    _camera_file(tmp_path)
    (tmp_path / "img").mkdir()
    stamps = T0 + np.array([500, 1500, 2500], np.int64) * 10**6
    for i, t in enumerate(stamps):
        img = cv2.imdecode(np.frombuffer(synthetic_jpeg(64, 48, i), np.uint8), cv2.IMREAD_COLOR)
        cv2.imwrite(str(tmp_path / "img" / f"cam1_{t}.png"), img)
    (tmp_path / "img" / "cam1_0001.jpg").write_bytes(synthetic_jpeg(64, 48, 9))  # no stamp match -> skipped
    m = _camera_mapping(tmp_path, 'images = "img"\nfilename_regex = "cam1_(\\\\d{19})"\n'
                                  'filename_time = { base = "unix", unit = "ns" }')
    res = import_flight(m, tmp_path / "o.mcap")
    fp = res.prepared.footages[0]
    assert fp.encoded == 3 and fp.passed_through == 0
    b = read_log(tmp_path / "o.mcap")
    assert np.array_equal(b.cameras[1].images.t_ns, stamps)
    assert jpeg_structure(b.cameras[1].images[0])[:2] == (64, 48)


def test_jpeg_checks():
    b = synthetic_jpeg(64, 48, 1)
    check_jpeg(b, 64, 48, "x", True)
    with pytest.raises(UserError, match="corrupted JPEG"):
        check_jpeg(b"\xff\xd8\x00\x00garbage", 64, 48, "x", True)
    with pytest.raises(UserError, match="truncated"):
        check_jpeg(b[:-2], 64, 48, "x", False)


def test_cli_import_check_report_and_one_line_error(flight, tmp_path, capsys):
    exp = flight["exp"].files["mapping"]
    assert main(["import", str(exp), "-o", str(tmp_path / "c.mcap"), "--report", str(tmp_path / "rep"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "2400 IMU samples, 1201 GPS fixes, 4 frames camera 1" in out
    assert (tmp_path / "rep" / "report.png").exists()
    assert main(["export", str(tmp_path / "c.mcap"), "-o", str(tmp_path / "e"), "--no-video"]) == 0
    assert (tmp_path / "e" / "camera_2" / "frame_000003.jpg").exists() and not (tmp_path / "e" / "camera_1.mp4").exists()
    _small_imu(tmp_path, header=("t", "gx", "gy", "gz", "ax", "ay", "acc_z"))
    capsys.readouterr()
    assert main(["import", str(_imu_mapping(tmp_path, "rad/s", "m/s^2")), "-o", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("horizon-nav import: error:") and "missing column" in err and err.count("\n") == 1


def test_library_examples_parse():
    """Every shipped example mapping parses (its files need not exist to parse)."""
    lib = Path(__file__).resolve().parents[1] / "scenarios" / "library" / "import"
    files = sorted(lib.glob("*.toml"))
    assert len(files) >= 4
    for f in files:
        m = load_mapping(f)
        assert m.imu is not None or m.gps is not None or m.cameras


def test_reimported_flight_replays_to_the_same_solution(flight, tmp_path):
    """Issue 9 round trip: the exported and re-imported flight (tables + image folder, and tables +
    video) replays through vision, filter and smoother like the original log. Both replays start
    from the same given state (the re-imported log has no truth) at T+60 and run to T+100 (4 frames
    per camera at T+60..63, then GPS).

    Tolerances: the image-folder import is byte-identical in every input, so the solutions must be
    identical to the last bit. The video import re-encodes the frames (PSNR ~40 dB, see
    test_round_trip_video_psnr): the vision vectors move by a fraction of their 1-sigma, so the
    attitude may differ by a small fraction of the filter's own sigma; asserted < 0.05 deg
    (sigma is ~1-2 deg at that point) and position < 0.5 m (GPS-dominated).
    """
    from scenarios.replay.pipeline import ReplayOptions, replay
    from nav.rotation import angle_between, quat_to_matrix

    d = flight["dir"]
    folder = d / "back.mcap"
    if not folder.exists():
        import_flight(flight["exp"].files["mapping"], folder)
    video = d / "video.mcap"
    if not video.exists():
        import_flight(flight["exp"].files["mapping_video"], video)
    tr = flight["orig"].truth
    i = int(np.searchsorted(tr.t_ns, T0 + 60 * 10**9))
    init = tmp_path / "init.toml"
    init.write_text(f'time = "T+60"\nq_eb = {list(map(float, tr.q_eb[i]))}\n')

    def run(path, name):
        opt = ReplayOptions(t_from="T+60", t_to="T+100", init="given", init_file=str(init), workers=1,
                            vision="images", output=str(tmp_path / f"{name}.solution.mcap"), rrd="",
                            progress=False)
        return replay(path, opt)

    a, b, c = run(flight["log"], "orig"), run(folder, "folder"), run(video, "video")
    assert a.vectors is not None and len(a.vectors.t_ns) > 0
    np.testing.assert_array_equal(a.nav.q_eb, b.nav.q_eb)
    np.testing.assert_array_equal(a.nav.x_e, b.nav.x_e)
    ang = angle_between(quat_to_matrix(a.nav.q_eb)[..., 0], quat_to_matrix(c.nav.q_eb)[..., 0])
    ang2 = angle_between(quat_to_matrix(a.nav.q_eb)[..., 1], quat_to_matrix(c.nav.q_eb)[..., 1])
    worst = np.degrees(max(ang.max(), ang2.max()))
    psi = a.nav.layout["psi"]
    sigma_min = np.degrees(np.sqrt(a.nav.P_diag[:, psi].max(axis=1)).min())
    print(f"smallest 1-sigma attitude bound of the run: {sigma_min:.3f} deg")
    assert worst < 3 * sigma_min
    assert np.abs(a.nav.x_e - c.nav.x_e).max() < 0.5


def test_saturation_check_tells_clipping_from_a_quantised_peak():
    """A 20 Hz rate quantised to 0.03 deg/s: a slow peak (0.011 deg/s^2 curvature scale, the atek
    coast's body y) holds its top value for seconds without clipping, while the same grid with a
    fast rise cut at a range is a clipped flat top. Only the second is reported. A rate that steps
    to a plateau below the floor (a tip-off) is not a range either."""
    from scenarios.importer.validate import Report, check_saturation
    q, fs = 0.03, 20.0
    t = np.arange(0, 60, 1 / fs)
    slow = 4.6 - 0.5 * 0.011 * (t - 30) ** 2 / 30          # peak 4.6 deg/s, changes ~1e-4 deg/s per sample at the top
    fast = np.clip(40.0 * np.sin(2 * np.pi * t / 20), -25.0, 25.0)  # 40 deg/s sine cut at +-25 deg/s
    for sig, expect in ((slow, 0), (fast, 1)):
        x = np.round((np.c_[sig, sig, sig] - 0.013) / q) * q + 0.013   # a grid off zero, as a real converter's
        rep = Report()
        check_saturation(rep, "imu", "gyro", np.radians(x), fs, None, "deg/s", np.radians(1.0))
        assert len(rep.findings) == 3 * expect, [f.message for f in rep.findings]
    step = np.where(t < 30, 0.0, np.where(t < 31, 4.57, np.maximum(4.57 - 1.5 * (t - 31), 0.0)))  # steps, holds 1 s, falls
    x = np.round((np.c_[step, step, step] - 0.013) / q) * q + 0.013
    rep = Report()
    check_saturation(rep, "imu", "gyro", np.radians(x), fs, None, "deg/s", np.radians(1.0), floor=0.5)
    assert rep.findings == []
    check_saturation(rep, "imu", "gyro", np.radians(x), fs, None, "deg/s", np.radians(1.0), floor=0.0)
    assert len(rep.findings) == 3      # without the floor its shape is a clipped one
    # the slow peak does hold: its top value lasts longer than the check's 0.25 s run
    xs = np.round((slow - 0.013) / q) * q + 0.013
    assert (xs == xs.max()).sum() > 5
