"""A swing under a wandering field: the widened sigma against the wander's projected effect, at one design.

A field wandering in the world frame, ``dB(t)``, enters a swing's rows as two functions of time alone
(to first order the |B| rows see ``B^ . dB``, the angle rows ``(up - mu B^) . dB / |B|``, whatever the
heading), and moves the fit by ``-(J^T J)^-1 J^T`` of them: on a steady swing the hard iron's columns are
once-a-turn functions of time, so the wander's part at the turn's frequency goes into the hard iron and
leaves the residual.  Linearised at a real fit (the same design every replicate, a wander and the
noise drawn afresh), the widening (``calibrate.installation.diagnosis._widen``, as the calibrator calls
it on an unexplained recording) is judged against the spread of the error it is meant to cover.
"""

from dataclasses import replace

import numpy as np

from calibrate.installation import InstallationCalibrator
from calibrate.installation.diagnosis import _widen
from calibrate.installation.model import coordinates, residuals
from compass.calibration import from_dict, model_to_dict
from compass.frames import r_world_from_housing
from compass.io.installation import InstallationRecording
from compass.sim.fourflip import simulate_fourflip
from compass.sim.installation import random_installation, simulate_installation, true_model


def _wander(rng, n: int, size: float, width: int = 301) -> np.ndarray:
    """A smoothed random walk in the world frame, shape (n, 3), ``size`` uT RMS about its mean."""
    steps = rng.normal(size=(n + width, 3))
    kernel = np.hanning(width) / np.hanning(width).sum()
    walk = np.cumsum(np.column_stack([np.convolve(steps[:, k], kernel, "same") for k in range(3)]), axis=0)[:n]
    walk -= walk.mean(axis=0)
    return walk * size / np.sqrt(np.mean(walk**2))


def with_wander(truth, inst, sim, seed: int, size_ut: float = 0.4) -> np.ndarray:
    """The swing's outputs with a field wander (:func:`_wander`, ``size_ut`` uT RMS in the world frame, seeded
    by ``[seed, 77]``) laid on them through the product's soft iron and the bench's channels."""
    housing = r_world_from_housing(sim.heading_deg, sim.pitch_deg, sim.roll_deg)
    d_h = housing.apply(_wander(np.random.default_rng([seed, 77]), len(sim.t_s), size_ut), inverse=True)
    d_h = d_h @ np.asarray(inst.soft_iron).T
    return sim.outputs + np.asarray(truth["gains_per_ut"]) * (d_h @ np.asarray(truth["directions"]).T)


def test_the_widened_sigma_covers_a_field_wander_of_known_size_and_zero_wander_is_not_widened():
    truth = simulate_fourflip(seed=0).truth
    bench = from_dict(model_to_dict(true_model(truth)) | {"format": "compass-calibration/1", "model": "channels"})
    inst = random_installation(500)
    sim = simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=10.0, seed=700)
    rec = InstallationRecording("sim", sim.kind, sim.channels, sim.outputs, sim.accel, sim.t_s, None, None, False,
                                np.arange(len(sim.t_s)), {})
    result = InstallationCalibrator(base=bench).fit(rec)
    fit, rows = result.diagnosis.fit, result.diagnosis.rows
    # zero wander: nothing unexplained, nothing widened; the sigma is the fit's own
    assert not result.diagnosis.block["unexplained"] and "unexplained_cost" not in result.diagnosis.block
    np.testing.assert_array_equal(result.hard_iron_sigma_ut, np.sqrt(np.diag(fit.covariance)[:3]))
    n, n_data = fit.n_rows, fit.n_obs
    assert n == len(sim.t_s)  # every row fitted: the wander below is laid on them in order
    t, dependent = coordinates(fit.fixed, True)  # no site: trace(S) = 3
    moved = ~fit.fixed
    if dependent is not None:
        moved[dependent] = False
    lift, jac = t[:, moved], fit.jac
    bread = np.linalg.pinv(jac.T @ jac)
    housing = r_world_from_housing(sim.heading_deg, sim.pitch_deg, sim.roll_deg)
    clean = residuals(fit.x, rows, (), {})[:n_data]
    rng = np.random.default_rng(31)
    err, var = [], []
    for _ in range(150):
        d_h = housing.apply(_wander(rng, n, 0.4), inverse=True) @ np.asarray(inst.soft_iron).T
        noisy = replace(rows, b=rows.b + d_h)
        shift = lift @ (-bread @ (jac[:n_data].T @ (residuals(fit.x, noisy, (), {})[:n_data] - clean)))
        wide, cost = _widen(replace(fit, x=fit.x + shift), noisy, {}, sim.t_s)
        err.append(shift[:3])
        var.append(np.diag(wide.covariance)[:3])
    err, var = np.array(err), np.array(var)
    assert np.all(np.sqrt(np.mean(err**2, axis=0)) > 5.0 * result.hard_iron_sigma_ut)  # the wander dominates
    # covered in expectation: the mean stated variance at least the error's mean square, less 3 standard errors
    # of that mean square (150 replicates: about 12 %); the vertical over-covered (blocks taken as independent
    # over-count a wander slower than they are, docs/benchmarks.md)
    mean_square = np.mean(err**2, axis=0)
    se = np.std(err**2, axis=0, ddof=1) / np.sqrt(len(err))
    assert np.all(var.mean(axis=0) > mean_square - 3.0 * se)
    # one error over its own sigma: the RMS over the three components in the benchmark's band (1.04 here).  Per
    # component it is not: x 1.46, y 0.95, z 0.49.  x's stated variance is right on average (0.075 against a mean
    # square of 0.073 uT^2) and still its err/sig is 1.46: the variance rests on about 6 degrees of freedom
    # (blocks.sandwich_dof; t tails alone give sqrt(6 / 4) = 1.22), and a wander whose turn-frequency part is
    # large goes into the hard iron and leaves the residual the sandwich reads, so a large error comes with a
    # small sigma; y and z are over-covered by the blocks' independence
    assert 0.8 < np.sqrt(np.mean(err**2 / var)) < 1.25


def test_a_field_wander_leaves_no_bias_in_the_vertical_hard_iron():
    """The wander is noise in the fit's regressors too (``calibrate.installation.model.debiased``): counted, the
    vertical hard iron's mean error over seeds is within 3 standard errors of zero and under half the
    0.52 uT it was without it (seeds 0-19 of ``tools/bench_swing_sigma.py``; 12 seeds here give a standard
    error of about 0.1 uT)."""
    errors = []
    for seed in range(12):
        truth = simulate_fourflip(seed=seed).truth
        bench = from_dict(model_to_dict(true_model(truth)) | {"format": "compass-calibration/1", "model": "channels"})
        inst = random_installation(500 + seed)
        sim = simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=10.0, seed=700 + seed)
        out = with_wander(truth, inst, sim, seed)
        rec = InstallationRecording("sim", sim.kind, sim.channels, out, sim.accel, sim.t_s, None, None, False,
                                    np.arange(len(sim.t_s)), {})
        result = InstallationCalibrator(base=bench).fit(rec)
        assert result.diagnosis.block["unexplained"]
        errors.append(result.hard_iron_ut[2] - inst.hard_iron_ut[2])
    mean, se = np.mean(errors), np.std(errors, ddof=1) / np.sqrt(len(errors))
    assert abs(mean) < 3.0 * se and abs(mean) < 0.26
