"""tools/leak_shape.py's transfer functions: reference relations of the steady-state Kalman filter and VQF's low-pass."""

import math

import numpy as np
import pytest
from scipy import signal

from tests._paths import load_tool


@pytest.fixture(scope="module")
def shape():
    return load_tool("leak_shape")


def todays_density(shape, turn_rad_s, leak_deg):
    q = shape.GYRO_VAR + (shape.SCALE_ERROR * turn_rad_s) ** 2 * shape.SCALE_TIME_S
    n = shape.ACCEL_DENSITY + 2.0 * shape.MOTION_TIME_S * math.radians(leak_deg) ** 2
    return q, n


@pytest.mark.parametrize("turn_rad_s, leak_deg", [(3.0, 0.93), (0.9, 1.13)])
def test_todays_gain_is_one_pole_at_the_square_root_of_noise_over_process(shape, turn_rad_s, leak_deg):
    """A random walk (density q) seen in white noise (density N): the steady-state filter is ``1 / (1 + T s)``,
    ``T = sqrt(N / q)``; after the 2 s low-pass, ``L = 1 / ((1 + tau s) (1 + T s))``."""
    q, n = todays_density(shape, turn_rad_s, leak_deg)
    big_t = math.sqrt(n / q)
    periods = np.array([0.5, 2.0, 10.0])
    jw = 2j * np.pi / periods
    expected = 1.0 / ((1.0 + shape.TAU_S * jw) * (1.0 + big_t * jw))
    got = shape.response(shape.whole(shape.today(turn_rad_s, math.radians(leak_deg) ** 2)), periods)
    np.testing.assert_allclose(got, expected, rtol=1e-6)


@pytest.mark.parametrize("turn_rad_s, leak_deg", [(6.0, 1.5), (1.7, 0.44)])
def test_a_rate_error_of_todays_low_frequency_density_keeps_todays_mean_age(shape, turn_rad_s, leak_deg):
    """``1 - K = sqrt(N) / Phi+(s)`` (white measurement noise), and ``Phi+(0)`` is set by the signal's density at low
    frequency alone: both designs have the mean age ``tau + sqrt(N / q)``, however the rate error is coloured."""
    q, n = todays_density(shape, turn_rad_s, leak_deg)
    var = math.radians(leak_deg) ** 2
    expected = shape.TAU_S + math.sqrt(n / q)
    for design in (shape.today, shape.rate_error):
        assert shape.mean_age_s(shape.whole(design(turn_rad_s, var))) == pytest.approx(expected, rel=1e-3)


def test_vqfs_low_pass_is_its_own_coefficients(shape):
    """The Butterworth of ``tauAcc`` 3 s: mean age 3 s, and at the hand's periods the response of VQF's own discrete
    coefficients (``PyVQF.filterCoeffs``) within 1 %."""
    vqf = pytest.importorskip("vqf")
    tf = shape.butterworth()
    assert shape.mean_age_s(tf) == pytest.approx(3.0, rel=1e-3)
    b, a = vqf.PyVQF.filterCoeffs(3.0, 1.0 / shape.RATE_HZ)
    periods = np.array([0.5, 2.0, 6.0])
    discrete = signal.freqz(b, np.r_[1.0, a], worN=1.0 / periods, fs=shape.RATE_HZ)[1]
    np.testing.assert_allclose(np.abs(shape.response(tf, periods)), np.abs(discrete), rtol=0.01)


def test_at_a_given_mean_age_the_scaled_design_has_it(shape):
    var = math.radians(0.93) ** 2
    tf = shape.at_age(shape.band_pass_leak, 3.0, var, 3.5)
    assert shape.mean_age_s(tf) == pytest.approx(3.5, rel=1e-6)
