"""The gyro bias at the start (issue 22 item 2): the rest the attitude starts in measures it from its first
reading (``FilterConfig.start_rest_bias``), and the field's heading row does not move it before that rest has
measured it (``FilterConfig.start_field_bias_hold``)."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.filter import AttitudeFilter, FilterConfig, run_filter
from compass.frames import world_field

RATE_HZ = 285.714  # BROAD's and compass.sim.motion's
GYRO_NOISE = 3e-4  # rad/s/sqrt(Hz), FilterConfig's default
BIAS = np.array([0.004, -0.003, 0.006])  # rad/s
DIP_DEG, FIELD_UT = 65.0, 48.0


def recording(seed: int, duration_s: float, turn_rad_s: float = 0.0, tilt=(0.0, 0.0)):
    """A housing at rest (or turning at ``turn_rad_s`` about the world vertical from the first sample), tilted by
    ``tilt`` (deg about X then Y), a constant gyro bias and white gyro noise; the accelerometer and field exact."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / RATE_HZ)
    base = Rotation.from_euler("XY", tilt, degrees=True)
    rotation = Rotation.from_euler("z", (turn_rad_s * t)[:, None]) * base  # R_world<-housing
    rate_h = base.inv().apply([0.0, 0.0, turn_rad_s])
    gyro = rate_h + BIAS + GYRO_NOISE * math.sqrt(RATE_HZ) * rng.normal(size=(len(t), 3))
    accel = rotation.apply(np.tile([0.0, 0.0, 9.81], (len(t), 1)), inverse=True)
    field = rotation.apply(np.tile(world_field(DIP_DEG, FIELD_UT), (len(t), 1)), inverse=True)
    return t, accel, gyro, field


def config(**changes) -> FilterConfig:
    return FilterConfig(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=0.05, **changes)


def bias_variance_after(cfg: FilterConfig, t, accel, gyro, field) -> np.ndarray:
    """The filter's bias variance (rad/s)^2 after the samples, per housing axis (the filter started from the first row)."""
    filt = AttitudeFilter(cfg, gyro=True)
    for row in zip(t, accel, gyro, field):
        filt.update(*row)
    return np.diag(filt.state.covariance_matrix)[3:]


def scalar_recursion(cfg: FilterConfig, t: np.ndarray, counted_from_s: float) -> float:
    """A one-state Kalman filter of one bias component: the prior, the random walk per step, and one direct
    measurement per reading at rest, each taken once the rest has held ``rest_confirm_s`` beyond it and the
    detector its 1.5 s; the readings from ``counted_from_s`` of the rest on (the first sample starts the filter:
    the rest counts from the second)."""
    dt = float(t[1] - t[0])
    var = cfg.gyro_noise**2 / dt + 1e-3**2  # compass.filter._records._REST_RATE_SIGMA: the filter's reading variance
    p, rest = cfg.gyro_bias_sigma0**2, np.cumsum(np.diff(t))
    walk = cfg.gyro_bias_walk**2 * dt
    counted = 0
    for k, now in enumerate(rest):
        p += walk
        if now < 1.5:
            continue
        while counted <= k and rest[counted] <= now - cfg.rest_confirm_s:
            if rest[counted] >= counted_from_s:
                p = p * var / (p + var)
            counted += 1
    return p


@pytest.mark.parametrize("seed", [0, 1])
def test_the_start_rest_measures_the_bias_from_its_first_reading(seed):
    # level and still for 1.99 s: the tilt rows hold the bias for 2 s and the field's heading row moves only the
    # vertical one (z), so the horizontal bias variance is the rest readings' alone
    data = recording(seed, 1.99)
    cfg = config()
    horizontal = bias_variance_after(cfg, *data)[:2]
    expected = scalar_recursion(cfg, data[0], 0.0)
    np.testing.assert_allclose(horizontal, expected, rtol=0.05)
    # the readings of the rest's first 0.99 s: a bias sigma within 20 % of GYRO_NOISE / sqrt(0.99 s)
    assert math.sqrt(expected) < 1.2 * GYRO_NOISE / math.sqrt(0.99)
    # as before issue 22, the rest counted from the detector's 1.5 s: nothing confirmed yet, the prior's sigma
    before = bias_variance_after(config(start_rest_bias=False), *data)[:2]
    np.testing.assert_allclose(before, scalar_recursion(cfg, data[0], 1.5), rtol=0.05)
    assert np.all(before > 0.9 * cfg.gyro_bias_sigma0**2)


