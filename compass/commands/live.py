"""``compass live --port PORT_OR_URL --cal CAL.json``: live heading, pitch and roll from a module.

Reads the module's stream (:mod:`compass.io.streams`: our line protocol, MotionCal's lines, bare
numbers) from a serial port or pyserial URL, filters
(:mod:`compass.filter`), prints a one-line readout and optionally records the attitude CSV and a
Rerun recording.  Ctrl-C (or SIGTERM, SIGHUP, or ``--duration``) ends it cleanly: files flushed, summary
with the dropped-line count printed.
"""

from __future__ import annotations

import contextlib
import sys
import time

from .. import limits
from ..limits import Range
from ..io.stream_options import add_stream_arguments
from ..viz import add_rerun_option, check_rerun_target
from ._port import open_reader, port_unavailable, stop_when_asked, stream_options


MAG_LATENCY_HELP = ("compensate the magnetometer's latency against the gyro that the calibration's gyro-aided tumble "
                    "fit found (tumble.gyro.mag_latency_s, when late beyond 3 sigma with a sigma under 10 ms): each "
                    "field reading is turned forward by the gyro over it; off by default (on BROAD it cost the "
                    "undisturbed trials' heading: docs/benchmarks.md)")


GYRO_MATRIX_HELP = ("correct every gyro sample by the scale and axis errors the calibration's gyro-aided tumble fit "
                    "found (tumble.gyro.gyro_matrix, the entries seen beyond 3 sigma of the identity with a sigma under "
                    "0.5 %%, none beyond 3 prior sigmas); off by default (on "
                    "BROAD the matrix fitted on another trial cost every group: docs/benchmarks.md)")


GYRO_SCALE_ERROR_HELP = ("the gyro's scale and axis error the filter allows for, a fraction of the rate (0.03: a "
                         "low-cost MPU-9250 class gyro); default: 0.005 and, in quadrature, what the calibration's "
                         "gyro-aided tumble fit saw (|G - I| and its sigma of the entries seen, only the sigma with "
                         "--gyro-matrix)")


def add_mag_latency_argument(p, *, with_filter: bool = False) -> None:
    """``--mag-latency`` (``FilterConfig.from_model(model, mag_latency=True)``), ``--gyro-matrix``
    (``gyro_matrix=True``) and ``--gyro-scale-error`` (``gyro_scale_error=F``), for ``live`` and ``attitude --filter``
    (there also ``--no-mag-latency`` and ``--no-gyro-matrix``, against a record's ``# replay:`` line; not given: None)."""
    import argparse

    switch = dict(action=argparse.BooleanOptionalAction, default=None) if with_filter else dict(action="store_true")
    p.add_argument("--mag-latency", **switch, help=("with --filter: " if with_filter else "") + MAG_LATENCY_HELP)
    p.add_argument("--gyro-matrix", **switch, help=("with --filter: " if with_filter else "") + GYRO_MATRIX_HELP)
    p.add_argument("--gyro-scale-error", type=limits.GYRO_SCALE_ERROR.option("--gyro-scale-error"), metavar="FRACTION",
                   help=("with --filter: " if with_filter else "") + GYRO_SCALE_ERROR_HELP)


