"""The tumble model's score tests reuse the fit they score against (its unit Jacobian, its corrected reading)
across the forms of a round: the scores must equal a fresh model's, also after the fit has moved on."""

import numpy as np

from calibrate.effects import Basis
from calibrate.tumble.diagnosis import TUMBLE_FORMS, _Context, _Model, _Rows, radial_noise_floor
from calibrate.tumble.ellipsoid import fit_ellipsoid
from compass.sim.tumble import simulate_tumble


def _model(fit, mag, t_s):
    rows = _Rows((mag[fit.inliers] - fit.centre) / fit.radius, t_s[fit.inliers], None)
    return _Model(fit, rows, _Context(radius=fit.radius, basis=Basis.of(t_s, None)), radial_noise_floor(fit.residuals))


def test_scores_against_a_new_fit_are_a_fresh_models():
    sim = simulate_tumble(n=2000, seed=22, drift_ut=3.0, drift_tau_s=12.0)
    fit, _, _ = fit_ellipsoid(sim.mag)
    kept = _model(fit, sim.mag, sim.t_s)
    base = kept.fit((), fit.params)
    drift, warm_up, gain = TUMBLE_FORMS["offset_drift"][0], TUMBLE_FORMS["offset_drift"][1], TUMBLE_FORMS["gain_drift"][0]
    first = [kept.score(base, e) for e in (drift, warm_up, gain)]  # one round: every form against the base
    for (drop, start), effect in zip(first, (drift, warm_up, gain)):
        fresh_drop, fresh_start = _model(fit, sim.mag, sim.t_s).score(base, effect)
        assert drop == fresh_drop and np.array_equal(start, fresh_start)
    assert first[1][0] > 100.0  # the warm-up the simulation put in is what the scores see
    trial = kept.refit(base, warm_up, first[1][1])
    assert trial.x.size == base.x.size + warm_up.n_params(3)
    drop, start = kept.score(trial, gain)  # the next round: against the fit with the warm-up
    fresh_drop, fresh_start = _model(fit, sim.mag, sim.t_s).score(trial, gain)
    assert drop == fresh_drop and np.array_equal(start, fresh_start)
    assert drop < 0.1 * first[1][0]  # the warm-up took what the base left


def test_every_form_at_its_score_points_leaves_the_fit_as_it_is():
    """What the scores reuse rests on: at a score point (a block of zero size) every form's correction returns the
    corrected reading it was given, to the bit, so the residual there is the fit's own (and so is the gradient by
    the corrected reading); the temperature forms on a recording with ``temp_c``."""
    sim = simulate_tumble(n=3000, seed=5, drift_ut=3.0, drift_tau_s=12.0)
    temp_c = 20.0 + 5.0 * np.sin(sim.t_s / sim.t_s[-1] * 3.0)
    fit, _, _ = fit_ellipsoid(sim.mag)
    rows = _Rows((sim.mag[fit.inliers] - fit.centre) / fit.radius, sim.t_s[fit.inliers], temp_c[fit.inliers])
    model = _Model(fit, rows, _Context(radius=fit.radius, basis=Basis.of(sim.t_s, temp_c)),
                   radial_noise_floor(fit.residuals))
    cubic = TUMBLE_FORMS["nonlinear_response"][0]
    for current in ((), (cubic,)):
        x = np.concatenate([fit.params] + [np.full(e.n_params(3), 0.01) for e in current])
        z = model.corrected(x, current, rows)
        r = model.weighted(x, current)
        for form in (f for forms in TUMBLE_FORMS.values() for f in forms if f not in current):
            for q0 in form.score_points(3):
                np.testing.assert_array_equal(form.correct(z, q0, rows, model.ctx), z)
                np.testing.assert_array_equal(model.weighted(np.concatenate([x, q0]), current + (form,)), r)
