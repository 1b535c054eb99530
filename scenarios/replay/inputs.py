"""Flight log -> filter inputs: IMU, GPS, cameras (intrinsics and nominal mounts), the vectors
already in the log, the truth, and the time window of the replay.

Every missing piece that the chosen processing needs is a :class:`scenarios.errors.UserError`
that says what is missing and what can still be done with the log.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav.navigator import GpsData, ImuData
from nav.rotation import quat_to_matrix
from nav.timescales import format_utc, parse_utc
from scenarios.errors import UserError
from scenarios.flightlog.reader import EDGE_FIELDS

NS = 1_000_000_000
TARGETS = ("earth", "sun", "moon")

#: the command line's flag of each parameter that messages name
FLAGS = {"t_from": "--from", "t_to": "--to", "cameras": "--cameras", "targets": "--targets", "vision": "--vision",
         "init": "--init", "init_file": "--init-file", "masks": "--mask", "vision_rate_hz": "--vision-rate",
         "rrd_image_rate_hz": "--rrd-image-rate"}
#: the Python functions' keyword of a parameter where it differs (the state file is ``init=PATH``)
KEYWORDS = {"init_file": "init"}


@dataclass(frozen=True)
class Wording:
    """How error messages and notes name what the caller chose: the keyword arguments of the
    Python functions (:data:`PYTHON`: ``t_from``, ``vision='images'``) or the command line's flags
    (:data:`CLI`: ``--from``, ``--vision images``)."""

    cli: bool = False

    def name(self, param: str) -> str:
        """The parameter's name: ``t_from`` or ``--from``."""
        return FLAGS[param] if self.cli else KEYWORDS.get(param, param)

    def set(self, param: str, value) -> str:
        """The parameter set to ``value``: ``vision='images'`` or ``--vision images``."""
        return f"{FLAGS[param]} {value}" if self.cli else f"{param}={value!r}"

    def given_state(self) -> str:
        """How to give the initial state: ``--init given --init-file STATE.toml`` or ``init=PATH``."""
        return "--init given --init-file STATE.toml" if self.cli else "init=PATH (a state TOML) or init=InitialState(...)"


PYTHON = Wording(False)
CLI = Wording(True)


@dataclass
class CameraSetup:
    """Camera k (1-based): intrinsics (None without CameraInfo), nominal mount R_bc (camera -> body),
    the image stream (None without images), the log's vector series (None without vectors) and the
    simulator's per-frame truth (``/camera_<k>/truth``: ``t_ns``, unit vectors ``nadir_c``,
    ``sun_c``, ``moon_c`` in the true camera frame; None for real flights) and the payload mask
    (``/camera_<k>/payload_mask``: (H, W) bool, True = payload, ignored by the edge search; None
    when the log has none)."""
    k: int
    camera: object | None
    R_bc: np.ndarray | None
    images: object | None
    vectors: dict | None
    truth: dict | None = None
    mask: np.ndarray | None = None


@dataclass
class Truth:
    t_ns: np.ndarray
    x_e: np.ndarray
    v_e: np.ndarray
    q_eb: np.ndarray

    def at(self, t_ns):
        """Truth interpolated at ``t_ns`` (linear in position/velocity, nearest-sample attitude
        rotated by nothing: the truth is written at the IMU rate, 50 ms apart, so callers compare
        at truth stamps where possible)."""
        t = np.asarray(t_ns, np.int64)
        i = np.clip(np.searchsorted(self.t_ns, t), 0, self.t_ns.size - 1)
        return self.x_e[i], self.v_e[i], self.q_eb[i]


@dataclass
class ReplayInputs:
    path: Path
    liftoff_ns: int | None
    imu: ImuData
    gps: GpsData | None
    cameras: dict
    truth: Truth | None
    t_from: int
    t_to: int
    info: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def mission_time(self, t_ns):
        """T+ seconds (seconds since the first IMU sample when the log has no lift-off time)."""
        ref = self.liftoff_ns if self.liftoff_ns is not None else int(self.imu.t_ns[0])
        return (np.asarray(t_ns, np.int64) - ref) / NS

    @property
    def has_images(self) -> bool:
        return any(c.images is not None and len(c.images) for c in self.cameras.values())

    @property
    def has_vectors(self) -> bool:
        return any(c.vectors is not None and len(c.vectors["t_ns"]) for c in self.cameras.values())


def parse_time(spec: str | None, liftoff_ns: int | None, what: str) -> int | None:
    """``T+60`` / ``T+60.5`` (seconds after lift-off) or a UTC ISO time -> int ns; errors begin
    with ``what`` (the parameter)."""
    if spec is None:
        return None
    s = str(spec).strip()
    if s.upper().startswith("T+") or s.upper().startswith("T-"):
        if liftoff_ns is None:
            raise UserError(f"{what} {s}: the log has no lift-off time (metadata liftoff_utc_ns); give a UTC "
                            "time such as 2019-06-13T02:22:00Z")
        try:
            sec = float(s[1:])
        except ValueError:
            raise UserError(f"{what} {s}: expected T+<seconds> or a UTC ISO time") from None
        return int(liftoff_ns + round(sec * NS))
    try:
        return int(parse_utc(s))
    except Exception:
        raise UserError(f"{what} {s}: expected T+<seconds> (e.g. T+60) or a UTC ISO time "
                        "(e.g. 2019-06-13T02:22:00Z)") from None


