"""A simulated GRBL controller turning the simulated bench's turntable, on its own pty.

It answers as GRBL 1.1 with a rotary A axis does (:mod:`compass.station.grbl`): ``ok`` to each
line it accepts (``$X``, ``G90``/``G91``, ``G0``/``G1`` moves on A with ``F`` in deg/min),
``error:20`` to others, a status report ``<Idle|MPos:0.000,0.000,0.000,A|FS:0,0>`` (or ``Run``)
to the real-time ``?``.  A move turns the rig's table (:meth:`BenchRig.turn_table`) in module
time, at the feed rate.  Faults: ``alarm`` (after its third move it pushes ``ALARM:2``, then
reports ``Alarm`` and refuses moves with ``error:9``) and ``silent`` (after its third move it
answers nothing).  ``invert_direction`` is GRBL's ``$3`` direction invert mask set for the axis the
wrong way for the table: a positive move turns the table clockwise seen from above (the reported
``MPos`` counts up all the same, the negated table angle).

:class:`GrblController` is the controller itself (bytes in, replies out, in module time);
:class:`GrblPty` serves it on a pty, :class:`LoopbackPort` hands it to
:class:`compass.station.grbl.GrblSource` in the same process (a benchmark in lock step).  A status
report is answered at the position of ``report_delay_s`` (uniform, 0 to that) before the time it
is asked at: the time a report takes to be formed, sent and read, which the station cannot see.
"""

from __future__ import annotations

import os
import re
import threading
from pathlib import Path

import numpy as np

from ._pty import open_pty

__all__ = ["GrblController", "GrblPty", "LoopbackPort"]

_BLOCK_AHEAD_S = 0.05  # module seconds a report may run ahead of the last sample written (one block)
_MOVE = re.compile(r"^G[01]\s*A(-?[\d.]+)(?:\s*F([\d.]+))?$")


class GrblController:
    """The controller's answers, moving ``rig``'s table in module time.

    Parameters
    ----------
    rig : BenchRig
    fault : {"alarm", "silent"} or None
    report_delay_s : float
        A status report gives the position this long (uniform from 0) before it is asked for, seconds.
    seed : int
        Seeds the report delays.
    invert_direction : bool
        The ``$3`` mask turns the table clockwise seen from above on a positive move (module docstring).
    """

    def __init__(self, rig, *, fault=None, report_delay_s: float = 0.0, seed: int = 0, invert_direction: bool = False):
        self.rig = rig
        self.fault = fault
        self.sign = -1.0 if invert_direction else 1.0  # the table's turn per degree of the axis
        self.report_delay_s = report_delay_s
        self.moves = 0
        self._t_s = 0.0  # the module's clock, as the device last set it
        self.module_clock = None  # or a callable: the module's time now (a device streaming in real time)
        self._relative = False
        self._feed = 600.0
        self._alarm = False
        self._buffer = b""
        self._lock = threading.Lock()
        self._rng = np.random.default_rng([seed, 0x6B1])

    def advance(self, t_s: float) -> None:
        """The module's clock (called by the device before each block)."""
        with self._lock:
            self._t_s = t_s

    def _now(self) -> float:
        if self.module_clock is not None:
            return self.module_clock()
        with self._lock:
            return self._t_s

    def receive(self, data: bytes) -> bytes:
        """The controller's replies to the bytes the host sent."""
        out = []
        for byte in data:
            if byte == ord("?"):
                out.append(self._status())
            elif byte in (10, 13):
                if self._buffer.strip():
                    out.append(self._line(self._buffer.decode("ascii", "replace").strip().upper()))
                self._buffer = b""
            else:
                self._buffer += bytes([byte])
        if self.fault == "silent" and self.moves >= 3:
            return b""
        return b"".join(text.encode("ascii") + b"\r\n" for text in out if text is not None)

    def _status(self) -> str:
        t = self._now()
        state = "Alarm" if self._alarm else ("Idle" if self.rig.idle_at(t) else "Run")
        seen = t - float(self._rng.uniform(0.0, self.report_delay_s)) if self.report_delay_s else t
        return f"<{state}|MPos:0.000,0.000,0.000,{self._axis_deg(seen):.3f}|FS:0,0>"

    def _axis_deg(self, t_s: float) -> float:
        """The axis' machine position at module time ``t_s``: the table's angle, negated under ``invert_direction``,
        degrees."""
        return self.sign * float(self.rig.pose(t_s)[0][0])

    def _line(self, line: str) -> str | None:
        if line == "$X":
            self._alarm = False
            return "[MSG:Caution: Unlocked]\r\nok"
        if line in ("G90", "G91"):
            self._relative = line == "G91"
            return "ok"
        if line.startswith("G91 "):
            self._relative = True
            line = line[4:].strip()
        move = _MOVE.match(line)
        if move is None:
            return "error:20"
        if self._alarm:
            return "error:9"
        if move.group(2):
            self._feed = float(move.group(2))
        value = float(move.group(1))
        t = self._now()
        delta = value if self._relative else value - self._axis_deg(t)
        self.rig.turn_table(t, self.sign * delta, self._feed / 60.0)
        self.moves += 1
        if self.fault == "alarm" and self.moves >= 3:
            self._alarm = True
            return "ok\r\nALARM:2"
        return "ok"


