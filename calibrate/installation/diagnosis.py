"""Residual diagnosis of an installation calibration (SPEC section 4), on the shared evidence loop.

The loop is :func:`calibrate.diagnosis.evidence.select_effects`, as for every kind: a score test
per candidate, a full refit of the promising ones, a decisive delta-BIC, the share veto
(:data:`~calibrate.diagnosis.evidence.MIN_SHARE`), and, when structure remains after effects were
added, none claimed (each named as not claimed) and the base fit kept.

Effects are changes of the hard iron ``h`` in H (:mod:`calibrate.installation.model`), zero at
their reference (the rows' mean time and temperature, where the file's hard iron holds):

``offset_drift`` (linear)
    ``h + g (t - t_ref) / T`` (``T`` the span of ``t_s``): a hard iron wandering steadily.
``temperature`` (linear)
    ``h + g (T - T_ref)``: a hard iron linear in ``temp_c``.
``gain_drift`` (linear)
    ``b / (1 + g (t - t_ref) / T)`` per axis of H before the hard iron is taken off: the sensor's
    gains changing with time (``b = (1 + g tau)(S B_H + h)``), as a room warming with no ``temp_c``.

What ``gain_drift`` can and cannot tell.  The rows constrain ``|B_H|`` and the field-gravity angle
to be constant.  The common part of ``g`` grows ``|B_H|`` in time: what a site field whose
magnitude changed during the recording does, so it is identifiable only under the assumption
that |B| stayed constant (a claimed gain drift on a changing field is that change).  The per-axis
parts move the field's direction against gravity and bend its circle or sphere in time: a tumble
and a swing with heel (the vertical field changes) determine all three.  A level swing keeps the
vertical field constant: its vertical gain change ``g_z tau B_z`` is a vertical offset drift, the
``offset_drift``'s z component, not another effect, so ``gain_drift`` is not applicable there
(said in ``not_applicable``; the horizontal parts are not tried alone).

The verdict: ``unexplained`` when the chi-square of the |B| residual against the bench's noise is
more than 5 standard deviations above its degrees of freedom (the noise floor is the bench's, not
measured on these rows, so the test leaves room for the noise model's own error).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..diagnosis.blocks import TIME_BLOCKS, level_heading_sigma_deg, time_blocks, widened_in_time
from ..diagnosis.evidence import Proposal, gather_forms, linearised_score, refit_from_better_start, select_effects
from ..effects import EffectForm, Recorded, TemperatureForm, TimeForm, why_no_temperature, why_no_time
from ..diagnosis.report import Diagnosis
from ..diagnosis.robust import extra_sigma
from ..noise import chi2_sf
from .model import InstallationFit, Rows, coordinates, effect_slice, fit_installation, is_level, residuals

__all__ = ["FORMS", "InstallationEffect", "InstallationDiagnosis", "UNEXPLAINED_WARNING", "diagnose_installation"]

UNEXPLAINED_SIGMAS = 5.0
"""The |B| residual's chi-square this many standard deviations above its dof is unexplained."""
UNEXPLAINED_WARNING = ("the |B| residual stays above the bench's noise floor: structure the installation model does "
                       "not explain (a nonlinear or field-dependent iron, a field that changed during the recording, "
                       "or a bench model that does not fit this sensor); the uncertainties are then optimistic")
_FD_STEP = 1e-4


_AXES_H = 3
"""The effects move the hard iron, one parameter per axis of H."""


@dataclass(frozen=True)
class InstallationEffect(EffectForm):
    """A change of the hard iron (:class:`calibrate.effects.Effect`), with its formula in the file's names
    (the file reads without this code)."""

    formula: str = ""
    """The hard iron's change, what the file's effect entry holds under ``form``."""
    scales: bool = False
    """True: the effect changes the gains of the axes of H (:func:`calibrate.installation.model.field_h`), not the
    hard iron."""

    def n_params(self, n_channels):
        return n_channels


class _InTime(TimeForm, InstallationEffect):
    """The hard iron linear in ``t_s``."""


class _InTemperature(TemperatureForm, InstallationEffect):
    """The hard iron linear in ``temp_c``."""


class _GainInTime(TimeForm, InstallationEffect):
    """The gains of the axes of H linear in ``t_s``; not on a level swing (module docstring)."""

    def applicable(self, columns):
        why = super().applicable(columns)
        if why is None and getattr(columns, "level", False):
            why = ("a level swing keeps the vertical field constant: a vertical gain change is then a vertical "
                   "offset drift (offset_drift's z), and the horizontal gains alone are not tried")
        return why


