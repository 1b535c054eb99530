"""The replay's steps as Python functions, for a notebook or a script: read a flight log, see (the
vision), navigate (initial state and filter), smooth. They write no file and leave the
interpreter as they found it (garbage collector, loggers, signal handlers, numpy's settings);
``horizon-nav replay`` (:func:`scenarios.replay.pipeline.replay`) composes them and adds the
solution log, the Rerun recording, the progress bar and the handling of Ctrl-C.

>>> from scenarios import read_flight, see, navigate, smooth       # doctest: +SKIP
>>> log = read_flight("logs/atek.mcap", t_from="T+60", t_to="T+430")  # doctest: +SKIP
>>> sol = navigate(log)              # the vision on the images (or the log's vectors), TRIAD, filter  # doctest: +SKIP
>>> df = smooth(sol).to_frame()      # doctest: +SKIP

Errors are :class:`scenarios.errors.UserError` naming the parameter (``t_from: ...``).
"""
from __future__ import annotations

import math
from contextlib import nullcontext
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Callable

import numpy as np

from nav.navigator import InitialState, VectorData
from scenarios.errors import UserError
from scenarios.replay import inputs as I
from scenarios.replay.inputs import PYTHON, Wording
from scenarios.replay.start import Start, initial_state, split_request, triad

NS = 1_000_000_000


def _tplus(inp, t_ns) -> str:
    return f"T+{float(inp.mission_time(t_ns)):.1f}"


@dataclass(repr=False)
class Flight:
    """A flight log read for the filter (:func:`read_flight`): its inputs and the chosen window,
    cameras and source of vectors.

    Attributes
    ----------
    inputs : scenarios.replay.inputs.ReplayInputs
        Everything read from the log (IMU, GPS, cameras, truth, metadata).
    imu, gps : nav.navigator.ImuData, nav.navigator.GpsData or None
        The IMU samples and GPS fixes in the window.
    cam_numbers : list of int
        The cameras used (1-based numbers of the log); camera index i of the vectors is
        ``cam_numbers[i]``.
    vision : str
        Where the vectors come from: ``"images"`` (the vision front end), ``"vectors"`` (the log's
        ``/camera_<k>/vectors``) or ``"none"`` (GPS/INS only).
    t_from, t_to : int
        The window [UTC ns].
    notes : list of str
        What the caller should know about the choices made (e.g. the default start).

    Examples
    --------
    >>> log = read_flight("logs/atek.mcap", t_from="T+60", t_to="T+130")  # doctest: +SKIP
    >>> log                                                               # doctest: +SKIP
    Flight(atek.mcap: T+60.0 .. T+130.0 s, 1401 IMU samples, 71 GPS fixes, cameras [1, 2], vision from images (142 frames), truth)
    """

    inputs: object
    imu: object
    gps: object
    cam_numbers: list
    vision: str
    t_from: int
    t_to: int
    notes: list = field(default_factory=list)

    @property
    def path(self) -> Path:
        return self.inputs.path

    @property
    def truth(self):
        """The log's /truth/state (:class:`scenarios.replay.inputs.Truth`) or None."""
        return self.inputs.truth

    @property
    def mounts(self) -> list:
        """The nominal mounting R_bc (camera -> body) of each used camera, in camera index order."""
        return [self.inputs.cameras[k].R_bc for k in self.cam_numbers]

    def frame_count(self, rate_hz: float | None = None) -> int:
        """Camera frames in the window (at most ``rate_hz`` per second and camera); 0 unless the
        vision runs on images."""
        if self.vision != "images":
            return 0
        return sum(I.frames_in(self.inputs.cameras[k].images.t_ns, self.t_from, self.t_to, rate_hz).size
                   for k in self.cam_numbers)

    def __repr__(self) -> str:
        inp = self.inputs
        parts = [f"{self.path.name}: {_tplus(inp, self.t_from)} .. {_tplus(inp, self.t_to)} s",
                 f"{self.imu.t_ns.size} IMU samples", f"{0 if self.gps is None else self.gps.t_ns.size} GPS fixes",
                 f"cameras {self.cam_numbers}"]
        if self.vision == "images":
            parts.append(f"vision from images ({self.frame_count()} frames)")
        else:
            parts.append({"vectors": "vectors from the log", "none": "no vectors (GPS/INS only)"}[self.vision])
        if inp.truth is not None:
            parts.append("truth")
        return f"Flight({', '.join(parts)})"


