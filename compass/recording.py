"""A whole attitude recording solved: the calibration file and the recording file in, the attitude table out.

:func:`solve_recording` is what ``compass attitude`` runs, without the terminal: it reads the
calibration (:func:`compass.calibration.load`) and the recording (SPEC section 2: ``t_s``, the
calibration's channel columns, optional ``ax,ay,az`` and ``gx,gy,gz``; known ``pitch_deg,
roll_deg`` columns are accepted as the tilt), turns the accelerometer into the model's frame
(:meth:`compass.calibration.ImuCorrection.in_model_frame`), solves every row
(:func:`compass.attitude.solve_attitude`) against the site's reference field and returns a
:class:`SolvedRecording`: the attitude, its CSV (:meth:`SolvedRecording.to_csv`) and what to tell
the user.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import limits
from .errors import BadInput
from .io.table import RecordingError, format_table, read_table
from .io.units import check_accel_up, check_two_axis_tilt
from .iron_uncertainty import undetermined_words
from .site import Site, reference_from_site, upside_down

__all__ = ["SolvedRecording", "solve_recording"]

ACCEL = ("ax", "ay", "az")
TILT = ("pitch_deg", "roll_deg")
GYRO = ("gx", "gy", "gz")
_IGNORED = ("t_s", *GYRO)
_FORMATS = {"in_range": "%d", "disturbed": "%d", "skipped": "%d", "t_s": "%.4f"}


@dataclass(frozen=True, eq=False)
class SolvedRecording:
    """A recording solved row by row.

    Attributes
    ----------
    attitude : compass.attitude.Attitude
    model : compass.model.SensorModel
        The calibration's sensor model the rows were solved with.
    columns : dict of str to ndarray
        The attitude CSV's columns (``t_s`` first when the recording has it).
    metadata : dict of str to str
        The CSV's ``# key: value`` lines: what was assumed and applied.
    warnings : list of str
        What the user must be told beside the file (the calibration's temperature effect not
        applied, a ``patent`` calibration).
    extrapolated : str
        Words for rows that read a linear channel beyond its calibrated field ("" if none).
    raw : ndarray, shape (n, c)
        The channel outputs, in the calibration's channel order.
    accel : ndarray, shape (n, 3), or None
        The accelerometer in the model's frame (or the tilt sensor's up vector).
    gyro : ndarray, shape (n, 3), or None
        The recording's ``gx,gy,gz`` as read (None unless all three are there: they are not solved with).
    """

    attitude: object
    model: object
    columns: dict
    metadata: dict
    warnings: list = field(default_factory=list)
    extrapolated: str = ""
    raw: np.ndarray | None = None
    accel: np.ndarray | None = None
    gyro: np.ndarray | None = None

    def to_csv(self) -> str:
        """The attitude CSV: ``# key: value`` lines, a header, one row per sample."""
        return format_table(self.columns, self.metadata, _FORMATS)

    def summary(self) -> str:
        """One line: rows, mode, disturbed and out-of-range counts, rows skipped and why."""
        result = self.attitude
        return (f"{len(self.raw)} rows, mode {result.mode}; {int(np.sum(result.disturbed))} disturbed against the "
                f"{result.reference.source} reference, {int(np.sum(~result.in_range))} out of calibrated range"
                f"{_skipped_note(result.skipped)}")


    def disagreement(self, share: float = 0.8) -> str:
        """Why most rows were flagged disturbed, in words, when at least ``share`` of them were; else "".

        A ``--site`` whose WMM field the recording does not read (another place, or a simulated field)
        flagged every row with no reason given: the field the rows read is set beside the reference's.
        """
        result = self.attitude
        disturbed = np.asarray(result.disturbed, dtype=bool)
        if disturbed.size < 10 or disturbed.mean() < share:
            return ""
        ref = result.reference
        ratio = np.nanpercentile(result.field_ratio, [10, 50, 90])
        dip = np.nanpercentile(result.dip_deg, [10, 50, 90])
        check = ("is the site (and --date) where the recording was made, and the calibration this sensor's?"
                 if ref.source == "site" else "iron near the module, another sensor's calibration, or channels swapped or "
                 "negated against the calibration's (--columns)? Their headings are not to be trusted")
        # the median says a reference the rows do not read (another site); the 10-90 % spread, rows that
        # scatter about a reference taken from themselves (iron turning with the module)
        return (f"{100 * disturbed.mean():.0f} % of the rows disagree with the {ref.source} reference: they read "
                f"|B| {ratio[1]:.3f} of its ({ratio[0]:.3f}-{ratio[2]:.3f}) and a dip of {dip[1]:.1f} deg "
                f"({dip[0]:.1f}-{dip[2]:.1f}) against its {ref.dip_deg:.1f} deg (median, 10-90 % of rows); {check}")


