"""The live tumble calibration's collector: samples of a module turned by hand, their coverage and the
converging ellipsoid fit, in the style of MotionCal.

``compass live --calibrate tumble`` feeds it the port's items (:meth:`TumbleCollector.feed`), shows
:meth:`TumbleCollector.readout` every second after :meth:`TumbleCollector.update`, and when
:attr:`TumbleCollector.enough` writes the samples as a tumble recording
(:meth:`TumbleCollector.write_recording`) that :class:`calibrate.tumble.TumbleCalibrator` then fits
like any other.

The recording keeps what the module sent of ``ax,ay,az``, ``gx,gy,gz`` (rad/s, as the decoder hands them and
as the tumble reader takes them by default) and ``temp_c``: with the gyro, ``compass calibrate`` fits the turns
between samples too (the gyro-aided fit of :mod:`calibrate.tumble.gyro`).  Its ``t_s`` never goes back: when
the module's clock restarts (a reset, t_s back to about 0), the times after it go on from the last one
by the stream's median step (the step across the restart is unknown; the ellipsoid fit uses no time, the
gyro-aided fit integrates that one step's rate over it), said in words when it happens
(:class:`ClockRestart`) and in the recording's ``# clock:`` line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compass.io.atomic import atomic_write_text
from compass.io.clock import SampleClock
from compass.io.streams import StreamDecoder

from .coverage import sphere_coverage
from .ellipsoid import fit_ellipsoid

__all__ = ["CHANNELS", "MIN_SAMPLES", "ClockRestart", "TumbleCollector"]

CHANNELS = ("mx", "my", "mz")
MIN_SAMPLES = 50
"""Samples below which no fit is tried (and the command refuses to calibrate)."""
_FIT_SAMPLES = 2000  # the live fit uses at most this many samples, evenly spread
_STEP_SAMPLES = 1000  # the median step across a restart is the last this many samples'
_COLUMNS = ("t_s", *CHANNELS, "ax", "ay", "az", "gx", "gy", "gz", "temp_c")
_GROUPS = ((1, 4), (4, 7), (7, 10), (10, 11))  # the samples' columns: magnetometer, accelerometer, gyro, temp_c


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
        The step the recording takes across it: the median of the steps before, s (0 with fewer than two
        samples before).
    """

    sample: int
    from_s: float
    to_s: float
    step_s: float

    def words(self) -> str:
        """One sentence: what went back, where, and the step taken across it."""
        return (f"the module's clock went back from {self.from_s:.6g} s to {self.to_s:.6g} s at sample "
                f"{self.sample} (a reset?): the tumble recording's t_s goes on across it at the stream's median "
                f"step, {1e3 * self.step_s:.3g} ms (the step across a restart is unknown)")


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
        Every time the module's clock went back, in order.
    """

    def __init__(self, *, min_coverage: float = 0.8, stream=None):
        self.min_coverage = min_coverage
        self.decoder = StreamDecoder(CHANNELS, stream)
        self.rows: list[tuple] = []
        self.coverage = None
        self.fit = None
        self.restarts: list[ClockRestart] = []
        self._t0 = None
        self._last_t = None  # the module's time of the last sample, s
        self._offset_s = 0.0  # added to the module's time since its last restart, s
        self._last_rx = 0.0
        self._clock = SampleClock()  # dates the samples of a stream without t_s, as compass live does

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
        said = len(self.restarts)
        self._add(self.decoder.feed(item.data, item.t_rx), item.t_rx)
        return (self.decoder.drain_events() if self.decoder.events else []) + self._restart_events(said)

    def finish(self) -> list:
        """At the end of the stream: the samples the decoder still held; returns its events."""
        said = len(self.restarts)
        if self._t0 is not None:
            self._add(self.decoder.flush(), self._last_rx)
        return self.decoder.drain_events() + self._restart_events(said)

    def _add(self, samples: list, t_rx: float) -> None:
        absent = (np.nan,) * 3
        for s in self._clock.dated(samples, t_rx, self._t0):
            self.rows.append((self._continued(s.t_s), *s.raw, *(absent if s.accel is None else s.accel),
                              *(absent if s.gyro is None else s.gyro), np.nan if s.temp_c is None else s.temp_c))

    def _continued(self, t_s: float) -> float:
        """The recording's time of a sample at the module's ``t_s``: a time that goes back (the module's clock
        restarted) goes on from the last one by the median step (:class:`ClockRestart`)."""
        if self._last_t is not None and t_s < self._last_t:
            recent = np.array([row[0] for row in self.rows[-_STEP_SAMPLES:]])
            step = float(np.median(np.diff(recent))) if len(recent) > 1 else 0.0
            self.restarts.append(ClockRestart(len(self.rows) + 1, self._last_t, t_s, step))
            self._offset_s = float(recent[-1]) + step - t_s
        self._last_t = t_s
        return t_s + self._offset_s

    def _restart_events(self, said: int) -> list:
        """The restarts since ``said`` of them were said, as events (level, text)."""
        return [("warn", restart.words()) for restart in self.restarts[said:]]

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
        """The module's clock restarts in one sentence (None without any): the recording's ``# clock:`` line."""
        if not self.restarts:
            return None
        at = ", ".join(f"sample {r.sample} ({r.from_s:.6g} -> {r.to_s:.6g} s)" for r in self.restarts)
        steps = sorted({f"{1e3 * r.step_s:.3g}" for r in self.restarts})
        return (f"the module's clock restarted {len(self.restarts)} time{'s' * (len(self.restarts) > 1)}, at {at}; "
                f"t_s goes on across {'it' if len(self.restarts) == 1 else 'each'} at the stream's median step, "
                f"{'/'.join(steps)} ms")

    def write_recording(self, path) -> Path:
        """The samples as a tumble recording (SPEC section 2): the accelerometer's, the gyro's (rad/s) and
        temp_c columns when every sample had them; a ``# clock:`` line when the module's clock restarted."""
        data = self.samples
        keep = list(range(*_GROUPS[0]))
        for lo, hi in _GROUPS[1:]:
            if np.all(np.isfinite(data[:, lo:hi])):
                keep += range(lo, hi)
        lines = ["# source: compass live --calibrate tumble"]
        if self.restarts:
            lines.append(f"# clock: {self.clock_words()}")
        lines.append(",".join(_COLUMNS[j] for j in [0, *keep]))
        lines += [",".join(f"{v:.9g}" for v in row) for row in data[:, [0, *keep]]]
        atomic_write_text(path, "\n".join(lines) + "\n")
        return Path(path)