def read_flight(path, *, t_from: str | None = None, t_to: str | None = None, cameras=None, vision: str = "auto",
                require_gps: bool = False, wording: Wording = PYTHON) -> Flight:
    """Read a flight log for the filter.

    Parameters
    ----------
    path : str or Path
        The flight log (MCAP, docs/log-format.md).
    t_from, t_to : str, optional
        The window: ``"T+60"`` (seconds after lift-off) or a UTC ISO time. Default: the log's IMU
        record, the start moved to the first camera frame (003 §7.4 starts the navigation where
        the cameras start) and to the first GPS fix.
    cameras : list of int, optional
        The cameras to use (default all).
    vision : {"auto", "images", "vectors"}
        The source of the camera vectors: the images through the vision front end, or the log's
        own vectors; ``"auto"``: images when the log has them.
    require_gps : bool
        Raise when the log has no GPS fixes (TRIAD needs them; a given state does not).
    wording : scenarios.replay.inputs.Wording
        How errors name the parameters (the command line uses its flags).

    Returns
    -------
    Flight

    Examples
    --------
    >>> log = read_flight("logs/atek.mcap", t_from="T+60", t_to="T+430", cameras=[1, 2])  # doctest: +SKIP
    >>> log.cam_numbers, log.vision                                                      # doctest: +SKIP
    ([1, 2], 'images')
    """
    w = wording
    check_vision(vision, w)
    inp = I.load_inputs(path, t_from=t_from, t_to=t_to, cameras=cameras, need_gps=require_gps, wording=w)
    a, b = inp.t_from, inp.t_to
    imu = I.window_imu(inp.imu, a, b)
    gps = I.window_gps(inp.gps, a, b)
    if imu.t_ns.size < 2:
        raise UserError(f"{inp.path}: fewer than 2 IMU samples in the window")
    notes: list = []
    mode = _vision_mode(inp, vision, notes, w)
    cam_numbers = _usable_cameras(inp, mode, w)
    if t_from is None and cam_numbers:
        # default start: the first camera frame / vector (003 §7.4 starts the navigation where the
        # cameras start, T+60; before it the spinning ascent saturates the gyros)
        firsts = [int((inp.cameras[k].images.t_ns if mode == "images" else inp.cameras[k].vectors["t_ns"])[0])
                  for k in cam_numbers]
        if min(firsts) > a:
            a = min(firsts)
            notes.append(f"start: the first camera frame, T+{inp.mission_time(a):.1f} s ({w.name('t_from')} to change)")
    if t_from is None and gps is not None and len(gps.t_ns) and gps.t_ns[0] > a:
        a = int(gps.t_ns[0])
    imu = I.window_imu(inp.imu, a, b)
    gps = I.window_gps(inp.gps, a, b)
    return Flight(inp, imu, gps, cam_numbers, mode, a, b, notes)


def _vision_mode(inp, vision: str, notes: list, w: Wording) -> str:
    mode = vision
    if mode == "auto":
        mode = "images" if inp.has_images else ("vectors" if inp.has_vectors else "none")
        if mode == "none" and inp.cameras:
            notes.append("the log has cameras but neither images nor vectors: GPS/INS only")
        elif mode == "none":
            notes.append("the log has no cameras: GPS/INS only")
    if mode == "images" and not inp.has_images:
        raise UserError(f"{w.set('vision', 'images')}: {inp.path} has no camera images"
                        + (f"; it has vectors: use {w.set('vision', 'vectors')}" if inp.has_vectors else ""))
    if mode == "vectors" and not inp.has_vectors:
        raise UserError(f"{w.set('vision', 'vectors')}: {inp.path} has no /camera_<k>/vectors"
                        + (f"; it has images: use {w.set('vision', 'images')}" if inp.has_images else ""))
    return mode


