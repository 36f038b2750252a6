"""The diagnosis loop on recordings with an effect the estimator is not told about."""

import re
from dataclasses import replace

import numpy as np
import pytest

from calibrate import calibrate_fourflip
from calibrate.fourflip.effects import EFFECTS
from tests.conftest import angle_deg
from compass.calibration import model_from_dict
from compass.sim.fourflip import simulate_fourflip


def _check_explained(result, truth):
    d = result.diagnosis
    assert d["unexplained"] is False
    # residual at the noise floor, within 10 %
    assert d["residual_rms_after"] == pytest.approx(d["noise_floor"], rel=0.10)
    sigma = np.array([c.direction_sigma_deg for c in result.channels])
    err = angle_deg(result.directions, truth["directions"])
    assert np.all(err < 3.0 * sigma), (err, sigma)


@pytest.mark.parametrize("effect", sorted(EFFECTS))
def test_undeclared_effect_is_found_and_removed(write_session, effect):
    rec, truth = write_session(seed=200, effects=(effect,))
    result = calibrate_fourflip(rec, diagnose=True)
    assert result.diagnosis["effects"] == [effect]
    assert [e["name"] for e in result.effects] == [effect]
    # the file reads without this code: the effect's formula in its own parameter and reference names
    entry = result.effects[0]
    names = {n.split(".")[-1] for n in entry["parameters"]} | set(entry.get("reference", {})) - {"after_warm_up"}
    assert all(n in entry["form"] or re.sub(r"\d+", "<k>", n) in entry["form"] for n in names), entry
    step = result.diagnosis["steps"][1]
    assert step["added"] == effect and step["delta_bic"] > 10 and step["evidence"]
    assert step["residual_rms"] < result.diagnosis["residual_rms_before"]
    _check_explained(result, truth)


@pytest.mark.parametrize("seed", [201, 202])
def test_clean_recording_comes_back_clean(write_session, seed):
    rec, truth = write_session(seed=seed)
    result = calibrate_fourflip(rec, diagnose=True)
    assert result.diagnosis["effects"] == []
    assert len(result.diagnosis["steps"]) == 1
    _check_explained(result, truth)


def test_unmodelled_gradient_is_unexplained_without_false_claim(write_session):
    """A field gradient across the turntable, sensor off the axis: nothing we model explains it."""
    rec, _ = write_session(seed=203, effects=("field_gradient",))
    result = calibrate_fourflip(rec, diagnose=True)
    assert result.diagnosis["unexplained"] is True
    assert result.diagnosis["effects"] == []
    assert any("structure remains" in w for w in result.warnings)


@pytest.mark.parametrize("effect, key, name", [
    ("flip_error", lambda p: np.asarray(p["flip_rotvec_deg"])[:, 0], "error_deg"),
    ("turntable_zero", lambda p: np.asarray(p["yaw_deg"]), "turntable_zero_deg"),
])
def test_flip_angles_recovered(write_session, effect, key, name):
    rec, truth = write_session(seed=204, effects=(effect,))
    result = calibrate_fourflip(rec, diagnose=True)
    params = result.effects[0]["parameters"]
    true = key([e for e in truth["effects"] if e["name"] == effect][0]["parameters"])
    for k, flip in enumerate((90, 180, 270), start=1):
        p = params[f"flip{flip}.{name}"]
        assert abs(p["value"] - true[k]) < 4 * p["sigma"], (flip, p, true[k])


@pytest.mark.parametrize("by_deg", [-4.0, 12.0])
def test_a_flip_set_down_turned_is_fitted_not_widened(write_session, by_deg):
    """One flip's turntable angles read from a zero a few degrees off (under the refusal's 15 deg): the diagnosis
    names the flip's zero and the directions come back at the clean recording's error, not spread over the fit."""
    rec, truth = write_session(seed=3)
    moved = replace(rec, platform_deg=np.where(rec.flip_index == 2, rec.platform_deg + by_deg, rec.platform_deg))
    result = calibrate_fourflip(moved, diagnose=True)
    assert result.diagnosis["effects"] == ["turntable_zero"]
    p = result.effects[0]["parameters"]["flip180.turntable_zero_deg"]
    assert abs(p["value"] + by_deg) < 4 * p["sigma"]  # true angle = recorded - by_deg
    _check_explained(result, truth)


