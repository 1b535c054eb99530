"""Tests of the MCAP flight-log format (scenarios/flightlog/format.py, writer.py, reader.py).

Truth sources: the values written (round trips must be bit-identical: CDR stores IEEE-754 float64
as is), the reference CDR codec of ``mcap_ros2`` (an independent implementation of the same
encoding), the ``mcap`` reader, and Rerun's MCAP importer.
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

from scenarios.flightlog import format as lf
from scenarios.errors import UserError
from scenarios.flightlog.reader import LogFormatError, LogWarning, read_log
from scenarios.flightlog.writer import LogWriter

T0 = 1_560_392_460_000_000_000  # 2019-06-13T02:21:00Z
META = {"scenario": "[flight]\nname = \"test\"\n", "seed": 7, "liftoff_utc_ns": T0, "kind": "simulated"}


def _data(rng, n_imu=2000):
    t_imu = T0 + np.arange(n_imu, dtype=np.int64) * 50_000_000 + 123  # 20 Hz, odd ns
    nv = 40
    t_cam = T0 + np.arange(nv, dtype=np.int64) * 100_000_000 + 7
    cov = rng.standard_normal((nv, 3, 3))
    ng = 30
    nn = 25
    nm = 6
    return {
        "imu": (t_imu, rng.standard_normal((n_imu, 3)), rng.standard_normal((n_imu, 3)) * 1e3),
        "inc": (t_imu[:50], rng.standard_normal((50, 3)), rng.standard_normal((50, 3)), np.full(50, 0.05)),
        "gps": (t_imu[::40][:ng], rng.standard_normal((ng, 3)) * 6e6, rng.standard_normal((ng, 3)) * 1e3,
                rng.standard_normal((ng, 3, 3)), rng.standard_normal((ng, 3, 3)),
                rng.integers(0, 20, ng).astype(np.uint16), rng.integers(-1, 3, ng).astype(np.int8)),
        "vec": (t_cam, list(rng.choice(["earth", "sun", "moon"], nv)), rng.standard_normal((nv, 3)), cov,
                cov * 2, rng.standard_normal(nv), rng.integers(0, 5000, nv).astype(np.uint32),
                rng.integers(0, 5000, nv).astype(np.uint32), list(rng.choice(["ellipse", "hyperbola", ""], nv)),
                rng.standard_normal(nv)),
        "truth": (t_imu[:100], rng.standard_normal((100, 3)), rng.standard_normal((100, 3)),
                  rng.standard_normal((100, 4)), rng.standard_normal((100, 3)), rng.standard_normal((100, 3))),
        "ctruth": (t_cam, rng.standard_normal((nv, 3)), rng.standard_normal((nv, 3)), rng.standard_normal((nv, 3)),
                   rng.random(nv) > 0.5, list(rng.choice(["ellipse", "hyperbola", ""], nv)), rng.random(nv) > 0.5,
                   rng.random(nv) > 0.5, rng.random(nv), rng.standard_normal((nv, 3)) * 1e-2),
        "nav": (t_imu[::10][:nn], rng.standard_normal((nn, 3)), rng.standard_normal((nn, 3)),
                rng.standard_normal((nn, 4)), rng.standard_normal((nn, 12, 12)), rng.standard_normal((nn, 5)),
                [f"s{i}" for i in range(12)]),
        "meas": (t_imu[5:5 + nm], ["gps", "camera_1/earth", "camera_2/sun", "gps", "camera_1/moon", "gps"],
                 rng.random(nm) > 0.5, ["", "nis gate", "", "outlier", "", ""],
                 [rng.standard_normal(m) for m in (6, 3, 3, 6, 3, 6)],
                 [rng.standard_normal(m * m) for m in (6, 3, 3, 6, 3, 6)], rng.random(nm) * 10),
        "K": np.array([[900.0, 0, 959.5], [0, 901.0, 539.5], [0, 0, 1]]),
        "D": np.array([-0.3, 0.1, 1e-4, -2e-4, -0.02]),
        "jpegs": [bytes(rng.integers(0, 256, 1000 + 37 * i, dtype=np.uint8)) for i in range(5)],
        "mask": rng.random((108, 192)) > 0.8,
    }


def _write_all(path, d, **kw):
    with LogWriter(path, META, **kw) as w:
        # deliberately out of time order across calls: the writer merges
        w.write_truth(*d["truth"])
        w.write_imu(*d["imu"])
        w.write_imu_increment(*d["inc"])
        t, p, v, pc, vc, ns, st = d["gps"]
        w.write_gps(t, p, v, pc, vc, ns, st)
        w.write_tf_static(T0, {1: ([0.1, 0.2, 0.3], [0, 0, 0.38268343236508984, 0.9238795325112867]),
                               2: ([-0.1, 0.2, 0.3], [0, 0, 0, 1.0])})
        for k in (1, 2):
            w.write_camera_info(k, T0 + k, 1920, 1080, d["K"] * k, d["D"], distortion_model="rational_polynomial")
            t, tg, vec, c, co, r, pcnt, icnt, ct, al = d["vec"]
            w.write_vectors(k, t, tg, vec, c, co, residual=r, pixel_count=pcnt, inlier_count=icnt, conic_type=ct,
                            alpha=al)
            w.write_camera_truth(k, *d["ctruth"])
            w.write_image(k, T0 + np.arange(5, dtype=np.int64) * 10**9 + k, d["jpegs"])
            w.write_payload_mask(k, T0 + k, d["mask"])
        t, p, v, q, cov, st, names = d["nav"]
        for topic in lf.NAV_TOPICS:
            w.write_nav(topic, t, p, v, q, cov, state=st, state_names=names)
        w.write_measurement(*d["meas"])


@pytest.fixture(scope="module")
def full_log(tmp_path_factory):
    rng = np.random.default_rng(42)
    d = _data(rng)
    path = tmp_path_factory.mktemp("logs") / "full.mcap"
    _write_all(path, d)
    return path, d


def _eq(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, (a.shape, b.shape)
    assert a.dtype.kind == b.dtype.kind or (a.dtype.kind in "iu" and b.dtype.kind in "iu"), (a.dtype, b.dtype)
    assert np.array_equal(a, b), (a, b)


def test_round_trip_every_topic_bit_identical(full_log):
    path, d = full_log
    with warnings.catch_warnings():
        warnings.simplefilter("error", LogWarning)  # a clean file gives no warning
        log = read_log(path)
    assert log.issues == []
    assert log.info["seed"] == "7" and log.info["kind"] == "simulated" and log.info["scenario"] == META["scenario"]
    assert log.info["liftoff_utc_ns"] == str(T0) and log.info["software_version"]
    assert log.complete is True
    t, g, a = d["imu"]
    _eq(log.imu.t_ns, t); _eq(log.imu.gyro, g); _eq(log.imu.accel, a)
    assert log.imu.t_ns.dtype == np.int64 and log.imu.gyro.dtype == np.float64
    assert set(log.imu.frame_id) == {"body"}
    _eq(log.imu.orientation_covariance[0], np.r_[-1.0, np.zeros(8)].reshape(3, 3))
    t, da, dv, dt = d["inc"]
    _eq(log.imu_increment.t_ns, t); _eq(log.imu_increment.delta_angle, da)
    _eq(log.imu_increment.delta_velocity, dv); _eq(log.imu_increment.dt, dt)
    t, p, v, pc, vc, ns, st = d["gps"]
    gps = log.gps
    _eq(gps.t_ns, t); _eq(gps.position, p); _eq(gps.velocity, v); _eq(gps.position_covariance, pc)
    _eq(gps.velocity_covariance, vc); _eq(gps.num_satellites, ns); _eq(gps.status, st)
    t, *vals = d["truth"]
    for name, val in zip(["position_e", "velocity_e", "q_eb", "angular_rate_b", "specific_force_b"], vals):
        _eq(getattr(log.truth, name), val)
    _eq(log.truth.t_ns, t)
    for k in (1, 2):
        cam = log.cameras[k]
        _eq(cam.info.k[0], d["K"] * k); _eq(cam.info.d[0], d["D"]); _eq(cam.info.width, [1920])
        _eq(cam.info.p[0], np.hstack([d["K"] * k, np.zeros((3, 1))])); _eq(cam.info.r[0], np.eye(3))
        assert cam.info.distortion_model[0] == "rational_polynomial"
        t, tg, vec, c, co, r, pcnt, icnt, ct, al = d["vec"]
        vv = cam.vectors
        _eq(vv.t_ns, t); assert list(vv.target) == tg; _eq(vv.vector, vec); _eq(vv.covariance, c)
        _eq(vv.covariance_overbound, co); _eq(vv.residual, r); _eq(vv.pixel_count, pcnt)
        _eq(vv.inlier_count, icnt); assert list(vv.conic_type) == ct; _eq(vv.alpha, al)
        assert set(vv.frame_id) == {f"camera_{k}"}
        ctr = d["ctruth"]
        for i, name in enumerate(["t_ns", "nadir_c", "sun_c", "moon_c", "horizon_visible", "conic_type",
                                  "sun_in_view", "moon_in_view", "earth_fraction", "misalignment"]):
            got = getattr(cam.truth, name)
            if name == "conic_type":
                assert list(got) == ctr[i]
            else:
                _eq(got, ctr[i])
        assert len(cam.images) == 5 and [cam.images[i] for i in range(5)] == d["jpegs"]
        _eq(cam.images.t_ns, T0 + np.arange(5) * 10**9 + k)
        assert cam.images.format(0) == "jpeg"
        t_m, m_stream = log.other[f"/camera_{k}/payload_mask"]     # PNG: lossless
        assert t_m.tolist() == [T0 + k] and m_stream.format(0) == "png; payload mask"
        m = cv2.imdecode(np.frombuffer(m_stream[0], np.uint8), cv2.IMREAD_GRAYSCALE)
        np.testing.assert_array_equal(m > 0, d["mask"])
        tf = log.tf_static[f"camera_{k}"]
        assert tf.parent == "body" and tf.t_ns == T0
    _eq(log.tf_static["camera_1"].q, [0, 0, 0.38268343236508984, 0.9238795325112867])
    _eq(log.tf_static["camera_2"].translation, [-0.1, 0.2, 0.3])
    t, p, v, q, cov, st, names = d["nav"]
    assert set(log.nav) == {"forward", "smoothed", "ins_unaided"}
    for s in log.nav.values():
        _eq(s.t_ns, t); _eq(s.position_e, p); _eq(s.velocity_e, v); _eq(s.q_eb, q); _eq(s.covariance, cov)
        _eq(s.state, st); assert s.state_names == names
    t, src, used, reason, inn, innc, nis = d["meas"]
    m = log.measurements
    _eq(m.t_ns, t); assert list(m.source) == src; _eq(m.used, used); assert list(m.reason) == reason
    for i in range(len(t)):
        _eq(m.innovation[i], inn[i])
        _eq(m.innovation_covariance[i], innc[i].reshape(len(inn[i]), -1))
    _eq(m.nis, nis)


def test_file_is_time_ordered_and_stamps_equal_log_time(full_log):
    """Every message's header.stamp = log_time = publish_time, the file in log_time order; checked
    with the `mcap` reader and mcap_ros2's decoder (not our code)."""
    path, _ = full_log
    times = []
    dec = DecoderFactory()
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[dec])
        for schema, channel, message, ros in reader.iter_decoded_messages(log_time_order=False):
            times.append(message.log_time)
            assert message.publish_time == message.log_time
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            assert schema.name == lf.ros2_name(lf.type_of_topic(channel.topic))
            if channel.topic != "/tf_static":
                st = ros.header.stamp
                assert st.sec * 10**9 + st.nanosec == message.log_time
        md = {m.name: m.metadata for m in reader.iter_metadata()}
    assert np.all(np.diff(times) >= 0)
    assert md["horizon-nav"]["seed"] == "7" and md["horizon-nav.status"]["complete"] == "true"


