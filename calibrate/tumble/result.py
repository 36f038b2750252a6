"""TumbleResult: what a tumble calibration found, its file, report and plots."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from compass.calibration import header

from ..contract import CalibrationResult, FitStatistics, fit_report
from ..diagnosis.forms import json_float
from .accelerometer import AccelCalibration
from .alignment import Misalignment
from .coverage import Coverage
from .ellipsoid import EllipsoidFit

if TYPE_CHECKING:
    from .diagnosis import TumbleDiagnosis

@dataclass(frozen=True)
class TumbleResult(CalibrationResult):
    """A tumble calibration (SPEC section 2, ``"model": "tumble"``).

    Attributes
    ----------
    fit : EllipsoidFit
        The chosen ellipsoid.
    candidates : tuple of EllipsoidFit
        Every kind tried, for the report and the BIC comparison.
    coverage : Coverage
    misalignment : Misalignment or None
        None without an accelerometer (or too few quasi-static samples).
    field_ut : float or None
        When known, ``soft_iron`` is scaled so that the calibrated field is in microtesla.
    noise : float
        White-noise sigma per axis from second differences of consecutive samples, recording units.
    n_samples, n_repeats : int
        Samples fitted; rows dropped as repeated magnetometer values.
    warnings : tuple of str
    refused : str
        Why no kind gives a usable calibration (every kind degenerate, or the field changed during
        the recording: see :func:`calibrate_tumble`), in words; empty when the result is usable.
        A refused result must not be written as a calibration file.
    diagnosis : TumbleDiagnosis or None
        The residual diagnosis (:mod:`calibrate.tumble.diagnosis`); None when every kind is degenerate.  With claimed
        effects, ``fit`` is the ellipsoid at their reference time and temperature.
    raw_unit : str
        The unit of the readings fitted, for the report: ``"uT"`` when the recording's magnetometer
        unit was named (the reader converted it), else ``"recording units"``.
    gyro : dict or None
        The gyro-aided fit's block (:mod:`calibrate.tumble.gyro`; ``used``: whether ``fit`` and
        ``misalignment`` are its), None when it was not tried.
    accelerometer : AccelCalibration or None
        The accelerometer's own correction (:mod:`calibrate.tumble.accelerometer`), fitted on the still rows and
        applied to every accelerometer row the fit takes as gravity; None when not fitted.
    accelerometer_words : str
        Why it was not fitted (empty when it was, or without an accelerometer).
    """

    fit: EllipsoidFit
    candidates: tuple
    coverage: Coverage
    misalignment: Misalignment | None
    field_ut: float | None
    noise: float
    n_samples: int
    n_repeats: int
    warnings: tuple = field(default_factory=tuple)
    refused: str = ""
    diagnosis: TumbleDiagnosis | None = None
    health: dict = field(default_factory=dict)
    """The file's ``"channel_health"`` block (:mod:`calibrate.health`), set by :class:`TumbleCalibrator`."""
    raw_unit: str = "recording units"
    gyro: dict | None = None
    accelerometer: AccelCalibration | None = None
    accelerometer_words: str = ""

    calibration_kind = "tumble"

    @property
    def statistics(self) -> FitStatistics:
        """The diagnosis's final fit (:attr:`TumbleDiagnosis.statistics`); without a diagnosis (every kind
        degenerate), the chosen ellipsoid's parameters with no covariance and no chi-square."""
        if self.diagnosis is not None:
            return self.diagnosis.statistics
        from .diagnosis import ellipsoid_parameter_names

        k = self.fit.params.size
        return FitStatistics(ellipsoid_parameter_names(self.fit.ellipsoid), self.fit.params, np.full((k, k), np.inf),
                             float("nan"), 0, float("nan"), self.fit.success, self.fit.message)

    @property
    def ellipsoid(self) -> str:
        """The chosen ellipsoid kind (``offset``, ``diagonal``, ``full``)."""
        return self.fit.ellipsoid

    @property
    def parameters(self) -> dict:
        """``hard_iron[i]`` (recording units), ``soft_iron[i,j]`` (file units), ``field_norm``: value and sigma."""
        fit = self.fit
        out = {f"hard_iron[{i}]": (float(v), float(e)) for i, (v, e) in enumerate(zip(fit.hard_iron, fit.hard_iron_sigma))}
        for (i, j), v in np.ndenumerate(self.soft_iron):
            out[f"soft_iron[{i},{j}]"] = (float(v), float(fit.soft_iron_sigma[i, j] * self.scale))
        out["field_norm"] = (self.field_norm, None if self.field_ut else float(fit.field_norm_sigma))
        return out

    def plots(self, recording, folder) -> list:
        """``tumble.png``: |B| before and after, per sample (:func:`calibrate.plots.plot_tumble`)."""
        from pathlib import Path

        from ..plots import plot_tumble

        return [plot_tumble(recording.mag, self, Path(folder) / "tumble.png")]

    @property
    def hard_iron(self) -> np.ndarray:
        return self.fit.hard_iron

    @property
    def scale(self) -> float:
        """Factor from det-1 units to the file's units (``field_ut / F`` when |B| is known, else 1)."""
        return self.field_ut / self.fit.field_norm if self.field_ut else 1.0

    @property
    def soft_iron(self) -> np.ndarray:
        """``S`` as written to the file: det 1, or scaled to microtesla when |B| is known."""
        return self.fit.soft_iron * self.scale

    @property
    def field_norm(self) -> float:
        return float(self.field_ut) if self.field_ut else self.fit.field_norm

    @property
    def mag_to_accel(self) -> np.ndarray | None:
        m = self.misalignment
        return None if m is None or m.rotation is None else m.rotation.as_matrix()

    def calibrated(self, mag: np.ndarray) -> np.ndarray:
        """``m = soft_iron @ (raw - hard_iron)``, shape (n, 3), magnetometer frame, file units."""
        return (np.asarray(mag, dtype=float) - self.hard_iron) @ self.soft_iron.T

    def corrected_accel(self, accel) -> np.ndarray | None:
        """The accelerometer rows corrected by :attr:`accelerometer` (as read without it), recording units."""
        if accel is None or self.accelerometer is None:
            return None if accel is None else np.asarray(accel, dtype=float)
        return self.accelerometer.apply(accel)

    def accelerometer_block(self) -> dict | None:
        """The file's ``accelerometer`` key: the correction, or null values and why; None without an accelerometer
        tried."""
        if self.accelerometer is not None:
            return self.accelerometer.to_json()
        if not self.accelerometer_words:
            return None
        return {"offset": None, "matrix": None, "words": self.accelerometer_words}

    def to_json(self) -> dict:
        """The calibration file (SPEC section 2, tumble kind), JSON-ready.

        ``hard_iron`` is the one at the claimed effects' reference (first sample's ``t_s``, mean
        ``temp_c``); the effects' parameters are under ``effects``; ``noise_floor`` is the per-axis
        noise of the raw readings, the diagnosis's that of the radial residual.

        Raises
        ------
        ValueError
            The result is refused (no usable calibration).
        """
        if self.refused:
            raise ValueError(f"a refused tumble calibration has no calibration file: {self.refused}")
        fit, mis, accelerometer = self.fit, self.misalignment, self.accelerometer_block()
        return header("tumble") | {
            "hard_iron": fit.hard_iron.tolist(),
            "soft_iron": self.soft_iron.tolist(),
            "field_norm": self.field_norm,
            "mag_to_accel": None if self.mag_to_accel is None else self.mag_to_accel.tolist(),
            "field_ut": self.field_ut,
            "dip_deg": None if mis is None else mis.dip_deg,
            "dip_sigma_deg": None if mis is None else json_float(mis.dip_sigma_deg),
            "channel_columns": ["mx", "my", "mz"],
            "noise_floor": [self.noise] * 3,
            "effects": list(self.diagnosis.effects),
            "diagnosis": self.diagnosis.block,
            "tumble": {
                "kind": fit.ellipsoid,
                "kinds": [{"kind": c.ellipsoid, "residual_rms": float(np.sqrt(np.mean(c.residuals[fit.inliers] ** 2))),
                           "bic": json_float(c.bic), "determined": c.determined} for c in self.candidates],
                "hard_iron_sigma": fit.hard_iron_sigma.tolist(),
                "soft_iron_sigma": (fit.soft_iron_sigma * self.scale).tolist(),
                "field_norm_recording_units": fit.field_norm,
                "field_norm_sigma_recording_units": fit.field_norm_sigma,
                "coverage_fraction": self.coverage.fraction,
                "coverage_missing": self.coverage.missing,
                "n_samples": self.n_samples,
                "n_repeats_dropped": self.n_repeats,
                "n_outliers": int(np.count_nonzero(~fit.inliers)),
                "misalignment_rotvec_deg": None if mis is None else [json_float(v) for v in mis.rotvec_deg],
                "misalignment_rotvec_sigma_deg": None if mis is None else [json_float(v) for v in mis.rotvec_sigma_deg],
                "field_gravity_angle_spread_deg": None if mis is None else
                {"before": mis.spread_before_deg, "after": mis.spread_after_deg, "n_static": mis.n_static},
                "method": "gyro" if self.gyro and self.gyro["used"] else "ellipsoid",
                "gyro": self.gyro,
            },
            "warnings": list(self.warnings),
        } | ({"channel_health": self.health} if self.health else {}) | (
            {} if accelerometer is None else {"accelerometer": accelerometer})

    def report(self) -> str:
        """A fit report for a person: values +- sigma, the kinds compared, coverage and warnings in words."""
        fit = self.fit
        aided = " (gyro-aided: the gyro's turns between samples in the fit)" if self.gyro and self.gyro["used"] else ""
        lines = [f"Tumble calibration: {fit.ellipsoid} ellipsoid{aided} from {self.n_samples} samples "
                 f"({self.n_repeats} repeated rows dropped, {np.count_nonzero(~fit.inliers)} outliers)"]
        lines.append("  hard iron " + ", ".join(f"{v:.5g} +- {s:.2g}" for v, s in zip(fit.hard_iron, fit.hard_iron_sigma))
                     + f" ({self.raw_unit})")
        unit = "uT" if self.field_ut else self.raw_unit
        lines.append(f"  field norm {self.field_norm:.5g} {unit}; soft iron (det 1 shape):")
        for row, srow in zip(fit.soft_iron, fit.soft_iron_sigma):
            lines.append("    " + "  ".join(f"{v:+.5f} +- {s:.1g}" for v, s in zip(row, srow)))
        lines.append("  kinds: " + "; ".join(
            f"{c.ellipsoid} BIC {c.bic:.1f} rms {np.sqrt(np.mean(c.residuals[fit.inliers] ** 2)):.3g}"
            + ("" if c.determined else f" (not determined: {c.reason})") for c in self.candidates))
        lines.append(f"  noise floor {self.noise:.3g} per axis; coverage: {self.coverage.words()}")
        if self.health:
            from ..health import describe

            lines.append(describe(self.health))
        mis = self.misalignment
        if mis is not None:
            lines.append(f"  dip {mis.dip_deg:.3f} +- {mis.dip_sigma_deg:.3f} deg from {mis.n_static} quasi-static samples")
            if mis.rotation is None:
                lines.append(f"  mag-to-accel {mis.words()}")
            else:
                lines.append("  mag-to-accel rotation vector " + ", ".join(
                    f"{v:+.3f} +- {s:.3f}" for v, s in zip(mis.rotvec_deg, mis.rotvec_sigma_deg)) + " deg")
            lines.append(f"  field-gravity angle spread {mis.spread_before_deg:.3f} -> {mis.spread_after_deg:.3f} deg")
        block = self.accelerometer_block()
        if block is not None:
            lines.append(f"  {block['words']}")
        if not self.refused:  # what the runtime will say of the file (compass.iron_uncertainty), read as it reads it
            from compass.calibration import from_dict
            from compass.iron_uncertainty import undetermined_words

            model = from_dict(self.to_json()).model
            words = undetermined_words(model.calibration_uncertainty, model.field_norm, model.dip_deg)
            if words is not None:
                lines.append(f"  at runtime: {words}")
        diagnosis = None if self.diagnosis is None else self.diagnosis.format(self.raw_unit)
        return fit_report(self, lines, diagnosis=diagnosis)
