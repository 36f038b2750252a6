"""What an unexplained swing's excess over the floor does to the errors-in-variables correction
(:func:`calibrate.installation.model.debiased`): the accelerometer's excess is not blamed on the field, and
a correction that would move a parameter beyond its sigma is left out and said so."""

import numpy as np
import pytest

import calibrate.installation.fit as fit_module
from calibrate.installation import InstallationCalibrator
from calibrate.installation.model import debiased
from compass.calibration import from_dict, model_to_dict
from compass.io.installation import InstallationRecording
from compass.sim.fourflip import simulate_fourflip
from compass.sim.installation import random_installation, simulate_installation, true_model
from tests.calibrate.installation.test_swing_wander import with_wander


def _bench(seed):
    truth = simulate_fourflip(seed=seed).truth
    return truth, from_dict(model_to_dict(true_model(truth)) | {"format": "compass-calibration/1", "model": "channels"})


def _recording(sim, outputs, accel):
    return InstallationRecording("sim", sim.kind, sim.channels, outputs, accel, sim.t_s, None, None, False,
                                 np.arange(len(sim.t_s)), {})


def _both(monkeypatch, rec, bench, **kwargs):
    """The calibrator's result, and its result with the excess left out of the correction."""
    corrected = InstallationCalibrator(base=bench, **kwargs).fit(rec)
    monkeypatch.setattr(fit_module, "debiased", lambda fit, rows, priors, unexplained=False: debiased(fit, rows, priors))
    plain = InstallationCalibrator(base=bench, **kwargs).fit(rec)
    monkeypatch.undo()
    return corrected, plain


def test_an_accelerometer_excess_alone_leaves_the_vertical_hard_iron_where_the_plain_correction_put_it(monkeypatch):
    """A slow accelerometer disturbance (2 % of g RMS, ~1 s, as a hand-held swing's) makes the angle rows
    noisier than their floor but not the |B| rows: the field gets no excess across it, so the vertical hard
    iron moves by under a third of its standard error over seeds (blaming it on the field moved it by about
    -1.5 uT: ``tools/bench_swing_sigma.py``'s ``accelerometer slow``, seeds 0-19, 1b40052 against 84b91b3)."""
    shifts, errors, flagged = [], [], 0
    for seed in range(8):
        truth, bench = _bench(seed)
        inst = random_installation(500 + seed, yaw_deg=0.0)
        sim = simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=10.0, seed=700 + seed,
                                    accel_noise_g=0.002)
        acc = np.array(sim.accel, dtype=float)
        rng = np.random.default_rng([seed, 5])
        kernel = np.hanning(101) / np.hanning(101).sum()
        slow = np.column_stack([np.convolve(rng.normal(size=len(acc)), kernel, "same") for _ in range(3)])
        acc = acc + slow * 0.02 / np.sqrt(np.mean(slow**2)) * np.linalg.norm(acc, axis=1, keepdims=True)
        corrected, plain = _both(monkeypatch, _recording(sim, sim.outputs, acc), bench, accel_noise_g=0.002)
        flagged += bool(corrected.diagnosis.block["unexplained"])
        shifts.append(corrected.hard_iron_ut[2] - plain.hard_iron_ut[2])
        errors.append(plain.hard_iron_ut[2] - inst.hard_iron_ut[2])
    assert flagged >= 4  # the excess is there to be counted
    se = np.std(errors, ddof=1) / np.sqrt(len(errors))
    assert abs(np.mean(shifts)) < se / 3.0


def test_a_correction_beyond_the_sigma_is_left_out_and_said_so(monkeypatch):
    """A 20 uT hard iron under a field wander: the fit fails (h_z off by ~140 uT) and its residuals, counted
    as noise in the regressors, would move h_z by ~190 uT; the excess's correction is left out, the
    message names the parameter, and the result is the plain correction's."""
    seed = 5
    truth, bench = _bench(seed)
    inst = random_installation(500 + seed, hard_iron_ut=20.0)
    sim = simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=10.0, seed=700 + seed)
    out = with_wander(truth, inst, sim, seed)
    corrected, plain = _both(monkeypatch, _recording(sim, out, sim.accel), bench)
    assert corrected.diagnosis.block["unexplained"]
    message = corrected.statistics.message
    assert "errors-in-variables correction left out" in message and "times its sigma" in message
    np.testing.assert_array_equal(corrected.hard_iron_ut, plain.hard_iron_ut)


def test_the_excess_across_the_field_is_at_most_the_one_along_it():
    """The accelerometer touches only the angle rows: what the field gets across it is bounded by the |B|
    rows' excess (:func:`calibrate.installation.model._excess`)."""
    from calibrate.installation.model import _excess

    truth, bench = _bench(0)
    inst = random_installation(500, yaw_deg=0.0)
    sim = simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=10.0, seed=700, accel_noise_g=0.002)
    acc = sim.accel + np.random.default_rng(1).normal(scale=0.02, size=np.shape(sim.accel))
    result = InstallationCalibrator(base=bench, accel_noise_g=0.002).fit(_recording(sim, sim.outputs, acc))
    fit = result.diagnosis.fit
    along, across = _excess(fit, result.diagnosis.rows, fit.effects, {})
    assert 0.0 <= across <= along
    with pytest.raises(TypeError):
        _excess(fit)


def test_an_excess_beyond_the_second_order_expansion_is_left_out_and_said_so(monkeypatch):
    """An excess of about twice the field RMS (``s`` ~ 2 rad: the neglected term ``s^2/4`` of the kept one is
    about 1, over a tenth): the correction is not made and the message says why."""
    import calibrate.installation.model as model

    seed = 0
    truth, bench = _bench(seed)
    inst = random_installation(500 + seed)
    sim = simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=10.0, seed=700 + seed)
    out = with_wander(truth, inst, sim, seed)
    def excess(fit, rows, effects, priors):  # |b| is |B| within the hard iron: s ~ 2 rad
        variance = (2.0 * float(np.median(np.linalg.norm(rows.b, axis=1)))) ** 2
        return variance, variance
    monkeypatch.setattr(model, "_excess", excess)
    corrected = InstallationCalibrator(base=bench).fit(_recording(sim, out, sim.accel))
    assert corrected.diagnosis.block["unexplained"]
    assert "beyond a second-order expansion" in corrected.statistics.message
    monkeypatch.setattr(fit_module, "debiased", lambda fit, rows, priors, unexplained=False: debiased(fit, rows, priors))
    plain = InstallationCalibrator(base=bench).fit(_recording(sim, out, sim.accel))
    np.testing.assert_array_equal(corrected.hard_iron_ut, plain.hard_iron_ut)
