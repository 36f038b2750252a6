"""The response form test: a curve the vocabulary's powers cannot follow is said, not absorbed by another effect."""

from types import SimpleNamespace

import numpy as np
import pytest

from calibrate.diagnosis.evidence import STRUCTURE_P
from calibrate.fourflip.diagnosis import FORM_WARNING, UNEXPLAINED_WARNING
from calibrate.fourflip._form import (_curve_columns, curve_components, response_form_check, response_form_test,
                                      response_misfit)
from calibrate.fourflip._mlfit import fit_ml
from calibrate.fourflip.effects import VARIANTS
from calibrate.fourflip.fit import physics_from_harmonics
from calibrate.noise import lattice_step, noise_floor
from compass.sim.bench import BenchSamples
from tests._paths import load_tool

CUBIC = VARIANTS["nonlinear_response"][0]


@pytest.fixture(scope="module")
def bench():
    return load_tool("bench_loop")


def _cubic_fit(bench, case, seed, noise_ut=None):
    """The recording's fit with an odd cubic, weighted by the noisy recording's floor (``noise_ut`` 0: the same
    recording without noise, so the fit's misfit is the model's alone)."""
    rec, _ = bench.session(seed, case)
    noise = noise_floor(rec.platform_deg, rec.flip_index, rec.outputs, lattice_step(rec.outputs))
    if noise_ut is not None:
        rec, _ = bench.session(seed, case, noise_ut=noise_ut)
    samples = BenchSamples.from_recording(rec)
    start = physics_from_harmonics(rec, 50.0, 1.0)
    base = fit_ml(samples, rec.outputs, rec.channels, start, noise)
    return fit_ml(samples, rec.outputs, rec.channels, base.physics, noise, effects=(CUBIC,)), noise


def test_a_cubic_the_fit_describes_leaves_nothing_to_the_curve(bench):
    """Reference relation: without noise, an odd cubic fitted with the cubic leaves no chi-square to a general
    curve (the fit's own misfit only); each channel's test has 7 Legendre columns less the cubic's one."""
    fit, noise = _cubic_fit(bench, "odd cubic", 60, noise_ut=0.0)
    form = response_form_test(fit, noise)
    assert form.dof == 6
    assert np.all(form.delta_chi2 < 0.1)
    assert form.p_value == pytest.approx(1.0)


def test_a_knee_is_a_curve_the_cubic_cannot_follow(bench):
    """Without noise, a knee on channel b (compressing only above 0.7 |B|, where b is vertical at a dip of 64.5
    deg) leaves channel b a chi-square (the test's noncentrality with noise: 7.8, against 6 degrees of
    freedom, so the test sees this knee only with some help from the noise), where the cubic itself left below
    0.1, and channel a, which never sees more than the horizontal field, next to nothing."""
    fit, noise = _cubic_fit(bench, "knee", 67, noise_ut=0.0)
    form = response_form_test(fit, noise)
    assert form.delta_chi2[1] > 5.0
    assert form.delta_chi2[0] < 1e-3 * form.delta_chi2[1]


def test_the_p_value_is_over_the_judged_channels_only(bench):
    """Reference relation: the p-value is the judged channels' smallest chi-square tail times their number; the
    knee's channel b left out (an ADC's undithered channel is not judged), it no longer rejects the form, and
    with no channel judged it is 1."""
    from scipy.stats import chi2

    fit, noise = _cubic_fit(bench, "knee", 67)
    every = response_form_test(fit, noise)
    judged = np.array([True, False, True])
    some = response_form_test(fit, noise, judged)
    assert some.delta_chi2 == pytest.approx(every.delta_chi2)
    tails = chi2.sf(every.delta_chi2, every.dof)
    assert every.p_value == pytest.approx(min(1.0, 3 * tails.min()))
    assert some.p_value == pytest.approx(min(1.0, 2 * tails[judged].min()))
    assert every.p_value < STRUCTURE_P <= some.p_value
    assert response_form_test(fit, noise, np.zeros(3, dtype=bool)).p_value == 1.0


