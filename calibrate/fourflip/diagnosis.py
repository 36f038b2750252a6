"""Residual diagnosis: find what the four-flip model lacks, add it, report before and after.

The loop (SPEC section 4; steps 3, 4 and 6 are :func:`calibrate.diagnosis.evidence.select_effects`, shared
with the tumble and the fits against known inputs):

1. Noise floor per channel from second differences of the raw outputs (:mod:`calibrate.noise`);
   it weights the fit and is the yardstick of "explained".
2. Fit the base model (linear channels, ideal bench).
3. For every candidate effect the recording can show, a score test linearises the effect at
   zero around the current fit and measures the chi-square drop its parameters could buy after
   removing what the current parameters already absorb: the residual's structure traced to the
   effect's signature.  The promising candidates are refitted in full.
4. The candidate with the largest decisive evidence (delta-BIC above
   :data:`~calibrate.diagnosis.evidence.DECISIVE_BIC`) is added, provided it explains a real share
   (:data:`~calibrate.diagnosis.evidence.MIN_SHARE`) of the structured residual; repeat.
5. ``unexplained`` is true when the final residual still carries structure above the floor:
   a harmonic regression per channel and flip against the turntable angle (and a trend) whose
   chi-square drop is significant, or an rms more than :data:`~calibrate.diagnosis.evidence.FLOOR_MARGIN` above the floor.
6. Effects are claimed only when, with them, the residual is explained.  If structure remains,
   the added effects may have absorbed part of an effect the toolkit does not model (a field
   gradient with the sensor off the turntable axis mimics an encoder error), so none is claimed,
   the base model is kept and every candidate tried is reported with its evidence.
   The final fit's response (its nonlinear response, or the linear one where the loop named none and the residual
   is white: a cubic at steep dip whose first harmonic reads as a gain) is tested against a general curve of each
   channel's field (:func:`calibrate.fourflip._form.response_form_test`; a linear one also on the cubic's columns
   alone).  Where a nonlinear response's form is
   rejected, an effect proposed next that takes less than that curve would is not claimed
   (:func:`~calibrate.fourflip._form.response_form_check`: a knee's misfit reads as per-flip offsets, a platform
   field's signature); where the final fit's is, a fit the structure test calls white is called unexplained with
   the response kept (the vocabulary's nearest curve; a linear file would be further off) and widened, also for
   the curve's static misfit
   (:func:`~calibrate.fourflip._form.response_misfit`: its bias in the parameters, which no structure in time
   covers).
7. A fit the structure test calls white (explained, or unexplained by the form test alone, whose misfit cover then
   comes on top) is asked once more, across the recording: the residual summed over 10 s blocks, the band
   test of the unexplained widening (:func:`calibrate.diagnosis.robust.band_p_values`) as one family
   (:func:`calibrate.diagnosis.robust.family_p_value`) and the likelihood-ratio test of no walk of any channel's
   offset (:func:`calibrate.diagnosis.walk.walk_p_value`: the walk's power sits in the lowest modes, which the
   band family spreads over ten tests), the two by Bonferroni (``block_test``).  Where it passes, a wander the named
   effects do not follow (a random walk of an offset, under a polynomial drift) remains below the floor in
   each sample but moves the directions between flips; the fit keeps its verdict and effects and its
   covariance is widened (``wander_cost``): for one channel's offset step where that explains the whole structure,
   else for a random walk of each channel's offset, its size from the block sums (:mod:`calibrate.diagnosis.walk`).
"""

from __future__ import annotations

import numpy as np

from compass.io.fourflip import FourFlipRecording
from compass.sim.bench import BenchSamples

from ._form import RESPONSE, ResponseMisfit, response_form_check, response_form_test, response_misfit
from ._unseen import platform_prior
from ._mlfit import (MLFit, block_p_values, curve_coefficients, fit_ml, offset_step, score_effect, step_size_output,
                     structured_covariance, walk_covariance, walk_p_value, with_covariance)
from ..diagnosis.evidence import DECISIVE_BIC, STRUCTURE_P, Proposal, gather_forms, is_unexplained, select_effects
from ..diagnosis.report import format_diagnosis
from ..diagnosis.robust import (BAND_P_VALUE, BLOCK_S, NULL_DRAWS, extra_sigma, family_p_value, heading_sigma_deg,
                                widened)
