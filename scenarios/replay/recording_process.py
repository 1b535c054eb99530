"""The replay's Rerun recording made in a process of its own (:mod:`.rerun_view` draws it).

Why a process: the recording is a large share of a replay's CPU time (importing Rerun, the camera
images, then overlays, 3D scene, time series and Rerun's own encoding and writing threads; figures
in docs/performance.md). In the replay's process it would compete with the vision workers for the
cores and run after the filter. Forked when the replay starts, the process
imports Rerun while the replay's process reads the log (one core idle), sends the images while
that one initialises, and draws the solution while it smooths and writes it.

The replay's process sends commands through a queue (its feeder thread pickles them, so a send
does not wait for the recording process to be free) and does not import Rerun at all:

1. :meth:`RecordingProcess.setup` with the inputs once the log is read (:func:`drawn_inputs`: the
   image streams go as their file's path and index, the file is mapped again there);
2. :meth:`RecordingProcess.begin` with the frames to show (anything with ``k`` and ``t_ns``): open
   the recording (:func:`.rerun_view.begin`) and send the camera images;
3. :meth:`RecordingProcess.add_overlays` with the front end's results as the frames come (drawn
   by :func:`.rerun_view.overlays` every :data:`OVERLAY_BATCH` frames), then
   :meth:`RecordingProcess.overlays` for the rest;
4. :meth:`RecordingProcess.solution` with the filter's result (:func:`.rerun_view.solution`: 3D
   scene and time series), the covariances the drawing does not use left out;
5. :meth:`RecordingProcess.finish` with the smoother's result (:func:`.rerun_view.finish`: its
   time series, flush, the file moved to its name), then :meth:`RecordingProcess.wait` for the file
   (it returns the path or raises the process's error).

:meth:`RecordingProcess.abandon` (an error or Ctrl-C in the replay) stops the images within one
send, ends the process and deletes the temporary file: no half recording is left under the
final name. The recording process ignores SIGINT (Ctrl-C reaches the whole process group): the
replay decides. An ``--rrd`` path that cannot be written is a UserError in :meth:`setup`;
:meth:`RecordingProcess.check` raises a later failure of the recording at the next stage instead
of after the filter.

Where ``fork`` is unavailable the same commands run in this process, synchronously.
"""
from __future__ import annotations

import dataclasses
import importlib
import signal
import threading
import traceback
from pathlib import Path
from types import SimpleNamespace

import numpy as np

#: seconds to wait for the process to end after an abandon before it is killed
ABANDON_TIMEOUT_S = 10.0
#: overlays drawn as soon as this many frames' have come (Rerun encodes and writes them while the
#: vision runs instead of after it); the rest when the vision ends
OVERLAY_BATCH = 256


#: imported by the recording process as soon as it starts, while the replay's process reads the log
#: (one core idle). pandas: pyarrow imports it on the first conversion of a Python list (Rerun's
#: blueprint does one), an import that would otherwise fall in :func:`.rerun_view.begin`,
#: while the vision workers run.
PRELOADED = ("rerun", "pandas")


class RecordingError(RuntimeError):
    """The recording process failed (its traceback is in the message)."""


def _frames_kt(frames) -> list:
    """Only what the drawing of the images and the 3D scene uses of a frame: camera and time."""
    return [SimpleNamespace(k=f.k, t_ns=f.t_ns) for f in frames]


def _frames_overlay(frames) -> list:
    return [SimpleNamespace(k=f.k, t_ns=f.t_ns, overlay=f.overlay) for f in frames]


def drawn_result(res):
    """The filter's result without what the drawing does not read (the full covariances at the
    update epochs and the smoother's store: tens of MB to pickle), its accepted innovations as
    columns (:class:`_AcceptedInnovations`)."""
    return dataclasses.replace(res, P_full=res.P_full[:0], store=None,
                               innovations=_AcceptedInnovations(res.innovations))


