"""The gyro-aided fit's gravity rows (:func:`calibrate.tumble.gyro.still_mask`): a robot's moves are not still."""

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.tumble import calibrate_tumble, static_mask
from calibrate.tumble import gyro
from calibrate.tumble.gyro import fit_with_gyro, still_mask
from compass.io.tumble import gyro_turns
from compass.sim.motion import SensorErrors
from compass.sim.robot import simulate_robot

ERRORS = SensorErrors(gyro_bias_rad_s=(0.004, -0.003, 0.005), gyro_scale=(0.005, -0.005, 0.005))


@pytest.fixture(scope="module")
def robot():
    """A simulated robot path (minimum-jerk moves, the board at a lever arm), rows at a sixth of the rate (48 Hz):
    the rows, the gyro's turns between them and each row's true tilt of the specific force from gravity, deg."""
    rec = simulate_robot(5, errors=ERRORS)
    keep = np.zeros(len(rec.t_s), bool)
    keep[::6] = True
    up = rec.rotation[keep].apply([0.0, 0.0, 1.0], inverse=True)
    force = rec.specific_force_m_s2[keep]
    tilt = np.degrees(np.arccos(np.clip(np.sum(force * up, axis=1) / np.linalg.norm(force, axis=1), -1.0, 1.0)))
    return rec.mag_ut[keep], rec.accel_m_s2[keep], gyro_turns(rec.t_s, rec.gyro_rad_s, keep), rec.t_s[keep], tilt


def test_a_robots_moves_pass_the_norm_test_and_not_the_direction_test(robot):
    _, accel, turns, t_s, tilt = robot
    old, new = static_mask(accel), still_mask(accel, turns, t_s)
    assert not np.any(new & ~old)  # the |a| test stays
    tilted = old & (tilt > 3.0)  # a sideways 0.5 m/s^2 or more
    assert np.count_nonzero(tilted) > 100
    assert np.count_nonzero(new & tilted) < 0.2 * np.count_nonzero(tilted)  # 13 of 141 at seed 5
    truly_still = old & (tilt < 0.01)
    assert np.count_nonzero(new & truly_still) > 0.6 * np.count_nonzero(truly_still)  # the dwells' edges go


def _gyro_matrix_z(robot, mask):
    """The fitted gyro matrix's diagonal less the truth, in its stated sigmas, with ``mask`` as the gravity rows."""
    mag, accel, turns, t_s, _ = robot
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate_tumble(mag, accel, t_s=t_s)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(gyro, "still_mask", mask)
        fit = fit_with_gyro(mag, accel, turns, t_s, hard_iron=res.fit.hard_iron, soft_iron=res.fit.soft_iron,
                            field_norm=res.fit.field_norm, mag_to_accel=res.mag_to_accel, noise=res.noise)
    true = 1.0 / (1.0 + np.asarray(ERRORS.gyro_scale))  # the housing's rate is G times the reading
    return (np.diag(fit.gyro_matrix) - true) / np.diag(fit.gyro_matrix_sigma)


def test_the_gyro_scale_on_a_robot_path_is_within_its_sigma(robot):
    z = _gyro_matrix_z(robot, still_mask)
    assert np.all(np.abs(z) < 3.0), z


def test_with_the_norm_test_alone_the_moves_bias_the_gyro_scale(robot):
    """The reference: the moves' tilt read as turns the gyro did not make (seed 5: 4-5 sigmas)."""
    z = _gyro_matrix_z(robot, lambda accel, turns, t_s: static_mask(accel))
    assert np.max(np.abs(z)) > 3.0, z


@pytest.mark.parametrize("rate_deg_s", [0.0, 40.0])
def test_gravity_alone_keeps_its_rows(rate_deg_s):
    """A housing still or turning about its centre (gravity only, 0.05 m/s^2 of noise, a 0.5 deg/s gyro bias):
    the rows kept but about 1 % (the chi-square's quantile) and a few at the ends."""
    rng = np.random.default_rng(3)
    rate_hz, n = 50.0, 3000
    t = np.arange(n) / rate_hz
    omega = np.radians(rate_deg_s) * np.column_stack([np.sin(0.3 * t), np.cos(0.2 * t), np.sin(0.5 * t + 1.0)])
    turns = np.vstack([np.zeros(3), omega[1:] / rate_hz])
    att = [Rotation.from_euler("ZYX", [30.0, 20.0, 10.0], degrees=True)]
    for step in Rotation.from_rotvec(turns[1:]):
        att.append(att[-1] * step)
    accel = Rotation.concatenate(att).apply([0.0, 0.0, 9.81], inverse=True) + rng.normal(scale=0.05, size=(n, 3))
    read = turns + np.radians(0.5) / rate_hz * np.array([1.0, -1.0, 1.0]) / np.sqrt(3.0)
    read[0] = 0.0
    kept = still_mask(accel, read, t)
    assert np.count_nonzero(kept) > 0.95 * np.count_nonzero(static_mask(accel))