def test_reference_decoder_gives_the_same_values(full_log):
    """The mcap reader with mcap_ros2's decoder factory (schema-aware, independent CDR decoder) sees
    the values we wrote."""
    path, d = full_log
    got: dict[str, list] = {}
    with open(path, "rb") as f:
        for _, channel, _, ros in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got.setdefault(channel.topic, []).append(ros)
    t, g, a = d["imu"]
    imu = got["/imu"]
    _eq([[x.angular_velocity.x, x.angular_velocity.y, x.angular_velocity.z] for x in imu], g)
    _eq([[x.linear_acceleration.x, x.linear_acceleration.y, x.linear_acceleration.z] for x in imu], a)
    assert {x.header.frame_id for x in imu} == {"body"} and imu[0].orientation.w == 1.0
    vec = got["/camera_2/vectors"]
    assert [x.target for x in vec] == d["vec"][1] and [x.conic_type for x in vec] == d["vec"][8]
    _eq([x.covariance for x in vec], d["vec"][3].reshape(-1, 9))
    _eq([x.pixel_count for x in vec], d["vec"][6])
    gps = got["/gps"]
    _eq([x.position for x in gps], d["gps"][1]); _eq([x.status for x in gps], d["gps"][6])
    nav = got["/nav/smoothed"]
    assert list(nav[0].state_names) == d["nav"][6] and all(len(x.state_names) == 0 for x in nav[1:])
    _eq([x.covariance for x in nav], d["nav"][4].reshape(len(nav), -1))
    meas = got["/nav/measurements"]
    for x, inn in zip(meas, d["meas"][4]):
        _eq(x.innovation, inn)
    ci = got["/camera_1/camera_info"][0]
    _eq(ci.d, d["D"]); assert ci.distortion_model == "rational_polynomial" and ci.roi.do_rectify is False
    img = got["/camera_2/image/compressed"]
    assert [bytes(x.data) for x in img] == d["jpegs"] and img[0].format == "jpeg"
    ct = got["/camera_1/truth"]
    _eq([x.horizon_visible for x in ct], d["ctruth"][4])
    tf = got["/tf_static"][0].transforms
    assert [(x.header.frame_id, x.child_frame_id) for x in tf] == [("body", "camera_1"), ("body", "camera_2")]


