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
