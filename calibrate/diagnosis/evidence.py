"""The evidence loop of the residual diagnosis (SPEC section 4), shared by every calibration that runs it.

The four-flip (:mod:`calibrate.fourflip.diagnosis`), the tumble (:mod:`calibrate.tumble.diagnosis`) and the
fits against known inputs (:mod:`calibrate.diagnosis.offsets`) differ in their models, their
effects and their verdicts, but choose effects the same way.  :func:`select_effects` is that
choice; each caller hands it what differs as small callables:

1. Score every candidate form not yet in the model (``score``: the chi-square drop a refit could
   buy to first order, and a start for the form's parameters), and rank the forms by the evidence
   the score promises, ``drop - k ln n`` for ``k`` parameters and ``n`` observations.
2. Keep the most promising form of each effect and refit the first :data:`MAX_REFITS` in full
   (``refit``), down to a promise of zero and :data:`REFIT_FRACTION` of the best one.  The promise is
   first order: an effect that moves what is in (an encoder error whose harmonics a response's powers 2
   and 3 had taken) can buy more in full than promised, so one promising less than :data:`DECISIVE_BIC`
   is refitted too (cut short first, :func:`_refit_by_promise`), and its refit, not its promise, must be
   decisive.
3. Take the refit with the largest delta-BIC; stop unless it is decisive (above
   :data:`DECISIVE_BIC`).
4. Veto it, and stop, if it explains less than :data:`MIN_SHARE` of the structured residual
   (the chi-square above its dof) while structure remains with it (``verdict`` of the fit with it), or if
   one of the caller's ``checks`` objects (e.g. :func:`determined`: a singular covariance; the tumble's: a
   wider field-gravity angle spread); else record a step (``write_step``) and repeat, at most
   :data:`MAX_STEPS` times.  The share alone does not veto: the chi-square above its dof is mostly the
   noise floor's own error on a long recording (the four-flip's second-difference floor, 3.7 % in sigma,
   moves it by about 160 on 4320 residuals; chi-square's own spread is 93), so a real effect of
   delta-chi-square 70-130 read a 23-28 % share and was dropped with the residual left unexplained, where
   with it the structure test found nothing (docs/benchmarks.md, "An odd cubic the loop did not name").
5. Revisit what is in (when the caller can ``revise``: refit a model with a given list of effects):
   after each addition, every effect already in is refitted without it (its evidence now) and its
   other forms are score-tested there; the most promising one is refitted as a candidate is in step 2
   (:func:`_refit_by_promise`), and one that beats the current form by more than :data:`DECISIVE_BIC` in its
   refit replaces it (a drift taken as linear before a cubic was in may be quadratic once it is), and an
   effect whose evidence has fallen to :data:`DECISIVE_BIC` or below is dropped; repeat while something
   changes (:func:`_revisit`).
6. Judge the final fit (``verdict``).  If structure remains after effects were added, they may
   have absorbed part of something the toolkit does not model: none is claimed, each is reported
   as not claimed, and the base fit is kept and judged again.

A fit is read only through ``effects`` (the effects in it, each with a ``name``), ``chi2``,
``dof`` and ``bic()`` (chi-square plus ``k ln n``, the noise floor known), and ``covariance``
for :func:`determined`; an effect (:class:`calibrate.effects.Effect`) through ``name``, ``label`` and
``description``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Protocol, Sequence

import numpy as np


__all__ = ["DECISIVE_BIC", "FLOOR_MARGIN", "MIN_SHARE", "MAX_REVISIONS", "MAX_STEPS", "MAX_REFITS", "REFIT_FRACTION", "SINGULAR_RCOND",
           "STRUCTURE_P", "Fit", "FitRecord", "Proposal", "Selection", "Check", "gather_forms", "linearised_score",
           "refit_from_better_start", "determined", "select_effects", "VERDICTS", "added_step_lines",
           "remark_lines", "residual_line", "is_unexplained", "linear_score", "unit_columns"]

SINGULAR_RCOND = 1e-7
"""Eigenvalues of a scaled normal matrix below ``SINGULAR_RCOND**2`` of the largest are singular."""
SCORE_CHUNK_ROWS = 16384
"""Rows of the projected block :func:`linear_score` forms at a time (16384 x its columns x 8 bytes: in cache)."""
FLOOR_MARGIN = 0.10
"""Residual rms above the noise floor by more than this fraction is unexplained."""
STRUCTURE_P = 1e-3
"""p-value below which structure left in the residual is significant."""
DECISIVE_BIC = 10.0
"""delta-BIC above which evidence counts as decisive (Kass and Raftery's 'very strong')."""
MIN_SHARE = 0.3
"""Smallest share of the structured residual an effect must explain to be tried further, when structure
remains with it (an effect that leaves none has explained all there was, whatever the share reads)."""
MAX_STEPS = 4
"""Most effects added to one model."""
MAX_REFITS = 4
"""Most candidate effects refitted in full per step."""
REFIT_FRACTION = 0.25
"""Candidates whose score test promises less than this fraction of the best one's are not refitted."""


@dataclass(frozen=True)
class FitRecord:
    """A fit of a model with effects, as the loop and the kinds' diagnoses keep it.

    Attributes
    ----------
    effects : tuple
        The effects in the model.
    x, jac, covariance : ndarray
        Parameters, Jacobian of the weighted residual, covariance.
    residuals : ndarray
        The residual in the kind's own units (what its report shows).
    chi2 : float
        Of the weighted residual.
    n_obs : int
        Number of weighted residuals.
    success : bool
    message : str
    """

    effects: tuple
    x: np.ndarray
    jac: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    chi2: float
    n_obs: int
    success: bool
    message: str

    @property
    def dof(self) -> int:
        return self.n_obs - self.x.size

    def bic(self) -> float:
        """chi2 + k ln n, with the noise floor known."""
        return self.chi2 + self.x.size * np.log(self.n_obs)


class Fit(Protocol):
    """What the loop reads of a fit (:class:`FitRecord` is one)."""

    effects: tuple
    chi2: float

    @property
    def dof(self) -> int: ...

    def bic(self) -> float: ...


@dataclass(frozen=True)
class Proposal:
    """The best refit of one step of the loop, before the vetoes.

    Attributes
    ----------
    effect : object
        The effect (one form of it) the refit added.
    current, trial : Fit
        The fit before and the refit with ``effect``.
    drop : float
        The score test's expected chi-square drop.
    gain : float
        ``current.bic() - trial.bic()``.
    share : float
        ``(current.chi2 - trial.chi2) / (current.chi2 - current.dof)``: the share of the structured
        residual the effect explains (not clipped; the denominator at least 1e-12).
    """

    effect: Any
    current: Any
    trial: Any
    drop: float
    gain: float
    share: float

    def evidence(self, n_params: int) -> dict:
        """A step's ``"evidence"`` (one line), ``"delta_bic"`` and ``"explained_share"``, in that order."""
        explained = min(self.share, 1.0)
        return {
            "evidence": (f"{self.effect.description}: score test expected chi2 drop {self.drop:.0f} for {n_params} "
                         f"parameters, refit chi2 {self.current.chi2:.0f} -> {self.trial.chi2:.0f}, "
                         f"{100 * explained:.0f} % of the structured residual explained"),
            "delta_bic": float(self.gain),
            "explained_share": float(explained),
        }


@dataclass(frozen=True)
class Selection:
    """Outcome of :func:`select_effects`.

    Attributes
    ----------
    fit : Fit
        The fit with the claimed effects (the base fit when none is claimed).
    steps : list of dict
        The base step, then one per claimed effect (``write_step``'s).
    not_claimed : list of str
        Why each effect that was tried and decisive was not claimed, one line each.
    structure : object
        The structure test of ``fit`` (the first item ``verdict`` returned).
    unexplained : bool or None
        Whether structure remains in ``fit``'s residual (None: not judged).
    revisions : list of str
        What revisiting changed (a form replaced, an effect dropped), one line each.
    """

    fit: Any
    steps: list
    not_claimed: list
    structure: Any
    unexplained: bool | None
    revisions: list = ()


Check = Callable[[Proposal], "tuple[str | None, dict]"]
"""A veto: ``(reason, measured)``, ``reason`` None to let the proposal through, else the words after
"but" in the not-claimed line; ``measured``, what it found, is handed to ``write_step``."""


def gather_forms(names: Iterable[str], forms: dict, why_not: Callable[[Any], str | None]) -> tuple[list, dict]:
    """The candidate forms of the named effects the recording can show.

    Parameters
    ----------
    names : iterable of str
        Effect names, keys of ``forms``.
    forms : dict
        Each effect name's forms, a sequence.
    why_not : callable
        ``why_not(form) -> str | None``: the reason a recording cannot show the effect (asked of its
        first form), None when it can.

    Returns
    -------
    pool : list
        Every form of every applicable effect, in order.
    skipped : dict
        ``{name: reason}`` of the others.
    """
    pool, skipped = [], {}
    for name in names:
        reason = why_not(forms[name][0])
        if reason:
            skipped[name] = reason
        else:
            pool.extend(forms[name])
    return pool, skipped


def linearised_score(weighted: Callable, current, effect, points: Sequence[np.ndarray],
                     step: float, block_jacobian: Callable | None = None,
                     j_b: np.ndarray | None = None, r0: np.ndarray | None = None,
                     normal_b: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """Score (Lagrange-multiplier) test for adding ``effect`` to a least-squares fit.

    The effect's Jacobian at each of its score points is projected off the current fit's Jacobian
    (what the current parameters absorb; :func:`linear_score`); the best point is kept.

    Parameters
    ----------
    weighted : callable
        ``weighted(x, effects) -> (m,)``: the model's weighted residual.
    current : Fit
        With ``x`` (parameters), ``jac`` (m, k) and ``effects``.
    effect : object
        The candidate form.
    points : sequence of ndarray
        Its parameters with the effect switched off, where the test is evaluated.
    step : float
        Finite-difference step of the effect's parameters.
    block_jacobian : callable, optional
        ``block_jacobian(q) -> (m, q.size)`` or None: the weighted residual's derivatives by the effect's
        parameters at ``q`` (finite differences where it is not given or gives None).
    j_b : ndarray, shape (m, k), optional
        :func:`unit_columns` of ``current.jac``, when the caller keeps it over the effects it scores
        against the same fit (computed otherwise).
    r0 : ndarray, shape (m,), optional
        ``weighted(current.x, current.effects)``, when the caller has it: the score points are blocks of
        zero size (:meth:`calibrate.effects.EffectForm.score_points`), so the effect is switched off there
        and the residual at every point is the current fit's (computed at each point otherwise).
    normal_b : ndarray, shape (k, k), optional
        ``j_b.T @ j_b``, when the caller keeps it with ``j_b``.

    Returns
    -------
    expected_delta_chi2 : float
    start : ndarray
        The Gauss-Newton estimate of the effect's parameters from the best point.
    """
    effects = current.effects + (effect,)
    j_b = unit_columns(current.jac) if j_b is None else j_b
    normal_b = j_b.T @ j_b if normal_b is None else normal_b
    best = (-np.inf, points[0])
    for q0 in points:
        drop, delta = linear_score(lambda p: weighted(p, effects), np.concatenate([current.x, q0]),
                                   current.x.size, j_b, step, None if block_jacobian is None else block_jacobian(q0),
                                   r0=r0, normal_b=normal_b)
        if drop > best[0]:
            best = (drop, q0 + delta)
    return best


def refit_from_better_start(fit: Callable, weighted: Callable, current, effect, plain: np.ndarray,
                            start: np.ndarray):
    """Refit with ``effect`` added, from the score test's start or the switched-off one, whichever fits better.

    A first-order start can overshoot: it is kept only if its weighted chi-square is below that of
    ``plain`` (the effect switched off).

    Parameters
    ----------
    fit : callable
        ``fit(effects, x0) -> Fit``.
    weighted : callable
        ``weighted(x, effects) -> (m,)``.
    current : Fit
        With ``x`` and ``effects``.
    effect : object
    plain, start : ndarray
        The effect's parameters switched off and from the score test.
    """
    effects = current.effects + (effect,)
    x_plain = np.concatenate([current.x, plain])
    x0 = np.concatenate([current.x, start])
    if np.sum(weighted(x_plain, effects) ** 2) < np.sum(weighted(x0, effects) ** 2):
        x0 = x_plain
    return fit(effects, x0)


def determined(together_with: str) -> Check:
    """A veto of a refit whose covariance is singular (a non-finite variance).

    Parameters
    ----------
    together_with : str
        What the effect's parameters cannot be told from, in words (e.g. ``"the base model"``).
    """

    def check(p: Proposal):
        if not np.all(np.isfinite(np.diag(p.trial.covariance))):
            return (f"the data cannot determine its parameters together with {together_with} "
                    "(singular covariance)"), {}
        return None, {}

    return check


def _withdrawn(step: dict) -> str:
    """The not-claimed line of an added step when structure remains (the form named when the step has one)."""
    head = f"{step['added']} ({step['form']}; " if "form" in step else f"{step['added']} ("
    return (f"{head}delta-BIC {step['delta_bic']:.0f}, explained {100 * step['explained_share']:.0f} % of the "
            "structured residual, but structure the model lacks remains, so it may be part of that: not claimed)")


def _refit_by_promise(current: Fit, effect, start, promise: float, refit: Callable,
                      quick_refit: Callable | None, against: Fit | None = None) -> Fit:
    """The refit of a candidate whose first-order evidence is ``promise``, the way every candidate is refitted.

    Promising more than :data:`DECISIVE_BIC` (or without ``quick_refit``), it is refitted in full.  Under it, the
    score test may still under-state what the refit buys (it is first order), so it is refitted cut short first
    (``quick_refit``): Levenberg-Marquardt takes only steps that lower the chi-square, so the cut-short fit's
    delta-BIC against ``against`` bounds the full refit's from below, and the full refit runs only when that bound
    is decisive; else the cut-short fit is returned (its delta-BIC, not decisive, decides nothing).

    Parameters
    ----------
    current : Fit
        The fit the refit starts from (``effect`` added to its effects).
    effect : object
        The candidate form.
    start : ndarray
        The score test's start of the form's parameters.
    promise : float
        Its first-order delta-BIC against ``against``.
    refit, quick_refit : callable
        ``(current, effect, start) -> Fit``, in full and cut short (:func:`select_effects`).
    against : Fit, optional
        The fit the gain is measured against (default ``current``; a revisit's swap starts from the model without
        the effect it replaces and is measured against the model with it).
    """
    if promise > DECISIVE_BIC or quick_refit is None:
        return refit(current, effect, start)
    trial = quick_refit(current, effect, start)
    reference = current if against is None else against
    return refit(current, effect, start) if reference.bic() - trial.bic() > DECISIVE_BIC else trial


def select_effects(base: Fit, pool: Sequence, *, score: Callable, refit: Callable, n_params: Callable[[Any], int],
                   log_n: float, base_step: dict, write_step: Callable[[Proposal, dict], dict],
                   verdict: Callable, checks: Sequence[Check] = (), rejected_as: Callable[[Any], str] | None = None,
                   progress: Callable[[str], None] | None = None, revise: Callable | None = None,
                   unclaimable: str | None = None, quick_refit: Callable | None = None) -> Selection:
    """Add the effects the evidence supports to a base fit, one at a time (see the module docstring).

    Parameters
    ----------
    base : Fit
        The base model's fit.
    pool : sequence
        Candidate forms, simplest first within each effect (:func:`gather_forms`).
    score : callable
        ``score(current, effect) -> (expected_delta_chi2, start)``.
    refit : callable
        ``refit(current, effect, start) -> Fit``: the model with ``effect`` added, refitted in full.
    n_params : callable
        ``n_params(effect) -> int``.
    log_n : float
        ``ln`` of the number of observations (the BIC's penalty per parameter).
    base_step : dict
        The first step (``{"model": "base", "residual_rms": ...}``).
    write_step : callable
        ``write_step(proposal, measured) -> dict``: the step of a claimed effect; ``measured``
        merges what the ``checks`` returned.
    verdict : callable
        ``verdict(fit) -> (structure, unexplained)``.
    checks : sequence of callable
        Vetoes after the share's, in order (:data:`Check`).
    rejected_as : callable, optional
        How a vetoed effect is named in its not-claimed line (default: its ``label``).
    progress : callable, optional
        Called with one line of text per stage.
    revise : callable, optional
        ``revise(current, effects) -> Fit``: the model refitted with exactly ``effects`` (a tuple),
        started from ``current``; without it, nothing added is revisited.
    unclaimable : str, optional
        Why no effect can be claimed from this recording whatever the evidence (e.g. structure of the
        recording's own making, as an ADC's undithered rounding): effects are tried and reported, not claimed.
    quick_refit : callable, optional
        ``quick_refit(current, effect, start) -> Fit``: the refit cut short, whose chi-square bounds the converged
        one's from above (its delta-BIC a lower bound), for a candidate promising less than :data:`DECISIVE_BIC`:
        refitted in full only when even the bound is decisive (a revisit's swap too).  None: such a candidate is
        refitted in full.

    Returns
    -------
    Selection
    """
    say = progress or (lambda text: None)
    name_of = rejected_as or (lambda e: e.label)
    current, steps, rejected, revisions = base, [base_step], [], []
    for _ in range(MAX_STEPS):
        present = {e.name for e in current.effects}
        scored = []
        for effect in (e for e in pool if e.name not in present):
            drop, start = score(current, effect)
            scored.append((drop - n_params(effect) * log_n, drop, effect, start))
        if not scored:
            break
        scored.sort(key=lambda item: -item[0])
        seen = set()  # one form per effect is refitted: the one whose score promises the most evidence
        scored = [item for item in scored if not (item[2].name in seen or seen.add(item[2].name))]
        say("score tests (expected chi2 drop): " + ", ".join(f"{e.label} {d:.0f}" for _, d, e, _ in scored))
        best = None
        for expected, drop, effect, start in scored[:MAX_REFITS]:
            if expected <= max(0.0, REFIT_FRACTION * scored[0][0]):
                break
            say(f"refitting with {effect.label}")
            trial = _refit_by_promise(current, effect, start, expected, refit, quick_refit)
            gain = current.bic() - trial.bic()
            share = (current.chi2 - trial.chi2) / max(current.chi2 - current.dof, 1e-12)
            if best is None or gain > best.gain:
                best = Proposal(effect, current, trial, drop, gain, share)
        if best is None or best.gain <= DECISIVE_BIC:
            break
        reason, measured = _veto(best, checks, verdict)
        if reason:
            rejected.append(f"{name_of(best.effect)} (delta-BIC {best.gain:.0f}, but {reason}: not claimed)")
            break
        steps.append(write_step(best, measured))
        say(f"added {best.effect.name} (delta-BIC {best.gain:.0f})")
        current = best.trial
        if revise is not None and len(current.effects) > 1:
            current, steps = _revisit(current, steps, pool, revise, score, refit, n_params, log_n, write_step,
                                      revisions, say, quick_refit)

    structure, unexplained = verdict(current)
    if unclaimable and len(steps) > 1:
        rejected.extend(f"{step['added']} (delta-BIC {step['delta_bic']:.0f}, but {unclaimable}: not claimed)"
                        for step in steps[1:])
        steps, current = steps[:1], base
        structure, unexplained = verdict(current)
    if unexplained and len(steps) > 1:
        # Structure the model lacks remains.  Whatever the added effects fitted may be partly that
        # unknown effect (e.g. a field gradient with the sensor off the axis mimics an encoder
        # error): claim nothing, keep the base fit, and say what was tried.
        rejected.extend(_withdrawn(step) for step in steps[1:])
        steps, current = steps[:1], base
        structure, unexplained = verdict(current)
    return Selection(current, steps, rejected, structure, unexplained, revisions)


MAX_REVISIONS = 4
"""Most changes one revisit makes (each a refit of every alternative)."""


def _revisit(current, steps: list, pool: Sequence, revise: Callable, score: Callable, refit: Callable,
             n_params: Callable, log_n: float, write_step: Callable, revisions: list,
             say: Callable, quick_refit: Callable | None = None) -> tuple[Any, list]:
    """Re-test the forms of the effects in ``current`` but the last added, and drop those no longer decisive.

    For each such effect the model without it is refitted (``revise``): the effect's evidence is
    what removing it costs in BIC.  Its other forms are score-tested against that model, and the
    most promising one is refitted from it when its first-order evidence beats the current form's at all,
    as :func:`select_effects` refits a candidate (:func:`_refit_by_promise`): the swap's promise over
    ``current`` is the form's first-order delta-BIC against the model without the effect less that
    effect's evidence; under :data:`DECISIVE_BIC` the refit is cut short first (``quick_refit``), started
    from the model without it, and its delta-BIC against ``current`` (a lower bound of the converged
    swap's) decides whether it runs in full.  The best replacement decisive in its refit is taken, else the
    effect with the least evidence is dropped if that evidence is at most :data:`DECISIVE_BIC`;
    repeat, at most :data:`MAX_REVISIONS` times.  ``steps`` (the base step, then one per effect in
    order) follows the effects: a replaced form goes to the end with a new step (the evidence of the
    replacement), a dropped effect loses its step.
    """
    for _ in range(MAX_REVISIONS):
        effects = current.effects
        swaps, drops = [], []
        for i, old in enumerate(effects[:-1]):
            without = revise(current, effects[:i] + effects[i + 1:])
            evidence = without.bic() - current.bic()
            drops.append((evidence, i, without))
            scored = []
            for form in (f for f in pool if f.name == old.name and f != old):
                drop, start = score(without, form)
                scored.append((drop - n_params(form) * log_n, form, start))
            if not scored:
                continue
            promise, form, start = max(scored, key=lambda item: item[0])
            if promise <= evidence:  # first order, the swap buys nothing over the current form
                continue
            say(f"revisiting {old.label}: refitting as {form.label}")
            trial = _refit_by_promise(without, form, start, promise - evidence, refit, quick_refit, against=current)
            swaps.append((current.bic() - trial.bic(), i, form, without, trial))
        best_swap = max(swaps, key=lambda item: item[0], default=None)
        weakest = min(drops, key=lambda item: item[0], default=None)
        if best_swap is not None and best_swap[0] > DECISIVE_BIC:
            gain, i, form, without, trial = best_swap
            old = effects[i]
            share = (without.chi2 - trial.chi2) / max(without.chi2 - without.dof, 1e-12)
            step = write_step(Proposal(form, without, trial, float("nan"), without.bic() - trial.bic(), share), {})
            step["evidence"] = (f"{form.description}: revisited once {effects[-1].label} was in, it replaces "
                                f"{old.label} (delta-BIC {gain:.0f} over it)")
            steps = steps[:i + 1] + steps[i + 2:] + [step]
            revisions.append(f"{old.label} replaced by {form.label} (delta-BIC {gain:.0f}) once {effects[-1].label} "
                             "was in")
            say(revisions[-1])
            current = trial
        elif weakest is not None and weakest[0] <= DECISIVE_BIC:
            evidence, i, without = weakest
            revisions.append(f"{effects[i].label} dropped: with the effects added after it, it no longer earns its "
                             f"place (removing it costs delta-BIC {evidence:.0f})")
            say(revisions[-1])
            steps = steps[:i + 1] + steps[i + 2:]
            current = without
        else:
            break
    return current, steps


def _veto(p: Proposal, checks: Sequence[Check], verdict: Callable) -> tuple[str | None, dict]:
    """The first veto of a proposal (the share first, then ``checks``), and what the checks measured."""
    if p.share < MIN_SHARE and verdict(p.trial)[1] is not False:
        return f"it explains only {100 * p.share:.0f} % of the structured residual", {}
    measured = {}
    for check in checks:
        reason, found = check(p)
        if reason:
            return reason, measured
        measured.update(found)
    return None, measured


VERDICTS = {True: "UNEXPLAINED: structure remains above the noise floor that no modelled effect accounts for",
            False: "explained: the residual is at the noise floor"}
"""A diagnosis block's ``unexplained`` in words, for the reports."""


def added_step_lines(step: dict) -> list[str]:
    """Report lines of an added effect: residual, delta-BIC, evidence and each parameter with its sigma."""
    form = f" ({step['form']})" if "form" in step else ""
    lines = [f"  + {step['added']}{form}: residual rms {step['residual_rms']:.4g}, delta-BIC {step['delta_bic']:.0f}",
             f"      evidence: {step['evidence']}"]
    return lines + [f"      {name} = {p['value']:.4g} +- {p['sigma']:.2g}"
                    for name, p in step.get("parameters", {}).items()]


def remark_lines(block: dict) -> list[str]:
    """Report lines of what revisiting changed, what was not claimed and what could not be examined, and why."""
    return ([f"  revisited: {text}" for text in block.get("revisions", [])]
            + [f"  not claimed: {text}" for text in block.get("not_claimed", [])]
            + [f"  {name} not examined: {reason}" for name, reason in block.get("not_applicable", {}).items()])


def residual_line(block: dict, verdict: str, test: str = "structure test") -> str:
    """The closing report line: residual rms before and after, the verdict, the structure test's p-value."""
    p = (block.get("structure_test") or {}).get("p_value")
    return (f"  residual rms {block['residual_rms_before']:.4g} -> {block['residual_rms_after']:.4g}; {verdict}"
            + ("" if p is None else f" ({test} p = {p:.2g})"))


def is_unexplained(p_value: float, rms: float, floor: float) -> bool:
    """Whether a residual is unexplained: structure (p below :data:`STRUCTURE_P`) or an rms above the floor by more than :data:`FLOOR_MARGIN`."""
    return bool(p_value < STRUCTURE_P or rms > (1.0 + FLOOR_MARGIN) * floor)


def unit_columns(jac: np.ndarray) -> np.ndarray:
    """The Jacobian with every non-zero column scaled to unit norm."""
    return jac / np.where(np.any(jac, axis=0), np.linalg.norm(jac, axis=0), 1.0)


def linear_score(residual, x, n_fitted: int, j_b: np.ndarray, step: float = 1e-6,
                 block_jacobian: np.ndarray | None = None, r0: np.ndarray | None = None,
                 normal_b: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """First-order chi-square drop and parameter step of the block ``x[n_fitted:]``.

    Parameters
    ----------
    residual : callable
        Weighted residuals of the extended model at a parameter vector.
    x : ndarray
        The fitted parameters followed by the candidate block at its score point.
    n_fitted : int
        Length of the fitted part.
    j_b : ndarray, shape (n_residuals, n_fitted)
        The current fit's Jacobian with unit columns.
    step : float
        Finite-difference step of the block's parameters.
    block_jacobian : ndarray, shape (n_residuals, len(x) - n_fitted), optional
        The residual's derivatives by the block at ``x`` (finite differences of ``residual`` when None).
    r0 : ndarray, shape (n_residuals,), optional
        ``residual(x)``, when the caller has it.
    normal_b : ndarray, shape (n_fitted, n_fitted), optional
        ``j_b.T @ j_b``, when the caller has it.

    Notes
    -----
    The block's Jacobian projected off the current one, ``J~ = J_e - J_b A`` with ``A`` the least squares
    of ``J_e`` on ``J_b``, enters only through ``J~^T J~`` and ``J~^T r0``: sums over the rows, taken
    :data:`SCORE_CHUNK_ROWS` rows at a time (each chunk's ``J~`` stays in the CPU's cache; the same sums
    as over the whole ``J~`` but for the order of the additions).
    """
    r0 = residual(x) if r0 is None else r0
    q = x.size - n_fitted
    j_e = block_jacobian
    if j_e is None:
        j_e = np.empty((r0.size, q))
        for i in range(q):
            xp = x.copy()
            xp[n_fitted + i] += step
            j_e[:, i] = (residual(xp) - r0) / step
    normal_b = j_b.T @ j_b if normal_b is None else normal_b
    absorbed, *_ = np.linalg.lstsq(normal_b, j_b.T @ j_e, rcond=SINGULAR_RCOND**2)  # small normal equations
    normal, pulled = np.zeros((q, q)), np.zeros(q)
    for start in range(0, r0.size, SCORE_CHUNK_ROWS):
        rows = slice(start, start + SCORE_CHUNK_ROWS)
        j_tilde = j_e[rows] - j_b[rows] @ absorbed
        normal += j_tilde.T @ j_tilde
        pulled += j_tilde.T @ r0[rows]
    # the effect's directions the current model cannot tell from its own parameters carry no
    # evidence (a shape parameter at zero size among them): drop them and leave them as they are
    scale = np.sqrt(np.diag(normal))
    scale[scale == 0] = 1.0
    w, v = np.linalg.eigh(normal / np.outer(scale, scale))
    keep = w > SINGULAR_RCOND**2 * max(w.max(), 1e-300)
    projected = pulled / scale
    coef_scaled = (v[:, keep] / w[keep]) @ (v[:, keep].T @ projected)
    # residual = data - model, so the model must move by +J coef: parameters step by -coef
    return float(projected @ coef_scaled), -coef_scaled / scale
