"""The ``horizon-nav`` command line.

Each subcommand is a module in :mod:`scenarios.cli` that defines ``NAME``, ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``. Modules are discovered, so a new capability
adds a file and touches nothing here. Errors that users can fix (:class:`UserError`, ``ValueError``
from input checks, missing files) are printed as one line without a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from scenarios import cli as commands
from scenarios.errors import UserError


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("horizon-nav")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "0+unknown"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="horizon-nav",
        description="Post-flight navigation of sounding rockets from IMU, GPS and camera "
        "Earth-horizon and Sun vectors (Braun & Barf 2022).",
    )
    parser.add_argument("--version", action="version", version=f"horizon-nav {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"scenarios.cli.{info.name}")
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run, _flags=getattr(module, "FLAGS", {}))
    return parser


def flag_names(message: str, flags: dict) -> str:
    """``message`` with the library's parameter spellings (keys of ``flags``, e.g. ``"force=True"``)
    replaced by the command's options (``"--force"``): library code names its parameters, the
    command line its options."""
    for name, flag in flags.items():
        message = message.replace(name, flag)
    return message


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "_run", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except (UserError, ValueError, FileNotFoundError) as exc:
        print(f"horizon-nav {args.command}: error: {flag_names(str(exc), args._flags)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"horizon-nav {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
