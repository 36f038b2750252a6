"""The K-matrix fit (seed 003): :func:`calibrate_reference`, :func:`fit_k` and :class:`ReferenceCalibrator`."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.linalg import block_diag, lstsq

from compass.io.reference import ReferenceRecording

from ..contract import Calibrator, CannotCalibrate, FitStatistics, require_response, require_sane_cells
from ..health import AXIS_TOLERANCE_DEG, ChannelHealth, check_channels
from ..health import to_json as health_json
from ..diagnosis.offsets import Grouped, OffsetDiagnosis, Problem, diagnose_offsets, pooled_repeat_noise, same_inputs
from ..platform3d import axis_geometry
from .result import ReferenceResult, SensorK

MAX_CONDITION = 1e8
"""Largest condition number of the column-scaled design ``[B, 1]`` accepted."""


WARN_CONDITION = 1e3
"""Above this the fields are nearly coplanar: the result is computed, with a warning."""


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
                   geometry, part(36, 45, (9,)), residuals, dof, cov)


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
    return ReferenceResult(sensors, len(rec.rows), float(max(conds.values())), spread, _statistics(sensors, diagnosis),
                           tuple(warnings), diagnosis, not_diagnosed)


def _statistics(sensors: tuple, diagnosis: OffsetDiagnosis | None) -> FitStatistics:
    """The joint statistics: each sensor's ``G`` and ``V_0``, then the claimed effects' parameters.

    The noise floor is the diagnosis's per channel (the scatter of repeated fields, else the base
    fit's residual); without a diagnosis, each channel's residual over its dof (chi2 = dof).
    """
    names = tuple(n for s in sensors for n in s.parameter_names)
    residuals = np.hstack([s.residuals for s in sensors])
    if diagnosis is not None:
        values, cov, names = diagnosis.x, diagnosis.covariance, names + tuple(diagnosis.names)
        floor = np.asarray(diagnosis.block["noise_floor_per_channel"], dtype=float)
    else:
        values = np.concatenate([np.concatenate([np.linalg.inv(s.k_matrix).ravel(), s.offset]) for s in sensors])
        cov = block_diag(*[np.full((12, 12), np.inf) if s.covariance is None else s.covariance for s in sensors])
        floor = np.concatenate([s.residual_rms for s in sensors])
    dof = residuals.size - values.size
    chi2 = float(np.sum((residuals / floor) ** 2)) if dof > 0 else float("nan")
    return FitStatistics(names, values, cov, chi2, dof, chi2 + values.size * np.log(residuals.size), True,
                         "linear least squares" + (" with the claimed effects" if diagnosis is not None else ""))


def _diagnose(rec: ReferenceRecording, sensors: tuple, candidates) -> OffsetDiagnosis:
    """The residual diagnosis over every sensor's channels (parameters: each sensor's G row-major, then V0)."""
    n_s = len(sensors)
    channels = tuple(ch for s in sensors for ch in s.channels)
    x_base = np.concatenate([np.concatenate([np.linalg.inv(s.k_matrix).ravel(), s.offset]) for s in sensors])
    refs = [rec.reference[s.name] for s in sensors]
    measured = np.hstack([rec.outputs[s.name] for s in sensors])

    def model(refs, measured):
        def linear(x):
            return np.hstack([ref @ x[12 * i:12 * i + 9].reshape(3, 3).T for i, ref in enumerate(refs)])

        def residuals(x, delta):
            offsets = np.concatenate([x[12 * i + 9:12 * i + 12] for i in range(n_s)])
            return measured - linear(x) - offsets - delta, np.empty(0)

        return linear, residuals

    _, groups = np.unique(np.round(np.hstack(refs), 9), axis=0, return_inverse=True)
    groups = groups.ravel()
    same = same_inputs(groups, rec.t_s, rec.temp_c)  # the fits run on their means
    grouped = None if len(same.counts) == len(groups) else Grouped(
        *model([ref[same.first] for ref in refs], same.mean(measured)), same.counts, same.mean(rec.t_s),
        same.mean(rec.temp_c))
    floor = pooled_repeat_noise(measured, groups)
    from_repeats = floor is not None
    if floor is None:
        groups = np.arange(len(measured))
        floor = np.concatenate([s.residual_rms for s in sensors])
    problem = Problem(channels, x_base, *model(refs, measured), floor, from_repeats, groups, k_channels=12 * n_s,
                      offset_index=np.concatenate([12 * i + 9 + np.arange(3) for i in range(n_s)]), grouped=grouped)
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

    def __init__(self, *, diagnose: bool = True, axis_tolerance_deg: float | None = AXIS_TOLERANCE_DEG,
                 direction_accuracy_deg: float | None = None):
        self.diagnose = diagnose
        self.axis_tolerance_deg, self.direction_accuracy_deg = axis_tolerance_deg, direction_accuracy_deg

    def fit(self, recording: ReferenceRecording) -> ReferenceResult:
        result = calibrate_reference(recording, diagnose=self.diagnose)
        health = channel_health(result, recording)
        warnings = check_channels(recording.path, health, axis_tolerance_deg=self.axis_tolerance_deg,
                                  direction_accuracy_deg=self.direction_accuracy_deg)
        return replace(result, warnings=result.warnings + warnings, health=health_json(health))


def channel_health(result: ReferenceResult, recording: ReferenceRecording) -> list[ChannelHealth]:
    """Each channel's response to the whole field (its scale factor times the median |reference field|),
    its residual rms as the noise, its sensing direction (a row of ``K^-1``, reference frame) and sigma."""
    from compass.frames import direction_sigma_deg

    out = []
    for s in result.sensors:
        field = float(np.median(np.linalg.norm(recording.reference[s.name], axis=1)))
        rows = np.linalg.inv(s.k_matrix)
        for c, name in enumerate(s.channels):
            sigma = (float(s.scale_sigma[c]) * field if s.scale_sigma is not None
                     else float(s.residual_rms[c]) * np.sqrt(2.0 / result.n_fields))
            out.append(ChannelHealth(name, float(s.scale[c]) * field, sigma, float(s.residual_rms[c]),
                                     rows[c] / np.linalg.norm(rows[c]),
                                     None if s.direction_covariance is None else
                                     float(direction_sigma_deg(s.direction_covariance[c]))))
    return out
