import dataclasses

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

from compass.attitude import solve_attitude
from compass.filter import AttitudeFilter, FilterConfig, reference_field, run_filter
from compass.sim.device import MAGNET_FIELD, MAGNET_PERIOD_S, default_model, simulate_device

RATE_HZ = 100.0
ACCEL_NOISE_G = 0.002  # the simulator's default


def wrap(d):
    return np.mod(np.asarray(d) + 180.0, 360.0) - 180.0


def rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


@pytest.fixture(scope="module")
def model():
    return default_model()


@pytest.fixture(scope="module")
def scripted(model):
    """One 40 s pass of the device script and the filters' tracks on it."""
    t = np.arange(0.0, 40.0, 1.0 / RATE_HZ)
    s = simulate_device(model, t, seed=3, gyro_bias=[0.01, -0.02, 0.015])
    field, _ = model.field(s.raw)
    # the simulated field is homogeneous and the calibration exact: no environment heading error
    cfg = dataclasses.replace(FilterConfig.from_model(model), mag_heading_sigma_deg=0.01)
    tracks = {
        "gyro": run_filter(t, s.accel, s.gyro, field, cfg),
        "gyro, no gate": run_filter(t, s.accel, s.gyro, field, dataclasses.replace(cfg, gate=False)),
        "two-vector": run_filter(t, s.accel, None, field, cfg),
    }
    two_vector = solve_attitude(model, s.raw, accel=s.accel, accel_noise_g=ACCEL_NOISE_G)
    return s, tracks, two_vector


def windows(t):
    lo, hi = MAGNET_PERIOD_S
    near_magnet = (t > lo - 0.5) & (t < hi + 0.5)
    return near_magnet, (t > 2.0) & ~near_magnet  # the filters have settled after 2 s


def test_gyro_filter_beats_the_two_vector_solution_against_truth(scripted):
    s, tracks, two_vector = scripted
    _, clean = windows(s.t_s)
    track = tracks["gyro"]
    # the unfiltered solution's own propagated 1-sigma sets the scale
    sigma_tv = float(np.mean(two_vector.heading_sigma_deg[clean]))
    assert rms(wrap(two_vector.heading_deg - s.heading_deg)[clean]) == pytest.approx(sigma_tv, rel=0.3)
    assert rms(wrap(track.heading_deg - s.heading_deg)[clean]) < sigma_tv
    tilt_noise_deg = np.degrees(ACCEL_NOISE_G)
    assert rms((track.pitch_deg - s.pitch_deg)[clean]) < tilt_noise_deg
    assert rms(wrap(track.roll_deg - s.roll_deg)[clean]) < tilt_noise_deg
    assert track.mag_used[clean].mean() > 0.99 and track.accel_used[clean].all()
    # gyro bias learnt: within a few of its own sigmas of the injected one
    np.testing.assert_allclose(track.gyro_bias[-1], [0.01, -0.02, 0.015], atol=2e-3)


def test_two_vector_filter_tracks_the_motion(scripted):
    s, tracks, two_vector = scripted
    _, clean = windows(s.t_s)
    track = tracks["two-vector"]
    assert track.gyro_bias is None
    assert rms(wrap(track.heading_deg - s.heading_deg)[clean]) < rms(wrap(two_vector.heading_deg - s.heading_deg)[clean])
    assert rms((track.pitch_deg - s.pitch_deg)[clean]) < np.degrees(ACCEL_NOISE_G)


