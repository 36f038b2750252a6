"""Atomic file writes: a reader never sees half a file, a crash never leaves one."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["OutputError", "atomic_write_text", "check_writable"]


class OutputError(ValueError):
    """An output path that cannot be written (exit status 2 on the command line)."""


def check_writable(path, force: bool) -> Path:
    """Refuse to overwrite ``path`` unless ``force``; make sure it can be written (before long work).

    Raises
    ------
    FileExistsError
        The file exists and ``force`` is False.
    OutputError
        The path is a folder, or its folder cannot be created or written.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path} is a folder: expected a file name")
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; use --force to overwrite it")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{path}: cannot create its folder ({exc.strerror})") from None
    if not os.access(path.parent, os.W_OK):
        raise OutputError(f"{path}: its folder is not writable")
    return path


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename.

    Raises
    ------
    OutputError
        The folder cannot be created or written, or the file cannot be replaced (the old
        file, if any, is left as it was).
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise OutputError(f"{path}: cannot write ({exc.strerror})") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise OutputError(f"{path}: cannot write ({exc.strerror})") from None
        raise
