"""The plain least-squares fit (calibrate/tumble/ellipsoid.py: plain_fit): Gauss-Newton from a close start,
MINPACK's Levenberg-Marquardt when Gauss-Newton cannot go on; both reach the same optimum."""

import numpy as np
import pytest
from scipy.optimize import leastsq

from calibrate.tumble import ellipsoid
from calibrate.tumble.ellipsoid import fit_covariance, plain_fit, radial_jacobian, radial_residual
from compass.sim.tumble import simulate_tumble


def _problem(seed=31, n=3000):
    sim = simulate_tumble(seed=seed, n=n)
    x = sim.mag
    centre = x.mean(axis=0)
    radius = float(np.median(np.linalg.norm(x - centre, axis=1)))
    return (x - centre) / radius


def _minpack(y, x0):
    x, *_ = leastsq(radial_residual, x0, args=("full", y), Dfun=radial_jacobian, ftol=1e-12, xtol=1e-12,
                    gtol=1e-12, maxfev=2000)
    return x


@pytest.mark.parametrize("seed", [31, 32, 33])
def test_gauss_newton_reaches_minpacks_optimum(seed):
    """From a start tens of standard errors off, within a thousandth of a standard error of MINPACK's optimum."""
    y = _problem(seed)
    best = _minpack(y, np.zeros(9))
    sigma = np.sqrt(np.diag(fit_covariance(plain_fit(radial_residual, best, radial_jacobian, args=("full", y)),
                                           len(y))))
    start = best + 30.0 * sigma * np.random.default_rng(seed).choice([-1.0, 1.0], size=9)
    res = plain_fit(radial_residual, start, radial_jacobian, args=("full", y))
    assert res.success and res.message.startswith("Gauss-Newton converged"), res.message
    assert np.max(np.abs(res.x - best) / sigma) < 1e-3
    np.testing.assert_array_equal(res.fun, radial_residual(res.x, "full", y))  # fun and jac at x
    np.testing.assert_array_equal(res.jac, radial_jacobian(res.x, "full", y))


def test_levenberg_marquardt_takes_over_when_gauss_newton_cannot_go_on(monkeypatch):
    """No Gauss-Newton step allowed: MINPACK from the start (the origin, a unit sphere about the mean) gives its answer."""
    y = _problem()
    best = _minpack(y, np.zeros(9))
    monkeypatch.setattr(ellipsoid, "GAUSS_NEWTON_STEPS", 0)
    res = plain_fit(radial_residual, np.zeros(9), radial_jacobian, args=("full", y))
    assert res.success and not res.message.startswith("Gauss-Newton"), res.message
    np.testing.assert_allclose(res.x, best, atol=1e-7)


def test_a_singular_normal_matrix_hands_over_to_minpack():
    """A parameter the residual does not depend on: J^T J is singular, MINPACK fits the others and keeps it."""
    y = _problem()
    best = _minpack(y, np.zeros(9))

    def residual(p, y):
        return radial_residual(p[:9], "full", y)

    def jacobian(p, y):
        return np.column_stack([radial_jacobian(p[:9], "full", y), np.zeros(len(y))])

    res = plain_fit(residual, np.r_[best + 1e-4, 0.5], jacobian, args=(y,))
    assert res.success and not res.message.startswith("Gauss-Newton"), res.message
    np.testing.assert_allclose(res.x[:9], best, atol=1e-7)
    assert res.x[9] == 0.5


def test_a_degenerate_tumble_leaks_no_numpy_warning():
    """A magnet attached halfway (two spheres, no ellipsoid): trial steps that overflow are rejected quietly
    (the command's stderr stays one line), and the fit is refused as degenerate."""
    import warnings

    from calibrate.tumble.fit import calibrate_tumble

    sim = simulate_tumble(seed=9, n=1500)
    mag = sim.mag.copy()
    mag[750:] += np.array([0.6, -0.5, 0.62]) * 150.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        res = calibrate_tumble(mag, sim.accel)
    assert res.refused and "field changed during the recording" in res.refused


@pytest.mark.parametrize("kind, n_shape", [("offset", 1), ("diagonal", 3), ("full", 6)])
def test_normal_equations_summed_in_chunks_are_the_whole_jacobians(monkeypatch, kind, n_shape):
    """``radial_normal`` (a chunk of rows at a time, no tall Jacobian) against ``J^T J``, ``J^T r`` and ``r^T r`` of
    the whole residual and Jacobian; chunks of 7 rows leave a partial last one."""
    y = _problem(n=1000)
    p = np.concatenate([[0.02, -0.01, 0.03], np.random.default_rng(3).normal(scale=0.1, size=n_shape)])
    monkeypatch.setattr(ellipsoid, "_JACOBIAN_CHUNK_ROWS", 7)
    normal = ellipsoid.radial_normal(p, kind, y)
    r, j = radial_residual(p, kind, y), radial_jacobian(p, kind, y)
    assert normal.rows == len(y)
    np.testing.assert_allclose(normal.chi2, r @ r, rtol=1e-12)
    np.testing.assert_allclose(normal.jtj, j.T @ j, rtol=1e-12, atol=1e-12 * np.max(np.abs(j.T @ j)))
    np.testing.assert_allclose(normal.jtr, j.T @ r, rtol=0, atol=1e-12 * np.sqrt(np.max(np.abs(j.T @ j)) * (r @ r)))


def test_gauss_newton_on_the_normal_equations_reaches_the_same_optimum():
    """With ``normal`` the fit takes the same steps (to rounding) and ends at the same optimum, chi-square and J^T J."""
    y = _problem(seed=32)
    best = _minpack(y, np.zeros(9))
    start = best + 1e-3
    tall = plain_fit(radial_residual, start, radial_jacobian, args=("full", y))
    summed = plain_fit(radial_residual, start, radial_jacobian, args=("full", y), normal=ellipsoid.radial_normal)
    assert summed.message.startswith("Gauss-Newton converged") and summed.nfev == tall.nfev
    assert summed.fun is None and summed.jac is None
    sigma = np.sqrt(np.diag(fit_covariance(tall, len(y))))
    assert np.max(np.abs(summed.x - tall.x) / sigma) < 1e-9
    np.testing.assert_allclose(fit_covariance(summed, len(y)), fit_covariance(tall, len(y)), rtol=1e-9)


def test_a_fit_stopped_at_its_evaluation_limit_is_judged_by_the_step_left(monkeypatch):
    """MINPACK stopped by ``max_nfev``: converged in fact when the next Gauss-Newton step moves it under a tenth of a
    standard error (its numbers are the minimum's to the data's precision), not converged when it still had far to go."""
    y = _problem()
    best = _minpack(y, np.zeros(9))
    sigma = np.sqrt(np.diag(fit_covariance(plain_fit(radial_residual, best, radial_jacobian, args=("full", y)), len(y))))
    monkeypatch.setattr(ellipsoid, "GAUSS_NEWTON_STEPS", 0)  # MINPACK from the start
    near = plain_fit(radial_residual, best + 0.05 * sigma, radial_jacobian, args=("full", y), max_nfev=2)
    far = plain_fit(radial_residual, np.zeros(9), radial_jacobian, args=("full", y), max_nfev=1)
    assert near.success and near.message.startswith("at its minimum, stopped at the evaluation limit"), near.message
    assert np.max(np.abs(near.x - best) / sigma) < 0.1
    assert not far.success and "maxfev" in far.message and "would still move it" in far.message, far.message
    assert np.max(np.abs(far.x - best) / sigma) > 1.0