def _usable_cameras(inp, mode: str, w: Wording) -> list:
    """The cameras that give vectors in ``mode``; a camera without its mount, or with images but
    no intrinsics, is an error that says how to leave it out."""
    cam_numbers = []
    for k, c in inp.cameras.items():
        usable = (mode == "images" and c.images is not None) or (mode == "vectors" and c.vectors is not None)
        if not usable:
            continue
        if c.R_bc is None:
            others = [x for x in inp.cameras if x != k]
            leave = (f"--cameras {','.join(str(x) for x in others) or 'NONE'}" if w.cli else f"cameras={others}")
            raise UserError(f"{inp.path}: camera {k} has no mount in /tf_static (body -> camera_{k}); the filter "
                            f"needs it. Replay without it: {leave}")
        if mode == "images" and c.camera is None:
            raise UserError(f"{inp.path}: camera {k} has images but no /camera_{k}/camera_info, so its images cannot "
                            "be turned into vectors. What can still be done: "
                            + (f"{w.set('vision', 'vectors')} (the log has vectors); " if inp.has_vectors else "")
                            + f"{w.name('cameras')} to leave camera {k} out, or a GPS/INS-only replay with "
                              f"{w.set('vision', 'vectors')} on a log without cameras")
        cam_numbers.append(k)
    return cam_numbers


@dataclass
class Hooks:
    """Calls into the caller while :func:`see` and :func:`navigate` run, every one optional: the
    replay times its stages and draws its progress bar and Rerun recording through them.

    Attributes
    ----------
    stage : callable
        ``stage(name)`` -> a context manager around each stage: ``"init"`` (initial state; on
        the image path with the frame plan and the TRIAD search), ``"vision"``, ``"filter"``,
        ``"smoother"``.
    frames : callable
        ``frames(jobs)``: the frames the vision will process (anything with ``k`` and ``t_ns``),
        once planned.
    started : callable
        ``started(start, search_vectors)``: the initial state (:class:`.start.Start`) and the
        TRIAD search's vectors (or None), before the vision of every frame begins.
    pool_start : callable
        ``pool_start()``: the vision's worker processes exist (this process then only waits).
    progress : callable
        ``progress(n)``: n more frames processed.
    result : callable
        ``result(outputs)``: a chunk of the front end's results
        (:class:`.vision_worker.FrameOutput`) has come.
    """

    stage: Callable | None = None
    frames: Callable | None = None
    started: Callable | None = None
    pool_start: Callable | None = None
    progress: Callable | None = None
    result: Callable | None = None

    def in_stage(self, name: str):
        return self.stage(name) if self.stage is not None else nullcontext()


def _counts(vectors) -> str:
    if vectors is None or not len(vectors.t_ns):
        return "no vectors"
    names, n = np.unique(vectors.target, return_counts=True)
    return f"{len(vectors.t_ns)} vectors (" + ", ".join(f"{({'hor': 'earth'}).get(str(t), str(t))} {c}"
                                                         for t, c in zip(names, n)) + ")"