def _linear_fit(bench, case, seed):
    """The recording's base fit (a linear response) and its noise floor."""
    rec, _ = bench.session(seed, case)
    noise = noise_floor(rec.platform_deg, rec.flip_index, rec.outputs, lattice_step(rec.outputs))
    return fit_ml(BenchSamples.from_recording(rec), rec.outputs, rec.channels,
                  physics_from_harmonics(rec, 50.0, 1.0), noise), noise


def test_a_linear_response_is_tested_with_every_degree(bench):
    """A fit without a nonlinear response keeps all seven Legendre columns (degree 3, the cubic, among them); a
    clean recording's linear response passes."""
    fit, noise = _linear_fit(bench, "clean", 60)
    form = response_form_test(fit, noise)
    assert form.dof == 7 and form.p_value >= STRUCTURE_P


def test_the_check_leaves_a_linear_response_to_the_cubic(bench):
    """Odd cubic, seed 64 (the loop names no cubic): the linear fit's form test rejects, yet the check vetoes
    nothing, the cubic proposed among them (its misfit is what a curve would take)."""
    fit, noise = _linear_fit(bench, "odd cubic", 64)
    assert response_form_test(fit, noise).p_value < STRUCTURE_P
    weaker = SimpleNamespace(current=fit, trial=SimpleNamespace(chi2=fit.chi2 - 1.0))
    assert response_form_check(noise)(weaker) == (None, {})


def test_an_unnamed_cubic_is_said_and_covered(bench):
    """bench_loop's odd cubic, seed 64: the loop names no cubic and the structure test calls the residual white,
    channel c's direction 2.5 of its sigma off (the missed cubic's static bias); the linear response's form test
    rejects it, the verdict is unexplained with the curve's misfit in the cost, the report says the file keeps the
    linear response, and every direction is within 1.25 of its widened sigma."""
    from calibrate import calibrate_fourflip

    rec, truth = bench.session(64, "odd cubic")
    result = calibrate_fourflip(rec, diagnose=True)
    d = result.diagnosis
    assert "nonlinear_response" not in d["effects"] and d["structure_test"]["p_value"] > STRUCTURE_P
    assert d["unexplained"] is True and d["response_form_test"]["p_value"] < STRUCTURE_P
    assert "response_misfit" in d["unexplained_cost"]
    assert "the file keeps the linear response" in result.report()
    err = np.degrees(np.arccos(np.clip(np.sum(result.directions * truth.directions, axis=1), -1, 1)))
    assert np.all(err < 1.25 * np.array([c.direction_sigma_deg for c in result.channels]))


def test_a_linear_response_is_also_asked_the_cubic_alone(bench):
    """Reference relation: a linear fit's p-value is the smaller of the general curves' (the channels' smallest
    chi-square tail on 7 dof, times 3) and the cubic columns' joint drop's tail on one dof a channel, times two; a
    fit with a curve has no cubic drop (its powers hold degree 3) and keeps the curves' alone."""
    from scipy.stats import chi2

    fit, noise = _linear_fit(bench, "odd cubic", 64)
    form = response_form_test(fit, noise)
    curves = min(1.0, 3 * chi2.sf(form.delta_chi2, form.dof).min())
    assert form.p_value == pytest.approx(min(1.0, 2 * min(curves, chi2.sf(form.cubic_delta_chi2, 3))))
    assert form.as_dict("abc")["cubic_delta_chi2"] == form.cubic_delta_chi2
    curved, noise = _cubic_fit(bench, "odd cubic", 64)
    assert response_form_test(curved, noise).cubic_delta_chi2 is None


