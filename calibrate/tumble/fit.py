"""The tumble calibration: ellipsoid, diagnosis, alignment, refusal (:func:`calibrate_tumble`, :class:`TumbleCalibrator`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from compass.axes import MIN_SIGNED_DIP_DEG, axes_from_gyro, check_axes
from compass.io.tumble import TumbleRecording

from ..contract import Calibrator, CannotCalibrate, metadata_field_ut
from ..health import AXIS_TOLERANCE_DEG, DEAD_SIGMAS, ChannelHealth, check_channels
from ..health import to_json as health_json
from ..noise import lattice_step, second_difference_sigma, second_differences
from ..site_field import compare_with_site
from .accelerometer import NoAccelCalibration, fit_accelerometer
from .alignment import MAX_ANGLE_WIDENING, field_gravity_angles, fit_misalignment, refine_jointly, static_mask
from .diagnosis import NOT_CONVERGED_WARNING, UNEXPLAINED_WARNING, diagnose_tumble
from .ellipsoid import fit_ellipsoid
from .gyro import falls_back, with_gyro
from .motion import fast_motion
from .result import TumbleResult

def _axis_noise(x: np.ndarray) -> np.ndarray:
    """White-noise sigma of each axis from second differences of consecutive samples, shape (3,),
    Sheppard's on integer codes (:func:`calibrate.noise.second_difference_sigma`)."""
    return np.asarray(second_difference_sigma(second_differences(x), lattice_step(x)), dtype=float)


def _noise_floor(x: np.ndarray, axis_noise: np.ndarray | None = None) -> float:
    """Per-axis white-noise sigma from second differences of consecutive samples (median over axes);
    ``axis_noise`` is :func:`_axis_noise` of ``x`` when the caller has it."""
    return float(np.median(_axis_noise(x) if axis_noise is None else axis_noise))


AXES = ("mx", "my", "mz")


def require_varying_axes(path, mag: np.ndarray, axis_noise: np.ndarray | None = None) -> None:
    """Refuse a tumble with an axis that never varied beyond its noise (a dead sensor, or never turned).

    An axis's variation is its readings' spread less the white noise in quadrature, as the amplitude
    of a sinusoid (sqrt(2) times the spread); it must be :data:`calibrate.health.DEAD_SIGMAS` noise
    sigmas at least.  A live axis in any tumble varies by tens of percent of |B|, hundreds of sigmas.

    ``axis_noise`` is :func:`_axis_noise` of ``mag`` when the caller has it (it is computed otherwise).

    Raises
    ------
    CannotCalibrate
        Naming the axis, its spread and its noise.
    """
    mag = np.asarray(mag, float)
    if len(mag) < 3:
        return
    noise = _axis_noise(mag) if axis_noise is None else axis_noise
    spread = np.std(mag, axis=0)
    for name, s, n in zip(AXES, spread, noise):
        varied = np.sqrt(2.0 * max(s**2 - n**2, 0.0))
        if not varied >= DEAD_SIGMAS * n:
            raise CannotCalibrate(f"{path}: column '{name}' never varied beyond its noise (spread {s:.3g}, white "
                                  f"noise {n:.3g} recording units): a dead or disconnected sensor, or a motion that "
                                  "never turned that axis through the field")


def channel_health(result: TumbleResult, mag: np.ndarray, axis_noise: np.ndarray | None = None) -> list[ChannelHealth]:
    """Each raw axis's response to the whole field, its noise and sensing direction (:mod:`calibrate.health`).

    Raw axis i reads ``row_i(S^-1) . m`` plus its hard iron, so its response to the whole field is
    ``|row_i(S^-1)| |m|``; its sigma is taken as a sinusoid amplitude's over the samples,
    ``noise sqrt(2 / n)``.  The axis's direction in the housing (the accelerometer's frame) is
    ``mag_to_accel`` applied to the axis, when fitted: the symmetric soft iron is left out, since it
    also holds the product's iron, which shears the axes without any mounting error (the tumble
    simulator's 8 % soft iron turns them by up to 9 deg).  Without a fitted rotation the tumble fixes
    no housing frame and no axis angle is judged.  ``axis_noise`` is :func:`_axis_noise` of ``mag`` when
    the caller has it.
    """
    rows = np.linalg.inv(result.soft_iron)
    turn = result.mag_to_accel
    noise = _axis_noise(np.asarray(mag, float)) if axis_noise is None else axis_noise
    out = []
    for i, (name, row, n) in enumerate(zip(AXES, rows, noise)):
        direction = None if turn is None else turn[:, i]
        out.append(ChannelHealth(name, float(np.linalg.norm(row)) * result.field_norm,
                                 float(n * np.sqrt(2.0 / len(mag))), float(n), direction))
    return out


