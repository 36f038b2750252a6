"""The live tumble calibration's collector: samples of a module turned by hand, their coverage and the
converging ellipsoid fit, in the style of MotionCal.

``compass live --calibrate tumble`` feeds it the port's items (:meth:`TumbleCollector.feed`), shows
:meth:`TumbleCollector.readout` every second after :meth:`TumbleCollector.update`, and when
:attr:`TumbleCollector.enough` writes the samples as a tumble recording
(:meth:`TumbleCollector.write_recording`) that :class:`calibrate.tumble.TumbleCalibrator` then fits
like any other.

The recording keeps what the module sent of ``ax,ay,az``, ``gx,gy,gz`` (rad/s, as the decoder hands them and
as the tumble reader takes them by default) and ``temp_c``: with the gyro, ``compass calibrate`` fits the turns
between samples too (the gyro-aided fit of :mod:`calibrate.tumble.gyro`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from compass.io.atomic import atomic_write_text
from compass.io.clock import SampleClock
from compass.io.streams import StreamDecoder

from .coverage import sphere_coverage
from .ellipsoid import fit_ellipsoid

__all__ = ["CHANNELS", "MIN_SAMPLES", "TumbleCollector"]

CHANNELS = ("mx", "my", "mz")
MIN_SAMPLES = 50
"""Samples below which no fit is tried (and the command refuses to calibrate)."""
_FIT_SAMPLES = 2000  # the live fit uses at most this many samples, evenly spread
_COLUMNS = ("t_s", *CHANNELS, "ax", "ay", "az", "gx", "gy", "gz", "temp_c")
_GROUPS = ((1, 4), (4, 7), (7, 10), (10, 11))  # the samples' columns: magnetometer, accelerometer, gyro, temp_c


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
    """

    def __init__(self, *, min_coverage: float = 0.8, stream=None):
        self.min_coverage = min_coverage
        self.decoder = StreamDecoder(CHANNELS, stream)
        self.rows: list[tuple] = []
        self.coverage = None
        self.fit = None
        self._t0 = None
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
        self._add(self.decoder.feed(item.data, item.t_rx), item.t_rx)
        return self.decoder.drain_events() if self.decoder.events else []

    def finish(self) -> list:
        """At the end of the stream: the samples the decoder still held; returns its events."""
        if self._t0 is not None:
            self._add(self.decoder.flush(), self._last_rx)
        return self.decoder.drain_events()

    def _add(self, samples: list, t_rx: float) -> None:
        absent = (np.nan,) * 3
        for s in self._clock.dated(samples, t_rx, self._t0):
            self.rows.append((s.t_s, *s.raw, *(absent if s.accel is None else s.accel),
                              *(absent if s.gyro is None else s.gyro), np.nan if s.temp_c is None else s.temp_c))

    @property
    def samples(self) -> np.ndarray:
        """(n, 11): t_s, mx, my, mz, ax, ay, az, gx, gy, gz, temp_c (NaN where not sent; the gyro in rad/s)."""
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

    def write_recording(self, path) -> Path:
        """The samples as a tumble recording (SPEC section 2): the accelerometer's, the gyro's (rad/s) and
        temp_c columns when every sample had them."""
        data = self.samples
        keep = list(range(*_GROUPS[0]))
        for lo, hi in _GROUPS[1:]:
            if np.all(np.isfinite(data[:, lo:hi])):
                keep += range(lo, hi)
        lines = ["# source: compass live --calibrate tumble", ",".join(_COLUMNS[j] for j in [0, *keep])]
        lines += [",".join(f"{v:.9g}" for v in row) for row in data[:, [0, *keep]]]
        atomic_write_text(path, "\n".join(lines) + "\n")
        return Path(path)
