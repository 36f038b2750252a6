"""Turntable angle sources of the bench station (``compass bench --turntable SOURCE``).

Two kinds, one interface each:

- *continuous* sources give an angle for every sample of a turn the operator makes (the table
  turned once round, from still to still): :class:`ColumnSource` (an encoder column in the
  module's stream) and :class:`GyroSource` (the module's gyro integrated about the table axis);
- *stop* sources put the table at stops and give the angle of each: :class:`ManualSource` (a
  graduated table turned by hand to marks) and :class:`compass.station.grbl.GrblSource` (a
  stepper table on a GRBL controller).

:func:`parse_turntable` builds one from the command line's text.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import cumulative_trapezoid

from .checks import coverage_gap, up_in_housing
from .turn import TurnData, TurnRejected, still_spans, turn_about_deg

__all__ = ["ColumnSource", "GyroSource", "ManualSource", "parse_turntable", "READ_HALF_WIDTH_DEG"]

READ_HALF_WIDTH_DEG = 0.5
"""How closely an operator reads a graduated table's mark, degrees (uniform error within +-this)."""
_MIN_STILL_S = 0.5  # still time the gyro needs at each end of a turn for its bias
_MARGIN_S = 0.5  # still time next to the motion left out of the bias


class ColumnSource:
    """The turntable's encoder sent by the module as one more column of its stream.

    Parameters
    ----------
    column : str
        The column's name in the module's header (degrees, any range); a leading ``-`` (``column:-enc``)
        negates it: an encoder counting clockwise seen from above, SPEC's angle being counterclockwise.
    """

    kind = "continuous"
    hold_s = 1.0

    def __init__(self, column: str):
        name = column[1:] if column.startswith("-") else column
        if not name:
            raise ValueError("--turntable column:NAME needs the encoder column's name")
        self.column = name
        self.sign = -1.0 if column.startswith("-") else 1.0
        self.spec = f"column:{column}"

    def reverse_words(self) -> str:
        """How to reverse the angle's sense, in words (the station's stop when it counts against the gyro)."""
        flipped = self.column if self.sign < 0 else f"-{self.column}"
        return f"use --turntable column:{flipped} (the column negated)"

    def begin(self, flip_deg: float) -> None:
        """Nothing to prepare: the encoder is absolute."""

    def live(self, data: TurnData) -> float:
        """Degrees of the circle covered so far."""
        return coverage_gap(data.encoder_deg)[0] if len(data) else 0.0

    def angles(self, data: TurnData, flip_deg: float) -> tuple[np.ndarray, np.ndarray, float]:
        """``(platform_deg, keep, angle_sigma_deg)``: the encoder's readings (negated for ``column:-NAME``), every
        sample kept.

        The stated sigma is the encoder's resolution (the smallest step between its readings) over
        sqrt(12): a quantised reading's error.
        """
        enc = data.encoder_deg
        steps = np.diff(np.unique(np.round(enc, 9)))
        resolution = float(steps.min()) if steps.size else 0.0
        return self.sign * enc, np.ones(len(enc), bool), resolution / np.sqrt(12.0)


