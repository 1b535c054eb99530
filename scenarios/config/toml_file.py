"""Reading a user's TOML file: the one wording of "not found", "cannot read" and "not valid TOML"
that every loader (camera, vision, tuning, scenario, mapping, study, state file) uses."""
from __future__ import annotations

import tomllib
from pathlib import Path

from scenarios.errors import UserError


def read_text(path: str | Path, what: str, label: str | None = None) -> str:
    """The file's text (UTF-8); UserError ``"<label>: <what> not found"`` or ``"... cannot read
    <what> (<reason>)"``. ``label`` defaults to the path."""
    p = Path(path)
    label = str(p) if label is None else label
    try:
        return p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{label}: {what} not found") from None
    except OSError as exc:
        raise UserError(f"{label}: cannot read {what} ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise UserError(f"{label}: cannot read {what} (not UTF-8 text: {exc.reason} at byte "
                        f"{exc.start})") from None


def parse_toml(text: str, label: str) -> dict:
    """The TOML document in ``text``; UserError ``"<label>: not valid TOML (<reason>)"``."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{label}: not valid TOML ({exc})") from None


def read_toml(path: str | Path, what: str, label: str | None = None) -> tuple[dict, str]:
    """``(document, text)`` of a TOML file, with the errors of :func:`read_text` and
    :func:`parse_toml`.

    Examples
    --------
    >>> doc, text = read_toml("scenarios/library/atek.toml", "scenario file")  # doctest: +SKIP
    """
    label = str(Path(path)) if label is None else label
    text = read_text(path, what, label)
    return parse_toml(text, label), text