def test_one_channel_claims_no_flip_angles_and_says_what_it_cannot_tell(write_session):
    """One channel cannot tell a flip's turntable zero from its direction: the effect is not examined, a flip_error
    fitted to tens of degrees is not claimed, and the words say so (the direction came back 175 deg off, explained)."""
    from calibrate.fourflip.diagnosis import FEW_CHANNELS_WARNING

    rec, _ = write_session(seed=7, n_channels=1, effects=("turntable_zero",), effect_scale=5.0)
    result = calibrate_fourflip(rec, diagnose=True)
    d = result.diagnosis
    assert "turntable_zero" in d["not_applicable"] and not {"turntable_zero", "flip_error"} & set(d["effects"])
    assert d["unexplained"] is True and FEW_CHANNELS_WARNING in result.warnings
    assert any(text.startswith("flip_error") and "beyond the 15 deg" in text for text in d["not_claimed"])


def test_no_diagnose_says_structure_it_leaves(write_session):
    rec, _ = write_session(seed=5)
    moved = replace(rec, platform_deg=np.where(rec.flip_index == 1, rec.platform_deg + 14.0, rec.platform_deg))
    result = calibrate_fourflip(moved, diagnose=False)
    assert any(w.startswith("the residual carries structure above the noise floor") for w in result.warnings)
    assert not any("carries structure" in w for w in calibrate_fourflip(rec, diagnose=False).warnings)


def test_noise_floor_matches_injected_noise(write_session):
    from calibrate.noise import noise_floor

    rec, truth = write_session(seed=205, effects=("offset_drift", "encoder_error"))
    floor = noise_floor(rec.platform_deg, rec.flip_index, rec.outputs)
    # MAD-based scale of ~4300 second differences: relative standard error about 2 %
    np.testing.assert_allclose(floor, truth["noise"], rtol=0.08)


def test_seed_rule_diagnosis_examines_only(write_session):
    rec, _ = write_session(seed=206)
    result = calibrate_fourflip(rec, method="harmonic", diagnose=True)
    assert result.diagnosis["effects"] == [] and "note" in result.diagnosis


@pytest.mark.parametrize("step_deg", [1.0, 10.0])
def test_noise_floor_with_coarse_steps(write_session, step_deg):
    """Coarse turntable steps: the field's curvature must not pass for noise."""
    from calibrate.noise import noise_floor

    rec, truth = write_session(seed=207, step_deg=step_deg)
    floor = noise_floor(rec.platform_deg, rec.flip_index, rec.outputs)
    n = rec.n_samples
    # relative standard error of a MAD scale of ~n second differences: about 1.1 * sqrt(3 / n)
    np.testing.assert_allclose(floor, truth["noise"], rtol=4 * 1.1 * np.sqrt(3.0 / n) + 0.02)


def test_asymmetric_response_found_and_inverted_at_runtime(tmp_path):
    """An even (asymmetric) response term, injected outside the simulator: found, and the runtime
    model inverts it back to the true field component."""
    from compass.sim.bench import housing_field
    from compass.sim.fourflip import simulate_fourflip

    session = simulate_fourflip(seed=208)
    truth = session.base_physics()
    x = housing_field(truth, session.samples) @ truth.directions.T  # uT along each channel
    c2 = np.array([2e-4, -1.5e-4, 1e-4])  # 1 % (0.75 %, 0.5 %) output change at 50 uT
    rec = session.recording()
    rec = type(rec)(**{**rec.__dict__, "outputs": rec.outputs + truth.gains * c2 * x**2})
    result = calibrate_fourflip(rec, diagnose=True)
    assert result.diagnosis["effects"] == ["nonlinear_response"] and not result.diagnosis["unexplained"]
    sigma = np.array([c.direction_sigma_deg for c in result.channels])
    assert np.all(angle_deg(result.directions, truth.directions) < 3 * sigma)
    model = model_from_dict(result.to_json())
    probe = np.array([[-40.0, 0.0, 40.0]]).T * np.ones(3)  # field components, uT
    raw = truth.offsets + truth.gains * (probe + c2 * probe**2)
    recovered = np.column_stack([ch.response.field_component(raw[:, i])[0] for i, ch in enumerate(result.channels)])
    # tolerance from the fitted curve's own sigmas: relative x^k terms at |B| = 50 uT, evaluated at 40 uT
    params = result.effects[0]["parameters"]
    tol = [4 * 50 * np.hypot(params[f"{ch}.x2_rel_at_B"]["sigma"] * 0.8**2, params[f"{ch}.x3_rel_at_B"]["sigma"] * 0.8**3)
           for ch in session.channels]
    assert np.all(np.abs(recovered - probe) < np.array(tol)[None, :] + 0.02)
    assert model.channels == tuple(truth_name for truth_name in session.channels)


