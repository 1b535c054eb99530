"""Atomic output files: write to a temporary file beside the target, then rename.

A reader never sees a half-written file, and an interrupted run leaves the previous file (or none).
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable


def atomic_output(path: str | os.PathLike, write: Callable[[str], None]) -> Path:
    """Call ``write(tmp_path)`` to produce the file, then rename it onto ``path``.

    The temporary file lives in the target's folder (same file system, so the rename is atomic) and
    gets the usual umask permissions. On any exception it is removed and the exception re-raised.
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent)
    os.close(fd)
    try:
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return p


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_output(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    return atomic_output(path, lambda tmp: Path(tmp).write_bytes(data))


def atomic_savez(path: str | os.PathLike, **arrays) -> Path:
    """``np.savez`` of ``arrays`` to exactly ``path``, atomically (given a file name, savez would
    append ".npz" to the temporary file's)."""
    import numpy as np

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return atomic_output(path, write)


def move_into_place(tmp: str | os.PathLike, path: str | os.PathLike) -> None:
    """Rename the finished file ``tmp`` to ``path``; a file already there is renamed aside first
    and deleted after. For large files written without fsync (the Rerun recording), where
    :func:`atomic_output`'s one rename over the old file is slow: ext4 (``auto_da_alloc``)
    allocates and starts writing a file renamed over another before the rename returns, which
    for a recording of hundreds of MB takes longer than deleting the old file after a rename
    aside. Interrupted in between, the old file is left as ``.<name>.old``, the new
    one in place."""
    path = Path(path)
    old = path.with_name("." + path.name + ".old")
    try:
        path.replace(old)
    except FileNotFoundError:
        old = None
    Path(tmp).replace(path)
    if old is not None:
        old.unlink(missing_ok=True)