_PER_AXIS = "per axis x, y, z of H, in the bench model's field units"
FORMS = {
    "offset_drift": (_InTime(
        "offset_drift", "linear", "the hard iron drifting with t_s, at a constant rate",
        f"hard_iron(t_s) = installation.hard_iron_ut + hard_iron_rate_per_s (t_s - reference.t_s), {_PER_AXIS}"),),
    "temperature": (_InTemperature(
        "temperature", "linear", "the hard iron changing linearly with temp_c",
        f"hard_iron(temp_c) = installation.hard_iron_ut + hard_iron_per_degc (temp_c - reference.temp_c), "
        f"{_PER_AXIS}"),),
    "gain_drift": (_GainInTime(
        "gain_drift", "linear", "the gains of the axes of H drifting with t_s, at a constant rate",
        "field(t_s) = field / (1 + gain_rate_rel_per_s (t_s - reference.t_s)) per axis x, y, z of H, before "
        "installation.hard_iron_ut is taken off", scales=True),),
}
"""Each effect's forms for the installation, simplest first."""


@dataclass(frozen=True)
class InstallationDiagnosis(Diagnosis):
    """Outcome of the residual diagnosis of an installation fit.

    Attributes
    ----------
    fit : InstallationFit
        The fit with the claimed effects (the base fit when none is claimed).
    rows : Rows
        The rows, with the regressors of the effects that were tried.
    effects : tuple of dict
        ``{"name", "form", "reference", "parameters"}`` of each claimed effect: the file's ``effects``.
    block : dict
        The SPEC section 4 ``diagnosis`` block.
    """

    fit: InstallationFit
    rows: Rows
    effects: tuple
    block: dict


@dataclass(frozen=True)
class _Columns(Recorded):
    """What an effect's ``applicable`` reads: the recording's columns, and whether it is a level swing."""

    level: bool = False


def _regressors(t_s, temp_c) -> tuple[dict, dict]:
    """Each effect's regressor and reference (``{"t_s": ..}`` or ``{"temp_c": ..}``) on the rows."""
    regressors, references = {}, {}
    if why_no_time(t_s) is None:
        regressors["offset_drift"] = (t_s - t_s.mean()) / np.ptp(t_s)
        references["offset_drift"] = {"t_s": float(t_s.mean())}
        regressors["gain_drift"] = regressors["offset_drift"]  # both zero at the mean time
        references["gain_drift"] = references["offset_drift"]
    if why_no_temperature(temp_c) is None:
        regressors["temperature"] = temp_c - temp_c.mean()
        references["temperature"] = {"temp_c": float(temp_c.mean())}
    return regressors, references


def _parameters(name: str, values: np.ndarray, sigmas: np.ndarray, t_s) -> dict:
    """An effect's change in H in physical units (hard iron: field units per s or per degC; gains: per s)."""
    label, per = {"offset_drift": ("hard_iron_rate_per_s", np.ptp(t_s)), "gain_drift": ("gain_rate_rel_per_s", np.ptp(t_s)),
                  "temperature": ("hard_iron_per_degc", 1.0)}[name]
    return {f"{axis}.{label}": {"value": float(v / per), "sigma": float(s / per)}
            for axis, v, s in zip("xyz", values, sigmas)}