def test_fitting_bin_means_is_fitting_every_sample(write_session, monkeypatch):
    # two samples per bin (twice the width the fit uses) and an encoder error (the effect least linear in
    # the angle) to find: the fits on bin means must land where the fits on every sample do, far inside the sigmas
    from calibrate.diagnosis import forms
    from calibrate.fourflip import _mlfit
    from calibrate.fourflip.diagnosis import diagnose_fourflip
    from calibrate.fourflip.fit import physics_from_harmonics

    rec, _ = write_session(seed=200, effects=("encoder_error",), step_deg=0.05)
    start = physics_from_harmonics(rec, rec.field_ut, 1.0)

    def diagnose():
        return diagnose_fourflip(rec, start, candidates=["encoder_error", "nonlinear_response"])[1]

    monkeypatch.setattr(_mlfit, "BIN_DEG", 0.1)
    monkeypatch.setattr(forms, "TIME_BINS", 1000)  # 29 samples a time bin: the angle bins decide
    binned = diagnose()
    assert len(binned.bins.outputs) < 0.6 * len(rec.outputs)  # the fit ran on bin means
    monkeypatch.setattr(_mlfit.Bins, "of", classmethod(lambda cls, samples, outputs: cls(samples, outputs, 1.0)))
    every = diagnose()
    assert [e.name for e in binned.effects] == [e.name for e in every.effects] == ["encoder_error"]
    assert np.all(np.abs(binned.x - every.x) < 1e-2 * every.sigma)
    np.testing.assert_allclose(binned.sigma, every.sigma, rtol=1e-4)
    assert binned.chi2 == pytest.approx(every.chi2, rel=1e-7) and binned.dof == every.dof


