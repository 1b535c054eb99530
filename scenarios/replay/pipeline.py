"""The replay (``horizon-nav replay``): a flight log through the vision front end, the filter and
the smoother, written as a solution log and drawn in a Rerun recording.

The steps are the notebook functions of :mod:`.steps` (:func:`.steps.read_flight`,
:func:`.steps.see`, :func:`.steps.initialise`, :func:`.steps.navigate`, :func:`.steps.smooth`);
:func:`replay` composes them and adds what a command run needs: the solution MCAP, the Rerun
recording, the progress bar, the stage timings and the handling of Ctrl-C. Stages (timed;
``ReplayResult.timings``):

1. **read**: the log (:func:`.steps.read_flight`), the time window, the cameras, the tuning.
2. **init**: ``truth`` (the log's /truth/state), ``given`` (a TOML file) or ``triad`` (GPS
   position/velocity and TRIAD at the first epoch with a horizon and a Sun vector, back-propagated
   to the start with the INS, 003 §7.4; :mod:`.start`). On the image path TRIAD needs vectors
   before any attitude exists: :func:`.sight.triad_pass` runs the vision without attitude prior on
   a sparse set of frames, and the free-inertial INS from the initial state then gives every frame
   an attitude prior (:func:`.sight.attach_priors`).
3. **vision** (``--vision images``): every camera frame in the window through the front end in
   worker processes (:mod:`.sight`, :mod:`.vision_worker`); TRIAD is repeated on these vectors.
   With ``--vision vectors`` the log's ``/camera_<k>/vectors`` are used as they are.
4. **filter**: :func:`nav.navigator.run` (one call over the window; it cannot be resumed).
5. **smoother**: :func:`nav.smoother.rts_smooth` (unless ``--no-smoother``).
6. **write**: the solution MCAP (:mod:`.solution_log`), atomically, with the verdict
   (:mod:`.verdict`) as the metadata record ``horizon-nav.verdict``.
7. **rerun**: the recording (:mod:`.rerun_view`), drawn in a process of its own
   (:mod:`.recording_process`) forked when the replay starts: it imports Rerun while the log is
   read here, sends the camera images while this process initialises, draws the front end's
   overlays as the frames come and while the filter runs, the 3D scene and the filter's time
   series while the smoother runs and the smoother's while the solution is written. The stage's
   time here is what this process waits for it (at the end, and the sending of the overlays);
   its CPU time is the recording process's whole.

While the vision workers run, a thread runs the filter and the smoother on the first second of
the window (:func:`_warm_filter`), so that numba's cached kernels are loaded before the filter
stage instead of in it.

Interruption (SIGINT / Ctrl-C): the solution log is finalised as a valid partial log
(``horizon-nav.status`` complete = false, reason names the stage). It holds what exists at that
moment: interrupted during vision, the vectors of the frames processed so far; during the filter
or smoother, all vectors (as given to the filter) but no solution, since the filter runs in one
call; during writing or Rerun, the complete solution. An unfinished recording is abandoned (its
temporary file deleted): a .rrd exists only complete.

Settings of the interpreter made for speed are undone when :func:`replay` returns: the garbage
collector's frozen generation (:func:`gc.freeze`) and numpy's huge-page switch (:func:`_small_pages`).
"""
from __future__ import annotations

import gc
import logging
import os
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav.navigator import VectorData
from scenarios.errors import UserError
from scenarios.replay import inputs as I
from scenarios.replay.inputs import CLI
from scenarios.replay.steps import (Hooks, check_rate, check_targets, check_vision, initialise, navigate,
                                     read_flight, see, smooth)

NS = 1_000_000_000
VERDICT_METADATA = "horizon-nav.verdict"   #: the solution log's metadata record of the verdict


@dataclass
class ReplayOptions:
    """The options of ``horizon-nav replay`` (docs/replay.md), one field per flag."""

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
    """What a replay made: the inputs, the filter's and smoother's results, the vectors and frames,
    the files written, the stage timings and the notes (:func:`.summary.summarize` reads it)."""

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
    #: OK / DEGRADED / FAILED with reasons and statistics (:mod:`.verdict`; docs/replay.md "Verdict")
    verdict: object = None


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


