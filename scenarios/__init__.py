"""Everything of horizon-nav that reads or writes files: the flight simulator (:mod:`.sim`), the
MCAP flight log (:mod:`.flightlog`), configuration files (:mod:`.config`), the replay
(:mod:`.replay`), studies (:mod:`.study`), the importer (:mod:`.importer`) and the command line
(:mod:`.cli`).

The names below are the notebook API, the replay's steps as functions
(:mod:`scenarios.replay.steps`): they write no file and leave the interpreter's global state as
they found it.

>>> from scenarios import read_flight, see, navigate, smooth          # doctest: +SKIP
>>> log = read_flight("logs/atek.mcap", t_from="T+60", t_to="T+430")    # doctest: +SKIP
>>> sol = navigate(log, tuning=None, init="auto")                       # doctest: +SKIP
>>> df = smooth(sol).to_frame()                                         # doctest: +SKIP

Each is imported from its module on first use (:mod:`scenarios._lazy`), so ``import scenarios``
stays cheap. The replay itself (the command's run, writing the solution log and the recording)
is :func:`scenarios.replay.pipeline.replay`.
"""
from typing import TYPE_CHECKING

from scenarios._lazy import lazy_exports

if TYPE_CHECKING:
    from .replay.start import Start
    from .replay.steps import Flight, Hooks, Sight, Smoothed, Solution, initialise, navigate, read_flight, see, smooth

__all__ = ["read_flight", "see", "initialise", "navigate", "smooth", "Flight", "Sight", "Start", "Solution", "Smoothed",
           "Hooks"]
__getattr__ = lazy_exports(__name__, __file__)