def test_unexplained_structure_widens_the_files_sigmas_and_says_the_cost(write_session):
    """A field gradient the model lacks: the file's sigmas grow to the time-process ones, the diagnosis
    and the report say what that costs, and the runtime model read back from the file carries them."""
    from calibrate.fourflip._mlfit import fit_ml
    from calibrate.fourflip.fit import physics_from_harmonics
    from compass.calibration import from_dict
    from compass.sim.bench import BenchSamples

    rec, _ = write_session(seed=203, effects=("field_gradient",))
    result = calibrate_fourflip(rec, diagnose=True)
    d = result.diagnosis
    assert d["unexplained"] is True
    cost = d["unexplained_cost"]
    naive = fit_ml(BenchSamples.from_recording(rec), rec.outputs, rec.channels,
                   physics_from_harmonics(rec, result.field_ut, 1.0), np.array(d["noise_floor_per_channel"]))
    for ch, sigma_naive in zip(result.channels, naive.direction_sigma_deg()):
        entry = cost["direction_sigma_deg"][ch.name]
        assert entry["naive"] == pytest.approx(sigma_naive, rel=1e-3)
        assert ch.direction_sigma_deg == pytest.approx(entry["widened"]) and entry["widened"] >= entry["naive"]
        assert cost["direction_deg"][ch.name] == pytest.approx(np.sqrt(entry["widened"] ** 2 - entry["naive"] ** 2))
    assert max(cost["direction_deg"].values()) > 0 and cost["heading_deg"] > 0
    assert cost["heading_sigma_deg"]["widened"] > cost["heading_sigma_deg"]["naive"]
    assert "unexplained cost at runtime: heading sigma" in result.report()
    model = from_dict(result.to_json()).model
    assert np.degrees(np.sqrt(np.trace(model.direction_covariance, axis1=1, axis2=2))) == pytest.approx(
        [entry["widened"] for entry in cost["direction_sigma_deg"].values()], rel=1e-6)
    # each channel's joint covariance in the file is the widened one: its marginals are the file's (widened)
    # sigmas, and the runtime's heading sigma from it is the diagnosis's widened one (but for the offsets'
    # correlation across channels, which the file does not keep)
    for c, joint in enumerate(model.joint_covariance):
        np.testing.assert_allclose(joint[:3, :3], model.direction_covariance[c], rtol=1e-9, atol=1e-12 * joint[0, 0])
        assert np.sqrt(np.diag(joint)[3:]) == pytest.approx(model.response_sigma[c], rel=1e-12)
    from compass.frames import r_world_from_housing, world_field

    rot = r_world_from_housing(np.arange(0.0, 360.0, 5.0), 0.0, 0.0)
    fields = rot.apply(world_field(model.dip_deg, model.field_norm), inverse=True)
    own = model.calibration_uncertainty
    runtime = np.sqrt(np.mean([own.heading_sigma_deg(m, b) ** 2 for m, b in zip(rot.as_matrix(), fields)]))
    assert runtime == pytest.approx(cost["heading_sigma_deg"]["widened"], rel=0.01)
    # the runtime's heading sigma (compass attitude / live) carries it: against the same file with the
    # naive fit's sigmas (its joint covariance and their marginals), every level sample's heading sigma is larger
    from compass.attitude import solve_attitude

    joint = naive.channel_covariance()
    naive_model = replace(model, direction_covariance=naive.direction_covariance, joint_covariance=tuple(joint),
                          response_sigma=np.sqrt(np.diagonal(joint, axis1=1, axis2=2)[:, 3:]))
    raw = rec.outputs[::40]
    wide = solve_attitude(model, raw, level=True).heading_sigma_deg
    plain = solve_attitude(naive_model, raw, level=True)
    assert np.all(wide > plain.heading_sigma_deg)
    # and compass live / the replay / run_filter (issue 24): the same stream, every row's heading sigma larger
    import io

    from compass.filter import FilterConfig, run_filter
    from compass.live import CSV_COLUMNS, LiveSession
    from compass.replay import replay
    from compass.sim.device import simulate_device

    t = np.arange(0.0, 8.0, 0.01)
    s = simulate_device(model, t, seed=3)
    sigmas = []
    for m in (model, naive_model):
        out = io.StringIO()
        replay(LiveSession(m, out=out), t, s.raw, s.accel, s.gyro)
        rows = np.array([line.split(",") for line in out.getvalue().splitlines()[2:]], dtype=float)
        sigmas.append(rows[:, CSV_COLUMNS.index("heading_sigma_deg")])
        track = run_filter(t, s.accel, s.gyro, m.field(s.raw)[0], FilterConfig.from_model(m))
        np.testing.assert_allclose(track.heading_sigma_deg[np.isfinite(track.heading_deg)], sigmas[-1], atol=5.1e-4)
    assert len(sigmas[0]) > 0.9 * len(t) and np.all(sigmas[0] > sigmas[1])


def test_clean_recording_keeps_its_sigmas(write_session):
    """Explained: no cost, and the file's sigmas are the fit's own (nothing widened)."""
    from calibrate.fourflip._mlfit import fit_ml
    from calibrate.fourflip.fit import physics_from_harmonics
    from compass.sim.bench import BenchSamples

    rec, _ = write_session(seed=201)
    result = calibrate_fourflip(rec, diagnose=True)
    assert result.diagnosis["unexplained"] is False and "unexplained_cost" not in result.diagnosis
    # asked across blocks of time too (issue 24): white noise passes the family test, nothing is widened
    assert result.diagnosis["block_test"]["p_value"] > result.diagnosis["block_test"]["threshold"]
    assert "wander_cost" not in result.diagnosis and not any("wander" in w for w in result.warnings)
    naive = fit_ml(BenchSamples.from_recording(rec), rec.outputs, rec.channels,
                   physics_from_harmonics(rec, result.field_ut, 1.0), np.array(result.noise))
    assert [c.direction_sigma_deg for c in result.channels] == pytest.approx(naive.direction_sigma_deg(), rel=1e-3)


