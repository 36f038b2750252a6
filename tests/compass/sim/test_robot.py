"""The robot-arm simulator (compass.sim.robot): its truth against its own kinematics, differentiated numerically."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.sim.motion import GRAVITY, SensorErrors
from compass.sim.robot import robot_path, simulate_robot

NOISELESS = SensorErrors(gyro_noise=0.0, accel_noise_m_s2=0.0, mag_noise_ut=0.0)


@pytest.mark.parametrize("seed", [0, 1])
def test_specific_force_is_the_imu_positions_second_derivative_plus_gravity(seed):
    path = robot_path(np.random.default_rng(seed), duration_s=30.0)
    t = np.linspace(0.0, 30.0, 4001)
    h = 1e-4  # s: truncation ~h^2 p''''/12 and the jerk's jump at a move's ends ~h |p'''|, both far below 1e-3
    second = (path.imu_position(t + h) - 2.0 * path.imu_position(t) + path.imu_position(t - h)) / h**2
    specific, accel_world = path.specific_force(t)
    expected = path.attitude(t).apply(second + [0.0, 0.0, GRAVITY], inverse=True)
    np.testing.assert_allclose(specific, expected, atol=1e-3)
    np.testing.assert_allclose(accel_world, second, atol=1e-3)
    assert np.max(np.linalg.norm(accel_world, axis=1)) > 0.5  # the moves do accelerate (not a vacuous check)


def test_lever_arm_is_in_the_specific_force():
    """With the arm gone the specific force changes by alpha x r + w x (w x r): the arm is not lost."""
    path = robot_path(np.random.default_rng(2), duration_s=30.0)
    t = np.linspace(0.0, 30.0, 3001)
    centre = robot_path(np.random.default_rng(2), duration_s=30.0, lever_arm_range_m=(0.0, 0.0))
    np.testing.assert_allclose(path.attitude(t).as_quat(), centre.attitude(t).as_quat(), atol=0.0)
    assert np.max(np.linalg.norm(path.specific_force(t)[0] - centre.specific_force(t)[0], axis=1)) > 0.5


@pytest.mark.parametrize("dwell_range_s", [(0.5, 2.0), (0.0, 0.0)])
def test_noise_free_gyro_integrates_to_the_truth(dwell_range_s):
    """Also with moves back to back (no dwell), where a sample interval spans the end of one and the start of the
    next."""
    rec = simulate_robot(3, duration_s=30.0, errors=NOISELESS, dwell_range_s=dwell_range_s)
    dt = rec.t_s[1] - rec.t_s[0]
    quats = np.empty((len(rec.t_s), 4))
    r = rec.rotation[0]
    quats[0] = r.as_quat()
    for k in range(1, len(rec.t_s)):
        r = r * Rotation.from_rotvec(rec.gyro_rad_s[k] * dt)
        quats[k] = r.as_quat()
    error = (Rotation.from_quat(quats).inv() * rec.rotation).magnitude()
    assert np.max(error) < 1e-9
    assert np.max(np.linalg.norm(rec.gyro_rad_s, axis=1)) > np.radians(60.0)  # large turns about the wrist


def test_dwells_are_still():
    rec = simulate_robot(4, duration_s=30.0, errors=NOISELESS)
    path = robot_path(np.random.default_rng(4), duration_s=30.0)  # simulate_robot draws its path first
    inside = np.any((rec.t_s[:, None] > path.start_s) & (rec.t_s[:, None] < path.start_s + path.duration_s), axis=1)
    dwell = ~inside & ~np.r_[False, inside[:-1]]  # the sample's interval (t_k-1, t_k] outside every move
    assert 0.2 < dwell.mean() < 0.8
    np.testing.assert_allclose(rec.gyro_rad_s[dwell], 0.0, atol=1e-12)
    gravity = rec.rotation[dwell].apply(np.tile([0.0, 0.0, GRAVITY], (dwell.sum(), 1)), inverse=True)
    np.testing.assert_allclose(rec.accel_m_s2[dwell], gravity, atol=1e-12)
    assert not rec.moving[dwell].any() and rec.moving[inside].mean() > 0.95
    np.testing.assert_allclose(np.linalg.norm(rec.mag_ut, axis=1), rec.field_ut, rtol=1e-12)


def test_waypoints_within_reach_and_tilt():
    path = robot_path(np.random.default_rng(5), duration_s=120.0, max_tilt_deg=60.0, reach_m=0.5)
    ends = path.position_m + path.step_m
    assert np.all(np.linalg.norm(np.r_[path.position_m, ends], axis=1) <= 0.5 + 1e-12)
    z = path.rotation.apply([0.0, 0.0, 1.0])
    assert np.all(np.degrees(np.arccos(np.clip(z[:, 2], -1.0, 1.0))) <= 60.0 + 1e-9)
    assert np.all((path.duration_s >= 1.0) & (path.duration_s <= 3.0))
    gaps = path.start_s[1:] - path.start_s[:-1] - path.duration_s[:-1]
    assert np.all((gaps >= 0.5) & (gaps <= 2.0))
    assert 0.05 <= np.linalg.norm(path.lever_arm_m) <= 0.15