def calibrate_tumble(mag: np.ndarray, accel: np.ndarray | None = None, *, ellipsoid: str = "auto",
                     field_ut: float | None = None, n_repeats: int = 0, t_s: np.ndarray | None = None,
                     temp_c: np.ndarray | None = None, site_dip_deg: float | None = None,
                     axis_noise: np.ndarray | None = None) -> TumbleResult:
    """Calibrate hard and soft iron (and the magnetometer-accelerometer rotation) from a tumble.

    Parameters
    ----------
    mag : ndarray, shape (n, 3)
        Raw magnetometer, recording units, magnetometer frame; repeated values already removed
        (:func:`compass.io.tumble.read_tumble` does that).
    accel : ndarray, shape (n, 3), optional
        Accelerometer at the same rows (specific force), any unit.  With ``t_s``, its own calibration is fitted on
        its still rows first (:func:`calibrate.tumble.accelerometer.fit_accelerometer`) and everything after takes
        the corrected rows as gravity.
    ellipsoid : {"auto", "offset", "diagonal", "full"}
    field_ut : float, optional
        Known |B|; the file's ``soft_iron`` then gives microtesla.
    n_repeats : int
        Rows dropped upstream as repeats (reported only).
    t_s, temp_c : ndarray, shape (n,), optional
        Time (s) and sensor temperature (degC) of each sample: the residual diagnosis then
        examines a drifting and a temperature-dependent hard iron too.
    site_dip_deg : float, optional
        The site's dip (the recording's site metadata): a field pointing the other way is refused.
    axis_noise : ndarray, shape (3,), optional
        Each axis's white-noise sigma of ``mag`` (:func:`_axis_noise`), when the caller has computed it.

    Returns
    -------
    TumbleResult
        Refused (``refused`` says why) when every kind is degenerate, or when the residual
        diagnosis leaves structure in |m| unexplained and, with an accelerometer, the calibrated
        field agrees worse with gravity than the raw readings (:func:`_widening`), or when the
        magnetometer's axes are left-handed against the accelerometer's and the site says which way
        the field points (:func:`compass.axes.check_axes`; without a site it is a warning naming the axis).

    Examples
    --------
    >>> from compass.sim.tumble import simulate_tumble
    >>> sim = simulate_tumble(seed=1, n=1500)
    >>> res = calibrate_tumble(sim.mag, sim.accel)
    >>> res.ellipsoid, bool(abs(res.field_norm - 50) < 5)
    ('full', True)
    """
    if field_ut is not None and not field_ut > 0:
        raise ValueError(f"field_ut must be positive, got {field_ut}")
    mag = raw = np.asarray(mag, dtype=float)
    accel_cal, accel_words = _accelerometer(accel, t_s)
    if accel_cal is not None:
        accel = accel_cal.apply(accel)
    noise = _noise_floor(mag, axis_noise)
    chosen, candidates, coverage = fit_ellipsoid(mag, ellipsoid)
    warnings = []
    if coverage.missing:
        warnings.append("incomplete coverage: " + coverage.words())
    full = candidates[-1]
    if ellipsoid == "auto" and chosen.ellipsoid != "full":
        why = full.reason or "the BIC prefers the simpler kind"
        warnings.append(f"used the {chosen.ellipsoid} kind: the full ellipsoid is not determined ({why})"
                        if not full.determined else f"used the {chosen.ellipsoid} kind ({why})")
    if chosen.degenerate:
        refused = (f"no usable calibration: no ellipsoid kind is determined, and the simplest ({chosen.ellipsoid}) is "
                   f"{chosen.reason}")
        return TumbleResult(chosen, candidates, coverage, None, field_ut, noise, len(mag), n_repeats,
                            tuple(warnings + [refused]), refused, accelerometer=accel_cal,
                            accelerometer_words=accel_words)
    if not chosen.determined:
        warnings.append(f"the {chosen.ellipsoid} kind is poorly determined: {chosen.reason}")
    n_out = int(np.count_nonzero(~chosen.inliers))
    if n_out > 0.2 * len(mag):
        warnings.append(f"{n_out} of {len(mag)} samples ({100 * n_out / len(mag):.0f} %) were rejected as "
                        "disturbed: the field around the device was not constant")
    offset_rel = np.linalg.norm(chosen.hard_iron) / chosen.field_norm
    if offset_rel > 3.0:
        warnings.append(f"hard iron is {offset_rel:.1f} times the field: the magnetometer may be near saturation")

    # effects the ellipsoid lacks are claimed first; everything after works on the readings they correct
    diagnosis = diagnose_tumble(mag, chosen, t_s=t_s, temp_c=temp_c, accel=accel, missing=coverage.missing)
    chosen, mag = diagnosis.fit, diagnosis.raw_at_reference
    if diagnosis.block["unexplained"]:
        warnings.append(UNEXPLAINED_WARNING)
    misalignment = None
    if accel is not None:
        keep = chosen.inliers
        accel = np.asarray(accel, dtype=float)
        mag_kept, accel_kept = chosen.calibrated(mag[keep]), accel[keep]
        misalignment = _unless_fast(fit_misalignment(mag_kept, accel_kept), mag_kept, accel_kept, t_s, keep, warnings)
        if misalignment is not None and coverage.missing and misalignment.rotation is not None:
            warnings.append("no magnetometer-accelerometer rotation fitted: with part of the sphere missing it "
                            "trades off against the hard iron; frames taken as aligned")
            misalignment = replace(misalignment, rotation=None, rotvec_deg=np.full(3, np.nan),
                                   rotvec_sigma_deg=np.full(3, np.nan),
                                   withheld="with part of the sphere missing it trades off against the hard iron")
        if misalignment is not None:
            chosen, misalignment = refine_jointly(chosen, mag, accel, misalignment)
            diagnosis = diagnosis.with_alignment(misalignment, chosen)
            chosen = diagnosis.fit
        else:
            warnings.append("fewer than 20 quasi-static samples: no magnetometer-accelerometer alignment, no dip")
        keep = chosen.inliers
        axes = check_axes(accel[keep], chosen.calibrated(mag[keep]), site_dip_deg=site_dip_deg, note_upward=True,
                          rotation=None if misalignment is None or misalignment.rotation is None
                          else misalignment.rotation.as_matrix())
        if axes is not None:
            if site_dip_deg is not None:
                return TumbleResult(chosen, candidates, coverage, misalignment, field_ut, noise, len(mag), n_repeats,
                                    tuple(warnings + [axes.text]), axes.text, diagnosis, accelerometer=accel_cal,
                                    accelerometer_words=accel_words)
            warnings.append(axes.text)
    warnings += not_converged(chosen, diagnosis)
    # the field changed partway: structure in |m| that no effect explains, and gravity agrees less with the result
    changed = diagnosis.block["unexplained"] and misalignment is not None
    refused = _widening(raw, accel, chosen.calibrated(mag), misalignment.rotation) if changed else ""
    return TumbleResult(chosen, candidates, coverage, misalignment, field_ut, noise, len(mag), n_repeats,
                        tuple(warnings + ([refused] if refused else [])), refused, diagnosis, accelerometer=accel_cal,
                        accelerometer_words=accel_words)


