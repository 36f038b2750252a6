"""Platform3DResult: what a 3-D platform calibration found, its file and report; the axis geometry."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from compass.calibration import channel_entry, header

from ..contract import CalibrationResult, FitStatistics, fit_report
from ..diagnosis.offsets import OffsetDiagnosis

MAG_CHANNELS = ("mx", "my", "mz")


AXES = "xyz"


def axis_geometry(matrix: np.ndarray) -> np.ndarray:
    """Scales, non-orthogonality and rotation of a sensor's axes, flattened.

    Parameters
    ----------
    matrix : ndarray, shape (c, 3)
        Rows: scale times unit sensing direction in H (c = 2 or 3).

    Returns
    -------
    ndarray
        ``c`` scales (row norms); the angles between axis pairs minus 90 degrees (3 for three
        axes, 1 for two: (x, y), (x, z), (y, z)); the rotation vector (degrees) of the rotation
        ``Q`` nearest the unit axes (``v_sensor = Q v_H``; the third axis of a two-axis sensor is
        the normal of the first two).
    """
    k = np.linalg.norm(matrix, axis=1)
    u = matrix / k[:, None]
    pairs = [(0, 1), (0, 2), (1, 2)] if len(u) == 3 else [(0, 1)]
    nonorth = [np.degrees(np.arccos(np.clip(u[i] @ u[j], -1, 1))) - 90.0 for i, j in pairs]
    full = u if len(u) == 3 else np.vstack([u, np.cross(u[0], u[1]) / np.linalg.norm(np.cross(u[0], u[1]))])
    w, _, vt = np.linalg.svd(full)
    q = w @ vt
    if np.linalg.det(q) < 0:
        q = w @ np.diag([1.0, 1.0, -1.0]) @ vt
    return np.concatenate([k, nonorth, Rotation.from_matrix(q).as_rotvec(degrees=True)])


def geometry_names(prefix: str, columns) -> list[str]:
    pairs = [(0, 1), (0, 2), (1, 2)] if len(columns) == 3 else [(0, 1)]
    return ([f"{prefix}_scale_{c}" for c in columns]
            + [f"{prefix}_nonorthogonality_{columns[i]}_{columns[j]}_deg" for i, j in pairs]
            + [f"{prefix}_rotvec_{a}_deg" for a in AXES])


@dataclass(frozen=True)
class Platform3DResult(CalibrationResult):
    """A 3-D platform calibration (seed 001) with its statistics.

    Attributes
    ----------
    statistics : FitStatistics
        The noise-weighted fit: parameters ``M[c,j]``, ``o_m[c]``, ``field_elevation_rad``,
        ``field_azimuth_rad``, ``A[c,j]``, ``o_t[c]``, ``base_tilt_x_rad``, ``base_tilt_y_rad`` (then the
        claimed effects'), their covariance scaled by the residual (reduced chi-square).
    mag_matrix : ndarray, shape (3, 3)
        ``M``: output units per field unit (uT when ``field_ut`` is known, else per |B|), H frame.
    mag_offset : ndarray, shape (3,)
    tilt_matrix : ndarray, shape (c, 3)
        ``A``: output units per g, H frame.
    tilt_offset : ndarray, shape (c,)
    tilt_columns : tuple of str
    field_w : ndarray, shape (3,)
        The field in W, field units.
    up_w : ndarray, shape (3,)
        The true up direction in W.
    derived : dict
        Name -> (value, sigma): scales, non-orthogonality and rotation of both sensors,
        ``mag_to_tilt_rotvec_*_deg``, ``dip_deg``, ``field_azimuth_deg``, ``base_tilt_*_deg``,
        ``field_norm_recording_units``.
    mag_direction_covariance : ndarray, shape (3, 3, 3)
        Covariance of each magnetometer sensing direction (rad^2).
    mag_response_sigma : ndarray, shape (3, 2)
        Standard errors of each magnetometer channel's (offset, gain).
    residuals_mag : ndarray, shape (n, 3)
    residuals_tilt : ndarray, shape (n, c)
        Measured minus predicted, output units.
    noise_mag, noise_tilt : ndarray or None
        White noise from the spread of repeated samples at one pose; None without repeats.
    field_ut : float or None
    warnings : tuple of str
    diagnosis : OffsetDiagnosis or None
        The residual diagnosis of the magnetometer (:mod:`calibrate.diagnosis.offsets`); None when
        not run.  With claimed effects, ``values`` end with their parameters, ``mag_offset`` is
        the offset at their reference (the first sample's ``t_s``, the mean ``temp_c``) and the
        residuals are those of the model with them.
    """

    statistics: FitStatistics
    mag_matrix: np.ndarray
    mag_offset: np.ndarray
    tilt_matrix: np.ndarray
    tilt_offset: np.ndarray
    tilt_columns: tuple
    field_w: np.ndarray
    up_w: np.ndarray
    derived: dict
    mag_direction_covariance: np.ndarray
    mag_response_sigma: np.ndarray
    residuals_mag: np.ndarray
    residuals_tilt: np.ndarray
    noise_mag: np.ndarray | None
    noise_tilt: np.ndarray | None
    field_ut: float | None
    warnings: tuple = field(default_factory=tuple)
    diagnosis: OffsetDiagnosis | None = None
    health: dict = field(default_factory=dict)
    """The file's ``"channel_health"`` block (:mod:`calibrate.health`), set by the calibrator."""

    calibration_kind = "platform3d"

    @property
    def parameters(self) -> dict:
        """The derived parameters (scales, non-orthogonality, rotations, dip, ...): name -> (value, sigma)."""
        return dict(self.derived)

    @property
    def dip_deg(self) -> float:
        return self.derived["dip_deg"][0]

    def to_json(self) -> dict:
        """The calibration file (SPEC section 2, channel form for the magnetometer), JSON-ready.

        Extra keys: ``tilt_sensor`` (read by :class:`compass.io.platform3d.TiltSensor`),
        ``misalignment`` and ``platform3d`` (every parameter with its sigma).
        """
        field_range = np.linalg.norm(self.field_w)
        channels = {}
        for c, name in enumerate(MAG_CHANNELS):
            gain = float(np.linalg.norm(self.mag_matrix[c]))
            response = {"model": "linear", "offset": float(self.mag_offset[c]), "gain": gain,
                        "range": [-float(field_range), float(field_range)]}
            channels[name] = channel_entry(self.mag_matrix[c] / gain, response,
                                           covariance=self.mag_direction_covariance[c],
                                           response_sigma=self.mag_response_sigma[c])
        noise = self.noise_mag if self.noise_mag is not None else np.sqrt(np.mean(self.residuals_mag**2, axis=0))
        rms = float(np.sqrt(np.mean(self.residuals_mag**2)))
        if self.diagnosis is not None:
            effects, diagnosis = list(self.diagnosis.effects), self.diagnosis.block
        else:
            effects = []
            diagnosis = {"noise_floor": float(np.mean(noise)), "steps": [{"model": "base", "residual_rms": rms}],
                         "effects": [], "residual_rms_before": rms, "residual_rms_after": rms,
                         "unexplained": None if self.noise_mag is None else bool(rms > 1.5 * np.mean(noise)),
                         "not_applicable": {"diagnosis": "not run (calibrate_platform3d(..., diagnose=False))"}}
        d = self.derived
        return header("platform3d") | {
            "channels": channels,
            "dip_deg": d["dip_deg"][0],
            "dip_sigma_deg": d["dip_deg"][1],
            "field_ut": self.field_ut,
            "noise_floor": [float(v) for v in noise],
            "effects": effects,
            "diagnosis": diagnosis,
            "method": "platform3d",
            "field_azimuth_deg": d["field_azimuth_deg"][0],
            "tilt_sensor": {
                "columns": list(self.tilt_columns),
                "matrix": self.tilt_matrix.tolist(),
                "offset": self.tilt_offset.tolist(),
                "unit": "output units per g (specific force, +1 g up at rest), housing frame H",
                "noise_floor": None if self.noise_tilt is None else self.noise_tilt.tolist(),
            },
            "misalignment": {k: list(d[f"{k}_{a}_deg"] for a in AXES) for k in
                             ("mag_rotvec", "tilt_rotvec", "mag_to_tilt_rotvec")},
            "platform3d": {"parameters": {k: {"value": v, "sigma": s} for k, (v, s) in d.items()},
                           "fit": {"chi2": self.statistics.chi2, "dof": self.statistics.dof,
                                   "bic": self.statistics.bic, "success": self.statistics.success,
                                   "message": self.statistics.message}},
            "warnings": list(self.warnings),
        } | ({"channel_health": self.health} if self.health else {})

    def plots(self, recording, folder) -> list:
        """``platform_residuals.png``: each channel's residual against the outer gimbal angle and time.

        Parameters
        ----------
        recording : compass.io.platform3d.Platform3DRecording
            The recording this result was fitted to.
        folder : path
        """
        from pathlib import Path

        from ..plots import plot_platform3d

        return [plot_platform3d(recording, self, Path(folder) / "platform_residuals.png")]

    def report(self) -> str:
        """A fit report for a person: values +- sigma, strong correlations, warnings in words."""
        unit = "uT" if self.field_ut else "|B|"
        d = self.derived
        lines = [f"3-D platform calibration (seed 001): {len(self.residuals_mag)} samples, "
                 f"tilt sensor {', '.join(self.tilt_columns)}; magnetometer gains per {unit}, tilt per g"]

        def row(label, keys, fmt=".4f"):
            parts = []
            for key in keys:
                short = key.rsplit("_", 2)[-2] if key.endswith("_deg") and len(keys) > 1 else key.split("_")[-1]
                parts.append((f"{short} " if len(keys) > 1 else "") + f"{d[key][0]:{fmt}} +- {d[key][1]:.2g}")
            lines.append(f"  {label}: " + ", ".join(parts))

        for prefix, cols in (("mag", MAG_CHANNELS), ("tilt", self.tilt_columns)):
            keys = geometry_names(prefix, cols)
            n_pair = 3 if len(cols) == 3 else 1
            row(f"{prefix} scales", keys[:len(cols)], ".6g")
            pairs = keys[len(cols):len(cols) + n_pair]
            lines.append(f"  {prefix} non-orthogonality (angle between axes - 90 deg): " + ", ".join(
                f"{'/'.join(k.split('_')[2:4])} {d[k][0]:+.4f} +- {d[k][1]:.2g}" for k in pairs))
            row(f"{prefix} rotation vector from H (deg)", keys[-3:])
        row("mag-to-tilt rotation vector (deg)", [f"mag_to_tilt_rotvec_{a}_deg" for a in AXES])
        lines.append("  magnetometer offsets " + ", ".join(f"{v:.6g}" for v in self.mag_offset)
                     + "; tilt offsets " + ", ".join(f"{v:.6g}" for v in self.tilt_offset))
        row("dip (deg)", ["dip_deg"])
        row("field azimuth from the platform zero (deg)", ["field_azimuth_deg"])
        row("base level error (deg)", ["base_tilt_x_deg", "base_tilt_y_deg"])
        row("|B| in output units at unit gain", ["field_norm_recording_units"], ".6g")
        for label, res, noise in (("magnetometer", self.residuals_mag, self.noise_mag),
                                  ("tilt sensor", self.residuals_tilt, self.noise_tilt)):
            rms = np.sqrt(np.mean(res**2, axis=0))
            lines.append(f"  {label} residual rms " + ", ".join(f"{v:.3g}" for v in rms)
                         + ("" if noise is None else " (noise from repeats " + ", ".join(f"{v:.3g}" for v in noise) + ")"))
        if self.health:
            from ..health import describe

            lines.append(describe(self.health))
        diagnosis = None if self.diagnosis is None else self.diagnosis.format("magnetometer output units")
        return fit_report(self, lines, diagnosis=diagnosis)
