"""The platform field's unseen x and z parts: a stated prior carried into the file's sigmas."""

import json

import numpy as np
import pytest

from calibrate import calibrate_fourflip
from calibrate.fourflip._mlfit import fit_ml
from calibrate.fourflip._unseen import platform_prior, unseen_platform_sensitivity
from calibrate.fourflip.effects import EFFECTS
from calibrate.fourflip.fit import physics_from_harmonics
from calibrate.noise import lattice_step, noise_floor
from compass.io.fourflip import read_fourflip
from compass.sim.bench import BenchSamples
from compass.sim.fourflip import simulate_fourflip, write_fourflip

C = 3
OFFSETS = [4 * k + 2 for k in range(C)]
GAINS = [4 * k + 3 for k in range(C)]
DIRECTIONS = [4 * k + j for k in range(C) for j in (0, 1)]
DIP = 4 * C


def _fits(rec, effects):
    samples = BenchSamples.from_recording(rec)
    noise = noise_floor(rec.platform_deg, rec.flip_index, rec.outputs, lattice_step(rec.outputs))
    start = physics_from_harmonics(rec, None, 1.0)
    return fit_ml(samples, rec.outputs, rec.channels, start, noise, effects=effects), noise


@pytest.fixture(scope="module")
def platform_fit(tmp_path_factory):
    path, _ = write_fourflip(simulate_fourflip(seed=200, effects=("platform_field",)),
                             tmp_path_factory.mktemp("plat") / "rec.csv")
    rec = read_fourflip(path)
    fit, noise = _fits(rec, (EFFECTS["platform_field"],))
    return rec, fit, noise


def test_the_x_part_moves_each_offset_by_a_x_and_nothing_else(platform_fit):
    _, fit, noise = platform_fit
    g = unseen_platform_sensitivity(fit, noise)
    a_x = fit.physics.directions[:, 0]
    # reference relation: offset_i (output units) += gain_i a_i,x b_x, b_x in the y parameter's units (field_norm);
    # the offset parameter counts the starting gain
    moved = a_x * fit.physics.field_norm * fit.physics.gains / fit.layout.start.gains
    assert np.abs(g[OFFSETS, 0]) == pytest.approx(np.abs(moved), rel=1e-6)
    assert np.ptp(np.sign(g[OFFSETS, 0] * a_x)) == 0  # one sign for every channel: the same b_x
    others = np.setdiff1d(np.arange(g.shape[0]), OFFSETS)
    assert np.max(np.abs(g[others, 0])) < 1e-6 * np.max(np.abs(a_x))


def test_the_z_part_moves_the_dip_and_one_common_gain_by_the_vertical_fields_geometry(platform_fit):
    _, fit, noise = platform_fit
    g = unseen_platform_sensitivity(fit, noise)[:, 1]
    dip = np.radians(fit.physics.dip_deg)
    # a vertical b_z: ln|B| moves by sin(dip) b_z / |B| and the dip by cos(dip) b_z / |B| (b_z in units of |B|)
    assert np.abs(g[GAINS]) == pytest.approx(np.full(C, abs(np.sin(dip))), rel=1e-3)
    assert np.ptp(g[GAINS]) < 1e-6
    assert abs(g[DIP]) == pytest.approx(abs(np.cos(dip)), rel=1e-3)
    assert np.max(np.abs(g[OFFSETS + DIRECTIONS])) < 1e-6
    # the fitted y part, in field units, keeps its output against the gains' common scale
    i = fit.block_start(fit.effects[0])
    assert g[i] == pytest.approx(-fit.x[i] * g[GAINS[0]], rel=1e-3)


def test_the_offset_covariance_grows_by_a_a_t_times_the_prior_variance(platform_fit):
    _, fit, noise = platform_fit
    wide, unseen = platform_prior(fit, noise)
    i = fit.block_start(fit.effects[0])
    var = fit.x[i] ** 2 + fit.covariance[i, i]
    a = fit.physics.directions[:, 0] * fit.physics.field_norm * fit.physics.gains / fit.layout.start.gains
    added = wide.covariance[np.ix_(OFFSETS, OFFSETS)] - fit.covariance[np.ix_(OFFSETS, OFFSETS)]
    assert added == pytest.approx(var * np.outer(a, a), rel=1e-5, abs=1e-12 * var)
    assert unseen["prior_sigma_fieldunit"] == pytest.approx(np.sqrt(var) * fit.physics.field_norm, rel=1e-12)
    # the directions do not move with b_x or b_z: their covariance is the fit's
    assert wide.direction_covariance == pytest.approx(fit.direction_covariance, rel=1e-6, abs=1e-18)


def test_a_fit_without_the_platform_field_keeps_its_sigmas(write_session):
    rec, _ = write_session(seed=201)
    fit, noise = _fits(rec, ())
    same, unseen = platform_prior(fit, noise)
    assert unseen is None and same is fit
    result = calibrate_fourflip(rec, diagnose=True)
    assert result.diagnosis["effects"] == [] and "platform_field_unseen" not in result.diagnosis
    assert not any("not seen by the bench" in w for w in result.warnings)


