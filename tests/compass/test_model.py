import json
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.calibration import FORMAT
from compass.filter import FilterConfig
from compass.model import SensorModel
from compass.response import CubicResponse, LinearResponse, TableResponse
from compass.calibration import load as load_calibration, model_from_dict
from compass.calibration import model_to_dict


def skewed_directions():
    """Three unit axes 10-25 degrees away from orthogonal."""
    a = np.array([[1.0, 0.0, 0.0], [np.sin(np.radians(20)), np.cos(np.radians(20)), 0.0],
                  [0.3, -0.2, 0.93]])
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def linear_model(directions, noise=None, field_ut=50.0, **kwargs):
    c = len(directions)
    rng = np.random.default_rng(7)
    responses = tuple(LinearResponse(2.5 + 0.1 * rng.normal(), 0.02 * (1 + 0.1 * rng.normal()), (-field_ut, field_ut))
                      for _ in range(c))
    return SensorModel(tuple(f"v{i + 1}" for i in range(c)), np.asarray(directions), responses, field_ut,
                       field_ut, 60.0, None if noise is None else np.full(c, noise), **kwargs)


def outputs(model, field_h):
    x = np.asarray(field_h) @ model.unit_directions.T
    return np.stack([r.output(x[:, c]) for c, r in enumerate(model.responses)], axis=-1)


def random_fields(n, magnitude=50.0, seed=0):
    return Rotation.random(n, random_state=seed).apply([magnitude, 0.0, 0.0])


def test_non_orthogonal_axes_are_solved_not_assumed_orthogonal():
    model = linear_model(skewed_directions())
    b = random_fields(500)
    got, ok = model.field(outputs(model, b))
    np.testing.assert_allclose(got, b, atol=1e-9)
    assert ok.all()
    # the seed's runtime step, sum_c a_c cos(beta_c), is only right for orthonormal axes
    x = b @ model.unit_directions.T
    seed = x @ model.unit_directions
    assert np.max(np.linalg.norm(seed - b, axis=1)) > 5.0