def solve_recording(calibration, recording, *, level=False, max_tilt_deg=5.0, accel_noise_g=0.002, site=None,
                    date=None, read_options=None) -> SolvedRecording:
    """Solve one recording file with one calibration file.

    Parameters
    ----------
    calibration : str or Path
        The calibration file.
    recording : str or Path
        The attitude recording.
    level : bool
        No accelerometer: assume pitch = roll = 0 and bound the heading error a tilt up to
        ``max_tilt_deg`` could cause.
    max_tilt_deg : float
        In [0, 90), degrees.
    accel_noise_g : float
        Accelerometer white noise per axis, fraction of 1 g (> 0).
    site : str or compass.site.Site, optional
        ``"LAT,LON[,ALT_M]"``: the reference field and true north from the WMM there (with
        ``date``); default the calibration's ``site`` block, else the recording's own quiet rows.
    date : str, optional
        ``YYYY-MM-DD`` with ``site``.
    read_options : compass.io.table.ReadOptions, optional

    Returns
    -------
    SolvedRecording

    Raises
    ------
    BadInput, RecordingError
        Bad input, naming the file (and row and column).
    """
    from .attitude import ScaleMismatch, UnusableCalibration, solve_attitude
    from .calibration import load

    try:  # the options' ranges (compass.limits), for a caller in Python
        limits.ACCEL_NOISE_G.check(accel_noise_g, "--accel-noise-g")
        limits.MAX_TILT_DEG.check(max_tilt_deg, "--max-tilt-deg")
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
    if site is None and cal.site is not None:
        site, source = cal.site, "calibration site"
    table = read_table(recording, read_options)
    table.ignore_unknown(set(model.channels) | set(ACCEL) | set(TILT) | set(_IGNORED) | {"temp_c"},
                         what=f"{calibration} (its channels: {', '.join(model.channels)})")
    raw = np.column_stack([table.column(name) for name in model.channels])
    if tilt_sensor is None:
        accel = table.group(ACCEL)
        if accel is not None:
            table.check_dead_axis(ACCEL)
            check_accel_up(accel, table.rows, where=table.path)
    else:  # a 3-D platform calibration: ax, ay[, az] are its tilt sensor's raw outputs
        tilt_raw = table.group(tilt_sensor.columns)
        accel = tilt_sensor.up(tilt_raw)
    # the bench's offsets undone, turned into H (and an installed file's product frame)
    accel, bench_fix_applied = cal.imu.in_model_frame(accel)
    accel = model.corrected_accel(accel)  # a tumble's own accelerometer calibration, as the filter applies it
    tilt = table.group(TILT)
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
        flipped = upside_down(result.dip_deg, result.reference, bench_sign_ambiguous=cal.provenance.hemisphere_assumed)
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
        to_housing = cal.imu.to_housing
        if to_housing is not None:
            from scipy.spatial.transform import Rotation

            angle = np.degrees(Rotation.from_matrix(to_housing).magnitude())
            metadata["accel_frame"] = (f"rotated into the housing by the calibration's mag_to_accel ({angle:.3f} deg)"
                                       + ("; the bench's offsets and Y/Z scales undone" if bench_fix_applied else ""))
    if result.mode == "level":
        metadata["max_tilt_deg"] = f"{max_tilt_deg:g}"
    warnings = []
    if effect is not None:
        if temp_c is not None:
            metadata["temperature"] = f"compensated to {effect.reference_c:.2f} degC from temp_c"
        else:
            why = ("its temperature effect names no reference temperature (recalibrate)" if effect.reference_c is None
                   else f"{recording} has no temp_c column")
            metadata["temperature"] = f"NOT compensated: {why}"
            warnings.append(f"the calibration's temperature effect is not applied: {why}")
    if model.calibration_uncertainty is None:
        metadata["note"] = "the calibration gives no uncertainty of its own: sigmas count sensor noise only"
    undetermined = undetermined_words(model.calibration_uncertainty, model.field_norm, model.dip_deg)
    if undetermined is not None:
        metadata["note"] = "heading_sigma_deg counts stated priors where the calibration left a part undetermined"
        warnings.append(undetermined)
    if cal.provenance.method == "patent":
        warnings.append(f"{calibration} was made with --method patent (seed 000's rule as written, kept for "
                        "comparison): its dip rule and tabulated response can be off by degrees and its sigmas count "
                        "sensor noise only; calibrate with the default method for use")
    linear_beyond = _linear_beyond(model, raw, temp_c, result.skipped)
    if linear_beyond:
        metadata["extrapolated"] = linear_beyond
    gyro = np.column_stack([table.column(n) for n in GYRO]) if all(table.has(n) for n in GYRO) else None
    return SolvedRecording(result, model, columns, metadata, warnings, linear_beyond, raw, accel, gyro)


def _linear_beyond(model, raw, temp_c, skipped) -> str:
    """Words for the rows that read a linear channel beyond the field it was calibrated over ('' if none).

    Not in ``in_range`` (which flags nonlinear curves extrapolated): a line beyond its range is the
    same line, wrong only by a nonlinearity the bench could not see (:mod:`compass.response`).  Rows
    ``skipped`` (non-zero: never solved, :data:`compass.sample_check.SKIP_REASONS`; None: none) extrapolate nothing.
    """
    x, _ = model.components(raw, temp_c)
    solved = np.ones(len(raw), dtype=bool) if skipped is None else np.asarray(skipped) == 0
    rows, names = np.zeros(len(raw), dtype=bool), []
    for c, (name, r) in enumerate(zip(model.channels, model.responses)):
        beyond = np.zeros(len(raw), dtype=bool) if r.nonlinear else r.beyond_range(x[:, c]) & np.isfinite(x[:, c])
        beyond &= solved
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
    from .sample_check import SKIP_REASONS

    if skipped is None or not skipped.any():
        return ""
    codes, counts = np.unique(skipped[skipped > 0], return_counts=True)
    return (f", {int(counts.sum())} skipped (" + ", ".join(f"{SKIP_REASONS[c]} {k}" for c, k in zip(codes, counts))
            + "): angles nan, see the skipped column")



def _check_rows(table, ok: np.ndarray, column: str, message: str) -> None:
    if not np.all(ok):
        raise RecordingError(table.path, message, row=int(table.rows[np.argmin(ok)]), column=column)