def test_magnet_rejected_by_the_gate_and_not_without(scripted, model):
    s, tracks, _ = scripted
    near, _ = windows(s.t_s)
    full = (s.t_s > MAGNET_PERIOD_S[0]) & (s.t_s < MAGNET_PERIOD_S[1])
    # heading error the magnet causes when believed: angle between the horizontal fields
    dip = np.radians(model.dip_deg)
    expected = np.degrees(np.arctan2(MAGNET_FIELD[1], np.cos(dip) + MAGNET_FIELD[0]))
    gated = np.abs(wrap(tracks["gyro"].heading_deg - s.heading_deg))
    ungated = np.abs(wrap(tracks["gyro, no gate"].heading_deg - s.heading_deg))
    assert gated[near].max() < 0.25 * expected
    assert ungated[full].max() > 0.75 * expected
    # without the gate the filter believes the magnet to the end of the period (a homogeneous simulated
    # field earns the field a fast heading gain, so it follows the 0.5 s ramp); with it, the gate state says why
    assert ungated[full][-100:].mean() > 0.75 * expected
    assert (~tracks["gyro"].mag_used[full]).mean() > 0.95
    assert set(tracks["gyro"].gate[full]) <= {"norm", "dip", "innovation"}
    assert tracks["gyro"].field_ratio[full].mean() == pytest.approx(
        np.linalg.norm([np.cos(dip), 0, -np.sin(dip)] + MAGNET_FIELD), rel=0.01)


@pytest.mark.parametrize("gyro", [True, False])
def test_static_heading_noise_three_times_below_the_two_vector_solution(model, gyro):
    t = np.arange(0.0, 30.0, 1.0 / RATE_HZ)
    s = simulate_device(model, t, seed=5, motion=lambda t: (np.full(len(t), 123.0), np.full(len(t), 10.0),
                                                            np.full(len(t), -5.0), np.zeros(len(t))))
    field, _ = model.field(s.raw)
    track = run_filter(t, s.accel, s.gyro if gyro else None, field, FilterConfig.from_model(model))
    settled = t > 5.0
    unfiltered = solve_attitude(model, s.raw, accel=s.accel).heading_deg[settled]
    assert np.std(unfiltered) / np.std(track.heading_deg[settled]) >= 3.0
    assert abs(wrap(np.mean(track.heading_deg[settled]) - 123.0)) < 3 * np.std(unfiltered)


def test_needs_gravity_to_start_and_restarts_after_a_gap():
    cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.15)
    f = AttitudeFilter(cfg, gyro=True)
    b = np.array([25.0, 0.0, -43.30127])
    assert f.step(0.0, None, np.zeros(3), b) is None and not f.initialised
    assert f.step(0.01, [0.0, 0.0, 1.0], np.zeros(3), b).heading_deg == pytest.approx(0.0, abs=1e-6)
    f.step(2.0, [0.0, 0.0, 1.0], np.zeros(3), b)  # right after the start: nothing to tell a gap from, it restarts
    assert any("gap" in e for e in f.drain_events())


def test_long_disturbance_becomes_the_new_reference(model):
    cfg = dataclasses.replace(FilterConfig.from_model(model), gate_timeout_s=5.0)
    t = np.arange(0.0, 12.0, 1.0 / 50.0)
    s = simulate_device(model, t, seed=2, motion=lambda t: (np.full(len(t), 40.0), np.zeros(len(t)), np.zeros(len(t)),
                                                            (t > 2.0).astype(float)))  # a magnet placed for good
    field, _ = model.field(s.raw)
    f = AttitudeFilter(cfg, gyro=True)
    used = [f.step(*row).mag_used for row in zip(t, s.accel, s.gyro, field)]
    used = np.array(used)
    assert not used[(t > 2.5) & (t < 7.0)].any() and used[t > 7.5].all()
    assert any("new reference" in e for e in f.events)


def test_reference_field_from_samples(model):
    s = simulate_device(model, np.arange(0.0, 5.0, 0.01), seed=4)
    field, _ = model.field(s.raw)
    norm, dip = reference_field(s.accel, field)
    assert norm == pytest.approx(model.field_norm, rel=0.01)
    assert dip == pytest.approx(model.dip_deg, abs=0.5)


@pytest.mark.parametrize("change, message", [({"mag_noise": 0.0}, "mag_noise"), ({"dip_deg": 95.0}, "dip_deg"),
                                             ({"gravity": -1.0}, "gravity")])