@dataclass(repr=False)
class Sight:
    """The camera vectors of a flight (:func:`see`).

    Attributes
    ----------
    flight : Flight
    vectors : nav.navigator.VectorData or None
        Unit vectors in the camera frames with their covariances (003 eq. (33)), time-ordered;
        camera index i is ``flight.cam_numbers[i]``; targets ``"hor"`` (geocentric nadir),
        ``"sun"``, ``"moon"``.
    frames : list of scenarios.replay.vision_worker.FrameOutput
        The front end's result per frame (empty for the log's own vectors).
    start : scenarios.replay.start.Start or None
        The initial state the image path found for the attitude prior (None for the log's vectors).
    notes : list of str

    Examples
    --------
    >>> sight = see(log, workers=2)      # doctest: +SKIP
    >>> sight                            # doctest: +SKIP
    Sight(images: 142 frames, 270 vectors (earth 142, sun 128), start triad)
    """

    flight: Flight
    vectors: VectorData | None
    frames: list = field(default_factory=list)
    start: Start | None = None
    notes: list = field(default_factory=list)

    def __repr__(self) -> str:
        src = f"images: {len(self.frames)} frames" if self.flight.vision == "images" else f"{self.flight.vision}"
        st = f", start {self.start.method}" if self.start is not None else ""
        return f"Sight({src}, {_counts(self.vectors)}{st})"


def check_targets(targets, w: Wording = PYTHON) -> None:
    """``targets`` are among earth, sun and moon."""
    bad = set(targets) - set(I.TARGETS)
    if bad:
        raise UserError(f"{w.name('targets')} {','.join(sorted(bad))}: expected earth, sun or moon")


