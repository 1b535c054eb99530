"""The flight log: an MCAP file of ROS 2 messages (docs/log-format.md). :mod:`.format` holds the
message definitions, topic names and the vectorised CDR codec; :mod:`.writer` writes a log
(:class:`LogWriter`, whole chunks through :mod:`._chunks`); :mod:`.reader` reads one
(:func:`read_log`, records scanned by the numba kernels of :mod:`._scan`); :mod:`.jpeg` decodes
the camera frames it carries. The public names below are imported from their module on first use
(:mod:`scenarios._lazy`), so a process that only decodes frames imports no more than :mod:`.jpeg`.
"""
from typing import TYPE_CHECKING

from scenarios._lazy import lazy_exports

if TYPE_CHECKING:
    from .jpeg import decode_frame
    from .reader import FlightLog, LogFormatError, LogWarning, read_log
    from .writer import LogWriter

__all__ = ["read_log", "FlightLog", "LogFormatError", "LogWarning", "LogWriter", "decode_frame"]
__getattr__ = lazy_exports(__name__, __file__)