def test_config_validated(change, message):
    with pytest.raises(ValueError, match=message):
        FilterConfig(**{"field_norm": 50.0, "dip_deg": 60.0, "mag_noise": 0.1, **change})


def test_run_filter_checks_shapes():
    cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1)
    with pytest.raises(ValueError, match="gyro of shape"):
        run_filter(np.zeros(3), np.zeros((3, 3)), np.zeros((2, 3)), np.zeros((3, 3)), cfg)


def test_run_filter_without_an_attitude_gives_nan_rows():
    """No usable accelerometer: no sample initialises the attitude; every row is NaN, none used, all counted."""
    cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1)
    for gyro in (np.zeros((5, 3)), None):
        track = run_filter(np.arange(5.0), np.full((5, 3), np.nan), gyro, np.ones((5, 3)), cfg)
        assert np.all(np.isnan(track.quat)) and np.all(np.isnan(track.heading_sigma_deg))
        assert not track.mag_used.any() and not track.accel_used.any() and list(track.gate) == ["absent"] * 5
        assert track.skipped.as_dict() == {"accel not finite": 5}
        assert (track.gyro_bias is None) == (gyro is None) and (gyro is None or np.all(np.isnan(track.gyro_bias)))


def wandering_rotation(n, sigma_deg, correlation_samples, seed):
    """Rotation vectors (rad), each component a Gauss-Markov sequence of 1-sigma ``sigma_deg``."""
    a = np.exp(-1.0 / correlation_samples)
    white = np.random.default_rng(seed).normal(0.0, np.radians(sigma_deg) * np.sqrt(1.0 - a * a), (n, 3))
    return lfilter([1.0], [1.0, -a], white, axis=0)


def test_field_heading_error_is_measured_from_the_wander_of_the_dip(model):
    # a field whose direction wanders by 1.5 deg per axis (a calibration residue that changes as the
    # housing turns): its dip wanders by 1.5 deg, so its heading error is 1.5 deg / cos(dip)
    t = np.arange(0.0, 120.0, 1.0 / RATE_HZ)  # three passes of the script: the start value is forgotten
    s = simulate_device(model, t, seed=3)
    field, _ = model.field(s.raw)
    phase = t % 40.0
    late = (t > 80.0) & ~((phase > MAGNET_PERIOD_S[0] - 0.5) & (phase < MAGNET_PERIOD_S[1] + 0.5))
    wander = Rotation.from_rotvec(wandering_rotation(len(t), 1.5, RATE_HZ, seed=8))
    expected = 1.5 / np.cos(np.radians(model.dip_deg))
    cfg = dataclasses.replace(FilterConfig.from_model(model), mag_heading_sigma_deg=0.01)  # a floor out of the way

    def measured(h):
        return np.median(run_filter(t, s.accel, s.gyro, h, cfg).field_heading_sigma_deg[late])

    # a variance averaged over ~20 correlation times (20 s reference, 1 s wander) scatters by
    # ~sqrt(2 / 20) ~ 30 %, its square root by ~16 %: twice that
    assert measured(wander.apply(field)) == pytest.approx(expected, rel=0.35)
    # the exact field: the white noise is taken out, only the filter's own small tilt error is left
    assert measured(field) < 0.1 * expected
    # and the configured value is a floor
    assert np.all(run_filter(t, s.accel, s.gyro, field, FilterConfig.from_model(model)).field_heading_sigma_deg[late]
                  >= FilterConfig.from_model(model).mag_heading_sigma_deg - 1e-9)


# ---------------------------------------------------------------- layout, closed forms, bad input

from filterpy.kalman import KalmanFilter  # noqa: E402

from compass.filter import (GateState, GyroFilter, MagneticGate, TwoVectorFilter,  # noqa: E402
                            FilterCoefficients)