from .effects import VARIANTS, FourFlipEffect
from ..noise import DITHER_FRACTION, chi2_sf, dithered, lattice_step, noise_floor

__all__ = ["DECISIVE_BIC", "FEW_CHANNELS_WARNING", "FORM_WARNING", "UNEXPLAINED_WARNING", "WANDER_WARNING",
           "diagnose_fourflip", "examine_residual", "format_diagnosis", "platform_unseen_warning", "residual_structure",
           "unexplained_warning"]

STRUCTURE_HARMONICS = 6
QUICK_EVALUATIONS = 10
"""Residual evaluations of a candidate's refit when its promise is under decisive (``select_effects``'s
``quick_refit``): a refit that converges takes 3-8 from its first-order start; one that needs many more (a warm-up's
time constant the residual does not hold) is cut short, its delta-BIC then a lower bound."""
WANDER_BAND_DRAWS = 2 * NULL_DRAWS
"""Null draws of the block test's band family under an explained fit: at half ``BAND_P_VALUE`` beside the walk's
test it passes where one band's statistic is beyond every draw, ``(N_BANDS + 1) / (WANDER_BAND_DRAWS + 1)``."""
UNEXPLAINED_WARNING = ("structure remains in the residual above the noise floor: the recording has an effect "
                       "the model lacks (see the diagnosis); the uncertainties are widened to cover it "
                       "(the diagnosis's unexplained_cost)")

FEW_CHANNELS_WARNING = ("with fewer than three channels the bench cannot tell a flip's turntable zero (the cube set "
                        "down turned, the table's zero moved) from a channel's direction, and a zero off by a few "
                        "degrees turned a simulated channel's direction by up to 175 deg, beyond any widened sigma: "
                        "check that every flip was set down square on one zero (calibrate.fourflip._phases)")

FORM_WARNING = ("the fitted response's curve is not a form the model has (a general curve of each channel's "
                "field follows it better; the rest of the residual is white): the file keeps the response the model "
                "fitted, and the uncertainties are widened to cover its misfit (the diagnosis's unexplained_cost)")

WANDER_WARNING = ("the residual is at the noise floor sample by sample, but its sums over 10 s blocks wander beyond "
                  "white noise (a drift that is not smooth in time, such as a random walk of an offset, which the "
                  "named effects do not follow): it moves the directions between flips, and the uncertainties are "
                  "widened to cover it (the diagnosis's wander_cost)")


def residual_structure(samples: BenchSamples, residuals: np.ndarray, noise: np.ndarray) -> tuple[float, int, float]:
    """Structure left in a residual, against white noise at the floor.

    Per channel and flip, the weighted residual is regressed on harmonics 1..6 of the turntable
    angle, a constant and a linear trend over the turn; under white noise the summed chi-square
    drop follows chi2(dof).

    Returns
    -------
    delta_chi2 : float
    dof : int
    p_value : float
    """
    total, dof = 0.0, 0
    for k in np.unique(samples.flip_index):
        mask = samples.flip_index == k
        phi = np.radians(samples.platform_deg[mask])
        index = np.linspace(-1.0, 1.0, mask.sum())
        cols = [np.ones_like(phi), index]
        for h in range(1, STRUCTURE_HARMONICS + 1):
            cols += [np.cos(h * phi), np.sin(h * phi)]
        design = np.column_stack(cols)
        w = residuals[mask] / noise[None, :]
        coef, *_ = np.linalg.lstsq(design, w, rcond=None)
        total += float(np.sum((design @ coef) ** 2))
        dof += design.shape[1] * w.shape[1]
    return total, dof, chi2_sf(total, dof)


def small_angles(p: Proposal) -> tuple[str | None, dict]:
    """A veto (:data:`calibrate.diagnosis.evidence.Check`) of an effect of angles fitted beyond what a bench can
    have (:attr:`~calibrate.fourflip.effects.FourFlipEffect.max_angle_deg`): a face tens of degrees off square, a
    cube set down turned as far, is a fit trading its angles against the directions (one channel: a flip's
    turntable zero against its direction), not a measurement of them."""
    limit = p.effect.max_angle_deg
    if limit is None:
        return None, {}
    _, values, _ = p.trial.effect_parameters(p.effect)
    worst = float(np.max(np.abs(values)))
    if worst <= limit:
        return None, {}
    return (f"its angles reach {worst:.1f} deg, beyond the {limit:g} deg a cube's faces or its setting down can be "
            "off: the fit trades them against the directions (too few channels to tell them apart, or flips "
            "mislabelled)"), {}


