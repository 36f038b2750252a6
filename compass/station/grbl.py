"""A stepper turntable on a GRBL controller as the bench station's angle source (``--turntable grbl:PORT``).

GRBL (1.1, and grblHAL / Grbl-Mega with rotary axes) speaks lines over a serial port: every
command line is answered ``ok`` or ``error:N``; ``?`` is a real-time command (no line end, no
``ok``) answered by a status report ``<Idle|MPos:x,y,z,a|FS:0,0>`` (state ``Idle``, ``Run``,
``Hold``, ``Jog``, ``Alarm``, ``Door``, ``Check``, ``Home``, ``Sleep``; GRBL 0.9 writes
``<Idle,MPos:...,WPos:...>``); ``ALARM:N`` is pushed when the machine stops on a fault (1 hard
limit, 2 soft limit, 3 reset while moving, ...) and it then refuses motion until ``$X`` unlocks it.

The station unlocks the controller (``$X``), sets relative moves (``G91``) and turns the table a
stop at a time (``G1 A<step> F<feed>``), polls ``?`` until the controller is ``Idle`` at the stop,
then waits for the module to be still and keeps the stop's mean at the controller's reported
position (``MPos`` of the axis, modulo 360: the table's zero is the controller's).
An alarm, an error or a controller that does not answer within ``timeout_s`` ends the session
(:class:`compass.station.session.SessionEnded`), the flips done kept.

Continuously (``mode="continuous"``, ``--grbl-mode continuous``) the station turns the table once
round in one move (``G1 A360``) and keeps every sample: the status reports polled during the turn,
dated half way between the request ``?`` and the report's arrival in the host's clock, are put on
the module's clock by the chunks of the module's stream (:meth:`GrblSource.clock_pair`: each
chunk's receive time and its last sample's ``t_s``, interpolated), and the table's angle at each
sample is the reports' positions interpolated linearly to its time.  Where in the round trip the
controller took its position is not known (up to half of it either way), nor its own delay; the stated
angle sigma is the reports' own scatter about their neighbours' interpolation (for reports of
white timing error ``sigma``: ``sqrt(3/2) sigma``).
"""

from __future__ import annotations

import re
import time
from collections import deque

import numpy as np

from .session import SessionEnded
from .turn import TurnRejected

__all__ = ["GrblSource", "parse_status", "ALARMS"]

ALARMS = {1: "hard limit", 2: "soft limit", 3: "reset while in motion", 4: "probe fail", 5: "probe fail",
          6: "homing fail", 7: "homing fail (door)", 8: "homing fail (pull-off)", 9: "homing fail (no switch)"}
_AXES = "XYZABC"
_STATUS = re.compile(r"<([A-Za-z]+)(?::\d+)?[|,]MPos:([-\d.,]+)")


def parse_status(line: str) -> tuple[str, list[float]] | None:
    """``(state, machine position)`` of a GRBL status report, None for other lines.

    >>> parse_status("<Idle|MPos:0.000,0.000,0.000,90.000|FS:0,0>")
    ('Idle', [0.0, 0.0, 0.0, 90.0])
    >>> parse_status("<Run,MPos:1.000,2.000,3.000,WPos:1.000,2.000,3.000>")
    ('Run', [1.0, 2.0, 3.0])
    """
    m = _STATUS.match(line.strip())
    if m is None:
        return None
    return m.group(1), [float(v) for v in m.group(2).strip(",").split(",") if v]