def replay(path, opt: ReplayOptions) -> ReplayResult:
    """Run the replay of the log at ``path`` (module docstring). Raises UserError for bad input."""
    frozen = gc.get_freeze_count()
    try:
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
    finally:
        if not frozen:
            gc.unfreeze()       # the objects frozen by the run return to the collector


@contextmanager
def _small_pages():
    """numpy without transparent huge pages for the run (restored after). numpy asks the kernel
    for huge pages (``madvise``) for every array of 4 MB or more; the filter's, the smoother's and
    the writer's output arrays (about 140 MB for the demo, written once, epoch by epoch) then
    fault in 2 MB at a time, each zeroed by the kernel on first touch, which makes the filter
    stage markedly slower (docs/performance.md). numpy reads its documented switch
    (``NUMPY_MADVISE_HUGEPAGE``) only at import; the runtime switch is private, hence looked up and
    skipped when absent. The vision's per-frame arrays are reused from frame to frame and do not
    depend on it."""
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


def _check_options(opt: ReplayOptions) -> None:
    """The options' values, before anything is read (messages name the command line's flags)."""
    check_targets(opt.targets, CLI)
    check_vision(opt.vision, CLI)
    check_rate(opt.vision_rate_hz, "vision_rate_hz", CLI)
    check_rate(opt.rrd_image_rate_hz, "rrd_image_rate_hz", CLI)
    if opt.init not in (None, "truth", "given", "triad", "align"):
        raise UserError(f"--init {opt.init}: expected truth, given, triad or align")


def _init_request(opt: ReplayOptions):
    """``--init`` / ``--init-file`` as the ``init`` argument of the steps."""
    if opt.init == "given" and opt.init_file:
        return opt.init_file
    return opt.init or "auto"


def _read(path, opt: ReplayOptions, timings: dict, cpu: dict):
    """The read stage: the options checked, the log read (:func:`.steps.read_flight`), the tuning
    loaded. Returns (Flight, Tuning)."""
    from scenarios.config.tuning import load_tuning
    t, c0 = time.perf_counter(), _cpu()
    _check_options(opt)
    flight = read_flight(path, t_from=opt.t_from, t_to=opt.t_to, cameras=opt.cameras, vision=opt.vision,
                         require_gps=opt.init != "given" and opt.init != "truth", wording=CLI)
    # the log's arrays and the imported modules live to the end: moved out of the garbage
    # collector's generations, so that its full collections (several per run) skip them
    gc.freeze()
    try:
        tuning = load_tuning(opt.tuning)
    except ValueError as e:
        raise UserError(str(e)) from None
    timings["read"] = time.perf_counter() - t
    cpu["read"] = _cpu() - c0
    return flight, tuning


def _outputs(flight, opt: ReplayOptions, rec):
    """The solution log's path and metadata, and the recording's path (None without one)."""
    from scenarios.replay import solution_log as SL
    inp = flight.inputs
    out = Path(opt.output) if opt.output else inp.path.with_name(inp.path.name.removesuffix(".mcap") + ".solution.mcap")
    meta = {"scenario": inp.info.get("scenario", ""), "seed": inp.info.get("seed", ""),
            "liftoff_utc_ns": inp.info.get("liftoff_utc_ns", ""), "kind": "solution", "source_log": str(inp.path),
            "vision": flight.vision, "window_ns": f"{flight.t_from},{flight.t_to}", **SL.log_metadata(inp)}
    rrd = None if rec is None or (opt.spawn and not opt.rrd) else Path(
        opt.rrd or out.with_name(out.name.removesuffix(".mcap").removesuffix(".solution") + ".rrd"))
    return out, meta, rrd


def _partial_log(w, stage: str, frames, vectors, res, cam_numbers) -> None:
    """The solution log closed as a partial log after Ctrl-C during ``stage``, with the vectors
    that exist then (module docstring)."""
    from scenarios.replay import solution_log as SL
    note = ""
    if stage == "vision":
        from scenarios.replay.sight import frame_vectors
        vectors = frame_vectors(frames, cam_numbers)
        note = "; /camera_<k>/vectors: the frames processed so far (geocentric nadir, attitude prior from the INS)"
    if stage in ("vision", "init", "filter", "smoother") or (stage == "rerun" and res is None):
        SL.write_vectors(w, vectors, cam_numbers)
    w.close(complete=False, reason=f"KeyboardInterrupt during {stage}" + note)


