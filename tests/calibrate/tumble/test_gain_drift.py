"""gain_drift and the unexplained widening of the tumble's diagnosis."""

import numpy as np

from calibrate.tumble import calibrate_tumble, diagnose_tumble, fit_ellipsoid
from compass.sim.tumble import simulate_tumble


def _drifted(sim, per_axis):
    h = np.array(sim.truth["hard_iron"])
    return h + (sim.mag - h) * (1.0 + np.outer(sim.t_s / sim.t_s[-1], per_axis))


def test_a_gain_drift_is_named_and_its_rate_recovered():
    sim = simulate_tumble(seed=3, n=3000)
    per_axis = np.array([0.02, -0.015, 0.01])
    result = calibrate_tumble(_drifted(sim, per_axis), sim.accel, t_s=sim.t_s)
    block = result.diagnosis.block
    assert block["effects"] == ["gain_drift"] and block["unexplained"] is False
    (effect,) = result.diagnosis.effects
    assert effect["reference"] == {"t_s": 0.0}
    rate, sigma = (np.array([effect["parameters"][f"{ax}.gain_rate_rel_per_s"][k] for ax in ("mx", "my", "mz")])
                   for k in ("value", "sigma"))
    assert np.all(np.abs(rate - per_axis / sim.t_s[-1]) < 4 * sigma)


def test_clean_tumbles_name_nothing():
    for seed in (5, 6, 7):
        sim = simulate_tumble(seed=seed, n=3000)
        block = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s).diagnosis.block
        assert block["effects"] == [] and "unexplained_cost" not in block


def test_gain_drift_is_not_tried_where_it_trades_with_a_moving_hard_iron_or_without_time():
    sim = simulate_tumble(seed=8, n=3000, coverage="upright")
    fit, _, coverage = fit_ellipsoid(sim.mag, "auto")
    assert coverage.missing
    block = diagnose_tumble(sim.mag, fit, t_s=sim.t_s, missing=coverage.missing).block
    assert "trades off against a moving hard iron" in block["not_applicable"]["gain_drift"]
    full = simulate_tumble(seed=8, n=3000)
    fit, _, _ = fit_ellipsoid(full.mag, "auto")
    assert diagnose_tumble(full.mag, fit).block["not_applicable"]["gain_drift"] == "the recording has no t_s column"


def test_an_unexplained_residual_widens_the_hard_iron_sigma():
    sim = simulate_tumble(seed=9, n=3000)
    rng = np.random.default_rng(10)
    walk = np.cumsum(rng.normal(size=sim.mag.shape), axis=0)
    walk = 0.5 * (walk - walk.mean(axis=0)) / walk.std()  # a hard iron wandering by 0.5 uT: not in the vocabulary
    result = calibrate_tumble(sim.mag + walk, sim.accel, t_s=sim.t_s)
    block = result.diagnosis.block
    assert block["unexplained"] is True
    cost = block["unexplained_cost"]["hard_iron"]
    naive = np.array([cost[a]["naive"] for a in ("mx", "my", "mz")])
    wide = np.array([cost[a]["widened"] for a in ("mx", "my", "mz")])
    assert np.all(wide >= naive) and np.any(wide > 1.5 * naive)
    assert np.all(result.fit.hard_iron_sigma >= wide - 1e-12)  # the joint refit with the rotation keeps it
    assert "hard-iron sigmas widened" in result.report() and "heading sigma of a level housing" in result.report()
    heading = block["unexplained_cost"]["heading_sigma_deg"]
    assert heading["widened"] > heading["naive"] > 0
