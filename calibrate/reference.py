"""Seed 003: the K matrix, offsets and axis angles of each sensor of an array, from known fields.

For every sensor the seed writes the known field ``B`` (array frame) as a linear function of the
outputs ``V``, its formula (1):

.. math:: B = K (V - V_0), \\qquad B_0 = K V_0,

with ``B_0`` the zero-point offsets in field units.  Its formula (2) ties ``K`` to the axis
angles: row ``c`` of ``K^{-1}`` is the axis' scale factor (``a, b, c``) times its direction
cosines in the array frame, ``(cos alpha_1, cos alpha_2, cos alpha_3)`` for the first axis,
beta for the second, gamma for the third, under the constraint (3) that the cosines of each axis
have unit norm.  So ``scale_c = |row_c(K^-1)|`` and ``alpha_j = arccos(row_1j / scale_1)``.

The fit regresses the outputs on the known fields, ``V = G B + V_0`` with ``G = K^{-1}``
(``scipy.linalg.lstsq`` per channel on the design ``[B, 1]``): the noise is in the outputs, not
in the reference fields, so this is the least-squares estimate the noise calls for; ``K = G^{-1}``.
The standard errors are ``s^2 (X^T X)^{-1}`` per channel with ``s^2`` the residual variance on
``n - 4`` degrees of freedom, propagated to ``K``, the offsets, the scales and the angles
through numerical Jacobians.  With exactly 4 fields nothing is left to estimate ``s``.

The design ``[B, 1]`` has rank 4 only when the fields are not coplanar (no plane, through zero
or not, holds all of them); otherwise the offsets and ``K`` cannot be separated and the fit
refuses (:class:`~calibrate.contract.CannotCalibrate`).

The reference fields are given in the array's frame, so every sensor's calibrated field
``K_s (V_s - V_0s)`` is in that common frame; each sensor's axes are also reported as scales,
angles between axes minus 90 degrees, and the rotation of its orthonormalised frame relative to
the array frame (:func:`calibrate.platform3d.axis_geometry`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lstsq

from compass.calibration_file import channel_entry, header
from compass.io.reference import ReferenceRecording

from .diagnosis.offsets import OffsetDiagnosis, Problem, diagnose_offsets, pooled_repeat_noise
from .contract import Calibration, Calibrator, CannotCalibrate, require_response, require_sane_cells
from .platform3d import axis_geometry

__all__ = ["ReferenceCalibrator", "SensorK", "ReferenceResult", "calibrate_reference", "fit_k"]

MAX_CONDITION = 1e8
"""Largest condition number of the column-scaled design ``[B, 1]`` accepted."""
WARN_CONDITION = 1e3
"""Above this the fields are nearly coplanar: the result is computed, with a warning."""
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

    @property
    def residual_rms(self) -> np.ndarray:
        """Per channel, output units (over the n - 4 degrees of freedom)."""
        return np.sqrt(np.sum(self.residuals**2, axis=0) / max(self.dof, 1))

    def field(self, outputs: np.ndarray) -> np.ndarray:
        """Calibrated field ``K (V - V_0)`` in the array frame, field units, shape (n, 3)."""
        return (np.asarray(outputs, float) - self.offset) @ self.k_matrix.T


@dataclass(frozen=True)
class ReferenceResult(Calibration):
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
    warnings: tuple = field(default_factory=tuple)
    diagnosis: OffsetDiagnosis | None = None
    not_diagnosed: str | None = None

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
        }

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
        if self.spread is not None:
            lines.append(f"  array: calibrated fields differ from the reference by {self.spread:.3g} rms (field units)")
        if self.diagnosis is not None:
            lines.append(self.diagnosis.format())
        elif self.not_diagnosed:
            lines.append(f"  residual diagnosis not run: {self.not_diagnosed}")
        for w in self.warnings:
            lines.append(f"  warning: {w}")
        return "\n".join(lines)


def _maybe(a):
    return None if a is None else np.asarray(a).tolist()


def _design_check(path: str, sensor: str, ref: np.ndarray) -> float:
    """Condition number of the column-scaled design ``[B, 1]``; CannotCalibrate when singular."""
    n = len(ref)
    if n < 4:
        raise CannotCalibrate(f"{path}: sensor '{sensor}' has {n} reference fields; K and the offsets need at least 4")
    design = np.hstack([ref, np.ones((n, 1))])
    norms = np.linalg.norm(design, axis=0)
    sv = np.linalg.svd(design / np.where(norms > 0, norms, 1.0), compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else np.inf
    if cond > MAX_CONDITION:
        centred = np.linalg.svd(ref - ref.mean(axis=0), compute_uv=False)
        what = ("all reference fields are the same" if centred[0] <= 1e-12 * max(np.abs(ref).max(), 1e-300) else
                "the reference fields lie on one line" if centred[1] <= 1e-9 * centred[0] else
                "the reference fields are coplanar (one plane holds them all)")
        raise CannotCalibrate(f"{path}: sensor '{sensor}': {what}, so K and the offsets cannot be separated "
                                  f"(condition number {cond:.3g} of the design [B, 1]); apply fields in at least "
                                  "4 directions that no plane contains")
    return cond


def fit_k(name: str, channels: tuple, reference: np.ndarray, outputs: np.ndarray) -> SensorK:
    """Least-squares ``K`` and offsets of one sensor (see the module docstring).

    Parameters
    ----------
    name : str
    channels : tuple of str
    reference : ndarray, shape (n, 3)
        Known fields, array frame, field units; n >= 4, not coplanar.
    outputs : ndarray, shape (n, 3)
        The sensor's outputs, output units.

    Returns
    -------
    SensorK
    """
    n = len(reference)
    design = np.hstack([reference, np.ones((n, 1))])
    coef, *_ = lstsq(design, outputs)  # (4, 3): rows G^T then V0
    g, v0 = coef[:3].T, coef[3]
    residuals = outputs - design @ coef
    dof = n - 4
    cov = None
    if dof > 0:
        s2 = np.sum(residuals**2, axis=0) / dof
        xtx_inv = np.linalg.inv(design.T @ design)
        # parameters: G row-major (channel c: entries 3c..3c+2), then V0; channels independent
        cov = np.zeros((12, 12))
        for c in range(3):
            idx = [3 * c, 3 * c + 1, 3 * c + 2, 9 + c]
            cov[np.ix_(idx, idx)] = s2[c] * xtx_inv
    return _sensor_k(name, channels, g, v0, cov, residuals, dof)


def _sensor_k(name: str, channels: tuple, g: np.ndarray, v0: np.ndarray, cov: np.ndarray | None,
              residuals: np.ndarray, dof: int) -> SensorK:
    """A :class:`SensorK` from ``G = K^-1``, ``V0`` and their covariance (G row-major, then V0; None: no sigmas)."""
    k = np.linalg.inv(g)
    geometry = axis_geometry(g)

    def derived(p):
        gg, vv = p[:9].reshape(3, 3), p[9:]
        kk = np.linalg.inv(gg)
        scale = np.linalg.norm(gg, axis=1)
        unit = gg / scale[:, None]
        angles = np.degrees(np.arccos(np.clip(unit, -1.0, 1.0)))
        return np.concatenate([kk.ravel(), vv, kk @ vv, scale, angles.ravel(), unit.ravel(), axis_geometry(gg)])

    base = derived(np.concatenate([g.ravel(), v0]))
    sig = None
    unit_cov = None
    if cov is not None:
        jac = _jacobian(derived, np.concatenate([g.ravel(), v0]))
        dcov = jac @ cov @ jac.T
        sig = np.sqrt(np.clip(np.diag(dcov), 0.0, None))
        unit_idx = np.arange(27, 36).reshape(3, 3)
        unit_cov = np.array([dcov[np.ix_(unit_idx[c], unit_idx[c])] for c in range(3)])

    def part(a, b, shape):
        return None if sig is None else sig[a:b].reshape(shape)

    return SensorK(name, tuple(channels), k, part(0, 9, (3, 3)), v0, part(9, 12, (3,)), base[12:15], part(12, 15, (3,)),
                   base[15:18], part(15, 18, (3,)), base[18:27].reshape(3, 3), part(18, 27, (3, 3)), unit_cov,
                   geometry, part(36, 45, (9,)), residuals, dof)


def _jacobian(f, p: np.ndarray) -> np.ndarray:
    """Central-difference Jacobian with steps relative to each parameter's size."""
    base = f(p)
    jac = np.empty((len(base), len(p)))
    for j in range(len(p)):
        h = np.zeros_like(p)
        h[j] = 1e-6 * max(abs(p[j]), 1e-3)
        jac[:, j] = (f(p + h) - f(p - h)) / (2 * h[j])
    return jac