class GrblSource:
    """The turntable turned by a GRBL controller, a stop at a time.

    Parameters
    ----------
    port : str
        The controller's serial port or pyserial URL.
    axis : str
        The rotary axis' letter (``A`` on grblHAL and Grbl-Mega-5X; ``X`` on a plain GRBL whose X
        drives the table, with its steps per mm set to steps per degree).
    step_deg : float
        Spacing of the stops, degrees (divides 360).
    feed_deg_min : float
        Feed rate of the moves, degrees a minute.
    timeout_s : float
        Longest wait for an answer, seconds (wall time).
    poll_s : float
        Interval between status requests, seconds.
    mode : {"stops", "continuous"}
        Turn a stop at a time, or once round in one move (module docstring).
    link : object, optional
        An open port (``write``, ``read``, ``close``) to use instead of opening ``port``
        (:class:`compass.sim.grbl.LoopbackPort`).
    clock : callable
        The host's clock, seconds (the receive times :meth:`clock_pair` is given are on it).
    """

    operator_moves = False
    angle_sigma_deg = 0.0  # a stepper's commanded position; its mechanics are not known here
    hold_s = 1.0  # continuous: still time at each end of the turn, seconds

    def __init__(self, port: str, *, axis: str = "A", step_deg: float = 10.0, feed_deg_min: float = 1800.0,
                 timeout_s: float = 2.0, poll_s: float = 0.1, mode: str = "stops", link=None, clock=time.monotonic):
        if mode not in ("stops", "continuous"):
            raise ValueError(f"--grbl-mode {mode}: expected stops or continuous")
        axis = axis.upper()
        if axis not in _AXES:
            raise ValueError(f"--grbl-axis {axis}: expected one of {', '.join(_AXES)}")
        if not (0 < step_deg <= 45.0) or abs(360.0 / step_deg - round(360.0 / step_deg)) > 1e-9:
            raise ValueError(f"--grbl-step {step_deg:g}: the step must divide 360 and be at most 45 deg")
        if not feed_deg_min > 0:
            raise ValueError(f"--grbl-feed must be positive, got {feed_deg_min:g}")
        self.port_name = port
        self.axis = axis
        self.step_deg = float(step_deg)
        self.feed_deg_min = float(feed_deg_min)
        self.timeout_s = timeout_s
        self.poll_s = poll_s
        self.mode = mode
        self.kind = mode
        self.clock = clock
        self.spec = "grbl" if mode == "stops" else "grbl:continuous"
        self._link = link
        self._reports: list = []  # continuous: (host time, position) of the turn's status reports
        self._pairs: deque = deque(maxlen=100000)  # (host receive time, module t_s) of the module's chunks
        self._start_deg = None
        self._port = None
        self._buffer = b""
        self._state = None
        self._position = None
        self._target = None
        self._waiting_ok = 0
        self._asked_at = None
        self._answered_at = None
        self._next_poll = 0.0

    # ---------------------------------------------------------------- link
    def open(self) -> None:
        """Open the controller's port, unlock it and set relative moves.

        Raises
        ------
        SessionEnded
            The port cannot be opened, or the controller does not answer or refuses.
        """
        import serial

        try:
            self._port = self._link or serial.serial_for_url(self.port_name, baudrate=115200, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise SessionEnded(f"GRBL controller: cannot open {self.port_name} ({exc})") from None
        self._send(b"\r\n\r\n")  # wake it; an unfinished line before is discarded
        time.sleep(0.05)
        self._read_lines()
        self._waiting_ok = 0
        for command in ("$X", "G91"):
            self._command(command)
            self._wait(lambda: self._waiting_ok == 0, f"'{command}'")
        self._status_now()

    def close(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except OSError:
                pass
            self._port = None

    def _send(self, data: bytes) -> None:
        try:
            self._port.write(data)
        except (OSError, Exception) as exc:  # serial.SerialException derives from OSError on posix only
            raise SessionEnded(f"GRBL controller on {self.port_name}: lost ({exc})") from None

    def _command(self, line: str) -> None:
        self._waiting_ok += 1
        self._send(line.encode("ascii") + b"\n")

    def _read_lines(self) -> None:
        try:
            data = self._port.read(4096)
        except Exception as exc:  # SerialException or OSError: the controller's port went away
            raise SessionEnded(f"GRBL controller on {self.port_name}: lost ({exc})") from None
        self._buffer += data
        *lines, self._buffer = self._buffer.replace(b"\r", b"\n").split(b"\n")
        for raw in lines:
            line = raw.decode("ascii", "replace").strip()
            if not line:
                continue
            if line == "ok":
                self._waiting_ok = max(0, self._waiting_ok - 1)
            elif line.startswith("ALARM:"):
                code = int(re.sub(r"\D", "", line) or 0)
                raise SessionEnded(f"GRBL controller on {self.port_name}: {line} ({ALARMS.get(code, 'alarm')}): the "
                                   f"table stopped; clear the cause, and continue with --resume")
            elif line.startswith("error:"):
                raise SessionEnded(f"GRBL controller on {self.port_name} refused a command: {line}")
            else:
                status = parse_status(line)
                if status is not None:
                    self._answered_at = self.clock()
                    self._state, position = status
                    index = _AXES.index(self.axis)
                    if index >= len(position):
                        raise SessionEnded(f"GRBL controller on {self.port_name} reports {len(position)} axes: no "
                                           f"{self.axis} axis (--grbl-axis)")
                    self._position = position[index]
                    if self._start_deg is not None:
                        asked = self._asked_at if self._asked_at is not None else self._answered_at
                        # formed between the request and its arrival: dated at the middle (the lag half known)
                        self._reports.append((0.5 * (min(asked, self._answered_at) + self._answered_at),
                                              self._position))
                    if self._state == "Alarm":
                        raise SessionEnded(f"GRBL controller on {self.port_name} is in alarm: the table cannot turn; "
                                           f"clear the cause, and continue with --resume")

    def _status_now(self) -> None:
        self._answered_at = None
        self._send(b"?")
        self._wait(lambda: self._answered_at is not None, "a status request '?'")

    def _wait(self, done, what: str) -> None:
        deadline = self.clock() + self.timeout_s
        while not done():
            if self.clock() > deadline:
                raise SessionEnded(f"GRBL controller on {self.port_name} does not answer {what} within "
                                   f"{self.timeout_s:g} s")
            time.sleep(0.01)
            self._read_lines()

    # ---------------------------------------------------------------- the station's side
    def poll(self) -> None:
        """Read what the controller sent; ask for its status every ``poll_s``; raise if it went quiet."""
        if self._port is None:
            return
        self._read_lines()
        now = self.clock()
        if self._asked_at is not None and (self._answered_at is None or self._answered_at < self._asked_at) \
                and now - self._asked_at > self.timeout_s:
            raise SessionEnded(f"GRBL controller on {self.port_name} does not answer a status request within "
                               f"{self.timeout_s:g} s")
        if now >= self._next_poll and (self._asked_at is None or (self._answered_at or 0) >= self._asked_at):
            self._asked_at = now
            self._next_poll = now + self.poll_s
            self._send(b"?")

    def stops(self) -> np.ndarray:
        return np.arange(0.0, 360.0 - 1e-9, self.step_deg)

    def request(self, angle_deg: float) -> None:
        """Turn to the next stop: one step further (the session's first stop is where the table is)."""
        if self._target is None:
            self._target = self._position
            return
        self._target += self.step_deg
        self._command(f"G1 {self.axis}{self.step_deg:.4f} F{self.feed_deg_min:.1f}")
        self._state = "Run"  # until a status report after the move says otherwise

    def arrived(self) -> bool:
        """The controller is idle at the stop and has acknowledged the move."""
        return (self._waiting_ok == 0 and self._state == "Idle" and self._position is not None
                and abs(self._position - self._target) < 1e-3)

    def position_deg(self, angle_deg: float) -> float:
        """The controller's reported position of the axis, modulo 360, degrees."""
        return float(np.mod(self._position, 360.0))

    def reverse_words(self) -> str:
        """How to reverse the angle's sense, in words (the station's stop when it counts against the gyro)."""
        return (f"invert the {self.axis} axis' direction in the controller (GRBL's $3, the direction port invert mask) "
                f"so that a positive move turns the table counterclockwise seen from above")

    # ---------------------------------------------------------------- continuous turns
    def clock_pair(self, t_rx: float, t_s: float) -> None:
        """A chunk of the module's stream received at host time ``t_rx`` whose last sample is at module time ``t_s``."""
        self._pairs.append((t_rx, t_s))

    def begin(self, flip_deg: float) -> None:
        """Turn the table once round, from where it stands, in one move."""
        self._start_deg = self._position
        self._reports = [(self.clock(), self._position)]
        self._command(f"G1 {self.axis}360.0000 F{self.feed_deg_min:.1f}")
        self._state = "Run"

    def live(self, data) -> float:
        """Degrees turned since the turn began, as the controller reports them."""
        return 0.0 if self._start_deg is None else float(np.clip(self._position - self._start_deg, 0.0, 360.0))

    def angles(self, data, flip_deg: float) -> tuple[np.ndarray, np.ndarray, float]:
        """``(platform_deg, keep, angle_sigma_deg)``: the reports' positions interpolated to the samples' times.

        Raises
        ------
        TurnRejected
            Too few status reports or stream chunks to put the reports on the module's clock.
        """
        pairs = np.array(self._pairs, float).reshape(-1, 2)
        reports = np.array(self._reports, float).reshape(-1, 2)
        if len(pairs) < 2 or len(reports) < 4:
            raise TurnRejected(f"{len(reports)} status reports from the GRBL controller during the turn: too few to "
                               f"date the table's angle; turn again")
        inside = (reports[:, 0] >= pairs[0, 0]) & (reports[:, 0] <= pairs[-1, 0])
        t_report = np.interp(reports[inside, 0], pairs[:, 0], pairs[:, 1])
        position = reports[inside, 1]
        order = np.argsort(t_report, kind="stable")
        t_report, position = t_report[order], position[order]
        platform = np.mod(np.interp(data.t_s, t_report, position), 360.0)
        return platform, np.ones(len(data), bool), _report_scatter_deg(t_report, position)


def _report_scatter_deg(t_s: np.ndarray, position_deg: np.ndarray) -> float:
    """The reports' angle error from their scatter about the interpolation of their neighbours, degrees.

    For reports with white errors ``sigma``, ``p_i - interp(p_{i-1}, p_{i+1})`` has variance ``3/2 sigma^2``
    at equal spacing; taken over the reports of a moving table (a still one's have no timing error).
    """
    t, p = t_s, position_deg
    if len(t) < 3:
        return 0.0
    span = t[2:] - t[:-2]
    ok = (span > 0) & (p[2:] != p[:-2])
    w = np.where(ok, (t[1:-1] - t[:-2]) / np.where(ok, span, 1.0), 0.5)
    residual = p[1:-1] - (p[:-2] + w * (p[2:] - p[:-2]))
    return float(np.sqrt(np.mean(residual[ok] ** 2) / 1.5)) if ok.any() else 0.0
