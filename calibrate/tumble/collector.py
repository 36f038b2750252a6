"""The live tumble calibration's collector: samples of a module turned by hand, their coverage and the
converging ellipsoid fit, in the style of MotionCal.

``compass live --calibrate tumble`` feeds it the port's items (:meth:`TumbleCollector.feed`), shows
:meth:`TumbleCollector.readout` every second after :meth:`TumbleCollector.update`, and when
:attr:`TumbleCollector.enough` writes the samples as a tumble recording
(:meth:`TumbleCollector.write_recording`) that :class:`calibrate.tumble.TumbleCalibrator` then fits
like any other.

The recording keeps what the module sent of ``ax,ay,az``, ``gx,gy,gz`` (rad/s, as the decoder hands them and
as the tumble reader takes them by default) and ``temp_c``: with the gyro, ``compass calibrate`` fits the turns
between samples too (the gyro-aided fit of :mod:`calibrate.tumble.gyro`).  Its ``t_s`` never goes back.  A time
that goes back, or jumps more than the runtime filter's ``max_gap_s`` ahead of a stream running within it, is kept
aside and the next sample tells what it was, as the runtime filter tells it
(:meth:`compass.filter.AttitudeFilter._time_step`): when the next goes on from the old clock it was a corrupted
value (a digit flipped on the serial line), and its sample is left out (:class:`CorruptedTime`); when the next goes
on from the new one, the module's clock restarted (a reset, t_s back to about 0: the times after it go on from the
last one after :data:`compass.io.clock.RESTART_GAP_S` and the stream's median step, a gap the gyro-aided fit
integrates no turn across, the step across the restart being unknown, :class:`ClockRestart`) or the stream paused
(a real gap, kept as it is).  Each is said in words when it is told and in the recording's ``# clock:`` line; a
sample still kept aside when the stream ends is kept when its time went ahead (a gap) and left out, said, when it
went back.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compass.io.atomic import atomic_write_text
from compass.io.clock import RESTART_GAP_S, SampleClock
from compass.filter import FilterConfig
from compass.io.streams import StreamDecoder

from .coverage import sphere_coverage
from .ellipsoid import fit_ellipsoid

__all__ = ["CHANNELS", "MIN_SAMPLES", "ClockRestart", "CorruptedTime", "TumbleCollector"]

CHANNELS = ("mx", "my", "mz")
MIN_SAMPLES = 50
"""Samples below which no fit is tried (and the command refuses to calibrate)."""
_FIT_SAMPLES = 2000  # the live fit uses at most this many samples, evenly spread
_STEP_SAMPLES = 1000  # the median step across a restart is the last this many samples'
_COLUMNS = ("t_s", *CHANNELS, "ax", "ay", "az", "gx", "gy", "gz", "temp_c")
_GROUPS = ((1, 4), (4, 7), (7, 10), (10, 11))  # the samples' columns: magnetometer, accelerometer, gyro, temp_c
_MAX_STEP_S = FilterConfig.max_gap_s  # a time further ahead than this is kept aside until the next tells what it was


@dataclass(frozen=True)
class ClockRestart:
    """The module's clock went back: the recording's ``t_s`` goes on across it.

    Attributes
    ----------
    sample : int
        1-based sample whose time went back.
    from_s, to_s : float
        The module's time before it and its own, s.
    step_s : float
        The step the recording takes across it: :data:`compass.io.clock.RESTART_GAP_S` plus the median of the
        steps before, s.
    """

    sample: int
    from_s: float
    to_s: float
    step_s: float

    def words(self) -> str:
        """One sentence: what went back, where, and the step taken across it."""
        return (f"the module's clock went back from {self.from_s:.6g} s to {self.to_s:.6g} s at sample "
                f"{self.sample} (a reset?): the tumble recording's t_s goes on across it after {self.step_s:.3g} s, a "
                f"gap the gyro-aided fit integrates no turn across (the step across a restart is unknown)")


@dataclass(frozen=True)
class CorruptedTime:
    """A sample whose time was out of step with the module's clock, left out of the recording.

    Attributes
    ----------
    sample : int
        1-based sample of the recording it came before.
    t_s : float
        Its time, s.
    last_s : float
        The module's time of the sample before it, s.
    next_s : float or None
        The time of the sample after it, which went on from ``last_s``'s clock, s (None: the stream ended first, and
        nothing told a corrupted value from a restart or a gap).
    """

    sample: int
    t_s: float
    last_s: float
    next_s: float | None

    def words(self) -> str:
        """One sentence: the time, its neighbours, what was told from them and that the sample is left out."""
        way = "went back" if self.t_s < self.last_s else "jumped ahead"
        if self.next_s is None:
            return (f"the last sample's time {way} from {self.last_s:.6g} s to {self.t_s:.6g} s and the stream ended: "
                    "nothing after it tells a corrupted time from a restart or a gap, so it is left out of the tumble "
                    "recording")
        return (f"a corrupted time before sample {self.sample}: {self.t_s:.6g} s between {self.last_s:.6g} s and "
                f"{self.next_s:.6g} s (the next sample goes on from the module's clock, not from it), so it is not a "
                "restart; its sample is left out of the tumble recording")


class TumbleCollector:
    """Samples of a tumble, their coverage and the converging fit.

    Parameters
    ----------
    min_coverage : float
        Fraction of the sphere's cells that must hold a sample (with every half-axis seen) for
        :attr:`enough`.
    stream : compass.io.streams.StreamOptions, optional
        The stream's format and units (default: found from the first lines).

    Attributes
    ----------
    decoder : compass.io.streams.StreamDecoder
    coverage : Coverage or None
        Of the latest :meth:`update`.
    fit : EllipsoidFit or None
        The latest ellipsoid fit (hard iron, its sigma).
    restarts : list of ClockRestart
        Every time the module's clock restarted (two samples in a row on the new clock), in order.
    corrupted : list of CorruptedTime
        Every sample left out for a time out of step with the module's clock, in order.
    """

    def __init__(self, *, min_coverage: float = 0.8, stream=None):
        self.min_coverage = min_coverage
        self.decoder = StreamDecoder(CHANNELS, stream)
        self.rows: list[tuple] = []
        self.coverage = None
        self.fit = None
        self.restarts: list[ClockRestart] = []
        self.corrupted: list[CorruptedTime] = []
        self._t0 = None
        self._last_t = None  # the module's time of the last sample, s
        self._running = False  # the last sample came within max_gap_s of the one before (not a slow stream's step)
        self._held = None  # (t_s, the other columns) of a sample kept aside until the next tells its time
        self._unsaid: list = []  # the clock's events not yet returned, (level, text)
        self._offset_s = 0.0  # added to the module's time since its last restart, s
        self._last_rx = 0.0
        self._clock = SampleClock()  # dates the samples of a stream without t_s, as compass live does
        self._streamed = 0  # rows written by stream_rows
        self._stream_columns = None  # the columns stream_rows writes (those of the first sample)
        self._stream_clock = None  # the clock words stream_rows said last

    def feed(self, item) -> list:
        """Take one item of :meth:`SerialReader.items`; returns the decoder's events (level, text)."""
        from compass.serial_reader import LinkEvent

        if isinstance(item, LinkEvent):
            if item.kind == "connected":
                self.decoder.resync()
                self._clock.restart()
            return [("warn" if item.kind == "disconnected" else "info", item.message)]
        if self._t0 is None:
            self._t0 = item.t_rx
        self._last_rx = item.t_rx
        self._add(self.decoder.feed(item.data, item.t_rx), item.t_rx)
        return (self.decoder.drain_events() if self.decoder.events else []) + self._clock_events()

    def finish(self) -> list:
        """At the end of the stream: the samples the decoder still held (a sample still kept aside for its time is
        left out, :class:`CorruptedTime`); returns the events."""
        if self._t0 is not None:
            self._add(self.decoder.flush(), self._last_rx)
        if self._held is not None:  # nothing tells it: a time ahead is kept (a gap, which the gyro-aided fit does
            if self._held[0] > self._last_t:  # not integrate across), one that went back left out
                self._record(*self._held)
            else:
                self._leave_out(self._held[0], None)
            self._held = None
        return self.decoder.drain_events() + self._clock_events()

    def _add(self, samples: list, t_rx: float) -> None:
        absent = (np.nan,) * 3
        for s in self._clock.dated(samples, t_rx, self._t0):
            self._take(s.t_s, (*s.raw, *(absent if s.accel is None else s.accel),
                               *(absent if s.gyro is None else s.gyro), np.nan if s.temp_c is None else s.temp_c))

    def _take(self, t_s: float, values: tuple) -> None:
        """One sample at the module's ``t_s``: the sample kept aside before it told by this time, then this one
        kept aside when its time goes back, or jumps over ``max_gap_s`` ahead of a stream running within it (a
        stream whose every step is over it, under 2 Hz, is recorded as it comes, as the runtime filter keeps no
        sample aside right after a restart), else recorded."""
        held, self._held = self._held, None
        if held is not None:
            if self._on_new_clock(held[0], t_s):
                self._record(*held)
            else:
                self._leave_out(held[0], t_s)
        if self._last_t is not None and (t_s < self._last_t or (t_s - self._last_t > _MAX_STEP_S and self._running)):
            self._held = (t_s, values)
        else:
            self._record(t_s, values)

    def _on_new_clock(self, held_s: float, next_s: float) -> bool:
        """Whether the time after a sample kept aside at ``held_s`` goes on from it (a restart or a gap), not from the
        old clock's last time (``held_s`` was a corrupted value)."""
        if held_s < self._last_t:
            return held_s <= next_s < self._last_t
        return next_s >= held_s

    def _leave_out(self, t_s: float, next_s: float | None) -> None:
        """A sample kept aside for its time is left out (:class:`CorruptedTime`), said."""
        self.corrupted.append(CorruptedTime(len(self.rows) + 1, t_s, self._last_t, next_s))
        self._unsaid.append(("warn", self.corrupted[-1].words()))

    def _record(self, t_s: float, values: tuple) -> None:
        """A sample into the recording at the module's ``t_s``: a time that goes back (the module's clock
        restarted) goes on from the last one after :data:`compass.io.clock.RESTART_GAP_S` and the median step
        (:class:`ClockRestart`, said)."""
        if self._last_t is not None and t_s < self._last_t:
            recent = np.array([row[0] for row in self.rows[-_STEP_SAMPLES:]])
            step = RESTART_GAP_S + (float(np.median(np.diff(recent))) if len(recent) > 1 else 0.0)
            self.restarts.append(ClockRestart(len(self.rows) + 1, self._last_t, t_s, step))
            self._unsaid.append(("warn", self.restarts[-1].words()))
            self._offset_s = float(recent[-1]) + step - t_s
        self._running = self._last_t is not None and 0.0 <= t_s - self._last_t <= _MAX_STEP_S
        self._last_t = t_s
        self.rows.append((t_s + self._offset_s, *values))

    def _clock_events(self) -> list:
        """The restarts and corrupted times not yet said, as events (level, text)."""
        events, self._unsaid = self._unsaid, []
        return events

    @property
    def samples(self) -> np.ndarray:
        """(n, 11): t_s, mx, my, mz, ax, ay, az, gx, gy, gz, temp_c (NaN where not sent; the gyro in rad/s;
        t_s going on across the module's restarts)."""
        return np.array(self.rows, dtype=float).reshape(-1, len(_COLUMNS))

    def update(self) -> None:
        """Fit the ellipsoid to the samples so far and measure their coverage about its centre."""
        mag = self.samples[:, 1:4]
        if len(mag) < MIN_SAMPLES:
            return
        subset = mag[np.unique(np.linspace(0, len(mag) - 1, min(len(mag), _FIT_SAMPLES)).astype(int))]
        fit, _, _ = fit_ellipsoid(subset)
        if np.all(np.isfinite(fit.hard_iron)):
            self.fit = fit
        centre = self.fit.hard_iron if self.fit is not None else 0.5 * (mag.min(axis=0) + mag.max(axis=0))
        self.coverage = sphere_coverage(mag - centre)

    @property
    def enough(self) -> bool:
        """Every half-axis seen and ``min_coverage`` of the sphere covered."""
        c = self.coverage
        return c is not None and not c.missing and c.fraction >= self.min_coverage

    def readout(self) -> str:
        """One line for the terminal: samples, coverage, the axes never along the field, the hard iron."""
        n = len(self.rows)
        if self.coverage is None:
            return (f"tumble: {n} samples; turn the module slowly through every orientation  "
                    f"[{self.decoder.describe()}]")
        c, fit = self.coverage, self.fit
        text = (f"tumble: {n} samples, {100 * c.fraction:.0f} % of the sphere covered "
                f"(need {100 * self.min_coverage:.0f} %)")
        if c.missing:
            text += f"; never along the field yet: {', '.join(c.missing)}"
        if fit is not None:
            text += ("; hard iron " + ", ".join(f"{h:.4g}" for h in fit.hard_iron)
                     + " +- " + ", ".join(f"{s:.2g}" for s in fit.hard_iron_sigma))
        return text + f"  [{self.decoder.describe()}]"

    def clock_words(self) -> str | None:
        """The module's clock restarts and the samples left out for their time, in one sentence each (None without
        any): the recording's ``# clock:`` line."""
        said = []
        if self.restarts:
            at = ", ".join(f"sample {r.sample} ({r.from_s:.6g} -> {r.to_s:.6g} s)" for r in self.restarts)
            steps = sorted({f"{r.step_s:.3g}" for r in self.restarts})
            said.append(f"the module's clock restarted {len(self.restarts)} time{'s' * (len(self.restarts) > 1)}, at "
                        f"{at}; t_s goes on across {'it' if len(self.restarts) == 1 else 'each'} after "
                        f"{'/'.join(steps)} s, a gap the gyro-aided fit integrates no turn across")
        if self.corrupted:
            at = ", ".join(f"before sample {c.sample} ({c.t_s:.6g} s after {c.last_s:.6g} s)" for c in self.corrupted)
            n = len(self.corrupted)
            said.append(f"{n} sample{'s' * (n > 1)} left out for a time out of step with the module's clock (a "
                        f"corrupted value, not a restart), {at}")
        return "; ".join(said) if said else None

    def stream_rows(self, out) -> int:
        """The rows recorded since the last call, to the text stream ``out`` as a tumble recording is written as it
        grows; returns the rows written so far.

        The first call writes the ``# source:`` line and the header (the columns of the groups the first sample had:
        a group missing on a later row is ``nan`` there, which the reader names; one that appears later is not kept),
        and a ``# clock:`` line (:meth:`clock_words`, a later one replacing the earlier) goes where the clock's words
        change.  ``compass live --calibrate tumble`` streams its collection so to a temporary file beside
        ``CAL.tumble.csv`` (:func:`compass.io.atomic.atomic_stream`), which a session killed outright leaves (the
        next write to ``CAL.tumble.csv`` keeps it as ``CAL.tumble.partial-PID.csv``); :meth:`write_recording` writes
        the recording at a clean end.
        """
        if self._streamed == len(self.rows):
            return self._streamed
        new = np.array(self.rows[self._streamed:], dtype=float).reshape(-1, len(_COLUMNS))
        lines = []
        if self._stream_columns is None:
            self._stream_columns = _columns_kept(new[:1])
            lines += ["# source: compass live --calibrate tumble (streamed as collected)",
                      ",".join(_COLUMNS[j] for j in self._stream_columns)]
        clock = self.clock_words()
        if clock != self._stream_clock:
            self._stream_clock = clock
            lines.append(f"# clock: {clock}")
        lines += _row_lines(new, self._stream_columns)
        out.write("\n".join(lines) + "\n")
        self._streamed = len(self.rows)
        return self._streamed

    def write_recording(self, path) -> Path:
        """The samples as a tumble recording (SPEC section 2): the accelerometer's, the gyro's (rad/s) and
        temp_c columns when every sample had them; a ``# clock:`` line when the module's clock restarted or a sample
        was left out for its time (:meth:`clock_words`)."""
        data = self.samples
        columns = _columns_kept(data)
        lines = ["# source: compass live --calibrate tumble"]
        clock = self.clock_words()
        if clock is not None:
            lines.append(f"# clock: {clock}")
        lines.append(",".join(_COLUMNS[j] for j in columns))
        lines += _row_lines(data, columns)
        atomic_write_text(path, "\n".join(lines) + "\n")
        return Path(path)


def _columns_kept(data: np.ndarray) -> list[int]:
    """The columns a recording of ``data`` (rows of :data:`_COLUMNS`) writes: the time, the field, and each other group
    every row has."""
    keep = [0, *range(*_GROUPS[0])]
    for lo, hi in _GROUPS[1:]:
        if np.all(np.isfinite(data[:, lo:hi])):
            keep += range(lo, hi)
    return keep


def _row_lines(data: np.ndarray, columns) -> list[str]:
    """``data``'s rows as a recording's lines, the ``columns`` given."""
    return [",".join(f"{v:.9g}" for v in row) for row in data[:, columns]]