from compass.filter._base import heading_pitch_roll_deg  # noqa: E402
from compass.filter._kalman import pack, predict_gyro, unpack, update_axis, update_tilt  # noqa: E402
from compass.frames import heading_pitch_roll  # noqa: E402

BERLIN = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.15)


def random_covariance(rng):
    a = rng.normal(size=(6, 6))
    return a @ a.T + 0.1 * np.eye(6)


def test_closed_form_kalman_steps_equal_filterpy():
    rng = np.random.default_rng(11)
    for _ in range(5):
        p, r, dt = random_covariance(rng), rng.normal(size=(3, 3)), 0.3
        kf = KalmanFilter(dim_x=6, dim_z=1)
        kf.P = p.copy()
        f = np.eye(6)
        f[:3, 3:] = -r * dt
        kf.predict(F=f, Q=np.diag([0.1] * 3 + [0.01] * 3))
        np.testing.assert_allclose(unpack(predict_gyro(pack(p), tuple(r.ravel()), dt, 0.1, 0.01)), kf.P, rtol=1e-12)
        # the two tilt rows h = (0, -1, 0, w) and (1, 0, 0, v), one after the other
        w, v, x = rng.normal(size=3), rng.normal(size=3), list(rng.normal(size=6))
        kf.P, kf.x = p.copy(), np.array(x)[:, None]
        kf.update(0.3, R=0.2, H=np.r_[0.0, -1.0, 0.0, w][None, :])
        kf.update(-0.1, R=0.2, H=np.r_[1.0, 0.0, 0.0, v][None, :])
        new = update_tilt(pack(p), x, tuple(w), 0.3, tuple(v), -0.1, 0.2)
        np.testing.assert_allclose(unpack(new), kf.P, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(x, kf.x[:, 0], rtol=1e-12)
        # a direct measurement of component 4
        y = list(rng.normal(size=6))
        kf.P, kf.x = p.copy(), np.array(y)[:, None]
        kf.update(0.3, R=0.2, H=np.eye(6)[4][None, :])
        np.testing.assert_allclose(unpack(update_axis(pack(p), y, 4, 0.3, 0.2)), kf.P, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(y, kf.x[:, 0], rtol=1e-12)


def test_closed_form_angles_equal_the_vectorised_ones():
    rotations = Rotation.random(200, random_state=4)
    expected = np.column_stack(heading_pitch_roll(rotations))
    got = np.array([heading_pitch_roll_deg(tuple(m.ravel())) for m in rotations.as_matrix()])
    np.testing.assert_allclose(wrap(got - expected), 0.0, atol=1e-9)


def test_attitude_filter_makes_the_two_kinds():
    assert type(AttitudeFilter(BERLIN, gyro=True)) is GyroFilter
    assert type(AttitudeFilter(BERLIN, gyro=False)) is TwoVectorFilter
    assert type(GyroFilter(BERLIN)) is GyroFilter
    with pytest.raises(ValueError, match="gyro=True filter"):
        GyroFilter(BERLIN, gyro=False)


def _samples(model, seconds=6.0, seed=3):
    t = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    s = simulate_device(model, t, seed=seed, gyro_bias=[0.01, -0.02, 0.015])
    return t, s.accel, s.gyro, model.field(s.raw)[0]


@pytest.mark.parametrize("gyro", [True, False])
def test_state_read_set_reset_replays_exactly(model, gyro):
    t, acc, gyr, field = _samples(model)
    f = AttitudeFilter(FilterConfig.from_model(model), gyro=gyro)
    half = len(t) // 2
    for row in zip(t[:half], acc[:half], gyr[:half], field[:half]):
        f.update(*row)
    saved = f.state
    first = [f.step(*row).heading_deg for row in zip(t[half:], acc[half:], gyr[half:], field[half:])]
    f.state = saved
    again = [f.step(*row).heading_deg for row in zip(t[half:], acc[half:], gyr[half:], field[half:])]
    assert first == again
    assert saved.covariance_matrix.shape == (6, 6) and np.allclose(saved.covariance_matrix, saved.covariance_matrix.T)
    f.reset()
    assert not f.initialised and f.skipped.total == 0
    fresh = AttitudeFilter(FilterConfig.from_model(model), gyro=gyro)
    assert [f.update(*r) for r in zip(t[:50], acc[:50], gyr[:50], field[:50])] \
        == [fresh.update(*r) for r in zip(t[:50], acc[:50], gyr[:50], field[:50])]
    assert f.matrix == fresh.matrix
    with pytest.raises(TypeError, match="State"):
        f.state = GateState.initial(BERLIN, FilterCoefficients.from_config(BERLIN))


def test_gate_alone():
    cfg = dataclasses.replace(BERLIN, gate_timeout_s=2.0)
    gate = MagneticGate(cfg, FilterCoefficients.from_config(cfg))
    state = GateState.initial(cfg, gate.coefficients)
    assert gate.check(state, 0.0, 0.01, 0.0, 60.0, 0.0, True) == "absent"
    assert gate.check(state, 0.0, 0.01, 56.0, 60.0, 0.0, True) == "norm"  # 12 % > 10 %
    assert gate.check(state, 0.0, 0.01, 50.0, 71.0, 0.0, True) == "dip"
    assert gate.check(state, 0.0, 0.01, 50.0, 60.0, np.radians(11.0), True) == "innovation"
    assert gate.check(state, 0.0, 0.01, 50.0, 60.0, np.radians(11.0), False) == "ok"  # not settled yet
    # an accepted field moves the reference by dt / tau of the way
    before = state.ref_norm
    gate.check(state, 0.0, 0.2, 54.0, 60.0, 0.0, True)
    assert state.ref_norm - before == pytest.approx(4.0 * -np.expm1(-0.2 / cfg.field_reference_tau_s))
    # a rejection longer than the timeout adopts the field
    reasons = [gate.check(state, t, 0.1, 70.0, 50.0, 0.0, True) for t in np.arange(1.0, 3.5, 0.1)]
    assert reasons[0] == "norm" and MagneticGate.ADOPTED in reasons
    assert state.ref_norm == 70.0 and state.ref_dip_deg == 50.0
    # without the gate every field is used and the reference stays
    free = MagneticGate(dataclasses.replace(cfg, gate=False), gate.coefficients)
    assert free.check(state, 0.0, 0.01, 500.0, 0.0, 3.0, True) == "ok" and state.ref_norm == 70.0


@pytest.mark.parametrize("gyro", [True, False])
@pytest.mark.parametrize("channel, value, reason", [
    ("gyro", 1e300, "gyro out of range"), ("gyro", np.nan, "gyro not finite"),
    ("accel", 1e300, "accel out of range"), ("accel", np.inf, "accel not finite"),
    ("field", 1e300, "field out of range"), ("field", np.nan, "field not finite"),
    ("t_s", np.nan, "t_s not finite")])
def test_a_bad_sample_is_skipped_counted_and_never_disables_a_sensor(model, gyro, channel, value, reason):
    if gyro is False and channel == "gyro":
        pytest.skip("the two-vector filter ignores the gyro")
    t, acc, gyr, field = _samples(model)
    cfg = FilterConfig.from_model(model)
    bad = 300
    columns = {"t_s": t.copy(), "accel": acc.copy(), "gyro": gyr.copy(), "field": field.copy()}
    if channel == "t_s":
        columns["t_s"][bad] = value
    else:
        columns[channel][bad, 0] = value
    f = AttitudeFilter(cfg, gyro=gyro)
    out = [f.step(*row) for row in zip(columns["t_s"], columns["accel"], columns["gyro"] if gyro else [None] * len(t),
                                       columns["field"])]
    assert f.skipped.as_dict() == {reason: 1}
    if channel == "t_s":
        assert out[bad] is None
    else:
        assert out[bad].skipped == reason
        assert not (channel == "accel" and out[bad].accel_used) and not (channel == "field" and out[bad].mag_used)
    later = out[bad + 1:]
    assert all(e.accel_used for e in later[-100:]) and all(e.mag_used for e in later[-100:])
    assert all(e.skipped == "" for e in later)
    # the same as the clean run with that sample's part absent (the gyro: its last rate held)
    ref = AttitudeFilter(cfg, gyro=gyro)
    for i, row in enumerate(zip(t, acc, gyr if gyro else [None] * len(t), field)):
        if i == bad:
            if channel == "t_s":
                continue
            row = tuple(None if name == channel else v for name, v in zip(("t_s", "accel", "gyro", "field"), row))
        ref.update(*row)
    np.testing.assert_allclose(np.reshape(f.matrix, (3, 3)), np.reshape(ref.matrix, (3, 3)), atol=1e-12)
    assert np.isfinite(f.estimate().heading_deg)


def test_gravity_relearnt_after_an_absurd_first_accelerometer_sample(model):
    t, acc, gyr, field = _samples(model)
    acc = acc.copy()
    acc[0] = (0.0, 0.0, 1e10)  # finite, absurd, and the first: taken as gravity at first
    f = AttitudeFilter(FilterConfig.from_model(model), gyro=True)
    for row in zip(t, acc, gyr, field):
        f.update(*row)
    assert f.state.gravity == pytest.approx(1.0, rel=0.01)
    assert any("re-learnt" in e for e in f.events) and f.diagnostics.accel_used


@pytest.mark.parametrize("order", [1, 2])
def test_the_low_pass_starts_afresh_when_gravity_is_relearnt(order):
    """Readings switching from m/s^2 to mg re-learn gravity; the low-pass content is then new, so its mean
    age restarts at 0 and settles at tau, never negative nor far above it (a Butterworth's ramp error
    overshoots by a few per cent); the tilt and bias updates scale with it."""
    tau, rate = 2.0, 100.0
    cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, accel_time_constant_s=tau,
                       accel_lowpass_order=order)
    f = AttitudeFilter(cfg, gyro=True)
    field = np.array([25.0, 0.0, -43.3])
    ages, relearnt_at = [], None
    for k in range(int(80 * rate)):
        accel = [0.0, 0.0, 9.81] if k < 60 * rate else [0.0, 0.0, 1000.0]
        f.update(k / rate, accel, [0.0, 0.0, 0.0], field)
        if relearnt_at is None and any("re-learnt" in e for e in f.events):
            relearnt_at = k
        if relearnt_at is not None:
            ages.append(f.state.acc_lp_age_s)
    assert relearnt_at is not None
    ages = np.array(ages)
    assert ages[0] < 0.05 and ages.min() >= 0.0 and ages.max() <= 1.1 * tau
    assert ages[-1] == pytest.approx(tau, rel=0.02)


@pytest.mark.parametrize("order", [1, 2])
def test_inertial_low_pass_gain_and_mean_age(order):
    """A still housing shaken sideways at 1 Hz: the low-pass keeps its theoretical gain of the shaking
    (first order ``1 / sqrt(1 + (w tau)^2)``, Butterworth ``1 / sqrt(1 + (w / w_c)^4)``, ``w_c = sqrt 2 / tau``)
    and its content's mean age converges to ``tau`` for both."""
    tau, rate, amp, omega = 2.0, 100.0, 0.3, 2.0 * np.pi
    cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, accel_time_constant_s=tau,
                       accel_lowpass_order=order)
    f = AttitudeFilter(cfg, gyro=True)
    field = np.array([25.0, 0.0, -43.3])
    t = np.arange(int(60 * rate)) / rate
    lp = []
    for tk in t:
        f.update(tk, [amp * np.sin(omega * tk), 0.0, 9.81], [0.0, 0.0, 0.0], field)
        lp.append(f.state.acc_lp[0])
    tail = np.array(lp)[-int(10 * rate):]
    gain = (tail.max() - tail.min()) / 2.0 / amp
    expected = 1.0 / np.sqrt(1.0 + (omega * tau) ** 2) if order == 1 else 1.0 / np.sqrt(1.0 + (omega * tau / np.sqrt(2.0)) ** 4)
    assert gain == pytest.approx(expected, rel=0.03)
    assert f.state.acc_lp_age_s == pytest.approx(tau, rel=0.01)


