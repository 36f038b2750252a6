"""The gyro filter's rest-bias update takes a reading only once the rest is confirmed after it
(``FilterConfig.rest_confirm_s``, issue 22: simulated tapping's heading)."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.filter import FilterConfig, run_filter
from compass.frames import world_field

RATE_HZ = 285.714  # BROAD's and compass.sim.motion's
GYRO_NOISE = 3e-4  # rad/s/sqrt(Hz), FilterConfig's default
BIAS = np.array([0.004, -0.003, 0.006])  # rad/s
REST_S = 6.0  # still, then a turn about the vertical ramps in over 1 s to 4 deg/s
PEAK = math.radians(4.0)


def onset_recording(seed: int):
    """A still housing, then the onset of a slow turn about the world vertical (a raised cosine), with a
    constant gyro bias and white gyro noise; the accelerometer and field exact."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, REST_S + 3.0, 1.0 / RATE_HZ)
    ramp = np.clip(t - REST_S, 0.0, 1.0)
    rate_z = PEAK * (0.5 - 0.5 * np.cos(np.pi * ramp))
    heading = np.concatenate([[0.0], np.cumsum(rate_z[1:]) / RATE_HZ])
    tilt = Rotation.from_euler("XY", [8.0, -5.0], degrees=True)
    rotation = Rotation.from_euler("z", heading[:, None]) * tilt  # R_world<-housing: turned about the world vertical
    rate_h = tilt.inv().apply(np.column_stack([np.zeros_like(t), np.zeros_like(t), rate_z]))
    gyro = rate_h + BIAS + GYRO_NOISE * math.sqrt(RATE_HZ) * rng.normal(size=(len(t), 3))
    accel = rotation.apply(np.tile([0.0, 0.0, 9.81], (len(t), 1)), inverse=True)
    field = rotation.apply(np.tile(world_field(65.0, 48.0), (len(t), 1)), inverse=True)
    return t, accel, gyro, field, rate_z


def bias_error_after_onset(confirm_s: float, seed: int) -> tuple[float, float]:
    """|bias error| (rad/s) at the first sample whose true rate exceeds 2 deg/s (the rest detector has let go
    by then) and at the last still sample (the rest's own estimate)."""
    t, accel, gyro, field, rate_z = onset_recording(seed)
    # the rest as any rest after motion: from the detector's 1.5 s (the start's own counts from its first reading)
    config = FilterConfig(field_norm=48.0, dip_deg=65.0, mag_noise=0.05, rest_confirm_s=confirm_s, start_rest_bias=False)
    track = run_filter(t, accel, gyro, field, config)
    moving = int(np.argmax(rate_z > math.radians(2.0)))
    still = int(np.argmax(rate_z > 0.0)) - 1
    return (float(np.linalg.norm(track.gyro_bias[moving] - BIAS)),
            float(np.linalg.norm(track.gyro_bias[still] - BIAS)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_onset_of_a_slow_turn_is_not_taken_for_the_bias(seed):
    # the rest's estimate: the mean of about 3.5 s of readings (the start window and the detector's 1.5 s taken
    # from the 6 s), sigma GYRO_NOISE / sqrt(3.5 s) per axis; twice its norm's RMS (1 % of draws beyond)
    bound = 2.0 * math.sqrt(3.0) * GYRO_NOISE / math.sqrt(3.5)
    confirmed, confirmed_at_rest = bias_error_after_onset(1.0, seed)
    unconfirmed, unconfirmed_at_rest = bias_error_after_onset(0.0, seed)
    assert confirmed_at_rest < bound and unconfirmed_at_rest < bound
    assert confirmed < bound  # the onset left the bias where the rest put it
    # without the confirmation the onset's first tenths of a deg/s pass for bias, beyond the rest's 3 sigma
    assert unconfirmed > bound


@pytest.mark.parametrize("value", [-0.5, math.nan])
def test_rest_confirm_validated(value):
    with pytest.raises(ValueError, match="rest_confirm_s"):
        FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, rest_confirm_s=value)


START_REST_S = 3.0  # the simulated trials' start rest (compass.sim.motion)


def reference_bias_sigma(first_s: float, confirm_s: float = 1.0, min_s: float = 1.5) -> float:
    """The bias sigma (rad/s, per axis) of a scalar Kalman filter counting, from the prior
    ``FilterConfig.gyro_bias_sigma0`` under the bias walk, each rest reading from ``first_s`` of rest on once the
    rest has held ``confirm_s`` beyond it and ``min_s`` in all (the rest detector's), over ``START_REST_S``."""
    from compass.filter._records import _REST_RATE_SIGMA

    dt = 1.0 / RATE_HZ
    config = FilterConfig(field_norm=48.0, dip_deg=65.0, mag_noise=0.05)
    var_reading = GYRO_NOISE**2 / dt + _REST_RATE_SIGMA**2
    p, counted = config.gyro_bias_sigma0**2, first_s
    for k in range(1, int(START_REST_S * RATE_HZ)):
        p += config.gyro_bias_walk**2 * dt
        rest_s = k * dt
        while rest_s >= min_s and counted <= rest_s - confirm_s:
            p = p * var_reading / (p + var_reading)
            counted += dt
    return math.sqrt(p)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("start_rest_bias", [True, False])
def test_the_start_rest_measures_the_bias_from_its_first_reading(seed, start_rest_bias):
    from compass.filter import AttitudeFilter

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, START_REST_S, 1.0 / RATE_HZ)
    tilt = Rotation.from_euler("XY", [8.0, -5.0], degrees=True)
    gyro = BIAS + GYRO_NOISE * math.sqrt(RATE_HZ) * rng.normal(size=(len(t), 3))
    accel, field = tilt.apply([0.0, 0.0, 9.81], inverse=True), tilt.apply(world_field(65.0, 48.0), inverse=True)
    config = FilterConfig(field_norm=48.0, dip_deg=65.0, mag_noise=0.05, start_rest_bias=start_rest_bias)
    filt = AttitudeFilter(config, gyro=True)
    for i in range(len(t)):
        filt.update(t[i], accel, gyro[i], field)
    sigma = np.sqrt(np.diag(filt.state.covariance_matrix[3:, 3:]))
    # the readings it counts: from the first (the rest the recording starts in), else from the detector's 1.5 s;
    # the tilt and the field teach the bias little in 3 s at rest (a few percent)
    reference = reference_bias_sigma(0.0 if start_rest_bias else 1.5)
    np.testing.assert_allclose(sigma, reference, rtol=0.05)
    assert np.all(np.abs(np.array(filt.gyro_bias) - BIAS) < 3.0 * reference)  # 3 sigma per axis
