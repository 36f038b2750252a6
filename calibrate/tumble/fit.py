"""The tumble calibration: ellipsoid, diagnosis, alignment, refusal (:func:`calibrate_tumble`, :class:`TumbleCalibrator`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from compass.io.tumble import TumbleRecording

from ..contract import Calibrator, CannotCalibrate, metadata_field_ut
from ..noise import robust_sigma
from .alignment import MAX_ANGLE_WIDENING, field_gravity_angles, fit_misalignment, refine_jointly, static_mask
from .diagnosis import UNEXPLAINED_WARNING, diagnose_tumble
from .ellipsoid import fit_ellipsoid
from .result import TumbleResult

def _noise_floor(x: np.ndarray) -> float:
    """Per-axis white-noise sigma from second differences of consecutive samples (median over axes)."""
    d = x[:-2] - 2.0 * x[1:-1] + x[2:]
    return float(np.median(robust_sigma(d)) / np.sqrt(6.0))


def calibrate_tumble(mag: np.ndarray, accel: np.ndarray | None = None, *, ellipsoid: str = "auto",
                     field_ut: float | None = None, n_repeats: int = 0, t_s: np.ndarray | None = None,
                     temp_c: np.ndarray | None = None) -> TumbleResult:
    """Calibrate hard and soft iron (and the magnetometer-accelerometer rotation) from a tumble.

    Parameters
    ----------
    mag : ndarray, shape (n, 3)
        Raw magnetometer, recording units, magnetometer frame; repeated values already removed
        (:func:`compass.io.tumble.read_tumble` does that).
    accel : ndarray, shape (n, 3), optional
        Accelerometer at the same rows (specific force), any unit.
    ellipsoid : {"auto", "offset", "diagonal", "full"}
    field_ut : float, optional
        Known |B|; the file's ``soft_iron`` then gives microtesla.
    n_repeats : int
        Rows dropped upstream as repeats (reported only).
    t_s, temp_c : ndarray, shape (n,), optional
        Time (s) and sensor temperature (degC) of each sample: the residual diagnosis then
        examines a drifting and a temperature-dependent hard iron too.

    Returns
    -------
    TumbleResult
        Refused (``refused`` says why) when every kind is degenerate, or when the residual
        diagnosis leaves structure in |m| unexplained and, with an accelerometer, the calibrated
        field agrees worse with gravity than the raw readings (:func:`_widening`).

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
    noise = _noise_floor(mag)
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
                            tuple(warnings + [refused]), refused)
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
        misalignment = fit_misalignment(chosen.calibrated(mag[keep]), accel[keep])
        if misalignment is not None and coverage.missing and misalignment.rotation is not None:
            warnings.append("no magnetometer-accelerometer rotation fitted: with part of the sphere missing it "
                            "trades off against the hard iron; frames taken as aligned")
            misalignment = replace(misalignment, rotation=None, rotvec_deg=np.full(3, np.nan),
                                   rotvec_sigma_deg=np.full(3, np.nan))
        if misalignment is not None:
            chosen, misalignment = refine_jointly(chosen, mag, accel, misalignment)
            diagnosis = diagnosis.with_alignment(misalignment, chosen)
            chosen = diagnosis.fit
        else:
            warnings.append("fewer than 20 quasi-static samples: no magnetometer-accelerometer alignment, no dip")
    # the field changed partway: structure in |m| that no effect explains, and gravity agrees less with the result
    changed = diagnosis.block["unexplained"] and misalignment is not None
    refused = _widening(raw, accel, chosen.calibrated(mag), misalignment.rotation) if changed else ""
    return TumbleResult(chosen, candidates, coverage, misalignment, field_ut, noise, len(mag), n_repeats,
                        tuple(warnings + ([refused] if refused else [])), refused, diagnosis)


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
    """

    kind = "tumble"
    plot_files = ("tumble.png",)

    def __init__(self, *, ellipsoid: str = "auto", field_ut: float | None = None):
        self.ellipsoid, self.field_ut = ellipsoid, field_ut

    def fit(self, recording: TumbleRecording) -> TumbleResult:
        field_ut = self.field_ut if self.field_ut is not None else metadata_field_ut(recording.path,
                                                                                      recording.metadata)
        result = calibrate_tumble(recording.mag, recording.accel, ellipsoid=self.ellipsoid, field_ut=field_ut,
                                  n_repeats=recording.n_repeats, t_s=recording.t_s, temp_c=recording.temp_c)
        if result.refused:
            raise CannotCalibrate(f"{recording.path}: {result.refused}")
        return result