def read_multi(path, topic: str) -> dict:
    """All messages of a topic that may carry several messages per stamp (``/camera_<k>/vectors``:
    Earth and Sun of one frame; ``/nav/measurements``), decoded with ``mcap_ros2`` in file order.
    ``scenarios.flightlog.reader`` keeps one message per stamp and topic (see docs/replay.md)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    out: dict = {"t_ns": []}
    with open(path, "rb") as f:
        for _, _, message, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=[topic]):
            out["t_ns"].append(message.log_time)
            for name in msg.__slots__:
                if name == "header":
                    continue
                out.setdefault(name, []).append(getattr(msg, name))
    res = {"t_ns": np.array(out.pop("t_ns"), np.int64)}
    for k, v in out.items():
        try:
            res[k] = np.array(v)
        except ValueError:
            res[k] = np.array(v, dtype=object)
    return res


def _vectors_of(path, log, k: int) -> dict | None:
    topic = f"/camera_{k}/vectors"
    if topic not in log.topics:
        return None
    s = log.series.get(topic)
    if s is not None and log.topics[topic].message_count == len(s):
        d = {"t_ns": s.t_ns, "target": np.asarray(s.target).astype(str), "vector": s.vector, "covariance": s.covariance}
        d.update({f: np.asarray(s.fields[f], float) for f in EDGE_FIELDS if f in s.fields})
    else:  # several vectors per stamp
        r = read_multi(path, topic)
        d = {"t_ns": r["t_ns"], "target": r["target"].astype(str), "vector": np.asarray(r["vector"], float).reshape(-1, 3),
             "covariance": np.asarray(r["covariance"], float).reshape(-1, 3, 3)}
        d.update({f: np.asarray(r[f], float).reshape(len(r["t_ns"]), -1).squeeze(-1) if f != "edge_sensitivity"
                  else np.asarray(r[f], float).reshape(-1, 3) for f in EDGE_FIELDS if f in r})
    order = np.argsort(d["t_ns"], kind="stable")
    return {key: v[order] for key, v in d.items()}


def camera_from_info(info, i: int = 0):
    from vision.camera import from_camera_info
    d = info.d
    di = d[i] if (getattr(d, "dtype", None) == object or np.ndim(d) == 2) else d
    return from_camera_info({"distortion_model": str(info.distortion_model[i]), "d": np.asarray(di, float),
                             "k": np.asarray(info.k[i], float).reshape(9), "r": np.asarray(info.r[i], float).reshape(9),
                             "width": int(info.width[i]), "height": int(info.height[i])})


def load_inputs(path, *, t_from: str | None = None, t_to: str | None = None, cameras=None,
                need_gps: bool = True, wording: Wording = PYTHON) -> ReplayInputs:
    """Read the log at ``path`` (see the module docstring). ``cameras``: camera numbers to use
    (default all); ``t_from``/``t_to``: window (T+ seconds or UTC ISO); ``wording``: how errors
    name these parameters."""
    from scenarios.flightlog.reader import LogWarning, read_log
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: log file not found")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LogWarning)
        log = read_log(p)
    notes = [str(w.message) for w in caught if "duplicate time stamp" not in str(w.message)]
    info = log.info
    liftoff = int(info["liftoff_utc_ns"]) if info.get("liftoff_utc_ns", "") not in ("", None) else None
    # IMU
    if log.imu is not None and len(log.imu):
        imu = ImuData(log.imu.t_ns, np.asarray(log.imu.accel, float), np.asarray(log.imu.gyro, float),
                      info.get("imu_sample", "average") or "average")
    elif log.imu_increment is not None and len(log.imu_increment):
        s = log.imu_increment
        dt = np.asarray(s.dt, float)[:, None]
        imu = ImuData(s.t_ns, np.asarray(s.delta_velocity) / dt, np.asarray(s.delta_angle) / dt, "average")
    else:
        what = [t for t in log.topics if t.startswith("/camera") or t in ("/gps",)]
        raise UserError(f"{p}: no IMU (/imu or /imu_increment): the filter cannot run without it. "
                        + (f"The log has {', '.join(sorted(what))}: `horizon-nav vision` can still process "
                           "the images on their own." if what else "The log holds nothing the replay can use."))
    gps = None
    if log.gps is not None and len(log.gps):
        g = log.gps
        gps = GpsData(g.t_ns, np.asarray(g.position, float), np.asarray(g.position_covariance, float),
                      np.asarray(g.velocity, float), np.asarray(g.velocity_covariance, float))
    elif need_gps:
        raise UserError(f"{p}: no GPS fixes (/gps): the replay needs GPS for the initial position and velocity "
                        f"and to bound the INS drift. What can still be done: replay with `{wording.given_state()}` "
                        "(position, velocity and attitude at the start) for a vision/INS "
                        "solution, or `horizon-nav vision` on the images alone")
    truth = None
    if log.truth is not None and len(log.truth):
        t = log.truth
        truth = Truth(t.t_ns, np.asarray(t.position_e, float), np.asarray(t.velocity_e, float), np.asarray(t.q_eb, float))
    # cameras
    cams = {}
    want = None if cameras is None else {int(c) for c in cameras}
    for k, cl in log.cameras.items():
        if want is not None and k not in want:
            continue
        tf = log.tf_static.get(f"camera_{k}")
        R_bc = quat_to_matrix(np.asarray(tf.q, float)) if tf is not None else None
        cam = None
        if cl.info is not None and len(cl.info):
            try:
                cam = camera_from_info(cl.info)
            except ValueError as e:
                raise UserError(f"{p}: /camera_{k}/camera_info: {e}") from None
        ct = None
        if cl.truth is not None and len(cl.truth):
            ct = {"t_ns": np.asarray(cl.truth.t_ns, np.int64)}
            for name in ("nadir_c", "sun_c", "moon_c"):
                ct[name] = np.asarray(getattr(cl.truth, name), float).reshape(-1, 3)
        cams[k] = CameraSetup(k, cam, R_bc, cl.images if cl.images is not None and len(cl.images) else None,
                              _vectors_of(p, log, k), ct, _payload_mask(p, log, k, cam))
    if want is not None:
        missing = sorted(want - set(cams))
        if missing:
            raise UserError(f"{wording.name('cameras')}: camera(s) {missing} not in {p} (it has {sorted(log.cameras) or 'none'})")
    t0, t1 = int(imu.t_ns[0]), int(imu.t_ns[-1])
    a = parse_time(t_from, liftoff, wording.name("t_from"))
    b = parse_time(t_to, liftoff, wording.name("t_to"))
    a = t0 if a is None else a
    b = t1 if b is None else b
    rng = f"{format_utc(t0)} .. {format_utc(t1)}"
    if liftoff is not None:
        rng += f" (T+{(t0 - liftoff) / NS:.1f} .. T+{(t1 - liftoff) / NS:.1f} s)"
    window = f"{wording.name('t_from')}/{wording.name('t_to')}"
    if b <= a:
        raise UserError(f"{window}: the window is empty (end not after start); the log's IMU covers {rng}")
    if a >= t1 or b <= t0:
        raise UserError(f"{window}: the window lies outside the log; its IMU covers {rng}")
    a, b = max(a, t0), min(b, t1)
    return ReplayInputs(p, liftoff, imu, gps, cams, truth, a, b, dict(info), notes)


def frames_in(t_ns, a, b, rate_hz=None) -> np.ndarray:
    """Indices of the frames in [a, b]; with ``rate_hz`` the first frame of every 1/rate_hz bucket
    from ``a`` on (a 30 frames/s video at 5 Hz: every 6th frame)."""
    t = np.asarray(t_ns, np.int64)
    sel = np.flatnonzero((t >= a) & (t <= b))
    if rate_hz is None or sel.size == 0:
        return sel
    bucket = ((t[sel] - a) * float(rate_hz) // NS).astype(np.int64)
    return sel[np.unique(bucket, return_index=True)[1]]


def window_imu(imu: ImuData, a: int, b: int) -> ImuData:
    m = (imu.t_ns >= a) & (imu.t_ns <= b)
    return ImuData(imu.t_ns[m], imu.f_b[m], imu.w_b[m], imu.sample)


def window_gps(gps: GpsData | None, a: int, b: int) -> GpsData | None:
    if gps is None:
        return None
    m = (gps.t_ns >= a) & (gps.t_ns <= b)
    return GpsData(gps.t_ns[m], gps.x_e[m], gps.P_x[m], None if gps.v_e is None else gps.v_e[m],
                   None if gps.P_v is None else gps.P_v[m])


__all__ = ["CameraSetup", "ReplayInputs", "Truth", "load_inputs", "parse_time", "read_multi", "window_imu",
           "window_gps", "camera_from_info", "TARGETS", "Wording", "PYTHON", "CLI"]


def _payload_mask(path, log, k, camera) -> np.ndarray | None:
    """The log's ``/camera_<k>/payload_mask`` (first message, non-zero = payload) as a (H, W) bool
    array, checked against the camera's size; None when absent."""
    from scenarios.config.camera import payload_mask_from_image
    item = log.other.get(f"/camera_{k}/payload_mask")
    if item is None or not len(item[0]):
        return None
    return payload_mask_from_image(item[1][0], camera, f"{path}: /camera_{k}/payload_mask")
