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
    p.set_defaults(func=run)


def run(args) -> int:
    from ..calibration import load, model_to_dict, save
    from ..cli import BadInput
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
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        device.run(stop, args.duration)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    c = device.counts
    print(f"compass device: sent {c['samples']} samples; injected {c['garbage']} garbage and {c['truncated']} "
          f"truncated lines, {c['disconnects']} disconnect(s); {c['overflow']} lines refused by the pty (nobody "
          f"reading)" + (f"; {c['packets']} calibration packet(s) taken" if args.format.startswith("motioncal") else ""),
          flush=True)
    return 0
