"""``horizon-nav scenarios``: list the built-in scenario library with a one-line description each."""
from __future__ import annotations

from scenarios.sim.scenario import library

NAME = "scenarios"
HELP = "list the built-in flight scenarios (scenarios/library/*.toml)"


def add_arguments(p) -> None:
    pass


def run(args) -> int:
    items = library()
    width = max((len(n) for n, _ in items), default=0)
    for name, desc in items:
        print(f"{name:<{width}}  {desc}")
    return 0