def test_the_cubic_keeps_the_dof_of_the_channels_it_was_taken_over(bench):
    """Reference relation: the cubic's joint drop over the judged channels (a and c: 2 columns) is a chi-square on 2
    dof whichever channels the p-value is asked over; asked over all three, the curves' part counts three channels and
    the cubic's still 2 (on odd cubic seed 64 its tail is 4x smaller than on the mask's 3 dof)."""
    from scipy.stats import chi2

    fit, noise = _linear_fit(bench, "odd cubic", 64)
    judged = np.array([True, False, True])
    form = response_form_test(fit, noise, judged)
    assert form.as_dict("abc")["cubic_dof"] == 2
    tail = chi2.sf(form.cubic_delta_chi2, 2)
    assert form.p_value == pytest.approx(min(1.0, 2 * min(2 * chi2.sf(form.delta_chi2[judged], form.dof).min(), tail)))
    curves = 3 * chi2.sf(form.delta_chi2, form.dof).min()
    assert tail < 0.5 * chi2.sf(form.cubic_delta_chi2, 3) and tail < curves  # the case where the dof decides
    assert form.p_value_over(np.ones(3, dtype=bool)) == pytest.approx(min(1.0, 2 * min(curves, tail)))


def test_an_unnamed_cubic_the_curves_dilute_is_said_alone(bench):
    """bench_loop's four stacked, seed 66 (dip 61.9 deg): the loop names the encoder error, the warm-up and the gain
    drift, not the 1 % cubic (its refit's delta-BIC -6.5), and the structure test calls the residual white; over
    seven Legendre columns a channel the cubic does not reject (p 0.17), its three columns alone do (chi2 18.5 on 3
    dof).  The fit is called unexplained with the curve's misfit in its cost, and the report says the cubic's
    chi-square; the naive sigmas left channel c 1.9 of its sigma off and the level heading 3.2 sigmas."""
    from calibrate import calibrate_fourflip
    from scipy.stats import chi2

    rec, truth = bench.session(66, "four stacked")
    result = calibrate_fourflip(rec, diagnose=True)
    d = result.diagnosis
    form = d["response_form_test"]
    assert "nonlinear_response" not in d["effects"] and d["structure_test"]["p_value"] > STRUCTURE_P
    assert 3 * chi2.sf(max(form["delta_chi2"].values()), form["dof"]) > STRUCTURE_P  # the curves alone: white
    assert d["unexplained"] is True and d["unexplained_by"] == "response_form_test"
    assert form["cubic_delta_chi2"] > chi2.isf(STRUCTURE_P / 2, 3)
    assert "response_misfit" in d["unexplained_cost"] and d["unexplained_cost"]["heading_deg"] > 0
    assert f"the odd cubic alone: chi2 {form['cubic_delta_chi2']:.0f} on 3 dof" in result.report()
    err = np.degrees(np.arccos(np.clip(np.sum(result.directions * truth.directions, axis=1), -1, 1)))
    assert np.all(err < 1.8 * np.array([c.direction_sigma_deg for c in result.channels]))


def test_the_check_vetoes_only_what_the_curve_could_take(bench):
    """On the noisy knee, an effect buying less chi-square than the general curve is vetoed with the test in its
    reason; one buying more (a real gain drift stacked with a cubic) is not."""
    fit, noise = _cubic_fit(bench, "knee", 67)
    curve = float(np.sum(response_form_test(fit, noise).delta_chi2))
    check = response_form_check(noise)
    weaker = SimpleNamespace(current=fit, trial=SimpleNamespace(chi2=fit.chi2 - 0.5 * curve))
    stronger = SimpleNamespace(current=fit, trial=SimpleNamespace(chi2=fit.chi2 - 2.0 * curve))
    reason, _ = check(weaker)
    assert reason is not None and "not the vocabulary's form" in reason
    assert check(stronger) == (None, {})