def register(sub) -> None:
    p = sub.add_parser(
        "live", help="live attitude from a compass module on a serial port (Kalman filter, optional Rerun)",
        description="Read a compass module speaking the line protocol (docs/runtime.md: 'Line protocol'), fuse "
                    "with a Kalman filter that rejects magnetic disturbances, and show heading/pitch/roll live.")
    p.add_argument("--port", required=True,
                   help="serial device (/dev/ttyUSB0, COM3) or pyserial URL (socket://host:port, rfc2217://...)")
    p.add_argument("--cal", help="calibration JSON (compass calibrate) of the module's sensor (required unless "
                                 "--calibrate)")
    p.add_argument("--baud", type=limits.BAUD.option("--baud"), default=115200,
                   help="baud rate (default 115200; ignored by ptys and sockets)")
    add_rerun_option(p)
    p.add_argument("--out", help="also write the attitude stream to this CSV file")
    p.add_argument("--record", metavar="RAW.csv",
                   help="also write every sample the module sends, dated (a stream without t_s: from when its lines "
                        "arrive), as a recording `compass attitude CAL RAW.csv --filter` replays to the same rows")
    p.add_argument("--site", metavar="LAT,LON[,ALT_M]",
                   help="where the module is (degrees, metres): reference field and true north from the World "
                        "Magnetic Model (default: the calibration's site block, else the field of the first quiet "
                        "second, magnetic heading only)")
    p.add_argument("--date", metavar="YYYY-MM-DD", help="with --site: the day (default today, UTC)")
    add_mag_latency_argument(p)
    p.add_argument("--gravity", type=limits.GRAVITY.option("--gravity"), metavar="G",
                   help="what 1 g reads in the module's accelerometer unit, in g with --accel-unit (default: the "
                        "median |a| of the first quiet second; one beyond a factor 2 of that is refused)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--duration", type=limits.DURATION_S.option("--duration"),
                   help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--wait", type=limits.WAIT_S.option("--wait"), default=0.0, metavar="S",
                   help="keep trying to open the port this long before giving up (default 0: a port that cannot "
                        "be opened is an error); once connected, a lost port is always waited for")
    p.add_argument("--quiet", action="store_true", help="no live readout and no event lines, only the summary")
    p.add_argument("--calibrate", choices=("tumble",),
                   help="tumble: calibrate the module while you turn it through every orientation (coverage and fit "
                        "shown live); writes --out CAL.json when the coverage is enough, or on Ctrl-C")
    p.add_argument("--min-coverage", type=Range(0.0, 1.0, lo_open=True).option("--min-coverage"), default=0.8,
                   help="--calibrate tumble: fraction of the sphere to cover, with every axis along the field once "
                        "(default 0.8)")
    add_stream_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import BadInput
    from ..io.atomic import atomic_stream, check_writable
    from ..io.sample_log import SampleLog
    from ..live import LiveSession, invalid_words
    from ..filter import FilterConfig
    from ..replay import gyro_matrix_note, hemisphere_note, mag_latency_note
    from ..calibration import load

    if args.calibrate == "tumble":
        from ._live_tumble import run_tumble

        if args.record is not None:
            raise BadInput("--record goes with an attitude session: --calibrate tumble writes its samples to "
                           "CAL.tumble.csv beside --out, streamed as they come (a session killed outright leaves "
                           "them beside it, kept as CAL.tumble.partial-PID.csv by the next session)")

        return run_tumble(args)
    if args.cal is None:
        raise BadInput("--cal CAL.json is required (or --calibrate tumble to make one)")
    try:
        cal = load(args.cal)
        model = cal.model
        config = FilterConfig.from_model(model, mag_latency=args.mag_latency, gravity=args.gravity,
                                         gyro_matrix=args.gyro_matrix, gyro_scale_error=args.gyro_scale_error)
    except ValueError as exc:
        raise BadInput(f"{args.cal}: {exc}" if args.cal not in str(exc) else str(exc)) from None
    for flag, note in ((args.mag_latency, mag_latency_note), (args.gyro_matrix, gyro_matrix_note)):
        if flag and not args.quiet:
            level, text = note(model)
            print(f"[{level}] {text}", flush=True)
    reference = _site_reference(args, model, cal.site)
    hemisphere = hemisphere_note(cal, site_given=reference is not None)
    if hemisphere is not None and (hemisphere[0] == "warn" or not args.quiet):  # a warning under --quiet too
        print(f"compass live: {'warning' if hemisphere[0] == 'warn' else 'note'}: {args.cal}: {hemisphere[1]}",
              file=sys.stderr, flush=True)
    stream = stream_options(args)
    reader = open_reader(args)
    inputs = (args.cal, args.port)  # --out /dev/ttyUSB0 (the options mixed up) would write into the module
    out_path = None if args.out is None else check_writable(args.out, args.force, inputs=inputs)
    record_path = None if args.record is None else check_writable(args.record, args.force, inputs=inputs)
    if record_path is not None and out_path is not None and record_path.resolve() == out_path.resolve():
        raise BadInput(f"--record and --out are both {args.out}: give two files")
    rerun = check_rerun_target(args.rerun, args.force)  # a symbolic link's target, the link kept

    tty = sys.stdout.isatty()
    every_s = 0.1 if tty else 1.0

    def on_event(level, text):
        if not args.quiet:
            print(("\r\x1b[K" if tty else "") + f"[{level}] {text}", flush=True)

    session, sink, out, log, start = None, None, None, None, time.perf_counter()
    try:
        if args.rerun is not None:
            from ..viz import RerunSink

            sink = RerunSink.for_model(rerun, model, config)
        with contextlib.ExitStack() as outputs:
            # --out is a stream, written as it goes into a temporary file beside it, which replaces --out when
            # the session ends with rows (a failure included: what was recorded is kept); a session that
            # recorded nothing, or found the field turned over, leaves --out (an older file) as it was
            if out_path is not None:
                out = outputs.enter_context(atomic_stream(out_path, keep=lambda: _recorded(session)))
            if record_path is not None:  # kept whenever it holds a sample: the raw samples are good as they are
                log = SampleLog(outputs.enter_context(atomic_stream(record_path, keep=lambda: log.rows > 0)),
                                model.channels, args.port, _replay_options(args))
            session = LiveSession(model, config=config, out=out, sink=sink, on_event=on_event, reference=reference,
                                  imu=cal.imu, stream=stream, record=log,
                                  sign_from_bench=cal.provenance.hemisphere_assumed)
            streamed = [f for f in (out, None if log is None else log.out) if f is not None]
            _run_session(args, reader, session, streamed, tty, every_s)
            _refuse(args, session)  # judged on close: a stream shorter than the check
            header = session.decoder.header
            if session.samples == 0 and session.decoder.stats.samples > 0 and header is not None \
                    and header.accel is None:
                raise BadInput(f"{args.port}: its {session.decoder.stats.samples} samples carry no ax,ay,az (the "
                               f"header: {','.join(header.names)}): no attitude without the accelerometer's tilt, "
                               "the field alone fixes two of the three angles")
            if session.decoder.fatal is not None:  # judged on close: fewer samples than the unit check holds
                raise BadInput(_fatal_words(args, session.decoder))
    finally:
        recorded = _recorded(session)
        if sink is not None and session is None:
            sink.discard()  # the session never started: no half-written recording left behind
        elapsed = time.perf_counter() - start
        if session is not None and reader.connected_once:  # a port that never opened is said in one line
            if tty and not args.quiet:
                print()
            # both outputs hold what was recorded up to the end, a failure included (the session closed them)
            wrote = [str(p) for p in (out_path, args.rerun) if recorded and p is not None and str(p) != "spawn"]
            wrote += [f"{record_path} ({log.rows} samples)"] if log is not None and log.rows else []
            print(f"compass live: {elapsed:.1f} s, {reader.disconnects} disconnect(s); {session.summary()}"
                  + (f"; wrote {', '.join(wrote)}" if wrote else ""), flush=True)
            hint = session.closing_hint()
            if hint:
                print(f"compass live: hint: {hint}", file=sys.stderr, flush=True)
    if session.decoder.stats.samples == 0:
        s = session.decoder.stats
        why = ("the port never opened" if not reader.connected_once else
               f"{s.rejected_headers} unusable header(s), {s.bad_lines} bad line(s)"
               + (f", {invalid_words(s)}" if s.invalid else "") if s.rejected_headers or s.bad_lines
               else "nothing arrived: check the module, its baud rate and that it sends the header")
        print(f"compass live: no sample arrived from {args.port} in {elapsed:.1f} s ({why})", file=sys.stderr)
        return 1
    return 0


