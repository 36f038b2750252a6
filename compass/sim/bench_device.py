"""``compass device --pty --bench``: the simulated bench (:class:`compass.sim.bench_rig.BenchRig`) on a pty.

The module streams its line protocol on a pseudo-terminal in real time (or ``speed`` times
faster: the bench station works in the module's own ``t_s``).  The simulated operator reads the
station's instructions from the station's prompt file (``compass bench --prompt-file``), as a
person reads them off the screen, and acts on them in module time.  Faults can be injected: the
port vanishing for a while, the module changing its sample rate or its columns mid-session.
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np

from ._pty import open_pty, write_or_count
from .bench_rig import BenchRig

__all__ = ["BenchPty"]

_BLOCK_S = 0.05  # module time written at once


class BenchPty:
    """The simulated bench's module on a pty.

    Parameters
    ----------
    rig : BenchRig
    prompt_file : path-like
        The station's instruction file (JSON), read whenever it changes.
    speed : float
        Module seconds per wall second.
    link : path-like, optional
        A symbolic link to the current pty (stable across a disconnect).
    on_path : callable, optional
        Called with the link (or pty path) each time the pty opens.
    disconnect_at_s, disconnect_for_s : float, optional
        Close the pty at this module time and open a new one this many wall seconds later.
    rate_change_at_s : float, optional
        Halve the sample rate at this module time.
    header_change_at_s : float, optional
        Stop sending the accelerometer's columns at this module time.
    table : object, optional
        A turntable driven from elsewhere (the GRBL controller): its ``advance(t_s)`` is called
        before each block.
    """

    def __init__(self, rig: BenchRig, prompt_file, *, speed: float = 1.0, link=None, on_path=None,
                 disconnect_at_s=None, disconnect_for_s: float = 1.0, rate_change_at_s=None, header_change_at_s=None,
                 table=None):
        if not speed > 0:
            raise ValueError(f"--speed must be positive, got {speed}")
        self.rig = rig
        self.prompt_file = Path(prompt_file)
        self.speed = float(speed)
        self.link = None if link is None else Path(link)
        self.on_path = on_path
        self.disconnect_at_s = disconnect_at_s
        self.disconnect_for_s = disconnect_for_s
        self.rate_change_at_s = rate_change_at_s
        self.header_change_at_s = header_change_at_s
        self.table = table
        self.counts = dict.fromkeys(("samples", "overflow", "disconnects", "instructions"), 0)
        self._fds = ()
        self._prompt_mtime = None

    def open(self) -> str:
        master, slave, path = open_pty(self.link, blocking=False)
        self._fds = (master, slave)
        if self.on_path is not None:
            self.on_path(str(self.link or path))
        return path

    def close(self) -> None:
        if self.link is not None:
            self.link.unlink(missing_ok=True)
        for fd in self._fds:
            os.close(fd)
        self._fds = ()

    def _write(self, data: bytes) -> None:
        write_or_count(self._fds[0], data, self.counts)

    def _read_prompt(self) -> dict | None:
        try:
            mtime = self.prompt_file.stat().st_mtime_ns
        except FileNotFoundError:
            return None
        if mtime == self._prompt_mtime:
            return None
        try:
            instruction = json.loads(self.prompt_file.read_text())
        except (OSError, ValueError):
            return None  # read mid-replace: the next block reads it
        self._prompt_mtime = mtime
        self.counts["instructions"] += 1
        return instruction

    def run(self, stop: threading.Event, duration_s: float | None = None) -> None:
        """Stream until ``stop``, ``duration_s`` of module time, or the station's "done"."""
        if not self._fds:
            self.open()
        start = time.perf_counter()
        t = 0.0
        next_header = 0.0
        try:
            while not stop.is_set() and (duration_s is None or t < duration_s):
                instruction = self._read_prompt()
                if instruction is not None:
                    if instruction.get("do") == "done":
                        return
                    self.rig.instruct(instruction, t)
                if self.rate_change_at_s is not None and t >= self.rate_change_at_s:
                    self.rate_change_at_s = None
                    self.rig.rate_hz /= 2.0
                if self.header_change_at_s is not None and t >= self.header_change_at_s:
                    self.header_change_at_s = None
                    self.rig.send_accel = False
                    next_header = t
                n = max(1, int(round(_BLOCK_S * self.rig.rate_hz)))
                times = t + np.arange(n) / self.rig.rate_hz
                data = self.rig.lines(times)
                delay = start + times[-1] / self.speed - time.perf_counter()
                if delay > 0 and stop.wait(delay):
                    return
                if self.disconnect_at_s is not None and t >= self.disconnect_at_s:
                    self.disconnect_at_s = None
                    self.counts["disconnects"] += 1
                    self.close()
                    if stop.wait(self.disconnect_for_s):
                        return
                    self.open()
                    gone = time.perf_counter() - start
                    t = max(t, gone * self.speed)  # module time went on while unplugged
                    next_header = t
                    continue
                if t >= next_header:
                    data = self.rig.header() + data
                    next_header = t + 1.0
                self._write(data)
                if self.table is not None:
                    self.table.advance(times[-1])
                self.counts["samples"] += n
                t = times[-1] + 1.0 / self.rig.rate_hz
        finally:
            if self._fds:
                self.close()
