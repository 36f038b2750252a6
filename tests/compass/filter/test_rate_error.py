"""The gyro's rate error for the current turn (``FilterConfig.gyro_error_var``, ``_gyro.attitude_noise``): reference
relations of ``Q = (sigma_g^2 I + R diag_i(sum_j v_ij w_j^2) tau_s R^T) dt``, the calibration's per-entry variances
through the reader and ``FilterConfig.from_model``, bad values refused."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.filter import DEFAULT_GYRO_SCALE_ERROR, FilterCoefficients, FilterConfig
from compass.filter._gyro import attitude_noise
from tests.compass.filter.test_gyro_scale import SIGMA, G, _doc

DT = 0.01
TAU_S = 1.0  # the scale error's correlation time (FilterCoefficients.scale_var = s^2 * 1 s)


def _q(config, m, w) -> np.ndarray:
    """The attitude noise of one step as a symmetric 3 x 3 array."""
    u = attitude_noise(tuple(np.ravel(m)), *w, DT, FilterCoefficients.from_config(config))
    return np.array([[u[0], u[1], u[2]], [u[1], u[3], u[4]], [u[2], u[4], u[5]]])


def _config(var=None, s=DEFAULT_GYRO_SCALE_ERROR) -> FilterConfig:
    return FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, gyro_scale_error=s,
                        gyro_error_var=None if var is None else tuple(map(tuple, var)))


def _white(config) -> np.ndarray:
    return config.gyro_noise**2 * DT * np.eye(3)


@pytest.mark.parametrize(("w", "axis"), [((0.0, 0.0, 2.0), 2), ((1.5, 0.0, 0.0), 0), ((0.0, -0.7, 0.0), 1)])
def test_a_scale_error_grows_only_the_turns_own_axis(w, axis):
    """``E = s I`` (independent diagonal entries of variance ``s^2``), housing level: a turn about z grows the heading's
    variance alone, by ``s^2 w^2 tau dt``; a turn about x the tilt about x alone; the isotropic model grows all three."""
    s = 0.03
    config = _config(np.diag([s * s] * 3))
    expected = np.zeros((3, 3))
    expected[axis, axis] = s * s * np.dot(w, w) * TAU_S * DT
    np.testing.assert_allclose(_q(config, np.eye(3), w) - _white(config), expected, rtol=1e-12, atol=1e-20)
    isotropic = _config(None, s)
    np.testing.assert_allclose(_q(isotropic, np.eye(3), w) - _white(isotropic),
                               s * s * np.dot(w, w) * TAU_S * DT * np.eye(3), rtol=1e-12)


def test_the_noise_turns_with_the_attitude():
    """``R -> A R`` turns the noise to ``A Q A^T`` (the world frame's), for any entry variances and turn."""
    rng = np.random.default_rng(5)
    for _ in range(5):
        config = _config(rng.uniform(0.0, 1e-3, (3, 3)))
        m, a = Rotation.random(2, random_state=rng).as_matrix()
        w = rng.normal(size=3)
        np.testing.assert_allclose(_q(config, a @ m, w), a @ _q(config, m, w) @ a.T, rtol=1e-10, atol=1e-22)


def test_it_is_the_covariance_of_the_rate_error_turned_to_the_world():
    """Monte Carlo: ``E`` with independent zero-mean entries of the given variances; the sample covariance of
    ``R E w`` (times ``tau dt``) against the closed form, within the sampling error of 4e5 draws (about 0.5 % of the
    largest entry at 2 sigma; 2 % bound)."""
    rng = np.random.default_rng(8)
    var = rng.uniform(0.0, 1e-3, (3, 3))
    config = _config(var)
    m = Rotation.random(random_state=rng).as_matrix()
    w = np.array([0.4, -1.1, 0.8])
    e = rng.normal(size=(400_000, 3, 3)) * np.sqrt(var)
    err = (e @ w) @ m.T
    sample = err.T @ err / len(err) * TAU_S * DT
    closed = _q(config, m, w) - _white(config)
    np.testing.assert_allclose(sample, closed, atol=0.02 * np.max(np.abs(closed)))


def test_equal_entries_give_the_isotropic_noise():
    """Every entry ``s^2`` is exactly the isotropic ``s^2 |w|^2`` about every axis: a board with no fit keeps the noise
    it had (the default's ``None``)."""
    rng = np.random.default_rng(2)
    s = DEFAULT_GYRO_SCALE_ERROR
    for _ in range(5):
        m, w = Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3)
        np.testing.assert_allclose(_q(_config(np.full((3, 3), s * s)), m, w), _q(_config(None, s), m, w),
                                   rtol=1e-12, atol=1e-16 * DT)


