"""The tumble's per-axis noise is computed once and handed on: what is handed on is what is used."""

import numpy as np
import pytest

from calibrate.contract import CannotCalibrate
from calibrate.tumble.fit import _axis_noise, calibrate_tumble, channel_health, require_varying_axes
from compass.sim.tumble import simulate_tumble


def test_handed_noise_gives_the_computed_result():
    sim = simulate_tumble(n=1500, seed=3)
    noise = _axis_noise(sim.mag)
    assert np.all(np.abs(noise / sim.truth["noise_ut"] - 1.0) < 0.15)  # second differences see the injected noise
    own, handed = calibrate_tumble(sim.mag, sim.accel), calibrate_tumble(sim.mag, sim.accel, axis_noise=noise)
    assert own.noise == handed.noise == float(np.median(noise))
    for a, b in zip(channel_health(own, sim.mag), channel_health(handed, sim.mag, noise)):
        assert (a.name, a.response, a.response_sigma, a.noise) == (b.name, b.response, b.response_sigma, b.noise)


def test_handed_noise_is_the_one_judged():
    sim = simulate_tumble(n=1500, seed=3)
    require_varying_axes("t.csv", sim.mag, _axis_noise(sim.mag))  # a live tumble passes
    with pytest.raises(CannotCalibrate, match=r"t.csv: column 'mx' never varied beyond its noise"):
        require_varying_axes("t.csv", sim.mag, np.array([1e3, 0.3, 0.3]))
