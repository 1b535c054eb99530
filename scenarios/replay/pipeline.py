"""The replay: a flight log through the vision front end, the filter and the smoother.

Stages (timed; ``ReplayResult.timings``):

1. **read**: the log (:func:`scenarios.replay.inputs.load_inputs`), the time window, the cameras.
2. **init**: ``truth`` (the log's /truth/state), ``given`` (a TOML file) or ``triad`` (GPS
   position/velocity and TRIAD at the first epoch with a horizon and a Sun vector, back-propagated
   to the start with the INS, 003 §7.4). On the image path TRIAD needs vectors before any attitude
   exists: :func:`_triad_pass` runs the vision without attitude prior (substitute sphere of 003
   §2.8 with the Gaussian radius at the GPS latitude, no Sun gate) on one frame per camera every
   ``TRIAD_SEARCH_DT_S`` seconds until it finds such an epoch (a few percent of the frames); the
   nadir is turned into the geocentric one with the attitude of a first TRIAD + free-inertial pass
   (:func:`.vision_worker.geocentric_correction`) and TRIAD repeated. The free-inertial INS from the
   initial state then gives every frame an attitude prior (:func:`_attach_priors`).
3. **vision** (``--vision images``): every camera frame in the window is decoded and processed by
   :func:`vision.frontend.process_frame` in worker processes (:mod:`.vision_worker`) with the GPS
   position and the INS attitude as prior: the ellipsoid Earth model (geocentric nadir, 003 eq.
   (39)), the exposure-invariant limb edge (`vision.limb`) and the Sun gate around the predicted
   Sun direction; TRIAD is repeated on these vectors. With ``--vision vectors`` the log's
   ``/camera_<k>/vectors`` are used as they are.
4. **filter**: :func:`nav.navigator.run` (one call over the window; it cannot be resumed).
5. **smoother**: :func:`nav.smoother.rts_smooth` (unless ``--no-smoother``).
6. **write**: the solution MCAP (:mod:`.solution_log`), atomically.
7. **rerun**: the recording (:mod:`.rerun_view`), drawn in a process of its own
   (:mod:`.recording_process`) forked when the replay starts: it imports Rerun while the log is
   read here, sends the camera images while this process initialises, draws the front end's
   overlays as the frames come and while the filter runs, the 3D scene and the filter's time
   series while the smoother runs and the smoother's while the solution is written. The stage's time here is what this process waits for it (at the end,
   and the sending of the overlays); its CPU time is the recording process's whole.

Interruption (SIGINT / Ctrl-C): the solution log is finalised as a valid partial log
(``horizon-nav.status`` complete = false, reason names the stage). It holds what exists at that
moment: interrupted during vision, the vectors of the frames processed so far; during the filter or smoother,
all vectors (as given to the filter) but no solution, since the filter runs in one call; during
writing or Rerun, the complete solution. An unfinished recording is abandoned (its temporary
file deleted): a .rrd exists only complete.
"""
from __future__ import annotations

import gc
import logging
import math
import os
import threading
import time
import tomllib
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav import earth, ins
from nav.navigator import InitialState, VectorData
from nav.rotation import quat_to_matrix
from scenarios.errors import UserError
from scenarios.replay import inputs as I

log = logging.getLogger(__name__)
NS = 1_000_000_000
NAV_TARGET = {"earth": "hor", "sun": "sun", "moon": "moon"}


@dataclass
class ReplayOptions:
    tuning: str | None = None
    t_from: str | None = None
    t_to: str | None = None
    cameras: list | None = None
    targets: tuple = ("earth", "sun")
    init: str | None = None            #: "truth", "given", "triad" or None (auto)
    init_file: str | None = None
    smoother: bool = True
    vision: str = "auto"               #: "auto", "images", "vectors"
    vision_config: str | None = None
    vision_rate_hz: float | None = None  #: process at most this many frames per second per camera (None: all)
    rrd_image_rate_hz: float | None = None  #: images (and overlays) in the recording per second per camera (None: all)
    masks: dict = field(default_factory=dict)  #: camera -> payload mask image file (overrides the log's)
    workers: int = 0
    output: str | None = None          #: solution MCAP (default FLIGHT.solution.mcap)
    rrd: str | None = None             #: Rerun file (default next to the solution); "" = none
    spawn: bool = False
    progress: bool = True


