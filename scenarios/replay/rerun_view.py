"""Rerun recording of a replay (rerun-sdk 0.41.0), laid out for inspection (003 figs. 36-44).

Entities (timelines ``utc`` = absolute time and ``mission_time`` = T+ seconds):

* ``world/earth`` WGS-84 ellipsoid, ``world/trajectory`` the forward solution (ECEF, metres);
  ``world/vehicle/aided`` and ``world/vehicle/unaided`` the body axes x (red), y (green), z (blue)
  of the filter and of the free-inertial INS, ``world/vehicle/att_3sigma`` spheres at the aided
  axis tips whose radius is the 3-sigma attitude bound times the axis length (fig. 40),
  ``world/vehicle/camera_<k>/earth|sun`` the measured Earth-nadir and Sun vectors rotated into e
  with the solution's attitude and mounting, ``world/vehicle/sun`` the Sun direction from the
  ephemeris, ``world/vehicle/rcs`` the measured specific force when above 0.7 mg during the coast
  (RCS thrust, fig. 38: the logs carry no thruster state, the accelerometer sees the firing).
  Drawn once per second of flight; the measured vectors at their camera's frame times.
* ``camera_<k>/image`` each frame as its JPEG bytes (EncodedImage) with ``.../<target>/edges``
  (candidates), ``inliers``, ``outliers``, ``conic`` (fitted cone through the distorted camera model)
  and ``point`` (vector image point), 003 figs. 15, 27.
* time series (send_columns): ``innovation/camera_<k>/<target>/<i>`` [deg] with ``+3sigma``/``-3sigma``
  (fig. 41), ``gps_innovation/<position|velocity>/<i>`` [m, m/s] likewise,
  ``angle_residual/<aided|unaided>/camera_<k>/<target>`` measured-vs-predicted angle [deg] (fig. 42;
  innovations and angles of the measurements the filter used;
  aided: the innovation's norm, unaided: predicted with the free-inertial attitude, the solution's
  position and the nominal mount),
  ``misalignment/camera_<k>/<axis>`` with 3 sigma (fig. 43), ``attitude_3sigma/<axis>`` (fig. 40),
  ``aided_minus_unaided/<axis>`` (fig. 39), ``triad_minus_solution/<axis>`` and
  ``triad_minus_unaided/<axis>`` (fig. 44 b, a),
  ``error/attitude/<axis>`` and ``error/position``, ``error/velocity`` when the log has truth.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav import earth
from nav.ephemeris import sun_position_e
from nav.rotation import matrix_to_rotvec, quat_to_matrix
from scenarios.atomic import move_into_place
from scenarios.replay.solution_log import source_name
from scenarios.replay.verdict import recovery_rows, recovery_text
from scenarios.replay.summary import attitude_error

NS = 1_000_000_000
AXIS_LEN = 60e3         # body-axis arrows [m] (the scene spans the Earth)
VEC_LEN = 90e3
RGB = np.array([[230, 60, 60], [60, 200, 60], [70, 110, 240]], np.uint8)
AXES = "xyz"


def _times(rr, inp, t_ns):
    t = np.asarray(t_ns, np.int64)
    return [rr.TimeColumn("utc", timestamp=t.astype("datetime64[ns]")),
            rr.TimeColumn("mission_time", duration=inp.mission_time(t))]


def _series(rec, rr, inp, path, t_ns, values):
    v = np.asarray(values, float)
    if v.size == 0:
        return
    rec.send_columns(path, indexes=_times(rr, inp, t_ns), columns=rr.Scalars.columns(scalars=v))


def blueprint(cam_numbers, x_e=None):
    """The default layout: 3D scene and camera frames left, the time series of 003 figs. 39-44 as
    tabs right. ``x_e``: the trajectory (N, 3), to aim the 3D eye at its middle from 1500 km."""
    import rerun.blueprint as rrb
    cams = [rrb.Spatial2DView(origin=f"camera_{k}/image", name=f"camera {k}") for k in cam_numbers]
    whole = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                  end=rrb.TimeRangeBoundary.infinite()))
    ts = [rrb.TimeSeriesView(origin=o, name=n, axis_x=whole) for o, n in (
          ("innovation", "camera innovations ±3σ [deg] (fig. 41)"),
          ("angle_residual", "measured − predicted angle [deg] (fig. 42)"),
          ("misalignment", "misalignment ±3σ [deg] (fig. 43)"),
          ("attitude_3sigma", "attitude 3σ [deg] (fig. 40)"),
          ("aided_minus_unaided", "aided − unaided [deg] (fig. 39)"),
          ("triad_minus_solution", "TRIAD − aided [deg] (fig. 44 b)"),
          ("triad_minus_unaided", "TRIAD − unaided [deg] (fig. 44 a)"),
          ("gps_innovation", "GPS innovations ±3σ [m, m/s]"),
          ("error", "error vs truth [deg, m, m/s]"))]
    ts.append(rrb.TextLogView(origin="events", name="recoveries"))
    eye = None
    if x_e is not None and len(x_e):
        x = np.asarray(x_e, float)
        mid = x[len(x) // 2]
        up = mid / np.linalg.norm(mid)
        side = np.cross(up, x[-1] - x[0])
        side = side / np.linalg.norm(side) if np.linalg.norm(side) > 0 else np.cross(up, [0.0, 0.0, 1.0])
        eye = rrb.EyeControls3D(position=mid + 1.2e6 * side + 0.9e6 * up, look_target=mid, eye_up=up)
    left = rrb.Vertical(rrb.Spatial3DView(origin="world", name="3D (fig. 38)", eye_controls=eye),
                        rrb.Horizontal(*cams) if cams else rrb.TextDocumentView(origin="notes"), row_shares=[3, 2])
    return rrb.Blueprint(rrb.Horizontal(left, rrb.Tabs(*ts), column_shares=[3, 2]),
                         rrb.TimePanel(timeline="mission_time", play_state="paused", state="collapsed"),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"))


@dataclass
class Recording:
    """An open recording between :func:`begin` and :func:`finish` (or :func:`abandon`)."""

    rec: object
    path: Path | None   #: final .rrd (None: viewer only)
    tmp: Path | None    #: the file being written, renamed to ``path`` by :func:`finish`
    timings: dict
    shown: set = field(default_factory=set)   #: (k, t_ns) of the frames whose images were sent


class RecordingStopped(Exception):
    """:func:`begin` was told to stop (its ``stop`` event set) while sending the images."""


def begin(inp, frames, cam_numbers, path: Path | None, *, spawn: bool = False, track=None,
          timings: dict | None = None, image_rate_hz: float | None = None, stop=None) -> Recording:
    """Open the recording (``path`` .rrd, written to a temporary name until :func:`finish`, and/or
    the viewer) and send the camera images of ``frames`` (anything with ``k`` and ``t_ns``: the
    vision's frames, before or after the front end ran): most of the recording's bytes, which
    Rerun encodes and writes in its own threads while the caller goes on (the replay begins the
    recording in a thread while the vision workers run). ``track``: positions (N, 3) known before
    the filter (GPS) to aim the 3D view. ``image_rate_hz``: the camera images (and their
    :func:`overlays`) at most this many per second and camera (the first frame of each interval;
    the vectors and time series keep every frame): a 30 frames/s video otherwise copies ~9 MB of
    JPEG per second of flight into the recording. ``timings`` (optional dict) receives the seconds
    per part (static, images, overlays, scene, series, flush). ``stop`` (a ``threading.Event``):
    when set, the images stop within one send, the recording is abandoned and
    :class:`RecordingStopped` raised (the replay was interrupted meanwhile)."""
    import time
    import rerun as rr
    tm = timings if timings is not None else {}
    t = time.perf_counter()
    rec = rr.RecordingStream("horizon-nav", recording_id=f"replay-{Path(inp.path).stem}")
    tmp = None
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        tmp = temporary_path(path)
        rec.save(str(tmp), default_blueprint=blueprint(cam_numbers, track))
    if spawn:
        rec.spawn(default_blueprint=blueprint(cam_numbers, track))
    shown = shown_frames(frames, cam_numbers, image_rate_hz)
    r = Recording(rec, None if path is None else Path(path), tmp, tm, {(f.k, f.t_ns) for f in shown})
    tm["static"] = time.perf_counter() - t
    t = time.perf_counter()
    try:
        _images(rec, rr, inp, shown, cam_numbers, stop)
    except BaseException:
        abandon(r)
        raise
    tm["images"] = time.perf_counter() - t
    return r


def overlays(r: Recording, inp, frames, cam_numbers) -> None:
    """The front end's overlays (``frames``: vision_worker.FrameOutput) on the images
    :func:`begin` sent: those of the frames among them whose images were sent (``r.shown``). Called
    for consecutive parts of the frames, the parts' rows follow each other."""
    import time
    import rerun as rr
    t = time.perf_counter()
    _overlays(r.rec, rr, inp, [f for f in frames if (f.k, f.t_ns) in r.shown], cam_numbers)
    r.timings["overlays"] = r.timings.get("overlays", 0.0) + time.perf_counter() - t


def solution(r: Recording, inp, res, vectors, cam_numbers, frames) -> None:
    """The forward solution's static parts (ellipsoid, trajectory, camera models), the 3D scene
    (``frames``: anything with ``k`` and ``t_ns``) and the time series."""
    import time
    import rerun as rr
    for name, fn, args in (("static", _static, (r.rec, rr, inp, res)),
                           ("scene", _scene, (r.rec, rr, inp, res, vectors, cam_numbers, frames)),
                           ("series", _timeseries, (r.rec, rr, inp, res, vectors, cam_numbers)),
                           ("series", _events, (r.rec, rr, inp, res, cam_numbers))):
        t = time.perf_counter()
        fn(*args)
        r.timings[name] = r.timings.get(name, 0.0) + time.perf_counter() - t


def finish(r: Recording, inp, res, smooth) -> Path | None:
    """The smoother's time series (after :func:`solution`; ``smooth`` None: none), then wait for
    Rerun to write everything and move the file to its name; returns the path."""
    import time
    import rerun as rr
    tm = r.timings
    t = time.perf_counter()
    if smooth is not None:
        _smoothed_timeseries(r.rec, rr, inp, res, smooth)
    tm["series"] = tm.get("series", 0.0) + time.perf_counter() - t
    t = time.perf_counter()
    r.rec.flush()
    if r.tmp is not None:
        r.rec.disconnect()
        move_into_place(r.tmp, r.path)
    tm["flush"] = time.perf_counter() - t
    return r.path


def temporary_path(path: Path) -> Path:
    """The name a recording is written to until :func:`finish` moves it to ``path``."""
    return Path(path).with_name("." + Path(path).name + ".tmp")


def abandon(r: Recording | None) -> None:
    """Close an unfinished recording and delete its temporary file (the run failed or was
    interrupted before the solution existed: no half recording under the final name)."""
    if r is None:
        return
    try:
        r.rec.disconnect()
    finally:
        if r.tmp is not None:
            r.tmp.unlink(missing_ok=True)


def _static(rec, rr, inp, res):
    rec.log("world/earth", rr.Ellipsoids3D(half_sizes=[[earth.A, earth.A, earth.B]], colors=[[40, 90, 160]],
                                           line_radii=[2000.0]), static=True)
    step = max(1, len(res.t_ns) // 4000)
    rec.log("world/trajectory", rr.LineStrips3D([res.x_e[::step]], colors=[[255, 200, 0]], radii=[800.0]), static=True)
    if len(res.unaided_x_e):
        rec.log("world/trajectory_unaided", rr.LineStrips3D([res.unaided_x_e[::step]], colors=[[160, 160, 160]],
                                                             radii=[500.0]), static=True)
    for k, c in inp.cameras.items():
        if c.camera is not None:
            rec.log(f"camera_{k}/image", rr.Pinhole(image_from_camera=np.asarray(c.camera.K if hasattr(c.camera, "K") else
                                                                                   _K(c.camera)), width=c.camera.width,
                                                   height=c.camera.height), static=True)


def _events(rec, rr, inp, res, cam_numbers):
    """The filter's recoveries (`nav.recovery`: re-initialisations from GPS, re-opened camera
    misalignments) as warnings on ``events`` at their times, in the verdict's words."""
    rows = recovery_rows(res.recoveries, cam_numbers)
    if rows:
        rec.send_columns("events", indexes=_times(rr, inp, [r["t_ns"] for r in rows]),
                         columns=rr.TextLog.columns(text=[recovery_text(r) for r in rows], level=["WARN"] * len(rows)))


def _K(cam):
    from vision.camera import to_opencv
    return to_opencv(cam)[0]


def _arrows(rec, rr, inp, path, t_ns, origins, vectors, lengths, colors, radius):
    """Time-varying arrows as columns: ``lengths[i]`` arrows at ``t_ns[i]`` (0 = none shown from then
    on); colours and radius are static (one value per arrow index)."""
    rec.log(path, rr.Arrows3D.from_fields(colors=colors, radii=[radius]), static=True)
    rec.send_columns(path, indexes=_times(rr, inp, t_ns),
                     columns=rr.Arrows3D.columns(origins=np.asarray(origins, float).reshape(-1, 3),
                                                 vectors=np.asarray(vectors, float).reshape(-1, 3)).partition(lengths))


def _scene(rec, rr, inp, res, vectors, cam_numbers, frames=()):
    """The 3D scene once per second of flight (fig. 38), all entities as columns."""
    t = res.t_ns
    sel = np.unique(np.searchsorted(t, np.arange(t[0], t[-1] + 1, NS)).clip(0, len(t) - 1))
    ts = t[sel]
    n = len(sel)
    ones3 = np.full(n, 3)
    R = quat_to_matrix(res.q_eb[sel])
    x = res.x_e[sel]
    ax = np.swapaxes(R, -1, -2) * AXIS_LEN                       # rows: body axes in e
    _arrows(rec, rr, inp, "world/vehicle/aided", ts, np.repeat(x, 3, axis=0), ax, ones3, RGB, 900.0)
    if len(res.unaided_q_eb):
        Ru = quat_to_matrix(res.unaided_q_eb[sel])
        _arrows(rec, rr, inp, "world/vehicle/unaided", ts, np.repeat(res.unaided_x_e[sel], 3, axis=0),
                np.swapaxes(Ru, -1, -2) * AXIS_LEN, ones3, RGB // 2, 600.0)
    sig = np.sqrt(res.P_diag[:, res.layout["psi"]])
    ci = np.clip(np.searchsorted(res.cov_t_ns, ts), 0, len(res.cov_t_ns) - 1)
    r3 = 3 * sig[ci].max(axis=1) * AXIS_LEN
    path = "world/vehicle/att_3sigma"
    rec.log(path, rr.Ellipsoids3D.from_fields(colors=RGB, line_radii=[300.0]), static=True)
    rec.send_columns(path, indexes=_times(rr, inp, ts),
                     columns=rr.Ellipsoids3D.columns(centers=(x[:, None, :] + ax).reshape(-1, 3),
                                                     half_sizes=np.repeat(r3, 9).reshape(-1, 3)).partition(ones3))
    s = sun_position_e(ts) - x
    _arrows(rec, rr, inp, "world/vehicle/sun", ts, x, s / np.linalg.norm(s, axis=1, keepdims=True) * VEC_LEN,
            np.ones(n, int), [[255, 230, 80]], 500.0)
    fi = np.clip(np.searchsorted(inp.imu.t_ns, ts), 0, len(inp.imu.t_ns) - 1)
    f = np.asarray(inp.imu.f_b)[fi]
    fn = np.linalg.norm(f, axis=1)
    on = (fn > 0.7e-3 * 9.80665) & (fn < 0.05 * 9.80665)
    d = np.einsum("nij,nj->ni", R[on], f[on] / fn[on, None]) * AXIS_LEN * 0.7
    _arrows(rec, rr, inp, "world/vehicle/rcs", ts, x[on], d, on.astype(int), [[255, 0, 255]], 1200.0)
    if vectors is None or not len(vectors.t_ns):
        return
    # measured vectors in e with the solution's attitude and the nominal mount, at the frame times of
    # their camera (no arrow at a frame without that vector)
    R_bc = np.array([inp.cameras[k].R_bc for k in cam_numbers])
    for c, k in enumerate(cam_numbers):
        ft = np.unique(np.array([f.t_ns for f in frames if f.k == k], np.int64))
        for tgt in np.unique(vectors.target):
            m = (vectors.camera == c) & (vectors.target == tgt)
            if not m.any():
                continue
            tv = vectors.t_ns[m]
            frame_t = np.union1d(ft, tv) if ft.size else np.unique(tv)
            first = np.unique(tv, return_index=True)[1]           # one vector per stamp and target
            tv, ev = tv[first], vectors.e_c[m][first]
            j = np.clip(np.searchsorted(t, tv), 0, len(t) - 1)
            dv = np.einsum("nij,jk,nk->ni", quat_to_matrix(res.q_eb[j]), R_bc[c], ev) * VEC_LEN
            name = {"hor": "earth"}.get(str(tgt), str(tgt))
            lengths = np.isin(frame_t, tv).astype(int)
            _arrows(rec, rr, inp, f"world/vehicle/camera_{k}/{name}", frame_t, res.x_e[j], dv, lengths,
                    [[0, 220, 255] if name == "earth" else [255, 150, 0]], 500.0)


_OVERLAY = (("edges", [150, 150, 150], 1.0), ("inliers", [0, 255, 0], 1.5), ("outliers", [255, 0, 0], 1.5),
            ("conic", None, 1.5), ("point", None, 8.0))


#: JPEG bytes read and sent to Rerun at a time: a long video log's images are not all held in
#: memory (a 6 min coast at 30 frames/s and two cameras is ~3 GB); Rerun is flushed between
#: batches. Below 2 GiB: Arrow list offsets are int32.
IMAGE_BATCH_BYTES = 2 ** 30


#: Images per column send (one Rerun chunk each, ~1 MB of JPEG). Rerun encodes and writes small
#: chunks much faster than large ones; 8 frames per chunk costs the least CPU of the sizes
#: compared (docs/performance.md).
IMAGES_PER_SEND = 8


def image_batches(inp, frames, cam_numbers, max_bytes: int | None = None) -> list:
    """The frames (anything with ``k`` and ``t_ns``) in time order, cut into consecutive batches
    of at most ``max_bytes`` (default :data:`IMAGE_BATCH_BYTES`) of image messages (at least one
    frame each), from the message sizes in the log index: nothing is read."""
    max_bytes = IMAGE_BATCH_BYTES if max_bytes is None else max_bytes
    fr = sorted((f for f in frames if f.k in cam_numbers), key=lambda f: (f.t_ns, f.k))
    if not fr:
        return []
    t = np.array([f.t_ns for f in fr], np.int64)
    cam = np.array([f.k for f in fr])
    size = np.empty(len(fr), np.int64)
    for k in cam_numbers:
        m = cam == k
        if m.any():
            st = inp.cameras[k].images
            size[m] = st.sizes[_image_index(st, t[m])]
    out, lo, acc = [], 0, 0
    for i, b in enumerate(size.tolist()):
        if i > lo and acc + b > max_bytes:
            out.append(fr[lo:i])
            lo, acc = i, 0
        acc += b
    out.append(fr[lo:])
    return out


def _images(rec, rr, inp, frames, cam_numbers, stop=None):
    """Each frame as its JPEG bytes (EncodedImage): the frames in :func:`image_batches`, sent as
    :func:`image_sends` gives them, waiting for Rerun to write each batch before the next is read
    when there are several; :class:`RecordingStopped` once ``stop`` is set."""
    for k in cam_numbers:
        if any(f.k == k for f in frames):
            rec.log(f"camera_{k}/image", rr.EncodedImage.from_fields(media_type="image/jpeg"), static=True)
    for n, batch in enumerate(image_batches(inp, frames, cam_numbers)):
        if n:
            rec.flush()    # bounded memory: the previous batch is written before this one is read
        for k, t, blobs in image_sends(inp, batch, cam_numbers):
            if stop is not None and stop.is_set():
                raise RecordingStopped
            rec.send_columns(f"camera_{k}/image", indexes=_times(rr, inp, t),
                             columns=rr.EncodedImage.columns(blob=_blob_batch(blobs)))


def image_sends(inp, frames, cam_numbers):
    """``(camera, times (n,), JPEG bytes)`` per column send of the frames' images, at most
    :data:`IMAGES_PER_SEND` images each: the frames are read in groups of that many per camera, in
    time order (the log's order), and each image is a view into the log's decompressed chunk
    (:func:`read_images`), so a group holds a few chunks, freed once its sends are made.

    Reading a batch's images whole would hold every chunk of the log at once: hundreds of MB of
    fresh memory for a video log, and the page faults' system time in the recording process.
    """
    fr = sorted((f for f in frames if f.k in cam_numbers), key=lambda f: (f.t_ns, f.k))
    group = IMAGES_PER_SEND * max(1, len({f.k for f in fr}))
    for g in range(0, len(fr), group):
        part = fr[g:g + group]
        got = read_images(inp, part, cam_numbers)
        for k in cam_numbers:
            t = np.array([f.t_ns for f in part if f.k == k], np.int64)    # in order: fr is
            for s in range(0, t.size, IMAGES_PER_SEND):
                yield k, t[s:s + IMAGES_PER_SEND], got[k][s:s + IMAGES_PER_SEND]
        del got


def _overlays(rec, rr, inp, frames, cam_numbers):
    """The overlays of the frames, one column send per entity (a frame without an overlay part
    shows none: empty row)."""
    for k in cam_numbers:
        fr = sorted((f for f in frames if f.k == k), key=lambda f: f.t_ns)
        if not fr:
            continue
        t = np.array([f.t_ns for f in fr], np.int64)
        base = f"camera_{k}/image"
        for target in ("earth", "sun", "moon"):
            ov = [f.overlay.get(target, {}) for f in fr]
            if not any(ov):
                continue
            col = [0, 220, 255] if target == "earth" else [255, 150, 0]
            for name, colour, radius in _OVERLAY:
                p = f"{base}/{target}/{name}"
                parts = [np.asarray(o.get(name, np.zeros((0, 2))), np.float32).reshape(-1, 2) for o in ov]
                if name == "conic":
                    strips = [_split(a) for a in parts]
                    rec.log(p, rr.LineStrips2D.from_fields(colors=[col], radii=[radius]), static=True)
                    flat = [s for ss in strips for s in ss]
                    rec.send_columns(p, indexes=_times(rr, inp, t),
                                     columns=rr.LineStrips2D.columns(strips=flat).partition([len(ss) for ss in strips]))
                else:
                    rec.log(p, rr.Points2D.from_fields(colors=[colour or col], radii=[radius]), static=True)
                    rec.send_columns(p, indexes=_times(rr, inp, t),
                                     columns=rr.Points2D.columns(positions=np.concatenate(parts)).partition(
                                         [len(a) for a in parts]))


def shown_frames(frames, cam_numbers, rate_hz=None) -> list:
    """The frames (anything with ``k`` and ``t_ns``) whose images go into the recording: all, or
    with ``rate_hz`` the first one per 1/rate_hz interval of each camera."""
    return list(frames) if rate_hz is None else _every(frames, cam_numbers, rate_hz)


def _every(frames, cam_numbers, rate_hz) -> list:
    """The frames of each camera thinned to the first one per 1/rate_hz interval."""
    from scenarios.replay.inputs import frames_in
    out = []
    for k in cam_numbers:
        fr = sorted((f for f in frames if f.k == k), key=lambda f: f.t_ns)
        if fr:
            t = np.array([f.t_ns for f in fr], np.int64)
            out += [fr[i] for i in frames_in(t, int(t[0]), int(t[-1]), rate_hz)]
    return out


def _image_index(stream, t_ns) -> np.ndarray:
    """Index in ``stream`` of the image of each frame time: the one at or after it (the last one
    past the end)."""
    return np.clip(np.searchsorted(stream.t_ns, t_ns), 0, len(stream) - 1)


def read_images(inp, frames, cam_numbers) -> dict:
    """camera -> the JPEG bytes of its frames (time order, the image at or after each frame time),
    each a uint8 array viewing the log's decompressed chunk (:meth:`ImageStream.view`: not copied).

    The images of all cameras are read in log time order, the order of the log's chunks: the
    reader keeps one decompressed chunk, so each chunk is decompressed once (camera by camera,
    every chunk holding frames of several cameras was decompressed once per camera).
    """
    want = []  # (t, camera, position in its frame list, image index)
    for k in cam_numbers:
        st = inp.cameras[k].images
        t = np.sort(np.array([f.t_ns for f in frames if f.k == k], np.int64))
        if not t.size:
            continue
        want += [(int(st.t_ns[i]), k, p, int(i)) for p, i in enumerate(_image_index(st, t))]
    out = {k: [None] * sum(1 for f in frames if f.k == k) for k in cam_numbers}
    for _, k, p, i in sorted(want):
        out[k][p] = inp.cameras[k].images.view(i)
    return out


def _blob_batch(blobs):
    """The JPEG bytes (uint8 arrays, at least one) as one Arrow list array, copied once into one
    buffer, much faster for a flight's frames than the array ``EncodedImage.columns(blob=list)``
    builds blob by blob."""
    import pyarrow as pa
    from rerun.encodings import BlobBatch
    off = np.zeros(len(blobs) + 1, np.int32)
    off[1:] = np.cumsum([b.size for b in blobs])
    return BlobBatch(pa.ListArray.from_arrays(pa.array(off), pa.array(np.concatenate(blobs)),
                                              type=BlobBatch._ARROW_DATATYPE))


def _split(poly):
    """Finite runs of a polyline (NaN marks the cut points) as separate strips of >= 2 points."""
    poly = np.asarray(poly).reshape(-1, 2)
    if not len(poly):
        return []
    ok = np.all(np.isfinite(poly), axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    return [poly[a:b] for a, b in zip(edges[::2], edges[1::2]) if b - a > 1]


def _predicted_c(inp, q_eb, x_e, t_ns, target, R_bc):
    """Unit vector to ``target`` ('hor' geocentric nadir, 'sun', 'moon') in the camera frame with
    attitude ``q_eb`` and position ``x_e`` (003 eq. (39))."""
    from nav.ephemeris import moon_direction_e, sun_direction_e
    if target == "hor":
        d = -x_e / np.linalg.norm(x_e, axis=1, keepdims=True)
    elif target == "sun":
        d = sun_direction_e(t_ns, x_e)
    else:
        d = moon_direction_e(t_ns, x_e)
    R_eb = quat_to_matrix(q_eb)
    return np.einsum("ji,nkj,nk->ni", R_bc, R_eb, d)


def _timeseries(rec, rr, inp, res, vectors, cam_numbers):
    """The forward solution's series (the smoother's: :func:`_smoothed_timeseries`)."""
    # innovations with +-3 sigma (fig. 41) and angle residuals (fig. 42): the measurements the filter
    # used (rejected ones are in the solution log's /nav/measurements with their reason)
    groups = {}
    for inn in res.innovations:
        if inn.accepted:
            groups.setdefault(source_name(inn.kind, inn.camera, cam_numbers), []).append(inn)
    used = {(int(i.t_ns), i.kind, int(i.camera)) for i in res.innovations if i.accepted}
    for src, lst in groups.items():
        s = np.array([i.s for i in lst], float)
        fin = np.all(np.isfinite(s.reshape(len(lst), -1)), axis=1)
        if not fin.any():
            continue
        if not fin.all():
            lst = [i for i, f in zip(lst, fin) if f]
            s = s[fin]
        t = np.array([i.t_ns for i in lst], np.int64)
        S = np.sqrt(np.clip(np.diagonal(np.array([i.S for i in lst], float), axis1=1, axis2=2), 0, None))
        cam = src.startswith("camera_")
        base, f = ("innovation/" + src, math.degrees(1.0)) if cam else ("gps_innovation/" + src.removeprefix("gps/"), 1.0)
        for c in range(s.shape[1]):
            _series(rec, rr, inp, f"{base}/{c}", t, f * s[:, c])
            _series(rec, rr, inp, f"{base}/{c}_+3sigma", t, 3 * f * S[:, c])
            _series(rec, rr, inp, f"{base}/{c}_-3sigma", t, -3 * f * S[:, c])
        if src.startswith("camera_"):
            _series(rec, rr, inp, f"angle_residual/aided/{src}", t, np.degrees(np.linalg.norm(s, axis=1)))
    # unaided angle residuals (fig. 42 a): the measured vectors against the ones predicted with the
    # free-inertial attitude (GPS-aided position, nominal mount), the vectors the filter used
    if len(res.unaided_q_eb) and vectors is not None and len(vectors.t_ns):
        from nav.rotation import angle_between
        j = np.clip(np.searchsorted(res.t_ns, vectors.t_ns), 0, len(res.t_ns) - 1)
        ok = np.array([(int(t), str(g), int(c)) in used for t, g, c in zip(vectors.t_ns, vectors.target, vectors.camera)],
                      bool)
        for c, k in enumerate(cam_numbers):
            for tgt in np.unique(vectors.target):
                m = (vectors.camera == c) & (vectors.target == tgt) & ok
                if not m.any():
                    continue
                jm = j[m]
                e = _predicted_c(inp, res.unaided_q_eb[jm], res.x_e[jm], res.t_ns[jm], str(tgt), inp.cameras[k].R_bc)
                name = {"hor": "earth"}.get(str(tgt), str(tgt))
                _series(rec, rr, inp, f"angle_residual/unaided/camera_{k}/{name}", vectors.t_ns[m],
                        np.degrees(angle_between(vectors.e_c[m], e)))
    # misalignment (fig. 43)
    for c, k in enumerate(cam_numbers):
        if len(res.misalignment_t_ns):
            for a in range(3):
                m = np.degrees(res.misalignment[:, c, a])
                s3 = np.degrees(3 * res.misalignment_sigma[:, c, a])
                _series(rec, rr, inp, f"misalignment/camera_{k}/{AXES[a]}", res.misalignment_t_ns, m)
                _series(rec, rr, inp, f"misalignment/camera_{k}/{AXES[a]}_3sigma", res.misalignment_t_ns, s3)
    # attitude 3 sigma (fig. 40)
    sig = np.degrees(3 * np.sqrt(res.P_diag[:, res.layout["psi"]]))
    for a in range(3):
        _series(rec, rr, inp, f"attitude_3sigma/forward/{AXES[a]}", res.cov_t_ns, sig[:, a])
    ci = res.cov_idx
    if len(res.unaided_q_eb):
        d = np.degrees(attitude_error(res.unaided_q_eb[ci], res.q_eb[ci]))  # aided - unaided, rotation in e
        for a in range(3):
            _series(rec, rr, inp, f"aided_minus_unaided/{AXES[a]}", res.cov_t_ns, d[:, a])
    if len(res.triad_t_ns):
        j = np.clip(np.searchsorted(res.t_ns, res.triad_t_ns), 0, len(res.t_ns) - 1)
        d = np.degrees(matrix_to_rotvec(quat_to_matrix(res.triad_q_eb) @ np.swapaxes(quat_to_matrix(res.q_eb[j]), -1, -2)))
        for a in range(3):
            _series(rec, rr, inp, f"triad_minus_solution/{AXES[a]}", res.triad_t_ns, d[:, a])
        if len(res.unaided_q_eb):       # fig. 44 a: TRIAD - unaided
            d = np.degrees(matrix_to_rotvec(quat_to_matrix(res.triad_q_eb)
                                            @ np.swapaxes(quat_to_matrix(res.unaided_q_eb[j]), -1, -2)))
            for a in range(3):
                _series(rec, rr, inp, f"triad_minus_unaided/{AXES[a]}", res.triad_t_ns, d[:, a])
    if inp.truth is not None:
        _errors(rec, rr, inp, "forward", res.cov_t_ns, res.x_e[ci], res.v_e[ci], res.q_eb[ci])
        # attitude error 3-sigma envelope for comparison
        for a in range(3):
            _series(rec, rr, inp, f"error/attitude/forward/{AXES[a]}_3sigma", res.cov_t_ns, sig[:, a])


def _smoothed_timeseries(rec, rr, inp, res, smooth):
    """The smoother's series: attitude 3 sigma (fig. 40) and errors against the truth."""
    ss = np.degrees(3 * np.sqrt(smooth.P[:, res.layout["psi"]]))
    for a in range(3):
        _series(rec, rr, inp, f"attitude_3sigma/smoothed/{AXES[a]}", smooth.t_ns, ss[:, a])
    if inp.truth is not None:
        _errors(rec, rr, inp, "smoothed", smooth.t_ns, smooth.x_e, smooth.v_e, smooth.q_eb)


def _errors(rec, rr, inp, name, t, x, v, q):
    """Attitude, position and velocity errors of a solution against the truth, at the solution's
    stamps that the truth has."""
    tr = inp.truth
    j = np.searchsorted(tr.t_ns, t)
    ok = j < tr.t_ns.size
    ok[ok] = tr.t_ns[j[ok]] == t[ok]
    if not ok.any():
        return
    jj = j[ok]
    psi = np.degrees(attitude_error(q[ok], tr.q_eb[jj]))
    for a in range(3):
        _series(rec, rr, inp, f"error/attitude/{name}/{AXES[a]}", t[ok], psi[:, a])
    _series(rec, rr, inp, f"error/position/{name}", t[ok], np.linalg.norm(x[ok] - tr.x_e[jj], axis=1))
    _series(rec, rr, inp, f"error/velocity/{name}", t[ok], np.linalg.norm(v[ok] - tr.v_e[jj], axis=1))