def _replay(path, opt: ReplayOptions, rec) -> ReplayResult:
    from scenarios.flightlog.writer import LogWriter
    from scenarios.replay import solution_log as SL

    timings: dict = {}
    cpu: dict = {}
    flight, tuning = _read(path, opt, timings, cpu)
    inp, mode, cam_numbers = flight.inputs, flight.vision, flight.cam_numbers
    out, meta, rrd = _outputs(flight, opt, rec)
    prog = _Progress(flight.frame_count(opt.vision_rate_hz), ["init", "filter"] + (["smoother"] if opt.smoother else [])
                     + ["write"] + (["rerun"] if (opt.rrd != "" or opt.spawn) else []), opt.progress, timings, cpu)
    w = LogWriter(out, meta)
    frames: list = []
    vectors = None
    res = sm = None
    warm: list = []      # the filter's warm-up thread
    rerun_parts: dict = {}
    gps = flight.gps
    R_bc = flight.mounts
    track = gps.x_e if gps is not None and len(gps.t_ns) else None   # aims the recording's 3D view

    def started(start, search_vectors):
        # the filter's kernels loaded in a thread while the vision workers run
        warm.append(threading.Thread(target=_warm_filter, args=(flight.imu, start.state, tuning, gps, search_vectors,
                                                                R_bc, opt.smoother), name="warm-filter", daemon=True))

    def result(outputs):
        frames.extend(outputs)
        if rec is not None:
            rec.add_overlays(outputs)   # sent and received while this process waits, drawn after the vision

    hooks = Hooks(stage=lambda name: prog.timed(name, block=name != "vision"),   # the frames are the vision's steps
                  frames=rec.begin if rec is not None else None, started=started,
                  pool_start=lambda: warm[0].start(), progress=prog.update, result=result)
    try:
        if rec is not None:     # it sends the images while this process initialises
            rec.setup(inp, cam_numbers, rrd, spawn=opt.spawn, track=track, image_rate_hz=opt.rrd_image_rate_hz)
            if mode != "images":
                rec.begin([])
        sight = see(flight, init=_init_request(opt), targets=opt.targets, workers=opt.workers,
                    vision_config=opt.vision_config, vision_rate_hz=opt.vision_rate_hz, masks=opt.masks, hooks=hooks,
                    wording=CLI,
                    edge_state=tuning.edge_height_edge if tuning.edge_height.on else False)
        vectors = sight.vectors
        start = sight.start or initialise(flight, sight, init=_init_request(opt), hooks=hooks, wording=CLI)
        gc.freeze()   # the vision results likewise
        if rec is not None:
            with prog.timed("rerun", block=False):
                rec.check()
                rec.overlays()      # drawn while the filter runs here
        if warm and warm[0].ident is not None:
            warm[0].join()     # its warm-up run of the filter has ended
        sol = navigate(flight, tuning=tuning, init=start, vectors=sight, smoother=opt.smoother, hooks=hooks,
                       wording=CLI)
        res = sol.nav
        verdict = sol.verdict
        if rec is not None:
            rec.check()
            rec.solution(res, vectors, frames)     # the 3D scene and series, drawn while the smoother runs
        if opt.smoother:
            with prog.timed("smoother"):
                sm = smooth(sol).result
                res.store = None
        if rec is not None:
            rec.finish(sm)         # the smoother's series drawn and the file written while this one is
        with prog.timed("write"):
            SL.write_solution(w, res, sm, cam_numbers, vectors=vectors)
            w.add_metadata(VERDICT_METADATA, verdict.metadata())
            w.close()
    except KeyboardInterrupt:
        prog.close()
        if rec is not None:
            rec.abandon()
        _partial_log(w, prog.current, frames, vectors, res, cam_numbers)
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
    return ReplayResult(inp, res, sm, vectors, cam_numbers, frames, out, rrd, timings, start.method, mode, sol.notes,
                        start.triad, cpu, rerun_parts, verdict)


def _warm_filter(imu, init, tuning, gps, vectors, R_bc, smoother: bool) -> None:
    """The filter (and the smoother) on the first second of the window, the result discarded:
    numba loads the filter's cached kernels in a new process while this process waits for the
    vision workers instead of when the filter starts. A few of the TRIAD search's vectors
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


__all__ = ["ReplayOptions", "ReplayResult", "replay"]
