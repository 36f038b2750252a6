"""Analytic Jacobians of the calibration fits against scipy's finite differences.

Tolerance: scipy's 3-point differences use the step ``h = eps^(1/3) max(1, |p|)`` (about 6e-6 for
parameters of order one), with truncation error ``h^2 |f'''| / 6`` and rounding error ``eps |f| / h``;
for residuals and third derivatives of order ten at most, both are below 1e-9, so 1e-7 leaves a margin
of a hundred and still catches any wrong term (whose error is of the order of the entries, ~0.1-1).
"""

import numpy as np
import pytest
from scipy.optimize._numdiff import approx_derivative

from calibrate.tumble.ellipsoid import radial_jacobian, radial_residual

TOL = 1e-7


@pytest.mark.parametrize("kind, n_shape", [("offset", 1), ("diagonal", 3), ("full", 6)])
def test_radial_jacobian_matches_finite_differences(kind, n_shape):
    rng = np.random.default_rng(7)
    y = rng.normal(size=(200, 3))
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    y = 1.3 * y + 0.1
    p = np.concatenate([rng.normal(scale=0.1, size=3), rng.normal(scale=0.2, size=n_shape)])
    analytic = radial_jacobian(p, kind, y)
    numeric = approx_derivative(radial_residual, p, method="3-point", args=(kind, y))
    assert analytic.shape == numeric.shape
    np.testing.assert_allclose(analytic, numeric, atol=TOL, rtol=0)
