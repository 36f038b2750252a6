"""``compass live --port P --calibrate tumble --out CAL.json``: a free-motion calibration while you
turn the module, in the style of MotionCal.

The module's samples (any stream :mod:`compass.io.streams` reads: our line protocol, MotionCal's
``Raw:``/``Uni:`` lines, bare numbers with ``--columns``; ``mx,my,mz`` and optionally ``ax,ay,az``,
``t_s``, ``temp_c``; a field unit named or fixed by the format is converted to uT) are collected while the readout (and, with ``--rerun``, the viewer) shows the coverage growing, the
ellipsoid fit's hard iron converging and, in words, the orientations still missing. When every
half-axis has been along the field and ``--min-coverage`` of the sphere's cells hold a sample (or on
Ctrl-C, or after ``--duration``), the samples are written as a tumble recording beside the
calibration (``CAL.tumble.csv``) and calibrated by the same code as ``compass calibrate`` (same
checks, refusals and diagnosis).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

__all__ = ["TumbleCollector", "run_tumble", "recording_path"]

_CHANNELS = ("mx", "my", "mz")
_FIT_SAMPLES = 2000  # the live fit uses at most this many samples, evenly spread
_MIN_SAMPLES = 50


def recording_path(out) -> Path:
    """Where the collected samples go: ``CAL.json`` -> ``CAL.tumble.csv``."""
    out = Path(out)
    return out.with_name(out.stem + ".tumble.csv")


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
    coverage : calibrate.tumble.Coverage or None
        Of the latest :meth:`update`.
    fit : calibrate.tumble.KindFit or None
        The latest ellipsoid fit (hard iron, its sigma).
    """

    def __init__(self, *, min_coverage: float = 0.8, stream=None):
        from ..io.streams import StreamDecoder

        self.min_coverage = min_coverage
        self.decoder = StreamDecoder(_CHANNELS, stream)
        self.rows: list[tuple] = []
        self.coverage = None
        self.fit = None
        self._t0 = None
        self._last_rx = 0.0

    def feed(self, item) -> list:
        """Take one item of :meth:`SerialReader.items`; returns the decoder's events (level, text)."""
        from ..serial_reader import LinkEvent

        if isinstance(item, LinkEvent):
            if item.kind == "connected":
                self.decoder.resync()
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
        for s in samples:
            t_s = s.t_s if s.t_s is not None else (t_rx if s.t_rx is None else s.t_rx) - self._t0
            self.rows.append((t_s, *s.raw, *(s.accel if s.accel is not None else (np.nan,) * 3),
                              np.nan if s.temp_c is None else s.temp_c))

    @property
    def samples(self) -> np.ndarray:
        """(n, 8): t_s, mx, my, mz, ax, ay, az, temp_c (NaN where not sent)."""
        return np.array(self.rows, dtype=float).reshape(-1, 8)

    def update(self) -> None:
        """Fit the ellipsoid to the samples so far and measure their coverage about its centre."""
        from calibrate.tumble import fit_ellipsoid, sphere_coverage

        mag = self.samples[:, 1:4]
        if len(mag) < _MIN_SAMPLES:
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
        """The samples as a tumble recording (SPEC section 2): accelerometer and temp_c columns when
        every sample had them."""
        from ..io.atomic import atomic_write_text

        data = self.samples
        columns, keep = ["t_s", *_CHANNELS], [0, 1, 2, 3]
        if np.all(np.isfinite(data[:, 4:7])):
            columns += ["ax", "ay", "az"]
            keep += [4, 5, 6]
        if np.all(np.isfinite(data[:, 7])):
            columns.append("temp_c")
            keep.append(7)
        lines = ["# source: compass live --calibrate tumble", ",".join(columns)]
        lines += [",".join(f"{v:.9g}" for v in row) for row in data[:, keep]]
        atomic_write_text(path, "\n".join(lines) + "\n")
        return Path(path)


def run_tumble(args) -> int:
    """``compass live --calibrate tumble``: collect, show, then calibrate (see the module docstring)."""
    from ..cli import BadInput
    from ..io.atomic import check_writable
    from ..serial_reader import PortUnavailable
    from ..viz import check_rerun_target
    from . import calibrate as calibrate_cmd
    from .live import open_reader, port_unavailable, stop_when_asked, stream_options

    if args.out is None:
        raise BadInput("--calibrate tumble needs --out CAL.json (the calibration to write)")
    if args.cal is not None:
        raise BadInput("--calibrate tumble calibrates the module from scratch: leave out --cal")
    if not 0.0 < args.min_coverage <= 1.0:
        raise BadInput(f"--min-coverage must be in (0, 1], got {args.min_coverage}")
    stream = stream_options(args)
    reader = open_reader(args)
    out = check_writable(args.out, args.force)
    recording = check_writable(recording_path(out), args.force)
    target = check_rerun_target(args.rerun, args.force)
    view = None
    if target is not None:
        from ..viz.calibration import LiveTumbleRecording

        view = LiveTumbleRecording(target)

    collector = TumbleCollector(min_coverage=args.min_coverage, stream=stream)
    last, said, result, port_error = time.perf_counter(), None, None, None
    try:
        with stop_when_asked(args.duration) as stop:
            for item in reader.items(stop):
                for level, text in collector.feed(item):
                    _say(args, view, collector, f"[{level}] {text}")
                if collector.decoder.fatal is not None:
                    port_error = BadInput(f"{args.port}: {collector.decoder.fatal}")
                    break
                now = time.perf_counter()
                if now - last >= 1.0:
                    last = now
                    collector.update()
                    if not args.quiet:
                        print(collector.readout(), flush=True)
                    if collector.coverage is not None and collector.coverage.missing != said:
                        said = collector.coverage.missing  # say it in words when the missing axes change
                        _say(args, view, collector, collector.coverage.words())
                    if view is not None:
                        view.update(collector)
                    if collector.enough:
                        break
    except PortUnavailable as exc:
        port_error = port_unavailable(exc)
    finally:
        reader.close()
        for level, text in collector.finish():
            _say(args, view, collector, f"[{level}] {text}")
        try:
            if port_error is not None:  # said as the port's fault, not as too few samples
                raise port_error
            if len(collector.rows) < _MIN_SAMPLES:
                raise BadInput(f"{args.port}: {len(collector.rows)} samples with {', '.join(_CHANNELS)} received; "
                               f"a tumble calibration needs at least {_MIN_SAMPLES}")
            collector.update()
            why = "coverage reached" if collector.enough else "stopped before the coverage was reached"
            print(f"compass live: {why}; {collector.readout()}", flush=True)
            print(f"wrote {collector.write_recording(recording)}", flush=True)
            result = calibrate_cmd.calibrate_file(recording, out, kind="tumble", force=True, quiet=args.quiet)
        finally:
            if view is not None:
                view.close(result, collector.samples[:, 1:4])
                print(f"wrote {target}", flush=True)
    return 0


def _say(args, view, collector, text: str) -> None:
    """An event line on the terminal (unless --quiet) and in the viewer's log."""
    if not args.quiet:
        print(text, flush=True)
    if view is not None:
        view.event(collector, text)
