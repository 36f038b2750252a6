"""The shared evidence loop revisits what it added (a form replaced once a later effect is in, an effect dropped) and
vetoes a small share only where structure remains."""

import dataclasses

import numpy as np
import pytest

from calibrate.diagnosis.evidence import (DECISIVE_BIC, MIN_SHARE, FitRecord, _revisit, linearised_score,
                                         select_effects)
from calibrate.effects import EffectForm
from calibrate.noise import chi2_sf

N = 500


class _Column(EffectForm):
    """A toy effect: columns added to a linear model's design."""

    def columns(self, t, z):
        return {"linear": [t], "quadratic": [t, t * t], "z": [z]}[self.form]


LIN = _Column("trend", "linear", "a trend")
QUAD = _Column("trend", "quadratic", "a curved trend")
ZED = _Column("zed", "z", "the z column")


def _problem(y, t, z):
    def design(effects):
        return np.column_stack([np.ones_like(t)] + [c for e in effects for c in e.columns(t, z)])

    def weighted(x, effects):
        return y - design(effects) @ x

    def fit(effects, x0=None):
        a = design(effects)
        x, *_ = np.linalg.lstsq(a, y, rcond=None)
        r = y - a @ x
        return FitRecord(tuple(effects), x, -a, np.linalg.inv(a.T @ a), r, float(r @ r), N, True, "")

    def score(current, effect):
        n = len(effect.columns(t, z))
        return linearised_score(weighted, current, effect, [np.zeros(n)], 1e-6)

    def step(p, measured):
        return {"added": p.effect.name, "form": p.effect.form, "delta_bic": p.gain, "residual_rms": 0.0,
                "explained_share": 1.0}

    def revisit(effects, pool):
        """``_revisit`` of a model holding ``effects`` (as if added in that order)."""
        steps = [{"model": "base"}] + [{"added": e.name, "form": e.form} for e in effects]
        revisions = []
        current, steps = _revisit(fit(effects), steps, pool, lambda c, e: fit(e), score,
                                  lambda c, e, s: fit(c.effects + (e,)), lambda e: len(e.columns(t, z)), np.log(N),
                                  step, revisions, lambda text: None)
        return current, steps, revisions

    def run(pool, revise=True, verdict=lambda f: (None, False)):
        return select_effects(fit(()), pool, score=score, refit=lambda c, e, s: fit(c.effects + (e,)),
                              n_params=lambda e: len(e.columns(t, z)), log_n=np.log(N),
                              base_step={"model": "base", "residual_rms": 0.0}, write_step=step,
                              verdict=verdict, revise=(lambda c, e: fit(e)) if revise else None)

    run.fit = fit
    return run, revisit


def test_a_form_is_replaced_once_a_later_effect_is_in():
    """y = 10 t + 2 t^2 + 3 z with z = -2/3 t^2 + w: before z is in, t^2 cancels and the trend looks
    linear; once z is in, the curvature shows and the quadratic form replaces the linear one."""
    rng = np.random.default_rng(0)
    t = np.linspace(-1.0, 1.0, N)
    z = -2.0 / 3.0 * t * t + rng.normal(size=N)
    y = 10 * t + 2 * t * t + 3 * z + rng.normal(size=N)
    run, _ = _problem(y, t, z)
    without = run([LIN, QUAD, ZED], revise=False)
    assert [e.form for e in without.fit.effects] == ["linear", "z"]
    chosen = run([LIN, QUAD, ZED])
    assert [e.form for e in chosen.fit.effects] == ["z", "quadratic"]
    assert [s.get("form") for s in chosen.steps] == [None, "z", "quadratic"]  # one step per effect, in order
    assert len(chosen.revisions) == 1 and "replaced by trend (quadratic)" in chosen.revisions[0]
    assert chosen.fit.x[-1] == pytest.approx(2.0, abs=0.3)


def test_an_effect_that_no_longer_earns_its_place_is_dropped():
    """y = 3 z with z = 4 t + w: a model holding the trend, then z, keeps z alone (the trend's evidence
    with z in is below zero); one that needs both keeps both."""
    rng = np.random.default_rng(1)
    t = np.linspace(-1.0, 1.0, N)
    z = 4.0 * t + 0.4 * rng.normal(size=N)
    _, revisit = _problem(3 * z + rng.normal(size=N), t, z)
    current, steps, revisions = revisit((LIN, ZED), [LIN, ZED])
    assert [e.form for e in current.effects] == ["z"]
    assert len(revisions) == 1 and "trend (linear) dropped" in revisions[0]
    assert [s.get("form") for s in steps] == [None, "z"]
    _, revisit = _problem(3 * z + 20 * t + rng.normal(size=N), t, z)
    current, steps, revisions = revisit((LIN, ZED), [LIN, ZED])
    assert [e.form for e in current.effects] == ["linear", "z"] and revisions == []


