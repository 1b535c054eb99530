"""The vision front end over the camera frames of a log, in parallel worker processes.

Frames are sent to a :class:`concurrent.futures.ProcessPoolExecutor` in chunks of 16 (the frame's
index in its image stream and its position prior; forked workers read the JPEG bytes from the log
themselves, see :func:`run_vision`); each worker decodes (:func:`scenarios.flightlog.jpeg.decode_frame`) and runs
:func:`vision.frontend.process_frame`, and returns the vector records plus a compact overlay for
the Rerun view (edge candidates, inliers, fitted conic and vector image points in distorted pixel
space, 003 figs. 15, 27) and the stage timings. With one worker (or one core) the frames are
processed in this process, with the same code.

Priors: a job with a position (GPS) and an attitude prior (``x_e``, ``R_ec``: the free-inertial
INS from the initial state, see :mod:`scenarios.replay.pipeline`) gets the ellipsoid Earth model
(the geocentric nadir -x_e/|x_e| the filter observes, 003 eq. (39)), the exposure-invariant limb
edge and the Sun gate around the predicted direction (``sun_c``). A job with only the GPS latitude
(the TRIAD search before an attitude exists) gets the substitute sphere of 003 §2.8 with the
Gaussian radius of curvature at that latitude, whose centre lies on the local geodetic normal
below the vehicle; :func:`geocentric_correction` turns that direction into the geocentric nadir
with an approximate attitude.
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

_STATE: dict = {}


@dataclass
class FrameJob:
    k: int
    index: int           #: frame index in the camera's image stream
    t_ns: int
    jpeg: bytes | None   #: None: read from the image stream given to run_vision (in the worker)
    height_m: float
    lat: float
    x_e: np.ndarray | None = None    #: position prior [m] (GPS); with R_ec: the ellipsoid model
    R_ec: np.ndarray | None = None   #: attitude prior camera -> e (INS); None: substitute sphere
    sun_c: np.ndarray | None = None  #: predicted Sun direction in c (ephemeris + R_ec)
    moon_c: np.ndarray | None = None  #: predicted Moon direction in c (ephemeris + R_ec)
    moon_alpha: float | None = None   #: the Moon's apparent radius [rad] (ephemeris distance)


@dataclass
class FrameOutput:
    k: int
    t_ns: int
    records: list        #: vision.frontend.VectorRecord
    reasons: dict        #: target -> why no vector
    overlay: dict        #: target -> {"edges", "inliers", "outliers", "conic", "point"} pixel arrays
    timings: dict        #: stage -> seconds (incl. "decode")
    limb: object = None  #: vision.limb_offset.LimbEdge of the Earth record when it is a limb-edge fit


def _init(cameras: dict, config, masks: dict) -> None:
    import cv2
    cv2.setNumThreads(1)
    _STATE["cameras"] = cameras
    _STATE["config"] = config
    _STATE["masks"] = masks


def _sub(a, n: int):
    a = np.asarray(a, float).reshape(-1, 2)
    if len(a) <= n:
        return a.astype(np.float32)
    return a[np.linspace(0, len(a) - 1, n).round().astype(int)].astype(np.float32)


def _overlay(camera, res) -> dict:
    from vision.camera import project
    from vision.frontend import conic_polyline
    out = {}
    for name, tr in res.targets.items():
        o: dict = {}
        det = tr.detection
        if det is not None and det.candidates:
            o["edges"] = _sub(np.concatenate([c.points for c in det.candidates]), 1500)
        if tr.points is not None and tr.inlier_mask is not None:
            o["inliers"] = _sub(tr.points[tr.inlier_mask], 600)
            o["outliers"] = _sub(tr.points[~tr.inlier_mask], 300)
        rec = tr.record
        if rec is not None:
            # the Earth: the visible horizon's cone about the geocentric nadir (the front end's
            # median inlier angle), not the fit's cone of the model
            alpha = tr.cone_alpha if math.isfinite(tr.cone_alpha) else rec.alpha
            poly = conic_polyline(camera, rec.e_c, alpha, 360)
            ok = np.all(np.isfinite(poly), axis=1) & (poly[:, 0] > -0.5 * camera.width) \
                & (poly[:, 0] < 1.5 * camera.width) & (poly[:, 1] > -0.5 * camera.height) & (poly[:, 1] < 1.5 * camera.height)
            o["conic"] = np.where(ok[:, None], poly, np.nan).astype(np.float32)
            with np.errstate(invalid="ignore", divide="ignore"):
                o["point"] = np.asarray(project(camera, rec.e_c), np.float32).reshape(1, 2)
        out[name] = o
    return out


def process_one(job: FrameJob, camera=None, config=None, mask=None) -> FrameOutput:
    """Decode one frame and run the front end on it (in a worker, or here)."""
    from scenarios.flightlog.jpeg import decode_frame
    from vision.frontend import FramePrior, process_frame
    from vision.limb_offset import limb_edge
    camera = camera if camera is not None else _STATE["cameras"][job.k]
    config = config if config is not None else _STATE["config"]
    mask = mask if mask is not None else _STATE.get("masks", {}).get(job.k)
    t0 = time.perf_counter()
    jpeg = job.jpeg if job.jpeg is not None else _STATE["images"][job.k][job.index]
    img = decode_frame(jpeg)
    t_dec = time.perf_counter() - t0
    if img is None:
        return FrameOutput(job.k, job.t_ns, [], {"frame": "JPEG could not be decoded"}, {}, {"decode": t_dec})
    if job.R_ec is not None and job.x_e is not None:
        prior = FramePrior(x_e=job.x_e, R_ec=job.R_ec, sun_c=job.sun_c, moon_c=job.moon_c, moon_alpha=job.moon_alpha)
    else:
        prior = FramePrior(lat=job.lat) if math.isfinite(job.lat) else None
    h = job.height_m if math.isfinite(job.height_m) else None
    config, skipped = sun_out_of_view(config, camera, job.sun_c)
    try:
        res = process_frame(img, camera, config, height_m=h, mask=mask, prior=prior,
                            rng=np.random.default_rng(job.t_ns % (2 ** 32)), t_ns=job.t_ns, camera_id=job.k)
    except ValueError as e:
        return FrameOutput(job.k, job.t_ns, [], {"frame": str(e)}, {}, {"decode": t_dec})
    tim = dict(res.timings)
    tim["decode"] = t_dec
    return FrameOutput(job.k, job.t_ns, res.records, {**skipped, **res.reasons}, _overlay(camera, res), tim,
                       limb_edge(res.targets.get("earth")))


def sun_out_of_view(config, camera, sun_c):
    """``(config, reasons)``: the configuration without the Sun search when the predicted Sun
    direction ``sun_c`` is farther from the optical axis than the widest angle the image sees
    (``camera.fov_theta``) plus the Sun gate (``gate_deg``: the front end would reject a Sun vector
    found there anyway), with the reason; else ``(config, {})``. Saves the Sun's detection on the
    frames without it (most of a flight)."""
    if sun_c is None or not config.sun.enabled:
        return config, {}
    off = math.degrees(math.acos(max(-1.0, min(1.0, float(sun_c[2]) / float(np.linalg.norm(sun_c))))))
    limit = math.degrees(camera.fov_theta) + config.sun.gate_deg
    if off <= limit:
        return config, {}
    cfg = _STATE.get("no_sun_config")
    if cfg is None or cfg[0] is not config:
        cfg = (config, dataclasses.replace(config, sun=dataclasses.replace(config.sun, enabled=False)))
        _STATE["no_sun_config"] = cfg
    return cfg[1], {"sun": f"predicted {off:.1f} deg off the optical axis: outside the field of view "
                           f"({limit:.1f} deg with the gate), not searched"}


def _chunk(jobs):
    return [process_one(j) for j in jobs]


def _fork_context():
    """The ``fork`` start method where the platform has it (Linux, macOS): the workers inherit the
    parent's imported modules, its loaded numba kernels (``cache=True``: loaded from disk once, in
    the parent, by the warm-up frame) and the log's image streams, so neither a start-up import, a
    kernel load nor the JPEG bytes cross the pipe. ``None`` elsewhere (spawn: the JPEG bytes are
    sent with the jobs and every worker imports and loads the kernels once in its initializer)."""
    import multiprocessing as mp
    return mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None


def _warm() -> None:
    """Import the front end and load its numba kernels (spawned workers: once per worker)."""
    import importlib
    for name in ("vision.frontend", "vision.binarize", "vision.borders"):
        importlib.import_module(name)


def _init_spawned(cameras, config, masks) -> None:
    _init(cameras, config, masks)
    _lower_priority()
    _warm()


def run_vision(jobs: list, cameras: dict, config, *, workers: int = 0, masks: dict | None = None,
               chunk_size: int = 16, progress=None, on_result=None, images: dict | None = None,
               on_pool_start=None) -> list:
    """Process ``jobs`` (list of :class:`FrameJob`); returns the :class:`FrameOutput` list in job
    order.

    ``workers``: 0 = one per core (at most 8), 1 = in this process. ``images``: camera number ->
    image stream (``stream[index]`` -> JPEG bytes, e.g. :class:`scenarios.flightlog.reader.ImageStream`)
    for jobs whose ``jpeg`` is ``None``; forked workers read the frames from it themselves.
    ``chunk_size`` frames go to a worker per task. ``progress(n)`` is called with the number of
    frames finished; ``on_result(outputs)`` with each finished chunk (in order).

    The first frame is processed here before the pool starts (warm-up: imports and numba kernels
    are loaded once and inherited by forked workers). ``on_pool_start()`` is called once the
    workers exist (this process then only waits: e.g. start a thread that imports Rerun).
    """
    masks = masks or {}
    images = images or {}
    if workers <= 0:
        workers = min(os.cpu_count() or 1, 8)
    missing = {j.k for j in jobs if j.jpeg is None and j.k not in images}
    if missing:
        raise ValueError(f"run_vision: jobs of camera(s) {sorted(missing)} have no JPEG bytes and no image stream")
    out: list = []
    _init(cameras, config, masks)
    _STATE["images"] = images
    try:
        _run(jobs, cameras, config, masks, images, workers, chunk_size, out, progress, on_result, on_pool_start)
    finally:
        _STATE.pop("images", None)     # do not keep the log's data alive after the run
    return out


def _run(jobs, cameras, config, masks, images, workers, chunk_size, out, progress, on_result, on_pool_start):
    def emit(res):
        out.extend(res)
        if on_result:
            on_result(res)
        if progress:
            progress(len(res))

    if workers == 1 or len(jobs) <= chunk_size + 1:
        for j in jobs:
            emit([process_one(j)])
        return
    emit([process_one(jobs[0])])          # warm-up, in this process
    rest = jobs[1:]
    ctx = _fork_context()
    if ctx is None:                       # spawned workers: ship the bytes
        rest = [j if j.jpeg is not None else dataclasses.replace(j, jpeg=images[j.k][j.index]) for j in rest]
        import multiprocessing as mp
        kw = {"mp_context": mp.get_context("spawn"), "initializer": _init_spawned, "initargs": (cameras, config, masks)}
    else:
        kw = {"mp_context": ctx, "initializer": _init_forked}
    chunks = _chunks(rest, chunk_size, workers)
    with ProcessPoolExecutor(max_workers=min(workers, len(chunks)), **kw) as ex:
        try:
            it = ex.map(_chunk, chunks)    # submits every chunk: with fork, the workers are forked here,
            if on_pool_start:              # before the executor's manager thread starts
                on_pool_start()
            for res in it:
                emit(res)
        except BaseException:
            ex.shutdown(wait=False, cancel_futures=True)
            raise


def _chunks(jobs: list, size: int, workers: int) -> list:
    """``jobs`` in tasks of ``size`` frames, the last ``2 * workers * size`` frames in tasks of a
    quarter of that: the workers then finish together instead of one waiting for the other's last
    full task (half a task on average)."""
    tail = min(len(jobs), 2 * workers * size)
    head, small = len(jobs) - tail, max(1, size // 4)
    return ([jobs[i:min(i + size, head)] for i in range(0, head, size)]
            + [jobs[i:i + small] for i in range(head, len(jobs), small)])


def _init_forked() -> None:
    import cv2
    cv2.setNumThreads(1)
    _lower_priority()


#: niceness added to the vision workers (see :func:`_lower_priority`)
WORKER_NICE = 5


def _lower_priority() -> None:
    """The workers run at a lower priority than the replay's process and its recording process:
    when those have work (the recording's images and Rerun's encoding early on, the filter and
    the overlays later) they get a core at once instead of a third of two, and finish before the
    workers do rather than after them; the workers use the time those leave."""
    try:
        os.nice(WORKER_NICE)
    except (OSError, AttributeError):   # not permitted, or no os.nice (Windows)
        pass


def geocentric_correction(e_c: np.ndarray, x_e: np.ndarray, R_ce: np.ndarray) -> np.ndarray:
    """Substitute-sphere nadir -> geocentric nadir (003 §2.8, eq. (39)), to first order.

    The front end's sphere (Gaussian radius at the GPS latitude, tangent below the vehicle) has its
    centre on the geodetic normal, so its direction is ``d_s = -n(lat, lon)`` in e; the filter
    observes ``d_g = -x_e / |x_e|``. The camera-frame vector is moved by ``R_ce (d_g - d_s)``
    (0.13 deg at 68 deg N) and renormalised; an attitude error psi in R_ce changes the result by
    ``|psi| * 0.0023 rad`` (4e-6 rad for 0.1 deg), negligible.
    """
    from nav import earth
    x = np.asarray(x_e, float).reshape(-1, 3)
    lat, lon, _ = earth.ecef_to_geodetic(x)
    n_up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)
    d = -x / np.linalg.norm(x, axis=1, keepdims=True) + n_up
    e = np.asarray(e_c, float).reshape(-1, 3) + np.einsum("nij,nj->ni", np.asarray(R_ce).reshape(-1, 3, 3), d)
    return e / np.linalg.norm(e, axis=1, keepdims=True)
