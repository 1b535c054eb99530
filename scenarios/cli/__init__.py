"""The ``horizon-nav`` command line: :func:`main` (in :mod:`._main`) builds the parser from the
subcommands, one module each in this package (``analyze``, ``calibrate``, ``demo``, ``ephem``,
``export``, ``import_flight``, ``plot_truth``, ``render``, ``replay``, ``scenarios``, ``simulate``,
``study``, ``vision``), each defining ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. Modules whose name starts with ``_`` are not commands. ``python -m
scenarios.cli`` runs :func:`main`.
"""
from scenarios.cli._main import build_parser, main

__all__ = ["main", "build_parser"]