@pytest.mark.parametrize("short", [t for t in lf.MSG_TEXTS if t != "tf2_msgs/TFMessage"])
def test_vectorised_codec_matches_mcap_ros2_bytes(short):
    """Our vectorised CDR encoder produces the same bytes as mcap_ros2's per-message encoder, and our
    decoder reads mcap_ros2's bytes back (strings and sequences of differing lengths included)."""
    from mcap_ros2._dynamic import serialize_dynamic
    rng = np.random.default_rng(abs(hash(short)) % 2**32)
    layout = lf.known_layout(short)
    n = 7
    values, msgs = {}, [dict() for _ in range(n)]
    for leaf in layout.leaves:
        if leaf.type == "string":
            if leaf.array is None:
                v = [("x" * int(rng.integers(0, 9))) for _ in range(n)]
            else:
                v = [["ab" * int(rng.integers(0, 3)) for _ in range(int(rng.integers(0, 4)))] for _ in range(n)]
        else:
            dt = np.dtype(lf.PRIMITIVES[leaf.type])
            shape = (n,) if leaf.array is None else (n, leaf.array if leaf.array > 0 else 0)
            if leaf.array == -1:
                v = [(rng.standard_normal(int(rng.integers(0, 5))) * 100).astype(dt) for _ in range(n)]
            elif leaf.type == "bool":
                v = rng.random(shape) > 0.5
            elif dt.kind == "f":
                v = (rng.standard_normal(shape) * 1e3).astype(dt)
            else:
                info = np.iinfo(dt)
                v = rng.integers(max(info.min, -1000), min(info.max, 1000), shape).astype(dt)
        values[leaf.path] = v
        for i in range(n):
            cur = msgs[i]
            *parents, last = leaf.path.split(".")
            for p in parents:
                cur = cur.setdefault(p, {})
            x = v[i]
            cur[last] = x.tolist() if isinstance(x, np.ndarray) else (x.item() if hasattr(x, "item") else x)
    ours = layout.encode(values, n)
    enc = serialize_dynamic(short, lf.schema_text(short))[short]
    ref = [bytes(enc(m)) for m in msgs]
    assert ours == ref
    width = max(map(len, ref))
    rows = np.zeros((n, width), np.uint8)
    for i, b in enumerate(ref):
        rows[i, :len(b)] = np.frombuffer(b, np.uint8)
    dec, ok = layout.decode(rows, np.array([len(b) for b in ref]))
    assert ok.all()
    for leaf in layout.leaves:
        v, got = values[leaf.path], dec[leaf.path]
        if leaf.array == -1 and leaf.type != "string":
            for i in range(n):
                _eq(np.asarray(got[i]).reshape(-1), v[i])
        elif leaf.type == "string":
            assert [list(x) if isinstance(x, list) else str(x) for x in got] == v
        else:
            _eq(np.asarray(got).reshape(np.shape(v)), v)


def test_image_data_parsed_directly_as_mcap_ros2_writes_it():
    """The direct parse of one CompressedImage (scenarios.flightlog.reader._compressed_image_span) gives
    the data bytes of messages serialised by mcap_ros2 (frame_id and format of every length
    mod 4, so every alignment; empty data included); truncated or wrongly encapsulated messages
    give None (the general decoder then reports them)."""
    from mcap_ros2._dynamic import serialize_dynamic
    from scenarios.flightlog.reader import IMAGE_TYPE, _compressed_image_span

    def _compressed_image_data(buf, off, ln):
        span = _compressed_image_span(buf, off, ln)
        return None if span is None else buf[span[0]:span[0] + span[1]]
    short = "sensor_msgs/CompressedImage"
    assert IMAGE_TYPE == short
    enc = serialize_dynamic(short, lf.schema_text(short))[short]
    rng = np.random.default_rng(5)
    for fid in range(6):
        for fmt in ("", "j", "png", "jpeg", "rgb8; jpeg compressed bgr8"):
            for n in (0, 1, 5, 300):
                data = bytes(rng.integers(0, 256, n, dtype=np.uint8))
                msg = bytes(enc({"header": {"stamp": {"sec": 7, "nanosec": 9}, "frame_id": "c" * fid},
                                 "format": fmt, "data": list(data)}))
                buf = b"\xff" * 3 + msg + b"\xee" * 5        # inside a chunk, neighbours around it
                assert _compressed_image_data(buf, 3, len(msg)) == data, (fid, fmt, n)
                for cut in (len(msg) - 1, len(msg) - n - 1, 10):
                    if 0 < cut < len(msg) and (n > 0 or cut < len(msg) - 4):
                        assert _compressed_image_data(buf, 3, cut) is None, (fid, fmt, n, cut)
    bad = b"\x01\x00" + msg[2:]                                # big-endian encapsulation: not parsed
    assert _compressed_image_data(bad, 0, len(bad)) is None


def test_image_stream_pickles_as_path_and_index(full_log, tmp_path):
    """An image stream sent to another process (pickle) maps the file again and reads the same
    bytes; a file replaced meanwhile is an error naming it, not other images."""
    import pickle
    import shutil
    from scenarios.flightlog.reader import LogFormatError, read_log
    path, d = full_log
    copy = tmp_path / "copy.mcap"
    shutil.copy(path, copy)
    st = read_log(copy).cameras[2].images
    blob = pickle.dumps(st)
    assert len(blob) < 4096                       # the index, not the images
    again = pickle.loads(blob)
    assert [again[i] for i in range(len(again))] == d["jpegs"]
    # the views (no copy) hold the same bytes, read-only
    views = [again.view(i) for i in range(len(again))]
    assert [v.tobytes() for v in views] == d["jpegs"] and not any(v.flags.writeable for v in views)
    _write_all(copy, {**d, "jpegs": [b"x" + j for j in d["jpegs"]]})
    with pytest.raises(LogFormatError, match="copy.mcap: the log changed"):
        pickle.loads(blob)