def calibrate_reference(rec: ReferenceRecording, *, diagnose: bool = True, candidates=None) -> ReferenceResult:
    """K-matrix calibration of every sensor of an array from known reference fields.

    Parameters
    ----------
    rec : ReferenceRecording
    diagnose : bool
        Run the residual diagnosis (SPEC section 4, :func:`calibrate.diagnosis.offsets.diagnose_offsets`)
        over every sensor's channels and keep the effects it claims.
    candidates : sequence of str, optional
        Effects the diagnosis considers (default ``offset_drift``, needing ``t_s``, and
        ``temperature``, needing ``temp_c``).

    Returns
    -------
    ReferenceResult

    Raises
    ------
    CannotCalibrate
        Fewer than 4 fields or coplanar fields for some sensor, or a channel that does not follow
        the fields (constant, or a cell far off); the message names the file and the column.

    Notes
    -----
    The diagnosis's noise floor is the pooled scatter of rows that repeat one applied field (the
    same reference field at every sensor).  Without repeats it is each channel's residual rms of
    the base fit: the evidence for an effect is then conservative (the floor holds what the effect
    would explain) and ``unexplained`` is null (nothing to test the residual against).
    """
    conds = {s: _design_check(rec.path, s, rec.reference[s]) for s in rec.sensors}
    for s in rec.sensors:
        require_sane_cells(rec.path, rec.channels[s], rec.outputs[s], rec.rows)
    sensors = tuple(fit_k(s, rec.channels[s], rec.reference[s], rec.outputs[s]) for s in rec.sensors)
    for s in sensors:
        require_response(rec.path, s.channels, rec.outputs[s.name], s.residuals, rec.rows)
    warnings = []
    worst = max(conds, key=conds.get)
    if conds[worst] > WARN_CONDITION:
        warnings.append(f"the reference fields of sensor '{worst}' are nearly coplanar (condition number "
                        f"{conds[worst]:.3g}): K and the offsets are poorly separated; apply fields in more directions")
    if rec.reference[rec.sensors[0]].shape[0] == 4:
        warnings.append("exactly 4 reference fields: K and the offsets fit them exactly, so no uncertainty can be "
                        "estimated and no error would show; record more fields")
    diagnosis, not_diagnosed = None, None
    outputs = dict(rec.outputs)
    if not diagnose:
        not_diagnosed = "not run (calibrate_reference(..., diagnose=False))"
    elif sensors[0].dof <= 0:
        not_diagnosed = "exactly 4 reference fields: no residual to examine"
    else:
        diagnosis = _diagnose(rec, sensors, candidates)
        if diagnosis.effects:
            sensors, outputs = _with_effects(rec, sensors, diagnosis)
    spread = None
    if len(sensors) > 1:
        diffs = np.concatenate([s.field(outputs[s.name]) - rec.reference[s.name] for s in sensors])
        spread = float(np.sqrt(np.mean(diffs**2)))
    return ReferenceResult(sensors, len(rec.rows), float(max(conds.values())), spread, tuple(warnings), diagnosis,
                           not_diagnosed)