def _low_floor_problem(unknown: float):
    """y = 0.7 t + 1.0 ``unknown`` sin(3 pi t) + noise of sigma 1.25, weighted as if the floor were 1: the chi-square
    above its dof (about 280 of it white) dwarfs the trend's drop (about 80, delta-BIC about 75).  The verdict
    regresses the residual on t, t^2 and the third half-wave against the residual's own variance."""
    rng = np.random.default_rng(2)
    t = np.linspace(-1.0, 1.0, N)
    y = 0.7 * t + unknown * np.sin(3 * np.pi * t) + 1.25 * rng.normal(size=N)
    run, _ = _problem(y, t, np.zeros(N))
    probe = np.column_stack([t, t * t, np.sin(3 * np.pi * t), np.cos(3 * np.pi * t)])

    def verdict(f):
        r = np.asarray(f.residuals)
        coef, *_ = np.linalg.lstsq(probe, r, rcond=None)
        found = probe @ coef
        stat = float(found @ found / (np.sum((r - found) ** 2) / (N - probe.shape[1] - f.x.size)))
        p = chi2_sf(stat, probe.shape[1])
        return (stat, probe.shape[1], p), p < 1e-3

    base, trial = run.fit(()), run.fit((LIN,))
    share = (base.chi2 - trial.chi2) / (base.chi2 - base.dof)
    return run([LIN], verdict=verdict), share, base.bic() - trial.bic()


def test_a_small_share_does_not_veto_an_effect_that_leaves_no_structure():
    """The share is read against chi2 - dof, which a floor 25 % low fills with white noise: the trend explains
    under MIN_SHARE of it, yet with the trend in the residual is white, so it is claimed (the share alone would
    veto it and call the residual unexplained)."""
    chosen, share, gain = _low_floor_problem(0.0)
    assert share < MIN_SHARE and gain > 3 * DECISIVE_BIC  # the case the share alone vetoed
    assert [e.name for e in chosen.fit.effects] == ["trend"]
    assert chosen.unexplained is False and chosen.not_claimed == []


def test_a_small_share_still_vetoes_an_effect_that_leaves_structure():
    """The same trend beside a structure no effect describes (a third half-wave): with the trend in, structure
    remains, so the trend's small share vetoes it and nothing is claimed."""
    chosen, share, gain = _low_floor_problem(1.0)
    assert share < MIN_SHARE and gain > 3 * DECISIVE_BIC
    assert chosen.fit.effects == () and chosen.unexplained is True
    assert len(chosen.not_claimed) == 1 and "it explains only" in chosen.not_claimed[0]


def test_an_effect_promising_less_than_decisive_is_refitted_and_judged_by_its_refit():
    """The score's promise is first order; where it under-states what the refit buys (here half of it, as for an
    encoder error whose harmonics a response's powers had taken), an effect promising under DECISIVE_BIC is refitted
    and claimed on its refit's decisive delta-BIC; on noise alone, whose promise is nothing, nothing is refitted."""
    rng = np.random.default_rng(3)
    t = np.linspace(-1.0, 1.0, N)
    z = rng.normal(size=N)
    for size, named in ((0.3, ["zed"]), (0.0, [])):
        run, _ = _problem(size * z + rng.normal(size=N), t, z)
        refits, promises = [], []

        def halved(current, effect):
            drop = current.chi2 - run.fit(current.effects + (effect,)).chi2
            promises.append(0.5 * drop - np.log(N))
            return 0.5 * drop, np.zeros(1)

        def refit(current, effect, start):
            refits.append(run.fit(current.effects + (effect,)))
            return refits[-1]

        chosen = select_effects(run.fit(()), [ZED], score=halved, refit=refit, n_params=lambda e: 1, log_n=np.log(N),
                                base_step={"model": "base", "residual_rms": 0.0},
                                write_step=lambda p, m: {"added": p.effect.name, "delta_bic": p.gain},
                                verdict=lambda f: (None, False))
        assert [e.name for e in chosen.fit.effects] == named
        if named:
            assert 0.0 < promises[0] < DECISIVE_BIC < chosen.steps[1]["delta_bic"]
        else:
            assert promises[0] <= 0.0 and refits == []