def test_a_knee_is_said_not_taken_as_a_platform_field(bench):
    """bench_loop's knee, seed 67: after the cubic, a platform field buys delta-BIC 11 (12 % of the structured
    residual; claimed, it leaves directions 3.3 and 2.9 sigmas off).  It is not claimed, the cubic
    stays (the vocabulary's nearest curve: a linear file reads the level heading 2 sigmas off), the response's
    form test makes the verdict unexplained (the structure test alone calls it white), and every direction is
    within 2 of its widened sigma."""
    from calibrate import calibrate_fourflip

    rec, truth = bench.session(67, "knee")
    result = calibrate_fourflip(rec, diagnose=True)
    d = result.diagnosis
    assert d["effects"] == ["nonlinear_response"]
    assert d["unexplained"] is True and d["structure_test"]["p_value"] > STRUCTURE_P
    assert "unexplained_cost" in d
    assert d["response_form_test"]["p_value"] < STRUCTURE_P
    assert any(line.startswith("platform_field") and "vocabulary's form" in line for line in d["not_claimed"])
    assert "the fitted response's curve is not the vocabulary's form" in result.report()
    err = np.degrees(np.arccos(np.clip(np.sum(result.directions * truth.directions, axis=1), -1, 1)))
    assert np.all(err < 2.0 * np.array([c.direction_sigma_deg for c in result.channels]))


def test_the_report_says_the_curve_not_structure_made_it_unexplained(bench):
    """Knee seed 67: white by the structure test, unexplained by the form test; the report's verdict names the curve
    rather than 'structure remains', beside the structure test's p-value that says the rest is white."""
    from calibrate import calibrate_fourflip

    rec, _ = bench.session(67, "knee")
    result = calibrate_fourflip(rec, diagnose=True)
    d = result.diagnosis
    assert d["unexplained"] is True and d["structure_test"]["p_value"] >= STRUCTURE_P
    assert d["response_form_test"]["p_value"] < STRUCTURE_P and d["unexplained_by"] == "response_form_test"
    verdict = next(line for line in result.report().splitlines() if "UNEXPLAINED" in line)
    assert "curve is not a form the model has" in verdict and "structure remains" not in verdict
    assert FORM_WARNING in result.warnings and UNEXPLAINED_WARNING not in result.warnings  # the warning says so too


def test_no_misfit_no_cover(bench):
    """Reference relation: an odd cubic without noise, fitted with the cubic, leaves the curves nothing, so the
    cover is the naive covariance itself; each judged channel leaves the curves its 7 degrees less the cubic's
    (degree 3 is the gain's and the cubic's span: dropped as degenerate)."""
    fit, noise = _cubic_fit(bench, "odd cubic", 60, noise_ut=0.0)
    misfit = response_misfit(fit, noise)
    assert misfit.taken == (0, 18)
    assert np.all(misfit.bias_covariance == 0.0)
    np.testing.assert_array_equal(misfit.cover(fit.covariance), fit.covariance)
    assert response_misfit(fit, noise, np.array([True, False, True])).taken[1] == 12


def test_the_components_are_the_augmented_fit(bench):
    """Reference relation, on the knee (seed 67, one channel's curve): the least squares of the fit's Jacobian with
    the curve's determined components beside it moves the parameters by the components' ``-sum m_k z_k`` and has
    the covariance ``(J^T W J)^-1 + sum m_k m_k^T`` at the noise floor, solved directly."""
    fit, noise = _cubic_fit(bench, "knee", 67)
    judged = np.array([False, True, False])
    z, moves, _ = curve_components(fit, noise, judged)
    r0, j_b, blocks = _curve_columns(fit, noise)
    scale = np.linalg.norm(np.nan_to_num(fit.jac), axis=0)
    scale[scale == 0] = 1.0
    curve = blocks[1] / np.linalg.norm(blocks[1], axis=0)
    absorbed = np.linalg.lstsq(j_b, curve, rcond=None)[0]
    w, v = np.linalg.eigh((curve - j_b @ absorbed).T @ (curve - j_b @ absorbed))
    augmented = np.hstack([j_b, curve @ v[:, w > 1e-12 * w.max()]])
    solved = np.linalg.lstsq(augmented, r0, rcond=None)[0][:j_b.shape[1]] / scale
    bread = fit.covariance / (fit.chi2 / fit.dof)
    good = np.isfinite(np.diag(bread))
    sigma = np.sqrt(np.diag(bread)[good])
    move = moves @ z
    assert z.size == 6 and np.max(np.abs(move[good]) / sigma) > 0.1  # a move worth checking
    assert np.max(np.abs(solved[good] + move[good]) / sigma) < 1e-4  # to the lstsq's conditioning
    inverse = np.linalg.pinv(augmented.T @ augmented)[:j_b.shape[1], :j_b.shape[1]] / np.outer(scale, scale)
    expected = bread + moves @ moves.T
    np.testing.assert_allclose(np.diag(inverse)[good], np.diag(expected)[good], rtol=1e-6)