def check_rate(value, param: str, w: Wording = PYTHON) -> None:
    """A frame rate ``value`` given as ``param`` is None or a positive number."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise UserError(f"{w.name(param)} {value}: expected a positive number of frames per second")


def check_vision(vision: str, w: Wording = PYTHON) -> None:
    """``vision`` names a source of vectors."""
    if vision not in ("auto", "images", "vectors"):
        raise UserError(f"{w.name('vision')} {vision}: expected auto, images or vectors")


def see(flight: Flight, *, init="auto", targets=("earth", "sun"), workers: int = 0, vision_config=None,
        vision_rate_hz: float | None = None, masks: dict | None = None, hooks: Hooks | None = None,
        wording: Wording = PYTHON, edge_state: bool | str = False) -> Sight:
    """The camera vectors of ``flight``: the vision front end on its images, or the log's vectors.

    On images every frame of the window is processed with the attitude of the free-inertial INS
    from the initial state as prior (the ellipsoid Earth model, 003 eq. (39), and the Sun gate);
    the initial state comes first (``init``; TRIAD on a sparse pass without attitude prior, 003
    §7.4) and is refined by TRIAD on the final vectors.

    Parameters
    ----------
    flight : Flight
    init : "auto", "truth", "triad", str or Path, InitialState or Start
        The initial state for the attitude prior (a path: a state TOML with time, q_eb and
        optionally position_e, velocity_e); unused for the log's vectors.
    targets : tuple of str
        Targets to use: ``"earth"``, ``"sun"``, ``"moon"``.
    workers : int
        Vision worker processes (0: one per core, 1: this process).
    vision_config : str or Path, optional
        A vision configuration TOML of overrides (default the library's).
    vision_rate_hz : float, optional
        Process at most this many frames per second and camera.
    masks : dict, optional
        Camera number -> payload mask image file (overrides the log's).
    hooks : Hooks, optional
    wording : scenarios.replay.inputs.Wording
    edge_state : bool or str
        The filter will estimate each camera's Earth edge height (``Tuning.edge_height`` on): the
        Earth vectors are then given the height, with their sensitivity to it and the arc's own
        height (`vision.config.EdgeHeightOptions.filter_state`, ``VectorData.dedge_c``); a log's
        vectors keep theirs (DirectionVector version 2). A string names the edge the state
        describes (``Tuning.edge_height_edge``: "limb", as True, or "threshold").

    Returns
    -------
    Sight

    Examples
    --------
    >>> sight = see(read_flight("logs/atek.mcap", t_from="T+60", t_to="T+70"), workers=2)  # doctest: +SKIP
    >>> sight.vectors.e_c.shape          # doctest: +SKIP
    (38, 3)
    """
    w = wording
    hooks = hooks or Hooks()
    check_targets(targets, w)
    check_rate(vision_rate_hz, "vision_rate_hz", w)
    inp = flight.inputs
    if flight.vision == "vectors":
        from scenarios.replay.sight import log_vectors
        return Sight(flight, log_vectors(inp, flight.cam_numbers, targets, flight.t_from, flight.t_to, edge_state))
    if flight.vision != "images":
        return Sight(flight, None)
    import cv2
    threads = cv2.getNumThreads()
    try:
        return _see_images(flight, init, targets, workers, vision_config, vision_rate_hz, masks or {}, hooks, w,
                           edge_state)
    finally:
        cv2.setNumThreads(threads)     # the vision runs OpenCV single-threaded


def _see_images(flight, init, targets, workers, vision_config, vision_rate_hz, masks, hooks, w,
                edge_state: bool | str = False) -> Sight:
    from scenarios.replay import sight as S
    imu, notes, frames = flight.imu, [], []
    with hooks.in_stage("init"):
        plan = S.image_plan(flight, targets, vision_config=vision_config, vision_rate_hz=vision_rate_hz, masks=masks,
                            workers=workers, wording=w, edge_state=edge_state)
        if hooks.frames is not None:
            hooks.frames(plan.jobs)
        # an attitude first (TRIAD on a sparse pass without attitude prior, or given/truth),
        # then every frame with the free-inertial attitude as the vision's prior
        pre = None
        if isinstance(init, Start):
            start = init
        else:
            method, file, state = split_request(init)
            pre = S.triad_pass(plan, imu) if method in (None, "triad") else None
            start = initial_state(flight, pre, method, file, state, search=True, wording=w)
            start.request = init
        S.attach_priors(plan, imu, start.state, flight.inputs)
    if hooks.started is not None:
        hooks.started(start, pre)
    with hooks.in_stage("vision"):
        vectors = S.run_images(plan, frames, hooks.progress, hooks.pool_start, hooks.result)
        notes += [o.describe() for o in plan.limb_offsets]
        if start.method == "triad" and vectors is not None:
            try:   # TRIAD again on the vectors measured with the attitude prior
                state, tri = triad(imu, flight.gps, vectors, flight.mounts, w)
                start = Start(state, "triad", tri, start.notes, start.request)
            except UserError as e:
                notes.append(f"TRIAD on the final vectors failed ({e}); kept the first TRIAD")
    return Sight(flight, vectors, frames, start, notes)


@dataclass(repr=False)
class Solution:
    """The forward filter's solution over a flight (:func:`navigate`).

    Attributes
    ----------
    flight : Flight
    nav : nav.navigator.NavResult
        The filter's result: the solution at every IMU sample, the covariance at every
        covariance epoch, the innovations, the estimated misalignments, the free-inertial run.
    vectors : nav.navigator.VectorData or None
        The vectors given to the filter.
    start : scenarios.replay.start.Start
        The initial state and how it was found.
    frames : list
        The front end's result per frame (image path).
    notes : list of str
        What the caller should know, from every step (read, initialisation, vision).
    tuning : nav.tuning.Tuning
    verdict : scenarios.replay.verdict.Verdict
        (property) ``.status`` OK, DEGRADED or FAILED, ``.reasons``, ``.statistics``.

    Examples
    --------
    >>> sol = navigate(log)              # doctest: +SKIP
    >>> sol                              # doctest: +SKIP
    Solution(forward, T+60.0 .. T+130.0 s, 701 epochs, init triad, measurements: 1218 used, 3 rejected)
    >>> sol.to_frame()[["lat", "lon", "height", "heading"]].iloc[-1]   # doctest: +SKIP
    """

    flight: Flight
    nav: object
    vectors: VectorData | None
    start: Start
    frames: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    tuning: object = None

    def __repr__(self) -> str:
        res, inp = self.nav, self.flight.inputs
        used = sum(1 for i in res.innovations if i.accepted)
        return (f"Solution(forward, {_tplus(inp, res.t_ns[0])} .. {_tplus(inp, res.t_ns[-1])} s, "
                f"{len(res.cov_t_ns)} epochs, init {self.start.method}, measurements: {used} used, "
                f"{len(res.innovations) - used} rejected)")

    @cached_property
    def verdict(self):
        """OK, DEGRADED or FAILED with the reasons and the per-sensor statistics it is judged on
        (:class:`scenarios.replay.verdict.Verdict`, docs/replay.md "Verdict"); never raises."""
        from scenarios.replay.verdict import assess
        return assess(self)

    def to_frame(self):
        """The forward solution at the covariance epochs as a pandas DataFrame
        (:mod:`scenarios.replay.table` lists the columns)."""
        from scenarios.replay.table import forward_columns, solution_frame
        res = self.nav
        return solution_frame(forward_columns(res, self.flight.inputs.mission_time(res.cov_t_ns),
                                              self.flight.cam_numbers))


def initialise(flight: Flight, vectors=None, *, init="auto", hooks: Hooks | None = None,
               wording: Wording = PYTHON) -> Start:
    """The filter's initial state (003 §7.4) for ``flight``.

    Parameters
    ----------
    flight : Flight
    vectors : None, Sight or nav.navigator.VectorData
        The camera vectors TRIAD may use (their first epoch with a horizon and a Sun vector).
    init : "auto", "truth", "triad", str or Path, or InitialState
        As for :func:`navigate`.
    hooks : Hooks, optional
    wording : scenarios.replay.inputs.Wording

    Returns
    -------
    scenarios.replay.start.Start

    Examples
    --------
    >>> start = initialise(log, see(log), init="triad")   # doctest: +SKIP
    >>> start.triad.t_triad_ns                            # doctest: +SKIP
    """
    vecs = vectors.vectors if isinstance(vectors, Sight) else vectors
    method, file, state = split_request(init)
    with (hooks or Hooks()).in_stage("init"):
        start = initial_state(flight, vecs, method, file, state, wording=wording)
    start.request = init
    return start


def _tuning(tuning):
    from nav.tuning import Tuning
    if isinstance(tuning, Tuning):
        return tuning
    from scenarios.config.tuning import load_tuning
    try:
        return load_tuning(tuning)
    except ValueError as e:
        raise UserError(str(e)) from None


def _same_request(a, b) -> bool:
    if a is b:
        return True
    if isinstance(a, InitialState) or isinstance(b, InitialState):
        return False
    return str(a) == str(b)


def navigate(flight: Flight, *, tuning=None, init="auto", vectors=None, smoother: bool = True, workers: int = 0,
             hooks: Hooks | None = None, wording: Wording = PYTHON) -> Solution:
    """The forward filter (003 §6) over ``flight``: the initial state, then GPS and camera
    vectors through the error-state filter (:func:`nav.navigator.run`).

    Parameters
    ----------
    flight : Flight
    tuning : None, str or Path, or nav.tuning.Tuning
        The filter's tuning: None for 003 table 3, a tuning TOML of overrides, or a Tuning (its
        per-camera keys name the log's camera numbers, :meth:`nav.tuning.Tuning.for_cameras`).
    init : "auto", "truth", "triad", str or Path, InitialState or Start
        The initial state: ``"auto"`` (TRIAD when the vectors hold an epoch with a horizon and a
        Sun vector and the log has GPS, else the log's truth), ``"truth"``, ``"triad"`` (003
        §7.4), a state TOML (time, q_eb and optionally position_e, velocity_e), an InitialState,
        or a Start (:attr:`Sight.start`).
    vectors : None, Sight or nav.navigator.VectorData
        The camera vectors; None: :func:`see` with its defaults (the vision on the images in
        ``workers`` processes, or the log's vectors).
    smoother : bool
        Keep what :func:`smooth` needs (memory: about 20 KB per covariance epoch).
    workers : int
        Vision worker processes when ``vectors`` is None (0: one per core).
    hooks : Hooks, optional
    wording : scenarios.replay.inputs.Wording

    Returns
    -------
    Solution

    Examples
    --------
    >>> sol = navigate(read_flight("logs/atek.mcap"), tuning=None, init="auto")  # doctest: +SKIP
    >>> sol.start.method                 # doctest: +SKIP
    'triad'
    """
    from nav import navigator
    hooks = hooks or Hooks()
    tuning = _tuning(tuning).for_cameras(flight.cam_numbers)   # per-camera keys name the log's cameras
    if vectors is None:
        sight = see(flight, init=init, workers=workers, hooks=hooks, wording=wording)
    elif isinstance(vectors, Sight):
        sight = vectors
    elif isinstance(vectors, VectorData):
        sight = Sight(flight, vectors)
    else:
        raise UserError(f"vectors: expected None, a Sight or a VectorData, got {type(vectors).__name__}")
    if isinstance(init, Start):
        start = init
    elif sight.start is not None and _same_request(init, sight.start.request):
        start = sight.start
    else:
        start = initialise(flight, sight, init=init, hooks=hooks, wording=wording)
    if start.alignment is not None:     # the filter starts with the alignment's attitude sigma
        tuning = tuning.with_(init_att_sigma=max(tuning.init_att_sigma, start.alignment.att_sigma))
    if start.vel_sigma is not None:     # and with the sigma of a velocity from position-only fixes
        tuning = tuning.with_(init_vel_sigma=max(tuning.init_vel_sigma, start.vel_sigma))
    with hooks.in_stage("filter"):
        try:
            res = navigator.run(flight.imu, start.state, tuning, gps=flight.gps, vectors=sight.vectors,
                                R_bc=flight.mounts, store_for_smoother=smoother)
        except ValueError as e:
            raise UserError(f"filter: {e}") from None
    return Solution(flight, res, sight.vectors, start, sight.frames, flight.notes + start.notes + sight.notes, tuning)


@dataclass(repr=False)
class Smoothed:
    """The RTS smoother's solution (:func:`smooth`) at the forward filter's covariance epochs.

    Attributes
    ----------
    solution : Solution
        The forward solution it smooths.
    result : nav.smoother.SmoothResult
        Epochs, smoothed position, velocity, attitude and covariance diagonal.

    Examples
    --------
    >>> sm = smooth(sol)                 # doctest: +SKIP
    >>> sm                               # doctest: +SKIP
    Smoothed(T+60.0 .. T+130.0 s, 701 epochs, init triad)
    """

    solution: Solution
    result: object

    def __repr__(self) -> str:
        r, inp = self.result, self.solution.flight.inputs
        return (f"Smoothed({_tplus(inp, r.t_ns[0])} .. {_tplus(inp, r.t_ns[-1])} s, {len(r.t_ns)} epochs, "
                f"init {self.solution.start.method})")

    def to_frame(self):
        """The smoothed solution as a pandas DataFrame (:mod:`scenarios.replay.table` lists the
        columns)."""
        from scenarios.replay.table import smoothed_columns, solution_frame
        r, sol = self.result, self.solution
        return solution_frame(smoothed_columns(r, sol.nav.layout, sol.flight.inputs.mission_time(r.t_ns),
                                               sol.flight.cam_numbers))


def smooth(solution: Solution, *, hooks: Hooks | None = None) -> Smoothed:
    """The RTS smoother (:func:`nav.smoother.rts_smooth`) over a forward solution made with
    ``smoother=True``.

    Examples
    --------
    >>> sm = smooth(navigate(read_flight("logs/atek.mcap")))   # doctest: +SKIP
    >>> sm.to_frame()["att_sd"].max()    # doctest: +SKIP
    """
    from nav.smoother import rts_smooth
    if solution.nav.store is None:
        raise UserError("solution: made without the smoother's store (navigate(..., smoother=False)) or already "
                        "released; nothing to smooth")
    with (hooks or Hooks()).in_stage("smoother"):
        return Smoothed(solution, rts_smooth(solution.nav))


__all__ = ["Flight", "Sight", "Solution", "Smoothed", "Hooks", "read_flight", "see", "initialise", "navigate",
           "smooth"]
