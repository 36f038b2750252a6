"""The bench station's session: four flips, one full turn each, judged as they come.

:class:`Station` is fed the module's samples one at a time (:meth:`Station.feed`) and keeps an
:class:`Instruction` for the operator (which face goes down, turn the table, turn to a stop); it
decides from the data alone, in module time, when a flip is done, a turn is complete, a stop is
held, and whether what it got is usable.  It does no I/O of its own beyond the session store:
the command (``compass bench``) feeds it a serial stream and prints its words, a benchmark or a
test feeds it a simulated module in lock step.

Per flip (SPEC section 1: flip kappa about the turntable's X axis):

1. *flip*: the operator puts the face asked for down; the station waits for a still second and,
   with an accelerometer, for gravity to show that face (a wrong face is said, once per face);
2. *turn* (continuous sources): the operator turns the table once round and holds still; the
   turn ends on a still second once 360 deg are covered (or after 3 s still short of it), or
   *stops* (stop sources): each stop is asked for, reached and held a still second, its mean kept;
3. the flip's rows are checked (coverage and widest gap, turn rate against the sample rate, the
   face the data show) and kept on disk, or the turn is asked for again with the reason.  An angle source
   that is not the gyro (an encoder column, a graduation, a GRBL axis) must count the turn the way the
   module's gyro saw it about the table's axis (:func:`compass.station.turn.gyro_turn_deg`): one that
   counts against it would mirror the calibration, and ends the session before its flip is kept, naming
   the fix; without a gyro, the direction is the source's word alone, said once.

The module's header and sample rate must not change during a session: a change ends it
(:class:`SessionEnded`, the flips done are kept).  Its clock may restart (a reset, a replug, a
``--resume`` after a power-up: ``t_s`` from about 0 again): the step in progress is redone, and a flip
kept after it has its ``t_s`` go on from the flips kept before, after :data:`compass.io.clock.RESTART_GAP_S` and its
median step, said and kept in the recording's ``# clock:`` line (SPEC: ``t_s`` non-decreasing).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..io.clock import RESTART_GAP_S
from ..io.fourflip import NOMINAL_FLIPS_DEG
from .checks import circle_axis, coverage_gap, face_name, is_still, nearest_face, up_in_housing
from .store import FlipRows
from .turn import Reading, ReadingBuffer, TurnData, TurnRejected, WrongFace, gyro_turn_deg

__all__ = ["Instruction", "SessionEnded", "Station"]

_CHECK_EVERY_S = 0.1  # how often (module time) the station judges its windows
_FACE_TOLERANCE_DEG = 25.0  # gravity this close to the face asked for is that face
_RATE_TOLERANCE = 0.1  # relative change of the sample rate that ends a session
_JUMP_S = 2.0  # a reading this far after the last is kept only when the next one follows it (a corrupted t_s)


class SessionEnded(ValueError):
    """The session cannot go on (the module changed its rate or header, the turntable failed)."""


@dataclass(frozen=True)
class Instruction:
    """What the station asks of the operator now.

    Attributes
    ----------
    n : int
        Increases with every new instruction (also when the same step is asked for again).
    do : {"flip", "turn", "stop", "done"}
    flip_deg : float or None
        The flip being recorded.
    stop_deg : float or None
        The stop to turn to (``do == "stop"``).
    text : str
        The instruction in words.
    redo : str or None
        Why the step is asked for again.
    """

    n: int
    do: str
    flip_deg: float | None
    stop_deg: float | None
    text: str
    redo: str | None = None

    def to_json(self) -> dict:
        return {"n": self.n, "do": self.do, "flip_deg": self.flip_deg, "stop_deg": self.stop_deg,
                "text": self.text, "redo": self.redo}


@dataclass
class Progress:
    """The readout: where the session is."""

    flip_deg: float | None = None
    step: str = ""
    covered_deg: float = 0.0
    rate_hz: float = float("nan")
    turn_dps: float = 0.0
    flips_done: int = 0


@dataclass
class Station:
    """The four-flip session as a state machine fed one sample at a time.

    Parameters
    ----------
    source : ColumnSource, GyroSource, ManualSource or GrblSource
        The turntable's angle (:mod:`compass.station.sources`).
    channels : tuple of str
        The module's magnetic channels, in the order of :attr:`Reading.outputs`.
    ask : bool
        Also wait for :meth:`confirm` (the operator pressing Enter) before taking a flip as done;
        False (``--yes``): the data alone decide.
    done : dict, optional
        Flips already kept (``--resume``): nominal flip -> :class:`FlipRows`.
    rate_hz : float, optional
        The module's sample rate of the flips already kept.
    on_flip : callable, optional
        ``on_flip(FlipRows)`` when a flip is finished (the store keeps it).
    still_s : float
        Still time that ends a flip, a turn or a stop, seconds.
    give_up_s : float
        Still time after which a turn short of 360 deg is judged as it is (and the session's first
        stop taken where the table stands), seconds.
    max_gap_deg : float
        Widest gap between a continuous turn's angles, degrees.
    max_step_deg : float
        Most the table may turn between two samples, degrees (sets the fastest turn).

    Attributes
    ----------
    instruction : Instruction
    events : list of (str, str)
        ``(level, text)``: "info", "warn" (a redo, a wrong face) for the readout; :meth:`drain`.
    progress : Progress
    finished : bool
    """

    source: object
    channels: tuple
    ask: bool = False
    done: dict = field(default_factory=dict)
    rate_hz: float | None = None
    on_flip: object = None
    still_s: float = 1.0
    give_up_s: float = 5.0
    max_gap_deg: float = 3.0
    max_step_deg: float = 1.0
    instruction: Instruction | None = None
    events: list = field(default_factory=list)
    progress: Progress = field(default_factory=Progress)
    finished: bool = False
    columns: tuple | None = None

    def __post_init__(self):
        self.channels = tuple(self.channels)
        self._n = 0
        self._buffer = ReadingBuffer()  # the step's readings
        self._recent = ReadingBuffer()  # the last readings, across steps (cleared now and then)
        self._dts: deque = deque(maxlen=64)  # the last sample intervals, seconds
        self._samples = 0
        self._last_t = None
        self._jump_to = None  # a reading far after the last, waiting for the next to confirm it
        self._next_check = -np.inf
        self._confirmed = False
        self._still_since = None
        self._moved = False
        self._warned_faces: set = set()
        self._stop_rows: list = []  # (still window, angle, the gyro's turn from the stop before), per stop
        self._stop_index = 0
        self._said_no_gyro = False
        self._offset_s = None  # the recording's t_s less the module's on its current clock (found at the next flip)
        self._first_stop = not self.done
        if self.done:
            self.columns = next(iter(self.done.values())).columns  # a resumed session keeps its columns
        self.progress.flips_done = len(self.done)
        self._next_flip()

    # ---------------------------------------------------------------- public
    def drain(self) -> list:
        """Return and clear the pending events."""
        events, self.events = self.events, []
        return events

    def confirm(self) -> None:
        """The operator says the face asked for is down (interactive sessions)."""
        self._confirmed = True

    def link_lost(self, reason: str) -> None:
        """The module's port went away: the step in progress is discarded and asked for again."""
        if self.finished:
            return
        kept = ", ".join(f"{f:g}" for f in sorted(self.done)) or "none"
        self.events.append(("warn", f"{reason}: flip {self.progress.flip_deg:g}'s "
                                    f"{self.instruction.do} is redone when it is back (flips kept: {kept})"))
        self._restart_step("the module's port was lost")

    def feed(self, reading: Reading) -> None:
        """Take one sample; may change :attr:`instruction`, add events, finish a flip.

        Raises
        ------
        SessionEnded
            The module's sample rate changed (by more than 10 %).
        """
        if self.finished or not self._in_time(reading.t_s):
            return
        if self._last_t is not None and reading.t_s < self._last_t:  # the module's clock restarted
            self.events.append(("warn", f"the module's clock went back from {self._last_t:.6g} s to {reading.t_s:.6g} "
                                        f"s (a reset?): flip {self.progress.flip_deg:g}'s {self.instruction.do} is "
                                        f"redone"))
            self._new_clock()
            self._restart_step("the module's clock restarted")
        self._check_rate(reading.t_s)
        self._buffer.append(reading)
        self._recent.append(reading)
        if len(self._recent) > 50000:  # keep the last seconds only (t_s is searched in it)
            kept = self._recent.arrays(2 * self.still_s)
            self._recent.clear()
            for i in range(len(kept)):
                self._recent.append(Reading(kept.t_s[i], kept.outputs[i], *(None if getattr(kept, n) is None
                                    else getattr(kept, n)[i] for n in ("accel", "gyro", "encoder_deg", "temp_c"))))
        if reading.t_s < self._next_check:
            return
        self._next_check = reading.t_s + _CHECK_EVERY_S
        step = self.instruction.do
        if step == "flip":
            self._on_flip_step()
        elif step == "turn":
            self._on_turn_step()
        elif step == "stop":
            self._on_stop_step()

    def _new_clock(self) -> None:
        """The module's clock restarted: the readings' times are forgotten, and the recording's offset of the new
        clock is found when its first flip is kept (:meth:`_after_kept`)."""
        self._last_t = None
        self._jump_to = None
        self._recent.clear()
        self._dts.clear()
        self._next_check = -np.inf
        self._offset_s = None

    def _in_time(self, t_s: float) -> bool:
        """Whether a reading's time can be taken: after the last one, and a jump of over :data:`_JUMP_S` only when
        the next reading follows it (a t_s corrupted on the line, which a stream without checksums lets through,
        would otherwise stop the session's clock: nothing is judged until module time reaches it); a time that went
        back likewise, when the next follows it (the module's clock restarted)."""
        last = self._last_t
        if last is None or not np.isfinite(t_s):
            return bool(np.isfinite(t_s))
        if 0.0 < t_s - last <= _JUMP_S:
            self._jump_to = None
            return True
        if t_s == last:
            return False
        jumped, self._jump_to = self._jump_to, t_s
        return jumped is not None and 0.0 < t_s - jumped <= _JUMP_S

    # ---------------------------------------------------------------- steps
    def _instruct(self, do: str, text: str, *, stop_deg=None, redo=None) -> None:
        self._n += 1
        self.instruction = Instruction(self._n, do, self.progress.flip_deg, stop_deg, text, redo)
        self._buffer.clear()
        self._still_since = None
        self._moved = False
        self._confirmed = False
        self.progress.step = do
        if do != "stop":  # a stop's instruction keeps the flip's stops counted so far
            self.progress.covered_deg = 0.0
        self.events.append(("info", text if redo is None else f"redo: {redo}; {text}"))

    def _next_flip(self) -> None:
        remaining = [f for f in NOMINAL_FLIPS_DEG if f not in self.done]
        if not remaining:
            self.finished = True
            self.progress.step = "done"
            self._n += 1
            self.instruction = Instruction(self._n, "done", None, None, "all four flips recorded")
            return
        self.progress.flip_deg = remaining[0]
        self._warned_faces = set()
        self._instruct("flip", f"flip {remaining[0]:g} ({len(self.done) + 1}/4): put the cube with "
                               f"{face_name(remaining[0])}, X edge on the turntable's X axis, and let go")

    def _restart_step(self, reason: str) -> None:
        if self.instruction.do == "flip":
            self._instruct("flip", self.instruction.text, redo=reason)
        else:
            self._start_turn(redo=reason)

    def _start_turn(self, redo=None) -> None:
        flip = self.progress.flip_deg
        if self.source.kind == "continuous":
            self.source.begin(flip)
            hold = "a second" if self.source.hold_s <= 1.0 else f"{self.source.hold_s:g} seconds"
            if getattr(self.source, "operator_moves", True):
                text = (f"flip {flip:g}: with the table at its mark, hold still {hold}, turn it once round "
                        f"counterclockwise (seen from above) back to the mark, and hold still {hold}")
            else:
                text = f"flip {flip:g}: the table turns once round"
            self._instruct("turn", text, redo=redo)
        else:
            self._stop_rows = []
            self._stop_index = 0
            self.progress.covered_deg = 0.0
            self._ask_stop(redo=redo)

    def _ask_stop(self, redo=None) -> None:
        angle = float(self.source.stops()[self._stop_index])
        self.source.request(angle)
        what = "turn the table to {} deg and hold still" if self.source.operator_moves else "the table turns to {} deg"
        self._instruct("stop", f"flip {self.progress.flip_deg:g}: " + what.format(f"{angle:g}"), stop_deg=angle,
                       redo=redo)

    def _window(self) -> TurnData | None:
        """The last ``still_s`` of samples, when they span it."""
        if len(self._recent) < 5:
            return None
        window = self._recent.arrays(self.still_s)
        if len(window) < 5 or window.t_s[-1] - window.t_s[0] < 0.9 * self.still_s:
            return None
        return window

    def _still_now(self) -> bool | None:
        window = self._window()
        if window is None:
            return None
        still = is_still(window.t_s, window.outputs)
        if not still:
            self._moved = True
            self._still_since = None
        elif self._still_since is None:
            self._still_since = window.t_s[0]
        return still

    def _on_flip_step(self) -> None:
        if not self._still_now():
            return
        if self.ask and not self._confirmed:
            return
        flip = self.progress.flip_deg
        window = self._window()
        if window.accel is not None:
            face, off = nearest_face(window.accel.mean(axis=0))
            expected = nearest_face(up_in_housing(flip))[0]
            if face != expected or off > _FACE_TOLERANCE_DEG:
                previous = [f for f in self.done if f != flip]
                stays = previous and nearest_face(up_in_housing(max(previous)))[0] == face
                if face != expected and not stays and face not in self._warned_faces:
                    self._warned_faces.add(face)
                    self._instruct("flip", f"flip {flip:g}: put the cube with {face_name(flip)}",
                                   redo=f"wrong face down: the accelerometer shows {face} up; flip {flip:g} needs "
                                        f"{face_name(flip)}")
                return
        elif not (self._moved or not self.done or self.ask):
            return  # without an accelerometer: the cube must have moved since the flip was asked for
        self._start_turn()

    def _on_turn_step(self) -> None:
        still = self._still_now()
        data = self._buffer.arrays()
        covered = self.source.live(data)
        self.progress.covered_deg = float(np.clip(covered, 0.0, 360.0))
        self.progress.rate_hz = data.rate_hz if len(data) > 2 else self.progress.rate_hz
        if not (still and self._moved):
            return
        held = self._recent.last_t_s - self._still_since
        if held < self.source.hold_s or (covered < 359.0 and held < self.give_up_s):
            return
        try:
            rows = self._turn_rows(data)
        except TurnRejected as exc:
            self._redo(exc)
            return
        self._keep(rows)

    def _on_stop_step(self) -> None:
        still = self._still_now()
        if not still:
            return
        held = self._recent.last_t_s - self._still_since
        if self.source.operator_moves and not self._moved and not (self._first_stop and held >= self.give_up_s):
            return  # the table has not left the last stop yet (the session's first may already be there)
        if not self.source.operator_moves and not self.source.arrived():
            return
        if held < self.still_s + 0.5:
            return  # the window must start after the motion's last tremor
        window = self._window()
        self._first_stop = False
        angle = self.source.position_deg(self.instruction.stop_deg)
        self._stop_rows.append((window, angle, gyro_turn_deg(self._buffer.arrays(), self.progress.flip_deg)))
        self.progress.covered_deg = 360.0 * len(self._stop_rows) / len(self.source.stops())
        self._stop_index += 1
        if self._stop_index < len(self.source.stops()):
            self._ask_stop()
            return
        try:
            rows = self._stops_rows()
        except TurnRejected as exc:
            self._redo(exc)
            return
        self._keep(rows)

    def _redo(self, exc: TurnRejected) -> None:
        """Ask for the turn again, or for the flip first when the face was wrong."""
        flip = self.progress.flip_deg
        if isinstance(exc, WrongFace):
            self._instruct("flip", f"flip {flip:g}: put the cube with {face_name(flip)}", redo=f"flip {flip:g}: {exc}")
        else:
            self._start_turn(redo=f"flip {flip:g}: {exc}")

    # ---------------------------------------------------------------- checks
    def _check_rate(self, t_s: float) -> None:
        if self._last_t is not None and t_s > self._last_t:
            self._dts.append(t_s - self._last_t)
        self._last_t = t_s
        self._samples += 1
        if len(self._dts) < self._dts.maxlen or self._samples % 16:
            return  # judged every 16 samples, over the last 64
        rate = 1.0 / float(np.median(self._dts))
        self.progress.rate_hz = rate
        if self.rate_hz is None:
            self.rate_hz = rate
        elif abs(rate / self.rate_hz - 1.0) > _RATE_TOLERANCE:
            kept = ", ".join(f"{f:g}" for f in sorted(self.done)) or "none"
            raise SessionEnded(f"the module's sample rate changed from {self.rate_hz:.4g} Hz to {rate:.4g} Hz during "
                               f"flip {self.progress.flip_deg:g}; flips kept: {kept}; set it back to "
                               f"{self.rate_hz:.4g} Hz and continue with --resume")

    def _turn_rows(self, data: TurnData) -> FlipRows:
        flip = self.progress.flip_deg
        platform, keep, sigma = self.source.angles(data, flip)
        kept = data.subset(keep)
        covered, gap, start = coverage_gap(platform)
        if gap > self.max_gap_deg:
            if covered < 360.0 - 2 * self.max_gap_deg and gap > 30.0:
                raise TurnRejected(f"the turn stopped short: {covered:.0f} of 360 deg covered ({start:.0f}.."
                                   f"{(start + gap) % 360:.0f} deg never visited); turn once round")
            raise TurnRejected(f"a {gap:.1f} deg gap in the turn at {start:.0f} deg (samples lost, or turned too "
                               f"fast): at most {self.max_gap_deg:g} deg; turn again, slower")
        rate = self.rate_hz or data.rate_hz
        dt = np.diff(kept.t_s)
        speed = np.abs(np.diff(platform))[dt > 0] / dt[dt > 0]
        fastest = float(np.percentile(speed, 95)) if speed.size else 0.0
        self.progress.turn_dps = fastest
        if fastest > self.max_step_deg * rate:
            raise TurnRejected(f"turned at {fastest:.0f} deg/s: at {rate:.3g} Hz that is {fastest / rate:.1f} deg "
                               f"between samples; turn at most {self.max_step_deg * rate:.0f} deg/s")
        self._check_face(kept.accel, platform, kept.outputs)
        self._check_sense(_turned_deg(platform), gyro_turn_deg(kept, flip))
        return self._rows(kept.t_s, platform, kept.outputs, kept.accel, kept.temp_c, sigma)

    def _stops_rows(self) -> FlipRows:
        windows = [w for w, _, _ in self._stop_rows]
        platform = np.array([a for _, a, _ in self._stop_rows])
        moves = [g for _, _, g in self._stop_rows[1:]]  # the first stop's move came from wherever the table stood
        mean = (lambda name: None if getattr(windows[0], name) is None
                else np.array([getattr(w, name).mean(axis=0) for w in windows]))
        t_s = np.array([w.t_s.mean() for w in windows])
        outputs = np.array([w.outputs.mean(axis=0) for w in windows])
        accel = mean("accel")
        self._check_face(accel, platform, outputs)
        self._check_sense(_turned_deg(platform), None if None in moves else float(np.sum(moves)))
        return self._rows(t_s, platform, outputs, accel, mean("temp_c"), self.source.angle_sigma_deg)

    def _check_face(self, accel, platform, outputs) -> None:
        flip = self.progress.flip_deg
        expected = nearest_face(up_in_housing(flip))[0]
        if accel is not None:
            face, _ = nearest_face(accel.mean(axis=0))
            how = "the accelerometer shows"
        else:
            axis = circle_axis(platform, outputs)
            if axis is None:
                return
            face, _ = nearest_face(axis)
            how = "the field's circle shows"
        if face != expected:
            raise WrongFace(f"wrong face down: {how} {face} up; flip {flip:g} needs {face_name(flip)}")

    def _check_sense(self, source_deg: float, gyro_deg: float | None) -> None:
        """The source's angle must turn the way the gyro turned about the table's axis (module docstring).

        Raises
        ------
        SessionEnded
            The gyro turned at least half as far as the source says, the other way.
        """
        if getattr(self.source, "from_gyro", False):
            return
        if gyro_deg is None:
            if not self._said_no_gyro:
                self._said_no_gyro = True
                self.events.append(("warn", f"the module sends no gyro: the turn's direction is --turntable "
                                            f"{self.source.spec}'s word alone (an angle counting clockwise seen from "
                                            f"above would mirror the calibration unseen: check that it goes up as "
                                            f"the table turns counterclockwise)"))
            return
        if source_deg * gyro_deg < 0 and abs(gyro_deg) >= 0.5 * abs(source_deg):
            kept = ", ".join(f"{f:g}" for f in sorted(self.done)) or "none"
            gyro_axis = "g" + "xyz"[int(np.argmax(np.abs(up_in_housing(self.progress.flip_deg))))]
            raise SessionEnded(
                f"the turntable's angle (--turntable {self.source.spec}) went {'down' if source_deg < 0 else 'up'} "
                f"{abs(source_deg):.0f} deg over flip {self.progress.flip_deg:g}'s turn while the module's gyro "
                f"turned {abs(gyro_deg):.0f} deg {'counterclockwise' if gyro_deg > 0 else 'clockwise'} seen from "
                f"above: the angle counts clockwise, against SPEC's counterclockwise, and would mirror the "
                f"calibration; {self.source.reverse_words()}, and run the session again (if the angle is right, "
                f"the gyro's axes are not the housing's: its {gyro_axis} about the table reads negated, as an FRD "
                f"board's or a chip turned half round does; send it in the housing's axes, or on a headerless stream "
                f"name the cell negated in --columns, -{gyro_axis}); flips kept: {kept}")

    def _rows(self, t_s, platform, outputs, accel, temp_c, sigma) -> FlipRows:
        """The flip's recording rows (the gyro is not kept: the four-flip fit does not use it)."""
        columns = ["t_s", "flip_deg", "platform_deg", *self.channels]
        parts = [t_s[:, None], np.full((len(t_s), 1), self.progress.flip_deg), np.asarray(platform)[:, None], outputs]
        for names, values in ((("ax", "ay", "az"), accel), (("temp_c",), temp_c)):
            if values is not None:
                columns += names
                parts.append(np.asarray(values).reshape(len(t_s), -1))
        t_s, clock = self._after_kept(np.asarray(t_s, float))
        parts[0] = t_s[:, None]
        if self.columns is not None and tuple(columns) != self.columns:
            raise SessionEnded(f"the module's columns changed: the flips kept have {','.join(self.columns)}, flip "
                               f"{self.progress.flip_deg:g} has {','.join(columns)}")
        self.columns = tuple(columns)
        return FlipRows(self.progress.flip_deg, tuple(columns), np.column_stack(parts), float(sigma), clock)

    def _after_kept(self, t_s: np.ndarray) -> tuple[np.ndarray, str | None]:
        """A flip's times on the recording's clock: the module's, going on from the flips kept when its clock restarted
        since they were (seen going back, or, in a resumed session, their last ``t_s`` not before the flip's first):
        after :data:`compass.io.clock.RESTART_GAP_S` and the flip's median step; the later flips on the same clock keep
        that offset.

        Returns
        -------
        t_s : ndarray, shape (n,)
            The recording's times, seconds.
        clock : str or None
            The restart in words (also said as an event), None when the times go on.
        """
        if self._offset_s is not None:
            return t_s + self._offset_s, None
        self._offset_s = 0.0
        if not self.done or not len(t_s):
            return t_s, None
        last = max(float(rows.table[:, rows.columns.index("t_s")].max()) for rows in self.done.values())
        if t_s[0] > last:
            return t_s, None
        step = RESTART_GAP_S + (float(np.median(np.diff(t_s))) if len(t_s) > 1 else 0.0)
        words = (f"the module's clock restarted before flip {self.progress.flip_deg:g} (its t_s from "
                 f"{t_s[0]:.6g} s, the flips kept end at {last:.6g} s): the recording's t_s goes on after {step:.3g} s")
        self.events.append(("info", words))
        self._offset_s = last + step - t_s[0]
        return t_s + self._offset_s, words

    def _keep(self, rows: FlipRows) -> None:
        if self.on_flip is not None:
            self.on_flip(rows)
        self.done[rows.flip_deg] = rows
        self.progress.flips_done = len(self.done)
        self.events.append(("info", f"flip {rows.flip_deg:g} kept: {len(rows.table)} rows, turn rate "
                                    f"{self.progress.turn_dps:.0f} deg/s, angle sigma {rows.angle_sigma_deg:.3g} deg"))
        self._next_flip()


def _turned_deg(platform_deg: np.ndarray) -> float:
    """How far a source's angle went from the first sample to the last, unwrapped (no step of 180 deg or more
    between samples), degrees: positive when it went up."""
    unwrapped = np.unwrap(np.asarray(platform_deg, float), period=360.0)
    return float(unwrapped[-1] - unwrapped[0]) if unwrapped.size else 0.0