def _pooled_rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def diagnose_fourflip(rec: FourFlipRecording, start, noise: np.ndarray | None = None, *,
                      candidates=None, progress=None) -> tuple[MLFit, MLFit, dict]:
    """Run the diagnosis loop on a four-flip recording.

    Parameters
    ----------
    rec : FourFlipRecording
    start : BenchPhysics
        Starting point of the base fit (e.g. the vector-harmonic estimate).
    noise : ndarray, shape (c,), optional
        Noise floor per channel; estimated from the data when None.
    candidates : sequence of str, optional
        Effect names to consider (default: every effect in the vocabulary).
    progress : callable, optional
        Called with one line of text per stage (for long runs on the command line).

    Returns
    -------
    base : MLFit
        The base-model fit.
    final : MLFit
        The fit with every effect the evidence supports.
    diagnosis : dict
        The SPEC section 4 block.
    """
    say = progress or (lambda text: None)
    samples = BenchSamples.from_recording(rec)
    if noise is None:
        noise = noise_floor(rec.platform_deg, rec.flip_index, rec.outputs, lattice_step(rec.outputs))
    names = list(candidates) if candidates is not None else list(VARIANTS)
    pool, skipped = gather_forms(names, VARIANTS,
                                 lambda e: e.applicable(samples) or e.too_few_channels(len(rec.channels)))

    say("fitting the base model")
    base = fit_ml(samples, rec.outputs, rec.channels, start, noise)
    floor = float(np.sqrt(np.mean(noise**2)))
    judged = dithered(lattice_step(rec.outputs), noise)

    def refit(current: MLFit, effect: FourFlipEffect, block: np.ndarray) -> MLFit:
        return fit_ml(samples, rec.outputs, rec.channels, current.physics, noise,
                      effects=current.effects + (effect,),
                      effect_start={**current.effect_start(), effect.name: block})

    def quick_refit(current: MLFit, effect: FourFlipEffect, block: np.ndarray) -> MLFit:
        return fit_ml(samples, rec.outputs, rec.channels, current.physics, noise,
                      effects=current.effects + (effect,),
                      effect_start={**current.effect_start(), effect.name: block}, max_evaluations=QUICK_EVALUATIONS)

    def revise(current: MLFit, effects: tuple) -> MLFit:
        kept = {e.name for e in effects if e in current.effects}  # a replaced form starts from zero
        return fit_ml(samples, rec.outputs, rec.channels, current.physics, noise, effects=effects,
                      effect_start={k: v for k, v in current.effect_start().items() if k in kept})

    def claim(p: Proposal, measured: dict) -> dict:
        names_e, values, sigmas = p.trial.effect_parameters(p.effect)
        return {
            "added": p.effect.name,
            "residual_rms": _pooled_rms(p.trial.residuals),
            "chi2_per_dof": p.trial.reduced_chi2,
            **p.evidence(p.effect.n_params(len(rec.channels))),
            "parameters": {k: {"value": float(v), "sigma": float(s)} for k, v, s in zip(names_e, values, sigmas)},
        }

    chosen = select_effects(
        base, pool,
        score=lambda current, effect: score_effect(current, noise, effect),
        refit=refit, n_params=lambda e: e.n_params(len(rec.channels)), log_n=np.log(rec.outputs.size),
        base_step={"model": "base", "residual_rms": _pooled_rms(base.residuals), "chi2_per_dof": base.reduced_chi2},
        write_step=claim, verdict=lambda f: _verdict(samples, f, noise, judged),
        checks=(small_angles, response_form_check(noise, judged)), rejected_as=lambda e: e.name, progress=say,
        revise=revise,
        unclaimable=None if judged.all() else "the ADC's undithered rounding is structured by itself and may be it",
        quick_refit=quick_refit)
    current, steps, rejected, unexplained = chosen.fit, chosen.steps, chosen.not_claimed, chosen.unexplained
    white = unexplained is False
    curved = any(e.name == RESPONSE for e in current.effects)
    # a linear fit is asked only where its residual is white: a structured one's rejection would be no curve's
    form = response_form_test(current, noise, judged) if white or curved else None
    by_form = white and form.p_value < STRUCTURE_P
    if by_form:
        unexplained = True  # white by the structure test, but the response's curve (or a linear one) is not the form
    structure, dof, p_value = chosen.structure
    rms_after = _pooled_rms(current.residuals)
    diagnosis = {
        "noise_floor": floor,
        "noise_floor_per_channel": [float(v) for v in noise],
        "steps": steps,
        "effects": [e.name for e in current.effects],
        "residual_rms_before": steps[0]["residual_rms"],
        "residual_rms_after": rms_after,
        "unexplained": unexplained,
        **({"unexplained_by": "response_form_test"} if by_form else {}),
        "structure_test": {"delta_chi2": structure, "dof": dof, "p_value": p_value},
        **({} if judged.all() else {"not_judged": _not_judged(rec.channels, judged)}),
        "not_claimed": rejected,
        "not_applicable": skipped,
        "revisions": chosen.revisions,
        **({} if form is None else {"response_form_test": form.as_dict(rec.channels)}),
        "calibration_change": _calibration_change(base, current, rec.channels),
    }
    naive, walked = current, None  # each widening sizes its structure from the naive fit
    if white:  # at the floor sample by sample: does a wander remain across blocks of time?
        bands = family_p_value(block_p_values(naive, noise, WANDER_BAND_DRAWS))
        walk = walk_p_value(naive, noise)
        family = family_p_value(np.array([bands, walk]))  # each at half BAND_P_VALUE: white noise's rate as before
        diagnosis["block_test"] = {"p_value": family, "threshold": BAND_P_VALUE, "bands_p_value": bands,
                                   "walk_p_value": walk}
        if family <= BAND_P_VALUE:
            walked, diagnosis["wander_cost"] = _widen_walk(naive, noise, rec.channels)
            current = walked
    if unexplained:  # structure remains, or (white) the form test rejects: the larger of this and any wander's cover
        misfit = None if form is None or form.p_value >= STRUCTURE_P else response_misfit(naive, noise, judged)
        wide, diagnosis["unexplained_cost"] = _widen(naive, noise, rec.channels, about_mean=True, misfit=misfit)
        current = wide if walked is None else with_covariance(naive, widened(walked.covariance, wide.covariance))
    current, unseen = _unseen_platform(current, noise, rec.channels)
    if unseen is not None:
        diagnosis["platform_field_unseen"] = unseen
    return base, current, diagnosis


