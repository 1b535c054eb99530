"""``horizon-nav replay``: a flight log through the vision front end, the filter and the smoother
(docs/replay.md). Modules: :mod:`.steps` (the steps as Python functions: ``read_flight``, ``see``,
``initialise``, ``navigate``, ``smooth``; also exported by :mod:`scenarios`), :mod:`.inputs` (log
-> filter inputs), :mod:`.start` (the initial state), :mod:`.sight` (the vectors: the log's or the
vision's), :mod:`.vision_worker` (vision in worker processes), :mod:`.table` (a solution as a
pandas DataFrame), :mod:`.pipeline` (the command's run: solution log, recording, progress),
:mod:`.solution_log` (solution MCAP), :mod:`.summary` (figures and table), :mod:`.rerun_view`
(Rerun recording and blueprint), :mod:`.recording_process` (the recording in a process of its
own). The public names below are imported from their module on first use (:mod:`scenarios._lazy`).
"""
from typing import TYPE_CHECKING

from scenarios._lazy import lazy_exports

if TYPE_CHECKING:
    from .pipeline import ReplayOptions, ReplayResult, replay
    from .steps import Flight, Sight, Smoothed, Solution, initialise, navigate, read_flight, see, smooth
    from .summary import format_table, summarize

__all__ = ["replay", "ReplayOptions", "ReplayResult", "summarize", "format_table",
           "read_flight", "see", "initialise", "navigate", "smooth", "Flight", "Sight", "Solution", "Smoothed"]
__getattr__ = lazy_exports(__name__, __file__)