def test_a_wander_under_a_named_drift_widens_the_explained_fit(write_session):
    """An offset random walk (0.004 uT a sample, outside the vocabulary) the loop calls explained with an
    offset drift named: below the floor in each sample, but its 10 s block sums fail the block test (the band
    family and the walk's likelihood-ratio test by Bonferroni, p at most 0.01), so the file's sigmas are widened
    for a random walk of each channel's offset and the
    diagnosis, the warnings and the report say so; the verdict and the named drift stay.  The naive sigmas miss
    the error (a channel's direction over 2.5 naive sigmas off: why it matters); the widened ones cover it (RMS
    over the channels 0.86), and the walk's stated size is the simulated one's (0.004 uT a 0.5 s sample: 0.0057 uT
    per square root of a second) within its noise (calibrate/diagnosis/walk.py; docs/benchmarks.md).  The walk's
    draw (seed 7) fires both tests beyond every draw of their nulls (bands 10/2001, walk 1/2001: the block test
    0.001)."""
    from compass.calibration import from_dict

    rec, truth = write_session(seed=201)
    rng = np.random.default_rng(7)
    walk = np.cumsum(rng.normal(scale=0.004, size=rec.outputs.shape), axis=0) * np.array(truth["gains_per_ut"])
    result = calibrate_fourflip(replace(rec, outputs=rec.outputs + walk), diagnose=True)
    d = result.diagnosis
    assert d["unexplained"] is False and "offset_drift" in d["effects"]
    assert d["block_test"]["p_value"] <= d["block_test"]["threshold"] == 0.01
    cost = d["wander_cost"]
    err = angle_deg(result.directions, truth["directions"])
    naive = np.array([cost["direction_sigma_deg"][ch]["naive"] for ch in rec.channels])
    assert np.max(err / naive) > 2.5, err / naive
    wide = np.array([cost["direction_sigma_deg"][ch]["widened"] for ch in rec.channels])
    assert np.sqrt(np.mean((err / wide) ** 2)) < 1.6, err / wide
    assert "random walk" in cost["method"]
    walk_ut = np.array(list(cost["walk_fieldunit_per_sqrt_s"].values()))
    assert np.all((walk_ut > 0.5 * 0.004 * np.sqrt(2)) & (walk_ut < 2.0 * 0.004 * np.sqrt(2))), walk_ut
    for ch in result.channels:
        entry = cost["direction_sigma_deg"][ch.name]
        assert ch.direction_sigma_deg == pytest.approx(entry["widened"]) and entry["widened"] >= entry["naive"]
    assert cost["heading_sigma_deg"]["widened"] > cost["heading_sigma_deg"]["naive"]
    assert any("wander beyond white noise" in w for w in result.warnings)
    assert "wander cost at runtime: heading sigma" in result.report()
    model = from_dict(result.to_json()).model  # the runtime reads the widened directions' covariance
    assert np.degrees(np.sqrt(np.trace(model.direction_covariance, axis1=1, axis2=2))) == pytest.approx(
        [cost["direction_sigma_deg"][ch]["widened"] for ch in rec.channels], rel=1e-6)


@pytest.mark.parametrize("ratio, verdict", [(2.5, False), (6.0, None)])
def test_coarse_adc_recording_is_clean_and_says_the_adc_limits_it(write_session, ratio, verdict):
    """Outputs rounded to a code step 2.5 or 6 times the noise: Sheppard's floor, nothing claimed, the ADC
    named; at 6 the rounding is not dithered (a sawtooth of the field), so the residual is not judged."""
    rec, truth = write_session(seed=205)
    step = ratio * np.array(truth["noise"])
    rec = replace(rec, outputs=np.round(rec.outputs / step) * step)
    result = calibrate_fourflip(rec, diagnose=True)
    d = result.diagnosis
    assert d["effects"] == [] and d["unexplained"] is verdict
    assert ("not_judged" in d) is (verdict is None)
    expected = np.sqrt(np.array(truth["noise"]) ** 2 + step**2 / 12)
    assert d["noise_floor_per_channel"] == pytest.approx(expected, rel=0.12)
    assert any("ADC" in w for w in result.warnings)
    assert result.extra["quantisation"]["step"] == pytest.approx(dict(zip(rec.channels, step)), rel=1e-6)


def test_one_offset_step_is_named_and_its_cost_covers_the_error(write_session):
    """One channel's offset jumping 0.4 uT within the third flip (outside the vocabulary): unexplained, and
    the diagnosis names the step (channel, size, time within a 10 s block) instead of a process in time;
    the widened sigmas cover the directions' errors and the report says what it took the structure for."""
    rec, truth = write_session(seed=201)
    at_s = float(np.median(rec.t_s[rec.flip_index == 2]))
    outputs = rec.outputs.copy()
    outputs[rec.t_s >= at_s, 1] += 0.4 * truth["gains_per_ut"][1]
    result = calibrate_fourflip(replace(rec, outputs=outputs), diagnose=True)
    d = result.diagnosis
    assert d["unexplained"] is True
    step = d["unexplained_cost"]["offset_step"]
    assert step["channel"] == rec.channels[1] and abs(step["t_s"] - at_s) <= 10.0
    assert step["size_field"] == pytest.approx(0.4, abs=0.05)
    assert step["size"] == pytest.approx(step["size_field"] * truth["gains_per_ut"][1], rel=0.05)
    sigma = np.array([c.direction_sigma_deg for c in result.channels])
    err = angle_deg(result.directions, truth["directions"])
    assert np.all(err < 3.0 * sigma), (err, sigma)
    assert err[1] > 5.0 * d["unexplained_cost"]["direction_sigma_deg"][rec.channels[1]]["naive"]  # the step matters
    assert f"one step of {rec.channels[1]}'s offset" in result.report()