def not_converged(fit, diagnosis) -> list[str]:
    """The warning (one, or none) for a final fit that stopped short of its minimum: the file's ellipsoid ``fit`` (the
    joint fit with the rotation to the housing, when made) or the diagnosis's final fit, whose statistics the report
    prints.  A fit stopped at its evaluation limit at its minimum in fact is converged
    (:func:`calibrate.tumble.ellipsoid.plain_fit`); one still moving is not, and its values and sigmas are not the
    data's: the export refuses it (the production class ``not_converged``)."""
    stats = diagnosis.statistics
    stopped = [f"{what}: {message}" for what, ok, message in (
        ("the ellipsoid", fit.success, fit.message), ("the diagnosis's final fit", stats.success, stats.message))
        if not ok]
    if not stopped:
        return []
    return [f"{NOT_CONVERGED_WARNING} ({'; '.join(stopped)}): its values are not at the data's minimum and their "
            "sigmas do not hold; do not use it as it is"]


COVERED_DEG = 10.0
"""The fitted magnetometer-accelerometer rotation within this of the axes the gyro named covers them, degrees."""


def _named_axes_warning(result: TumbleResult, axes, site_dip_deg: float | None, path: str) -> str:
    """The warning for magnetometer axes the gyro named (:func:`compass.axes.axes_from_gyro`) where ``result``'s fitted
    rotation ``C`` (calibrated magnetometer -> accelerometer) takes them into the gyro's: ``C ~ Q^T``; or
    ``C ~ -Q^T``, the same chip with the field reversed, where the field's sign is not known (no site, or one near
    the magnetic equator: :func:`compass.axes.check_axes` then judges the dip).  Raises CannotCalibrate with the
    remap otherwise."""
    m = result.misalignment
    c = None if result.refused or m is None or m.rotation is None else m.rotation.as_matrix()

    def near(t: np.ndarray) -> bool:
        return c is not None and np.linalg.det(t) > 0 and Rotation.from_matrix(c @ t.T).magnitude() < np.radians(
            COVERED_DEG)

    sign_known = site_dip_deg is not None and abs(site_dip_deg) >= MIN_SIGNED_DIP_DEG
    if near(axes.matrix.T):
        return ("the magnetometer's axes are not the gyro's, and the rotation fitted to the accelerometer turns them "
                "into the gyro's (the runtime reads the stream as this recording was read)")
    if near(-axes.matrix.T) and not sign_known:
        return (f"{axes.finding}; the rotation fitted to the accelerometer reads it as a half turn with the field "
                f"reversed, right only south of the magnetic equator; north of it, read it in the gyro's axes: "
                f"{axes.remap}")
    raise CannotCalibrate(f"{path}: {axes.text}")