def unexplained_warning(diagnosis: dict) -> str:
    """The warning of an unexplained fit: :data:`FORM_WARNING` where the response form test alone made it unexplained
    (the structure test white), else :data:`UNEXPLAINED_WARNING`."""
    return FORM_WARNING if diagnosis.get("unexplained_by") == "response_form_test" else UNEXPLAINED_WARNING


def platform_unseen_warning(unseen: dict) -> str:
    """The report's words for the platform field's unseen parts (``diagnosis["platform_field_unseen"]``): the prior
    they took and its cost, or that none could be stated."""
    if not unseen["prior_stated"]:
        return ("the platform field's x part (along the flip axis) and z part (vertical) are not seen by the bench, and "
                "the fit could not determine its y part (no finite variance), so no prior for them is stated: the "
                "file's offset, gain and dip sigmas leave them out and the heading sigma at runtime is too small by "
                "an amount nobody can say; recalibrate with the turntable's magnetised part removed")
    return (f"the platform field's x part (along the flip axis) and z part (vertical) are not seen by the bench: "
            f"the offsets absorb the x part and the dip and gains the z part; each is taken as 0 +- "
            f"{unseen['prior_sigma_fieldunit']:.3g} field units (from the fitted y part "
            f"{unseen['fitted_y_fieldunit']:+.3g}: a magnetised part's field has no preferred direction), which "
            f"adds {unseen['heading_deg']:.3g} deg to the heading sigma at runtime (in the file's sigmas)")


