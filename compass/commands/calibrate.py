"""``compass calibrate REC.csv --out CAL.json``: fit, diagnose, write the calibration file.

The command line layer on top of both packages: it loops over :data:`calibrate.kinds.KINDS` (each
kind's column sniffer, reader and calibrator) and writes through :func:`compass.calibration.save`.
Only the command layer (``compass/commands/``) imports ``calibrate``.
"""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path

from .. import limits
from ..io.atomic import check_writable
from ..io.progress import working
from ..io.table import ReadOptions, add_read_arguments, read_table
from ..viz import add_rerun_option, check_rerun_target

AXIS_TOLERANCE_DEG = 10.0
"""``--axis-tolerance-deg``'s default: :data:`calibrate.health.AXIS_TOLERANCE_DEG` (not imported here,
so ``compass --help`` stays fast; a test holds the two equal)."""
_ANGLE_DEG = limits.Range(0.0, 180.0, "deg", lo_open=True, hi_open=True)
"""``--axis-tolerance-deg`` and ``--direction-accuracy-deg``: an angle between two directions."""


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="calibrate from a recording and write a calibration file")
    p.add_argument("recording", help="recording CSV (four-flip: has flip_deg; 3-D platform: platform_z_deg; "
                                     "reference fields: bx_ref; tumble: mx,my,mz, and with gx,gy,gz, ax,ay,az and "
                                     "t_s the gyro's turns pin soft iron and mag-to-accel where the ellipsoid alone "
                                     "falls back or the motion was too fast for the accelerometer, and the "
                                     "magnetometer's latency against the gyro is fitted)")
    p.add_argument("--out", required=True, help="calibration JSON to write")
    p.add_argument("--method", choices=("ml", "harmonic", "patent"), default="ml",
                   help="ml: joint maximum likelihood (default); harmonic: seed formulas on harmonic fits; "
                        "patent: the seed exactly (lowest samples)")
    p.add_argument("--no-diagnose", action="store_true", help="skip the residual diagnosis loop")
    p.add_argument("--report", metavar="DIR", help="also write plots of fit and residuals into DIR")
    p.add_argument("--field-ut", type=limits.FIELD_UT.option("--field-ut"),
                   default=None, help="|B| in uT (overrides '# field_ut:' metadata)")
    p.add_argument("--kind", default=None, help="force the recording kind (fourflip, platform3d, reference, tumble, "
                                                "or any kind in calibrate.kinds.KINDS)")
    p.add_argument("--ellipsoid", choices=("auto", "offset", "diagonal", "full"), default="auto",
                   help="tumble only: ellipsoid kind (default auto: the determined kind with the lowest BIC)")
    p.add_argument("--base", metavar="BENCH.json",
                   help="the recording is an installation (the module turned in its product, a tumble or a swing): "
                        "calibrate the product's iron on top of this bench calibration")
    p.add_argument("--site", metavar="LAT,LON[,ALT_M]", help="with --base: where the installation was recorded "
                   "(the WMM's |B| and dip; written into the file for the runtime); four-flip: where the bench "
                   "stood (its hemisphere, which the data cannot tell, and the WMM check of the dip)")
    p.add_argument("--date", metavar="YYYY-MM-DD", help="with --site: the day (default: a four-flip recording's "
                                                        "'# date:', else today, UTC)")
    p.add_argument("--axis-tolerance-deg", type=_ANGLE_DEG.option("--axis-tolerance-deg"), default=AXIS_TOLERANCE_DEG, metavar="DEG",
                   help="warn when a channel's sensing direction is farther than this from the nearest housing axis "
                        f"(a gross mounting error; default {AXIS_TOLERANCE_DEG:g}; raise it for oblique designs)")
    p.add_argument("--direction-accuracy-deg", type=_ANGLE_DEG.option("--direction-accuracy-deg"), default=None, metavar="DEG",
                   help="warn when a channel's direction sigma is larger than this, with the signal-to-noise "
                        "ratio that would reach it")
    p.add_argument("--force", action="store_true", help="overwrite an existing calibration file")
    p.add_argument("--quiet", action="store_true", help="do not print the fit report")
    add_rerun_option(p)
    add_read_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    target = check_rerun_target(args.rerun, args.force)
    read_options = ReadOptions.from_args(args)
    result = calibrate_file(args.recording, args.out, method=args.method, diagnose=not args.no_diagnose,
                            report=args.report, field_ut=args.field_ut, kind=args.kind, force=args.force,
                            quiet=args.quiet, ellipsoid=args.ellipsoid, read_options=read_options,
                            base=args.base, site=args.site, date=args.date,
                            axis_tolerance_deg=args.axis_tolerance_deg,
                            direction_accuracy_deg=args.direction_accuracy_deg)
    if target is not None:
        from ..viz.calibration import record_calibration

        record_calibration(target, args.recording, result, base_residuals=_base_residuals(result),
                           read_options=read_options)
        print(f"wrote {target}")
    return 0


def _base_residuals(result):
    """Four-flip: ``recording -> the base model's residuals`` (the replay's "before"), None without effects."""
    if result.calibration_kind != "fourflip":
        return None
    return lambda recording: result.base_residuals