def _accelerometer(accel, t_s) -> tuple:
    """``(AccelCalibration or None, why not in words)`` of the tumble's accelerometer (``("", "")`` without one)."""
    if accel is None:
        return None, ""
    if t_s is None:
        return None, "no accelerometer calibration: the recording has no times to find its still rows"
    try:
        return fit_accelerometer(accel, t_s), ""
    except NoAccelCalibration as exc:
        return None, f"no accelerometer calibration: {exc}"


def _unless_fast(misalignment, mag_cal, accel, t_s, keep, warnings: list):
    """The misalignment, its rotation withheld when the motion was fast (:func:`calibrate.tumble.motion.fast_motion`:
    the field-gravity angle grows with the turn rate), said in ``warnings`` (appended to)."""
    if t_s is None or misalignment is None:
        return misalignment
    motion = fast_motion(mag_cal, accel, np.asarray(t_s, float)[keep], misalignment.rotation)
    if motion is None:
        return misalignment
    warnings.append(motion.words())
    if misalignment.rotation is None:
        return misalignment
    return replace(misalignment, rotation=None, rotvec_deg=np.full(3, np.nan), rotvec_sigma_deg=np.full(3, np.nan),
                   withheld="the field-gravity angle grows with the turn rate (fast motion)")


def _widening(raw: np.ndarray, accel: np.ndarray, mag_cal: np.ndarray, rotation: Rotation | None) -> str:
    """Why the calibration must not be used when it widens the field-gravity angle spread, else "".

    The angle between the field and gravity is a constant of the site.  Called when the residual
    diagnosis left structure in |m| that no effect explains: if then, on the quasi-static samples,
    the calibrated field also agrees worse with gravity than the raw readings (beyond
    :data:`MAX_ANGLE_WIDENING`), the fit is a compromise between fields that differed during the
    recording, however well it lowers the |B| spread.  Either sign alone is not enough: an
    uncalibrated accelerometer can make a right calibration agree worse with gravity.
    """
    static = static_mask(accel)
    before = float(np.std(field_gravity_angles(raw[static], accel[static])))
    after = float(np.std(field_gravity_angles(mag_cal[static], accel[static], rotation)))
    if not after > (1.0 + MAX_ANGLE_WIDENING) * before:  # also when either is NaN (no quasi-static samples)
        return ""
    return (f"no usable calibration: it widens the spread of the field-gravity angle over the quasi-static samples "
            f"from {before:.3g} deg (raw) to {after:.3g} deg, so the raw readings agree better with gravity than the "
            "calibrated ones: the field changed during the recording (a magnet or magnetised part attached or moved "
            "partway), which no single ellipsoid describes")


