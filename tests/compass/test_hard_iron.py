"""The causal hard-iron step tracker on simulated motion with a magnet fixed to the housing."""

import numpy as np
from scipy.spatial.transform import Rotation

from compass.frames import world_field
from compass.hard_iron import track_hard_iron

RATE_HZ = 50.0
DIP_DEG = 60.0
FIELD_UT = 50.0
NOISE_UT = 0.3


def _motion(seed: int, duration_s: float):
    """Housing attitudes turning smoothly through many orientations, and the sensors' readings."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / RATE_HZ)
    rates = np.cumsum(rng.normal(scale=0.1, size=(t.size, 3)), axis=0)
    rates = 2.5 * rates / np.maximum(np.linalg.norm(rates, axis=1, keepdims=True), 1.0)  # rad/s, bounded
    att = [Rotation.identity()]
    for w in rates[1:]:
        att.append(att[-1] * Rotation.from_rotvec(w / RATE_HZ))
    att = Rotation.concatenate(att)
    field_h = att.apply(world_field(DIP_DEG, FIELD_UT), inverse=True)
    accel = att.apply([0.0, 0.0, 1.0], inverse=True)
    return t, field_h + rng.normal(scale=NOISE_UT, size=field_h.shape), accel


def test_a_magnet_attached_partway_is_found_and_its_offset_estimated():
    t, mag, accel = _motion(seed=1, duration_s=90.0)
    magnet = np.array([12.0, -8.0, 5.0])  # uT, fixed in the housing from 30 s on
    attached = t >= 30.0
    mag[attached] += magnet
    track = track_hard_iron(mag, accel, RATE_HZ, dip_deg=DIP_DEG)
    assert track.step_t_s.size >= 1
    first = track.step_t_s[0]
    assert 30.0 <= first <= 30.0 + 20.0  # causal: after the step, within the tracker's window lag
    late = t > first + 10.0
    # offset of a window of hundreds of samples at 0.3 uT noise: well under a microtesla
    np.testing.assert_allclose(track.offset_ut[late].mean(axis=0), magnet, atol=1.0)
    before = t < 29.0
    assert np.all(track.offset_ut[before] == 0.0)  # causal: nothing before the magnet


def test_no_step_without_a_magnet():
    t, mag, accel = _motion(seed=2, duration_s=60.0)
    track = track_hard_iron(mag, accel, RATE_HZ, dip_deg=DIP_DEG)
    assert track.step_t_s.size == 0 and np.all(track.offset_ut == 0.0)
