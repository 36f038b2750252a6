"""``compass device --pty``: a simulated compass module streaming on a pseudo-terminal.

Prints the device path, then streams the line protocol (or, with ``--format``, MotionCal's lines or
bare numbers: :mod:`compass.sim.stream_formats`) from the forward model with scripted motion
(:mod:`compass.sim.device`) until Ctrl-C or ``--duration``.  Line noise and a disconnect
can be injected to exercise a receiver.
"""

from __future__ import annotations

import os
import signal
import threading

from .. import limits
from ..limits import Range
from ._port import stop_signals


DEVICE_FORMATS = ("compass", "motioncal", "motioncal-raw", "csv")  # compass.sim.stream_formats, not imported at start


def register(sub) -> None:
    p = sub.add_parser(
        "device", help="simulated compass module on a pseudo-terminal (for compass live without hardware)",
        description="Stream the line protocol from a simulated module: slow turns, tilts, a magnet nearby "
                    "from 22.5 to 31 s of every 40 s. Prints the device path to open with compass live --port.")
    p.add_argument("--pty", action="store_true", required=True, help="serve on a new pseudo-terminal (required)")
    p.add_argument("--cal", help="calibration JSON: the module carries this sensor (default: a built-in sensor)")
    p.add_argument("--save-cal", metavar="CAL.json",
                   help="write the module's sensor as a calibration file for compass live, then stream")
    p.add_argument("--rate", type=limits.RATE_HZ.option("--rate"),
                   default=100.0, help="samples per second (default 100)")
    p.add_argument("--seed", type=limits.SEED.option("--seed"), default=0, help="noise seed (default 0)")
    p.add_argument("--no-gyro", action="store_true", help="send no gx,gy,gz columns")
    p.add_argument("--format", choices=DEVICE_FORMATS, default="compass",
                   help="compass: the line protocol (default); motioncal: a MotionCal sketch as Adafruit's (Raw: and "
                        "Uni: lines, Cal1:/Cal2: echoes, takes the 68-byte calibration packet); motioncal-raw: as "
                        "PJRC's (Raw: only); csv: bare numbers t_s ax ay az gx gy gz mx my mz. Without --cal these "
                        "carry a magnetometer in uT")
    p.add_argument("--motion", choices=("script", "tumble"), default="script",
                   help="script: the 40 s attitude script with a magnet (default); tumble: every orientation, for "
                        "a free-motion calibration (compass live --calibrate tumble)")
    p.add_argument("--link", help="keep a symbolic link with this name to the current pty (stable across disconnects)")
    p.add_argument("--garbage", type=limits.FRACTION.option("--garbage"), default=0.0, metavar="P",
                   help="probability per sample of a line of random bytes (default 0)")
    p.add_argument("--truncate", type=limits.FRACTION.option("--truncate"), default=0.0, metavar="P",
                   help="probability per sample of cutting the line short (default 0)")
    p.add_argument("--disconnect-at", type=limits.WAIT_S.option("--disconnect-at"),
                   metavar="S", help="unplug at this module time, seconds")
    p.add_argument("--disconnect-for", type=limits.DURATION_S.option("--disconnect-for"), default=1.0, metavar="S",
                   help="stay unplugged this long, seconds (default 1)")
    p.add_argument("--duration", type=limits.DURATION_S.option("--duration"),
                   help="stop after this many seconds of module time")
    p.add_argument("--force", action="store_true", help="overwrite --save-cal's file")
    bench = p.add_argument_group("a module on a simulated turntable, for compass bench (--bench)")
    bench.add_argument("--bench", action="store_true",
                       help="the module sits on a simulated turntable; a simulated operator does what compass bench "
                            "asks in its --prompt-file (give the same file as --operator)")
    bench.add_argument("--turntable", choices=("encoder", "grbl", "manual", "gyro"), default="encoder",
                       help="encoder: the table's angle sent as column 'enc' (default); grbl: a GRBL controller on a "
                            "second pty turns the table; manual: the operator turns to marks, read within "
                            "+-0.5 deg; gyro: the operator turns from the mark once round (the module's gyro has "
                            "a 0.5 deg/s bias and a 1 %% scale error)")
    bench.add_argument("--operator", metavar="FILE", help="--bench: the station's prompt file the operator reads")
    bench.add_argument("--encoder-step", type=Range(0.0, 90.0, "deg").option("--encoder-step"), default=0.1, metavar="DEG",
                       help="--turntable encoder: the encoder's resolution (default 0.1 deg)")
    bench.add_argument("--speed", type=Range(0.0, 1e3, lo_open=True).option("--speed"), default=1.0,
                       help="--bench: module seconds per wall second (default 1; the station works in module time)")
    bench.add_argument("--save-truth", metavar="TRUTH.json",
                       help="--bench: write the simulated sensor's truth (directions, offsets, gains, dip)")
    bench.add_argument("--mistake", action="append", default=[], choices=("short_turn", "wrong_face"),
                       help="--bench: the operator makes this mistake once (repeatable)")
    bench.add_argument("--table-clockwise", action="store_true",
                       help="--bench: the table's encoder and graduation count clockwise seen from above, and the "
                            "GRBL controller's $3 mask inverts the axis (a positive move turns the table clockwise), "
                            "against SPEC's counterclockwise turntable angle (compass bench must stop)")
    bench.add_argument("--rate-change-at", type=limits.WAIT_S.option("--rate-change-at"), metavar="S", help="--bench: halve the rate at this module time")
    bench.add_argument("--header-change-at", type=limits.WAIT_S.option("--header-change-at"), metavar="S",
                       help="--bench: stop sending the accelerometer at this module time")
    bench.add_argument("--grbl-link", help="--turntable grbl: a symbolic link to the controller's pty")
    bench.add_argument("--grbl-fault", choices=("alarm", "silent"),
                       help="--turntable grbl: the controller alarms (ALARM:2, soft limit) or stops answering after "
                            "its third move")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import BadInput

    for option, link in (("--link", args.link), ("--grbl-link", getattr(args, "grbl_link", None))):
        if link is not None and not os.path.isdir(os.path.dirname(os.path.abspath(link))):
            raise BadInput(f"{option} {link}: its folder does not exist")
    if args.bench:
        return _run_bench(args)
    from ..calibration import load, model_to_dict, save
    from ..sim.device import MOTIONS, PtyDevice, default_model
    from ..sim.stream_formats import board_model

    imu_from_model = None
    if args.cal is not None:
        try:
            cal = load(args.cal)
        except ValueError as exc:
            raise BadInput(str(exc)) from None
        model, to_model = cal.model, cal.imu.rotation
        # the module's accelerometer and gyro in their own frame, which compass live turns into the model's
        imu_from_model = None if to_model is None else to_model.T
        if model.dip_deg is None:
            raise BadInput(f"{args.cal}: the calibration has no dip_deg: the module cannot simulate its field")
    else:
        model = default_model() if args.format == "compass" else board_model()
    if args.link is not None and os.path.lexists(args.link) and not os.path.islink(args.link):
        raise BadInput(f"--link {args.link}: exists and is not a symbolic link; it would be replaced")
    try:
        device = PtyDevice(model, rate_hz=args.rate, seed=args.seed, link=args.link, garbage_rate=args.garbage,
                           truncate_rate=args.truncate, disconnect_at_s=args.disconnect_at,
                           disconnect_for_s=args.disconnect_for, gyro=not args.no_gyro, motion=MOTIONS[args.motion],
                           imu_from_model=imu_from_model, fmt=args.format,
                           on_path=lambda path: print(args.link or path, flush=True))
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    if args.save_cal is not None:
        save(args.save_cal, model_to_dict(model), force=args.force)
    _run_until_signal(device, args.duration)
    c = device.counts
    print(f"compass device: sent {c['samples']} samples; injected {c['garbage']} garbage and {c['truncated']} "
          f"truncated lines, {c['disconnects']} disconnect(s); {c['overflow']} lines refused by the pty (nobody "
          f"reading)" + (f"; {c['packets']} calibration packet(s) taken" if args.format.startswith("motioncal") else ""),
          flush=True)
    return 0