class LoopbackPort:
    """A controller as a port object (``write``, ``read``, ``close``) in the same process: what is written is
    answered at once."""

    def __init__(self, controller: GrblController):
        self.controller = controller
        self._out = b""

    def write(self, data: bytes) -> int:
        self._out += self.controller.receive(data)
        return len(data)

    def read(self, size: int = 1) -> bytes:
        data, self._out = self._out[:size], self._out[size:]
        return data

    def close(self) -> None:
        self._out = b""


class GrblPty:
    """The controller on a pty, moving ``rig``'s table.

    Parameters
    ----------
    rig : BenchRig
    link : path-like, optional
        A symbolic link to the controller's pty.
    fault : {"alarm", "silent"} or None
    speed : float
        Module seconds per wall second (the rig's clock runs that much faster).
    on_path : callable, optional
    invert_direction : bool
        A positive move turns the table clockwise seen from above (:class:`GrblController`).
    """

    def __init__(self, rig, *, link=None, fault=None, speed: float = 1.0, on_path=None,
                 invert_direction: bool = False):
        self.controller = GrblController(rig, fault=fault, invert_direction=invert_direction)
        self.link = None if link is None else Path(link)
        self.speed = speed
        self.on_path = on_path
        self._stop = threading.Event()
        self._thread = None
        self._fds = ()

    @property
    def moves(self) -> int:
        return self.controller.moves

    def advance(self, t_s: float) -> None:
        """The module's clock: the last sample the device has written (called after each block).  Between
        blocks the controller's time runs on with the wall clock, at most a block ahead: a report gives the
        position when it is asked for, and never one the stream has not reached (a device behind its pace
        under load stays consistent with its stream)."""
        import time

        self.controller.advance(t_s)
        wall, speed = time.perf_counter(), self.speed
        self.controller.module_clock = lambda: t_s + min(time.perf_counter() - wall, _BLOCK_AHEAD_S / speed) * speed

    def open(self) -> str:
        master, slave, path = open_pty(self.link)
        self._fds = (master, slave)
        if self.on_path is not None:
            self.on_path(str(self.link or path))
        os.write(master, b"\r\nGrbl 1.1h ['$' for help]\r\n")
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()
        return path

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        if self.link is not None:
            self.link.unlink(missing_ok=True)
        for fd in self._fds:
            os.close(fd)
        self._fds = ()

    def _serve(self) -> None:
        import select

        master = self._fds[0]
        while not self._stop.is_set():
            ready, _, _ = select.select([master], [], [], 0.05)
            if not ready:
                continue
            try:
                reply = self.controller.receive(os.read(master, 1024))
                if reply:
                    os.write(master, reply)
            except OSError:
                return
