"""The four-flip report's heading sigma: every correlation of a channel's direction, offset and gain carried."""

import numpy as np
import pytest

from calibrate.diagnosis.robust import heading_sigma_deg
from calibrate.fourflip._mlfit import curve_coefficients, fit_ml
from calibrate.fourflip.diagnosis import _heading_sigma
from calibrate.fourflip.effects import VARIANTS
from calibrate.fourflip.fit import physics_from_harmonics
from compass.iron_uncertainty import CURVE_POWERS
from compass.sim.bench import BenchSamples

N_HEADINGS = 72


def _heading_rad(reference, physics) -> np.ndarray:
    """A level housing's heading read through ``physics`` from outputs ``reference`` makes, every 5 degrees."""
    psi = np.linspace(0.0, 2 * np.pi, N_HEADINGS, endpoint=False)
    dip = np.radians(reference.dip_deg)
    b = reference.field_norm * np.column_stack([np.cos(dip) * np.cos(psi), -np.cos(dip) * np.sin(psi),
                                                np.full_like(psi, -np.sin(dip))])
    out = reference.offsets + reference.gains * (b @ reference.directions.T)
    m = ((out - physics.offsets) / physics.gains) @ np.linalg.pinv(physics.directions).T
    return np.arctan2(-m[:, 1], m[:, 0])


@pytest.fixture(scope="module")
def warm_up_fit(tmp_path_factory):
    from calibrate import calibrate_fourflip
    from compass.io.fourflip import read_fourflip
    from compass.sim.fourflip import simulate_fourflip, write_fourflip

    path, _ = write_fourflip(simulate_fourflip(seed=200, effects=("offset_drift",)),
                             tmp_path_factory.mktemp("warm") / "rec.csv")
    rec = read_fourflip(path)
    samples = BenchSamples.from_recording(rec)
    start = physics_from_harmonics(rec, 50.0, 1.0)
    noise = np.array(calibrate_fourflip(rec, diagnose=False).noise)
    warm_up = VARIANTS["offset_drift"][-1]
    return fit_ml(samples, rec.outputs, rec.channels, start, noise, effects=(warm_up,))


def test_heading_sigma_is_the_fits_covariance_taken_through_the_runtime(warm_up_fit):
    """Reference relation: the stated heading sigma is the RMS over headings of ``sqrt(j^T C j)``, ``j`` the
    runtime heading's derivative by every fit parameter (finite differences through the layout), ``C`` the
    fit's covariance; the per-channel formula taking direction, offset and gain as independent is not."""
    fit = warm_up_fit
    x, phys = fit.x, fit.physics
    h0 = _heading_rad(phys, phys)
    jac = np.zeros((N_HEADINGS, x.size))
    for j in range(x.size):
        step = 1e-6 * max(1.0, abs(x[j]))
        moved = x.copy()
        moved[j] += step
        jac[:, j] = np.angle(np.exp(1j * (_heading_rad(phys, fit.layout.physics(moved)) - h0))) / step
    reference = np.degrees(np.sqrt(np.mean(np.einsum("hi,ij,hj->h", jac, np.nan_to_num(fit.covariance), jac))))
    assert _heading_sigma(fit) == pytest.approx(reference, rel=0.005)
    c = len(phys.gains)
    var = np.diag(fit.covariance)[:4 * c].reshape(c, 4)[:, 2:] * phys.gains[:, None] ** 2
    independent = heading_sigma_deg(phys.directions, fit.direction_covariance, var, phys.gains, phys.dip_deg,
                                    phys.field_norm)
    assert abs(independent / reference - 1.0) > 0.02  # 3 % on this recording, 18 % median on bench_loop's


def test_joint_covariance_keeps_the_files_sigmas(warm_up_fit):
    """The joint block's diagonal parts are the file's direction covariance and (to the start's gain against the
    fitted one) its offset and gain variances: nothing stated in the file changes."""
    fit = warm_up_fit
    joint = fit.channel_covariance()
    np.testing.assert_allclose(joint[:, :3, :3], fit.direction_covariance, rtol=1e-9, atol=1e-18)
    c = len(fit.physics.gains)
    var = np.diag(fit.covariance)[:4 * c].reshape(c, 4)[:, 2:] * fit.physics.gains[:, None] ** 2
    np.testing.assert_allclose(joint[:, 4, 4], var[:, 1], rtol=1e-9)
    np.testing.assert_allclose(joint[:, 3, 3], var[:, 0], rtol=0.05)


