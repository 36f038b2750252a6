"""The one noise-floor module: second differences, and Sheppard's floor on integer codes."""

import numpy as np
import pytest

from calibrate.noise import (COARSE_LATTICE, lattice_step, noise_floor, quantisation_note, second_difference_sigma,
                             second_differences)


def _turn(rng, sigma, step=0.0, n=1440, swing=200.0):
    """Four flips of a first-harmonic output with white noise, rounded to ``step`` when given."""
    flip = np.repeat(np.arange(4), n // 4)
    phi = np.tile(np.arange(0.0, 360.0, 360.0 / (n // 4)), 4)
    v = swing * np.cos(np.radians(phi) + flip)[:, None] + rng.normal(scale=sigma, size=(n, 1))
    if step:
        v = np.round(v / step) * step
    return phi, flip, v


def test_lattice_step_finds_codes_and_rejects_floats():
    rng = np.random.default_rng(1)
    codes = rng.integers(-500, 500, size=(300, 2)) * np.array([1.0, 0.25]) + np.array([0.0, 3.0])
    assert lattice_step(codes) == pytest.approx([1.0, 0.25])
    assert lattice_step(rng.normal(size=(300, 1)))[0] == 0.0
    assert float(lattice_step(np.array([2.0, 2.0]))) == 0.0  # one level: no lattice to speak of


@pytest.mark.parametrize("ratio", [3.0, 6.0, 10.0])
def test_coarse_codes_read_sheppard_floor(ratio):
    """Code step ``ratio`` times the noise: the floor is sqrt(sigma^2 + q^2/12), which the MAD misses."""
    rng = np.random.default_rng(int(ratio))
    sigma = 1.0
    phi, flip, v = _turn(rng, sigma, step=ratio * sigma)
    q = lattice_step(v)
    assert q[0] == pytest.approx(ratio * sigma)
    expected = np.sqrt(sigma**2 + q[0] ** 2 / 12.0)
    floor = noise_floor(phi, flip, v, q)[0]
    assert floor == pytest.approx(expected, rel=0.12)
    mad_only = noise_floor(phi, flip, v)[0]  # without the lattice: off by more than the tolerance
    assert abs(mad_only - expected) > 0.12 * expected


def test_fine_codes_keep_the_robust_floor():
    """A step far below the noise changes nothing: the MAD floor stands (and spikes do not move it)."""
    rng = np.random.default_rng(4)
    phi, flip, v = _turn(rng, 1.0, step=0.01)
    v[::97] += 40.0  # spikes
    q = lattice_step(v)
    assert q[0] < COARSE_LATTICE * 1.0
    assert noise_floor(phi, flip, v, q) == pytest.approx(noise_floor(phi, flip, v))
    assert noise_floor(phi, flip, v, q)[0] == pytest.approx(1.0, rel=0.1)


def test_coarse_floor_ignores_spikes():
    rng = np.random.default_rng(5)
    phi, flip, v = _turn(rng, 1.0, step=5.0)
    clean = noise_floor(phi, flip, v, lattice_step(v))[0]
    v[::53] += 200.0
    assert noise_floor(phi, flip, v, lattice_step(v))[0] == pytest.approx(clean, rel=0.05)


def test_second_difference_sigma_of_white_noise_in_time():
    rng = np.random.default_rng(6)
    x = rng.normal(scale=0.3, size=(20000, 3))
    assert second_difference_sigma(second_differences(x)) == pytest.approx([0.3] * 3, rel=0.05)


def test_quantisation_note_only_when_the_step_matters():
    assert quantisation_note(np.array([0.1, 0.1]), np.array([1.0, 1.0]), ("a", "b")) is None
    note = quantisation_note(np.array([3.0, 0.1]), np.array([1.2, 1.0]), ("a", "b"))
    assert "ADC" in note["words"] and "a 3" in note["words"] and " b " not in note["words"]
    assert note["share_of_floor_variance"]["a"] == pytest.approx(min(9.0 / 12.0 / 1.44, 1.0))