def _unseen_platform(fit: MLFit, noise: np.ndarray, channels) -> tuple[MLFit, dict | None]:
    """The fit with the platform field's unseen x and z parts in its covariance
    (:func:`calibrate.fourflip._unseen.platform_prior`), and what they cost: each offset's sigma and a level
    housing's heading sigma (:func:`calibrate.diagnosis.robust.heading_sigma_deg`) they add,
    ``sqrt(with^2 - without^2)``; None when the platform field is not in the fit.  When the fitted y part's
    variance is not finite no prior is stated: the fit unchanged, and ``prior_stated`` false with the reason."""
    wide, prior = platform_prior(fit, noise)
    if prior is None:
        return fit, None
    if prior["prior_sigma_fieldunit"] is None:
        return fit, {"prior_stated": False, "fitted_y_fieldunit": prior["fitted_y_fieldunit"],
                     "method": ("the platform field's x and z parts are not seen by the bench; the fitted y part's "
                                "variance p_y^2 + s_y^2, the prior's, is not finite (the fit could not determine the y "
                                "part), so no prior is stated and the file's sigmas leave the unseen parts out")}
    off_sigma = [np.sqrt(f.channel_covariance()[:, 3, 3]) for f in (fit, wide)]  # the file's offset sigma's scale
    heading = [_heading_sigma(f) for f in (fit, wide)]
    return wide, {
        "prior_stated": True,
        "fitted_y_fieldunit": prior["fitted_y_fieldunit"],
        "prior_sigma_fieldunit": prior["prior_sigma_fieldunit"],
        "offset_sigma_added": {name: float(v) for name, v in zip(channels, extra_sigma(off_sigma[1], off_sigma[0]))},
        "heading_deg": float(extra_sigma(heading[1], heading[0])),
        "heading_sigma_deg": {"without": heading[0], "with": heading[1]},
        "method": ("the platform field's x part (along the flip axis: an offset a_x b_x in every flip) and z part "
                   "(added to the Earth's vertical field: the dip and the gains) are not seen by the bench; each is "
                   "taken as zero with the variance p_y^2 + s_y^2 of the fitted y part (a magnetised part's field has "
                   "no preferred direction; one draw's estimate), its move of the parameters propagated into the "
                   "file's sigmas"),
    }


def _widen(fit: MLFit, noise: np.ndarray, channels, about_mean: bool = False, structure=None,
           misfit: ResponseMisfit | None = None) -> tuple[MLFit, dict]:
    """The fit with its covariance widened to cover the residual's structure, and what that costs.

    :func:`calibrate.fourflip._mlfit.structured_covariance` (or the ``structure`` given) and
    :func:`calibrate.diagnosis.robust.widened`; the cost is the part of each direction's sigma and of
    a level housing's heading sigma (:func:`calibrate.diagnosis.robust.heading_sigma_deg`) the
    structure adds, ``sqrt(widened^2 - naive^2)``.  ``about_mean`` (the unexplained fit's): the structure's
    move taken about each channel's mean level over the session, the level the file's offset states
    (:func:`calibrate.diagnosis.robust.structure_in_time`; robust.py, "About the session's mean").  ``misfit``
    (a fit whose response's curve the form test rejects): the naive covariance plus the curve's squared bias in
    the parameters (:func:`calibrate.fourflip._form.response_misfit`), a static misfit as a function of the field
    that no structure in time covers; the file's covariance the larger of the two (``response_misfit`` its cost).
    """
    if structure is None:
        structure = structured_covariance(fit, noise, about_mean=about_mean)
    wide = with_covariance(fit, widened(fit.covariance, structure.covariance))
    cost = {
        **_sigma_cost(fit, wide, channels),
        "method": ("the residual's structure taken as a stationary process in time over the whole recording (each "
                   "channel's own and common to pairs), its spectrum in octave bands estimated from the residual's "
                   "block sums with what the fit absorbed accounted for, propagated into the parameters; the file's "
                   "sigmas are the larger of it and the naive ones"),
    }
    if structure.gain:
        cost["method"] = ("the residual's structure taken as each channel's gain wandering, a stationary process in "
                          "time times the channel's signal (its spectrum in octave bands estimated from the residual's "
                          "block sums demodulated by the signal, decisively likelier than an offsets' wander), "
                          "propagated into the parameters; the file's sigmas are the larger of it and the naive ones")
    if structure.locked:
        cost["method"] = ("the residual's structure is locked to the turntable's turn (each turn's own gain of the "
                          "turning signal and lag in each channel, and the turn angle's harmonics 2 and up; what "
                          "remains is white): what it moved the parameters by, estimated from the residual, "
                          "propagated; the file's sigmas are the larger of it and the naive ones")
    step = structure.step
    if step is not None:
        size = step_size_output(fit, noise, step.channel, step.size)
        field = size / float(fit.physics.gains[step.channel])
        cost["offset_step"] = {"channel": channels[step.channel], "t_s": step.t_s, "size": size,
                               "size_field": field, "delta_chi2": step.delta_chi2}
        cost["method"] = (f"the residual's structure is one step of {channels[step.channel]}'s offset by {size:.4g} "
                          f"output units ({field:.3g} field units) near t = {step.t_s:g} s (within {BLOCK_S:g} s; what "
                          "remains is white), its move of the parameters propagated; the file's sigmas are the larger "
                          "of it and the naive ones")
    if about_mean and structure.gain:
        cost["method"] += ("; the move is taken about each channel's mean gain over the session, the gain the file "
                           "states")
    elif about_mean and not structure.locked:
        cost["method"] += ("; the move is taken about each channel's mean level over the session, the level the "
                           "file's offsets state (a wander's own mean is no error of it)")
    if misfit is not None:
        cost["response_misfit"] = _misfit_cost(fit, misfit, channels)
        wide = with_covariance(fit, widened(wide.covariance, misfit.cover(fit.covariance)))
        cost.update(_sigma_cost(fit, wide, channels))
        cost["method"] = ("the response's curve is not the vocabulary's form: a general curve of each judged "
                          "channel's field component (Legendre degrees 2-8) fitted beside the fit's parameters, the "
                          "bias each of its components the recording determines put in them estimated without its "
                          "noise and added to the naive covariance (response_misfit); the file's sigmas are the "
                          "larger of that and the structure in time's widening: " + cost["method"])
    return wide, cost