class GyroSource:
    """A hand-turned table without an encoder: the module's gyro integrated about the table axis.

    The operator starts each turn with the table at its mark, holds still two seconds, turns once
    round counterclockwise (seen from above) and stops at the mark again.  The turn is the last
    motion between two still spans; the gyro's bias is the mean rate over those still spans
    (linear in time between them), the axis is the direction of the bias-free rotation over the
    turn (oriented up, :func:`compass.station.checks.up_in_housing`), and the angle is the bias-free
    rate about it integrated in time.  Its scale is closed on the full turn: the field at the end
    equals the field at the start after exactly 360 deg, so the end's angle is
    ``360 + (v_end - v_start) . d / |d|^2`` with ``d`` the outputs' slope in angle at the start
    (from a first-harmonic fit of the turn), and the integral is rescaled to it.
    """

    kind = "continuous"
    spec = "gyro"
    hold_s = 2.0  # asked-for stillness at each end of a turn, seconds
    from_gyro = True  # the angle is the gyro's own: nothing to check its sense against

    def __init__(self):
        self._up = up_in_housing(0.0)

    def begin(self, flip_deg: float) -> None:
        """The flip the next turn is made in (orients the live readout)."""
        self._up = up_in_housing(flip_deg)

    def live(self, data: TurnData) -> float:
        """Degrees turned since the turn was asked for, roughly (bias from its first half second)."""
        if data.gyro is None or len(data) < 3:
            return 0.0
        bias = data.gyro[data.t_s - data.t_s[0] <= _MIN_STILL_S].mean(axis=0)
        return turn_about_deg(data, self._up, bias)

    def angles(self, data: TurnData, flip_deg: float) -> tuple[np.ndarray, np.ndarray, float]:
        """``(platform_deg, keep, angle_sigma_deg)`` of the turn's samples (the last motion and its stills).

        Raises
        ------
        TurnRejected
            No gyro columns, no still second before or after the turn, or a turn far from 360 deg.
        """
        if data.gyro is None:
            raise TurnRejected("--turntable gyro needs gx,gy,gz in the module's stream; it sends none")
        still = still_spans(data)
        first, last = _last_motion(still)
        if first is None:
            raise TurnRejected("no turn seen: turn the table once round and hold it still at the mark")
        t = data.t_s
        moving_before = np.flatnonzero(~still[:first])
        begin = moving_before[-1] + 1 if moving_before.size else 0
        before = np.arange(begin, first)  # the still span just before the motion
        after = np.arange(last + 1, len(t))
        if before.size == 0 or np.ptp(t[before]) < _MIN_STILL_S - 0.1:
            raise TurnRejected("the table was not held still before the turn (the gyro's bias needs half a "
                               "second of stillness at the mark): hold still, then turn")
        if after.size == 0 or np.ptp(t[after]) < _MIN_STILL_S - 0.1:
            raise TurnRejected("the table was not held still after the turn: stop at the mark and hold still")
        keep = np.zeros(len(t), bool)
        keep[before[0]:after[-1] + 1] = True
        # a slow start or end of the motion can pass for stillness: the bias is taken away from it
        lead = _MARGIN_S if begin > 0 else 0.0  # a span that follows motion loses its start too
        before = before[(t[before] <= t[before[-1]] - _MARGIN_S) & (t[before] >= t[before[0]] + lead)]
        after = after[t[after] >= t[after[0]] + _MARGIN_S]
        if before.size < 5 or after.size < 5:
            raise TurnRejected("the table was not held still long enough before and after the turn (the gyro's "
                               f"bias needs {_MIN_STILL_S + _MARGIN_S:g} s at each end): hold still at the mark")
        bias_a, bias_b = data.gyro[before].mean(axis=0), data.gyro[after].mean(axis=0)
        ta, tb = t[before].mean(), t[after].mean()
        w = np.clip((t - ta) / (tb - ta), 0.0, 1.0)[:, None]
        rate = data.gyro - ((1.0 - w) * bias_a + w * bias_b)
        moving = slice(first, last + 1)
        axis = np.trapezoid(rate[moving], t[moving], axis=0)
        if np.linalg.norm(axis) == 0:
            raise TurnRejected("the gyro saw no rotation during the turn")
        axis /= np.linalg.norm(axis)
        axis *= np.sign(axis @ up_in_housing(flip_deg)) or 1.0
        raw_deg = np.degrees(cumulative_trapezoid(rate @ axis, t, initial=0.0))
        raw_deg -= raw_deg[before].mean()
        total = raw_deg[after].mean()
        if total < 0:
            raise TurnRejected(f"the table turned {-total:.0f} deg clockwise: turn it counterclockwise (seen from "
                               "above), once round from the mark back to the mark")
        if abs(total - 360.0) > 30.0:
            raise TurnRejected(f"the turn was about {total:.0f} deg, not one full turn: turn from the mark once "
                               "round back to the mark")
        phi = np.radians(raw_deg[keep])
        design = np.column_stack([np.ones_like(phi), np.cos(phi), np.sin(phi)])
        coef, *_ = np.linalg.lstsq(design, data.outputs[keep], rcond=None)
        slope = np.radians(1.0) * coef[2]  # d outputs / d angle at angle 0, per degree
        change = data.outputs[after].mean(axis=0) - data.outputs[before].mean(axis=0)
        closed = 360.0 + float(change @ slope / (slope @ slope))
        scale = closed / total
        if abs(closed - 360.0) > 10.0:
            raise TurnRejected(f"the table stopped {closed - 360.0:+.1f} deg from the mark it started at: turn "
                               "once round, from the mark back to the mark")
        platform = raw_deg * scale
        # the closure's own error: the end and start field means' noise, projected on the slope
        n_a, n_b = before.size, after.size
        spread = np.std(data.outputs[before] - data.outputs[before].mean(axis=0), axis=0)
        sigma_close = float(np.sqrt((spread**2 @ slope**2) / (slope @ slope) ** 2 * (1 / n_a + 1 / n_b)))
        return platform[keep], keep, sigma_close


