"""A gyro axis held at its rail: the turn it hid as attitude noise (``compass.filter._rail``, issue 22)."""

import math
import numpy as np
import pytest

from compass.evaluation import orientation_errors
from compass.filter import AttitudeFilter, FilterConfig, run_filter
from compass.filter import _gyro
from compass.filter._rail import RAIL_EXCESS, RAIL_WAIT_S, RailState, rail_variances
from compass.sample_check import RAIL_MIN_RAD_S, RAIL_SAMPLES
from compass.sim.device import default_model, simulate_device
from scipy.spatial.transform import Rotation

RAIL = math.radians(250.0)  # rad/s, a low-cost gyro's smallest full scale
DT = 0.01  # s


def reading(x: float, y: float, z: float) -> tuple:
    return x, y, z, x * x + y * y + z * z


def flick(t_s):
    """tools/audit_bad_input.py's: still, rocking, flicked 90 deg in heading in 0.25 s at 10 s (565 deg/s at its
    peak) and back at 20 s; degrees."""
    t = np.asarray(t_s, dtype=float)
    turn = sum(sign * 0.5 * (1.0 - np.cos(np.pi * np.clip((t - t0) / 0.25, 0.0, 1.0)))
               for t0, sign in ((10, 1), (20, -1)))
    return 30.0 + 90.0 * turn, 10.0 * np.sin(2 * np.pi * t / 7), 8.0 * np.sin(2 * np.pi * t / 5), np.zeros(len(t))


@pytest.mark.parametrize("n", [RAIL_SAMPLES, 25, 400])
def test_run_variance_grows_as_the_run_squared(n):
    """Reference relation: a run of ``n`` readings on the rail adds ``(k r n dt)^2`` in all (capped at pi^2), the
    first ``RAIL_SAMPLES`` at once when the rail is learnt; each later sample ``(k r dt)^2 (2 m - 1)``."""
    state, added = RailState(), []
    for _ in range(n):
        added.append(sum(v for _, v in rail_variances(state, reading(0.1, -RAIL, 0.2), DT)))
    expected = min(RAIL_EXCESS * RAIL * n * DT, math.pi) ** 2
    assert sum(added) == pytest.approx(expected, rel=1e-12)
    assert not any(added[:RAIL_SAMPLES - 1])
    assert added[RAIL_SAMPLES - 1] == pytest.approx((RAIL_EXCESS * RAIL * RAIL_SAMPLES * DT) ** 2, rel=1e-12)
    if n == 25:
        m = RAIL_SAMPLES + 1
        assert added[m - 1] == pytest.approx((RAIL_EXCESS * RAIL * DT) ** 2 * (2 * m - 1), rel=1e-12)


def test_learnt_rail_counts_from_the_first_sample():
    """Once learnt, a later run on the rail (either sign, one count apart) is counted from its first reading, at
    the learnt rail."""
    state = RailState()
    for _ in range(RAIL_SAMPLES):
        rail_variances(state, reading(0.0, 0.0, RAIL), DT)
    rail_variances(state, reading(0.0, 0.0, 0.3), DT)  # off the rail, below RAIL_MIN_RAD_S: the run ends
    other = -RAIL * (1.0 + 1.0 / 32768.0)  # the negative rail of a 16-bit part: one count more
    assert rail_variances(state, reading(0.0, 0.0, other), DT) == [(2, pytest.approx((RAIL_EXCESS * RAIL * DT) ** 2))]


@pytest.mark.parametrize("rate", [RAIL_MIN_RAD_S + 0.5, 1.0])
def test_chance_repeat_does_not_inflate(rate):
    """A turning gyro repeating a reading by chance (fewer than RAIL_SAMPLES in a row, or below RAIL_MIN_RAD_S at
    any length) adds nothing and learns no rail."""
    state = RailState()
    repeats = RAIL_SAMPLES - 1 if rate >= RAIL_MIN_RAD_S else 5 * RAIL_SAMPLES
    out = [rail_variances(state, reading(rate, 0.5, -0.2), DT) for _ in range(repeats)]
    out += [rail_variances(state, reading(rate + 0.001, 0.5, -0.2), DT)]
    assert not any(out)
    assert all(math.isnan(r) for r in state.rail_rad_s)


