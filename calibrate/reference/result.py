"""ReferenceResult and SensorK: what a K-matrix calibration found, its file and report."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from compass.calibration import channel_entry, header

from ..contract import CalibrationResult, FitStatistics, fit_report
from ..diagnosis.offsets import OffsetDiagnosis

_ANGLE_NAMES = tuple(f"{g}{j}" for g in ("alpha", "beta", "gamma") for j in (1, 2, 3))


@dataclass(frozen=True)
class SensorK:
    """One sensor's calibration.

    Attributes
    ----------
    name : str
    channels : tuple of str
    k_matrix, k_sigma : ndarray, shape (3, 3)
        ``K`` (field units per output unit) and its element-wise standard errors.
    offset, offset_sigma : ndarray, shape (3,)
        ``V_0``, output units.
    field_offset, field_offset_sigma : ndarray, shape (3,)
        ``B_0 = K V_0``, field units (the seed's zero-point offsets).
    scale, scale_sigma : ndarray, shape (3,)
        Scale factors (the seed's a, b, c): output units per field unit.
    angles_deg, angles_sigma_deg : ndarray, shape (3, 3)
        Row c: the angles between axis c and the array's x, y, z axes (alpha, beta, gamma).
    direction_covariance : ndarray, shape (3, 3, 3)
        Covariance of each axis' unit direction, rad^2.
    geometry, geometry_sigma : ndarray, shape (9,)
        :func:`calibrate.platform3d.axis_geometry` of ``K^-1``: scales, non-orthogonality (deg),
        rotation vector relative to the array frame (deg).
    residuals : ndarray, shape (n, 3)
        Measured minus predicted output.
    dof : int
        ``n - 4``.
    covariance : ndarray, shape (12, 12), or None
        Of ``G = K^-1`` (row-major) then ``V_0``; None with exactly 4 fields (no residual to scale it).
    """

    name: str
    channels: tuple
    k_matrix: np.ndarray
    k_sigma: np.ndarray | None
    offset: np.ndarray
    offset_sigma: np.ndarray | None
    field_offset: np.ndarray
    field_offset_sigma: np.ndarray | None
    scale: np.ndarray
    scale_sigma: np.ndarray | None
    angles_deg: np.ndarray
    angles_sigma_deg: np.ndarray | None
    direction_covariance: np.ndarray | None
    geometry: np.ndarray
    geometry_sigma: np.ndarray | None
    residuals: np.ndarray
    dof: int
    covariance: np.ndarray | None = None

    @property
    def parameter_names(self) -> list[str]:
        """Names of the fitted ``G`` (row-major) then ``V_0``, as in :attr:`covariance`."""
        return [f"{self.name}.G[{i},{j}]" for i in range(3) for j in range(3)] + [f"{self.name}.V0[{c}]" for c in range(3)]

    @property
    def residual_rms(self) -> np.ndarray:
        """Per channel, output units (over the n - 4 degrees of freedom)."""
        return np.sqrt(np.sum(self.residuals**2, axis=0) / max(self.dof, 1))

    def field(self, outputs: np.ndarray) -> np.ndarray:
        """Calibrated field ``K (V - V_0)`` in the array frame, field units, shape (n, 3)."""
        return (np.asarray(outputs, float) - self.offset) @ self.k_matrix.T


@dataclass(frozen=True)
class ReferenceResult(CalibrationResult):
    """A reference-field (K-matrix) calibration of an array.

    Attributes
    ----------
    sensors : tuple of SensorK
    n_fields : int
    condition : float
        Largest condition number of a sensor's column-scaled design ``[B, 1]``.
    spread : float or None
        Rms difference between the sensors' calibrated fields and the reference fields over all
        sensors, field units (None with one sensor).
    warnings : tuple of str
    diagnosis : OffsetDiagnosis or None
        The residual diagnosis of every sensor's channels (:mod:`calibrate.diagnosis.offsets`);
        None when not run.  With claimed effects the sensors' offsets hold at their reference
        (the first row's ``t_s``, the mean ``temp_c``) and their residuals are those of the model
        with them.
    not_diagnosed : str or None
        Why the diagnosis did not run, when it did not.
    """

    sensors: tuple
    n_fields: int
    condition: float
    spread: float | None
    statistics: FitStatistics
    warnings: tuple = field(default_factory=tuple)
    diagnosis: OffsetDiagnosis | None = None
    not_diagnosed: str | None = None
    health: dict = field(default_factory=dict)
    """The file's ``"channel_health"`` block (:mod:`calibrate.health`), set by the calibrator."""

    calibration_kind = "reference"

    @property
    def parameters(self) -> dict:
        """``<sensor>.K[i,j]``, ``<sensor>.offset[c]``: value and sigma (None with exactly 4 fields)."""
        out = {}
        for s in self.sensors:
            for (i, j), v in np.ndenumerate(s.k_matrix):
                out[f"{s.name}.K[{i},{j}]"] = (float(v), None if s.k_sigma is None else float(s.k_sigma[i, j]))
            for c, v in enumerate(s.offset):
                out[f"{s.name}.offset[{c}]"] = (float(v), None if s.offset_sigma is None else float(s.offset_sigma[c]))
        return out

    def to_json(self) -> dict:
        """The calibration file (SPEC section 2, channel form), JSON-ready.

        Every sensor's channels are listed (a uniform field read by the whole array); the
        per-sensor ``K``, offsets, scales and angles are under ``"reference"``.
        """
        channels, noise, sensors = {}, [], {}
        for s in self.sensors:
            g = np.linalg.inv(s.k_matrix)
            for c, name in enumerate(s.channels):
                response = {"model": "linear", "offset": float(s.offset[c]), "gain": float(s.scale[c])}
                known = s.direction_covariance is not None
                channels[name] = channel_entry(g[c] / s.scale[c], response,
                                               covariance=s.direction_covariance[c] if known else None,
                                               response_sigma=(s.offset_sigma[c], s.scale_sigma[c]) if known else None)
                noise.append(float(s.residual_rms[c]))
            sensors[s.name] = {
                "channels": list(s.channels),
                "K": s.k_matrix.tolist(), "K_sigma": _maybe(s.k_sigma),
                "offset": s.offset.tolist(), "offset_sigma": _maybe(s.offset_sigma),
                "field_offset": s.field_offset.tolist(), "field_offset_sigma": _maybe(s.field_offset_sigma),
                "scale_factors": s.scale.tolist(), "scale_factors_sigma": _maybe(s.scale_sigma),
                "angles_deg": dict(zip(_ANGLE_NAMES, s.angles_deg.ravel().tolist())),
                "angles_sigma_deg": None if s.angles_sigma_deg is None else
                dict(zip(_ANGLE_NAMES, s.angles_sigma_deg.ravel().tolist())),
                "nonorthogonality_deg": s.geometry[3:6].tolist(),
                "rotvec_deg": s.geometry[6:].tolist(),
                "geometry_sigma": _maybe(s.geometry_sigma),
                "residual_rms": s.residual_rms.tolist(),
            }
        rms = float(np.sqrt(np.mean(np.concatenate([s.residuals.ravel() for s in self.sensors]) ** 2)))
        if self.diagnosis is not None:
            effects, diagnosis = list(self.diagnosis.effects), self.diagnosis.block
        else:
            effects = []
            diagnosis = {"noise_floor": float(np.mean(noise)), "steps": [{"model": "base", "residual_rms": rms}],
                         "effects": [], "residual_rms_before": rms, "residual_rms_after": rms, "unexplained": None,
                         "not_applicable": {"diagnosis": self.not_diagnosed or "not run"}}
        return header("reference") | {
            "channels": channels,
            "dip_deg": None,
            "dip_sigma_deg": None,
            "field_ut": None,
            "noise_floor": noise,
            "effects": effects,
            "diagnosis": diagnosis,
            "method": "reference",
            "reference": {"sensors": sensors, "n_fields": self.n_fields, "condition": self.condition,
                          "array_spread": self.spread,
                          "unit": "field units of the recording's bx_ref.. columns; K in field units per output unit"},
            "warnings": list(self.warnings),
        } | ({"channel_health": self.health} if self.health else {})

    def report(self) -> str:
        """A fit report for a person: K, offsets, scales and angles with +- sigma, warnings."""
        lines = [f"Reference-field calibration (seed 003): {len(self.sensors)} sensor(s), {self.n_fields} fields, "
                 f"design condition {self.condition:.3g}; alpha_j, beta_j, gamma_j: angles of axes 1, 2, 3 "
                 "to the array's x, y, z"]

        def pm(v, s, fmt):
            return " ".join(f"{x:{fmt}}" + ("" if s is None else f" +- {y:.2g}") for x, y in
                            zip(np.ravel(v), np.ravel(s) if s is not None else np.ravel(v)))

        for s in self.sensors:
            lines.append(f"  sensor {s.name} ({', '.join(s.channels)}):")
            for c in range(3):
                lines.append(f"    K row {c + 1}: {pm(s.k_matrix[c], None if s.k_sigma is None else s.k_sigma[c], '+.6g')}")
            lines.append(f"    offsets V0: {pm(s.offset, s.offset_sigma, '.6g')} (output units); "
                         f"B0 = K V0: {pm(s.field_offset, s.field_offset_sigma, '.5g')} (field units)")
            lines.append(f"    scale factors a, b, c: {pm(s.scale, s.scale_sigma, '.6g')}")
            for c, g in enumerate(("alpha", "beta", "gamma")):
                sig = None if s.angles_sigma_deg is None else s.angles_sigma_deg[c]
                lines.append(f"    {g}1..3: {pm(s.angles_deg[c], sig, '.4f')} deg")
            gs = (None, None) if s.geometry_sigma is None else (s.geometry_sigma[3:6], s.geometry_sigma[6:])
            lines.append(f"    angles between axes - 90 (xy, xz, yz): {pm(s.geometry[3:6], gs[0], '+.4f')} deg")
            lines.append(f"    rotation vector from the array frame: {pm(s.geometry[6:], gs[1], '+.4f')} deg; "
                         f"residual rms {pm(s.residual_rms, None, '.3g')}")
        if self.health:
            from ..health import describe

            lines.append(describe(self.health))
        if self.spread is not None:
            lines.append(f"  array: calibrated fields differ from the reference by {self.spread:.3g} rms (field units)")
        diagnosis = self.diagnosis.format() if self.diagnosis is not None else (
            f"  residual diagnosis not run: {self.not_diagnosed}" if self.not_diagnosed else None)
        return fit_report(self, lines, diagnosis=diagnosis)


def _maybe(a):
    return None if a is None else np.asarray(a).tolist()