def _recorded(session) -> bool:
    """The session's outputs are worth keeping: rows written (not lines decoded) and no reason found that its
    attitudes are wrong (:attr:`~compass.live.LiveSession.stopped`)."""
    return session is not None and session.samples > 0 and not session.stopped


def _fatal_words(args, decoder) -> str:
    """Why the stream cannot be used (:attr:`compass.io.streams.StreamDecoder.fatal`), asking after the calibration
    only when its format is known: the unit check or the channels found the calibration and the stream apart.  Before
    that the stream itself is at fault (bare numbers whose columns are not named: the words say how to name them)."""
    if decoder.format is None:
        return f"{args.port}: {decoder.fatal}"
    return f"{args.port}: {decoder.fatal} ({args.cal}): is it the right calibration?"


def _refuse(args, session) -> None:
    """BadInput when the session found the field turned over (against ``--site`` or the calibration's dip),
    ``--gravity`` (or the calibration's accelerometer correction's unit) not what 1 g reads, the times not telling
    the steps, the field staying put in the housing or the gyro turning tens of times more than the field."""
    from ..cli import BadInput

    if session.turned_over is not None:
        raise BadInput(f"{args.cal}: {session.turned_over}")
    if session.wrong_gravity is not None:
        raise BadInput(f"{args.port}: {session.wrong_gravity}")
    if session.wrong_time is not None:
        raise BadInput(f"{args.port}: {session.wrong_time}")
    if session.wrong_field is not None:
        raise BadInput(f"{args.port}: {session.wrong_field} ({args.cal})")
    if session.gyro_unit is not None:
        raise BadInput(f"{args.port}: {session.gyro_unit}")


