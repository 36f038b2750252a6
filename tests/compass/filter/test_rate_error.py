"""The gyro's scale error as a Gauss-Markov rate-error state (``FilterConfig.scale_error_state``, issue 22):
the augmented covariance's steps against their textbook forms, the option reducing to today's filter where the
housing does not turn, the rate error's stationary variance, and the bad combination refused."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.filter import AttitudeFilter, FilterConfig
from compass.filter import _rate_error
from compass.filter._kalman import pack
from compass.frames import world_field

RATE_HZ = 285.714
DIP_DEG, FIELD_UT = 65.0, 48.0


def random_covariance(seed: int) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(9, 9))
    return a @ a.T + np.eye(9)


def config(**changes) -> FilterConfig:
    return FilterConfig(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=0.05, **changes)


def test_the_two_parts_are_the_matrix_and_the_six_state_block_is_packed_as_today():
    m = random_covariance(0)
    p, extra = _rate_error.split(m)
    assert p == pack(m[:6, :6]) and len(extra) == 24
    np.testing.assert_allclose(_rate_error.full(p, extra), m, rtol=1e-14)


def test_predict_is_f_p_ft_plus_q():
    m = random_covariance(1)
    r = Rotation.from_euler("ZYX", [30, -10, 5], degrees=True).as_matrix()
    dt, decay = 0.0035, math.exp(-0.0035)
    f = np.eye(9)
    f[:3, 3:6], f[:3, 6:], f[6:, 6:] = -dt * r, dt * np.eye(3), decay * np.eye(3)
    expected = f @ m @ f.T + np.diag([1e-9] * 3 + [2e-10] * 3 + [3e-8] * 3)
    got = _rate_error.full(*_rate_error.predict(*_rate_error.split(m), tuple(r.ravel()), dt, 1e-9, 2e-10, 3e-8, decay))
    np.testing.assert_allclose(got, expected, rtol=1e-12)


@pytest.mark.parametrize("held", [False, True])
def test_update_is_the_kalman_update_or_the_joseph_form_of_its_schmidt_gain(held):
    """All states estimated: ``x += K nu``, ``P - P h h^T P / s``.  The bias considered: its gain zero, the covariance
    ``(I - K h) P (I - K h)^T + K var K^T`` for that gain, and the bias's own block unchanged."""
    m = random_covariance(2)
    h = np.array([0.0, -1.0, 0.0, 0.3, -0.2, 0.1, 0.0, 0.0, 0.0])
    var, z = 0.02, 0.7
    x0 = list(np.random.default_rng(3).normal(size=9) * 0.01)
    estimated = (True,) * 3 + (not held,) * 3 + (True,) * 3
    k = np.where(estimated, m @ h / (h @ m @ h + var), 0.0)
    expected_x = np.array(x0) + k * (z - h @ np.array(x0))
    a = np.eye(9) - np.outer(k, h)
    expected = a @ m @ a.T + var * np.outer(k, k)
    x = list(x0)
    got = _rate_error.full(*_rate_error.update(*_rate_error.split(m), x, tuple(h), z, var, estimated))
    np.testing.assert_allclose(x, expected_x, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12)
    if held:
        np.testing.assert_allclose(got[3:6, 3:6], m[3:6, 3:6], rtol=1e-12)


def still_recording(seconds: float, tilt_deg=(4.0, -3.0)):
    """A still, tilted housing: exact accelerometer and field, a gyro reading exactly zero."""
    rotation = Rotation.from_euler("XY", tilt_deg, degrees=True)
    n = int(seconds * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    accel = np.tile(rotation.apply([0.0, 0.0, 9.81], inverse=True), (n, 1))
    field = np.tile(rotation.apply(world_field(DIP_DEG, FIELD_UT), inverse=True), (n, 1))
    return t, accel, np.zeros((n, 3)), field


def test_where_the_housing_does_not_turn_the_option_is_todays_filter():
    """At zero rate the scale error makes no noise: the rate error's variance stays zero and nothing moves it, so the
    attitude and the six-state covariance are today's (the start's 0.05 rad tilt prior converging as before)."""
    rows = list(zip(*still_recording(5.0)))
    today, augmented = AttitudeFilter(config(), gyro=True), AttitudeFilter(config(scale_error_state=True), gyro=True)
    for row in rows:
        today.update(*row)
        augmented.update(*row)
    np.testing.assert_allclose(augmented.matrix, today.matrix, atol=1e-12)
    np.testing.assert_allclose(augmented.state.covariance, today.state.covariance, rtol=1e-9, atol=1e-18)
    np.testing.assert_allclose(augmented.state.rate_error, 0.0, atol=1e-15)  # round-off only
    np.testing.assert_allclose(augmented.state.rate_error_cov[18:], 0.0, atol=1e-20)


def test_in_a_steady_turn_the_rate_errors_variance_is_the_scale_errors():
    """Turning at 2 rad/s about the vertical with no accelerometer or field after the first sample: the rate error is
    a Gauss-Markov process of variance ``s^2 |w|^2 / 2`` per axis (the white noise it replaces is its low-frequency
    density ``s^2 |w|^2 T``); after ten correlation times it is there within 1 %."""
    cfg = config(scale_error_state=True)
    filt = AttitudeFilter(cfg, gyro=True)
    t, accel, gyro, field = still_recording(10.0, (0.0, 0.0))
    gyro[:, 2] = 2.0
    filt.update(t[0], accel[0], gyro[0], field[0])
    for row in zip(t[1:], gyro[1:]):
        filt.update(row[0], None, row[1], None)
    extra = filt.state.rate_error_cov
    expected = (cfg.gyro_scale_error * 2.0) ** 2 / 2.0
    np.testing.assert_allclose([extra[18], extra[21], extra[23]], expected, rtol=0.01)


def test_the_option_needs_the_kalman_field_update():
    with pytest.raises(ValueError, match="scale_error_state needs field_update 'kalman'"):
        config(scale_error_state=True, field_update="heading")
