"""The gyro scale error as a Schmidt (consider) state (``FilterConfig.gyro_scale_model`` "consider"): the packed
steps against the full 15-state filter they stand for, and the coherent growth of a one-way turn."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.filter import AttitudeFilter, FilterConfig
from compass.filter._kalman import pack, predict_consider, predict_gyro, unpack, update_axis, update_heading, update_tilt


def _random_cov(seed: int, n: int = 15) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(n, n))
    return a @ a.T / n + 0.1 * np.eye(n)


def _full(p_xx, cross, p_cc) -> np.ndarray:
    return np.block([[p_xx, cross], [cross.T, p_cc]])


def _joseph(p, k, h, var) -> np.ndarray:
    """The full-state update for the gain ``k`` (any gain): ``(I - k h) P (I - k h)^T + k var k^T``."""
    a = np.eye(len(k)) - np.outer(k, h)
    return a @ p @ a.T + var * np.outer(k, k)


def _pad(v) -> np.ndarray:
    """A 6-state row or gain, zero on the nine consider states (``h_c = 0``: no measurement sees ``E``; ``K_c = 0``)."""
    return np.concatenate([np.asarray(v, float), np.zeros(9)])


def _check_x_rows(p_full, new_p, cross, reference):
    np.testing.assert_allclose(unpack(new_p), reference[:6, :6], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(cross, reference[:6, 6:], rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(reference[6:, 6:], p_full[6:, 6:])  # the consider block never changes


@pytest.mark.parametrize("seed", [0, 1])
def test_axis_and_heading_updates_are_the_full_state_updates_x_rows(seed):
    """For a scalar row ``h`` on ``(eps, db)``, the packed update and the cross block equal the x-rows of the full
    state's Joseph update with the consider states' gain zero, whatever the gain (the heading's is not Kalman's)."""
    p_full = _random_cov(seed)
    var, z = 0.3, 0.7
    cross = p_full[:6, 6:].copy()
    x = [0.0] * 6
    new = update_axis(pack(p_full[:6, :6]), x, 2, z, var, cross)
    k = np.array(x) / z  # x started at zero: it moved by K times the innovation
    _check_x_rows(p_full, new, cross, _joseph(p_full, _pad(k), _pad(np.eye(6)[2]), var))

    up, tilt = (0.2, -0.3, 0.933), (0.4, -0.2)
    cross = p_full[:6, 6:].copy()
    x = [0.0] * 6
    new = update_heading(pack(p_full[:6, :6]), x, z, var, up, tilt, cross)
    k = np.array(x) / z
    _check_x_rows(p_full, new, cross, _joseph(p_full, _pad(k), _pad([*tilt, 1.0, 0, 0, 0]), var))


@pytest.mark.parametrize("hold", [False, True])
def test_tilt_rows_are_the_full_state_updates_x_rows(hold):
    """The two tilt rows one after the other, the bias held (a second consider block) or not."""
    p_full = _random_cov(2)
    w, v, var = (0.1, -0.2, 0.05), (0.03, 0.2, -0.1), 0.2
    cross = p_full[:6, 6:].copy()
    new = update_tilt(pack(p_full[:6, :6]), [0.0] * 6, w, 0.3, v, -0.1, var, hold, cross)
    ref = p_full
    for h in ([0, -1, 0, *w], [1, 0, 0, *v]):
        h = _pad(h)
        k = ref @ h / (h @ ref @ h + var)
        k[6:] = 0.0
        if hold:
            k[3:6] = 0.0
        ref = _joseph(ref, k, h, var)
    _check_x_rows(p_full, new, cross, ref)


def test_propagation_is_the_full_state_propagation():
    """``F P F^T + Q`` of the 15 states, ``F = [[I, -R dt, -R W dt], [0, I, 0], [0, 0, I]]`` with ``E w = W vec E``."""
    p_full = _random_cov(3)
    p_full[6:, 6:] = np.diag(np.random.default_rng(4).uniform(1e-5, 1e-4, 9))
    r = Rotation.from_rotvec([0.3, -0.5, 1.1]).as_matrix()
    w, dt, q_att, q_bias = (0.7, -1.2, 2.1), 0.01, 1e-6, 1e-8
    f = np.eye(15)
    f[:3, 3:6] = -r * dt
    f[:3, 6:] = -r @ np.kron(np.eye(3), np.reshape(w, (1, 3))) * dt
    reference = f @ p_full @ f.T + np.diag([q_att] * 3 + [q_bias] * 3 + [0.0] * 9)
    cross = p_full[:6, 6:].copy()
    new = predict_gyro(pack(p_full[:6, :6]), tuple(r.ravel()), dt, q_att, q_bias)
    new = predict_consider(new, cross, tuple(r.ravel()), w, dt, np.diag(p_full[6:, 6:]))
    _check_x_rows(p_full, new, cross, reference)


def _spin(p, cross, var_c, rate, seconds, dt, r):
    """Propagate a constant turn at ``rate`` (rad/s) about the housing's z, level, no other noise."""
    for _ in range(round(seconds / dt)):
        r = r @ Rotation.from_rotvec([0.0, 0.0, rate * dt]).as_matrix()
        p = predict_gyro(p, tuple(r.ravel()), dt, 0.0, 0.0)
        p = predict_consider(p, cross, tuple(r.ravel()), (0.0, 0.0, rate), dt, var_c)
    return p, r