def test_the_start_rest_after_its_first_second_is_no_better_for_it():
    # a still start of 4 s: counted in full, 3 s of readings; from 1.5 s, 1.5 s of them (a variance twice as large)
    data = recording(2, 4.0)
    full = bias_variance_after(config(), *data)[:2]
    late = bias_variance_after(config(start_rest_bias=False), *data)[:2]
    assert np.all(late > 1.5 * full)


@pytest.mark.parametrize("hold", [True, False])
def test_the_heading_row_does_not_move_the_bias_before_the_start_rest_measures_it(hold):
    # tilted, still: the true vertical bias turns the heading by 0.3 deg/s, the field sees it; with the hold the
    # bias stays at its start until the rest's first confirmed readings (1.5 s), then the rest measures it
    t, accel, gyro, field = recording(3, 4.0, tilt=(8.0, -5.0))
    track = run_filter(t, accel, gyro, field, config(start_field_bias_hold=hold))  # not the default: measured
    started = np.all(np.isfinite(track.gyro_bias), axis=1)
    early = started & (t < 1.45)
    assert early.sum() > 100
    moved = np.abs(track.gyro_bias[early]).max()
    if hold:
        assert moved == 0.0
    else:
        assert moved > 1e-3  # 0.06 deg/s: the heading row's push
    # by the rest's end both have the rest's estimate: within 4 sigma of the 2 s of readings
    assert np.linalg.norm(track.gyro_bias[-1] - BIAS) < 4.0 * math.sqrt(3.0) * GYRO_NOISE / math.sqrt(2.0)


def test_in_motion_from_the_start_the_heading_row_holds_the_bias_for_the_tilts_hold_only():
    # turning at 20 deg/s from the first sample: no rest; the heading row moves the bias after the tilt's 2 s hold
    t, accel, gyro, field = recording(4, 4.0, turn_rad_s=math.radians(20.0), tilt=(8.0, -5.0))
    cfg = config(start_field_bias_hold=True)
    track = run_filter(t, accel, gyro, field, cfg)
    started = np.all(np.isfinite(track.gyro_bias), axis=1)
    first = track.t_s[np.argmax(started)]
    held = started & (track.t_s < first + cfg.accel_time_constant_s - 0.05)
    free = started & (track.t_s > first + cfg.accel_time_constant_s + 0.5)
    assert np.abs(track.gyro_bias[held]).max() == 0.0
    assert np.abs(track.gyro_bias[free]).max() > 1e-4


def test_without_the_tilts_hold_the_heading_row_is_not_held_in_motion():
    # start_bias_hold off: the tilt's 2 s hold is gone, and with no rest at the start the heading row's hold has
    # nothing to follow, so start_field_bias_hold changes nothing (it held the heading row for 2 s regardless)
    t, accel, gyro, field = recording(4, 4.0, turn_rad_s=math.radians(20.0), tilt=(8.0, -5.0))
    held, free = (run_filter(t, accel, gyro, field, config(start_bias_hold=False, start_field_bias_hold=hold))
                  for hold in (True, False))
    np.testing.assert_array_equal(held.gyro_bias, free.gyro_bias)


@pytest.mark.parametrize("which", ["axis", "heading"])
def test_the_held_bias_update_is_the_joseph_form_of_its_gain(which):
    """update_axis / update_heading with ``hold_bias``: the gain zero on the bias (3-5; update_heading also on
    the tilt), the Joseph covariance of that gain computed here with numpy; the bias's block and values untouched."""
    from compass.filter._kalman import pack, unpack, update_axis, update_heading

    rng = np.random.default_rng(7)
    for _ in range(5):
        a = rng.normal(size=(6, 6))
        p = a @ a.T + 0.1 * np.eye(6)
        x = list(rng.normal(size=6))
        h = np.eye(6)[2]
        gain = p @ h / (h @ p @ h + 0.2)
        gain[3:] = 0.0
        if which == "heading":
            gain[:2] = 0.0
        k = np.eye(6) - np.outer(gain, h)
        expected_p = k @ p @ k.T + 0.2 * np.outer(gain, gain)
        expected_x = np.array(x) + gain * (0.3 - h @ x)
        if which == "axis":
            new = unpack(update_axis(pack(p), x, 2, 0.3, 0.2, hold_bias=True))
        else:
            new = unpack(update_heading(pack(p), x, 0.3, 0.2, (0.0, 0.0, 1.0), hold_bias=True))
        np.testing.assert_allclose(new, expected_p, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(x, expected_x, rtol=1e-12)
        assert np.all(new[3:, 3:] == p[3:, 3:]) and new[2, 2] < p[2, 2]
