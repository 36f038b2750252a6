"""Analytic Jacobians of the calibration fits against scipy's finite differences.

Tolerance: scipy's 3-point differences use the step ``h = eps^(1/3) max(1, |p|)`` (about 6e-6 for
parameters of order one), with truncation error ``h^2 |f'''| / 6`` and rounding error ``eps |f| / h``;
for residuals and third derivatives of order ten at most, both are below 1e-9, so 1e-7 leaves a margin
of a hundred and still catches any wrong term (whose error is of the order of the entries, ~0.1-1).
"""

import numpy as np
import pytest
from scipy.optimize._numdiff import approx_derivative
from scipy.spatial.transform import Rotation

from calibrate.tumble import alignment
from calibrate.tumble.alignment import _JointResidual, _rotation_derivatives
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


@pytest.mark.parametrize("with_rot", [True, False])
@pytest.mark.parametrize("kind, n_shape", [("offset", 1), ("diagonal", 3), ("full", 6)])
def test_joint_alignment_jacobian_matches_finite_differences(kind, n_shape, with_rot):
    """The joint ellipsoid-rotation-dip residual of ``refine_jointly`` (radial and angle rows)."""
    rng = np.random.default_rng(11)
    y = rng.normal(size=(300, 3))
    y = 1.2 * y / np.linalg.norm(y, axis=1, keepdims=True) + 0.05
    a = rng.normal(size=(120, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    q = np.concatenate([rng.normal(scale=0.1, size=3), rng.normal(scale=0.2, size=n_shape),
                        rng.normal(scale=0.05, size=3) if with_rot else [], [1.0]])
    joint = _JointResidual(kind, 3 + n_shape, with_rot, y, y[:120], a, 0.7, 1.3)
    analytic = joint.jacobian(q)
    numeric = approx_derivative(joint.residual, q, method="3-point")
    assert analytic.shape == numeric.shape == (420, q.size)
    np.testing.assert_allclose(analytic, numeric, atol=TOL, rtol=0)


@pytest.mark.parametrize("rotvec", [np.array([0.3, -0.2, 0.5]), np.array([1e-9, 0.0, 0.0]), np.zeros(3)])
def test_rotation_derivatives_match_finite_differences(rotvec):
    """``dR/dv`` of the rotation vector, also at and near the identity (the limit ``[e_i]x``)."""
    numeric = approx_derivative(lambda v: Rotation.from_rotvec(v).as_matrix().ravel(), rotvec, method="3-point")
    analytic = _rotation_derivatives(rotvec).reshape(3, 9).T
    np.testing.assert_allclose(analytic, numeric, atol=TOL, rtol=0)


def test_joint_alignment_jacobian_in_chunks_equals_at_once(monkeypatch):
    """The radial rows computed a chunk at a time (an uneven last chunk) are those computed at once."""
    rng = np.random.default_rng(12)
    y = rng.normal(size=(100, 3))
    a = rng.normal(size=(30, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    q = np.concatenate([rng.normal(scale=0.1, size=9), rng.normal(scale=0.05, size=3), [1.0]])
    joint = _JointResidual("full", 9, True, y, y[:30], a, 0.7, 1.3)
    at_once = joint.jacobian(q)
    monkeypatch.setattr(alignment, "_JACOBIAN_CHUNK_ROWS", 7)
    np.testing.assert_array_equal(joint.jacobian(q), at_once)



# ---- the residual diagnosis's model (calibrate/tumble/diagnosis.py) -------------------------------

def _diagnosis_model():
    """A diagnosis model on a simulated tumble with time and temperature, and its chosen ellipsoid."""
    from calibrate.effects import Basis
    from calibrate.tumble import diagnosis
    from calibrate.tumble.ellipsoid import fit_ellipsoid
    from compass.sim.tumble import simulate_tumble

    sim = simulate_tumble(seed=21, n=1500, temp_swing_c=10.0)
    fit, _, _ = fit_ellipsoid(sim.mag)
    temp_c = sim.temp_c if sim.temp_c is not None else 20.0 + 5.0 * np.sin(sim.t_s / 7.0)
    rows = diagnosis._Rows((sim.mag - fit.centre) / fit.radius, sim.t_s, temp_c)
    return diagnosis._Model(fit, rows, diagnosis._Context(fit.radius, Basis.of(sim.t_s, temp_c)), 0.3), fit


def _forms():
    from calibrate.tumble.diagnosis import TUMBLE_FORMS

    return [form for forms in TUMBLE_FORMS.values() for form in forms]


def _effect_params(form, rng):
    q = rng.normal(scale=0.02, size=form.n_params(3))
    if form.form == "warm-up":
        q[3] = -1.0  # log(tau / session), inside its clip
    return q


@pytest.mark.parametrize("form", _forms(), ids=lambda f: f"{f.name}-{f.form}")
@pytest.mark.parametrize("after_cubic", [False, True])
def test_diagnosis_jacobian_matches_finite_differences(form, after_cubic):
    """The fits' Jacobian (analytic back through the chain of corrections) against 3-point differences, whose
    error is ~1e-9 of the entries' scale (hundreds: the field over the floor): 1e-6 of the largest entry, the
    tolerance the forward-difference fallback also meets (``h |f''| / 2``, ``h = sqrt(eps)``), catches any
    wrong term."""
    from calibrate.tumble.diagnosis import TUMBLE_FORMS

    model, fit = _diagnosis_model()
    rng = np.random.default_rng(22)
    cubic = TUMBLE_FORMS["nonlinear_response"][0]
    effects = ((cubic,) if after_cubic and form is not cubic else ()) + (form,)
    x = np.concatenate([fit.params] + [_effect_params(e, rng) for e in effects])
    numeric = approx_derivative(model.weighted, x, method="3-point", args=(effects,))
    np.testing.assert_allclose(model.jacobian(x, effects), numeric, atol=1e-6 * np.max(np.abs(numeric)), rtol=0)
    plain = approx_derivative(model.weighted, fit.params, method="3-point", args=((),))
    np.testing.assert_allclose(model.jacobian(fit.params, ()), plain, atol=1e-6 * np.max(np.abs(plain)), rtol=0)


@pytest.mark.parametrize("form", _forms(), ids=lambda f: f"{f.name}-{f.form}")
@pytest.mark.parametrize("after_cubic", [False, True])
def test_effect_columns_of_the_score_test_match_finite_differences(form, after_cubic):
    """``_Model.pulled`` (the score test's analytic columns of an effect added last) against 3-point
    differences of the weighted residual, at a non-zero size (where the time constant's column is alive)."""
    from calibrate.diagnosis.evidence import FitRecord
    from calibrate.tumble.diagnosis import TUMBLE_FORMS

    model, fit = _diagnosis_model()
    rng = np.random.default_rng(23)
    cubic = TUMBLE_FORMS["nonlinear_response"][0]
    current = (cubic,) if after_cubic and form is not cubic else ()
    x = np.concatenate([fit.params] + [_effect_params(e, rng) for e in current])
    q = _effect_params(form, rng)
    record = FitRecord(current, x, None, None, None, 0.0, 0, True, "")
    analytic = model.pulled(record, form, q, model.corrected(x, current, model.rows))
    if analytic is None:
        pytest.skip(f"{form.name} ({form.form}) gives no derivatives: its score test differences (tested below)")
    numeric = approx_derivative(lambda p: model.weighted(np.concatenate([x, p]), current + (form,)), q,
                                method="3-point")
    assert analytic.shape == numeric.shape
    np.testing.assert_allclose(analytic, numeric, atol=TOL * np.max(np.abs(numeric)), rtol=0)


def test_diagnosis_jacobian_of_a_form_without_derivatives_is_differenced():
    """A form that gives no derivatives (``pulled`` None) leaves the Jacobian to finite differences, still right."""
    from calibrate.tumble.diagnosis import TUMBLE_FORMS, LinearDrift

    class Opaque(LinearDrift):
        def pulled(self, g, z, q, rows, ctx):
            return None

    model, fit = _diagnosis_model()
    opaque = Opaque("offset_drift", "linear", "a drift without derivatives")
    effects = (TUMBLE_FORMS["nonlinear_response"][0], opaque)
    x = np.concatenate([fit.params, [0.01, -0.02, 0.005], [0.02, 0.01, -0.03]])
    assert model.analytic_jacobian(x, effects, model.rows) is None
    numeric = approx_derivative(model.weighted, x, method="3-point", args=(effects,))
    np.testing.assert_allclose(model.jacobian(x, effects), numeric, atol=1e-6 * np.max(np.abs(numeric)), rtol=0)


@pytest.mark.parametrize("with_rot", [True, False])
def test_joint_normal_equations_are_the_jacobians(with_rot):
    """``_JointResidual.normal`` (the radial rows summed a chunk at a time) against the whole residual and Jacobian."""
    rng = np.random.default_rng(12)
    y = rng.normal(size=(300, 3))
    y = 1.2 * y / np.linalg.norm(y, axis=1, keepdims=True) + 0.05
    a = rng.normal(size=(120, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    q = np.concatenate([rng.normal(scale=0.1, size=3), rng.normal(scale=0.2, size=6),
                        rng.normal(scale=0.05, size=3) if with_rot else [], [1.0]])
    joint = _JointResidual("full", 9, with_rot, y, y[:120], a, 0.7, 1.3)
    r, j = joint.residual(q), joint.jacobian(q)
    normal = joint.normal(q)
    assert normal.rows == len(r)
    np.testing.assert_allclose(normal.chi2, r @ r, rtol=1e-12)
    np.testing.assert_allclose(normal.jtj, j.T @ j, rtol=0, atol=1e-12 * np.max(np.abs(j.T @ j)))
    np.testing.assert_allclose(normal.jtr, j.T @ r, rtol=0, atol=1e-12 * np.max(np.abs(j.T @ r)))


@pytest.mark.parametrize("rotvec", [np.array([0.03, -0.02, 0.05]), np.zeros(3)])
def test_turned_angles_jacobian_matches_finite_differences(rotvec):
    """The first misalignment fit's residual (angle between gravity and the turned field, minus the dip angle)."""
    from calibrate.tumble.alignment import _turned_angles, _turned_angles_jacobian

    rng = np.random.default_rng(13)
    m = rng.normal(size=(200, 3))
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    a = rng.normal(size=(200, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    p = np.concatenate([rotvec, [1.2]])
    numeric = approx_derivative(_turned_angles, p, method="3-point", args=(m, a))
    np.testing.assert_allclose(_turned_angles_jacobian(p, m, a), numeric, atol=TOL, rtol=0)