def _run_session(args, reader, session, files: list, tty: bool, every_s: float) -> None:
    """Feed the reader's items to the session until stopped (Ctrl-C, SIGTERM, --duration); print the readout and
    flush ``files`` (the streamed outputs) at its pace, so a killed session leaves them a readout old at most."""
    from ..cli import BadInput
    from ..serial_reader import PortUnavailable

    last = time.perf_counter()
    last_count = 0
    try:
        with stop_when_asked(args.duration) as stop:
            for item in reader.items(stop):
                session.feed(item)
                _refuse(args, session)
                if session.decoder.fatal is not None:
                    raise BadInput(_fatal_words(args, session.decoder))
                now = time.perf_counter()
                if now - last >= every_s:
                    rate = (session.decoder.stats.samples - last_count) / (now - last)
                    last, last_count = now, session.decoder.stats.samples
                    for f in files:
                        f.flush()
                    if not args.quiet:
                        print(("\r\x1b[K" if tty else "") + session.readout(rate), end="" if tty else "\n", flush=True)
    except PortUnavailable as exc:
        raise port_unavailable(exc) from None
    finally:
        reader.close()
        session.close()


def _replay_options(args) -> str:
    """The options of this session a replay of its ``--record`` needs to write the same rows (the replay takes them
    as defaults: :func:`compass.io.sample_log.read_replay_line`)."""
    import shlex

    from ..site import Site

    words = []
    if args.site is not None:  # the day too: the field of --site without --date is today's (the calibration's site
        # block, without --site, is the replay's default as it is live's)
        words.append(f"--site {shlex.quote(args.site)} --date {Site.parse(args.site, args.date).date.isoformat()}")
    if args.gravity is not None:
        words.append(f"--gravity {args.gravity!r}")
    words += [flag for flag, on in (("--mag-latency", args.mag_latency), ("--gyro-matrix", args.gyro_matrix)) if on]
    if args.gyro_scale_error is not None:
        words.append(f"--gyro-scale-error {args.gyro_scale_error!r}")
    return " ".join(words)


def _site_reference(args, model, calibration_site):
    """The WMM's field at ``--site``, else at the calibration's site block (as the replay takes it), None without
    either: the session seeds it from the stream."""
    from ..cli import BadInput
    from ..site import Site, reference_from_site

    if args.site is None and args.date is not None:
        raise BadInput("--date needs --site LAT,LON[,ALT_M]: the date only chooses the field at a site")
    field_ut = None if model.field_ut is None else 1.0
    try:
        if args.site is not None:
            return reference_from_site(Site.parse(args.site, args.date), field_ut=field_ut)
        if calibration_site is not None:
            return reference_from_site(calibration_site, field_ut=field_ut, source="calibration site")
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    return None