OPTIONS = {"method": ("--method", "ml"), "diagnose": ("--no-diagnose", True), "field_ut": ("--field-ut", None),
           "ellipsoid": ("--ellipsoid", "auto"), "base": ("--base", None), "site": ("--site", None),
           "date": ("--date", None), "axis_tolerance_deg": ("--axis-tolerance-deg", AXIS_TOLERANCE_DEG),
           "direction_accuracy_deg": ("--direction-accuracy-deg", None)}
"""Calibrator option -> (command-line flag, default): passed to the kinds whose calibrator takes it."""


def calibrate_file(recording, out, *, method="ml", diagnose=True, report=None, field_ut=None, kind=None,
                   force=False, quiet=False, ellipsoid="auto", read_options=None, base=None, site=None,
                   date=None, axis_tolerance_deg=AXIS_TOLERANCE_DEG, direction_accuracy_deg=None):
    """Calibrate one recording file into a calibration file; returns the Calibration.

    The kind comes from the columns (:func:`calibrate.kinds.sniff`) unless ``kind`` names one; its
    calibrator gets the options its constructor takes, and an option it would ignore is refused.

    Raises
    ------
    RecordingError, BadInput, FileExistsError
        Bad input (exit status 2 on the command line).
    """
    from calibrate.contract import CannotCalibrate
    from calibrate.session import find_kind

    from ..calibration import CalibrationFileError, save
    from ..cli import BadInput

    out = check_writable(out, force, inputs=(recording, base))
    table = read_table(recording, read_options)
    _check_time_steps(table)
    if base is not None and kind is None:
        kind = "installed"  # --base: the recording is an installation on top of that bench calibration
    try:
        found = find_kind(table, recording, kind)
    except CannotCalibrate as exc:
        raise BadInput(str(exc)) from None
    if field_ut is not None:  # the option's range, for a caller in Python
        try:
            limits.FIELD_UT.check(field_ut, "--field-ut")
        except ValueError as exc:
            raise BadInput(str(exc)) from None
    for flag, value in (("--axis-tolerance-deg", axis_tolerance_deg),
                        ("--direction-accuracy-deg", direction_accuracy_deg)):
        try:
            if value is not None:
                _ANGLE_DEG.check(value, flag)
        except ValueError as exc:
            raise BadInput(str(exc)) from None
    given = {"method": method, "diagnose": diagnose, "field_ut": field_ut, "ellipsoid": ellipsoid, "base": base,
             "site": site, "date": date, "axis_tolerance_deg": axis_tolerance_deg,
             "direction_accuracy_deg": direction_accuracy_deg}
    takes = found.calibrator.options()
    ignored = [OPTIONS[name][0] for name, value in given.items() if name not in takes and value != OPTIONS[name][1]]
    ignored += ["--report"] * (report is not None and not found.calibrator.plot_files)
    if ignored:
        raise BadInput(f"{recording}: a {found.name} recording does not use {', '.join(ignored)}")
    if report is not None and Path(report).exists() and not Path(report).is_dir():
        raise BadInput(f"--report {report}: is a file, expected a folder")
    for name in found.calibrator.plot_files if report is not None else ():
        check_writable(Path(report) / name, force)  # plots are never overwritten without --force either
    options = {name: value for name, value in given.items() if name in takes}
    if "progress" in takes and not quiet:
        options["progress"] = lambda text: print(f"  ... {text}", flush=True)
    try:
        with working(f"calibrating {Path(recording).name} ({found.name})") if "progress" not in options else nullcontext():
            rec = found.read(table)
            del table  # the fit needs the recording only, not the table's copy of every cell beside it
            result = found.calibrator(**options).fit(rec)
        save(out, result.to_json(), force=force)
    except CannotCalibrate as exc:  # the recording cannot determine the model: bad input
        raise BadInput(str(exc)) from None
    except CalibrationFileError as exc:  # never write a calibration the runtime would refuse
        raise BadInput(f"{recording}: the fit gives an unusable calibration, not written: {exc}") from None
    if not quiet:
        print(result.report())
    print(f"wrote {out}")
    if report:
        paths = result.plots(rec, report)
        print("wrote " + ", ".join(str(p) for p in paths))
    return result


def _check_time_steps(table) -> None:
    """RecordingError when a recording with a gyro has a ``t_s`` that does not count seconds between samples, as the
    runtime refuses it (:func:`compass.io.streams.time_steps_verdict` against the filter's ``max_gap_s``): a time in
    milliseconds read as seconds (``--columns t_s=time_ms``) steps 1000 times too far, and a gyro-aided fit would turn
    by as much.  Without a gyro ``t_s`` is no sample clock (a four-flip bench's rows are seconds apart)."""
    from ..filter import FilterConfig
    from ..io.streams import time_steps_verdict
    from ..io.table import RecordingError

    if not (table.has("t_s") and table.has("gx")):
        return
    wrong = time_steps_verdict(table.column("t_s"), FilterConfig.max_gap_s)
    if wrong is not None:
        column = table.original.get("t_s", "t_s")
        raise RecordingError(table.path, f"{wrong}: a time in ms is read with --columns t_ms={column} (t_us=: in us), "
                                         "or from a header 'Time (ms)'", row=table.header_line, column=column)