def _filter_on_rail(jitter: float) -> AttitudeFilter:
    """A filter started level, then fed only the gyro: 30 readings whose z holds the rail (``jitter`` 0) or wobbles
    by +-``jitter`` (never a repeat)."""
    f = AttitudeFilter(FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1), gyro=True)
    f.update(0.0, [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [25.0, 0.0, -43.3])
    for k in range(1, 31):
        f.update(k * DT, None, [0.0, 0.0, RAIL + jitter * (-1) ** k], None)
    return f


def test_filter_covariance_grows_on_each_world_axis():
    """In the filter: against the same readings that never repeat, each world axis's variance is larger by the run's
    ``(k r T)^2`` (the prediction is linear in P: no measurement here)."""
    on, off = _filter_on_rail(0.0), _filter_on_rail(1e-9)
    expected = (RAIL_EXCESS * RAIL * 30 * DT) ** 2
    for i in range(3):
        assert on.state.covariance_matrix[i, i] - off.state.covariance_matrix[i, i] == pytest.approx(expected, rel=1e-6)


@pytest.fixture(scope="module")
def flicked():
    model = default_model()
    t = np.arange(0.0, 30.0, 0.01)
    s = simulate_device(model, t, motion=flick, seed=3, gyro_bias=[0.004, -0.003, 0.002])
    return model, s


def test_heading_back_after_a_clipped_flick(flicked):
    """After a 565 deg/s flick read by a gyro clipped at 250 deg/s (35 deg of heading lost; the filter before this
    change still 32 deg off 9 s later), the heading is back within three times the field's heading floor
    (``mag_heading_sigma_deg``, 1 deg: the field's own error; its 0.15 uT noise is 0.3 deg) within 2 s."""
    model, s = flicked
    config = FilterConfig.from_model(model)
    track = run_filter(s.t_s, s.accel, np.clip(s.gyro, -RAIL, RAIL), model.field(s.raw)[0], config)
    heading, _, inclination = orientation_errors(Rotation.from_quat(track.quat), s.rotation)
    tolerance = 3.0 * config.mag_heading_sigma_deg
    for end in (10.25, 20.25):
        later = (s.t_s >= end + 2.0) & (s.t_s < end + 9.0)
        assert np.max(heading[later]) < tolerance
        assert np.max(inclination[later]) < tolerance


def test_nothing_changes_where_nothing_clips(flicked, monkeypatch):
    """Identity: the same flick unclipped (its rates pass RAIL_MIN_RAD_S), with one reading at its peak repeated
    ``RAIL_SAMPLES - 1`` times in a row (a chance repeat one short of a rail), gives the same attitudes, bit for
    bit, as a filter whose rail watch never fires."""
    model, s = flicked
    config = FilterConfig.from_model(model)
    field = model.field(s.raw)[0]
    gyro = s.gyro.copy()
    peak = int(np.argmax(np.abs(gyro[:, 2])))
    gyro[peak:peak + RAIL_SAMPLES - 1] = gyro[peak]
    assert np.abs(gyro[peak, 2]) > RAIL_MIN_RAD_S
    track = run_filter(s.t_s, s.accel, gyro, field, config)
    monkeypatch.setattr(_gyro, "rail_variances", lambda state, w, dt: [])
    silent = run_filter(s.t_s, s.accel, gyro, field, config)
    np.testing.assert_array_equal(track.quat, silent.quat)
    np.testing.assert_array_equal(track.heading_sigma_deg, silent.heading_sigma_deg)


def test_state_round_trip_keeps_the_rail():
    """The learnt rail is part of the state: set into another filter, the next reading is counted alike."""
    f = _filter_on_rail(0.0)
    g = AttitudeFilter(f.config, gyro=True)
    g.state = f.state
    for h in (f, g):
        h.update(0.31, None, [0.0, 0.0, RAIL], None)
    assert f.state.covariance == g.state.covariance
    assert f.state.rail == g.state.rail


def test_field_does_not_wait_without_an_accelerometer(flicked):
    """Without an accelerometer after the flick nothing can bring the tilt back: the field waits at most
    ``RAIL_WAIT_S`` and is then used as without the rail (the heading sigma falls back below 10 deg)."""
    model, s = flicked
    accel = s.accel.copy()
    accel[s.t_s >= 8.0] = np.nan  # the accelerometer gone before the flick
    track = run_filter(s.t_s, accel, np.clip(s.gyro, -RAIL, RAIL), model.field(s.raw)[0],
                       FilterConfig.from_model(model))
    assert np.any(track.gate[(s.t_s >= 10.0) & (s.t_s < 10.25 + RAIL_WAIT_S)] == "rail")
    later = (s.t_s >= 10.25 + RAIL_WAIT_S + 0.5) & (s.t_s < 19.0)
    assert not np.any(track.gate[later] == "rail")
    assert np.mean(track.gate[later] == "ok") > 0.9
    assert np.max(track.heading_sigma_deg[(s.t_s >= 18.0) & (s.t_s < 19.0)]) < 10.0


def test_added_variance_stops_at_an_angle():
    """Runs on the rail without a measurement between them add at most ``pi^2`` to each attitude variance in all
    (beside the same readings never repeating: the propagation's own noise)."""
    on, off = _filter_on_rail(0.0), _filter_on_rail(1e-9)
    for k in range(31, 400):  # 3.7 s more on the rail, off it once a second
        for f, jitter in ((on, 0.0), (off, 1e-9)):
            f.update(k * DT, None, [0.0, 0.0, (RAIL + jitter * (-1) ** k) if k % 100 else 0.5], None)
    p, q = on.state.covariance_matrix, off.state.covariance_matrix
    added = np.diag(p)[:3] - np.diag(q)[:3]
    assert np.all(added <= math.pi**2) and np.all(added > 0.9 * math.pi**2)
    assert np.all(np.linalg.eigvalsh(p) > 0.0)


def test_gyro_matrix_scales_the_hidden_turn():
    """With the gyro's matrix ``G`` the hidden turn is about ``G e_z``: the variance added is ``|G e_z|^2`` times."""
    scale = 1.05
    config = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1,
                          gyro_matrix=((1.0, 0.0, 0.02), (0.0, 1.0, 0.0), (0.0, 0.0, scale)))
    f = AttitudeFilter(config, gyro=True)
    f.update(0.0, [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [25.0, 0.0, -43.3])
    f.update(DT, None, [0.0, 0.0, RAIL], None)
    state = f.state
    for k in range(2, RAIL_SAMPLES + 1):
        f.update(k * DT, None, [0.0, 0.0, RAIL], None)
    g = AttitudeFilter(config, gyro=True)
    g.state = state
    for k in range(2, RAIL_SAMPLES + 1):
        g.update(k * DT, None, [0.0, 0.0, RAIL * (1.0 + 1e-9 * (-1) ** k)], None)  # never a repeat
    added = f.state.covariance_matrix[2, 2] - g.state.covariance_matrix[2, 2]
    expected = (RAIL_EXCESS * RAIL * RAIL_SAMPLES * DT) ** 2 * (0.02**2 + scale**2)  # |G e_z|^2
    assert added == pytest.approx(expected, rel=1e-4)
