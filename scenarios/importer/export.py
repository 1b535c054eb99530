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
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav.timescales import format_utc
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


def _write_csv(path: Path, cols: dict) -> None:
    import pyarrow as pa
    import pyarrow.csv as pcsv
    pcsv.write_csv(pa.table(cols), path, write_options=pcsv.WriteOptions(quoting_style="none"))


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
            mfile.write_bytes(pm[1][0])          # the log's PNG as it is
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
                (d / nm).write_bytes(b)
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
    (out / "mapping.toml").write_text("\n".join(head + sections + cam_img))
    res.files["mapping"] = out / "mapping.toml"
    if video and cam_vid:
        (out / "mapping_video.toml").write_text("\n".join(head + sections + cam_vid))
        res.files["mapping_video"] = out / "mapping_video.toml"
    return res