def test_more_channels_weighted_least_squares_and_field_covariance():
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(5, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    noise_v = 0.003
    model = linear_model(directions, noise=noise_v)
    b_true = np.array([20.0, -30.0, 35.0])
    clean = outputs(model, np.tile(b_true, (20000, 1)))
    got, _ = model.field(clean + noise_v * rng.normal(size=clean.shape))
    np.testing.assert_allclose(got.mean(axis=0), b_true, atol=5 * np.sqrt(np.diag(model.field_covariance(b_true)) / 20000).max())
    empirical = np.cov(got.T)
    predicted = model.field_covariance(b_true)
    # sample covariance of 20000 draws: relative error of a variance ~ sqrt(2 / n) = 1 %
    np.testing.assert_allclose(np.diag(empirical), np.diag(predicted), rtol=0.05)


def test_a_zero_noise_floor_weighs_channels_equally_and_the_filter_refuses_it():
    rng = np.random.default_rng(4)
    directions = rng.normal(size=(5, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    zero = linear_model(directions, noise=0.0)
    unknown = linear_model(directions)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no division by the zero floor
        np.testing.assert_allclose(zero.solver, unknown.solver)
        b = random_fields(50)
        np.testing.assert_allclose(zero.field(outputs(zero, b))[0], b, atol=1e-9)
    with pytest.raises(ValueError, match="no noise_floor above zero"):
        FilterConfig.from_model(zero)


def test_field_covariance_adds_calibration_uncertainty():
    cov = np.array([np.diag(1e-6 * (1.0 - np.eye(3)[c])) for c in range(3)])  # tangent: none along a_c
    plain = linear_model(np.eye(3), noise=0.002)
    with_cal = linear_model(np.eye(3), noise=0.002, direction_covariance=cov,
                            response_sigma=np.tile([1e-4, 1e-5], (3, 1)))
    b = np.array([0.0, 50.0, 0.0])
    added = np.diag(with_cal.field_covariance(b) - plain.field_covariance(b))
    # X and Z channels see B . da with da_y ~ 1e-3 rad: 50^2 * 1e-6; offset and gain errors on every channel
    gain = np.array([r.gain for r in with_cal.responses])
    expected = (1e-4**2 + (b**2) * 1e-5**2) / gain**2 + np.array([2500e-6, 0.0, 2500e-6])
    np.testing.assert_allclose(added, expected, rtol=1e-9)


def test_nonlinear_responses_are_inverted_monotonically_and_out_of_range_is_flagged():
    x_table = np.linspace(-60, 60, 25)
    v_table = 2.5 + 0.02 * 80 * np.tanh(x_table / 80)
    responses = (CubicResponse(2.5, 0.02, (-60, 60), cubic=-2e-5),
                 TableResponse(2.5, 0.0175, (-60, 60), x_table=tuple(x_table), v_table=tuple(v_table)),
                 LinearResponse(2.5, 0.02, (-60, 60)))
    model = SensorModel(("a", "b", "c"), skewed_directions(), responses, 50.0, 50.0, 60.0)
    b = random_fields(300)
    got, ok = model.field(outputs(model, b))
    np.testing.assert_allclose(got, b, atol=1e-3)  # 2049-knot table: interpolation error << noise
    assert ok.all()
    far, ok_far = model.field(outputs(model, np.array([[80.0, 0.0, 0.0]])))
    assert not ok_far[0]  # the cubic channel (along X) read beyond its range: its curve is extrapolated
    # a linear channel beyond its range is the same line: not flagged, but beyond_range says so
    x, ok_line = model.components(outputs(model, np.array([[0.0, 0.0, 80.0]])))
    assert ok_line.all() and responses[2].beyond_range(x[0, 2]) and not responses[0].beyond_range(x[0, 0])


def test_tumble_form_is_the_same_model():
    rng = np.random.default_rng(5)
    q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    soft = q @ np.diag([1.1, 0.9, 1.05]) @ q.T
    hard = np.array([12.0, -7.0, 3.0])
    rot = Rotation.from_rotvec([0.02, -0.01, 0.03]).as_matrix()
    doc = {"format": FORMAT, "model": "tumble", "hard_iron": hard.tolist(), "soft_iron": soft.tolist(),
           "field_norm": 50.0, "mag_to_accel": rot.tolist(), "field_ut": 50.0, "dip_deg": 60.0,
           "diagnosis": {"noise_floor": 0.2}}
    model = model_from_dict(doc)
    assert model.channels == ("mx", "my", "mz") and model.form == "tumble"
    b_h = random_fields(100)  # in the accelerometer (housing) frame
    raw = hard + (rot.T @ b_h.T).T @ np.linalg.inv(soft).T  # m = soft (raw - hard), b_h = rot m
    got, ok = model.field(raw)
    np.testing.assert_allclose(got, b_h, atol=1e-9)
    assert ok.all()
    np.testing.assert_allclose(model.noise, [0.2] * 3)
    back = model_from_dict(json.loads(json.dumps(model_to_dict(model))))
    np.testing.assert_allclose(back.field(raw)[0], b_h, atol=1e-9)


def test_round_trip_through_json():
    model = linear_model(skewed_directions(), noise=0.003, direction_covariance=np.tile(np.eye(3) * 1e-8, (3, 1, 1)))
    back = model_from_dict(json.loads(json.dumps(model_to_dict(model))))
    assert back.channels == model.channels
    np.testing.assert_allclose(back.solver, model.solver)
    np.testing.assert_allclose(back.field_covariance([1.0, 2.0, 3.0]), model.field_covariance([1.0, 2.0, 3.0]))


@pytest.mark.parametrize("change, message", [
    ({"format": "compass-calibration/2"}, "unknown calibration format 'compass-calibration/2'"),
    ({"format": None}, "unknown calibration format None"),
    ({"model": "ellipsoid"}, "unknown calibration model"),
    ({"channels": {}}, "expected 'channels'"),
])
def test_from_json_rejects_unknown_forms(change, message):
    doc = model_to_dict(linear_model(np.eye(3))) | change
    with pytest.raises(ValueError, match=message):
        model_from_dict(doc)


def test_bad_channels_and_geometry_are_refused():
    doc = model_to_dict(linear_model(np.eye(3)))
    doc["channels"]["v2"]["direction"] = [0.0, 2.0, 0.0]
    with pytest.raises(ValueError, match="channel 'v2': 'direction' must be a unit vector"):
        model_from_dict(doc)
    with pytest.raises(ValueError, match="do not span three dimensions"):
        linear_model(np.array([[1.0, 0, 0], [0, 1.0, 0], [np.sqrt(0.5), np.sqrt(0.5), 0]]))
    with pytest.raises(ValueError, match="at least 3 channels"):
        SensorModel(("a", "b"), np.eye(3)[:2], (LinearResponse(0.0, 1.0),) * 2, 1.0)


def test_from_file_names_the_file(tmp_path):
    bad = tmp_path / "cal.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="cal.json: not a JSON calibration file"):
        load_calibration(bad).model
    bad.write_text(json.dumps({"format": "other/1"}))
    with pytest.raises(ValueError, match="cal.json: unknown calibration format 'other/1'"):
        load_calibration(bad).model
    with pytest.raises(ValueError, match="missing.json: cannot read"):
        load_calibration(tmp_path / "missing.json").model


def test_runtime_takes_readings_back_to_the_calibrated_temperature():
    # a four-flip calibration that found the temperature effect, then the true sensor read at 10 and
    # 45 degC (the recording spanned 22-32 degC) in 300 known fields
    from calibrate import calibrate_fourflip
    from compass.sim.fourflip import simulate_fourflip

    session = simulate_fourflip(seed=0, effects=("temperature",))
    d = calibrate_fourflip(session.recording(), diagnose=True).to_json()
    model = model_from_dict(d)
    effect = next(e for e in d["effects"] if e["name"] == "temperature")
    b = np.random.default_rng(0).normal(size=(300, 3))
    b *= session.truth["field_ut"] / np.linalg.norm(b, axis=1, keepdims=True)

    def rms_error(temp, compensate):
        field = model.field(session.outputs_at(b, temp), temp if compensate else None)[0]
        return float(np.sqrt(np.mean(np.sum((field - b) ** 2, axis=1))))

    at_reference = rms_error(effect["reference"]["temp_c"], True)
    for temp in (10.0, 45.0):
        dt = temp - effect["reference"]["temp_c"]
        p = effect["parameters"]
        # what the effect's own sigmas allow (offset in field units, relative gain at |x| ~ |B| / sqrt 3)
        var = sum((p[f"{c}.offset_fieldunit_per_degc"]["sigma"] * dt) ** 2
                  + (p[f"{c}.gain_rel_per_degc"]["sigma"] * dt) ** 2 * session.truth["field_ut"] ** 2 / 3.0
                  for c in model.channels)
        allowed = 3.0 * np.sqrt(var + at_reference**2)
        assert rms_error(temp, True) < allowed < 0.2 * rms_error(temp, False)


def temperature_effect(reference, spelling):
    """A temperature effect: per channel (name, offset change, relative gain change) in the given keys."""
    params = {f"{c}.{k}": {"value": v} for c, dv, g in spelling[1]
              for k, v in ((spelling[0][0], dv), (spelling[0][1], g))}
    return {"name": "temperature", "parameters": params, **({"reference": {"temp_c": reference}} if reference else {})}


def test_temperature_compensation_inverts_its_model_in_every_spelling():
    # v = V0 + dV dT + (1 + g dT)(v_ref - V0), in output units, whatever the fit's spelling
    v0, dv, g = np.array([5.0, -3.0, 2.0]), np.array([0.2, -0.1, 0.05]), np.array([1e-3, -2e-3, 0.0])
    soft = np.array([[1.1, 0.05, 0.0], [0.05, 0.9, 0.02], [0.0, 0.02, 1.0]])
    tumble = {"format": FORMAT, "model": "tumble", "hard_iron": v0.tolist(), "soft_iron": soft.tolist(),
              "field_norm": 50.0, "field_ut": 48.0, "mag_to_accel": None, "dip_deg": 60.0,
              "effects": [temperature_effect(25.0, (("hard_iron_per_degc", "scale_rel_per_degc"),
                                                    list(zip(("mx", "my", "mz"), dv, g))))]}
    gains = np.array([0.02, 0.05, 0.5])  # channel form with gains far from 1: output units per field unit
    channels = {"format": FORMAT, "dip_deg": 60.0, "field_ut": 50.0, "channels": {
        c: {"direction": d, "response": {"model": "linear", "offset": o, "gain": k}}
        for c, d, o, k in zip(("a", "b", "c"), np.eye(3).tolist(), v0, gains)}}
    platform = dict(channels, effects=[temperature_effect(25.0, (("offset_per_degc", "gain_rel_per_degc"),
                                                                 list(zip("abc", dv, g))))])
    fourflip = dict(channels, effects=[temperature_effect(25.0, (("offset_fieldunit_per_degc", "gain_rel_per_degc"),
                                                                 list(zip("abc", dv / gains, g))))])
    dt = 40.0 - 25.0
    for d in (tumble, platform, fourflip):
        model = model_from_dict(d)
        again = model_from_dict(model_to_dict(model))  # written back in the runtime's spelling
        b = np.random.default_rng(1).normal(0.0, 30.0, (5, 3))
        v_ref = model.zero_outputs + (b @ model.unit_directions.T) * model.gains
        v = v0 + dv * dt + (1 + g * dt) * (v_ref - v0)
        for m in (model, again):
            np.testing.assert_allclose(m.field(v, 40.0)[0], b, atol=1e-9)
            assert np.max(np.abs(m.field(v)[0] - b)) > 0.1  # ignored without temp_c
    # 600 degC below the reference mx's gain factor 1 + 1e-3 dT is negative: out of range, not mirrored
    _, valid = model_from_dict(tumble).temperature.to_reference(v, 25.0 - 600.0, v0)
    assert valid.tolist() == [False, True, True]


def test_temperature_effect_without_reference_or_with_unknown_keys():
    d = {"format": FORMAT, "dip_deg": 60.0, "field_ut": None, "channels": {
        c: {"direction": e, "response": {"model": "linear", "offset": 0.0, "gain": 1.0}}
        for c, e in zip("abc", np.eye(3).tolist())}}
    d["effects"] = [temperature_effect(None, (("offset_per_degc", "gain_rel_per_degc"), [("a", 0.1, 0.0)]))]
    model = model_from_dict(d)  # an older file: loads, usable without temp_c
    assert model.temperature.reference_c is None and model.field([[1.0, 0.0, 0.0]])[0].shape == (1, 3)
    with pytest.raises(ValueError, match="reference temperature"):
        model.field([[1.0, 0.0, 0.0]], 30.0)
    d["effects"] = [temperature_effect(20.0, (("offset_per_degc", "gain_rel_per_degc"), [("x", 0.1, 0.0)]))]
    with pytest.raises(ValueError, match="x.offset_per_degc.*name no channel"):
        model_from_dict(d)