def _run_bench(args) -> int:
    import json

    from ..cli import BadInput
    from ..io.atomic import atomic_write_text, check_writable
    from ..sim.bench_device import BenchPty
    from ..sim.bench_rig import BenchRig, Operator

    if args.operator is None:
        raise BadInput("--bench needs --operator FILE: the station's --prompt-file the simulated operator reads")
    if args.cal is not None or args.save_cal is not None:
        raise BadInput("--bench simulates its own sensor: --cal and --save-cal do not apply (--save-truth does)")
    if args.save_truth is not None:
        check_writable(args.save_truth, args.force)
    kind = args.turntable
    operator = Operator(read_half_width_deg=0.5 if kind == "manual" else 0.0, mistakes=tuple(args.mistake))
    if args.format.startswith("motioncal") and kind == "gyro" and args.speed != 1.0:
        raise BadInput(f"--format {args.format} --turntable gyro --speed {args.speed:g}: MotionCal lines carry no time, "
                       f"so the station dates them as they arrive and integrates the gyro in that time: the simulated "
                       f"module must run in real time (--speed 1)")
    try:
        rig = BenchRig(seed=args.seed, rate_hz=args.rate, operator=operator,
                       encoder_step_deg=args.encoder_step if kind == "encoder" else None,
                       gyro_bias_dps=0.5 if kind == "gyro" else 0.0, gyro_scale_error=0.01 if kind == "gyro" else 0.0,
                       fmt=args.format, table_clockwise=args.table_clockwise)
    except ValueError as exc:
        raise BadInput(f"--bench --format {args.format} --turntable {kind}: {exc}") from None
    if args.format == "csv":
        print(f"columns {','.join(rig.csv_columns())} (compass bench --columns; the gyro in deg/s: --gyro-unit deg/s)",
              flush=True)
    table = None
    if kind == "grbl":
        rig.operator_turns = False
        from ..sim.grbl import GrblPty

        table = GrblPty(rig, link=args.grbl_link, fault=args.grbl_fault, speed=args.speed,
                        on_path=lambda path: print(f"grbl {path}", flush=True), invert_direction=args.table_clockwise)
        table.open()
    if args.save_truth is not None:
        atomic_write_text(args.save_truth, json.dumps(rig.truth, indent=2) + "\n")
    try:
        device = BenchPty(rig, args.operator, speed=args.speed, link=args.link,
                          on_path=lambda path: print(path, flush=True), disconnect_at_s=args.disconnect_at,
                          disconnect_for_s=args.disconnect_for, rate_change_at_s=args.rate_change_at,
                          header_change_at_s=args.header_change_at, table=table)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    try:
        _run_until_signal(device, args.duration)
    finally:
        if table is not None:
            table.close()
    c = device.counts
    print(f"compass device: sent {c['samples']} samples, read {c['instructions']} instructions, "
          f"{c['disconnects']} disconnect(s); {c['overflow']} writes refused by the pty (nobody reading)", flush=True)
    return 0


def _run_until_signal(device, duration) -> None:
    """Run a simulated device until ``duration`` passes or Ctrl-C / SIGTERM / SIGHUP, restoring the handlers after."""
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in stop_signals()}
    try:
        device.run(stop, duration)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
