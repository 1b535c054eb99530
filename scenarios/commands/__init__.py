"""Subcommands of ``horizon-nav``: one module each, discovered by :mod:`scenarios.cli`."""