def test_the_bias_is_a_covariance(bench):
    """Invariant: on the noisy knee the squared bias taken is symmetric and positive semi-definite, and it adds
    to no parameter's variance more than its components' chi-square above their noise allows (each taken one
    moves no parameter by more than MAX_MOVE_SIGMAS of its sigma per unit z)."""
    from calibrate.fourflip._form import MAX_MOVE_SIGMAS

    fit, noise = _cubic_fit(bench, "knee", 67)
    misfit = response_misfit(fit, noise)
    bias = misfit.bias_covariance
    np.testing.assert_allclose(bias, bias.T, atol=1e-15)
    assert np.linalg.eigvalsh(bias).min() > -1e-12 * np.abs(bias).max()
    assert 0 < misfit.taken[0] <= misfit.taken[1]
    bread = np.diag(fit.covariance) / (fit.chi2 / fit.dof)
    assert np.all(np.diag(bias) <= MAX_MOVE_SIGMAS**2 * bread * misfit.delta_chi2)


def test_a_knee_the_cubic_absorbed_is_covered(bench):
    """bench_loop's knee, seed 6 (dip 64.8): the form test rejects the cubic's curve and the fit is unexplained, but
    the widening sized structure in time and left the directions 1.98, 1.57, 0.33 of their sigmas off; the
    curve's bias in the parameters, propagated, covers them (each within 1.5 of its widened sigma) and says so in
    the cost."""
    from calibrate import calibrate_fourflip

    rec, truth = bench.session(6, "knee")
    result = calibrate_fourflip(rec, diagnose=True)
    d = result.diagnosis
    assert d["unexplained"] is True and d["response_form_test"]["p_value"] < STRUCTURE_P
    cost = d["unexplained_cost"]
    assert "response_misfit" in cost and "not the vocabulary's form" in cost["method"]
    assert cost["response_misfit"]["components"]["with_bias"] > 0
    err = np.degrees(np.arccos(np.clip(np.sum(result.directions * truth.directions, axis=1), -1, 1)))
    assert np.all(err < 1.5 * np.array([c.direction_sigma_deg for c in result.channels]))


def test_a_wander_and_a_misfit_are_each_sized_from_the_naive_fit(bench):
    """bench_loop's knee, seed 101: white by the structure test, its curve rejected by the form test, and its block
    sums wander; both widenings are sized from the naive fit (the same naive sigmas in both costs), not the misfit's
    from the fit the walk already widened, and the file states the larger of the two."""
    from calibrate import calibrate_fourflip

    rec, _ = bench.session(101, "knee")
    result = calibrate_fourflip(rec, diagnose=True)
    d = result.diagnosis
    assert d["unexplained_by"] == "response_form_test" and "wander_cost" in d and "unexplained_cost" in d
    wander, cost = d["wander_cost"]["direction_sigma_deg"], d["unexplained_cost"]["direction_sigma_deg"]
    for name in wander:
        assert cost[name]["naive"] == pytest.approx(wander[name]["naive"], rel=1e-12)
    stated = np.array([c.direction_sigma_deg for c in result.channels])
    larger = [max(wander[n]["widened"], cost[n]["widened"]) for n in wander]
    assert np.all(stated >= np.array(larger) * (1 - 1e-9))
