"""``horizon-nav replay``: a flight log through the vision front end, the filter and the smoother
(docs/replay.md). Modules: :mod:`.inputs` (log -> filter inputs), :mod:`.vision_worker` (vision in
worker processes), :mod:`.pipeline` (the run), :mod:`.solution_log` (solution MCAP),
:mod:`.summary` (figures and table), :mod:`.rerun_view` (Rerun recording and blueprint),
:mod:`.recording_process` (the recording in a process of its own). The public names below are
imported from their module on first use (:mod:`scenarios._lazy`).
"""
from typing import TYPE_CHECKING

from scenarios._lazy import lazy_exports

if TYPE_CHECKING:
    from .pipeline import ReplayOptions, ReplayResult, replay
    from .summary import format_table, summarize

__all__ = ["replay", "ReplayOptions", "ReplayResult", "summarize", "format_table"]
__getattr__ = lazy_exports(__name__, __file__)