def test_an_undetermined_parameter_leaves_the_channels_other_terms(warm_up_fit):
    """A log gain the fit could not determine (its covariance row and column NaN) makes NaN only the gain's
    row and column of that channel's joint covariance; its direction and offset terms are those of the fit
    with the gain known."""
    from dataclasses import replace

    fit = warm_up_fit
    cov = fit.covariance.copy()
    cov[3, :] = cov[:, 3] = np.nan  # channel 0's log gain
    joint, known = replace(fit, covariance=cov).channel_covariance(), fit.channel_covariance()
    assert np.all(np.isnan(joint[0, 4, :])) and np.all(np.isnan(joint[0, :, 4]))
    assert np.all(np.isfinite(joint[0, :4, :4]))
    # without the gain's correlations the rest of the block is the known one with the gain's column removed
    expected = replace(fit, covariance=np.nan_to_num(cov, nan=0.0)).channel_covariance()
    np.testing.assert_allclose(joint[0, :4, :4], expected[0, :4, :4], rtol=1e-12)
    np.testing.assert_allclose(joint[1:], known[1:], rtol=1e-12)


def _curved_heading_rad(reference, physics) -> np.ndarray:
    """:func:`_heading_rad` through each response curve: outputs ``reference``'s curve makes, each channel's
    component found by inverting ``physics``'s curve (Newton steps from the linear reading)."""
    psi = np.linspace(0.0, 2 * np.pi, N_HEADINGS, endpoint=False)
    dip = np.radians(reference.dip_deg)
    b = reference.field_norm * np.column_stack([np.cos(dip) * np.cos(psi), -np.cos(dip) * np.sin(psi),
                                                np.full_like(psi, -np.sin(dip))])
    powers = np.array(CURVE_POWERS)

    def curve(x, coefficients):
        return x + np.sum(coefficients * x[..., None] ** powers, axis=-1)

    out = reference.offsets + reference.gains * curve(b @ reference.directions.T, curve_coefficients(reference))
    y = (out - physics.offsets) / physics.gains
    x, coefficients = y.copy(), curve_coefficients(physics)
    for _ in range(20):
        slope = 1.0 + np.sum(powers * coefficients * x[..., None] ** (powers - 1), axis=-1)
        x = x - (curve(x, coefficients) - y) / slope
    m = x @ np.linalg.pinv(physics.directions).T
    return np.arctan2(-m[:, 1], m[:, 0])


@pytest.fixture(scope="module")
def cubic_fit(tmp_path_factory):
    from calibrate import calibrate_fourflip
    from compass.io.fourflip import read_fourflip
    from compass.sim.fourflip import simulate_fourflip, write_fourflip

    path, _ = write_fourflip(simulate_fourflip(seed=201, effects=("nonlinear_response",)),
                             tmp_path_factory.mktemp("cubic") / "rec.csv")
    rec = read_fourflip(path)
    start = physics_from_harmonics(rec, 50.0, 1.0)
    noise = np.array(calibrate_fourflip(rec, diagnose=False).noise)
    cubic = VARIANTS["nonlinear_response"][0]
    return fit_ml(BenchSamples.from_recording(rec), rec.outputs, rec.channels, start, noise, effects=(cubic,))


def test_a_linear_response_keeps_the_old_sigma(warm_up_fit):
    """No curve: the fit has no curve covariance, and zero coefficients with the joint covariance padded by
    zero rows give the five-term sigma to rounding (``g = x``, ``g' = 1``)."""
    fit = warm_up_fit
    assert fit.curve_covariance() is None
    phys, joint = fit.physics, fit.channel_covariance()
    c = len(phys.gains)
    padded = np.zeros((c, 8, 8))
    padded[:, :5, :5] = joint
    var = np.stack([joint[:, 3, 3], joint[:, 4, 4]], axis=1)
    args = (phys.directions, fit.direction_covariance, var, phys.gains, phys.dip_deg, phys.field_norm)
    assert heading_sigma_deg(*args, channel_covariance=padded, curves=np.zeros((c, 3))) == pytest.approx(
        heading_sigma_deg(*args, channel_covariance=joint), rel=1e-12)