def _widen(fit: InstallationFit, rows: Rows, priors: dict, t_s) -> tuple[InstallationFit, dict]:
    """The fit with its covariance widened over blocks of time, and the ``unexplained_cost``.

    The sandwich is taken in the coordinates the fit moved (:func:`calibrate.installation.model.coordinates`),
    its bread from every row (priors included), its meat from the data rows only (a row's |B|,
    angle and heading residuals share the sample's block; each sort of row gets its own level per
    block beside the hard iron's, :func:`calibrate.diagnosis.blocks.widened_in_time`); the held
    parameters' prior part of the covariance is kept as it was.
    """
    n = fit.n_rows
    n_data = n * (3 if rows.heading_ref is not None else 2)
    t, dependent = coordinates(fit.fixed, "field" not in priors)
    moved = ~fit.fixed
    if dependent is not None:
        moved[dependent] = False
    jac = fit.jac
    bread = np.linalg.pinv(jac.T @ jac)
    scale = max(1.0, fit.chi2 / max(fit.n_obs - fit.n_free, 1))
    weighted = residuals(fit.x, rows, fit.effects, priors)[:n_data]
    order = np.arange(n, dtype=float) if t_s is None else np.asarray(t_s, dtype=float)
    blocks = np.tile(time_blocks(order), n_data // n)
    naive = bread * scale
    hard = np.flatnonzero(moved).searchsorted(np.flatnonzero(moved[:3]))  # the hard iron's moved columns
    wide = widened_in_time(jac[:n_data], weighted, blocks, naive, bread=bread, hard=hard,
                           row_sort=np.repeat(np.arange(n_data // n), n))  # |B|, angle, heading rows
    lift = t[:, moved]
    covariance = fit.covariance + lift @ (wide - naive) @ lift.T
    naive_h, wide_h = np.sqrt(np.diag(fit.covariance)[:3]), np.sqrt(np.diag(covariance)[:3])
    noise_h = np.sqrt(np.diag(fit.covariance + lift @ (bread - naive) @ lift.T)[:3])  # the floor's alone
    heading = [level_heading_sigma_deg(*sig[:2], fit.x[9], fit.x[10]) for sig in (naive_h, wide_h)]
    cost = {"hard_iron": {axis: {"naive": float(a), "widened": float(b), "noise_only": float(c)}
                          for axis, a, b, c in zip("xyz", naive_h, wide_h, noise_h)},
            "heading_deg": float(extra_sigma(heading[1], heading[0])),
            "heading_sigma_deg": {"naive": heading[0], "widened": heading[1]},
            "method": f"a hard-iron walk between {TIME_BLOCKS} blocks of consecutive rows propagated to the fit, "
                      "the CR2 sandwich over them for the rest (calibrate.diagnosis.blocks; with a walk the noise's "
                      "part is scaled by what the walk leaves, not by the naive's chi-square, which counted the walk "
                      "as white noise: the widened sigma may then be under the naive, never under the noise's alone); "
                      "the heading sigma from the hard iron alone, a level housing, RMS over headings"}
    return replace(fit, covariance=covariance), cost


def diagnose_installation(rows: Rows, priors: dict, base: InstallationFit, *, t_s=None, temp_c=None,
                          diagnose: bool = True) -> InstallationDiagnosis:
    """Run the evidence loop on an installation's base fit.

    Parameters
    ----------
    rows : Rows
        The rows of ``base`` (their ``regressors`` are replaced by the effects' the recording can show).
    priors : dict
        The fit's priors (:func:`calibrate.installation.model.fit_installation`).
    base : InstallationFit
        The fit without effects.
    t_s, temp_c : ndarray, shape (n,), optional
        Time (s) and temperature (degC) of the rows.
    diagnose : bool
        False: no effect is tried; the verdict is still given.

    Returns
    -------
    InstallationDiagnosis
    """
    regressors, references = _regressors(t_s, temp_c)
    rows = replace(rows, regressors=regressors)
    columns = _Columns(t_s, temp_c, level=is_level(rows))
    pool, skipped = gather_forms(FORMS, FORMS, lambda e: e.applicable(columns))
    if not diagnose:
        pool, skipped = [], {"diagnosis": "not run (--no-diagnose)"}
    def weighted(x, effects):
        return residuals(x, rows, effects, priors)

    def fit(effects, x0):  # what the base fit held stays held; the effects' parameters move
        return fit_installation(rows, effects, priors, x0,
                                np.concatenate([base.fixed, np.zeros(x0.size - base.fixed.size, dtype=bool)]))

    def refit(current, effect, start):
        return refit_from_better_start(fit, weighted, current, effect, effect.score_points(_AXES_H)[0], start)

    def score(current, effect):
        return linearised_score(weighted, current, effect, effect.score_points(_AXES_H), _FD_STEP)

    def claim(p: Proposal, measured: dict) -> dict:
        where = effect_slice(rows, p.trial.effects, p.effect.name)
        sigma = np.sqrt(np.diag(p.trial.covariance))[where]
        return {"added": p.effect.name, "form": p.effect.form, "residual_rms": p.trial.residual_rms,
                **p.evidence(p.effect.n_params(_AXES_H)), **measured, "parameters": _parameters(p.effect.name, p.trial.x[where], sigma, t_s)}

    def verdict(f: InstallationFit):
        dof = f.n_rows - 1
        structure = {"name": "chi-square of |B| - F against the bench's noise, 5-sigma rule", "chi2": f.chi2_mag,
                     "dof": dof, "p_value": chi2_sf(f.chi2_mag, dof)}
        return structure, bool(f.chi2_mag > dof + UNEXPLAINED_SIGMAS * np.sqrt(2.0 * dof))

    chosen = select_effects(base, pool, score=score, refit=refit, n_params=lambda e: e.n_params(_AXES_H), log_n=np.log(base.n_obs),
                            base_step={"model": "base", "residual_rms": base.residual_rms}, write_step=claim,
                            verdict=verdict)
    final, steps = chosen.fit, chosen.steps
    cost = None
    if chosen.unexplained:  # the sigmas grow to cover the structure that remains (calibrate.diagnosis.blocks)
        final, cost = _widen(final, rows, priors, t_s)
    effects = tuple({"name": step["added"], "form": effect.formula, "reference": references[step["added"]],
                     "parameters": step["parameters"]} for step, effect in zip(steps[1:], final.effects))
    sigma_h = np.sqrt(np.diag(final.covariance))[:3]
    block = {
        "subject": "|B_H| - F",
        "noise_floor": rows.sigma_b,
        "noise_floor_source": "the bench calibration's channel noise, through its sensing matrix",
        "steps": steps,
        "effects": [e.name for e in final.effects],
        "residual_rms_before": steps[0]["residual_rms"],
        "residual_rms_after": final.residual_rms,
        "unexplained": chosen.unexplained,
        "structure_test": chosen.structure,
        "not_claimed": chosen.not_claimed,
        "not_applicable": skipped,
        "hard_iron_change": {"value": (final.x[:3] - base.x[:3]).tolist(), "sigma": sigma_h.tolist()},
    }
    if cost is not None:
        block["unexplained_cost"] = cost
    return InstallationDiagnosis(final, rows, effects, block)
