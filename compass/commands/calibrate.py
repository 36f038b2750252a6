"""``compass calibrate REC.csv --out CAL.json``: fit, diagnose, write the calibration file."""

from __future__ import annotations

import json
from pathlib import Path

from ..io.atomic import atomic_write_text, check_writable
from ..io.fourflip import fourflip_from_table
from ..io.table import read_table
from ..io.tumble import tumble_from_table


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="calibrate from a recording and write a calibration file")
    p.add_argument("recording", help="recording CSV (four-flip: has flip_deg; 3-D platform: platform_z_deg; "
                                     "reference fields: bx_ref; tumble: mx,my,mz)")
    p.add_argument("--out", required=True, help="calibration JSON to write")
    p.add_argument("--method", choices=("ml", "harmonic", "patent"), default="ml",
                   help="ml: joint maximum likelihood (default); harmonic: seed formulas on harmonic fits; "
                        "patent: the seed exactly (lowest samples)")
    p.add_argument("--no-diagnose", action="store_true", help="skip the residual diagnosis loop")
    p.add_argument("--report", metavar="DIR", help="also write plots of fit and residuals into DIR")
    p.add_argument("--field-ut", type=float, default=None, help="|B| in uT (overrides '# field_ut:' metadata)")
    p.add_argument("--kind", choices=("fourflip", "platform3d", "reference", "tumble"), default=None, help="force the recording kind")
    p.add_argument("--ellipsoid", choices=("auto", "offset", "diagonal", "full"), default="auto",
                   help="tumble only: ellipsoid kind (default auto: the determined kind with the lowest BIC)")
    p.add_argument("--force", action="store_true", help="overwrite an existing calibration file")
    p.add_argument("--quiet", action="store_true", help="do not print the fit report")
    p.set_defaults(func=run)


def run(args) -> int:
    calibrate_file(args.recording, args.out, method=args.method, diagnose=not args.no_diagnose,
                   report=args.report, field_ut=args.field_ut, kind=args.kind, force=args.force, quiet=args.quiet,
                   ellipsoid=args.ellipsoid)
    return 0


def calibrate_file(recording, out, *, method="ml", diagnose=True, report=None, field_ut=None, kind=None,
                   force=False, quiet=False, ellipsoid="auto"):
    """Calibrate one recording file into a calibration file; returns the CalibrationResult.

    Raises
    ------
    RecordingError, BadInput, FileExistsError
        Bad input (exit status 2 on the command line).
    """
    from ..cli import BadInput

    out = check_writable(out, force)
    table = read_table(recording)
    if kind is None and table.has("flip_deg"):
        kind = "fourflip"
    elif kind is None and table.has("platform_z_deg"):
        kind = "platform3d"
    elif kind is None and any(c.endswith("bx_ref") for c in table.columns):
        kind = "reference"
    elif kind is None and all(table.has(c) for c in ("mx", "my", "mz")):
        kind = "tumble"
    if kind is None:
        raise BadInput(f"{recording}: cannot tell the recording kind from its columns "
                       f"({', '.join(table.columns)}); a four-flip recording has flip_deg, a 3-D platform one "
                       f"platform_z_deg, a reference-field one bx_ref, a tumble mx,my,mz")
    if field_ut is not None and not field_ut > 0:
        raise BadInput(f"--field-ut must be positive, got {field_ut}")
    _refuse_ignored_options(recording, kind, method=method, diagnose=diagnose, report=report, field_ut=field_ut,
                            ellipsoid=ellipsoid)
    if report is not None and Path(report).exists() and not Path(report).is_dir():
        raise BadInput(f"--report {report}: is a file, expected a folder")
    if kind == "tumble":
        return _calibrate_tumble(table, out, field_ut=field_ut, ellipsoid=ellipsoid, quiet=quiet, report=report)
    if kind in ("platform3d", "reference"):
        return _calibrate_other(kind, table, out, field_ut=field_ut, diagnose=diagnose, quiet=quiet)
    rec = fourflip_from_table(table)

    from calibrate import calibrate_fourflip

    result = calibrate_fourflip(rec, method=method, field_ut=field_ut, diagnose=diagnose,
                                progress=None if quiet else (lambda text: print(f"  ... {text}", flush=True)))
    if not quiet:
        print(result.report())
    atomic_write_text(out, json.dumps(result.to_json(), indent=2) + "\n")
    print(f"wrote {out}")
    if report:
        from calibrate.plots import plot_fit, plot_residuals

        folder = Path(report)
        used = result.used(rec)
        paths = [plot_fit(used, result, folder / "fit.png"),
                 plot_residuals(used, _residual_sets(rec, result), folder / "residuals.png", result.noise)]
        print("wrote " + ", ".join(str(p) for p in paths))
    return result