def test_low_pass_order_validated():
    with pytest.raises(ValueError, match="accel_lowpass_order must be 1 or 2"):
        FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, accel_lowpass_order=3)


@pytest.mark.parametrize("up, tilt", [(False, (0.0, 0.0)), (True, (0.0, 0.0)), (True, (1.2, -0.9))])
def test_decoupled_heading_update_is_the_joseph_form_of_its_gain(up, tilt):
    """update_heading: the Schmidt gain (zero on the tilt; with ``up_h`` the bias only along it) for the row
    ``h = (tilt, 1, 0, 0, 0)`` and the Joseph covariance of that gain, computed here with numpy; the considered
    block is left exactly as it was."""
    from compass.filter._kalman import update_heading

    rng = np.random.default_rng(5)
    for _ in range(5):
        p, x = random_covariance(rng), list(rng.normal(size=6))
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        h = np.r_[tilt, 1.0, 0.0, 0.0, 0.0]
        gain = p @ h / (h @ p @ h + 0.2)
        gain[:2] = 0.0
        if up:
            gain[3:] = u * (u @ gain[3:])
        a = np.eye(6) - np.outer(gain, h)
        expected_p = a @ p @ a.T + 0.2 * np.outer(gain, gain)
        expected_x = np.array(x) + gain * (0.3 - h @ x)
        new = unpack(update_heading(pack(p), x, 0.3, 0.2, tuple(u) if up else None, tilt))
        np.testing.assert_allclose(new, expected_p, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(x, expected_x, rtol=1e-12)
        assert np.all(new[:2, :2] == p[:2, :2])  # the tilt's own block is untouched
        assert np.linalg.eigvalsh(new).min() > 0.0
        assert new[2, 2] < p[2, 2]  # the heading did learn


@pytest.mark.parametrize("mode", ["kalman", "no-tilt", "heading", "heading-tilt"])
def test_a_disturbed_field_moves_the_tilt_only_under_the_kalman_update(model, mode):
    """After motion has built the covariance's cross terms, one sample with a field turned 8 deg and 5 % strong
    (the gate off: it is used) against the same sample without a field: the decoupled updates leave the tilt
    (the world's up in H) and the bias across the vertical to 1e-12; the full Kalman gain moves them."""
    t, acc, gyr, field = _samples(model, seconds=8.0)
    cfg = dataclasses.replace(FilterConfig.from_model(model), gate=False, field_update=mode)
    f = AttitudeFilter(cfg, gyro=True)
    for row in zip(t[:-1], acc[:-1], gyr[:-1], field[:-1]):
        f.update(*row)
    assert abs(f.state.covariance_matrix[0, 2]) + abs(f.state.covariance_matrix[1, 2]) > 1e-9  # cross terms exist
    saved = f.state
    disturbed = 1.05 * Rotation.from_rotvec([0.0, np.radians(8.0), 0.0]).apply(field[-1])
    f.update(t[-1], acc[-1], gyr[-1], disturbed)
    assert f.diagnostics.mag_used
    used, used_state = np.reshape(f.matrix, (3, 3)), f.state
    f.state = saved
    f.update(t[-1], acc[-1], gyr[-1], None)
    without, without_state = np.reshape(f.matrix, (3, 3)), f.state
    f.state = saved
    f.update(t[-1], None, gyr[-1], None)
    up = np.reshape(f.matrix, (3, 3))[2]  # the world's up in H where the update ran: propagated, before the tilt update
    tilt_moved = np.abs(used[2] - without[2]).max()
    bias_change = np.subtract(used_state.bias_rad_s, without_state.bias_rad_s)
    across = np.linalg.norm(bias_change - up * (up @ bias_change))
    if mode == "kalman":
        assert tilt_moved > 1e-9 and across > 1e-12
    else:
        assert tilt_moved < 1e-12
        assert np.abs(used[:2] - without[:2]).max() > 1e-6  # the heading did move
        if mode != "no-tilt":
            assert across < 1e-16 and np.linalg.norm(bias_change) > 1e-9  # the vertical component did learn
    p = used_state.covariance_matrix
    assert np.all(p == p.T) and np.linalg.eigvalsh(p).min() > 0.0


def test_field_update_validated():
    with pytest.raises(ValueError, match="field_update must be one of kalman, no-tilt, heading, heading-tilt"):
        FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, field_update="decoupled")