def test_a_spin_one_way_grows_the_heading_as_the_angle_and_back_cancels():
    """``E`` with the z scale factor of variance ``s^2``: after a turn of ``theta`` about the vertical the heading's
    variance is ``s^2 theta^2`` (coherent, not the random walk's ``theta``); turning back by the same angle returns
    the attitude's covariance to the start (zero), the tilt's share from ``E_xz, E_yz`` included."""
    s, rate, dt = 0.03, 1.5, 0.01
    var_c = np.full(9, 0.005**2)
    var_c[[0, 4, 8]] = s**2
    p0, cross = pack(np.zeros((6, 6))), np.zeros((6, 9))
    p, r = _spin(p0, cross, var_c, rate, 4.0, dt, np.eye(3))
    theta = rate * 4.0
    assert unpack(p)[2, 2] == pytest.approx(s**2 * theta**2, rel=1e-9)
    assert unpack(p)[0, 0] > 0.0  # the cross-axis entries tilt it while it turns
    p, _ = _spin(p, cross, var_c, -rate, 4.0, dt, r)
    assert unpack(p)[2, 2] == pytest.approx(0.0, abs=1e-12 * s**2 * theta**2)
    # the tilt: the way back's steps sample the turn one step off the way out's (the attitude after each step), so
    # one step's worth of the cross-axis entries' turn is left, (0.005 rate dt)^2 in variance; without the return it
    # would be of order (0.005 theta)^2
    step = (0.005 * rate * dt) ** 2
    np.testing.assert_allclose(unpack(p)[:3, :3], 0.0, atol=2.0 * step)
    np.testing.assert_allclose(cross[:3], 0.0, atol=2.0 * 0.005**2 * rate * dt)


def _run(model: str, seconds: float = 10.0):
    """A level board turning at 1 rad/s about the vertical with its gyro 3 % high, field and gravity every sample."""
    cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.3, gyro_scale_error=0.03, gyro_scale_model=model)
    f = AttitudeFilter(cfg, gyro=True)
    dt, field_w = 0.01, np.array([50 * np.cos(np.radians(60)), 0.0, -50 * np.sin(np.radians(60))])
    heading_var = []
    for k in range(round(seconds / dt)):
        r = Rotation.from_rotvec([0.0, 0.0, k * dt])
        f.update(k * dt, r.inv().apply([0.0, 0.0, 9.81]), (0.0, 0.0, 1.03), r.inv().apply(field_w))
        heading_var.append(f.state.covariance_matrix[2, 2])
    return f, np.array(heading_var)


def test_the_filter_carries_the_consider_block_and_the_default_none():
    f, _ = _run("consider", 2.0)
    assert f.state.cross.shape == (6, 9) and np.all(np.isfinite(f.state.cross))
    assert np.any(f.state.cross[2] != 0.0)
    g, _ = _run("noise", 2.0)
    assert g.state.cross is None


def test_an_unknown_scale_model_is_refused():
    cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.3, gyro_scale_model="schmidt")
    with pytest.raises(ValueError, match="gyro_scale_model must be one of noise, consider"):
        AttitudeFilter(cfg, gyro=True)
