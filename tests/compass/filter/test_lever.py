"""The lever arm of a hand-held turn (``FilterConfig.lever_arm``, :mod:`compass.filter._lever`): fitted from a
rigid turn about a point off the IMU, taken out of the inertial low-pass and out of the motion the tilt's noise
follows, zero for a zero arm, and the offline and per-sample paths agree."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.filter import FilterConfig, FilterStart, run_filter, through_start
from compass.filter._lever import BLOCK_S, MEMORY_S, PRIOR, LeverState, acceleration, add_sample, restart_block

RATE_HZ = 200.0
G = 9.81
ACCEL_NOISE = 0.005 * G  # m/s^2 per sample (FilterConfig's default accel_noise)
GYRO_NOISE = 3e-4  # rad/s/sqrt(Hz) (FilterConfig's default)
FIELD_NWU = np.array([20.0, 0.0, -40.0])  # uT, dip 63 deg
ARM_M = np.array([0.15, 0.03, -0.02])  # the IMU's offset from the turn's centre in H, m


def off_centre_turn(arm=ARM_M, seconds=70.0, seed=1, still_from_s=None):
    """A housing still for 2 s, then turned by hand about a fixed centre ``arm`` (H, m) from the IMU: three
    sinusoidal rates (about 2 rad/s), the attitude stepped as the filter steps it; the sensors with white noise.
    With ``still_from_s`` the rates ramp down to zero over 2 s from then on (the housing held still)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    ramp = np.clip((t - 2.0) / 2.0, 0.0, 1.0)[:, None]
    if still_from_s is not None:
        ramp = ramp * np.clip((still_from_s + 2.0 - t) / 2.0, 0.0, 1.0)[:, None]
    w = ramp * np.stack([1.5 * np.sin(2 * np.pi * 0.31 * t), 1.2 * np.sin(2 * np.pi * 0.43 * t + 1.0),
                         2.0 * np.sin(2 * np.pi * 0.23 * t + 2.0)], axis=1)
    steps = Rotation.from_rotvec(w / RATE_HZ)
    r = [Rotation.identity()]
    for k in range(1, len(t)):
        r.append(r[-1] * steps[k])
    r = Rotation.concatenate(r)
    dw = np.gradient(w, 1.0 / RATE_HZ, axis=0)
    lever = np.cross(dw, arm) + np.cross(w, np.cross(w, arm))  # the IMU's acceleration in H, the centre at rest
    accel = r.inv().apply([0.0, 0.0, G]) + lever + rng.normal(0.0, ACCEL_NOISE, (len(t), 3))
    gyro = w + rng.normal(0.0, GYRO_NOISE * np.sqrt(RATE_HZ), (len(t), 3))
    field = r.inv().apply(FIELD_NWU) + rng.normal(0.0, 0.2, (len(t), 3))
    return t, accel, gyro, field, r


def config(lever_arm=True):
    return FilterConfig(field_norm=float(np.linalg.norm(FIELD_NWU)), dip_deg=63.43, mag_noise=0.2, gravity=G,
                        lever_arm=lever_arm)


def run(t, accel, gyro, field, cfg):
    """FilterStart and the per-sample ``step()`` as ``compass live`` calls them: the filter and its estimates."""
    filt, out = None, [None] * len(t)
    for filt, j in through_start(FilterStart(cfg, None), zip(t, accel, gyro, field)):
        out[j] = filt.step(t[j], accel[j], gyro[j], field[j])
    return filt, out


def inclination_deg(quat, truth: Rotation, rows) -> float:
    e = Rotation.from_quat(quat[rows]) * truth[rows].inv()
    z = e.apply([0.0, 0.0, 1.0])
    return float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(z[:, 2], -1.0, 1.0)) ** 2))))


@pytest.fixture(scope="module")
def turn():
    return off_centre_turn()


