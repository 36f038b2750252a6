"""``compass live --port P --calibrate tumble --out CAL.json``: a free-motion calibration while you
turn the module, in the style of MotionCal.

The module's samples (any stream :mod:`compass.io.streams` reads: our line protocol, MotionCal's
``Raw:``/``Uni:`` lines, bare numbers with ``--columns``; ``mx,my,mz`` and optionally ``ax,ay,az``,
``t_s``, ``temp_c``, ``gx,gy,gz``; a field unit named or fixed by the format is converted to uT) are collected
while the readout (and, with ``--rerun``, the viewer) shows the coverage growing, the
ellipsoid fit's hard iron converging and, in words, the orientations still missing. When every
half-axis has been along the field and ``--min-coverage`` of the sphere's cells hold a sample (or on
Ctrl-C, or after ``--duration``), the samples are written as a tumble recording beside the
calibration (``CAL.tumble.csv``, the gyro kept: the gyro-aided fit uses it; its ``t_s`` going on across
a restart of the module's clock, :class:`calibrate.tumble.collector.ClockRestart`, a sample with a corrupted time
left out, :class:`calibrate.tumble.collector.CorruptedTime`) and calibrated by the
same code as ``compass calibrate`` (same checks, refusals and diagnosis).  While they are collected the samples go
to a temporary file beside ``CAL.tumble.csv`` as they come (:meth:`TumbleCollector.stream_rows`, flushed every
second), which a session killed outright leaves and the next write to ``CAL.tumble.csv`` keeps as
``CAL.tumble.partial-PID.csv`` (:func:`compass.io.atomic.atomic_stream`).
"""

from __future__ import annotations

import time
from pathlib import Path

__all__ = ["run_tumble", "recording_path"]


def recording_path(out) -> Path:
    """Where the collected samples go: ``CAL.json`` -> ``CAL.tumble.csv``."""
    out = Path(out)
    return out.with_name(out.stem + ".tumble.csv")


def run_tumble(args) -> int:
    """``compass live --calibrate tumble``: collect, show, then calibrate (see the module docstring)."""
    from calibrate.tumble.collector import CHANNELS, MIN_SAMPLES, TumbleCollector

    from ..cli import BadInput
    from ..io.atomic import atomic_stream, check_writable
    from ..serial_reader import PortUnavailable
    from ..viz import check_rerun_target
    from . import calibrate as calibrate_cmd
    from ._port import open_reader, port_unavailable, stop_when_asked, stream_options

    if args.out is None:
        raise BadInput("--calibrate tumble needs --out CAL.json (the calibration to write)")
    if args.cal is not None:
        raise BadInput("--calibrate tumble calibrates the module from scratch: leave out --cal")
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
    # the samples go to a temporary file beside CAL.tumble.csv as they come (flushed every second), left by a session
    # killed outright and kept by the next write to CAL.tumble.csv as CAL.tumble.partial-PID.csv; at any other end
    # the collection is written as CAL.tumble.csv below, and the temporary file removed
    with atomic_stream(recording, keep=lambda: False) as partial:
        if not args.quiet:
            print(f"compass live: the samples go to {partial.name} as they come (a session killed outright leaves "
                  f"it; the next session writing {recording} keeps it as {_partial_name(recording)})", flush=True)
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
                        collector.stream_rows(partial)
                        partial.flush()
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
                if len(collector.rows) < MIN_SAMPLES:
                    raise BadInput(f"{args.port}: {len(collector.rows)} samples with {', '.join(CHANNELS)} received; "
                                   f"a tumble calibration needs at least {MIN_SAMPLES}")
                collector.update()
                why = "coverage reached" if collector.enough else "stopped before the coverage was reached"
                print(f"compass live: {why}; {collector.readout()}", flush=True)
                clock = collector.clock_words()
                if clock is not None:  # restarts and corrupted times: said when told too, unless --quiet
                    print(f"compass live: {clock}", flush=True)
                print(f"wrote {collector.write_recording(recording)}", flush=True)
                result = calibrate_cmd.calibrate_file(recording, out, kind="tumble", force=True, quiet=args.quiet)
            finally:
                if view is not None:
                    view.close(result, collector.samples[:, 1:4])
                    print(f"wrote {target}", flush=True)
    return 0


def _partial_name(path: Path) -> str:
    """Where the next write to ``path`` keeps a killed session's samples (:func:`compass.io.atomic.atomic_stream`)."""
    return str(path.with_name(f"{path.stem}.partial-PID{path.suffix}"))


def _say(args, view, collector, text: str) -> None:
    """An event line on the terminal (unless --quiet) and in the viewer's log."""
    if not args.quiet:
        print(text, flush=True)
    if view is not None:
        view.event(collector, text)