@pytest.mark.parametrize("size, named", [(0.5, ["zed"]), (0.37, [])])
def test_a_refit_cut_short_decides_whether_a_sub_decisive_candidate_is_refitted_in_full(size, named):
    """A candidate promising under DECISIVE_BIC is first refitted cut short (``quick_refit``: here the fit a
    quarter of the way from the current one's chi-square to the converged one's, a lower bound of its drop): the
    full refit runs only where that bound is decisive, and the claim is the full refit's; where the bound is not,
    the full refit never runs and nothing is claimed, even if the converged fit might have been decisive."""
    rng = np.random.default_rng(3)
    t = np.linspace(-1.0, 1.0, N)
    z = rng.normal(size=N)
    run, _ = _problem(size * z + rng.normal(size=N), t, z)
    full, quick = [], []

    def refit(current, effect, start):
        full.append(run.fit(current.effects + (effect,)))
        return full[-1]

    def cut_short(current, effect, start):
        converged = run.fit(current.effects + (effect,))
        quick.append(dataclasses.replace(converged, chi2=current.chi2 - 0.25 * (current.chi2 - converged.chi2)))
        return quick[-1]

    def halved(current, effect):  # the first-order promise under decisive in both cases
        drop = current.chi2 - run.fit(current.effects + (effect,)).chi2
        return min(0.5 * drop, DECISIVE_BIC + np.log(N) - 1.0), np.zeros(1)

    base = run.fit(())
    chosen = select_effects(base, [ZED], score=halved, refit=refit, n_params=lambda e: 1, log_n=np.log(N),
                            base_step={"model": "base", "residual_rms": 0.0},
                            write_step=lambda p, m: {"added": p.effect.name, "delta_bic": p.gain},
                            verdict=lambda f: (None, False), quick_refit=cut_short)
    assert [e.name for e in chosen.fit.effects] == named and len(quick) == 1
    bound = base.bic() - quick[0].bic()
    if named:
        assert bound > DECISIVE_BIC and len(full) == 1 and chosen.fit is full[0]
    else:
        assert bound <= DECISIVE_BIC and full == []
        assert base.bic() - run.fit((ZED,)).bic() > DECISIVE_BIC  # the converged one would have been claimed


@pytest.mark.parametrize("bound_over_decisive, swapped", [(1.0, True), (-1.0, False)])
def test_a_swap_promising_under_decisive_is_refitted_cut_short_then_judged_by_its_refit(bound_over_decisive, swapped):
    """The revisit decides a swap as the loop decides an addition.  y = 10 t + 2 t^2 + 3 z with z = -2/3 t^2 + w,
    the model holding the linear trend, then z: the quadratic form's first-order promise over the linear one is put
    at half of DECISIVE_BIC (a swap refitted only on a decisive promise keeps the linear form), while its
    refit from the model without the trend buys far more.  Cut short (here: the converged fit's chi-square plus a
    slack, its delta-BIC against the model with the linear form a lower bound), the swap is refitted in full only where
    that bound is decisive, and taken on the full refit's delta-BIC; where the bound is not, the full refit never
    runs and the linear form stays, though the converged swap would have been decisive."""
    rng = np.random.default_rng(0)
    t = np.linspace(-1.0, 1.0, N)
    z = -2.0 / 3.0 * t * t + rng.normal(size=N)
    run, _ = _problem(10 * t + 2 * t * t + 3 * z + rng.normal(size=N), t, z)
    current = run.fit((LIN, ZED))
    converged = run.fit((ZED, QUAD))
    gain = current.bic() - converged.bic()
    assert gain > DECISIVE_BIC + 1.0  # the converged swap is decisive in both cases
    full, quick = [], []

    def score(without, form):  # the swap's first-order promise over the current form: half of DECISIVE_BIC
        return without.bic() - current.bic() + 2 * np.log(N) + 0.5 * DECISIVE_BIC, np.zeros(2)

    def refit(without, form, start):
        full.append(run.fit(without.effects + (form,)))
        return full[-1]

    def cut_short(without, form, start):
        slack = gain - DECISIVE_BIC - bound_over_decisive
        quick.append(dataclasses.replace(run.fit(without.effects + (form,)), chi2=converged.chi2 + slack))
        return quick[-1]

    steps = [{"model": "base"}, {"added": "trend", "form": "linear"}, {"added": "zed", "form": "z"}]
    revisions = []
    final, steps = _revisit(current, steps, [LIN, QUAD, ZED], lambda c, e: run.fit(e), score, refit,
                            lambda e: len(e.columns(t, z)), np.log(N),
                            lambda p, m: {"added": p.effect.name, "form": p.effect.form, "delta_bic": p.gain},
                            revisions, lambda text: None, quick_refit=cut_short)
    assert len(quick) == 1
    if swapped:
        assert len(full) == 1 and final is full[0]
        assert [e.form for e in final.effects] == ["z", "quadratic"]
        assert len(revisions) == 1 and "replaced by trend (quadratic)" in revisions[0]
    else:
        assert full == [] and revisions == []
        assert final is current