class TumbleCalibrator(Calibrator):
    """Free-motion (tumble) calibration: ellipsoid, coverage, magnetometer-accelerometer rotation.

    Parameters
    ----------
    ellipsoid : {"auto", "offset", "diagonal", "full"}
        The ellipsoid kind (auto: the determined kind with the lowest BIC).
    field_ut : float, optional
        Known |B| (the file's ``soft_iron`` then gives uT); default the recording's
        ``# field_ut:`` metadata.

    Notes
    -----
    The residual diagnosis always runs (the refusal of a field that changed partway rests on it).
    With a gyro (``gx,gy,gz``, ``t_s`` and an accelerometer in the recording) and a present fit that
    fell back (a kind simpler than ``full``, or the rotation to the housing withheld), the gyro-aided fit
    (:mod:`calibrate.tumble.gyro`) replaces it where it is determined.
    """

    kind = "tumble"
    plot_files = ("tumble.png",)

    def __init__(self, *, ellipsoid: str = "auto", field_ut: float | None = None,
                 axis_tolerance_deg: float | None = AXIS_TOLERANCE_DEG, direction_accuracy_deg: float | None = None):
        self.ellipsoid, self.field_ut = ellipsoid, field_ut
        self.axis_tolerance_deg, self.direction_accuracy_deg = axis_tolerance_deg, direction_accuracy_deg

    def fit(self, recording: TumbleRecording) -> TumbleResult:
        field_ut = self.field_ut if self.field_ut is not None else metadata_field_ut(recording.path,
                                                                                      recording.metadata)
        # once, for the check, the noise floor and the health (a recording too short for it fails later, as before)
        axis_noise = _axis_noise(np.asarray(recording.mag, float)) if len(recording.mag) >= 3 else None
        require_varying_axes(recording.path, recording.mag, axis_noise)
        site = compare_with_site(0.0, None, recording.metadata, recording.path)
        site_dip_deg = None if site is None else site["model_dip_deg"]
        axes = None if recording.gyro_turn_rad is None else axes_from_gyro(
            recording.mag, recording.gyro_turn_rad, recording.t_s, up=recording.accel, site_dip_deg=site_dip_deg)
        result = calibrate_tumble(recording.mag, recording.accel, ellipsoid=self.ellipsoid, field_ut=field_ut,
                                  n_repeats=recording.n_repeats, t_s=recording.t_s, temp_c=recording.temp_c,
                                  site_dip_deg=site_dip_deg, axis_noise=axis_noise)
        if self.ellipsoid == "auto" and recording.gyro_turn_rad is not None and falls_back(result):  # the gyro pins what |m| cannot
            result = with_gyro(result, recording.mag, recording.accel, recording.gyro_turn_rad, recording.t_s,
                               recording.temp_c)
        if axes is not None:  # the magnetometer's axes are not the gyro's: right only where the fitted rotation is
            warning = _named_axes_warning(result, axes, site_dip_deg, recording.path)
            result = replace(result, warnings=result.warnings + (warning,))
        if result.refused:
            raise CannotCalibrate(f"{recording.path}: {result.refused}")
        health = channel_health(result, recording.mag, axis_noise)
        warnings = check_channels(recording.path, health, axis_tolerance_deg=self.axis_tolerance_deg,
                                  direction_accuracy_deg=self.direction_accuracy_deg)
        return replace(result, warnings=result.warnings + warnings, health=health_json(health),
                       raw_unit="uT" if recording.mag_unit else "recording units")
