"""A simulated GRBL controller turning the simulated bench's turntable, on its own pty.

It answers as GRBL 1.1 with a rotary A axis does (:mod:`compass.station.grbl`): ``ok`` to each
line it accepts (``$X``, ``G90``/``G91``, ``G0``/``G1`` moves on A with ``F`` in deg/min),
``error:20`` to others, a status report ``<Idle|MPos:0.000,0.000,0.000,A|FS:0,0>`` (or ``Run``)
to the real-time ``?``.  A move turns the rig's table (:meth:`BenchRig.turn_table`) in module
time, at the feed rate.  Faults: ``alarm`` (after its third move it pushes ``ALARM:2``, then
reports ``Alarm`` and refuses moves with ``error:9``) and ``silent`` (after its third move it
answers nothing).
"""

from __future__ import annotations

import os
import re
import threading
from pathlib import Path

from ._pty import open_pty

__all__ = ["GrblPty"]

_MOVE = re.compile(r"^G[01]\s*A(-?[\d.]+)(?:\s*F([\d.]+))?$")


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
    """

    def __init__(self, rig, *, link=None, fault=None, speed: float = 1.0, on_path=None):
        self.rig = rig
        self.link = None if link is None else Path(link)
        self.fault = fault
        self.speed = speed
        self.on_path = on_path
        self.moves = 0
        self._t_s = 0.0  # the module's clock, as the device last set it
        self._relative = False
        self._feed = 600.0
        self._alarm = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None
        self._fds = ()

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

    def advance(self, t_s: float) -> None:
        """The module's clock (called by the device before each block)."""
        with self._lock:
            self._t_s = t_s

    def _position(self) -> float:
        with self._lock:
            t = self._t_s
        return float(self.rig.pose(t)[0][0])

    def _serve(self) -> None:
        import select

        master = self._fds[0]
        buffer = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(master, 1024)
            except OSError:
                return
            for byte in data:
                if byte == ord("?"):
                    self._reply(self._status())
                elif byte in (10, 13):
                    if buffer.strip():
                        self._reply(self._line(buffer.decode("ascii", "replace").strip().upper()))
                    buffer = b""
                else:
                    buffer += bytes([byte])

    def _reply(self, text: str | None) -> None:
        if text is None or (self.fault == "silent" and self.moves >= 3):
            return
        try:
            os.write(self._fds[0], text.encode("ascii") + b"\r\n")
        except OSError:
            pass

    def _status(self) -> str:
        if self._alarm:
            state = "Alarm"
        else:
            with self._lock:
                t = self._t_s
            state = "Idle" if self.rig.idle_at(t) else "Run"
        return f"<{state}|MPos:0.000,0.000,0.000,{self._position():.3f}|FS:0,0>"

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
        with self._lock:
            t = self._t_s
        target = value if not self._relative else None
        self.rig.turn_table(t, value if self._relative else target - self._position(), self._feed / 60.0)
        self.moves += 1
        if self.fault == "alarm" and self.moves >= 3:
            self._alarm = True
            return "ok\r\nALARM:2"
        return "ok"
