"""The gate's lock-out release (``FilterConfig.gate_release``, issue 22): a gyro scale error beyond the filter's
``gyro_scale_error`` drifts the heading coherently past the innovation test; most field samples are then refused,
alternating with acceptances (``gate_timeout_s`` never fires), and the release lets go."""

import numpy as np
from scipy.spatial.transform import Rotation

from compass.filter import FilterConfig, run_filter
from compass.frames import world_field

FIELD_UT, DIP_DEG, RATE_HZ, MAG_NOISE_UT = 50.0, 60.0, 100.0, 0.3
SCALE = 0.05  # the gyro reads 5 % more than the true rate (a low-cost board; the filter allows for 0.5 %)


def _recording(seconds=60.0, seed=0):
    """Turning at 60 deg/s about the vertical, the sense reversed every 8 s (so no gyro bias can take up the scale
    error), with a tilt wobble; exact accelerometer, the field with white noise; the gyro ``1 + SCALE`` times the
    true rate.  The true ``R_world<-H`` of every row."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    yaw_rate = np.radians(60.0) * np.where((t // 8.0) % 2 == 0, 1.0, -1.0)
    omega = np.column_stack([0.3 * np.sin(2 * np.pi * 0.2 * t), 0.3 * np.cos(2 * np.pi * 0.13 * t), yaw_rate])
    truth = [Rotation.identity()]
    for w in omega[1:] / RATE_HZ:
        truth.append(truth[-1] * Rotation.from_rotvec(w))
    truth = Rotation.concatenate(truth)
    accel = truth.apply([0.0, 0.0, 9.81], inverse=True)
    field = truth.apply(world_field(DIP_DEG, FIELD_UT), inverse=True) + rng.normal(0.0, MAG_NOISE_UT, (len(t), 3))
    return t, accel, omega * (1.0 + SCALE), field, truth


def _second_half(release: bool):
    """Innovation refusals (booleans) and |heading error| (deg) over the second half of the run."""
    t, accel, gyro, field, truth = _recording()
    config = FilterConfig(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=MAG_NOISE_UT, gate_release=release)
    track = run_filter(t, accel, gyro, field, config, reference="config")
    est = Rotation.from_quat(track.quat)
    error = np.degrees(est.as_euler("ZYX")[:, 0] - truth.as_euler("ZYX")[:, 0])
    error = (error + 180.0) % 360.0 - 180.0
    half = len(t) // 2
    return track.gate[half:] == "innovation", np.abs(error[half:]), config


def test_the_release_leaves_the_lock_out():
    refused, error, config = _second_half(release=False)
    # the field's own heading noise is mag_noise / (|B| cos dip), under a degree: a 10-degree innovation is >10 of
    # its sigmas, so every refusal is the heading's drift; locked out, most samples are refused and the heading sits
    # beyond the gate's tolerance most of the time
    noise_deg = np.degrees(MAG_NOISE_UT / (FIELD_UT * np.cos(np.radians(DIP_DEG))))
    assert config.heading_tolerance_deg > 10 * noise_deg
    assert refused.mean() > 0.5 and np.median(error) > config.heading_tolerance_deg
    released, error_released, _ = _second_half(release=True)
    # released: the refused fraction stays under the release's one half, the heading within the tolerance mostly
    assert released.mean() < 0.5 and np.median(error_released) < config.heading_tolerance_deg
    assert np.sqrt(np.mean(error_released**2)) < np.sqrt(np.mean(error**2))


def test_no_release_without_a_lock_out():
    """The same motion read by an exact gyro: nothing is refused, and the release changes nothing."""
    from compass.filter._gate import GateState, MagneticGate
    from compass.filter import FilterCoefficients

    t, accel, gyro, field, truth = _recording(seconds=20.0)
    gyro = gyro / (1.0 + SCALE)
    tracks = [run_filter(t, accel, gyro, field, FilterConfig(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=MAG_NOISE_UT,
                                                              gate_release=r), reference="config") for r in (False, True)]
    np.testing.assert_array_equal(tracks[0].quat, tracks[1].quat)
    assert not np.any(tracks[1].gate == "innovation")
    config = FilterConfig(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=MAG_NOISE_UT, gate_release=True)
    gate = MagneticGate(config, FilterCoefficients.from_config(config))
    state = GateState.initial(config, gate.coefficients)
    for k in range(400):  # 4 s of refusals: the leaky fraction passes one half after field_error_time_s ln 2
        assert gate.check(state, k * 0.01, 0.01, FIELD_UT, DIP_DEG, np.radians(20.0), True) == "innovation"
        if k * 0.01 < config.field_error_time_s * np.log(2.0) - 0.02:
            assert not gate.locked_out(state)
    assert gate.locked_out(state) and state.refused_fraction == 0.0  # said once, the count restarts