def _diagnose(rec: ReferenceRecording, sensors: tuple, candidates) -> OffsetDiagnosis:
    """The residual diagnosis over every sensor's channels (parameters: each sensor's G row-major, then V0)."""
    n_s = len(sensors)
    channels = tuple(ch for s in sensors for ch in s.channels)
    x_base = np.concatenate([np.concatenate([np.linalg.inv(s.k_matrix).ravel(), s.offset]) for s in sensors])
    refs = [rec.reference[s.name] for s in sensors]
    measured = np.hstack([rec.outputs[s.name] for s in sensors])

    def linear(x):
        return np.hstack([ref @ x[12 * i:12 * i + 9].reshape(3, 3).T for i, ref in enumerate(refs)])

    def residuals(x, delta):
        offsets = np.concatenate([x[12 * i + 9:12 * i + 12] for i in range(n_s)])
        return measured - linear(x) - offsets - delta, np.empty(0)

    _, groups = np.unique(np.round(np.hstack(refs), 9), axis=0, return_inverse=True)
    groups = groups.ravel()
    floor = pooled_repeat_noise(measured, groups)
    from_repeats = floor is not None
    if floor is None:
        groups = np.arange(len(measured))
        floor = np.concatenate([s.residual_rms for s in sensors])
    problem = Problem(channels, x_base, linear, residuals, floor, from_repeats, groups, k_channels=12 * n_s,
                      offset_index=np.concatenate([12 * i + 9 + np.arange(3) for i in range(n_s)]))
    return diagnose_offsets(problem, t_s=rec.t_s, temp_c=rec.temp_c, candidates=candidates)


def _with_effects(rec: ReferenceRecording, sensors: tuple, diagnosis: OffsetDiagnosis) -> tuple[tuple, dict]:
    """Each sensor refitted with the claimed effects, and its outputs at the effects' reference."""
    x, cov, c = diagnosis.x, diagnosis.covariance, 3 * len(sensors)
    n_effect = (x.size - 4 * c) / c  # effect parameters per channel (a shared time constant counts a part)
    out, corrected = [], {}
    for i, s in enumerate(sensors):
        idx = np.arange(12 * i, 12 * i + 12)
        g, v0 = x[idx[:9]].reshape(3, 3), x[idx[9:]]
        v_ref = rec.outputs[s.name] - diagnosis.delta[:, 3 * i:3 * i + 3]
        block = cov[np.ix_(idx, idx)]
        dof = int(len(v_ref) - 4 - np.ceil(n_effect))
        out.append(_sensor_k(s.name, s.channels, g, v0, block if np.all(np.isfinite(block)) else None,
                             v_ref - rec.reference[s.name] @ g.T - v0, dof))
        corrected[s.name] = v_ref
    return tuple(out), corrected


class ReferenceCalibrator(Calibrator):
    """Seed 003's K-matrix calibration of a sensor array (:func:`calibrate_reference`).

    Parameters
    ----------
    diagnose : bool
        Run the residual diagnosis (SPEC section 4).
    """

    kind = "reference"

    def __init__(self, *, diagnose: bool = True):
        self.diagnose = diagnose

    def fit(self, recording: ReferenceRecording) -> ReferenceResult:
        return calibrate_reference(recording, diagnose=self.diagnose)