class _AcceptedInnovations:
    """The accepted innovations as columns: a few arrays pickle far faster than thousands of
    innovation objects, and this send comes at the end of the replay. Iterated, it
    gives rows with the fields the drawing reads (:func:`.rerun_view._timeseries` draws the
    accepted ones only)."""

    def __init__(self, innovations):
        acc = [i for i in innovations if i.accepted]
        self.t_ns = np.array([i.t_ns for i in acc], np.int64)
        self.kind = [i.kind for i in acc]
        self.camera = np.array([i.camera for i in acc], np.int64)
        self.m = np.array([np.size(i.s) for i in acc], np.int64)
        self.s = np.concatenate([np.ravel(i.s) for i in acc]) if acc else np.empty(0)
        self.S = np.concatenate([np.ravel(i.S) for i in acc]) if acc else np.empty(0)

    def __iter__(self):
        o1 = np.concatenate([[0], np.cumsum(self.m)]).tolist()
        o2 = np.concatenate([[0], np.cumsum(self.m * self.m)]).tolist()
        for j, m in enumerate(self.m.tolist()):
            yield SimpleNamespace(t_ns=int(self.t_ns[j]), kind=self.kind[j], camera=int(self.camera[j]),
                                  s=self.s[o1[j]:o1[j + 1]], S=self.S[o2[j]:o2[j + 1]].reshape(m, m), accepted=True)


class _Drawer:
    """The recording's state and the commands, run in the recording process (or here)."""

    def __init__(self, stop):
        self.stop = stop
        self.r = None
        self.res = None
        self.pending: list = []      # overlays received, drawn by overlays()
        self.timings: dict = {}

    def setup(self, inp, cam_numbers, rrd, spawn, track, image_rate_hz):
        self.inp, self.cam_numbers, self.rrd = inp, cam_numbers, rrd
        self.spawn, self.track, self.image_rate_hz = spawn, track, image_rate_hz

    def begin(self, frames):
        from scenarios.replay import rerun_view as RV
        self.r = RV.begin(self.inp, frames, self.cam_numbers, self.rrd, spawn=self.spawn, track=self.track,
                          timings=self.timings, image_rate_hz=self.image_rate_hz, stop=self.stop)

    def add_overlays(self, frames):
        self.pending.extend(frames)
        if len(self.pending) >= OVERLAY_BATCH:
            self.overlays()

    def overlays(self):
        from scenarios.replay import rerun_view as RV
        if self.pending:
            RV.overlays(self.r, self.inp, self.pending, self.cam_numbers)
        self.pending = []

    def solution(self, res, vectors, frames):
        from scenarios.replay import rerun_view as RV
        self.res = res
        RV.solution(self.r, self.inp, res, vectors, self.cam_numbers, frames)

    def finish(self, smooth):
        from scenarios.replay import rerun_view as RV
        path = RV.finish(self.r, self.inp, self.res, smooth)
        self.r = None
        return path, self.timings

    def abandon(self):
        from scenarios.replay import rerun_view as RV
        r, self.r = self.r, None
        RV.abandon(r)