def test_foreign_imu_file_uses_the_fast_path(tmp_path):
    """A sensor_msgs/Imu log written by mcap_ros2 with the ROS 2 schema text (comments, another
    frame id) reads the same values as the reference decoder."""
    ros_imu = ("# IMU from another tool\nstd_msgs/Header header # comment\n\ngeometry_msgs/Quaternion orientation\n"
               "float64[9] orientation_covariance # Row major about x, y, z axes\n"
               "geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n"
               "geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n"
               "================================================================================\n"
               "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
               "================================================================================\n"
               "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
               "================================================================================\n"
               "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
               "================================================================================\n"
               "MSG: geometry_msgs/Vector3\n# This represents a vector in free space.\nfloat64 x\nfloat64 y\nfloat64 z\n")
    rng = np.random.default_rng(3)
    g = rng.standard_normal((20, 3))
    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as f:
        w = Ros2Writer(f)
        schema = w.register_msgdef("sensor_msgs/msg/Imu", ros_imu)
        for i in range(20):
            t = T0 + i * 10**7
            w.write_message("/imu", schema, {"header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9},
                                                       "frame_id": "imu_link"},
                                            "angular_velocity": dict(zip("xyz", g[i].tolist()))},
                            log_time=t, publish_time=t)
        w.finish()
    with warnings.catch_warnings():
        warnings.simplefilter("error", LogWarning)
        log = read_log(path)
    _eq(log.imu.gyro, g)
    _eq(log.imu.accel, np.zeros((20, 3)))
    assert set(log.imu.frame_id) == {"imu_link"}


@pytest.mark.skipif(not (Path(sys.executable).parent / "rerun").exists() and shutil.which("rerun") is None,
                    reason="the rerun binary of rerun-sdk is not installed")