@pytest.mark.parametrize("azimuth", [0.0, 0.7, -2.5])
def test_heading_innovation_moves_with_the_tilt_as_the_heading_tilt_model_says(azimuth):
    """The innovation's Jacobian in the attitude error (finite differences, R_true = Exp(eps) R) is the
    heading-tilt measurement row (tan(dip) cos a, tan(dip) sin a, 1)."""
    from compass.filter._gyro import heading_innovation

    dip = np.radians(60.0)
    world = 50.0 * np.array([np.cos(dip) * np.cos(azimuth), np.cos(dip) * np.sin(azimuth), -np.sin(dip)])
    truth = Rotation.from_euler("ZYX", [30.0, 10.0, -20.0], degrees=True).as_matrix()
    b = truth.T @ world
    step = 1e-6
    row = [heading_innovation(tuple((Rotation.from_rotvec(-step * e).as_matrix() @ truth).ravel()), *b, azimuth) / step
           for e in np.eye(3)]
    np.testing.assert_allclose(row, [np.tan(dip) * np.cos(azimuth), np.tan(dip) * np.sin(azimuth), 1.0], atol=1e-5)


def _residual_var(freq_hz, in_band, amp=2.0, rate=500.0, seconds=8.0):
    """Mean ``residual_var`` over the last 3 s of a still, level housing shaken sideways at ``freq_hz``."""
    cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, residual_in_band=in_band)
    f = AttitudeFilter(cfg, gyro=True)
    field = np.array([25.0, 0.0, -43.3])
    t = np.arange(int(seconds * rate)) / rate
    kept = []
    for k, tk in enumerate(t):
        f.update(tk, [amp * np.sin(2.0 * np.pi * freq_hz * tk), 0.0, 9.81], [0.0, 0.0, 0.0], field)
        if tk > seconds - 3.0 and k % 10 == 0:
            kept.append(f.state.residual_var)
    return float(np.mean(kept)), cfg


@pytest.mark.parametrize("freq_hz", [25.0, 0.5])
def test_the_motion_residual_in_band_drops_a_vibration_and_keeps_the_motion(freq_hz):
    """residual_in_band low-passes the raw motion at motion_time_s / 2 pi before squaring it: the motion residual
    shrinks by that first-order filter's power gain, 1 / (1 + (2 pi f tau_r)^2) (a 25 Hz vibration to under 1 %,
    hand-held motion at 0.5 Hz kept at 94 %)."""
    raw, cfg = _residual_var(freq_hz, False)
    band, _ = _residual_var(freq_hz, True)
    tau_r = cfg.motion_time_s / (2.0 * np.pi)
    expected = 1.0 / (1.0 + (2.0 * np.pi * freq_hz * tau_r) ** 2)
    assert raw > 0.0
    assert band / raw == pytest.approx(expected, rel=0.1)
