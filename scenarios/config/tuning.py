"""Read a navigation-filter tuning TOML file into :class:`nav.tuning.Tuning`.

A tuning file holds overrides of the defaults (003 table 3, :class:`nav.tuning.Tuning`) in
tables per part of the filter (:mod:`nav.tuning` lists them); errors name the file and the key."""
from __future__ import annotations

from pathlib import Path

from nav.tuning import Tuning, tuning_from_dict
from scenarios.config.toml_file import read_toml

#: The default tuning file: 003 table 3, i.e. no override.
DEFAULT_TUNING_FILE = Path(__file__).parent.parent / "library" / "tuning" / "table3.toml"


def load_tuning(path: str | Path | None = None) -> Tuning:
    """Load a tuning file; ``None`` loads 003 table 3. Errors name the file."""
    p = Path(path) if path is not None else DEFAULT_TUNING_FILE
    doc, _ = read_toml(p, "tuning file")
    try:
        return tuning_from_dict(doc)
    except ValueError as e:
        raise ValueError(f"{p}: {e}") from None