def test_the_report_says_the_x_and_z_parts_are_unseen_and_their_heading_cost(platform_fit):
    rec, _, _ = platform_fit
    result = calibrate_fourflip(rec, diagnose=True)
    unseen = result.diagnosis["platform_field_unseen"]
    assert unseen["heading_deg"] > 0
    assert unseen["heading_sigma_deg"]["with"] > unseen["heading_sigma_deg"]["without"]
    text = result.report()
    assert "x part (along the flip axis) and z part (vertical) are not seen by the bench" in text
    assert f"adds {unseen['heading_deg']:.3g} deg to the heading sigma" in text
    # the prior from the y part as the file states it (whose sigma the z part widens a little: it moves p_y
    # with the gains' common scale, by ~p_y sin(dip) b_z)
    y = result.effects[0]["parameters"]["platform_field.y_fieldunit"]
    assert unseen["prior_sigma_fieldunit"] == pytest.approx(np.hypot(y["value"], y["sigma"]), rel=1e-3)


def test_the_files_joint_covariance_carries_the_prior_and_its_marginals_are_the_files_sigmas(platform_fit):
    """With the platform prior in, each channel's ``joint_covariance`` is the widened one: its marginals are the
    file's sigmas (which hold the prior), and the runtime's heading sigma from the file is the diagnosis's
    ``heading_sigma_deg.with`` but for the offsets' correlation across channels (the prior's ``a_x b_x`` moves
    every offset by one ``b_x``; the file keeps each channel's block)."""
    from compass.calibration import dumps, from_dict
    from compass.frames import r_world_from_housing, world_field

    rec, _, _ = platform_fit
    result = calibrate_fourflip(rec, diagnose=True)
    doc = json.loads(dumps(result.to_json()))
    for ch in doc["channels"].values():
        joint = np.array(ch["joint_covariance"])
        np.testing.assert_allclose(joint[:3, :3], ch["direction_covariance"], rtol=1e-9, atol=1e-12 * joint[0, 0])
        assert np.sqrt(np.diag(joint)[3:]) == pytest.approx([ch["response_sigma"]["offset"],
                                                             ch["response_sigma"]["gain"]], rel=1e-12)
    model = from_dict(doc).model
    rot = r_world_from_housing(np.arange(0.0, 360.0, 5.0), 0.0, 0.0)
    fields = rot.apply(world_field(model.dip_deg, model.field_norm), inverse=True)
    own = model.calibration_uncertainty
    runtime = np.sqrt(np.mean([own.heading_sigma_deg(m, b) ** 2 for m, b in zip(rot.as_matrix(), fields)]))
    assert runtime == pytest.approx(result.diagnosis["platform_field_unseen"]["heading_sigma_deg"]["with"], rel=0.01)


def test_a_y_part_without_a_finite_variance_states_no_prior_and_says_so(platform_fit, monkeypatch):
    """The fitted y part's variance not finite (the fit could not determine it): no prior can be stated; the fit
    comes back unchanged, and the diagnosis and the report's warnings say the unseen parts are left out (they
    were dropped without a word)."""
    from dataclasses import replace

    import calibrate.fourflip.diagnosis as diagnosis
    from calibrate.fourflip.diagnosis import _unseen_platform, platform_unseen_warning

    rec, fit, noise = platform_fit
    i = fit.block_start(fit.effects[0])
    cov = fit.covariance.copy()
    cov[i, :] = cov[:, i] = np.nan
    undetermined = replace(fit, covariance=cov)
    same, unseen = platform_prior(undetermined, noise)
    assert same is undetermined and unseen["prior_sigma_fieldunit"] is None
    assert unseen["fitted_y_fieldunit"] == pytest.approx(fit.x[i] * fit.physics.field_norm, rel=1e-12)
    same, unseen = _unseen_platform(undetermined, noise, rec.channels)
    assert same is undetermined and unseen["prior_stated"] is False
    assert "no prior for them is stated" in platform_unseen_warning(unseen)

    real = diagnosis.platform_prior

    def y_undetermined(f, n):  # the loop's final fit with its y part's row and column NaN
        j = f.block_start(f.effects[0])
        c = f.covariance.copy()
        c[j, :] = c[:, j] = np.nan
        return real(replace(f, covariance=c), n)

    monkeypatch.setattr(diagnosis, "platform_prior", y_undetermined)
    result = calibrate_fourflip(rec, diagnose=True)
    assert result.diagnosis["platform_field_unseen"]["prior_stated"] is False
    said = [w for w in result.warnings if "not seen by the bench" in w]
    assert len(said) == 1 and "no prior for them is stated" in said[0] and "no prior for them is stated" in result.report()
    assert "adds" not in said[0]
