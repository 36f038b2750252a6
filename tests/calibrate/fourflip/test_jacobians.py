"""The four-flip fit's analytic Jacobians (:mod:`calibrate.fourflip._jacobian`, each effect's
``jacobian``) against scipy's finite differences.

Tolerance: scipy's 3-point differences use the step ``h = eps^(1/3) max(1, |p|)`` (about 6e-6 for
parameters of order one), with truncation error ``h^2 |f'''| / 6`` and rounding error ``eps |f| / h``;
for outputs and third derivatives of order ten at most, both are below 1e-9, so 1e-7 leaves a margin
of a hundred and still catches any wrong term (whose error is of the order of the entries, 0.02-1).
"""

import numpy as np
import pytest
from scipy.optimize._numdiff import approx_derivative

from calibrate.fourflip._mlfit import _Layout, output_jacobian
from calibrate.fourflip.effects import EFFECTS, VARIANTS
from compass.sim.bench import BenchPhysics, BenchSamples, bench_outputs

TOL = 1e-7


def _fourflip_layout(effects):
    """A four-flip session (4 flips x 90 samples, t_s and temp_c) and a fit layout with ``effects``."""
    rng = np.random.default_rng(5)
    flip_index = np.repeat(np.arange(4), 90)
    platform = np.tile(np.arange(0.0, 360.0, 4.0), 4) + rng.uniform(0, 4, size=flip_index.size)
    t_s = np.arange(flip_index.size) * 2.0 + 30.0 * flip_index
    samples = BenchSamples(platform, 90.0 * flip_index, flip_index, t_s, 20.0 + 0.01 * t_s)
    directions = np.eye(3) + rng.normal(scale=0.05, size=(3, 3))
    start = BenchPhysics(directions / np.linalg.norm(directions, axis=1, keepdims=True), rng.normal(size=3),
                         0.02 * (1 + rng.normal(scale=0.05, size=3)), 55.0, 20.0, 50.0)
    layout = _Layout(start, effects, samples, ("a", "b", "c"))
    x = layout.x0() + rng.normal(scale=0.05, size=len(layout.names))  # every parameter away from zero
    return layout, x, samples


def _all_forms():
    return [pytest.param((form,), id=form.label) for forms in VARIANTS.values() for form in forms]


@pytest.mark.parametrize("effects", [pytest.param((), id="base")] + _all_forms() + [pytest.param(
    "stack", id="every effect at once")])
def test_fourflip_jacobian_matches_finite_differences(effects):
    """Each four-flip effect's analytic Jacobian (and the base model's) against central differences of the
    forward model; all effects at once checks that their derivatives compose (the gain drift multiplies
    the response, the log gain scales every drift).  Outputs are of order one: :data:`TOL` as above."""
    if effects == "stack":
        effects = tuple(EFFECTS[name] for name in VARIANTS if name != "offset_drift") + (VARIANTS["offset_drift"][-1],)
    layout, x, samples = _fourflip_layout(effects)
    analytic = output_jacobian(layout, x, samples)
    numeric = approx_derivative(lambda p: bench_outputs(layout.physics(p), samples).ravel(), x, method="3-point")
    assert analytic.shape == (samples.flip_index.size, 3, x.size)
    np.testing.assert_allclose(analytic.reshape(-1, x.size), numeric, atol=TOL, rtol=0)
