"""``compass bench --port P --out CAL.json --turntable SOURCE``: the guided four-flip session.

Reads the module's stream as ``compass live`` does (:func:`compass.commands._port.open_reader`; any format
of :mod:`compass.io.streams`, found from the first lines and said, :mod:`compass.station.stream`), runs the
session (:class:`compass.station.Station`), keeps each finished flip in ``CAL.flips/``, writes the
recording ``CAL.fourflip.csv`` and calibrates it with ``compass calibrate``'s own code
(:func:`compass.commands.calibrate.calibrate_file`).  Instructions and the readout go to stderr;
``--prompt-file`` also writes the current instruction as JSON (for a simulated operator, or a
display beside the bench).
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time

from .. import limits
from ..io.stream_options import add_stream_arguments
from ..limits import Range
from ..viz import add_rerun_option


def register(sub) -> None:
    p = sub.add_parser(
        "bench", help="guided four-flip session: a module on a turntable to a calibration file",
        description="Record the four-flip calibration of a compass module on a turntable: the station says which "
                    "face of the cube goes down, records one full turn per flip, checks each as it comes, keeps "
                    "each finished flip on disk, and calibrates the recording as compass calibrate does.")
    p.add_argument("--port", required=True, help="the module's serial port or pyserial URL")
    p.add_argument("--out", required=True, help="calibration JSON to write (the recording goes beside it: "
                                                 "CAL.fourflip.csv; finished flips are kept in CAL.flips/)")
    p.add_argument("--turntable", required=True, metavar="SOURCE",
                   help="the turntable's angle: column:NAME (an encoder column in the stream), grbl:PORT (a GRBL "
                        "controller turning the table), manual:STEP_DEG (a graduated table turned by hand to "
                        "marks), gyro (the module's gyro about the table axis); a - before NAME or STEP_DEG "
                        "(column:-enc, manual:-30) negates an encoder or a graduation that counts clockwise seen from "
                        "above (the station stops on an angle that counts against the module's gyro)")
    p.add_argument("--module-id", default="unknown", help="the module's serial or name (written into the recording)")
    p.add_argument("--operator", default=os.environ.get("USER", "unknown"), help="who ran the session")
    p.add_argument("--site", metavar="LAT,LON[,ALT_M]", help="where the bench stands (its hemisphere, the WMM "
                                                              "check of the dip, and the WMM's |B| written as "
                                                              "'# field_ut:', so offsets come out in uT)")
    p.add_argument("--date", metavar="YYYY-MM-DD", help="the session's date (default today, UTC)")
    p.add_argument("--yes", action="store_true", help="no prompts: proceed when the data show the next flip done")
    p.add_argument("--resume", action="store_true", help="continue the session whose flips are kept in CAL.flips/")
    p.add_argument("--force", action="store_true", help="overwrite CAL.json and its recording; start over")
    p.add_argument("--prompt-file", metavar="FILE", help="also write the current instruction here as JSON")
    p.add_argument("--grbl-axis", default="A", help="grbl: the rotary axis' letter (default A)")
    p.add_argument("--grbl-step", type=Range(0.0, 360.0, "deg", lo_open=True).option("--grbl-step"), default=10.0, metavar="DEG",
                   help="grbl: the table stops every DEG degrees (default 10)")
    p.add_argument("--grbl-feed", type=Range(0.0, 1e6, "deg/min", lo_open=True).option("--grbl-feed"), default=None,
                   metavar="DEG_PER_MIN", help="grbl: feed rate of the moves, degrees a minute (default 1800 for stops; "
                                               "720 for a continuous turn: 0.12 deg between samples at 100 Hz)")
    p.add_argument("--grbl-mode", choices=("stops", "continuous"), default="stops",
                   help="grbl: turn a stop at a time (default), or once round in one move, every sample kept and its "
                        "angle interpolated from the controller's status reports")
    p.add_argument("--baud", type=limits.BAUD.option("--baud"), default=115200, help="serial baud rate (default 115200)")
    p.add_argument("--wait", type=limits.WAIT_S.option("--wait"), default=0.0, metavar="S",
                   help="how long the port may take to appear, seconds (default 0: a port that cannot be opened is "
                        "an error); once connected, a lost port is always waited for")
    p.add_argument("--quiet", action="store_true", help="do not print the fit report")
    add_rerun_option(p)
    add_stream_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import BadInput
    from ..io.atomic import check_writable
    from ..serial_reader import Chunk, PortUnavailable
    from ..site import Site
    from ..station import SessionEnded, SessionStore, Station, StationStream, parse_turntable, recording_path
    from ..viz import check_rerun_target
    from ._port import open_reader, port_unavailable, stream_options
    from .calibrate import calibrate_file

    try:
        feed = args.grbl_feed or (720.0 if args.grbl_mode == "continuous" else 1800.0)
        source = parse_turntable(args.turntable, grbl_options={"axis": args.grbl_axis, "step_deg": args.grbl_step,
                                                                "feed_deg_min": feed, "mode": args.grbl_mode,
                                                                "clock": time.perf_counter})  # the reader's clock
        site = Site.parse(args.site, args.date) if args.site is not None else None
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    options = stream_options(args)
    out = check_writable(args.out, args.force)
    target = check_rerun_target(args.rerun, args.force)
    check_writable(recording_path(out), args.force)
    metadata = _metadata(args, source, site)
    store = SessionStore(out)
    if store.folder.exists() and not store.folder.is_dir():
        raise BadInput(f"{store.folder} is a file, not the session's folder (compass bench keeps the finished flips "
                       f"in {store.folder.name}/ beside --out): move it away, or give another --out")
    if args.resume and store.exists() and not store.finished():
        raise BadInput(f"--resume: {store.folder} holds an earlier session that kept no flip: run without --resume "
                       f"to start over")
    if store.discard_empty():
        print(f"compass bench: {store.folder} held an earlier session that kept no flip: starting over",
              file=sys.stderr)
    description, done = None, {}
    if store.exists() and not args.resume:
        if not args.force:
            raise BadInput(f"{store.folder} holds {len(store.finished())} flip(s) of an earlier session: --resume "
                           f"continues it, --force starts over")
        store.discard()
    elif args.resume:
        if not store.exists():
            raise BadInput(f"--resume: {store.folder} holds no session to continue")
        description = store.description()
        if description["turntable"] != source.spec:
            raise BadInput(f"--resume: the flips in {store.folder} were recorded with --turntable "
                           f"{description['turntable']}, not {source.spec}")
        done = store.finished()
        metadata = description["metadata"]  # the session's, as it began
    encoder = getattr(source, "column", None)
    stream = StationStream(encoder, tuple(description["header"]) if description else None, options)
    reader = open_reader(args)
    readout = _Readout(args.prompt_file, stream)
    state = {"station": None}

    def make_station():
        info = {"format": "compass-bench-session/1", "stream_format": stream.format, "header": list(stream.header),
                "turntable": source.spec,
                "metadata": metadata, "rate_hz": description.get("rate_hz") if description else None}

        def keep(rows):
            store.save(rows)
            readout.flip(rows)
            info["rate_hz"] = station.rate_hz
            store.start(info)

        if description is None:
            store.start(info)
        if target is not None:
            readout.record(target, stream.channels)
        station = Station(source, stream.channels, ask=not args.yes, done=done, on_flip=keep,
                          rate_hz=info["rate_hz"])
        if done:
            readout.say("info", f"resuming: flips {', '.join(f'{f:g}' for f in sorted(done))} kept in {store.folder}")
        return station

    stop = threading.Event()
    if not args.yes:
        threading.Thread(target=_confirmations, args=(state, stop), daemon=True).start()
    try:
        if hasattr(source, "open"):
            source.open()
        for item in reader.items(stop):
            station = state["station"]
            if hasattr(source, "poll"):
                source.poll()
            if not isinstance(item, Chunk):
                if item.kind == "waiting" and not reader.connected_once:  # asked for with --wait S
                    readout.say("info", f"{item.message}: up to {args.wait:g} s")
                    continue
                readout.say("info" if item.kind == "connected" else "warn", item.message)
                if item.kind == "connected":
                    stream.resync()
                elif item.kind == "disconnected" and station is not None:
                    station.link_lost(f"{args.port} lost")
                    readout.events(station)
                continue
            readings = stream.feed(item.data, item.t_rx)
            if readings and hasattr(source, "clock_pair"):
                source.clock_pair(item.t_rx, readings[-1].t_s)
            for level, text in stream.drain():
                readout.say(level, text)
            if station is None and stream.header is not None:
                station = state["station"] = make_station()
            if station is None:
                continue
            for reading in readings:
                station.feed(reading)
            if readings:
                readout.track(station, readings[-1].t_s)
            readout.events(station)
            readout.show(station)
            if station.finished:
                break
    except PortUnavailable as exc:
        raise port_unavailable(exc) from None
    except SessionEnded as exc:
        station = state["station"]
        kept = "" if station is None or not station.done else (
            f" (flips {_flips(station)} kept in {store.folder}: --resume continues)")
        raise BadInput(f"{exc}{kept}") from None
    except KeyboardInterrupt:
        station = state["station"]
        if station is not None and station.done:
            print(f"compass bench: flips {_flips(station)} kept in {store.folder}; --resume continues",
                  file=sys.stderr)
        raise
    finally:
        stop.set()
        store.discard_empty()  # a session that ended before its first flip leaves nothing to resume
        reader.close()
        if hasattr(source, "close"):
            source.close()
        readout.close()
    path = store.write_recording(metadata, force=args.force)
    print(f"wrote {path}")
    calibrate_file(path, out, force=args.force, quiet=args.quiet)
    store.discard()
    return 0


def _flips(station) -> str:
    return ", ".join(f"{f:g}" for f in sorted(station.done))


def _metadata(args, source, site) -> dict:
    import datetime as dt

    meta = {"module_id": args.module_id, "turntable": source.spec, "operator": args.operator,
            "date": (site.date.isoformat() if site is not None else args.date)
            or dt.datetime.now(dt.timezone.utc).date().isoformat(),
            "source": "compass bench"}
    if site is not None:  # the WMM's |B| there: the field unit, so the calibration's offsets are in uT
        meta.update(site_lat_deg=f"{site.lat_deg:g}", site_lon_deg=f"{site.lon_deg:g}", site_alt_m=f"{site.alt_m:g}",
                    field_ut=f"{site.field().field_ut:.3f}")
    return meta


def _confirmations(state, stop) -> None:
    """Each line on stdin (Enter) confirms the flip asked for."""
    for _ in sys.stdin:
        if stop.is_set():
            return
        if state["station"] is not None:
            state["station"].confirm()


class _Readout:
    """Instructions, warnings and a progress line on stderr; the instruction as JSON in a prompt file."""

    def __init__(self, prompt_file, stream):
        self.prompt_file = prompt_file
        self.stream = stream
        self.viz = None  # the Rerun recording (--rerun), once the module's channels are known
        self._tracked = -float("inf")
        self.tty = sys.stderr.isatty()
        self._shown = None
        self._next = 0.0

    def record(self, target, channels) -> None:
        from ..viz.bench import BenchRecording

        self.viz = BenchRecording(target, channels)

    def flip(self, rows) -> None:
        if self.viz is not None:
            self.viz.flip(rows)

    def track(self, station, t_s: float) -> None:
        """The degrees covered, to the Rerun recording every quarter second of module time."""
        if self.viz is not None and t_s >= self._tracked + 0.25:
            self._tracked = t_s
            self.viz.progress(t_s, station.progress.flip_deg, station.progress.covered_deg)

    def say(self, level: str, text: str) -> None:
        if self.tty:
            sys.stderr.write("\r\033[K")
        print(f"compass bench: {'warning: ' if level == 'warn' else ''}{text}", file=sys.stderr, flush=True)
        if self.viz is not None:
            self.viz.event(None, level, text)

    def events(self, station) -> None:
        for level, text in station.drain():
            self.say(level, text)
        if self.prompt_file is not None and station.instruction.n != self._shown:
            from ..io.atomic import atomic_write_text

            self._shown = station.instruction.n
            atomic_write_text(self.prompt_file, json.dumps(station.instruction.to_json()) + "\n")

    def show(self, station) -> None:
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + (0.5 if self.tty else 5.0)
        p = station.progress
        if p.flip_deg is None or station.finished:
            return
        line = (f"flip {p.flip_deg:g} ({p.flips_done}/4 done), {p.step}: {p.covered_deg:.0f}/360 deg, "
                f"{p.rate_hz:.4g} Hz, {self.stream.describe()}")
        if self.tty:
            sys.stderr.write("\r\033[K" + line)
            sys.stderr.flush()
        else:
            print(f"compass bench: {line}", file=sys.stderr, flush=True)

    def close(self) -> None:
        """End the progress line; write the Rerun recording (everything the session showed, also when it ended
        early: the flips kept are in it)."""
        if self.tty:
            sys.stderr.write("\n")
        if self.viz is not None:
            self.viz.close()
            if self.viz.recording.path is not None:
                print(f"compass bench: wrote {self.viz.recording.path}", file=sys.stderr, flush=True)
