"""``compass attitude CAL.json REC.csv --out ATT.csv``: heading, pitch, roll per row, with quality.

Parses the options, solves the recording (:func:`compass.recording.solve_recording`), writes the
attitude CSV atomically and says what it did.
"""

from __future__ import annotations

import sys

from .. import limits
from ..io.atomic import atomic_write_text, check_writable
from ..io.table import ReadOptions, add_read_arguments
from ..viz import add_rerun_option, check_rerun_target
from .live import add_mag_latency_argument


def register(sub) -> None:
    p = sub.add_parser(
        "attitude", help="heading, pitch and roll from a calibration and an attitude recording",
        description="Solve heading/pitch/roll per row. Gravity comes from ax,ay,az columns, known pitch_deg,roll_deg "
                    "columns, or --level; the field alone fixes only two of the three angles.")
    p.add_argument("calibration", help="calibration JSON (compass calibrate)")
    p.add_argument("recording", help="attitude recording CSV: the calibration's channel columns, optional t_s, "
                                     "ax,ay,az (any unit), gx,gy,gz (ignored here), or pitch_deg,roll_deg")
    p.add_argument("--out", required=True, help="attitude CSV to write")
    p.add_argument("--level", action="store_true",
                   help="no accelerometer: assume pitch = roll = 0 and report the heading error a tilt could cause")
    p.add_argument("--max-tilt-deg", type=limits.MAX_TILT_DEG.option("--max-tilt-deg"), default=5.0,
                   help="with --level: the tilt the assumption allows, for heading_bound_deg (default 5)")
    p.add_argument("--site", metavar="LAT,LON[,ALT_M]",
                   help="where the recording was made (degrees, metres): the reference field and true north come "
                        "from the World Magnetic Model there (default: the calibration's site block, else the "
                        "recording's own quiet rows, magnetic heading only)")
    p.add_argument("--date", metavar="YYYY-MM-DD", help="with --site: the day of the recording (default today, UTC)")
    p.add_argument("--accel-noise-g", type=limits.ACCEL_NOISE_G.option("--accel-noise-g"), default=0.002,
                   help="accelerometer white noise per axis as a fraction of 1 g (default 0.002)")
    p.add_argument("--filter", action="store_true",
                   help="run compass live's pipeline over the recording (needs t_s and ax,ay,az; gx,gy,gz used when "
                        "present): the same start, gate and Kalman filter, the columns of live --out plus the "
                        "quaternion qw,qx,qy,qz (R_world<-housing); instead of solving each row alone. On a "
                        "compass live --record file the options its '# replay:' line names (--site, --date, "
                        "--gravity, --mag-latency, --gyro-matrix, --gyro-scale-error, --accel-unit) are the defaults, "
                        "so the plain command writes the session's rows; one given here wins")
    p.add_argument("--gravity", type=limits.GRAVITY.option("--gravity"), metavar="G",
                   help="with --filter: what 1 g reads in the accelerometer's unit, in g when --accel-unit names one "
                        "(default: the median |a| of the recording's first quiet second; one beyond a factor 2 of "
                        "that is refused)")
    add_mag_latency_argument(p, with_filter=True)
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    add_rerun_option(p)
    add_read_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import BadInput

    if args.filter:  # the options a live record's '# replay:' line names are the defaults (--date's site too)
        from ..replay import replay_file

        if args.level:
            raise BadInput("--level cannot go with --filter: the filter needs the accelerometer's tilt")
        replay_file(args.calibration, args.recording, args.out, site=args.site, date=args.date, gravity=args.gravity,
                    mag_latency=args.mag_latency, gyro_matrix=args.gyro_matrix,
                    gyro_scale_error=args.gyro_scale_error, force=args.force, rerun=args.rerun, read_options=ReadOptions.from_args(args))
        return 0
    if args.date is not None and args.site is None:
        raise BadInput("--date needs --site LAT,LON[,ALT_M]: the date only chooses the field at a site")
    if args.gravity is not None:
        raise BadInput("--gravity goes with --filter (the per-row solution normalises each accelerometer row)")
    if args.mag_latency:
        raise BadInput("--mag-latency goes with --filter (the per-row solution has no gyro to turn the field with)")
    if args.gyro_matrix:
        raise BadInput("--gyro-matrix goes with --filter (the per-row solution uses no gyro)")
    if args.gyro_scale_error is not None:
        raise BadInput("--gyro-scale-error goes with --filter (the per-row solution uses no gyro)")
    attitude_file(args.calibration, args.recording, args.out, level=args.level, max_tilt_deg=args.max_tilt_deg,
                  accel_noise_g=args.accel_noise_g, force=args.force, site=args.site, date=args.date, rerun=args.rerun,
                  read_options=ReadOptions.from_args(args))
    return 0


def attitude_file(calibration, recording, out, *, level=False, max_tilt_deg=5.0, accel_noise_g=0.002, force=False,
                  site=None, date=None, rerun=None, read_options=None):
    """Solve one recording file into an attitude CSV (:func:`compass.recording.solve_recording`); returns the
    :class:`~compass.attitude.Attitude`.

    Raises
    ------
    RecordingError, BadInput, FileExistsError
        Bad input (exit status 2 on the command line).
    """
    from ..recording import solve_recording

    out = check_writable(out, force, inputs=(calibration, recording))
    rerun = check_rerun_target(rerun, force)
    solved = solve_recording(calibration, recording, level=level, max_tilt_deg=max_tilt_deg,
                             accel_noise_g=accel_noise_g, site=site, date=date, read_options=read_options)
    for text in solved.warnings:
        print(f"warning: {text}", file=sys.stderr)
    atomic_write_text(out, solved.to_csv())
    print(f"wrote {out} ({solved.summary()})" + (f"\n  note: {solved.extrapolated}" if solved.extrapolated else ""))
    if solved.disagreement():  # most headings untrustworthy: a warning, beside the others
        print(f"warning: {solved.disagreement()}", file=sys.stderr)
    if rerun is not None:
        from ..viz.attitude import record_attitude

        record_attitude(rerun, solved.attitude, solved.model, t_s=solved.columns.get("t_s"), raw=solved.raw,
                        accel=solved.accel, gyro=solved.gyro)
        print(f"wrote {rerun}")
    return solved.attitude