def test_the_arm_of_a_rigid_turn_off_the_imu_is_found(turn):
    """The fit's ridge solution ``(info + PRIOR I)^-1 info r`` within what the noise allows: the accelerometer's
    white noise through the fit, and the filter's own tilt error (its reported sigma) as a wrong gravity."""
    t, accel, gyro, field, _ = turn
    filt, out = run(t, accel, gyro, field, config())
    st = filt.state.lever
    i = st.info
    info = np.array([[i[0], i[1], i[2]], [i[1], i[3], i[4]], [i[2], i[4], i[5]]])
    expected = np.linalg.solve(info + PRIOR * np.eye(3), info @ ARM_M)
    smallest = np.linalg.eigvalsh(info)[0]
    white = ACCEL_NOISE / np.sqrt(RATE_HZ * smallest)  # m, 1 sigma per axis
    tilt = G * np.radians(out[-1].tilt_sigma_deg) * np.sqrt(MEMORY_S / smallest)  # a gravity tilted by 1 sigma, m
    assert np.max(np.abs(np.array(st.arm) - expected)) < 5.0 * white + 2.0 * tilt
    assert np.linalg.norm(expected - ARM_M) < 0.2 * np.linalg.norm(ARM_M)  # the turn outweighs the prior


def test_taking_the_arm_out_lowers_the_inclination_error(turn):
    """The first-order low-pass leaves ``(v - LP v) / tau`` of the turn: about ``w |r| / tau`` = 2 x 0.15 / 2 m/s^2,
    1.7 deg; taking it out, the filter's inclination error after the fit has settled is the smaller."""
    t, accel, gyro, field, truth = turn
    rows = t > 30.0
    off = inclination_deg(run_filter(t, accel, gyro, field, config(False)).quat, truth, rows)
    on = inclination_deg(run_filter(t, accel, gyro, field, config()).quat, truth, rows)
    assert on < 0.7 * off


def motion_var(arm, lever_arm: bool) -> float:
    """The tilt's motion variance (``GyroState.residual_var``, dimensionless) averaged after the fit has settled, on
    :func:`off_centre_turn` about ``arm``."""
    t, accel, gyro, field, _ = off_centre_turn(arm=np.asarray(arm))
    out = np.full(len(t), np.nan)
    for filt, j in through_start(FilterStart(config(lever_arm), None), zip(t, accel, gyro, field)):
        filt.step(t[j], accel[j], gyro[j], field[j])
        out[j] = filt.state.residual_var
    return float(np.nanmean(out[t > 30.0]))


def test_the_arm_is_taken_out_of_the_motion_variance():
    """Off the centre, the residual's ``M r`` leaks no more once the measurement is corrected: with the arm modelled
    the motion variance keeps only the fit's error ``M (r - r_fit)`` (within 20 % of ``r``: at most 4 % of the
    variance) and the noise, so under a tenth of the uncorrected one; about the IMU itself (``r`` fitted near 0) the
    two agree."""
    off, on = motion_var(ARM_M, False), motion_var(ARM_M, True)
    assert on < 0.1 * off
    centred_off, centred_on = motion_var((0.0, 0.0, 0.0), False), motion_var((0.0, 0.0, 0.0), True)
    assert centred_on == pytest.approx(centred_off, rel=0.05)
    assert off > 20.0 * centred_off  # the arm is what the uncorrected motion variance reads


def test_the_arms_acceleration_is_m_r():
    """A rate rising linearly: once the rate's change has been low-passed over many ``BLOCK_S``, ``dw/dt x r + w x
    (w x r)``; zero for ``r = 0``; the first sample after a restart has no ``dw/dt``, and the next takes
    ``1 - exp(-dt / BLOCK_S)`` of it."""
    arm, dt = (0.1, -0.05, 0.02), 0.005
    w0, dw = np.array([0.5, -1.0, 2.0]), np.array([3.0, 1.0, -2.0])
    st, zero = LeverState(arm=arm), LeverState()
    assert np.allclose(acceleration(st, dt, tuple(w0)), np.cross(w0, np.cross(w0, arm)), rtol=1e-12, atol=0.0)
    settled = int(20 * BLOCK_S / dt)
    for k in range(1, settled + 1):
        w = w0 + dw * dt * k
        got = acceleration(st, dt, tuple(w))
        assert acceleration(zero, dt, tuple(w)) == (0.0, 0.0, 0.0)
    assert np.allclose(got, np.cross(dw, arm) + np.cross(w, np.cross(w, arm)), rtol=1e-6, atol=1e-9)
    restart_block(st)
    assert np.allclose(acceleration(st, dt, tuple(w)), np.cross(w, np.cross(w, arm)), rtol=1e-12, atol=0.0)
    share = -np.expm1(-dt / BLOCK_S)
    w_next = w + dw * dt
    assert np.allclose(acceleration(st, dt, tuple(w_next)),
                       share * np.cross(dw, arm) + np.cross(w_next, np.cross(w_next, arm)), rtol=1e-9, atol=1e-12)


