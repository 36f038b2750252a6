"""The inertial low-passes with their leak measured in band (compass/filter/_lowpass.py) against their transfer
functions, and the filter's accel_leak option."""

import numpy as np
import pytest

from compass.filter import AttitudeFilter, FilterConfig
from compass.filter._lowpass import BandLeak, blend_weight, butterworth_coefficients

TAU, RATE, G = 2.0, 100.0, 9.81


def _h1(w):
    return 1.0 / (1.0 + 1j * w * TAU)


def _h2(w):
    s = 1.0 / TAU
    return 2.0 * s * s / ((1j * w) ** 2 + 2.0 * s * (1j * w) + 2.0 * s * s)


def _run(band, force, seconds):
    """Step ``band`` over ``force(t)`` (3-vectors, H) at :data:`RATE`; the outputs and the two leak estimates' x
    components per sample."""
    dt = 1.0 / RATE
    alpha, k2, beta = -np.expm1(-dt / TAU), butterworth_coefficients(dt, TAU), -np.expm1(-dt / 0.5)
    band.restart(tuple(force(0.0)), 0.0)
    out = []
    for k in range(1, int(seconds * RATE)):
        t = k * dt
        direction, age, var = band.step(dt, alpha, k2, beta, tuple(force(t)), G, t)
        out.append((direction, age, var, band.lp1[0], band.q1[0], band.lp2[0], band.q2[0], band.v11, band.v22))
    return out


@pytest.mark.parametrize("first, second", [(True, False), (False, True), (True, True)])
def test_a_constant_tilt_passes_unchanged_with_no_leak(first, second):
    """A still housing, tilted: the direction is the reading's, its leak variance exactly zero, the age tends to tau."""
    up = np.array([0.3, -0.4, 1.0])
    up *= G / np.linalg.norm(up)
    out = _run(BandLeak(first, second), lambda t: up, 40.0)
    direction, age, var = out[-1][:3]
    np.testing.assert_allclose(direction, up, rtol=1e-12)
    assert var == 0.0
    assert age == pytest.approx(TAU, rel=0.01)


@pytest.mark.parametrize("freq_hz", [1.0, 0.3, 0.1])
def test_a_sinusoidal_motion_leaks_by_h_and_is_measured_by_h_times_one_minus_h(freq_hz):
    """Sideways shaking at ``freq_hz``: each low-pass leaks ``|H|`` of it (first order and Butterworth) and its leak
    estimate reads ``|H (1 - H)|`` of it, ``|1 - H|`` times the leak: within 1.3 % of it at 1 Hz for both, half of
    it at 0.1 Hz."""
    amp, w = 0.5, 2.0 * np.pi * freq_hz
    out = np.array([row[3:7] for row in _run(BandLeak(True, True), lambda t: (amp * np.sin(w * t), 0.0, G), 120.0)])
    tail = out[-int(3 * RATE / freq_hz):]
    half_range = (tail.max(axis=0) - tail.min(axis=0)) / 2.0 / amp
    for h, lp, q in ((_h1(w), half_range[0], half_range[1]), (_h2(w), half_range[2], half_range[3])):
        assert lp == pytest.approx(abs(h), rel=0.02)
        assert q == pytest.approx(abs(h * (1.0 - h)), rel=0.02)
        assert q / lp == pytest.approx(abs(1.0 - h), rel=0.01)
    if freq_hz == 1.0:
        np.testing.assert_allclose(half_range[[1, 3]] / half_range[[0, 2]], 1.0, atol=0.013)


def test_the_leak_variances_are_the_measured_leaks_mean_squares():
    """v11 and v22 average ``|q|^2 / g^2`` (plus the norm error, zero to second order for sideways motion): over
    whole periods, a sinusoid's ``(|H (1 - H)| amp)^2 / 2 / g^2``."""
    amp, w = 0.5, 2.0 * np.pi * 0.5
    out = _run(BandLeak(True, True), lambda t: (amp * np.sin(w * t), 0.0, G), 60.0)
    v = np.mean([row[7:] for row in out[-int(10 * RATE):]], axis=0)
    for h, v in ((_h1(w), v[0]), (_h2(w), v[1])):
        assert v == pytest.approx((abs(h * (1.0 - h)) * amp) ** 2 / 2.0 / G**2, rel=0.1)


def test_the_blend_weight_is_the_least_variance_one():
    """blend_weight against a grid search of ``w^2 v11 + (1 - w)^2 v22 + 2 w (1 - w) v12``, clipped to [0, 1];
    two indistinguishable estimates give the first one."""
    rng = np.random.default_rng(3)
    grid = np.linspace(0.0, 1.0, 100001)
    for _ in range(20):
        a, b = rng.normal(size=(2, 4))
        v11, v22, v12 = a @ a, b @ b, a @ b
        best = grid[np.argmin(grid**2 * v11 + (1 - grid) ** 2 * v22 + 2 * grid * (1 - grid) * v12)]
        assert blend_weight(v11, v22, v12) == pytest.approx(best, abs=2e-5)
    assert blend_weight(2.0, 2.0, 2.0) == 1.0


@pytest.mark.parametrize("leak, order", [("band", 1), ("band", 2), ("band-blend", 1)])
def test_the_filter_keeps_a_still_tilt_with_the_leak_measured(leak, order):
    """The filter with ``accel_leak`` band or band-blend on a still, tilted housing: the low-pass is the reading, the
    motion residual zero, the attitude's up the reading's direction."""
    cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, accel_leak=leak, accel_lowpass_order=order)
    f = AttitudeFilter(cfg, gyro=True)
    up = np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0])
    for k in range(int(10 * RATE)):
        f.update(k / RATE, G * up, [0.0, 0.0, 0.0], [25.0, 0.0, -43.3])
    np.testing.assert_allclose(np.array(f.state.acc_lp) / G, up, atol=1e-12)
    assert f.state.residual_var == 0.0
    np.testing.assert_allclose(np.reshape(f.matrix, (3, 3))[2], up, atol=1e-6)


def test_accel_leak_validated():
    with pytest.raises(ValueError, match="accel_leak must be one of raw, band, band-blend"):
        FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, accel_leak="both")
