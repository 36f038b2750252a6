"""A magnetometer slower than the stream: its reading held on the rows until its next conversion is fused once
(``compass.filter._gyro.GyroFilter._fresh_field``)."""

import numpy as np
import pytest

from scipy.spatial.transform import Rotation

from compass.evaluation import orientation_errors
from compass.filter import AttitudeFilter, FilterConfig, run_filter
from compass.filter._gyro import FIELD_HOLD_S
from compass.frames import world_field
from compass.sim.motion import SensorErrors, simulate_motion

MAG_HZ = 20.0


def held_motion(kind: str, seed: int, mag_hz: float = MAG_HZ):
    """60 s of ``kind`` at 285.7 Hz with the magnetometer converting at ``mag_hz``."""
    errors = SensorErrors(gyro_bias_rad_s=(0.004, -0.003, 0.002), mag_noise_ut=0.7, mag_rate_hz=mag_hz)
    return simulate_motion(kind, seed=seed, errors=errors)


def config() -> FilterConfig:
    return FilterConfig(field_norm=43.0, dip_deg=69.0, mag_noise=0.7)


def repeated(mag: np.ndarray) -> np.ndarray:
    """Rows whose three components equal the row before's, shape (n,)."""
    return np.r_[False, np.all(mag[1:] == mag[:-1], axis=1)]


def test_the_simulated_magnetometer_converts_at_its_own_rate():
    rec = held_motion("slow_rotation", 0)
    new = ~repeated(rec.mag_ut)
    duration = rec.t_s[-1] - rec.t_s[0]
    assert abs(new.sum() - duration * MAG_HZ) <= 1.0
    assert np.allclose(np.diff(rec.t_s[new]), 1.0 / MAG_HZ, atol=1.0 / 285.714)


def stepped(cfg: FilterConfig, t, accel, gyro, field) -> dict:
    """The filter stepped row by row from the first: per row its attitude (9), heading variance, ``mag_used``, gate
    and the time since the last new field reading (its state)."""
    filt = AttitudeFilter(cfg, gyro=True)
    out = {"matrix": [], "heading_var": [], "mag_used": [], "gate": [], "field_step_s": []}
    for row in zip(t, accel, gyro, field):
        filt.update(*row)
        d = filt.diagnostics
        out["matrix"].append(filt.matrix)
        out["heading_var"].append(filt.heading_var)
        out["mag_used"].append(d.mag_used)
        out["gate"].append(d.gate)
        out["field_step_s"].append(filt.state.field_step_s)
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("kind, mag_hz", [("slow_rotation", MAG_HZ), ("breaks", MAG_HZ), ("fast_rotation", 8.0)])
def test_a_held_reading_changes_the_attitude_as_an_absent_one(kind, mag_hz):
    # the held rows given as absent (NaN: skipped by the screen) leave the attitude bit for bit as it is, down to an
    # 8 Hz magnetometer (AK8963's slow mode): no held reading is fused again before its successor
    rec = held_motion(kind, 1, mag_hz)
    held = repeated(rec.mag_ut)
    absent = rec.mag_ut.copy()
    absent[held] = np.nan
    rows = (rec.t_s, rec.accel_m_s2, rec.gyro_rad_s)
    as_held, as_absent = stepped(config(), *rows, rec.mag_ut), stepped(config(), *rows, absent)
    np.testing.assert_array_equal(as_held["matrix"], as_absent["matrix"])
    np.testing.assert_array_equal(as_held["heading_var"], as_absent["heading_var"])
    # a held row keeps the verdict of the reading it repeats; an absent one has none
    rows = np.flatnonzero(held)
    assert len(rows) > 0.9 * (1.0 - mag_hz / 285.714) * len(held)
    np.testing.assert_array_equal(as_held["mag_used"][rows], as_held["mag_used"][rows - 1])
    np.testing.assert_array_equal(as_held["gate"][rows], as_held["gate"][rows - 1])
    assert as_held["mag_used"].mean() > 0.5
    assert np.all(as_absent["gate"][rows] == "absent")


def heading_rms_deg(rec, field) -> float:
    """The filter's heading RMS against the truth over the rows with an attitude, deg."""
    track = run_filter(rec.t_s, rec.accel_m_s2, rec.gyro_rad_s, field, config(), reference="config")
    ok = np.all(np.isfinite(track.quat), axis=1)
    heading, _, _ = orientation_errors(Rotation.from_quat(track.quat[ok]), rec.rotation[ok])
    return float(np.sqrt(np.mean(heading**2)))


@pytest.mark.parametrize("kind", ["slow_rotation", "fast_rotation"])
def test_fusing_each_reading_once_is_closer_to_the_truth_than_fusing_it_on_every_row(kind):
    # what the hold is for: a reading fused on each of its 14 rows counts its noise (2.6 deg of azimuth a reading
    # here) as 14 independent ones; the held rows made new by a 1e-9 uT step are fused as before the hold
    rec = held_motion(kind, 2)
    every_row = rec.mag_ut.copy()
    held = repeated(every_row)
    every_row[held] += 1e-9 * np.arange(1, held.sum() + 1)[:, None]
    once, again = heading_rms_deg(rec, rec.mag_ut), heading_rms_deg(rec, every_row)
    assert once < 0.6 * again, (once, again)


def test_a_field_constant_for_longer_than_the_hold_is_fused_again_once_per_hold():
    # still and noise-free: every row reads the same field; it is taken as new at the start, then once per
    # FIELD_HOLD_S (its state's time since the last new reading restarts there)
    rate = 200.0
    t = np.arange(0.0, 5.5, 1.0 / rate)
    n = len(t)
    accel = np.tile([0.0, 0.0, 9.81], (n, 1))
    field = np.tile(world_field(69.0, 43.0), (n, 1))
    out = stepped(FilterConfig(field_norm=43.0, dip_deg=69.0, mag_noise=0.7), t, accel, np.zeros((n, 3)), field)
    new = np.flatnonzero(out["field_step_s"] == 0.0)
    gaps = np.diff(t[new])
    assert new[0] == 0 and len(new) >= 0.95 * t[-1] / FIELD_HOLD_S
    assert np.all(gaps >= FIELD_HOLD_S - 1e-9) and np.all(gaps <= FIELD_HOLD_S + 1.5 / rate)
    assert np.all(out["mag_used"])
