"""Pseudo-terminals for the simulated hardware: one opened (raw, linked atomically), one written to."""

from __future__ import annotations

import os
import pty
import tty
from pathlib import Path


def open_pty(link=None, *, blocking: bool = True) -> tuple[int, int, str]:
    """Open a raw pseudo-terminal; with ``link``, point that path at it (replaced atomically).

    Returns
    -------
    master, slave : int
        File descriptors (the caller closes both).
    path : str
        The slave's device path (what a reader opens).
    """
    master, slave = pty.openpty()
    tty.setraw(slave)
    if not blocking:
        os.set_blocking(master, False)
    path = os.ttyname(slave)
    if link is not None:
        tmp = Path(f"{link}.tmp{os.getpid()}")
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(path)
        os.replace(tmp, link)
    return master, slave, path


def write_or_count(fd: int, data: bytes, counts: dict) -> None:
    """Write ``data`` to a non-blocking pty; what its full buffer refuses counts in ``counts["overflow"]``."""
    try:
        written = os.write(fd, data)
    except BlockingIOError:
        written = 0
    if written < len(data):
        counts["overflow"] += 1