def _misfit_cost(fit: MLFit, misfit: ResponseMisfit, channels) -> dict:
    """What the response curve's misfit alone adds (:func:`_sigma_cost`), and the chi-square its curves take."""
    return {**_sigma_cost(fit, with_covariance(fit, widened(fit.covariance, misfit.cover(fit.covariance))), channels),
            "delta_chi2": misfit.delta_chi2,
            "components": {"with_bias": misfit.taken[0], "not_degenerate": misfit.taken[1]}}


def _widen_walk(fit: MLFit, noise: np.ndarray, channels) -> tuple[MLFit, dict]:
    """The fit with its covariance widened for a wander across blocks of time, and what that costs: one step of one
    channel's offset where that explains the whole structure (:func:`_widen`), else a random walk of each
    channel's offset.

    :func:`calibrate.fourflip._mlfit.walk_covariance` (one walk size per channel from the residual's block sums,
    its move of the parameters propagated whole; :mod:`calibrate.diagnosis.walk`) and
    :func:`calibrate.diagnosis.robust.widened`; the cost as :func:`_widen`'s, and each channel's walk in field
    units per square root of a second.
    """
    step = offset_step(fit, noise, about_mean=True)
    if step is not None:  # one step of one channel's offset leaves white block sums: its own move about the mean
        return _widen(fit, noise, channels, about_mean=True, structure=step)
    walk = walk_covariance(fit, noise)
    wide = with_covariance(fit, widened(fit.covariance, walk.covariance))
    per_sample = walk.q_per_sqrt_s * noise  # output units per sqrt(s): q is in noise sigmas of one sample
    return wide, {
        **_sigma_cost(fit, wide, channels),
        "walk_fieldunit_per_sqrt_s": {name: float(q) for name, q in zip(channels, per_sample / fit.physics.gains)},
        "method": ("the residual's wander taken as a random walk of each channel's offset (one size per channel, "
                   "estimated by restricted maximum likelihood from the residual's 10 s block sums with what the fit "
                   "absorbed accounted for, the white floor beside it), its move of the parameters propagated "
                   "whole; the file's sigmas are the larger of it and the naive ones"),
    }