def _serve(drawer: _Drawer, commands, replies) -> None:
    """The recording process: run the commands in order until ``finish`` or ``abandon``; a failure
    abandons the recording and is sent back."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        for name in PRELOADED:              # while the replay's process reads the log
            importlib.import_module(name)
        while True:
            name, args = commands.get()
            if name == "abandon":
                drawer.abandon()
                return
            out = getattr(drawer, name)(*args)
            if name == "finish":
                replies.put(("ok", out))
                return
    except BaseException as e:  # noqa: BLE001 - reported to the replay's process, which raises it
        try:
            drawer.abandon()
        except Exception:  # noqa: BLE001 - the first error is the one to report
            pass
        from scenarios.replay.rerun_view import RecordingStopped
        if not isinstance(e, RecordingStopped):
            kind = "OSError" if isinstance(e, OSError) else type(e).__name__
            replies.put(("error", (kind, f"{type(e).__name__}: {e}", traceback.format_exc())))
    finally:
        replies.close()
        replies.join_thread()


def drawn_inputs(inp):
    """The replay's inputs without what the drawing does not read (GPS, the cameras' vectors, truth
    and masks), to send to the recording process; the image streams pickle as their file's path
    and index."""
    cams = {k: dataclasses.replace(c, vectors=None, truth=None, mask=None) for k, c in inp.cameras.items()}
    return dataclasses.replace(inp, gps=None, cameras=cams, notes=[])


class RecordingProcess:
    """The recording of one replay (module docstring), started before the log is read so that
    Rerun's import overlaps the reading; :meth:`setup` with the inputs once they are read."""

    def __init__(self):
        import multiprocessing as mp
        self.rrd = None
        self.timings: dict = {}
        self._done = False
        ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
        if ctx is None:
            self._stop = threading.Event()
            self._local = _Drawer(self._stop)
            self._proc = None
            return
        self._local = None
        self._stop = ctx.Event()
        self._commands, self._replies = ctx.Queue(), ctx.Queue()
        self._proc = ctx.Process(target=_serve, args=(_Drawer(self._stop), self._commands, self._replies),
                                 name="horizon-nav-rerun", daemon=True)
        self._proc.start()

    def setup(self, inp, cam_numbers, rrd: Path | None, *, spawn: bool = False, track=None,
              image_rate_hz: float | None = None) -> None:
        """The recording's inputs: ``rrd`` the .rrd path (None: viewer only, ``spawn``), ``track``
        GPS positions to aim the 3D view, ``image_rate_hz`` the images' thinning
        (:func:`.rerun_view.shown_frames`). A path that cannot be written is a UserError here."""
        rrd = None if rrd is None else Path(rrd)
        if rrd is not None:
            from scenarios.errors import UserError
            from scenarios.replay.rerun_view import temporary_path
            try:
                rrd.parent.mkdir(parents=True, exist_ok=True)
                temporary_path(rrd).touch()
                temporary_path(rrd).unlink()
            except OSError as e:
                raise UserError(f"rrd = {rrd}: the recording cannot be written there ({e})") from None
        self.rrd = rrd
        self._send("setup", inp if self._local is not None else drawn_inputs(inp), cam_numbers, self.rrd, spawn,
                   track, image_rate_hz)

    def _send(self, name: str, *args):
        if self._done:
            raise RecordingError(f"the recording has ended; cannot {name}")
        if self._local is not None:
            out = getattr(self._local, name)(*args)
            if name == "finish":
                self._local_out, self._done = out, True
            return None
        self._commands.put((name, args))
        return None

    def begin(self, frames) -> None:
        self._send("begin", _frames_kt(frames))

    def add_overlays(self, frames) -> None:
        """The front end's results of some frames (their overlays), as they come."""
        self._send("add_overlays", _frames_overlay(frames))

    def overlays(self) -> None:
        """Draw the overlays received (:func:`.rerun_view.overlays`)."""
        self._send("overlays")

    def solution(self, res, vectors, frames) -> None:
        self._send("solution", drawn_result(res), vectors, _frames_kt(frames))

    def check(self) -> None:
        """Raise the recording process's failure if it has already reported one."""
        if self._local is not None or self._done:
            return
        import queue
        try:
            status, out = self._replies.get_nowait()
        except queue.Empty:
            if not self._proc.is_alive():
                self._ended_without_reply()
            return
        self._end()
        if status == "error":
            self._raise(out)
        raise RecordingError("Rerun recording: the recording process ended early")

    def finish(self, smooth) -> None:
        """Send the smoother's result (None: no smoother): the time series are drawn and the file
        written while the caller goes on; :meth:`wait` for the end."""
        self._send("finish", smooth)

    def wait(self) -> Path | None:
        """Wait for the recording to be written (after :meth:`finish`); returns its path (None:
        viewer only). Raises :class:`RecordingError` (or UserError for a file the recording
        could not write) when the recording process failed."""
        if self._local is not None:
            path, tm = self._local_out
            self.timings.update(tm)
            return path
        import queue
        while True:
            try:
                status, out = self._replies.get(timeout=0.5)
                break
            except queue.Empty:
                if not self._proc.is_alive():
                    self._ended_without_reply()
        self._end()
        if status == "error":
            self._raise(out)
        path, tm = out
        self.timings.update(tm)
        return path

    def _raise(self, out):
        kind, msg, tb = out
        if kind == "OSError":
            from scenarios.errors import UserError
            raise UserError(f"Rerun recording {self.rrd}: {msg}")
        raise RecordingError(f"Rerun recording: {msg}\n{tb}")

    def abandon(self) -> None:
        """Stop and end the recording (its temporary file deleted); no error is raised."""
        if self._done:
            return
        self._stop.set()
        if self._local is not None:
            self._done = True
            self._local.abandon()
            return
        self._commands.put(("abandon", ()))
        self._proc.join(ABANDON_TIMEOUT_S)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        self._end()
        if self.rrd is not None:      # killed before it could delete its file
            from scenarios.replay.rerun_view import temporary_path
            try:
                temporary_path(self.rrd).unlink(missing_ok=True)
            except OSError:
                pass

    def _ended_without_reply(self):
        code = self._proc.exitcode
        self._end()
        raise RecordingError(f"Rerun recording: the recording process ended (exit code {code}) without finishing")

    def _end(self) -> None:
        self._done = True
        self._commands.cancel_join_thread()   # nothing more is read: do not wait for the pipe at exit
        self._proc.join(ABANDON_TIMEOUT_S)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        self._proc.close()
        self._commands.close()
        self._replies.close()

