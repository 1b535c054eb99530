"""Export a horizon-nav log to plain files: CSV tables, image folders, videos, camera files and the
mapping files that import them again (the round trip of tests/test_import.py, and for users who
want their data in other tools).

Layout written into ``out_dir``::

    imu.csv              t_utc_ns, gx, gy, gz [rad/s], ax, ay, az [m/s^2]   (body frame)
                         (increment logs: t_utc_ns, dax, day, daz [rad], dvx, dvy, dvz [m/s], dt [s])
    gps.csv              t_utc_ns, x, y, z [m], vx, vy, vz [m/s] (ECEF), pos_cov_xx .. pos_cov_zz [m^2],
                         vel_cov_xx .. vel_cov_zz [(m/s)^2] (upper triangles), num_satellites
    camera_<k>.toml      camera file (scenarios/config/camera.py) from the log's CameraInfo
    camera_<k>/          frame_000000.jpg ... (the log's JPEG bytes, unchanged) + timestamps.csv (file, t_utc_ns)
    camera_<k>.mp4       the frames as a video (re-encoded) + camera_<k>_frames.csv (frame, t_utc_ns)
    mapping.toml         imports the tables and the image folders
    mapping_video.toml   imports the tables and the videos

Numbers are written by Arrow's CSV writer with the shortest representation that reads back to the
same float64 (as Python's ``repr``): the tables round-trip bit for bit; times are integer ns.

A solution log (``FLIGHT.solution.mcap`` of ``horizon-nav replay``: metadata ``kind =
"solution"`` or a ``/nav/forward`` topic) is exported as tables instead (:func:`export_solution`),
each as CSV and Parquet::

    forward.csv / .parquet      the forward filter at every covariance epoch
    smoothed.csv / .parquet     the RTS smoother at the same epochs (when the log has it)
    ins_unaided.csv / .parquet  the free-inertial solution (time, position, velocity, attitude)
    measurements.csv / .parquet every measurement offered to the filter: source, used, reason,
                                NIS, innovation and its predicted 1-sigma per component

The columns are those of :mod:`scenarios.replay.table` (docs/replay.md "Exporting a solution").
Every file is written atomically (:mod:`scenarios.atomic`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav.timescales import format_utc
from scenarios.atomic import atomic_output, atomic_write_bytes, atomic_write_text
from scenarios.config.camera import save_camera
from scenarios.errors import UserError
from scenarios.flightlog.reader import read_log
from vision.camera import from_camera_info

_UT = ("xx", "xy", "xz", "yy", "yz", "zz")
_UT_IDX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
VIDEO_CODECS = {"mp4v": (".mp4", "mp4v"), "mjpg": (".avi", "MJPG")}


@dataclass
class ExportResult:
    out_dir: Path
    files: dict = field(default_factory=dict)  # label -> Path
    counts: dict = field(default_factory=dict)
    #: a solution log's export: what its T+ column counts from (else None)
    t_plus_origin: str | None = None


def _write_csv(path: Path, cols: dict) -> None:
    import pyarrow as pa
    import pyarrow.csv as pcsv
    atomic_output(path, lambda tmp: pcsv.write_csv(pa.table(cols), tmp,
                                                   write_options=pcsv.WriteOptions(quoting_style="none")))


def _toml_float(x: float) -> str:
    return repr(float(x))


def _time_line() -> str:
    return 'time = { column = "t_utc_ns", base = "unix", unit = "ns" }'


def write_video(frames, path: Path, fps: float, width: int, height: int, codec: str = "mp4v",
                quality: int = 95) -> int:
    """Write decoded JPEG frames to a video with OpenCV; returns the frame count."""
    import cv2
    ext, fourcc = VIDEO_CODECS[codec]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), float(fps), (int(width), int(height)))
    if not vw.isOpened():
        raise UserError(f"{path}: OpenCV cannot write {codec} video here")
    if codec == "mjpg":
        vw.set(cv2.VIDEOWRITER_PROP_QUALITY, float(quality))
    n = 0
    try:
        for b in frames:
            img = cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_COLOR)
            if img is None:
                raise UserError(f"{path}: frame {n} of the log cannot be decoded")
            vw.write(img)
            n += 1
    finally:
        vw.release()
    return n


def export_log(log_path: str | Path, out_dir: str | Path, *, images: bool = True, video: bool = True,
               video_codec: str = "mp4v", jpeg_quality: int = 95) -> ExportResult:
    """Export ``log_path`` into ``out_dir`` (module docstring)."""
    if video_codec not in VIDEO_CODECS:
        raise UserError(f"video codec {video_codec!r}: expected one of {list(VIDEO_CODECS)}")
    log = read_log(log_path)
    if is_solution_log(log):
        return export_solution(log, log_path, out_dir)
    if log.imu is None and log.imu_increment is None and log.gps is None and not log.cameras:
        raise UserError(f"{log_path}: neither a flight log (no /imu, /imu/increment, /gps or camera topic) nor a "
                        f"solution log (no /nav/forward); nothing to export")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    res = ExportResult(out)
    liftoff = int(log.info.get("liftoff_utc_ns", "0") or 0)
    name = log.info.get("name") or log.info.get("scenario_name") or Path(log_path).stem
    head = [f"# Written by `horizon-nav export` from {Path(log_path).name}", f"name = {name!r}".replace("'", '"'),
            f'liftoff_utc = "{format_utc(liftoff, 9)}"', ""]
    sections = []
    if log.imu is not None or log.imu_increment is not None:
        inc = log.imu is None
        s = log.imu_increment if inc else log.imu
        if inc:
            g, a = s.delta_angle, s.delta_velocity
            cols = {"t_utc_ns": s.t_ns, "dax": g[:, 0], "day": g[:, 1], "daz": g[:, 2],
                    "dvx": a[:, 0], "dvy": a[:, 1], "dvz": a[:, 2], "dt": s.dt}
        else:
            g, a = s.gyro, s.accel
            cols = {"t_utc_ns": s.t_ns, "gx": g[:, 0], "gy": g[:, 1], "gz": g[:, 2],
                    "ax": a[:, 0], "ay": a[:, 1], "az": a[:, 2]}
        _write_csv(out / "imu.csv", cols)
        res.files["imu"] = out / "imu.csv"
        res.counts["imu"] = len(s.t_ns)
        if inc:
            sections.append("\n".join([
                "[imu]", 'file = "imu.csv"', 'sample = "increment"', _time_line(),
                'gyro = { columns = ["dax", "day", "daz"], unit = "rad" }',
                'accel = { columns = ["dvx", "dvy", "dvz"], unit = "m/s" }', 'dt_column = "dt"',
                'axes = ["+x", "+y", "+z"]', ""]))
        else:
            sections.append("\n".join([
                "[imu]", 'file = "imu.csv"', 'sample = "rate"', _time_line(),
                'gyro = { columns = ["gx", "gy", "gz"], unit = "rad/s" }',
                'accel = { columns = ["ax", "ay", "az"], unit = "m/s^2" }', 'axes = ["+x", "+y", "+z"]', ""]))
    if log.gps is not None:
        s = log.gps
        has_v = not np.all(np.isnan(s.velocity))  # position-only fixes carry NaN velocities
        cols = {"t_utc_ns": s.t_ns}
        for i, c in enumerate("xyz"):
            cols[c] = s.position[:, i]
        for i, c in enumerate("xyz" if has_v else ""):
            cols[f"v{c}"] = s.velocity[:, i]
        for pre, P in (("pos_cov_", s.position_covariance),) + ((("vel_cov_", s.velocity_covariance),) if has_v else ()):
            for nm, (i, j) in zip(_UT, _UT_IDX):
                cols[pre + nm] = P[:, i, j]
        cols["num_satellites"] = s.num_satellites.astype(np.int64)
        _write_csv(out / "gps.csv", cols)
        res.files["gps"] = out / "gps.csv"
        res.counts["gps"] = len(s.t_ns)
        sections.append("\n".join([
            "[gps]", 'file = "gps.csv"', _time_line(),
            'position = { frame = "ecef", columns = ["x", "y", "z"], unit = "m" }',
            *(['velocity = { frame = "ecef", columns = ["vx", "vy", "vz"], unit = "m/s" }'] if has_v else []),
            "position_covariance = { columns = [" + ", ".join(f'"pos_cov_{c}"' for c in _UT) + '], unit = "m^2" }',
            *(["velocity_covariance = { columns = [" + ", ".join(f'"vel_cov_{c}"' for c in _UT)
               + '], unit = "(m/s)^2" }'] if has_v else []),
            'num_satellites = "num_satellites"', ""]))
    cam_img, cam_vid = [], []
    for k, c in log.cameras.items():
        if c.info is None:
            continue
        info = {"distortion_model": str(c.info.distortion_model[0]), "d": np.asarray(c.info.d)[0],
                "k": np.asarray(c.info.k)[0].ravel(), "r": np.asarray(c.info.r)[0].ravel(),
                "width": int(c.info.width[0]), "height": int(c.info.height[0])}
        try:
            cam = from_camera_info(info)
        except ValueError as exc:
            raise UserError(f"{log_path}: camera {k}: {exc}") from None
        cfile = out / f"camera_{k}.toml"
        save_camera(cam, cfile, comment=f"camera {k} of {Path(log_path).name} (from its CameraInfo)")
        res.files[f"camera_{k}_file"] = cfile
        tf = log.tf_static.get(f"camera_{k}")
        q = np.asarray(tf.q, float) if tf is not None else np.array([0.0, 0.0, 0.0, 1.0])
        tr = np.asarray(tf.translation, float) if tf is not None else np.zeros(3)
        common = ["[[cameras]]", f"k = {k}", f'camera_file = "camera_{k}.toml"',
                  "mount = { quaternion = [" + ", ".join(map(_toml_float, q)) + "] }",
                  "translation_m = [" + ", ".join(map(_toml_float, tr)) + "]"]
        pm = log.other.get(f"/camera_{k}/payload_mask")
        if pm is not None and len(pm[0]):
            mfile = out / f"camera_{k}_mask.png"
            atomic_write_bytes(mfile, pm[1][0])          # the log's PNG as it is
            res.files[f"camera_{k}_mask"] = mfile
            common.append(f'payload_mask = "camera_{k}_mask.png"')
        ims = c.images
        if ims is None or len(ims) == 0:
            cam_img.append("\n".join(common + [""]))
            cam_vid.append("\n".join(common + [""]))
            continue
        t = np.asarray(ims.t_ns, np.int64)
        res.counts[f"camera_{k}"] = len(t)
        if images:
            d = out / f"camera_{k}"
            d.mkdir(exist_ok=True)
            names = [f"frame_{i:06d}.jpg" for i in range(len(t))]
            for nm, b in zip(names, ims):
                atomic_write_bytes(d / nm, b)
            _write_csv(d / "timestamps.csv", {"file": names, "t_utc_ns": t})
            res.files[f"camera_{k}_images"] = d
            cam_img.append("\n".join(common + [
                "[cameras.footage]", f'images = "camera_{k}"',
                f'timestamps = {{ file = "camera_{k}/timestamps.csv", file_column = "file", '
                f'time = {{ column = "t_utc_ns", base = "unix", unit = "ns" }} }}', ""]))
        if video:
            ext = VIDEO_CODECS[video_codec][0]
            vpath = out / f"camera_{k}{ext}"
            fps = 1e9 / float(np.median(np.diff(t))) if len(t) > 1 else 1.0
            n = write_video(iter(ims), vpath, fps, info["width"], info["height"], video_codec, jpeg_quality)
            _write_csv(out / f"camera_{k}_frames.csv", {"frame": np.arange(n, dtype=np.int64), "t_utc_ns": t[:n]})
            res.files[f"camera_{k}_video"] = vpath
            cam_vid.append("\n".join(common + [
                "[cameras.footage]", f'video = "camera_{k}{ext}"', f"jpeg_quality = {int(jpeg_quality)}",
                f'timestamps = {{ file = "camera_{k}_frames.csv", frame_column = "frame", '
                f'time = {{ column = "t_utc_ns", base = "unix", unit = "ns" }} }}', ""]))
    atomic_write_text(out / "mapping.toml", "\n".join(head + sections + cam_img))
    res.files["mapping"] = out / "mapping.toml"
    if video and cam_vid:
        atomic_write_text(out / "mapping_video.toml", "\n".join(head + sections + cam_vid))
        res.files["mapping_video"] = out / "mapping_video.toml"
    return res


# ------------------------------------------------------------------------------------------------
# Solution logs
# ------------------------------------------------------------------------------------------------
def is_solution_log(log) -> bool:
    """A solution log of ``horizon-nav replay``: metadata ``kind = "solution"`` or a /nav/forward topic."""
    from scenarios.flightlog import format as lf
    return log.info.get("kind") == "solution" or lf.TOPIC_NAV_FORWARD in log.topics


def mission_origin_ns(log) -> tuple[int, str]:
    """The T+ origin of a solution log [ns] and what it is: lift-off, else the mission-time origin
    the replay recorded (the input log's first IMU sample), else the first forward epoch."""
    for key, what in (("liftoff_utc_ns", "lift-off"), ("mission_time_origin_ns", "the input log's first IMU sample")):
        v = log.info.get(key, "")
        if v and v.lstrip("-").isdigit():
            return int(v), what
    return int(log.nav["forward"].t_ns[0]), "the first forward epoch"


def _time_columns(t_ns, origin: int) -> dict:
    t_ns = np.asarray(t_ns, np.int64)
    return {"t_ns": t_ns, "t_plus_s": (t_ns - origin) / 1e9}


def _write_tables(out: Path, stem: str, cols: dict, res: ExportResult) -> None:
    """``stem.csv`` (``time_utc`` as ISO-8601 text) and ``stem.parquet`` (a UTC timestamp column),
    each atomically, ``time_utc`` first."""
    import pyarrow as pa
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq
    t = np.asarray(cols["t_ns"], np.int64)
    iso = np.char.add(np.datetime_as_string(t.astype("datetime64[ns]"), unit="ns"), "Z")
    body = {k: v for k, v in cols.items()}
    csv_tab = pa.table({"time_utc": iso, **body})
    pq_tab = pa.table({"time_utc": pa.array(t, pa.timestamp("ns", tz="UTC")), **body})
    atomic_output(out / f"{stem}.csv", lambda tmp: pcsv.write_csv(csv_tab, tmp))
    atomic_output(out / f"{stem}.parquet", lambda tmp: pq.write_table(pq_tab, tmp))
    res.files[stem] = out / f"{stem}.csv"
    res.files[f"{stem}_parquet"] = out / f"{stem}.parquet"
    res.counts[stem] = len(t)


def _nav_columns(log_path, series, origin: int, *, states: bool, full_nav: bool = True) -> dict:
    """:func:`scenarios.replay.table.solution_columns` of a NavSolution series of the log; without
    ``states`` (the free-inertial solution, which has no covariance) time, position, velocity and
    attitude only. ``full_nav``: the log's 9x9 navigation blocks are full at every epoch (metadata
    ``nav_covariance = "full"``)."""
    from scenarios.replay.table import NAV, solution_columns
    tc = _time_columns(series.t_ns, origin)
    K = len(tc["t_ns"])
    if not states:
        cols = solution_columns(tc["t_ns"], tc["t_plus_s"], series.position_e, series.velocity_e, series.q_eb,
                                np.zeros((K, NAV)), [])
        return {k: v for k, v in cols.items() if not k.endswith("_sd")}
    cov = np.asarray(series.covariance, float)
    names = list(series.state_names)
    m = len(names)
    if m < NAV or cov.shape != (K, m, m) or np.shape(series.state) != (K, m):
        raise UserError(f"{log_path}: topic {series.topic}: expected {m} state names (at least {NAV}), a covariance "
                        f"({K}, {m}, {m}) and a state ({K}, {m}); got covariance {cov.shape}, state "
                        f"{np.shape(series.state)}")
    P_nav = cov[:, :NAV, :NAV].copy()
    if not full_nav:   # a log that keeps only the diagonal between updates: those epochs have no NED sigmas
        diag_only = ~np.any(P_nav - np.einsum("kii->ki", P_nav)[:, :, None] * np.eye(NAV) != 0.0, axis=(1, 2))
        P_nav[diag_only] = np.nan
    return solution_columns(tc["t_ns"], tc["t_plus_s"], series.position_e, series.velocity_e, series.q_eb,
                            np.diagonal(cov, axis1=1, axis2=2), names, np.asarray(series.state, float), P_nav)


def _measurement_columns(log_path, origin: int) -> dict | None:
    """Every measurement of ``/nav/measurements`` (several share a stamp, hence ``read_multi``):
    source, used, reason, NIS, the innovation's components ``innovation_<i>`` and their predicted
    1-sigma ``innovation_sd_<i>`` (sqrt of S's diagonal), NaN beyond a measurement's size."""
    from scenarios.flightlog import format as lf
    from scenarios.replay.inputs import read_multi
    m = read_multi(log_path, lf.TOPIC_MEASUREMENTS)
    n = len(m["t_ns"])
    if not n:
        return None
    inn = [np.asarray(x, float).ravel() for x in m["innovation"]]
    S = [np.asarray(x, float).ravel() for x in m["innovation_covariance"]]
    width = max(len(x) for x in inn)
    I = np.full((n, width), np.nan)
    D = np.full((n, width), np.nan)
    for i, (a, c) in enumerate(zip(inn, S)):
        I[i, :a.size] = a
        if c.size == a.size * a.size and a.size:
            D[i, :a.size] = np.sqrt(np.clip(np.diag(c.reshape(a.size, a.size)), 0.0, None))
    order = np.argsort(m["t_ns"], kind="stable")
    cols = _time_columns(m["t_ns"][order], origin)
    cols.update(source=np.asarray(m["source"]).astype(str)[order], used=np.asarray(m["used"], bool)[order],
                reason=np.asarray(m["reason"]).astype(str)[order], nis=np.asarray(m["nis"], float)[order],
                size=np.array([x.size for x in inn], np.int64)[order])
    cols.update({f"innovation_{j}": I[order, j] for j in range(width)})
    cols.update({f"innovation_sd_{j}": D[order, j] for j in range(width)})
    return cols


def export_solution(log, log_path, out_dir) -> ExportResult:
    """Export a solution log (module docstring) into ``out_dir``."""
    out = Path(out_dir)
    nav = log.nav
    if "forward" not in nav or not len(nav["forward"].t_ns):
        raise UserError(f"{log_path}: a solution log without /nav/forward messages (an interrupted replay?); "
                        f"nothing to export")
    origin, what = mission_origin_ns(log)
    out.mkdir(parents=True, exist_ok=True)
    res = ExportResult(out)
    res.t_plus_origin = what
    for name in ("forward", "smoothed", "ins_unaided"):
        if name in nav and len(nav[name].t_ns):
            cols = _nav_columns(log_path, nav[name], origin, states=name != "ins_unaided",
                                full_nav=log.info.get("nav_covariance") == "full")
            _write_tables(out, name, cols, res)
    meas = _measurement_columns(log_path, origin)
    if meas is not None:
        _write_tables(out, "measurements", meas, res)
    return res