def test_a_curves_heading_sigma_is_the_spread_of_drawn_fits(cubic_fit):
    """Monte Carlo: the fit's parameters drawn from their joint covariance (curve included), each draw's level
    heading read through its own curve against the fit's; the RMS of that heading error over draws and headings
    is the stated sigma within the draws' sampling error (400 draws: ~4 % on a sigma) and the terms across
    channels the per-channel formula leaves out (9 % here: the dip ties the gains and curves of the channels
    together), and the sigma that leaves the curve out (the gain's variance alone) is not: the curve and the gain
    trade against each other.  Reference relation: the stated sigma is the fit's linearised heading (finite
    differences) through each channel's block of the covariance, curve parameter included."""
    fit = cubic_fit
    phys = fit.physics
    assert fit.curve_covariance() is not None
    h0 = _curved_heading_rad(phys, phys)
    jac = np.zeros((N_HEADINGS, fit.x.size))
    for j in range(fit.x.size):
        moved = fit.x.copy()
        moved[j] += 1e-6 * max(1.0, abs(fit.x[j]))
        jac[:, j] = np.angle(np.exp(1j * (_curved_heading_rad(phys, fit.layout.physics(moved)) - h0))) / (
            moved[j] - fit.x[j])
    blocks = np.zeros_like(fit.covariance)
    for ch, name in enumerate(fit.layout.channels):
        at = list(range(4 * ch, 4 * ch + 4)) + [fit.names.index(f"{name}.x3_rel_at_B")]
        blocks[np.ix_(at, at)] = np.nan_to_num(fit.covariance[np.ix_(at, at)])
    linearised = np.degrees(np.sqrt(np.mean(np.einsum("hi,ij,hj->h", jac, blocks, jac))))
    assert _heading_sigma(fit) == pytest.approx(linearised, rel=0.005)
    rng = np.random.default_rng(5)
    draws = rng.multivariate_normal(fit.x, np.nan_to_num(fit.covariance), size=400, method="eigh")
    errors = [np.angle(np.exp(1j * (_curved_heading_rad(phys, fit.layout.physics(x)) - h0))) for x in draws]
    spread = np.degrees(np.sqrt(np.mean(np.square(errors))))
    assert _heading_sigma(fit) == pytest.approx(spread, rel=0.15)
    joint = fit.channel_covariance()
    var = np.stack([joint[:, 3, 3], joint[:, 4, 4]], axis=1)
    without = heading_sigma_deg(phys.directions, fit.direction_covariance, var, phys.gains, phys.dip_deg,
                                phys.field_norm, channel_covariance=joint)
    assert without / spread > 1.2


def test_curve_covariance_keeps_the_five_terms(cubic_fit):
    """The curve's joint block holds :meth:`channel_covariance` unchanged in its first five rows, and its cubic
    coefficient's variance is the fit's parameter variance over ``|B|^4`` (powers without a parameter: zero)."""
    fit = cubic_fit
    curved, joint = fit.curve_covariance(), fit.channel_covariance()
    np.testing.assert_allclose(curved[:, :5, :5], joint, rtol=1e-9, atol=1e-30)
    at = [fit.names.index(f"{ch}.x3_rel_at_B") for ch in fit.layout.channels]
    np.testing.assert_allclose(curved[:, 6, 6], np.diag(fit.covariance)[at] / fit.physics.field_norm ** 4, rtol=1e-9)
    assert np.all(curved[:, 5, :] == 0.0) and np.all(curved[:, 7, :] == 0.0)


def test_curve_covariance_of_a_quadratic_and_cubic(cubic_fit):
    """The quadratic-and-cubic form: each coefficient ``c_k = p_k / |B|^(k - 1)``, so the block holds the two
    parameters' covariance scaled by ``|B|^-1`` and ``|B|^-2`` in rows 5 and 6, the quintic's row zero."""
    from dataclasses import replace

    fit = cubic_fit
    both = VARIANTS["nonlinear_response"][1]
    assert both.powers == (2, 3)
    c = len(fit.physics.gains)
    start = len(fit.x) - c  # the cubic form's block, replaced by the two powers' with a drawn covariance
    names = fit.names[:start] + both.param_names(fit.layout.channels)
    cov = np.zeros((start + 2 * c, start + 2 * c))
    cov[:start, :start] = fit.covariance[:start, :start]
    rng = np.random.default_rng(3)
    root = rng.normal(size=(2 * c, 2 * c))
    cov[start:, start:] = 1e-6 * root @ root.T
    other = replace(fit, effects=(both,), names=names, covariance=cov, x=np.r_[fit.x[:start], np.zeros(2 * c)])
    curved, norm = other.curve_covariance(), fit.physics.field_norm
    scale = np.array([1.0 / norm, 1.0 / norm**2])
    for ch in range(c):
        block = cov[start + 2 * ch:start + 2 * ch + 2, start + 2 * ch:start + 2 * ch + 2]
        np.testing.assert_allclose(curved[ch, 5:7, 5:7], block * np.outer(scale, scale), rtol=1e-12)
    assert np.all(curved[:, 7, :] == 0.0)