def _refuse_ignored_options(recording, kind, *, method, diagnose, report, field_ut, ellipsoid) -> None:
    """BadInput for an option the recording's kind would silently ignore (checked before any work)."""
    from ..cli import BadInput

    ignored = []
    if kind != "fourflip":
        ignored += ["--method"] * (method != "ml") + ["--report"] * (report is not None and kind != "tumble")
    if kind == "tumble" and not diagnose:
        ignored.append("--no-diagnose")  # the tumble fit always runs its diagnosis
    if kind == "reference" and field_ut is not None:
        ignored.append("--field-ut")
    if kind != "tumble" and ellipsoid != "auto":
        ignored.append("--ellipsoid")
    if ignored:
        raise BadInput(f"{recording}: a {kind} recording does not use {', '.join(ignored)}")


def _residual_sets(rec, result) -> dict:
    """Residuals before (base model) and after the diagnosis, or the one fit there is."""
    if not result.diagnosis or len(result.diagnosis["steps"]) < 2:
        return {result.method: result.residuals}
    from calibrate import calibrate_fourflip

    base = calibrate_fourflip(rec, method="ml", field_ut=result.field_ut, diagnose=False)
    return {"before (base model)": base.residuals, "after (" + ", ".join(result.diagnosis["effects"]) + ")": result.residuals}


def _calibrate_tumble(table, out, *, field_ut, ellipsoid, quiet, report=None):
    """Tumble recordings (SPEC section 2): ellipsoid, coverage, mag-to-accel rotation."""
    from calibrate.tumble import calibrate_tumble

    rec = tumble_from_table(table)
    field_ut = field_ut if field_ut is not None else table.metadata_float("field_ut")
    result = calibrate_tumble(rec.mag, rec.accel, kind=ellipsoid, field_ut=field_ut, n_repeats=rec.n_repeats,
                              t_s=rec.t_s, temp_c=rec.temp_c)
    if result.refused:
        from ..cli import BadInput

        raise BadInput(f"{table.path}: {result.refused}")
    if not quiet:
        print(result.report())
    atomic_write_text(out, json.dumps(result.to_json(), indent=2) + "\n")
    print(f"wrote {out}")
    if report:
        from calibrate.plots import plot_tumble

        print(f"wrote {plot_tumble(rec.mag, result, Path(report) / 'tumble.png')}")
    return result


def _calibrate_other(kind, table, out, *, field_ut, diagnose, quiet):
    """3-D platform (seed 001) and reference-field (seed 003) recordings: fit, report, write."""
    from ..cli import BadInput

    if kind == "platform3d":
        from calibrate.platform3d import NotIdentifiable as Undetermined
        from calibrate.platform3d import calibrate_platform3d as fit

        from ..io.platform3d import platform3d_from_table as parse
    else:
        from calibrate.reference import DegenerateReference as Undetermined
        from calibrate.reference import calibrate_reference as fit

        from ..io.reference import reference_from_table as parse
    try:
        result = fit(parse(table), diagnose=diagnose, **({"field_ut": field_ut} if kind == "platform3d" else {}))
    except Undetermined as exc:  # the recording cannot determine the model: bad input
        raise BadInput(str(exc)) from None
    if not quiet:
        print(result.report())
    atomic_write_text(out, json.dumps(result.to_json(), indent=2) + "\n")
    print(f"wrote {out}")
    return result
