"""Residual diagnosis of fits made against known inputs: the 3-D platform (seed 001) and reference fields (seed 003).

The loop of :mod:`calibrate.fourflip.diagnosis` (SPEC section 4; steps 2 and 3 and the last part of 4 are
:func:`calibrate.diagnosis.evidence.select_effects`) for a model whose diagnosed channels read

.. math:: v_{ic} = y_{ic}(p) + o_c + \\Delta_{ic}(q),

``y`` the linear response to the known field (platform pose or applied reference field), ``o`` the
channel offsets and ``Delta`` the sum of the effects' corrections (zero for the base model):

1. Noise floor per channel: the pooled scatter of repeated samples (the same pose, the same applied
   field) when the recording has repeats; else the base fit's own residual, and then nothing can be
   called unexplained (``unexplained: null``) and the evidence is conservative (the floor holds
   whatever an effect would explain).
2. Score (Lagrange-multiplier) test of every applicable form (:func:`calibrate.diagnosis.evidence.linear_score`,
   the current parameters projected out); the most promising form per effect is refitted.
3. The refit with the largest decisive evidence (:data:`~calibrate.diagnosis.evidence.DECISIVE_BIC`) is added
   when it explains a real share (:data:`~calibrate.diagnosis.evidence.MIN_SHARE`) of the structured residual
   and its parameters are determined; repeat (at most :data:`~calibrate.diagnosis.evidence.MAX_STEPS`).
4. ``unexplained`` (with a floor from repeats): a lack-of-fit test, the repeat groups' mean
   residuals against the floor (chi-square on ``groups x channels - parameters`` dof) with
   p below :data:`~calibrate.diagnosis.evidence.STRUCTURE_P`, or an rms more than
   :data:`~calibrate.diagnosis.evidence.FLOOR_MARGIN` above the floor.  If structure remains, nothing is
   claimed and the base fit is kept.

Effects (per diagnosed channel, output units; ``tau = (t - t_ref) / T`` with ``t_ref`` the first
sample and ``T`` the session, ``d = (temp - T_ref) / span`` with ``T_ref`` the mean of ``temp_c``;
every correction is zero at ``t_ref`` and ``T_ref``, so the file's offsets hold there):

``offset_drift`` (linear, quadratic, cubic)
    ``sum_k a_ck tau^k``, k = 1..degree.
``offset_drift`` (warm-up)
    ``A_c (1 - exp(-(t - t_ref) / tau_s))``, one time constant for every channel.
``temperature`` (offset; offset and gain)
    ``k_c d`` and, with the gain, ``g_c d y_c``.
``gain_drift`` (linear, quadratic)
    ``y_c sum_k g_ck tau^k``, k = 1..degree: the gain ``K (1 + sum_k g_ck tau^k)``.
``nonlinear_response`` (odd cubic)
    ``c_c y_c^3 / s_c^2`` with ``s_c`` the channel's largest linear response: only where the known
    inputs set ``y`` (the platform), not in a free tumble.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from scipy.optimize import least_squares

from ..noise import chi2_sf
from ..effects import (Basis, EffectForm, OddCubic, Recorded, TemperatureForm, TimePolynomial, WarmUpForm, settled,
                       time_powers, warm_up_tau_s)
from .evidence import (FitRecord, Proposal, determined, gather_forms, is_unexplained, linearised_score,
                       refit_from_better_start, select_effects)
from .forms import json_float, rms, session_bin
from .report import Diagnosis

__all__ = ["OffsetEffect", "FORMS", "GainDrift", "Problem", "Grouped", "SampleGroups", "OffsetDiagnosis",
           "diagnose_offsets", "pooled_repeat_noise", "lack_of_fit", "same_inputs"]

_FD_STEP = 1e-6
_SINGULAR_COND = 1e12


@dataclass(frozen=True)
class _Context:
    """Constants the effects are written against (output units, s, degC)."""

    channels: tuple
    scale: np.ndarray
    t_s: np.ndarray | None
    temp_c: np.ndarray | None
    basis: Basis

    @property
    def tau(self) -> np.ndarray:
        return self.basis.tau(self.t_s)

    @property
    def d(self) -> np.ndarray:
        return self.basis.d(self.temp_c)


class OffsetEffect(EffectForm):
    """One extension of a linear-response model (:class:`calibrate.effects.Effect`): its correction.

    Parameters are in units of each channel's full scale (:attr:`_Context.scale`);
    :meth:`report` turns them into output units.
    """

    def delta(self, q: np.ndarray, y: np.ndarray, ctx: _Context) -> np.ndarray:
        """Change of the predicted outputs, shape (n, c), output units, from the linear responses ``y``."""
        raise NotImplementedError

    def reference(self, ctx: _Context) -> dict:
        """Where the effect is zero (the file's offsets hold there)."""
        return {}

    def report(self, q, sigma, ctx: _Context) -> dict:
        """``{name: {"value", "sigma"}}`` in output units (named in each key)."""
        raise NotImplementedError


def _per_channel(ctx: _Context, label: str, values, sigmas) -> dict:
    return {f"{ch}.{label}": {"value": float(v), "sigma": float(s)} for ch, v, s in zip(ctx.channels, values, sigmas)}


class _AtFirstSample(OffsetEffect):
    def reference(self, ctx):
        return {"t_s": ctx.basis.t_ref_s}


@dataclass(frozen=True)
class PolynomialDrift(TimePolynomial, _AtFirstSample):
    """Each channel's offset a polynomial in time without constant term (``degree`` coefficients each)."""

    def delta(self, q, y, ctx):
        return time_powers(ctx.tau, self.degree) @ (q.reshape(self.degree, -1) * ctx.scale)

    def report(self, q, sigma, ctx):
        out = {}
        for k in range(1, self.degree + 1):
            unit = ctx.scale / ctx.basis.session_s**k
            label = "offset_rate_per_s" if k == 1 else f"offset_per_s{k}"
            sl = slice((k - 1) * len(ctx.channels), k * len(ctx.channels))
            out.update(_per_channel(ctx, label, q[sl] * unit, sigma[sl] * unit))
        return out


@dataclass(frozen=True)
class WarmUp(WarmUpForm, _AtFirstSample):
    """Offsets settling exponentially after switch-on: per-channel change, one ``log(tau / session)``."""

    def delta(self, q, y, ctx):
        tau = warm_up_tau_s(ctx.basis.session_s, q[-1])
        return np.outer(settled(ctx.t_s, ctx.basis.t_ref_s, tau), q[:-1] * ctx.scale)

    def report(self, q, sigma, ctx):
        tau = warm_up_tau_s(ctx.basis.session_s, q[-1])
        out = _per_channel(ctx, "offset_settled_change", q[:-1] * ctx.scale, sigma[:-1] * ctx.scale)
        out["tau_s"] = {"value": float(tau), "sigma": float(tau * sigma[-1])}
        return out


@dataclass(frozen=True)
class Temperature(TemperatureForm, OffsetEffect):
    """Each channel's offset (and, with ``gain``, its gain) linear in ``temp_c``."""

    gain: bool = False

    def n_params(self, c):
        return 2 * c if self.gain else c

    def delta(self, q, y, ctx):
        c = len(ctx.channels)
        out = np.outer(ctx.d, q[:c] * ctx.scale)
        return out + ctx.d[:, None] * q[c:] * y if self.gain else out

    def reference(self, ctx):
        return {"temp_c": ctx.basis.temp_ref_c}

    def report(self, q, sigma, ctx):
        c = len(ctx.channels)
        span = ctx.basis.temp_span_c
        unit = ctx.scale / span
        out = _per_channel(ctx, "offset_per_degc", q[:c] * unit, sigma[:c] * unit)
        if self.gain:
            out.update(_per_channel(ctx, "gain_rel_per_degc", q[c:] / span, sigma[c:] / span))
        return out


@dataclass(frozen=True)
class GainDrift(TimePolynomial, _AtFirstSample):
    """Each channel's gain a polynomial in time without constant term: ``y (sum_k g_ck tau^k)`` added."""

    def delta(self, q, y, ctx):
        return (time_powers(ctx.tau, self.degree) @ q.reshape(self.degree, -1)) * y

    def report(self, q, sigma, ctx):
        out = {}
        for k in range(1, self.degree + 1):
            label = "gain_rel_per_s" if k == 1 else f"gain_rel_per_s{k}"
            sl = slice((k - 1) * len(ctx.channels), k * len(ctx.channels))
            unit = 1.0 / ctx.basis.session_s**k
            out.update(_per_channel(ctx, label, q[sl] * unit, sigma[sl] * unit))
        return out


class OddCubicOutput(OddCubic, OffsetEffect):
    """Odd cubic per channel in its linear response: ``c y^3 / s^2`` (``c``: output change at full scale)."""

    def delta(self, q, y, ctx):
        u = y / ctx.scale
        return q * ctx.scale * (u * u * u)

    def report(self, q, sigma, ctx):
        return _per_channel(ctx, "cubic_at_full_scale", q * ctx.scale, sigma * ctx.scale)


_DRIFT = "channel offsets changing with t_s"
FORMS: dict = {
    "offset_drift": (PolynomialDrift("offset_drift", "linear", _DRIFT + ", at a constant rate", 1),
                     PolynomialDrift("offset_drift", "quadratic", _DRIFT + ", quadratic in time", 2),
                     PolynomialDrift("offset_drift", "cubic", _DRIFT + ", cubic in time", 3),
                     WarmUp("offset_drift", "warm-up", _DRIFT + ", settling exponentially (one time constant)")),
    "temperature": (Temperature("temperature", "offset", "channel offsets linear in temp_c"),
                    Temperature("temperature", "offset and gain", "channel offsets and gains linear in temp_c",
                                gain=True)),
    "gain_drift": (GainDrift("gain_drift", "linear", "channel gains changing with t_s, at a constant rate", 1),
                   GainDrift("gain_drift", "quadratic", "channel gains changing with t_s, quadratic in time", 2)),
    "nonlinear_response": (OddCubicOutput("nonlinear_response", "odd cubic",
                                         "outputs bending away from linear in the known field: an odd cubic per "
                                         "channel"),),
}
"""Each effect's forms, simplest first; the score test and the evidence (BIC) choose among them."""


@dataclass(frozen=True)
class Problem:
    """What a fit hands to the diagnosis.

    Attributes
    ----------
    channels : tuple of str
        The diagnosed output channels (c).
    x_base : ndarray, shape (k,)
        The base fit's parameters.
    linear : callable
        ``linear(x) -> (n, c)``: each channel's response to the known field, without offset, output units.
    residuals : callable
        ``residuals(x, delta) -> (r, other)``: the diagnosed channels' residuals (n, c), output
        units, with ``delta`` (n, c) added to their prediction, and any other weighted residuals
        of the joint fit (1-D, possibly empty; e.g. a tilt sensor's).
    floor : ndarray, shape (c,)
        Noise floor per channel, output units.
    floor_from_repeats : bool
        True when ``floor`` is the scatter of repeated samples (then ``unexplained`` can be judged).
    groups : ndarray of int, shape (n,)
        Repeat group of every sample (samples taken under the same known input).
    k_channels : int
        Base parameters acting on the diagnosed channels (the lack-of-fit test's dof).
    offset_index : ndarray of int, shape (c,)
        Where each channel's offset is in ``x`` (output units).
    grouped : Grouped, optional
        The same model on the means of samples taken under the same inputs, where the fits and
        score tests run (the residuals, chi-square and verdicts stay those of every sample).
    """

    channels: tuple
    x_base: np.ndarray
    linear: Callable
    residuals: Callable
    floor: np.ndarray
    floor_from_repeats: bool
    groups: np.ndarray
    k_channels: int
    offset_index: np.ndarray
    grouped: "Grouped | None" = None


@dataclass(frozen=True)
class Grouped:
    """A problem's sufficient statistics: the means of samples taken under the same inputs (:func:`same_inputs`).

    When a group's samples share the known input, ``t_s`` and ``temp_c``, every effect's
    correction is one value per group, so a residual's sum of squares over the samples is
    ``sum_g n_g (mean_g - prediction_g)^2`` plus the scatter within groups, which no parameter
    changes.  The fit on the group means weighted by ``sqrt(n_g)`` has the same minimum and the
    same ``J^T J`` at a cost independent of the number of repeats.  Samples within one of
    :data:`~calibrate.diagnosis.forms.TIME_BINS` bins of the session count as simultaneous: exact
    for a correction linear in time, within ``7e-5`` of a warm-up's size otherwise.

    Attributes
    ----------
    linear : callable
        ``linear(x) -> (g, c)`` at each group's input.
    residuals : callable
        ``residuals(x, delta) -> (r, other)``: the groups' mean residuals (g, c), output units, with
        ``delta`` (g, c) added to their prediction, and the other weighted residuals of the joint
        fit on the groups, each already times ``sqrt(n_g)``.
    counts : ndarray of int, shape (g,)
        Samples in each group.
    t_s, temp_c : ndarray, shape (g,), or None
        Each group's time and temperature.
    """

    linear: Callable
    residuals: Callable
    counts: np.ndarray
    t_s: np.ndarray | None
    temp_c: np.ndarray | None


@dataclass(frozen=True)
class OffsetDiagnosis(Diagnosis):
    """Outcome of the diagnosis.

    Attributes
    ----------
    x : ndarray
        Final parameters: the base ones, then each claimed effect's block (the base fit's when none).
    jac : ndarray
        Jacobian of the joint weighted residual at ``x``.
    covariance : ndarray
        ``(J^T J)^-1 chi2 / dof`` at ``x`` (inf when singular).
    delta : ndarray, shape (n, c)
        The claimed effects' correction of the diagnosed outputs (zeros when none).
    names : list of str
        Names of the effect parameters appended to ``x``.
    effects : tuple of dict
        ``{"name", "form", "reference", "parameters"}`` of each claimed effect: the file's ``effects``.
    block : dict
        The SPEC section 4 ``diagnosis`` block.
    """

    x: np.ndarray
    jac: np.ndarray
    covariance: np.ndarray
    delta: np.ndarray
    names: list
    effects: tuple
    block: dict


@dataclass(frozen=True)
class SampleGroups:
    """Samples taken under identical inputs: each sample's group and the groups' sizes and first samples."""

    index: np.ndarray
    counts: np.ndarray
    first: np.ndarray

    @classmethod
    def of(cls, *keys) -> "SampleGroups":
        """Groups of the rows equal in every key (arrays of n rows, 1-D or 2-D; None keys ignored)."""
        key = np.column_stack([k for k in keys if k is not None])
        _, first, index, counts = np.unique(key, axis=0, return_index=True, return_inverse=True, return_counts=True)
        return cls(index.ravel(), counts, first)

    def mean(self, values: np.ndarray | None) -> np.ndarray | None:
        """Each group's mean of ``values`` (n, k) or (n,), shape (g, k) or (g,); None for None."""
        if values is None:
            return None
        columns = np.reshape(values, (len(self.index), -1)).T
        means = np.column_stack([np.bincount(self.index, weights=v, minlength=len(self.counts)) for v in columns]) \
            / self.counts[:, None]
        return means if np.ndim(values) == 2 else means[:, 0]


def same_inputs(key: np.ndarray, t_s: np.ndarray | None, temp_c: np.ndarray | None) -> SampleGroups:
    """Samples under one known input (equal ``key`` rows), at one ``temp_c``, in one bin of the session.

    The bins are :func:`~calibrate.diagnosis.forms.session_bin`'s; without ``t_s``, the input and ``temp_c`` alone.
    """
    return SampleGroups.of(key, session_bin(t_s), temp_c)


def pooled_repeat_noise(values: np.ndarray, groups: np.ndarray) -> np.ndarray | None:
    """Pooled within-group standard deviation per column; None when fewer than 3 repeat dof."""
    counts = np.bincount(groups)
    dof = int(np.sum(counts - 1))
    if dof < 3:
        return None
    means = np.array([np.bincount(groups, weights=v) / counts for v in values.T]).T
    return np.sqrt(np.sum((values - means[groups]) ** 2, axis=0) / dof)


def lack_of_fit(weighted: np.ndarray, groups: np.ndarray, k: int) -> tuple[float, int, float]:
    """Lack-of-fit chi-square of a weighted residual: its repeat groups' means against white noise.

    Parameters
    ----------
    weighted : ndarray, shape (n, c)
        Residual over the noise floor (the floor from the scatter within groups).
    groups : ndarray of int, shape (n,)
    k : int
        Parameters fitted to these channels.

    Returns
    -------
    delta_chi2 : float
        ``sum_g n_g mean_g^2`` over groups and channels.
    dof : int
        ``groups x channels - k``.
    p_value : float
    """
    counts = np.bincount(groups)
    sums = np.array([np.bincount(groups, weights=w) for w in weighted.T]).T
    stat = float(np.sum(sums**2 / counts[:, None]))
    dof = int(np.count_nonzero(counts) * weighted.shape[1] - k)
    return stat, dof, chi2_sf(stat, dof) if dof > 0 else 1.0


def _covariance(jac: np.ndarray, chi2: float, dof: int) -> np.ndarray:
    """``(J^T J)^-1 chi2 / dof`` (column-scaled; inf when singular)."""
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    jtj = (jac / scale).T @ (jac / scale)
    if np.linalg.cond(jtj) > _SINGULAR_COND:
        return np.full(jtj.shape, np.inf)
    return np.linalg.inv(jtj) / np.outer(scale, scale) * chi2 / max(dof, 1)


def diagnose_offsets(problem: Problem, *, t_s=None, temp_c=None, candidates=None) -> OffsetDiagnosis:
    """Run the diagnosis loop on a fit (see the module docstring).

    Parameters
    ----------
    problem : Problem
    t_s, temp_c : ndarray, shape (n,), optional
        Time (s) and temperature (degC) of each sample.
    candidates : sequence of str, optional
        Effect names to consider (default: ``offset_drift``, ``temperature``, ``gain_drift``).

    Returns
    -------
    OffsetDiagnosis

    Raises
    ------
    ValueError
        An unknown candidate name.
    """
    names = ["offset_drift", "temperature", "gain_drift"] if candidates is None else list(candidates)
    unknown = [c for c in names if c not in FORMS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; known: {', '.join(FORMS)}")
    floor = np.asarray(problem.floor, dtype=float)
    c = len(problem.channels)
    kb = problem.x_base.size
    scale = np.max(np.abs(problem.linear(problem.x_base)), axis=0)
    ctx = _Context(tuple(problem.channels), np.where(scale > 0, scale, 1.0), t_s, temp_c, Basis.of(t_s, temp_c))
    pool, skipped = gather_forms(names, FORMS, lambda e: e.applicable(Recorded(t_s, temp_c)))
    grouped = problem.grouped
    # where the fits run: the group means (each residual times sqrt(n_g)), else every sample
    every_sample = (problem.linear, ctx, len(problem.groups))
    fit_view, fit_residuals, root_n = every_sample, problem.residuals, 1.0
    if grouped is not None:
        fit_view = (grouped.linear, replace(ctx, t_s=grouped.t_s, temp_c=grouped.temp_c), len(grouped.counts))
        fit_residuals, root_n = grouped.residuals, np.sqrt(grouped.counts)[:, None]

    def delta(x, effects, view=every_sample):
        linear, context, rows = view
        out = np.zeros((rows, c))
        y, i = (linear(x[:kb]) if effects else None), kb
        for e in effects:
            out = out + e.delta(x[i:i + e.n_params(c)], y, context)
            i += e.n_params(c)
        return out

    def weighted(x, effects):
        r, other = fit_residuals(x[:kb], delta(x, effects, fit_view))
        return np.concatenate([(r * root_n / floor).ravel(), np.ravel(other)])

    def fit(effects, x0) -> FitRecord:
        res = least_squares(weighted, x0, args=(effects,), method="lm", x_scale="jac", max_nfev=100 * (x0.size + 1))
        if grouped is None:
            chi2, n_obs = float(res.fun @ res.fun), res.fun.size
            r, _ = problem.residuals(res.x[:kb], delta(res.x, effects))
        else:  # the chi-square of every sample: the groups' plus the scatter within them
            r, other = problem.residuals(res.x[:kb], delta(res.x, effects))
            other = np.ravel(other)
            chi2, n_obs = float(np.sum((r / floor) ** 2) + other @ other), r.size + other.size
        return FitRecord(tuple(effects), res.x, res.jac, _covariance(res.jac, chi2, n_obs - res.x.size), r, chi2,
                         n_obs, bool(res.success), str(res.message))

    def verdict(f: FitRecord):
        if not problem.floor_from_repeats:
            return None, None
        k = problem.k_channels + f.x.size - kb
        structure = lack_of_fit(f.residuals / floor, problem.groups, k)
        return structure, is_unexplained(structure[2], rms(f.residuals), rms(floor))

    def claim(p: Proposal, measured: dict) -> dict:
        start = p.trial.x.size - p.effect.n_params(c)
        return {
            "added": p.effect.name,
            "form": p.effect.form,
            "residual_rms": rms(p.trial.residuals),
            **p.evidence(p.effect.n_params(c)),
            "parameters": p.effect.report(p.trial.x[start:], np.sqrt(np.diag(p.trial.covariance))[start:], ctx),
        }

    base = fit((), problem.x_base)
    chosen = select_effects(
        base, pool,
        score=lambda current, effect: linearised_score(weighted, current, effect, effect.score_points(c), _FD_STEP),
        refit=lambda current, effect, start: refit_from_better_start(fit, weighted, current, effect,
                                                                     effect.score_points(c)[0], start),
        n_params=lambda e: e.n_params(c), log_n=np.log(base.n_obs),
        base_step={"model": "base", "residual_rms": rms(base.residuals)},
        write_step=claim, verdict=verdict, checks=(determined("the base model"),))
    current, steps, structure, unexplained = chosen.fit, chosen.steps, chosen.structure, chosen.unexplained

    sig = np.sqrt(np.diag(current.covariance))
    change = current.x[problem.offset_index] - problem.x_base[problem.offset_index]
    block = {
        "noise_floor": rms(floor),
        "noise_floor_per_channel": [float(v) for v in floor],
        "noise_floor_source": ("pooled scatter of repeated samples under the same known input" if
                               problem.floor_from_repeats else
                               "the base fit's own residual (no repeated samples): 'unexplained' cannot be judged and "
                               "the evidence for an effect is conservative"),
        "steps": steps,
        "effects": [e.name for e in current.effects],
        "residual_rms_before": steps[0]["residual_rms"],
        "residual_rms_after": rms(current.residuals),
        "unexplained": unexplained,
        "structure_test": None if structure is None else
        {"name": "lack-of-fit", "kind": "lack of fit of the repeat groups' mean residual", "delta_chi2": structure[0], "dof": structure[1],
         "p_value": structure[2]},
        "not_claimed": chosen.not_claimed,
        "not_applicable": skipped,
        "offset_change": {"channels": list(problem.channels), "value": change.tolist(),
                          "sigma": [json_float(v) for v in sig[problem.offset_index]]},
    }
    names_out, effects_out = [], []
    for step, e in zip(steps[1:], current.effects):
        names_out += [f"{e.name}[{j}]" for j in range(e.n_params(c))]
        effects_out.append({"name": e.name, "form": e.form, "reference": e.reference(ctx),
                            "parameters": step["parameters"]})
    return OffsetDiagnosis(current.x, current.jac, current.covariance, delta(current.x, current.effects), names_out,
                           tuple(effects_out), block)