def test_the_arm_leaves_the_motion_variance_at_rest_as_it_was():
    """Held still after a turn that fitted a 10 cm arm, the tilt's motion variance is what it is without the arm:
    the gyro's white noise differenced sample to sample (``sqrt(2) sigma / dt``, 1.2 rad/s^2, 0.12 m/s^2 through the
    arm) read five to six times that variance; low-passed over ``BLOCK_S`` it is ``dt / BLOCK_S`` of it."""
    t, accel, gyro, field, _ = off_centre_turn(seconds=50.0, still_from_s=30.0)
    variances = {}
    for lever_arm in (False, True):
        out = np.full(len(t), np.nan)
        for filt, j in through_start(FilterStart(config(lever_arm), None), zip(t, accel, gyro, field)):
            filt.step(t[j], accel[j], gyro[j], field[j])
            out[j] = filt.state.residual_var
        variances[lever_arm] = float(np.nanmean(out[t > 40.0]))
    assert variances[True] == pytest.approx(variances[False], rel=0.2)


def test_a_sample_without_the_accelerometer_drops_the_open_block():
    """A block opened at rest, the accelerometer's sample skipped while the rate rose to 3 rad/s about z, then a
    steady turn whose specific force is exactly ``w x (w x r)``: with the block dropped the fit is the ridge solution
    on x (``info r / (info + PRIOR)``) and nothing on y; kept, the rise would be read as an angular acceleration of
    3 rad/s over the block's 0.05 s, ``dw/dt x r`` 6 m/s^2 along y that the specific force does not show."""
    arm, w = np.array([0.1, 0.0, 0.0]), (0.0, 0.0, 3.0)
    y = tuple(np.cross(w, np.cross(w, arm)).tolist())
    st = LeverState()
    add_sample(st, 0.005, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    restart_block(st)  # as GyroFilter.update does on a sample without the accelerometer
    for _ in range(200):
        add_sample(st, 0.005, w, y)
    assert st.info[0] > 50.0  # 1 s of the turn: M's xx is -9, info about 81 s^-3
    assert st.arm[0] == pytest.approx(st.info[0] * arm[0] / (st.info[0] + PRIOR), rel=1e-9)
    assert abs(st.arm[1]) < 1e-12 and abs(st.arm[2]) < 1e-12


def test_run_filter_and_step_agree(turn):
    t, accel, gyro, field, _ = turn
    n = int(20 * RATE_HZ)
    cfg = config()
    track = run_filter(t[:n], accel[:n], gyro[:n], field[:n], cfg)
    _, out = run(t[:n], accel[:n], gyro[:n], field[:n], cfg)
    ok = ~np.isnan(track.quat[:, 0])
    assert np.array_equal(ok, [e is not None for e in out]) and ok[-1]
    stepped = np.array([e.matrix for e, kept in zip(out, ok) if kept])
    assert np.allclose(Rotation.from_quat(track.quat[ok]).as_matrix(), stepped, atol=1e-9)


def test_lever_arm_needs_the_first_order_low_pass():
    with pytest.raises(ValueError, match="lever_arm needs accel_lowpass_order 1"):
        dataclasses.replace(config(), accel_lowpass_order=2)