@dataclass
class ReplayResult:
    inputs: object
    nav: object
    smooth: object
    vectors: VectorData | None
    cam_numbers: list
    frames: list
    solution_path: Path
    rrd_path: Path | None
    timings: dict
    init_method: str
    vision_mode: str
    messages: list = field(default_factory=list)
    triad_init: object = None
    cpu_timings: dict = field(default_factory=dict)    #: stage -> CPU seconds (this process + workers)
    rerun_timings: dict = field(default_factory=dict)  #: Rerun stage parts -> seconds


def _cpu() -> float:
    """CPU seconds of this process and of its finished child processes (the vision workers)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class _Progress:
    """One progress bar over every stage: each vision frame is one step, every other stage (init,
    filter, smoother, write, Rerun) a block of ``max(5, frames // 8)`` steps counted when it ends
    (the filter and smoother are single calls); the description names the running stage.
    :meth:`timed` also records each stage's wall and CPU seconds and which stage is running."""

    def __init__(self, n_frames: int, stages: list, enabled: bool, wall: dict, cpu: dict):
        self.block = max(5, n_frames // 8)
        self.wall, self.cpu = wall, cpu
        self.current = ""
        self.bar = None
        if enabled:
            from tqdm import tqdm
            self.bar = tqdm(total=n_frames + self.block * len(stages), desc="replay", unit="step", leave=False)

    def stage(self, name: str) -> None:
        if self.bar is not None:
            self.bar.set_description(f"replay: {name}")

    def update(self, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def end_stage(self) -> None:
        self.update(self.block)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    @contextmanager
    def timed(self, name: str, block: bool = True):
        """Run a stage: name it on the bar, time it (wall and CPU), count its block at the end."""
        self.current = name
        self.stage(name)
        t, c0 = time.perf_counter(), _cpu()
        yield
        # a stage timed in parts (the Rerun recording: begun before the filter, finished after
        # writing) accumulates
        self.wall[name] = self.wall.get(name, 0.0) + time.perf_counter() - t
        self.cpu[name] = self.cpu.get(name, 0.0) + _cpu() - c0
        if block:
            self.end_stage()


def _gps_at(inp, t_ns):
    g = inp.gps
    t = np.asarray(t_ns, float)
    return np.stack([np.interp(t, g.t_ns.astype(float), g.x_e[:, i]) for i in range(3)], -1)


def _vectors_from_log(inp, cam_numbers, targets, a, b) -> VectorData | None:
    rows = []
    for i, k in enumerate(cam_numbers):
        v = inp.cameras[k].vectors
        if v is None:
            continue
        m = (v["t_ns"] >= a) & (v["t_ns"] <= b) & np.isin(v["target"], list(targets))
        for j in np.flatnonzero(m):
            rows.append((int(v["t_ns"][j]), i, NAV_TARGET[str(v["target"][j])], v["vector"][j], v["covariance"][j]))
    return _vd(rows)


def _vd(rows) -> VectorData | None:
    if not rows:
        return None
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    c = list(zip(*rows))
    return VectorData(np.array(c[0], np.int64), np.array(c[1], int), np.array(c[2], dtype=str),
                      np.array(c[3], float).reshape(-1, 3), np.array(c[4], float).reshape(-1, 3, 3))


def _given_init(path, inp, imu) -> InitialState:
    p = Path(path)
    try:
        d = tomllib.loads(p.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise UserError(f"--init-file {p}: cannot read ({e})") from None
    try:
        t = I.parse_time(str(d["time"]), inp.liftoff_ns, f"--init-file {p}: time") if "time" in d else int(imu.t_ns[0])
        q = np.asarray(d["q_eb"], float)
    except KeyError as e:
        raise UserError(f"--init-file {p}: missing key {e} (expected time, q_eb [x, y, z, w], and position_e / "
                        "velocity_e unless the log has GPS)") from None
    i = int(np.searchsorted(imu.t_ns, t))
    if i >= imu.t_ns.size - 1:
        raise UserError(f"--init-file {p}: time is after the IMU record")
    t0 = int(imu.t_ns[i])
    if "position_e" in d:
        x, v = np.asarray(d["position_e"], float), np.asarray(d.get("velocity_e", [0, 0, 0]), float)
    elif inp.gps is not None:
        from nav.initialise import gps_interpolator
        x, v = gps_interpolator(inp.gps)(t0)
    else:
        raise UserError(f"--init-file {p}: no position_e and the log has no GPS")
    if q.shape != (4,) or not np.isclose(np.linalg.norm(q), 1.0, atol=1e-6):
        raise UserError(f"--init-file {p}: q_eb must be a unit quaternion [x, y, z, w]")
    return InitialState(t0, x, v, q)


def _truth_init(inp, imu) -> InitialState:
    tr = inp.truth
    t0 = int(imu.t_ns[0])
    j = int(np.searchsorted(tr.t_ns, t0))
    if j >= tr.t_ns.size or tr.t_ns[j] != t0:
        # start at the first IMU sample that has a truth sample
        common = np.intersect1d(imu.t_ns, tr.t_ns)
        if not common.size:
            raise UserError("--init truth: no /truth/state sample at an IMU sample time")
        t0 = int(common[0])
        j = int(np.searchsorted(tr.t_ns, t0))
    return InitialState(t0, tr.x_e[j], tr.v_e[j], tr.q_eb[j])


def replay(path, opt: ReplayOptions) -> ReplayResult:
    """Run the replay of the log at ``path`` (module docstring). Raises UserError for bad input."""
    with _small_pages():
        rec = None
        if opt.rrd != "" or opt.spawn:
            # forked now: it imports Rerun while this process reads the log
            from scenarios.replay.recording_process import RecordingProcess
            rec = RecordingProcess()
        try:
            return _replay(path, opt, rec)
        except BaseException:
            if rec is not None:
                rec.abandon()
            raise


@contextmanager
def _small_pages():
    """numpy without transparent huge pages for the run (restored after). numpy asks the kernel
    for huge pages (``madvise``) for every array of 4 MB or more; the filter's, the smoother's and
    the writer's output arrays (~140 MB for the demo, written once, epoch by epoch) then fault in
    2 MB at a time, each zeroed by the kernel on first touch: the demo's filter stage took 0.43-0.55 s
    with them against 0.30-0.34 s without (three runs each, alternating). numpy reads its
    documented switch (``NUMPY_MADVISE_HUGEPAGE``) only at import; the runtime switch is private,
    hence looked up and skipped when absent. The vision's per-frame arrays are reused from frame
    to frame and see no difference (5.1-5.4 ms per frame either way)."""
    mod = getattr(np, "_core", None) or getattr(np, "core", None)
    switch = getattr(getattr(mod, "multiarray", None), "_set_madvise_hugepage", None)
    if switch is None:
        yield
        return
    before = switch(False)
    try:
        yield
    finally:
        switch(before)


def _replay(path, opt: ReplayOptions, rec) -> ReplayResult:
    from nav.navigator import run as nav_run
    from scenarios.flightlog.writer import LogWriter
    from scenarios.config.tuning import load_tuning
    from scenarios.replay import solution_log as SL

    timings: dict = {}
    cpu: dict = {}
    msgs = []
    t, c0 = time.perf_counter(), _cpu()
    bad_t = set(opt.targets) - set(I.TARGETS)
    if bad_t:
        raise UserError(f"--targets {','.join(sorted(bad_t))}: expected earth, sun or moon")
    if opt.vision not in ("auto", "images", "vectors"):
        raise UserError(f"--vision {opt.vision}: expected auto, images or vectors")
    if opt.vision_rate_hz is not None and not (math.isfinite(opt.vision_rate_hz) and opt.vision_rate_hz > 0):
        raise UserError(f"--vision-rate {opt.vision_rate_hz}: expected a positive number of frames per second")
    if opt.rrd_image_rate_hz is not None and not (math.isfinite(opt.rrd_image_rate_hz) and opt.rrd_image_rate_hz > 0):
        raise UserError(f"--rrd-image-rate {opt.rrd_image_rate_hz}: expected a positive number of frames per second")
    if opt.init not in (None, "truth", "given", "triad"):
        raise UserError(f"--init {opt.init}: expected truth, given or triad")
    inp = I.load_inputs(path, t_from=opt.t_from, t_to=opt.t_to, cameras=opt.cameras,
                        need_gps=opt.init != "given" and opt.init != "truth")
    # the log's arrays and the imported modules live to the end: moved out of the garbage
    # collector's generations, later full collections skip them (0.1-0.5 s each, several per run)
    gc.freeze()
    try:
        tuning = load_tuning(opt.tuning)
    except ValueError as e:
        raise UserError(str(e)) from None
    a, b = inp.t_from, inp.t_to
    imu = I.window_imu(inp.imu, a, b)
    gps = I.window_gps(inp.gps, a, b)
    if imu.t_ns.size < 2:
        raise UserError(f"{inp.path}: fewer than 2 IMU samples in the window")
    # vision mode
    mode = opt.vision
    if mode == "auto":
        mode = "images" if inp.has_images else ("vectors" if inp.has_vectors else "none")
        if mode == "none" and inp.cameras:
            msgs.append("the log has cameras but neither images nor vectors: GPS/INS only")
        elif mode == "none":
            msgs.append("the log has no cameras: GPS/INS only")
    if mode == "images" and not inp.has_images:
        raise UserError(f"--vision images: {inp.path} has no camera images"
                        + ("; it has vectors: use --vision vectors" if inp.has_vectors else ""))
    if mode == "vectors" and not inp.has_vectors:
        raise UserError(f"--vision vectors: {inp.path} has no /camera_<k>/vectors"
                        + ("; it has images: use --vision images" if inp.has_images else ""))
    cam_numbers = []
    for k, c in inp.cameras.items():
        usable = (mode == "images" and c.images is not None) or (mode == "vectors" and c.vectors is not None)
        if not usable:
            continue
        if c.R_bc is None:
            raise UserError(f"{inp.path}: camera {k} has no mount in /tf_static (body -> camera_{k}); the filter "
                            f"needs it. Replay without it: --cameras {','.join(str(x) for x in inp.cameras if x != k) or 'NONE'}")
        if mode == "images" and c.camera is None:
            raise UserError(f"{inp.path}: camera {k} has images but no /camera_{k}/camera_info, so its images cannot "
                            "be turned into vectors. What can still be done: "
                            + ("--vision vectors (the log has vectors); " if inp.has_vectors else "")
                            + f"--cameras to leave camera {k} out, or a GPS/INS-only replay with --vision vectors "
                              "on a log without cameras")
        cam_numbers.append(k)
    if opt.t_from is None and cam_numbers:
        # default start: the first camera frame / vector (003 §7.4 starts the navigation where the
        # cameras start, T+60; before it the spinning ascent saturates the gyros)
        firsts = [int((inp.cameras[k].images.t_ns if mode == "images" else inp.cameras[k].vectors["t_ns"])[0])
                  for k in cam_numbers]
        if min(firsts) > a:
            a = min(firsts)
            msgs.append(f"start: the first camera frame, T+{inp.mission_time(a):.1f} s (--from to change)")
    if opt.t_from is None and gps is not None and len(gps.t_ns) and gps.t_ns[0] > a:
        a = int(gps.t_ns[0])
    imu = I.window_imu(inp.imu, a, b)
    gps = I.window_gps(inp.gps, a, b)
    timings["read"] = time.perf_counter() - t
    cpu["read"] = _cpu() - c0

    out = Path(opt.output) if opt.output else inp.path.with_name(inp.path.name.removesuffix(".mcap") + ".solution.mcap")
    meta = {"scenario": inp.info.get("scenario", ""), "seed": inp.info.get("seed", ""),
            "liftoff_utc_ns": inp.info.get("liftoff_utc_ns", ""), "kind": "solution", "source_log": str(inp.path),
            "vision": mode, "window_ns": f"{a},{b}"}
    n_frames = 0
    if mode == "images":
        n_frames = sum(I.frames_in(inp.cameras[k].images.t_ns, a, b, opt.vision_rate_hz).size for k in cam_numbers)
    prog = _Progress(n_frames, ["init", "filter"] + (["smoother"] if opt.smoother else []) + ["write"]
                     + (["rerun"] if (opt.rrd != "" or opt.spawn) else []), opt.progress, timings, cpu)
    w = LogWriter(out, meta)
    frames = []
    vectors = None
    res = sm = None
    warm = None      # the filter's warm-up thread
    rerun_parts: dict = {}
    rrd = None if rec is None or (opt.spawn and not opt.rrd) else Path(
        opt.rrd or out.with_name(out.name.removesuffix(".mcap").removesuffix(".solution") + ".rrd"))
    R_bc = [inp.cameras[k].R_bc for k in cam_numbers]
    track = gps.x_e if gps is not None and len(gps.t_ns) else None   # aims the recording's 3D view
    try:
        if rec is not None:     # it sends the images while this process initialises
            rec.setup(inp, cam_numbers, rrd, spawn=opt.spawn, track=track, image_rate_hz=opt.rrd_image_rate_hz)
        if mode == "images":
            with prog.timed("init"):
                plan = _image_plan(inp, cam_numbers, opt, a, b)
                if rec is not None:
                    rec.begin(plan.jobs)
                # an attitude first (TRIAD on a sparse pass without attitude prior, or given/truth),
                # then every frame with the free-inertial attitude as the vision's prior
                pre = _triad_pass(plan, inp, cam_numbers, opt, imu) if opt.init in (None, "triad") else None
                init, tri_init, init_method, _ = _initialise(opt, inp, imu, gps, pre, R_bc, mode, msgs)
                _attach_priors(plan, imu, init, inp, cam_numbers)
            # the filter's kernels loaded in a thread while the workers run
            warm = threading.Thread(target=_warm_filter, args=(imu, init, tuning, gps, pre, R_bc, opt.smoother),
                                    name="warm-filter", daemon=True)
            with prog.timed("vision", block=False):  # the frames are its steps
                # the overlays go to the recording process as the frames come (sent and received
                # while this process waits), drawn after the vision
                frames, vectors = _run_images(plan, opt, frames_out=frames, progress=prog.update,
                                              on_pool_start=warm.start,
                                              on_result=rec.add_overlays if rec is not None else None)
                if init_method == "triad" and vectors is not None:
                    try:   # TRIAD again on the vectors measured with the attitude prior
                        init, tri_init = _triad(imu, gps, vectors, R_bc)
                    except UserError as e:
                        msgs.append(f"TRIAD on the final vectors failed ({e}); kept the first TRIAD")
        else:
            if rec is not None:
                rec.begin([])
            if mode == "vectors":
                vectors = _vectors_from_log(inp, cam_numbers, opt.targets, a, b)
            with prog.timed("init"):
                init, tri_init, init_method, vectors = _initialise(opt, inp, imu, gps, vectors, R_bc, mode, msgs)
        gc.freeze()   # the vision results likewise
        if rec is not None:
            with prog.timed("rerun", block=False):
                rec.check()
                rec.overlays()      # drawn while the filter runs here
        if warm is not None and warm.ident is not None:
            warm.join()     # its warm-up run of the filter has ended
        with prog.timed("filter"):
            try:
                res = nav_run(imu, init, tuning, gps=gps, vectors=vectors, R_bc=R_bc,
                              store_for_smoother=opt.smoother)
            except ValueError as e:
                raise UserError(f"filter: {e}") from None
        if rec is not None:
            rec.check()
            rec.solution(res, vectors, frames)     # the 3D scene and series, drawn while the smoother runs
        if opt.smoother:
            with prog.timed("smoother"):
                from nav.smoother import rts_smooth
                sm = rts_smooth(res)
                res.store = None
        if rec is not None:
            rec.finish(sm)         # the smoother's series drawn and the file written while this one is
        with prog.timed("write"):
            SL.write_solution(w, res, sm, cam_numbers, vectors=vectors)
            w.close()
    except KeyboardInterrupt:
        prog.close()
        if rec is not None:
            rec.abandon()
        stage = prog.current
        note = ""
        if stage == "vision":
            vectors = _vd([(r.t_ns, cam_numbers.index(r.camera), NAV_TARGET[r.target], r.e_c, r.P_c)
                           for f in frames for r in f.records if r.camera in cam_numbers])
            note = "; /camera_<k>/vectors: the frames processed so far (geocentric nadir, attitude prior from the INS)"
        if stage in ("vision", "init", "filter", "smoother") or (stage == "rerun" and res is None):
            SL.write_vectors(w, vectors, cam_numbers)
        w.close(complete=False, reason=f"KeyboardInterrupt during {stage}" + note)
        raise
    except BaseException:
        prog.close()
        if rec is not None:
            rec.abandon()
        w.discard()
        raise
    if rec is not None:
        try:
            with prog.timed("rerun"):
                rec.wait()
        except BaseException:
            prog.close()
            rec.abandon()
            raise
        rerun_parts.update(rec.timings)
    prog.close()
    return ReplayResult(inp, res, sm, vectors, cam_numbers, frames, out, rrd, timings, init_method, mode, msgs, tri_init,
                        cpu, rerun_parts)


def _initialise(opt, inp, imu, gps, vectors, R_bc, mode, msgs):
    """The initial state (003 §7.4): truth, a given state, or TRIAD + back-propagation; on the image
    path the Earth vectors are corrected to the geocentric nadir with the initial attitude (and TRIAD
    repeated on the corrected vectors). Returns (init, TRIAD result or None, method, vectors)."""
    tri_init = None
    init_method = opt.init
    has_pair = vectors is not None and {"hor", "sun"} <= set(np.unique(vectors.target))
    if init_method is None:
        if has_pair and gps is not None:
            init_method = "triad"
        else:
            init_method = "truth" if inp.truth is not None else "gps"
            msgs.append("initialisation: no epoch with both a horizon and a Sun vector for TRIAD (003 §7.4); "
                        + ("using the log's truth (--init truth)" if init_method == "truth"
                           else "using the first GPS fix and a level attitude with 180 deg sigma is not "
                                "possible: give --init given --init-file STATE.toml"))
            if init_method == "gps":
                raise UserError("--init: no TRIAD epoch and no truth in the log; give --init given --init-file STATE.toml "
                                "(time, q_eb and optionally position_e, velocity_e)")
    if init_method == "truth":
        if inp.truth is None:
            raise UserError(f"--init truth: {inp.path} has no /truth/state; use --init triad or given")
        init = _truth_init(inp, imu)
    elif init_method == "given":
        if not opt.init_file:
            raise UserError("--init given: needs --init-file STATE.toml (time, q_eb, position_e, velocity_e)")
        init = _given_init(opt.init_file, inp, imu)
    else:
        if not has_pair:
            raise UserError("--init triad: no epoch with both a horizon and a Sun vector"
                            + (" (use --init truth: the log has truth)" if inp.truth is not None else
                               " (use --init given --init-file STATE.toml)"))
        if gps is None:
            raise UserError("--init triad: needs GPS position and velocity")
        init, tri_init = _triad(imu, gps, vectors, R_bc)
    if mode == "images" and vectors is not None:
        vectors = _correct_earth(vectors, imu, init, inp, R_bc)
        if init_method == "triad":
            init, tri_init = _triad(imu, gps, vectors, R_bc)
    return init, tri_init, init_method, vectors


def _triad(imu, gps, vectors, R_bc):
    """TRIAD at the first epoch with both vectors after the start, back-propagated to the start
    (003 §7.4). The back-propagation needs an IMU interval: epochs before the second IMU sample (a
    frame at the window start) are skipped for the next one."""
    from nav.initialise import triad_initialise
    try:
        ti = triad_initialise(imu, gps, vectors, R_bc, int(imu.t_ns[0]), not_before_ns=int(imu.t_ns[min(1, imu.t_ns.size - 1)]))
    except ValueError as e:
        raise UserError(f"--init triad: {e}") from None
    return ti.initial, ti


def _free_inertial_R_eb(imu, init, t_ns) -> np.ndarray:
    """Body attitude R_eb (n, 3, 3) at ``t_ns`` from the free-inertial INS started at ``init`` (the
    IMU sample at or after each time; times before the start get the initial attitude)."""
    i0 = int(np.searchsorted(imu.t_ns, init.t_ns))
    ts = (imu.t_ns[i0:] - imu.t_ns[i0]) / NS
    _, _, Q = ins.propagate(init.x_e, init.v_e, init.q_eb, ts, imu.f_b[i0:], imu.w_b[i0:], sample=imu.sample)
    j = np.clip(np.searchsorted(imu.t_ns[i0:], np.asarray(t_ns, np.int64)), 0, len(ts) - 1)
    return quat_to_matrix(Q[j])


def _correct_earth(vectors, imu, init, inp, R_bc):
    """Substitute-sphere -> geocentric nadir with the free-inertial attitude from ``init``."""
    from scenarios.replay.vision_worker import geocentric_correction
    m = vectors.target == "hor"
    if not m.any():
        return vectors
    t = vectors.t_ns[m]
    R_eb = _free_inertial_R_eb(imu, init, t)
    R_bc_a = np.array(R_bc)[vectors.camera[m]]
    R_ce = np.swapaxes(R_eb @ R_bc_a, -1, -2)
    e = vectors.e_c.copy()
    e[m] = geocentric_correction(vectors.e_c[m], _gps_at(inp, t), R_ce)
    return VectorData(vectors.t_ns, vectors.camera, vectors.target, e, vectors.P_c)


def _warm_filter(imu, init, tuning, gps, vectors, R_bc, smoother: bool) -> None:
    """The filter (and the smoother) on the first second of the window, the result discarded:
    numba loads the filter's cached kernels (~0.2 s in a new process) while this process waits for
    the vision workers instead of when the filter starts. A few of the TRIAD search's vectors
    (``vectors``), stamped inside that second, load the vector-update kernels; the filter's log
    messages are muted meanwhile."""
    from nav.navigator import run as nav_run
    from nav.smoother import rts_smooth
    b = init.t_ns + NS
    im = I.window_imu(imu, init.t_ns, b)
    if im.t_ns.size < 3:
        return
    v = None
    if vectors is not None and len(vectors.t_ns):
        n = min(4, len(vectors.t_ns))
        v = VectorData(np.full(n, im.t_ns[im.t_ns.size // 2]), np.asarray(vectors.camera)[:n],
                       np.asarray(vectors.target)[:n], np.asarray(vectors.e_c)[:n], np.asarray(vectors.P_c)[:n])
    logs = [logging.getLogger(n) for n in logging.root.manager.loggerDict if n == "nav" or n.startswith("nav.")]
    was = [lg.disabled for lg in logs]
    for lg in logs:
        lg.disabled = True
    try:
        res = nav_run(im, init, tuning, gps=I.window_gps(gps, init.t_ns, b), vectors=v, R_bc=R_bc,
                      store_for_smoother=smoother)
        if smoother:
            rts_smooth(res)
    except Exception:  # noqa: BLE001 - a warm-up only: the filter itself reports its errors
        pass
    finally:
        for lg, w in zip(logs, was):
            lg.disabled = w


#: spacing [s] of the frames the TRIAD search looks at (the vision runs there without attitude)
TRIAD_SEARCH_DT_S = 5.0
#: frames per batch of the TRIAD search (it stops at the first batch that gives a TRIAD epoch)
TRIAD_SEARCH_BATCH = 16


@dataclass
class _ImagePlan:
    """The frames to process (time order) with their jobs, cameras and the vision configuration."""

    jobs: list            #: vision_worker.FrameJob
    cams: dict            #: camera number -> FisheyeCamera
    config: object        #: vision.frontend.VisionConfig
    images: dict          #: camera number -> image stream
    cam_numbers: list
    masks: dict = field(default_factory=dict)   #: camera number -> vision.mask.PayloadMask


def _image_plan(inp, cam_numbers, opt, a, b) -> _ImagePlan:
    """The frames in the window (``--vision-rate``) with their GPS position and height priors."""
    from scenarios.replay.vision_worker import FrameJob
    from scenarios.config.vision import load_vision_config
    rows, cams, configs = [], {}, {}
    for k in cam_numbers:
        c = inp.cameras[k]
        cams[k] = c.camera
        configs[k] = load_vision_config(opt.vision_config, camera=c.camera)
        for i in I.frames_in(c.images.t_ns, a, b, opt.vision_rate_hz):
            rows.append((int(c.images.t_ns[i]), k, int(i)))
    rows.sort()
    # one config per camera only differs through the focal length; the worker takes one config
    cfg = _targets_only(configs[cam_numbers[0]], opt.targets) if cam_numbers else None
    plan = _ImagePlan([], cams, cfg, {k: inp.cameras[k].images for k in cam_numbers}, cam_numbers,
                      _payload_masks(inp, cam_numbers, opt.masks))
    if not rows:
        return plan
    t_all = np.array([r[0] for r in rows], np.int64)
    if inp.gps is not None:
        x = _gps_at(inp, t_all)
    elif inp.truth is not None:
        x = np.stack([np.interp(t_all.astype(float), inp.truth.t_ns.astype(float), inp.truth.x_e[:, i]) for i in range(3)], -1)
    else:
        raise UserError("--vision images: the Earth fit needs the height (003 eq. (5)); the log has neither GPS nor truth")
    lat, _, h = earth.ecef_to_geodetic(x)
    plan.jobs = [FrameJob(k, i, t, None, float(h[n]), float(lat[n]), x_e=x[n]) for n, (t, k, i) in enumerate(rows)]
    return plan


def _payload_masks(inp, cam_numbers, files: dict) -> dict:
    """Camera -> `vision.mask.PayloadMask`: ``--mask K=FILE`` where given, else the log's
    ``/camera_<k>/payload_mask``; cameras without either are searched without a mask."""
    from scenarios.config.camera import read_payload_mask
    from vision import mask as vmask
    unknown = sorted(set(files) - set(cam_numbers))
    if unknown:
        raise UserError(f"--mask: camera(s) {unknown} are not replayed (cameras: {cam_numbers})")
    out = {}
    for k in cam_numbers:
        m = inp.cameras[k].mask
        if k in files:
            m = read_payload_mask(files[k], inp.cameras[k].camera, f"--mask {k}={files[k]}", f"camera {k}'s")
        if m is not None:
            out[k] = vmask.from_binary(m)
    return out


def _run_plan(plan: _ImagePlan, jobs, opt, frames_out=None, progress=None, on_pool_start=None,
              on_result=None) -> list:
    """The vision on ``jobs``; returns the vector rows ``(t_ns, camera index, target, e_c, P_c)``
    of the replayed targets (for :func:`_vd`). Each finished chunk of frames goes to
    ``frames_out.extend`` and ``on_result``."""
    from scenarios.replay.vision_worker import run_vision

    def got(res):
        if frames_out is not None:
            frames_out.extend(res)
        if on_result is not None:
            on_result(res)
    out = run_vision(jobs, plan.cams, plan.config, workers=opt.workers, progress=progress, masks=plan.masks,
                     on_result=got, images=plan.images, on_pool_start=on_pool_start)
    return [(r.t_ns, plan.cam_numbers.index(r.camera), NAV_TARGET[r.target], r.e_c, r.P_c)
            for f in out for r in f.records if r.target in opt.targets]


def _triad_pass(plan: _ImagePlan, inp, cam_numbers, opt, imu) -> VectorData | None:
    """Vectors for TRIAD (003 §7.4) before any attitude exists: the vision without attitude prior
    (substitute sphere, no Sun gate) on the first frame of each camera in every
    ``TRIAD_SEARCH_DT_S`` interval, in batches, until a batch gives an epoch with a horizon and a
    Sun vector. Costs a few percent of the frames; every frame is processed again with the prior."""
    from nav.initialise import first_triad_epoch
    if not plan.jobs or not {"earth", "sun"} <= set(opt.targets):
        return None
    t0 = plan.jobs[0].t_ns
    seen, pick = set(), []
    for j in plan.jobs:
        key = (j.k, (j.t_ns - t0) // int(TRIAD_SEARCH_DT_S * NS))
        if key not in seen:
            seen.add(key)
            pick.append(j)
    not_before = int(imu.t_ns[min(1, imu.t_ns.size - 1)])
    rows: list = []
    for i in range(0, len(pick), TRIAD_SEARCH_BATCH):
        rows += _run_plan(plan, pick[i:i + TRIAD_SEARCH_BATCH], opt)
        vd = _vd(rows)
        try:
            if vd is not None:
                first_triad_epoch(vd, not_before)
                return vd
        except ValueError:
            pass            # no epoch with both vectors yet: the next batch
    return _vd(rows)


def _attach_priors(plan: _ImagePlan, imu, init, inp, cam_numbers) -> None:
    """Attitude prior of every job: the free-inertial INS from the initial state with the nominal
    mounting (a few degrees at most: enough for the ellipsoid model, the limb's Sun-elevation test
    and the Sun gate), and the predicted Sun direction in the camera frame."""
    import dataclasses

    from nav.ephemeris import sun_direction_e
    if not plan.jobs:
        return
    t = np.array([j.t_ns for j in plan.jobs], np.int64)
    R_eb = _free_inertial_R_eb(imu, init, t)
    x = np.array([j.x_e for j in plan.jobs])
    s_e = sun_direction_e(t, x)
    for n, j in enumerate(plan.jobs):
        R_ec = R_eb[n] @ np.asarray(inp.cameras[j.k].R_bc, float)
        plan.jobs[n] = dataclasses.replace(j, R_ec=R_ec, sun_c=R_ec.T @ s_e[n])


def _run_images(plan: _ImagePlan, opt, frames_out, progress=None, on_pool_start=None, on_result=None):
    """Every planned frame through the vision (with the priors attached to its job)."""
    if not plan.jobs:
        return frames_out, None
    return frames_out, _vd(_run_plan(plan, plan.jobs, opt, frames_out, progress, on_pool_start, on_result))


def _targets_only(cfg, targets):
    import dataclasses
    ch = {}
    for name in ("earth", "sun", "moon"):
        tc = getattr(cfg, name)
        if tc.enabled and name not in targets:
            ch[name] = dataclasses.replace(tc, enabled=False)
    return dataclasses.replace(cfg, **ch) if ch else cfg


__all__ = ["ReplayOptions", "ReplayResult", "replay", "math"]