def test_from_model_adds_the_default_to_each_entry_the_fit_saw():
    """The per-entry variances are the default's square plus what the fit left of each entry it saw (as read:
    ``(G - I)^2 + sigma^2``; the matrix applied: ``sigma^2``); none without a fit, or with ``--gyro-scale-error``."""
    from compass.calibration import from_dict, gyro_error_variance, gyro_matrix_seen
    from compass.sim.device import default_model

    model = from_dict(_doc()).model
    seen = gyro_matrix_seen(G, SIGMA)
    floor2 = DEFAULT_GYRO_SCALE_ERROR**2
    as_read = floor2 + np.where(seen, (G - np.eye(3)) ** 2 + SIGMA**2, 0.0)
    applied = floor2 + np.where(seen, SIGMA**2, 0.0)
    np.testing.assert_allclose(FilterConfig.from_model(model).gyro_error_var, as_read, rtol=1e-12)
    np.testing.assert_allclose(FilterConfig.from_model(model, gyro_matrix=True).gyro_error_var, applied, rtol=1e-12)
    # the one number is the per-entry variances' sum over 3 (its RMS over rate directions)
    np.testing.assert_allclose(np.sqrt(np.sum(gyro_error_variance(G, SIGMA), axis=(1, 2)) / 3.0),
                               model.gyro_scale_error, rtol=1e-12)
    assert FilterConfig.from_model(model, gyro_scale_error=0.02).gyro_error_var is None
    assert FilterConfig.from_model(default_model()).gyro_error_var is None
    doc = _doc()
    doc["tumble"]["gyro"]["used"] = False
    assert from_dict(doc).model.gyro_error_var is None


def test_a_z_only_error_reaches_the_heading_in_a_yaw_turn_in_full():
    """A board whose z axis alone is 5 % high, level, turning about z: the heading's rate-error variance is the
    default's plus the whole ``0.05^2 w^2`` (the isotropic model gave a third of it, as the RMS over directions),
    and a roll sees the default alone."""
    from compass.calibration import from_dict

    sigma = np.full((3, 3), 1e-3)
    config = FilterConfig.from_model(from_dict(_doc(np.diag([1.0, 1.0, 1.05]), sigma)).model)
    w = 1.2
    yaw = _q(config, np.eye(3), (0.0, 0.0, w)) - _white(config)
    assert yaw[2, 2] == pytest.approx((DEFAULT_GYRO_SCALE_ERROR**2 + 0.05**2 + 1e-6) * w * w * TAU_S * DT, rel=1e-12)
    roll = _q(config, np.eye(3), (w, 0.0, 0.0)) - _white(config)
    np.testing.assert_allclose(np.diag(roll), DEFAULT_GYRO_SCALE_ERROR**2 * w * w * TAU_S * DT, rtol=1e-12)


def test_an_installation_that_turns_the_frame_drops_the_entries():
    from compass.calibration import from_dict
    from compass.installed import installed_model

    base = from_dict(_doc()).model
    assert base.gyro_error_var is not None
    turned = installed_model(base, np.zeros(3), np.eye(3), alignment=Rotation.from_euler("z", 30, degrees=True).as_matrix())
    assert turned.gyro_error_var is None and turned.gyro_scale_error == base.gyro_scale_error
    np.testing.assert_array_equal(installed_model(base, np.zeros(3), np.eye(3)).gyro_error_var, base.gyro_error_var)


@pytest.mark.parametrize("bad", [np.full((3, 3), -1e-4), np.full((3, 3), np.nan), np.zeros((3, 3)), np.zeros((2, 3))])
def test_bad_entry_variances_are_refused(bad):
    with pytest.raises(ValueError, match="FilterConfig.gyro_error_var must be a 3 x 3 matrix"):
        FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, gyro_error_var=tuple(map(tuple, bad)))
    from compass.calibration import from_dict

    if not np.any(bad):  # nothing seen: a model's zeros are fine (the filter then takes the default alone)
        return
    base = from_dict(_doc()).model
    with pytest.raises(ValueError, match="gyro_error_var must be 2 3 x 3 arrays"):
        dataclasses.replace(base, gyro_error_var=(bad, bad))