def _sigma_cost(fit: MLFit, wide: MLFit, channels) -> dict:
    """What a widening adds to each direction's sigma and to a level housing's heading sigma (deg),
    ``sqrt(widened^2 - naive^2)``, with both sigmas."""
    before, after = fit.direction_sigma_deg(), wide.direction_sigma_deg()
    heading = [_heading_sigma(f) for f in (fit, wide)]
    return {
        "direction_deg": {name: float(v) for name, v in zip(channels, extra_sigma(after, before))},
        "heading_deg": float(extra_sigma(heading[1], heading[0])),
        "direction_sigma_deg": {name: {"naive": float(b), "widened": float(a)}
                                for name, b, a in zip(channels, before, after)},
        "heading_sigma_deg": {"naive": heading[0], "widened": heading[1]},
    }


def _heading_sigma(fit: MLFit) -> float:
    """A level housing's RMS heading sigma over headings from each channel's joint direction, offset and gain
    covariance (:meth:`MLFit.channel_covariance`: a warm-up during the first flip ties a channel's offset to its
    direction), with its response curve's coefficients where the fit has a curve (:meth:`MLFit.curve_covariance`:
    the curve trades against the gain), and the offsets' covariance across channels (a shared warm-up time
    constant correlates them)."""
    phys = fit.physics
    c = len(phys.gains)
    joint, curved = fit.channel_covariance(), fit.curve_covariance()
    offsets = 4 * np.arange(c) + 2
    offset_cov = fit.covariance[np.ix_(offsets, offsets)] * np.outer(fit.layout.start.gains, fit.layout.start.gains)
    var = np.stack([joint[:, 3, 3], joint[:, 4, 4]], axis=1)
    curves = None if curved is None else curve_coefficients(phys)
    return heading_sigma_deg(phys.directions, fit.direction_covariance, var, phys.gains, phys.dip_deg,
                             phys.field_norm, offset_covariance=offset_cov,
                             channel_covariance=joint if curved is None else curved, curves=curves)


def _verdict(samples, fit: MLFit, noise, judged: np.ndarray) -> tuple[tuple[float, int, float], bool | None]:
    """Structure test of a fit's residual over the ``judged`` channels and whether it is unexplained
    (None when no channel can be judged)."""
    if not judged.any():
        return (float("nan"), 0, float("nan")), None
    structure, dof, p_value = residual_structure(samples, fit.residuals[:, judged], noise[judged])
    rms = _pooled_rms(fit.residuals[:, judged])
    return (structure, dof, p_value), is_unexplained(p_value, rms, float(np.sqrt(np.mean(noise[judged] ** 2))))


def _not_judged(channels, judged: np.ndarray) -> str:
    """Why some channels' residual is left out of the verdict (:func:`calibrate.noise.dithered`)."""
    names = ", ".join(ch for ch, ok in zip(channels, judged) if not ok)
    return (f"{names}: the ADC's code step is over {1 / DITHER_FRACTION:g} times the noise, so its rounding is not "
            "dithered: a structured function of the field by itself, which the residual's structure test cannot tell "
            "from an effect" + ("" if judged.any() else "; nothing is judged ('unexplained' null)"))


def examine_residual(samples: BenchSamples, residuals: np.ndarray, noise: np.ndarray) -> dict:
    """The diagnosis block for a fit the loop cannot extend (the seed's rules): base step only."""
    floor = float(np.sqrt(np.mean(noise**2)))
    rms = _pooled_rms(residuals)
    structure, dof, p_value = residual_structure(samples, residuals, noise)
    return {
        "noise_floor": floor,
        "noise_floor_per_channel": [float(v) for v in noise],
        "steps": [{"model": "base", "residual_rms": rms}],
        "effects": [],
        "residual_rms_before": rms,
        "residual_rms_after": rms,
        "unexplained": is_unexplained(p_value, rms, floor),
        "structure_test": {"delta_chi2": structure, "dof": dof, "p_value": p_value},
        "note": "the seed's rules are examined, not extended: the loop that adds effects runs with --method ml",
    }


def _calibration_change(base: MLFit, final: MLFit, channels) -> dict:
    """How each channel's direction and the dip moved from the base fit to the final one."""
    out = {"channels": {}}
    for c, name in enumerate(channels):
        a, b = base.physics.directions[c], final.physics.directions[c]
        moved = float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))
        out["channels"][name] = {"direction_change_deg": moved,
                                 "sigma_deg": float(final.direction_sigma_deg()[c])}
    out["dip_change_deg"] = float(final.physics.dip_deg - base.physics.dip_deg)
    return out