def test_rerun_mcap_import(full_log, tmp_path):
    """Rerun's MCAP importer (`rerun mcap convert`, rerun-sdk 0.41.0) converts the log offline and
    headless, keeps every topic and decodes the ROS 2 payloads (ros2_timestamp index)."""
    path, _ = full_log
    exe = Path(sys.executable).parent / "rerun"
    exe = str(exe) if exe.exists() else shutil.which("rerun")
    out = tmp_path / "full.rrd"
    r = subprocess.run([exe, "mcap", "convert", str(path), "-o", str(out)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 0
    stats = subprocess.run([exe, "rrd", "stats", str(out)], capture_output=True, text=True, timeout=120)
    assert stats.returncode == 0, stats.stderr
    for topic in ["/imu", "/imu_increment", "/gps", "/tf_static", "/truth/state", "/nav/forward", "/nav/smoothed",
                  "/nav/ins_unaided", "/nav/measurements"] + [
            f"/camera_{k}/{s}" for k in (1, 2) for s in lf.CAMERA_SUFFIXES]:
        assert f"{topic}:" in stats.stdout, topic
    assert "ros2_timestamp" in stats.stdout


# ---------------------------------------------------------------- damaged and odd files
def _small_log(path, n=3000, gyro=None):
    rng = np.random.default_rng(5)
    t = T0 + np.arange(n, dtype=np.int64) * 2_500_000
    g = rng.standard_normal((n, 3)) if gyro is None else gyro
    with LogWriter(path, META, chunk_size=32 * 1024) as w:
        w.write_imu(t, g, rng.standard_normal((n, 3)))
        w.write_gps(t[::100], rng.standard_normal((n // 100, 3)), rng.standard_normal((n // 100, 3)))
    return t, g


@pytest.mark.parametrize("fraction", [0.3, 0.77, 0.999])
def test_truncated_file_keeps_every_complete_message(tmp_path, fraction):
    full = tmp_path / "full.mcap"
    t, g = _small_log(full)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:int(len(data) * fraction)])
    with pytest.warns(LogWarning, match=r"cut\.mcap.*truncated.*last good message at 2019-06-13T"):
        log = read_log(cut)
    n = len(log.imu)
    assert 0 < n <= len(t)
    _eq(log.imu.t_ns, t[:n]); _eq(log.imu.gyro, g[:n])  # a prefix, nothing invented
    assert log.complete is None or fraction > 0.99
    # the chunks are 32 KiB of ~355-byte messages: at most one chunk (~100 IMU messages) plus the
    # summary is lost beyond the cut
    assert n >= fraction * len(t) - 200 - 0.1 * len(t) * (fraction > 0.99)


def test_unknown_schema_warns_naming_the_topic(tmp_path):
    path = tmp_path / "unknown.mcap"
    with open(path, "wb") as f:
        w = McapWriter(f)
        w.start("", "test")
        sj = w.register_schema("Weird", "jsonschema", b"{}")
        cj = w.register_channel("/weird_json", "json", sj)
        sr = w.register_schema("foo_msgs/msg/Thing", "ros2msg", b"float64 a\nstring b\n")
        cr = w.register_channel("/thing", "cdr", sr)
        w.add_message(cj, T0, b'{"a": 1}', T0)
        w.add_message(cr, T0 + 1, bytes([0, 1, 0, 0]) + np.float64(2.5).tobytes() + b"\x03\0\0\0hi\0", T0 + 1)
        w.finish()
    with pytest.warns(LogWarning) as rec:
        log = read_log(path)
    msgs = [str(r.message) for r in rec]
    assert any("/weird_json" in m and "unknown schema" in m for m in msgs)
    assert any("/thing" in m and "unknown schema" in m for m in msgs)
    _eq(log.series["/thing"].a, [2.5])  # decoded generically all the same
    assert list(log.series["/thing"].b) == ["hi"]
    assert "/weird_json" in log.topics and "/weird_json" not in log.series


def _raw_imu_log(path, t, gyro):
    """IMU messages written with the plain mcap writer in the order given (our writer would sort)."""
    layout = lf.known_layout("sensor_msgs/Imu")
    n = len(t)
    v = lf.header_values(t, "body")
    v.update({"orientation.x": 0.0, "orientation.y": 0.0, "orientation.z": 0.0, "orientation.w": 1.0,
              "orientation_covariance": np.zeros(9), "angular_velocity_covariance": np.zeros(9),
              "linear_acceleration_covariance": np.zeros(9),
              "angular_velocity.x": gyro[:, 0], "angular_velocity.y": gyro[:, 1], "angular_velocity.z": gyro[:, 2],
              "linear_acceleration.x": 0.0, "linear_acceleration.y": 0.0, "linear_acceleration.z": 0.0})
    with open(path, "wb") as f:
        w = McapWriter(f)
        w.start("ros2", "test")
        s = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", lf.schema_text("sensor_msgs/Imu").encode())
        c = w.register_channel("/imu", "cdr", s)
        for ti, b in zip(t.tolist(), layout.encode(v, n)):
            w.add_message(c, ti, b, ti)
        w.finish()


def test_out_of_order_and_duplicate_stamps(tmp_path):
    t = T0 + np.array([0, 10, 20, 15, 30, 30, 40], dtype=np.int64) * 1_000_000
    g = np.arange(21, dtype=float).reshape(7, 3)
    path = tmp_path / "order.mcap"
    _raw_imu_log(path, t, g)
    with pytest.warns(LogWarning) as rec:
        log = read_log(path)
    msgs = [str(r.message) for r in rec]
    assert any("/imu" in m and "out of order" in m and "02:21:00.015000000Z" in m for m in msgs), msgs
    assert any("/imu" in m and "duplicate" in m and "02:21:00.030000000Z" in m for m in msgs), msgs
    _eq(log.imu.t_ns, T0 + np.array([0, 10, 15, 20, 30, 40]) * 1_000_000)
    _eq(log.imu.gyro, g[[0, 1, 3, 2, 4, 6]])  # sorted; of the two at 30 ms the first is kept


def test_nan_samples_warn_with_topic_and_time(tmp_path):
    g = np.random.default_rng(1).standard_normal((3000, 3))
    g[1234, 1] = np.nan
    g[2000, 0] = np.nan
    path = tmp_path / "nan.mcap"
    t, _ = _small_log(path, gyro=g)
    with pytest.warns(LogWarning, match=r"/imu: NaN in 2 message\(s\) \(first at 2019-06-13T02:21:03\.085000000Z"):
        log = read_log(path)
    assert np.isnan(log.imu.gyro[1234, 1]) and len(log.imu) == 3000


def test_stamp_differing_from_log_time_warns(tmp_path):
    path = tmp_path / "stamp.mcap"
    layout = lf.known_layout(f"{lf.PKG}/ImuIncrement")
    v = lf.header_values(np.array([T0, T0 + 5]), "body")
    v.update({"delta_angle": np.zeros((2, 3)), "delta_velocity": np.zeros((2, 3)), "dt": 0.1})
    with open(path, "wb") as f:
        w = McapWriter(f)
        w.start("ros2", "test")
        s = w.register_schema(lf.ros2_name(f"{lf.PKG}/ImuIncrement"), "ros2msg",
                              lf.schema_text(f"{lf.PKG}/ImuIncrement").encode())
        c = w.register_channel("/imu_increment", "cdr", s)
        for ti, b in zip([T0, T0 + 7], layout.encode(v, 2)):
            w.add_message(c, ti, b, ti)
        w.finish()
    with pytest.warns(LogWarning, match="/imu_increment: header.stamp differs from log_time in 1"):
        log = read_log(path)
    _eq(log.imu_increment.t_ns, [T0, T0 + 7])


@pytest.mark.parametrize("content", [b"", b"hello, not a log\n", b"\x89MCAP0\r", b"PK\x03\x04" + bytes(100)])
def test_non_mcap_file_is_a_clear_error(tmp_path, content):
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    with pytest.raises(LogFormatError, match=r"bad\.mcap: not an MCAP file") as e:
        read_log(path)
    assert isinstance(e.value, UserError)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(LogFormatError, match=r"nope\.mcap: cannot read log"):
        read_log(tmp_path / "nope.mcap")


def test_garbage_after_header_gives_warning_not_traceback(tmp_path):
    full = tmp_path / "full.mcap"
    _small_log(full, n=500)
    data = bytearray(full.read_bytes())
    data[200:400] = b"\xff" * 200  # overwrite the middle of the first chunk's records/lengths
    bad = tmp_path / "garbled.mcap"
    bad.write_bytes(bytes(data))
    with pytest.warns(LogWarning, match="garbled.mcap"):
        read_log(bad)


# ---------------------------------------------------------------- writer semantics
def test_exception_leaves_no_file(tmp_path):
    path = tmp_path / "run.mcap"
    with pytest.raises(RuntimeError):
        with LogWriter(path, META) as w:
            w.write_imu(np.array([T0]), np.zeros((1, 3)), np.zeros((1, 3)))
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_partial_on_error_and_explicit_partial_close(tmp_path):
    path = tmp_path / "run.mcap"
    with pytest.raises(KeyboardInterrupt):
        with LogWriter(path, META, partial_on_error=True) as w:
            w.write_imu(T0 + np.arange(10, dtype=np.int64), np.ones((10, 3)), np.zeros((10, 3)))
            w.advance(T0 + 5)
            raise KeyboardInterrupt
    assert [p.name for p in tmp_path.iterdir()] == ["run.mcap"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", LogWarning)
        log = read_log(path)
    assert log.complete is False and "KeyboardInterrupt" in log.metadata["horizon-nav.status"]["reason"]
    assert len(log.imu) == 10
    w = LogWriter(tmp_path / "b.mcap", META)
    w.write_gps(np.array([T0]), np.ones(3), np.ones(3))
    w.close(complete=False, reason="stopped by user")
    log = read_log(tmp_path / "b.mcap")
    assert log.complete is False and len(log.gps) == 1


def test_advance_streams_in_order_and_rejects_the_past(tmp_path):
    path = tmp_path / "s.mcap"
    with LogWriter(path, META) as w:
        w.write_imu(T0 + np.arange(0, 100, 2, dtype=np.int64), np.zeros((50, 3)), np.zeros((50, 3)))
        w.write_gps(T0 + np.arange(1, 100, 10, dtype=np.int64), np.zeros((10, 3)), np.zeros((10, 3)))
        w.advance(T0 + 50)
        assert w.message_count == 25 + 5
        with pytest.raises(ValueError, match=r"/gps: message at t_ns=.* is before advance"):
            w.write_gps(np.array([T0 + 49]), np.zeros(3), np.zeros(3))
        w.write_imu(T0 + np.arange(100, 120, 2, dtype=np.int64), np.zeros((10, 3)), np.zeros((10, 3)))
    times = [m.log_time for _, _, m in make_reader(open(path, "rb")).iter_messages(log_time_order=False)]
    assert times == sorted(times) and len(times) == 70


@pytest.mark.parametrize("bad, match", [
    ({"kind": "dreamt"}, "kind 'dreamt'"),
    ({"kind": None}, "missing keys"),
])
def test_bad_metadata_is_rejected(tmp_path, bad, match):
    meta = dict(META)
    meta.update(bad)
    if bad.get("kind", 1) is None:
        del meta["kind"]
    with pytest.raises(ValueError, match=match):
        LogWriter(tmp_path / "x.mcap", meta)
    assert list(tmp_path.iterdir()) == []


def test_bad_writer_input_names_the_field(tmp_path):
    with LogWriter(tmp_path / "x.mcap", META) as w:
        with pytest.raises(ValueError, match=r"/imu gyro: expected shape \(2, 3\)"):
            w.write_imu(np.array([T0, T0 + 1]), np.zeros((3, 3)), np.zeros((2, 3)))
        with pytest.raises(ValueError, match="t_ns must be a 1-D array of int64"):
            w.write_imu(np.array([1.5e18]), np.zeros((1, 3)), np.zeros((1, 3)))
        with pytest.raises(ValueError, match=r"target \['venus'\]"):
            w.write_vectors(1, np.array([T0]), "venus", np.zeros((1, 3)), np.eye(3))


def test_schema_texts_parse_back_to_the_same_structure():
    for short in lf.MSG_TEXTS:
        defs = lf.parse_schema(lf.ros2_name(short), lf.schema_text(short))
        assert defs[short] == lf.parse_msg(lf.MSG_TEXTS[short], short.split("/")[0])
    assert lf.parse_msg("int8 STATUS_FIX=0\nstring<=5 s\nfloat64[<=3] a # c\nHeader h", "p") == [
        lf.Field("s", "string", None), lf.Field("a", "float64", -1), lf.Field("h", "std_msgs/Header", None)]


def test_docs_carry_every_message_definition():
    """docs/log-format.md repeats the definitions of scenarios.flightlog.format.MSG_TEXTS verbatim (one source)."""
    doc = (Path(__file__).resolve().parents[1] / "docs" / "log-format.md").read_text()
    for short, text in lf.MSG_TEXTS.items():
        assert f"`{lf.ros2_name(short)}`:\n\n```\n{text.rstrip()}\n```" in doc, short


def test_imu_layout_is_324_bytes_as_documented():
    layout = lf.known_layout("sensor_msgs/Imu")
    v = lf.header_values(np.array([T0]), "body")
    v.update({lf_.path: 0.0 for lf_ in layout.leaves if lf_.path not in v})
    assert len(layout.encode(v, 1)[0]) == 324


# ---------------------------------------------------------------- bulk MCAP writer (scenarios.flightlog._chunks)
def _interleaved_log(path, *, chunk_size=4096, compression="zstd", windows=None):
    """IMU at 400 Hz, GPS at 10 Hz, truth at 50 Hz, NavSolution (state_names in the first message:
    two layouts) and measurements of varying size, written out of order across calls (optionally
    streamed with advance() every ``windows`` IMU samples). Returns {topic: t_ns}."""
    rng = np.random.default_rng(11)
    n = 1200
    t = T0 + np.arange(n, dtype=np.int64) * 2_500_000
    g, a = rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
    tg, tt, tn = t[::40], t[::8], t[::20]
    tm = t[5::100]
    cov = rng.standard_normal((len(tn), 4, 4))
    gp, gv = rng.standard_normal((len(tg), 3)), rng.standard_normal((len(tg), 3))
    with LogWriter(path, META, chunk_size=chunk_size, compression=compression) as w:
        steps = [(0, n)] if windows is None else [(i, min(i + windows, n)) for i in range(0, n, windows)]
        for lo, hi in steps:
            s = slice(lo, hi)
            sg, st, sn, sm = ((x >= t[lo]) & (x <= t[hi - 1]) for x in (tg, tt, tn, tm))
            w.write_truth(tt[st], np.ones((st.sum(), 3)), np.ones((st.sum(), 3)), np.ones((st.sum(), 4)),
                          np.ones((st.sum(), 3)), np.ones((st.sum(), 3)))
            w.write_imu(t[s], g[s], a[s])
            w.write_gps(tg[sg], gp[sg], gv[sg])
            w.write_nav(lf.TOPIC_NAV_FORWARD, tn[sn], np.zeros((sn.sum(), 3)), np.zeros((sn.sum(), 3)),
                        np.zeros((sn.sum(), 4)), cov[sn], state_names=list("abcd"))
            k = int(sm.sum())
            sizes = 3 + np.flatnonzero(sm) % 4
            w.write_measurement(tm[sm], ["gps"] * k, np.ones(k, bool), [""] * k,
                                [np.ones(m) for m in sizes], [np.ones(m * m) for m in sizes], np.ones(k))
            if windows is not None and hi < n:
                w.advance(int(t[hi]))
    return {lf.TOPIC_IMU: t, lf.TOPIC_GPS: tg, lf.TOPIC_TRUTH: tt, lf.TOPIC_NAV_FORWARD: tn, lf.TOPIC_MEASUREMENTS: tm}


def _records(path):
    """Top-level records of an MCAP file with their byte offsets (parsed with the mcap library's
    record classes, chunks not broken up)."""
    from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Message, MessageIndex,
                              Metadata, MetadataIndex, Schema, Statistics, SummaryOffset)
    from mcap.data_stream import ReadDataStream
    import io
    classes = {1: Header, 2: Footer, 3: Schema, 4: Channel, 5: Message, 6: Chunk, 7: MessageIndex, 8: ChunkIndex,
               12: Metadata, 13: MetadataIndex, 11: Statistics, 14: SummaryOffset, 15: DataEnd}
    data = Path(path).read_bytes()
    assert data[:8] == data[-8:] == b"\x89MCAP0\r\n"
    out, p = [], 8
    while p < len(data) - 8:
        op, ln = data[p], int.from_bytes(data[p + 1:p + 9], "little")
        body = io.BytesIO(data[p + 9:p + 9 + ln])
        rec = classes[op].read(ReadDataStream(body), ln) if op == 5 else classes[op].read(ReadDataStream(body))
        out.append((p, 9 + ln, rec))
        p += 9 + ln
    assert p == len(data) - 8
    return data, out


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_chunks_and_indexes_follow_the_mcap_spec(tmp_path, compression):
    """Every Chunk/Message Index/Chunk Index/Statistics field checked against the records
    themselves (mcap library record parsers and its chunk decompression with CRC validation): chunk
    times are the min/max of its messages, each Message Index entry points at a Message record of
    that channel and time and together they cover the chunk, each Chunk Index points at its chunk
    and index records, the statistics count what is in the file, the footer CRC covers the summary."""
    import zlib
    from mcap.records import Chunk, ChunkIndex, Footer, Message, MessageIndex, Statistics, SummaryOffset
    from mcap.stream_reader import breakup_chunk
    path = tmp_path / "c.mcap"
    times = _interleaved_log(path, compression=compression)
    data, recs = _records(path)
    by_offset = {p: (ln, r) for p, ln, r in recs}
    chunks = [(p, ln, r) for p, ln, r in recs if isinstance(r, Chunk)]
    assert len(chunks) > 20  # 4 KiB chunks of ~430 kB
    all_msgs = []
    channels = {}
    for i, (p, ln, ch) in enumerate(chunks):
        assert ch.compression == {"none": ""}.get(compression, compression)
        assert ch.uncompressed_crc != 0
        inner = breakup_chunk(ch, validate_crc=True)  # raises on a CRC mismatch
        channels.update({r.id: r.topic for r in inner if type(r).__name__ == "Channel"})
        msgs = [r for r in inner if isinstance(r, Message)]
        assert msgs and ch.message_start_time == min(m.log_time for m in msgs)
        assert ch.message_end_time == max(m.log_time for m in msgs)
        raw = ch.data if compression == "none" else (
            __import__("zstandard").ZstdDecompressor().decompress(ch.data, max_output_size=ch.uncompressed_size)
            if compression == "zstd" else __import__("lz4.frame").frame.decompress(ch.data))
        assert len(raw) == ch.uncompressed_size
        # the Message Index records right after the chunk
        j = [k for k, (q, _, _) in enumerate(recs) if q == p][0] + 1
        covered = 0
        while j < len(recs) and isinstance(recs[j][2], MessageIndex):
            mi = recs[j][2]
            for t, off in mi.records:
                assert raw[off] == 5
                cid, lt = int.from_bytes(raw[off + 9:off + 11], "little"), int.from_bytes(raw[off + 15:off + 23], "little")
                assert (cid, lt) == (mi.channel_id, t)
            covered += len(mi.records)
            j += 1
        assert covered == len(msgs)
        all_msgs += msgs
    lt = [m.log_time for m in all_msgs]
    assert lt == sorted(lt)
    for topic, t in times.items():
        cid = [c for c, tp in channels.items() if tp == topic][0]
        _eq([m.log_time for m in all_msgs if m.channel_id == cid], t)
    # summary
    footer = recs[-1][2]
    assert isinstance(footer, Footer)
    cidx = [r for _, _, r in recs if isinstance(r, ChunkIndex)]
    assert [c.chunk_start_offset for c in cidx] == [p for p, _, _ in chunks]
    for c, (p, ln, ch) in zip(cidx, chunks):
        assert c.chunk_length == ln and c.compressed_size == len(ch.data) and c.uncompressed_size == ch.uncompressed_size
        assert (c.message_start_time, c.message_end_time) == (ch.message_start_time, ch.message_end_time)
        total = 0
        for cid, off in c.message_index_offsets.items():
            mln, mi = by_offset[off]
            assert isinstance(mi, MessageIndex) and mi.channel_id == cid
            total += mln
        assert total == c.message_index_length
    stats = [r for _, _, r in recs if isinstance(r, Statistics)][0]
    assert stats.message_count == len(all_msgs) and stats.chunk_count == len(chunks)
    assert stats.message_start_time == lt[0] and stats.message_end_time == lt[-1]
    assert stats.channel_message_counts == {c: sum(m.channel_id == c for m in all_msgs) for c in channels}
    assert stats.channel_count == len(channels) == 5
    offs = [r for _, _, r in recs if isinstance(r, SummaryOffset)]
    assert {o.group_opcode for o in offs} >= {3, 4, 8, 11, 13}
    for o in offs:
        if o.group_length:
            assert data[o.group_start] == o.group_opcode
    crc = zlib.crc32(data[footer.summary_start:len(data) - 8 - 9 - 20] + data[len(data) - 8 - 29:len(data) - 8 - 4])
    assert footer.summary_crc == crc


@pytest.mark.parametrize("windows", [None, 37])
def test_mcap_reader_index_stream_and_topic_filter_agree(tmp_path, windows):
    """The mcap reader reads the same messages through the chunk indexes (all topics, one topic:
    uses the Chunk Index channel map) and as a stream; streaming with advance() gives the same
    messages as writing at once; chunks stay full-size across advance() calls."""
    from mcap.reader import NonSeekingReader, SeekingReader
    path = tmp_path / "s.mcap"
    times = _interleaved_log(path, windows=windows)
    with open(path, "rb") as f:
        idx = [(c.topic, m.log_time, m.data) for _, c, m in SeekingReader(f, validate_crcs=True).iter_messages(
            log_time_order=False)]
    with open(path, "rb") as f:
        stream = [(c.topic, m.log_time, m.data) for _, c, m in NonSeekingReader(f, validate_crcs=True).iter_messages()]
    with open(path, "rb") as f:
        gps = [m.log_time for _, c, m in SeekingReader(f).iter_messages(topics=[lf.TOPIC_GPS])]
    assert idx == stream and len(idx) == sum(len(t) for t in times.values())
    assert [x[1] for x in idx] == sorted(x[1] for x in idx)
    _eq(gps, times[lf.TOPIC_GPS])
    with open(path, "rb") as f:
        summ = SeekingReader(f).get_summary()
    sizes = [c.uncompressed_size for c in summ.chunk_indexes]
    assert all(s > 4096 for s in sizes[:-1])  # every chunk but the last is full, windows or not
    if windows:
        ref = tmp_path / "ref.mcap"
        _interleaved_log(ref)
        with open(ref, "rb") as f:
            assert [(c.topic, m.log_time, m.data) for _, c, m in SeekingReader(f).iter_messages(log_time_order=False)] == idx


def test_equal_stamps_keep_call_order(tmp_path):
    """Messages with the same log_time are written in call order (a stable merge), also when a
    later call brings earlier times."""
    path = tmp_path / "ties.mcap"
    t = T0 + np.array([0, 10, 10, 20], dtype=np.int64)
    with LogWriter(path, META) as w:
        w.write_gps(t[1:3], [[1.0, 0, 0], [2.0, 0, 0]], np.zeros(3))
        w.write_imu(t, np.arange(12.0).reshape(4, 3), np.zeros((4, 3)))
        w.write_gps(t[[0, 3]], [[3.0, 0, 0], [4.0, 0, 0]], np.zeros(3))
    dec = DecoderFactory()
    order = []
    with open(path, "rb") as f:
        for _, c, m, ros in make_reader(f, decoder_factories=[dec]).iter_decoded_messages(log_time_order=False):
            order.append((m.log_time - T0, c.topic, ros.position[0] if c.topic == "/gps" else ros.angular_velocity.x))
    assert order == [(0, "/imu", 0.0), (0, "/gps", 3.0), (10, "/gps", 1.0), (10, "/gps", 2.0), (10, "/imu", 3.0),
                     (10, "/imu", 6.0), (20, "/imu", 9.0), (20, "/gps", 4.0)]


def test_streaming_memory_is_bounded_by_a_chunk(tmp_path):
    """With advance() per window, the writer holds at most one open chunk plus the current window:
    the tracemalloc peak (numpy reports its buffers) stays far below the size of the log."""
    import tracemalloc
    n_win, per = 60, 4000
    rng = np.random.default_rng(2)
    g = rng.standard_normal((per, 3))
    path = tmp_path / "big.mcap"
    with LogWriter(path, META) as w:
        w.write_imu(T0 + np.arange(per, dtype=np.int64), g, g)  # warm-up (codec caches)
        w.advance(T0 + per)
        tracemalloc.start()
        for i in range(1, n_win):
            t = T0 + np.arange(i * per, (i + 1) * per, dtype=np.int64)
            w.write_imu(t, g, g)
            w.advance(int(t[-1]) + 1)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    total = n_win * per * 355  # uncompressed records
    assert total > 80e6 and peak < 8e6, peak  # one window is 1.4 MB of records, a chunk 1 MiB
    assert len(read_log(path, topics=["/imu"]).imu) == n_win * per


def test_nine_messages_of_fixed_arrays(tmp_path):
    """A batch of N = 9 IMU samples (N equal to the 9 elements of a covariance) is one value for
    all messages, not one element per message (the codec used to reject it)."""
    path = tmp_path / "nine.mcap"
    g = np.arange(27.0).reshape(9, 3)
    with LogWriter(path, META) as w:
        w.write_imu(T0 + np.arange(9, dtype=np.int64), g, g, gyro_covariance=np.diag([1.0, 2, 3]))
    log = read_log(path)
    _eq(log.imu.gyro, g)
    _eq(log.imu.angular_velocity_covariance, np.broadcast_to(np.diag([1.0, 2, 3]), (9, 3, 3)))
    _eq(log.imu.orientation_covariance[:, 0, 0], -np.ones(9))


def test_encode_groups_rows_are_the_payloads_after_a_head():
    """``Layout.encode_groups`` gives per layout group a matrix whose columns after ``prefix`` are the
    payloads of ``encode`` (checked against mcap_ros2 in test_layout_matches_reference_encoder) and
    whose first columns are ``head(L)``; broadcast and per-message values encode the same bytes."""
    layout = lf.known_layout(f"{lf.PKG}/NavSolution")
    n = 5
    rng = np.random.default_rng(4)
    v = lf.header_values(T0 + np.arange(n, dtype=np.int64), "earth")
    v.update({"position_e": rng.standard_normal((n, 3)), "velocity_e": np.broadcast_to(np.ones(3), (n, 3)),
              "q_eb": [0.0, 0.0, 0.0, 1.0], "state": np.zeros((n, 0)), "covariance": rng.standard_normal((n, 4)),
              "state_names": [["a", "b"]] + [[]] * (n - 1)})
    ref = layout.encode(v, n)
    groups = layout.encode_groups(v, n, prefix=3, head=lambda L: bytes([L % 256, 7, 9]))
    assert sorted(list(i) for i, _ in groups) == [[0], [1, 2, 3, 4]]
    for idx, rows in groups:
        for j, i in enumerate(idx):
            assert rows[j, 3:].tobytes() == ref[i]
            assert list(rows[j, :3]) == [len(ref[i]) % 256, 7, 9]
    v2 = dict(v, velocity_e=np.ones((n, 3)), q_eb=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)))
    assert layout.encode(v2, n) == ref


def test_image_not_parsed_directly_goes_through_the_general_decoder(full_log, monkeypatch):
    """An image message the direct parse does not accept (here: every one) is read by the general
    decoder: the same bytes, through ``stream[i]`` and ``stream.view(i)``."""
    from scenarios.flightlog import reader as log_reader
    path, d = full_log
    st = log_reader.read_log(path).cameras[2].images
    monkeypatch.setattr(log_reader, "_compressed_image_span", lambda buf, off, ln: None)
    assert [st[i] for i in range(len(st))] == d["jpegs"]
    assert [st.view(i).tobytes() for i in range(len(st))] == d["jpegs"]


def _image_log(path, n_img=120, size=100_000, chunk=256 * 1024):
    """Two cameras' incompressible 'images' (random bytes) interleaved with 200 Hz IMU messages in
    chunks of ``chunk`` bytes: ~n_img * size / chunk chunks, each holding images and IMU rows."""
    rng = np.random.default_rng(11)
    t_img = T0 + np.arange(n_img, dtype=np.int64) * 50_000_000
    imgs = [bytes(rng.integers(0, 256, size + i, dtype=np.uint8)) for i in range(n_img)]
    t_imu = T0 + np.arange(n_img * 10, dtype=np.int64) * 5_000_000 + 1
    g, a = rng.standard_normal((len(t_imu), 3)), rng.standard_normal((len(t_imu), 3))
    with LogWriter(path, META, chunk_size=chunk) as w:
        w.write_imu(t_imu, g, a)
        w.write_image(1, t_img[0::2], imgs[0::2])
        w.write_image(2, t_img[1::2] + 1, imgs[1::2])
    return t_imu, g, a, imgs


def test_read_log_frees_each_chunk_once_scanned(tmp_path):
    """read_log keeps where the images are and copies the other messages' payloads out of each
    decompressed chunk as it scans it: its peak of Python-allocated memory stays near one chunk,
    not the log's 12 MB of images (each chunk was held until every topic was decoded: a video
    log's whole size in memory, 267 MB for 30 s). The values and images read are the ones written."""
    import tracemalloc
    path = tmp_path / "img.mcap"
    t_imu, g, a, imgs = _image_log(path)
    read_log(path)    # imports and compiled kernels loaded before the measurement
    tracemalloc.start()
    try:
        log = read_log(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # 12 MB of images in ~47 chunks of 256 KiB; allow a few chunks plus the IMU arrays (~0.3 MB)
    assert peak < 2_000_000, peak
    _eq(log.imu.t_ns, t_imu); _eq(log.imu.gyro, g); _eq(log.imu.accel, a)
    assert [log.images[1][i] for i in range(len(log.images[1]))] == imgs[0::2]
    assert [log.images[2][i] for i in range(len(log.images[2]))] == imgs[1::2]
