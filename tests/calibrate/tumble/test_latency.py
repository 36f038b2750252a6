"""A magnetometer late against the accelerometer and gyro: the gyro-aided fit estimates the latency, the
present fit says fast motion and withholds the rotation it would have got wrong (calibrate/tumble/motion.py)."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.tumble import calibrate_tumble
from calibrate.tumble.gyro import LATENCY_PRIOR_S, falls_back, fit_with_gyro, turn_rates, with_gyro
from calibrate.tumble.motion import FAST_MOTION_WARNING, fast_motion, field_turn_rate
from compass.io.tumble import gyro_turns
from compass.sim.partial_tumble import simulate_partial_tumble


def _late(sim, rows):
    """Row k of the magnetometer reads the field of row k - rows (rows / 50 Hz late)."""
    if rows == 0:
        return sim.t_s, sim.mag, sim.accel, sim.gyro
    return sim.t_s[rows:], sim.mag[:-rows], sim.accel[rows:], sim.gyro[rows:]


@pytest.fixture(scope="module")
def fast():
    return simulate_partial_tumble("fast_rotation", seed=5, coverage=0.3)


@pytest.mark.parametrize("rows", [0, 1])
def test_a_simulated_latency_is_recovered_within_its_sigma(fast, rows):
    t_s, mag, accel, gyro = _late(fast, rows)
    turns = gyro_turns(t_s, gyro, np.ones(len(t_s), bool))
    present = calibrate_tumble(mag, accel, t_s=t_s)
    g = fit_with_gyro(mag, accel, turns, t_s, hard_iron=present.hard_iron, soft_iron=present.fit.soft_iron,
                      field_norm=present.field_norm, noise=present.noise)
    true_s = rows * 0.02
    # the sigma is the data's (far inside the prior), and the truth within 4 of it (the first-order model's
    # (tau |w|)^2 / 2 and the gyro's unmodelled 0.5 % scale error: a floor of 0.3 ms)
    assert g.latency_sigma_s < 0.05 * LATENCY_PRIOR_S
    assert abs(g.latency_s - true_s) < 4 * g.latency_sigma_s + 3e-4
    assert g.latency_known is (rows > 0)
    assert ("ms late against the gyro" in g.words()) is (rows > 0)
    # held at zero, the latency goes into the residual and the hard iron
    if rows:
        held = fit_with_gyro(mag, accel, turns, t_s, hard_iron=present.hard_iron, soft_iron=present.fit.soft_iron,
                             field_norm=present.field_norm, noise=present.noise, fit_latency=False)
        assert abs(held.latency_s) < 1e-9 and held.mag_rms > 1.5 * g.mag_rms
        h_true = np.array(fast.truth["hard_iron"])
        assert np.linalg.norm(held.hard_iron - h_true) > 2 * np.linalg.norm(g.hard_iron - h_true)
        # a gyro later than the magnetometer is a negative latency, which the runtime filter cannot take
        early = dataclasses.replace(g, latency_s=-g.latency_s).words()
        assert "early against the gyro" in early and "cannot compensate" in early and "ms late" not in early


def test_turn_rates_are_the_centred_mean_rate():
    dt = np.array([0.0, 0.01, 0.02, 0.01])
    w = np.array([[0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    rates = turn_rates(w * dt[:, None], dt)
    # (t0, t2] turned 0.01 + 0.04 rad in 0.03 s; the ends one-sided
    assert np.allclose(rates[:, 0], [1.0, 0.05 / 0.03, (0.04 + 0.03) / 0.03, 3.0])
    assert np.all(rates[:, 1:] == 0)
    # no time passed: no rate, not a division by zero
    assert np.all(turn_rates(np.zeros((3, 3)), np.zeros(3)) == 0)


@pytest.fixture(scope="module")
def whole():
    return simulate_partial_tumble("fast_rotation", seed=6, coverage=None, duration_s=40.0)


def test_fast_motion_with_a_late_magnetometer_is_said_and_the_rotation_withheld(whole):
    t_s, mag, accel, gyro = _late(whole, 1)
    res = calibrate_tumble(mag, accel, t_s=t_s)
    said = [w for w in res.warnings if w.startswith(FAST_MOTION_WARNING)]
    assert len(said) == 1 and "deg/s" in said[0] and "frames taken as aligned" in said[0]
    # the latency from the field-gravity angle alone (the scan's 2 ms steps)
    late_ms = float(said[0].split("magnetometer reads about ")[1].split(" ms late")[0])
    assert abs(late_ms - 20.0) <= 2.0
    assert res.mag_to_accel is None and "fast motion" in res.misalignment.withheld
    assert falls_back(res)  # with a gyro, the gyro-aided fit takes over, and fits the latency
    turns = gyro_turns(t_s, gyro, np.ones(len(t_s), bool))
    aided = with_gyro(res, mag, accel, turns, t_s)
    assert aided.gyro["used"] and abs(aided.gyro["mag_latency_s"] - 0.02) < 4 * aided.gyro["mag_latency_sigma_s"] + 3e-4
    assert not any(w.startswith(FAST_MOTION_WARNING) for w in aided.warnings)
    err = Rotation.from_matrix(whole.truth["mag_to_accel"]).inv() * aided.misalignment.rotation
    assert np.degrees(err.magnitude()) < 0.5


def test_the_same_motion_on_time_is_not_fast_motion(whole):
    res = calibrate_tumble(whole.mag, whole.accel, t_s=whole.t_s)
    assert not any(w.startswith(FAST_MOTION_WARNING) for w in res.warnings)
    assert res.mag_to_accel is not None
    # without times there is no rate: no check
    assert not any(w.startswith(FAST_MOTION_WARNING)
                   for w in calibrate_tumble(whole.mag[:-1], whole.accel[1:]).warnings)


def test_field_turn_rate_against_a_known_turn():
    t = np.arange(50) * 0.02
    angle = np.radians(90.0) * t  # 90 deg/s about z
    mag = np.column_stack([np.cos(angle), np.sin(angle), np.full_like(t, 0.0)]) * 40.0
    assert np.allclose(np.degrees(field_turn_rate(mag, t)), 90.0, rtol=1e-3)
    t[10] = t[9] = t[11]  # repeated times: no rate there, not an infinity
    rate = field_turn_rate(mag, t)
    assert np.isnan(rate[10]) and np.all(np.isfinite(np.delete(rate, 10)))


def test_bad_input_is_refused_in_words():
    with pytest.raises(ValueError, match=r"mag must have shape \(n, 3\) and t_s shape \(n,\)"):
        field_turn_rate(np.zeros((5, 2)), np.arange(5.0))
    with pytest.raises(ValueError, match=r"accel must have the shape of mag_cal \(5, 3\)"):
        fast_motion(np.ones((5, 3)), np.ones((4, 3)), np.arange(5.0))
    # too few quasi-static rows to judge: no verdict
    assert fast_motion(np.ones((5, 3)), np.ones((5, 3)), np.arange(5.0)) is None
