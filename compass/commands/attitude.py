"""``compass attitude CAL.json REC.csv --out ATT.csv``: heading, pitch, roll per row, with quality.

Reads the calibration's sensor model and an attitude recording (SPEC section 2: ``t_s``, the
calibration's channel columns, optional ``ax,ay,az`` and ``gx,gy,gz``; known ``pitch_deg,
roll_deg`` columns are accepted as the tilt), solves every row (:func:`compass.attitude.solve_attitude`)
and writes the attitude CSV atomically.
"""

from __future__ import annotations

import sys

import numpy as np

from .. import limits
from ..io.atomic import atomic_write_text, check_writable
from ..io.table import ReadOptions, RecordingError, add_read_arguments, format_table, read_table
from ..io.units import check_accel_up, check_two_axis_tilt
from ..site import Site, reference_from_site, upside_down
from ..viz import add_rerun_option, check_rerun_target

_ACCEL = ("ax", "ay", "az")
_TILT = ("pitch_deg", "roll_deg")
_GYRO = ("gx", "gy", "gz")
_IGNORED = ("t_s", *_GYRO)
_FORMATS = {"in_range": "%d", "disturbed": "%d", "skipped": "%d", "t_s": "%.4f"}


_MAX_TILT_DEG = limits.Range(0.0, 90.0, "deg", hi_open=True)
"""--level: the largest tilt assumed (90 deg leaves no heading)."""


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
    p.add_argument("--max-tilt-deg", type=_MAX_TILT_DEG.option("--max-tilt-deg"), default=5.0,
                   help="with --level: the tilt the assumption allows, for heading_bound_deg (default 5)")
    p.add_argument("--site", metavar="LAT,LON[,ALT_M]",
                   help="where the recording was made (degrees, metres): the reference field and true north come "
                        "from the World Magnetic Model there (default: the calibration's site block, else the "
                        "recording's own quiet rows, magnetic heading only)")
    p.add_argument("--date", metavar="YYYY-MM-DD", help="with --site: the day of the recording (default today, UTC)")
    p.add_argument("--accel-noise-g", type=limits.ACCEL_NOISE_G.option("--accel-noise-g"), default=0.002,
                   help="accelerometer white noise per axis as a fraction of 1 g (default 0.002)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    add_rerun_option(p)
    add_read_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import BadInput

    if args.date is not None and args.site is None:
        raise BadInput("--date needs --site LAT,LON[,ALT_M]: the date only chooses the field at a site")
    attitude_file(args.calibration, args.recording, args.out, level=args.level, max_tilt_deg=args.max_tilt_deg,
                  accel_noise_g=args.accel_noise_g, force=args.force, site=args.site, date=args.date, rerun=args.rerun,
                  read_options=ReadOptions.from_args(args))
    return 0


def attitude_file(calibration, recording, out, *, level=False, max_tilt_deg=5.0, accel_noise_g=0.002, force=False,
                  site=None, date=None, rerun=None, read_options=None):
    """Solve one recording file into an attitude CSV; returns the :class:`~compass.attitude.Attitude`.

    The reference field is the site's: ``site`` (``"LAT,LON[,ALT_M]"`` or a :class:`compass.site.Site`)
    and ``date``, else the calibration's ``site`` block, else estimated from the recording.

    Raises
    ------
    RecordingError, BadInput, FileExistsError
        Bad input (exit status 2 on the command line).
    """
    from ..accel_alignment import accel_in_housing, housing_from_accel
    from ..attitude import ScaleMismatch, UnusableCalibration, solve_attitude
    from ..calibration_file import hemisphere_assumed, load
    from ..cli import BadInput
    from ..installed import accel_to_product

    out = check_writable(out, force)
    rerun = check_rerun_target(rerun, force)
    try:  # the options' ranges, for a caller in Python
        limits.ACCEL_NOISE_G.check(accel_noise_g, "--accel-noise-g")
        _MAX_TILT_DEG.check(max_tilt_deg, "--max-tilt-deg")
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    try:
        if site is not None and not isinstance(site, Site):
            site = Site.parse(site, date)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    try:
        cal = load(calibration)
    except ValueError as exc:
        raise BadInput(exc if str(calibration) in str(exc) else f"{calibration}: {exc}") from None
    model, tilt_sensor = cal.model, cal.tilt_sensor
    if model.noise is None:  # the calibration's fault, not the recording's (16.6)
        raise BadInput(f"{calibration}: the calibration has no noise_floor: the solution cannot be weighted nor "
                       f"its uncertainty propagated")
    source = "site"
    if site is None and cal.sections.get("site") is not None:
        site, source = cal.sections["site"], "calibration site"
    table = read_table(recording, read_options)
    table.ignore_unknown(set(model.channels) | set(_ACCEL) | set(_TILT) | set(_IGNORED) | {"temp_c"},
                         what=f"{calibration} (its channels: {', '.join(model.channels)})")
    raw = np.column_stack([table.column(name) for name in model.channels])
    if tilt_sensor is None:
        accel = _group(table, _ACCEL)
        if accel is not None:
            check_accel_up(accel, table.rows, where=table.path)
    else:  # a 3-D platform calibration: ax, ay[, az] are its tilt sensor's raw outputs
        tilt_raw = _group(table, tilt_sensor.columns)
        accel = tilt_sensor.up(tilt_raw)
    accel, bench_fix_applied = accel_in_housing(cal.data, accel)  # the bench's offsets undone, turned into H
    accel = accel_to_product(cal.data, accel)  # an installed file with an alignment: the product's frame
    tilt = _group(table, _TILT)
    if accel is not None:
        _check_rows(table, np.sum(accel**2, axis=1) > 0, "ax", "accelerometer reads zero: expected gravity")
    if tilt is not None:
        _check_rows(table, np.abs(tilt[:, 0]) <= 90.0, "pitch_deg", "pitch must be in [-90, 90] degrees")
    temp_c = table.column("temp_c") if table.has("temp_c") else None
    effect = model.temperature
    if effect is not None and effect.reference_c is None:
        temp_c = None  # a file written before effects carried their reference: the effect cannot be applied
    tilt_args = dict(accel=accel, pitch_deg=None if tilt is None else tilt[:, 0],
                     roll_deg=None if tilt is None else tilt[:, 1], level=level)
    try:
        reference = None if site is None else reference_from_site(
            site, field_ut=None if model.field_ut is None else 1.0, source=source)
        result = solve_attitude(model, raw, **tilt_args, reference=reference, accel_noise_g=accel_noise_g,
                                max_tilt_deg=max_tilt_deg, temp_c=temp_c)
    except UnusableCalibration as exc:
        raise BadInput(f"{calibration}: {exc}") from None
    except ScaleMismatch as exc:
        raise BadInput(f"{recording} does not fit {calibration}: {exc}") from None
    except np.linalg.LinAlgError as exc:  # the model's weighted solver: the calibration's numbers, not the rows
        raise BadInput(f"{calibration}: unusable calibration ({exc}): its noise_floor or directions are out of "
                       f"any sensible range") from None
    except ValueError as exc:
        raise BadInput(f"{recording}: {exc}") from None

    if tilt_sensor is not None and len(tilt_sensor.columns) == 2:  # judged against the dip the rows were solved with
        check_two_axis_tilt(tilt_sensor.upside_down_rows(tilt_raw, model.field(raw, temp_c)[0],
                                                         result.reference.dip_deg), len(raw), where=table.path)
    elif result.mode == "accelerometer":  # dips against a full up vector: a turned-over field shows
        flipped = upside_down(result.dip_deg, result.reference, bench_sign_ambiguous=hemisphere_assumed(cal.data))
        if flipped is not None:
            raise BadInput(f"{calibration}: {flipped}")
    columns = ({"t_s": table.column("t_s")} if table.has("t_s") else {}) | result.columns()
    metadata = {"calibration": calibration, "recording": recording, "mode": result.mode,
                "reference_field": result.reference.description}
    if result.heading_true_deg is not None:
        metadata["true_north"] = (f"heading_true_deg = heading_deg + declination {result.reference.declination_deg:+.3f} "
                                  f"deg (sigma {result.reference.declination_sigma_deg:.2f} deg in heading_true_sigma_deg)")
    if result.mode == "accelerometer":
        metadata["accel_noise_g"] = f"{accel_noise_g:g}"
        to_housing = housing_from_accel(cal.data)
        if to_housing is not None:
            from scipy.spatial.transform import Rotation

            angle = np.degrees(Rotation.from_matrix(to_housing).magnitude())
            metadata["accel_frame"] = (f"rotated into the housing by the calibration's mag_to_accel ({angle:.3f} deg)"
                                       + ("; the bench's offsets and Y/Z scales undone" if bench_fix_applied else ""))
    if result.mode == "level":
        metadata["max_tilt_deg"] = f"{max_tilt_deg:g}"
    if effect is not None:
        if temp_c is not None:
            metadata["temperature"] = f"compensated to {effect.reference_c:.2f} degC from temp_c"
        else:
            why = ("its temperature effect names no reference temperature (recalibrate)" if effect.reference_c is None
                   else f"{recording} has no temp_c column")
            metadata["temperature"] = f"NOT compensated: {why}"
            print(f"warning: the calibration's temperature effect is not applied: {why}", file=sys.stderr)
    if model.direction_covariance is None:
        metadata["note"] = "the calibration gives no direction covariance: sigmas count sensor noise only"
    if cal.data.get("method") == "patent":
        print(f"warning: {calibration} was made with --method patent (seed 000's rule as written, kept for comparison): "
              "its dip rule and tabulated response can be off by degrees and its sigmas count sensor noise only; "
              "calibrate with the default method for use", file=sys.stderr)
    linear_beyond = _linear_beyond(model, raw, temp_c)
    if linear_beyond:
        metadata["extrapolated"] = linear_beyond
    atomic_write_text(out, _format_csv(columns, metadata))
    print(f"wrote {out} ({len(raw)} rows, mode {result.mode}; {int(np.sum(result.disturbed))} disturbed against the "
          f"{result.reference.source} reference, {int(np.sum(~result.in_range))} out of calibrated range"
          f"{_skipped_note(result.skipped)})" + (f"\n  note: {linear_beyond}" if linear_beyond else ""))
    if rerun is not None:
        from ..viz.attitude import record_attitude

        record_attitude(rerun, result, model, t_s=columns.get("t_s"), raw=raw, accel=accel, gyro=_group(table, _GYRO))
        print(f"wrote {rerun}")
    return result


def _linear_beyond(model, raw, temp_c) -> str:
    """Words for the rows that read a linear channel beyond the field it was calibrated over ('' if none).

    Not in ``in_range`` (which flags nonlinear curves extrapolated): a line beyond its range is the
    same line, wrong only by a nonlinearity the bench could not see (:mod:`compass.response`).
    """
    x, _ = model.components(raw, temp_c)
    rows, names = np.zeros(len(raw), dtype=bool), []
    for c, (name, r) in enumerate(zip(model.channels, model.responses)):
        beyond = np.zeros(len(raw), dtype=bool) if r.nonlinear else r.beyond_range(x[:, c]) & np.isfinite(x[:, c])
        if beyond.any():
            rows |= beyond
            names.append(f"{name} (calibrated over {r.x_range[0]:.3g}..{r.x_range[1]:.3g})")
    if not rows.any():
        return ""
    return (f"{int(rows.sum())} rows read a linear channel beyond the field it was calibrated over: "
            f"{', '.join(names)}; extrapolated linearly (not flagged in in_range, which marks nonlinear responses "
            "extrapolated)")


def _skipped_note(skipped) -> str:
    """``, N skipped (reason k, ...)`` for rows never solved (``skipped`` column: the reason's code)."""
    from ..sample_check import SKIP_REASONS

    if skipped is None or not skipped.any():
        return ""
    codes, counts = np.unique(skipped[skipped > 0], return_counts=True)
    return (f", {int(counts.sum())} skipped (" + ", ".join(f"{SKIP_REASONS[c]} {k}" for c, k in zip(codes, counts))
            + "): angles nan, see the skipped column")


def _group(table, names) -> np.ndarray | None:
    """The columns ``names`` together, None when all are absent; RecordingError naming a missing one."""
    present = [n for n in names if table.has(n)]
    if not present:
        return None
    for name in names:
        if not table.has(name):
            raise RecordingError(table.path, f"has {', '.join(present)} but not '{name}': give all of "
                                             f"{', '.join(names)}", row=table.header_row, column=name)
    return np.column_stack([table.column(n) for n in names])


def _check_rows(table, ok: np.ndarray, column: str, message: str) -> None:
    if not np.all(ok):
        raise RecordingError(table.path, message, row=int(table.rows[np.argmin(ok)]), column=column)


def _format_csv(columns: dict, metadata: dict) -> str:
    """CSV text: ``# key: value`` lines, a header, one row per sample (formatted block by block)."""
    return format_table(columns, metadata, _FORMATS)