def _last_motion(still: np.ndarray) -> tuple[int | None, int | None]:
    """First and last index of the last run of non-still samples that has still samples after it."""
    moving = np.flatnonzero(~still)
    if moving.size == 0:
        return None, None
    last = int(moving[-1])
    if last == len(still) - 1:
        return None, None
    breaks = np.flatnonzero(np.diff(moving) > 1)
    first = int(moving[breaks[-1] + 1]) if breaks.size else int(moving[0])
    return first, last


class ManualSource:
    """A graduated table turned by hand to a mark every ``step_deg`` degrees.

    The station asks for each stop in turn ("turn to 30 deg and hold still"), waits for the motion
    and then a still second, and keeps that second's mean as one row at the stop's angle.  The
    stated sigma is a reading uniform within +-0.5 deg (:data:`READ_HALF_WIDTH_DEG`).

    Parameters
    ----------
    step_deg : float
        Spacing of the stops, degrees; must divide 360 and be at most 45.
    clockwise : bool
        The graduation counts clockwise seen from above (a compass rose; ``manual:-STEP_DEG``): a mark's angle is
        recorded negated, SPEC's angle being counterclockwise.
    """

    kind = "stops"
    operator_moves = True

    def __init__(self, step_deg: float, clockwise: bool = False):
        if not (0 < step_deg <= 45.0) or abs(360.0 / step_deg - round(360.0 / step_deg)) > 1e-9:
            raise ValueError(f"--turntable manual:STEP_DEG: the step must divide 360 and be at most 45 deg, "
                             f"got {step_deg:g}")
        self.step_deg = float(step_deg)
        self.sign = -1.0 if clockwise else 1.0
        self.spec = f"manual:{'-' * clockwise}{step_deg:g}"
        self.angle_sigma_deg = READ_HALF_WIDTH_DEG / np.sqrt(3.0)

    def reverse_words(self) -> str:
        """How to reverse the angle's sense, in words (the station's stop when it counts against the gyro)."""
        return f"use --turntable manual:{'' if self.sign < 0 else '-'}{self.step_deg:g} (a graduation counting " \
               f"{'counterclockwise' if self.sign < 0 else 'clockwise'})"

    def stops(self) -> np.ndarray:
        """The stops of one flip, degrees."""
        return np.arange(0.0, 360.0 - 1e-9, self.step_deg)

    def request(self, angle_deg: float) -> None:
        """Nothing to command: the instruction asks the operator."""

    def position_deg(self, angle_deg: float) -> float:
        """The angle recorded for a stop: the mark asked for (negated, modulo 360, for a clockwise graduation)."""
        return float(np.mod(self.sign * angle_deg, 360.0))


def parse_turntable(text: str, *, grbl_options: dict | None = None):
    """The angle source named by ``--turntable`` (``column:NAME``, ``grbl:PORT``, ``manual:STEP_DEG``, ``gyro``; a ``-``
    before NAME or STEP_DEG: the table's angle counts clockwise seen from above).

    Raises
    ------
    ValueError
        An unknown source or a bad parameter, in words.
    """
    kind, _, rest = str(text).partition(":")
    if kind == "column":
        return ColumnSource(rest)
    if kind == "gyro" and not rest:
        return GyroSource()
    if kind == "manual":
        try:
            step = float(rest)
        except ValueError:
            raise ValueError(f"--turntable {text}: expected manual:STEP_DEG, a number of degrees") from None
        return ManualSource(abs(step), clockwise=rest.strip().startswith("-"))
    if kind == "grbl":
        if not rest:
            raise ValueError("--turntable grbl:PORT needs the GRBL controller's port")
        from .grbl import GrblSource

        return GrblSource(rest, **(grbl_options or {}))
    raise ValueError(f"--turntable {text}: unknown source; expected column:NAME, grbl:PORT, manual:STEP_DEG or gyro")