@pytest.mark.parametrize("seed", [206, 207])
def test_rate_memory_is_taken_as_locked_to_the_turn_and_its_cost_is_honest(write_session, seed):
    """Rate memory (outside the vocabulary: each channel's offset +-0.08 uT by the sign of its field's change,
    a square wave locked to the turn): unexplained, its structure taken as locked to the turn (the locked
    columns wired through the four-flip), and the widened sigmas honest for what a user copies: every
    direction and gain within 3.5 stated sigmas, and the gains' errors not lost in an inflated sigma (RMS of
    gain err/sig over the three channels above 0.2: chi-square with 3 dof below 0.12 has probability about
    1 %; the propagated move's noise made it 0.01-0.1), the heading sigma at most 1.5 times the naive one
    (the locked structure moves the directions by about their noise: 1.04-1.09 on tools/bench_loop.py's rate
    memory seeds 40-43, 1.2-26 when the nearly absorbed combinations were propagated)."""
    rec, truth = write_session(seed=seed)
    clean = simulate_fourflip(seed=seed, noise_ut=0.0)
    gains = np.array(truth["gains_per_ut"])
    rate = np.gradient(clean.outputs, axis=0)
    rate[np.r_[True, rec.flip_index[1:] != rec.flip_index[:-1]]] = 0.0
    result = calibrate_fourflip(replace(rec, outputs=rec.outputs + 0.08 * np.sign(rate) * gains), diagnose=True)
    d = result.diagnosis
    assert d["unexplained"] is True and "locked to the turntable's turn" in d["unexplained_cost"]["method"]
    sigma = np.array([c.direction_sigma_deg for c in result.channels])
    err = angle_deg(result.directions, truth["directions"])
    assert np.all(err < 3.5 * sigma), (err, sigma)
    gain_ratio = np.array([(c.response.gain - g) / c.gain_sigma for c, g in zip(result.channels, gains)])
    assert np.all(np.abs(gain_ratio) < 3.5) and np.sqrt(np.mean(gain_ratio**2)) > 0.2, gain_ratio
    heading = d["unexplained_cost"]["heading_sigma_deg"]
    assert heading["widened"] < 1.5 * heading["naive"], heading


def test_an_unexplained_wander_widens_the_directions_not_the_offsets_beyond_its_mean(write_session):
    """An offset random walk strong enough to be unexplained (0.01 uT a sample): the process model widens the
    directions, but the offsets the file states are the session's mean levels, which the walk's own mean moves
    with the fit: their sigmas stay near the noise's and cover their error from that level (RMS err/sig within
    0.3-3 over the three channels; taken about zero, as before, the offsets' sigmas were 50-100 times their error
    here and the level housing's heading sigma 0.79 deg for 0.14)."""
    rec, truth = write_session(seed=201)
    rng = np.random.default_rng(1)
    walk = np.cumsum(rng.normal(scale=0.01, size=rec.outputs.shape), axis=0) * np.array(truth["gains_per_ut"])
    result = calibrate_fourflip(replace(rec, outputs=rec.outputs + walk), diagnose=True)
    d = result.diagnosis
    assert d["unexplained"] is True and "mean level over the session" in d["unexplained_cost"]["method"]
    cost = d["unexplained_cost"]
    assert all(v["widened"] > 3.0 * v["naive"] for v in cost["direction_sigma_deg"].values())
    level = np.array(truth["offsets"]) + walk.mean(axis=0)
    ratio = (np.array([c.response.offset for c in result.channels]) - level) / [c.offset_sigma for c in result.channels]
    assert 0.3 < np.sqrt(np.mean(ratio**2)) < 3.0, ratio
    assert cost["heading_sigma_deg"]["widened"] < 0.3  # deg: the directions' part, not a wander's mean
