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

The verdict: ``unexplained`` when the chi-square of the |B| residual against the bench's noise is
more than 5 standard deviations above its degrees of freedom (the noise floor is the bench's, not
measured on these rows, so the test leaves room for the noise model's own error).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..diagnosis.evidence import Proposal, gather_forms, linearised_score, refit_from_better_start, select_effects
from ..effects import EffectForm, Recorded, TemperatureForm, TimeForm, why_no_temperature, why_no_time
from ..diagnosis.report import Diagnosis
from ..noise import chi2_sf
from .model import InstallationFit, Rows, effect_slice, fit_installation, residuals

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

    def n_params(self, n_channels):
        return n_channels


class _InTime(TimeForm, InstallationEffect):
    """The hard iron linear in ``t_s``."""


class _InTemperature(TemperatureForm, InstallationEffect):
    """The hard iron linear in ``temp_c``."""


_PER_AXIS = "per axis x, y, z of H, in the bench model's field units"
FORMS = {
    "offset_drift": (_InTime(
        "offset_drift", "linear", "the hard iron drifting with t_s, at a constant rate",
        f"hard_iron(t_s) = installation.hard_iron_ut + hard_iron_rate_per_s (t_s - reference.t_s), {_PER_AXIS}"),),
    "temperature": (_InTemperature(
        "temperature", "linear", "the hard iron changing linearly with temp_c",
        f"hard_iron(temp_c) = installation.hard_iron_ut + hard_iron_per_degc (temp_c - reference.temp_c), "
        f"{_PER_AXIS}"),),
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


def _regressors(t_s, temp_c) -> tuple[dict, dict]:
    """Each effect's regressor and reference (``{"t_s": ..}`` or ``{"temp_c": ..}``) on the rows."""
    regressors, references = {}, {}
    if why_no_time(t_s) is None:
        regressors["offset_drift"] = (t_s - t_s.mean()) / np.ptp(t_s)
        references["offset_drift"] = {"t_s": float(t_s.mean())}
    if why_no_temperature(temp_c) is None:
        regressors["temperature"] = temp_c - temp_c.mean()
        references["temperature"] = {"temp_c": float(temp_c.mean())}
    return regressors, references


def _parameters(name: str, values: np.ndarray, sigmas: np.ndarray, t_s) -> dict:
    """An effect's hard-iron change in H in physical units (field units per s, or per degC)."""
    label, per = ("hard_iron_rate_per_s", np.ptp(t_s)) if name == "offset_drift" else ("hard_iron_per_degc", 1.0)
    return {f"{axis}.{label}": {"value": float(v / per), "sigma": float(s / per)}
            for axis, v, s in zip("xyz", values, sigmas)}


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
    pool, skipped = gather_forms(FORMS, FORMS, lambda e: e.applicable(Recorded(t_s, temp_c)))
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
    return InstallationDiagnosis(final, rows, effects, block)
