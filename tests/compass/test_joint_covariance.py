"""A four-flip channel's joint direction, offset and gain covariance in the file (``joint_covariance``) and the
runtime's heading sigma: the four-flip's own number when the key is there, today's when it is not, a clear
refusal when it is malformed."""

import json

import numpy as np
import pytest

from calibrate.diagnosis.robust import heading_sigma_deg
from compass.calibration import CalibrationFileError, dumps, from_dict, load
from compass.cli import main
from compass.frames import r_world_from_housing, world_field
from compass.iron_uncertainty import with_calibration_sigma, with_calibration_sigma_many

N_HEADINGS = 72


@pytest.fixture(scope="module")
def warm_up(tmp_path_factory):
    """A four-flip with a warm-up during the first flip (the loop fits it: each channel's offset tied to its
    direction), calibrated; its file's document."""
    from calibrate import calibrate_fourflip
    from compass.io.fourflip import read_fourflip
    from compass.sim.fourflip import simulate_fourflip, write_fourflip

    path, _ = write_fourflip(simulate_fourflip(seed=200, effects=("offset_drift",)),
                             tmp_path_factory.mktemp("warm") / "rec.csv")
    result = calibrate_fourflip(read_fourflip(path), diagnose=True)
    assert "offset_drift" in result.diagnosis["effects"]
    return json.loads(dumps(result.to_json()))


def _assert_paths_agree(model):
    """The scalar and the vectorised (run_filter's) heading sigma with the calibration's own agree at tilted
    attitudes; returns those attitudes' housing fields and the calibration's own uncertainty."""
    rot = r_world_from_housing(np.arange(0.0, 360.0, 30.0), 7.0, -4.0)
    fields = rot.apply(world_field(model.dip_deg, model.field_norm), inverse=True)
    own = model.calibration_uncertainty
    scalar = [with_calibration_sigma(0.3, own, m, b) for m, b in zip(rot.as_matrix(), fields)]
    np.testing.assert_allclose(with_calibration_sigma_many(np.full(len(fields), 0.3), own, rot.as_matrix(), fields),
                               scalar, rtol=1e-9)
    return fields, own


def _runtime_rms_deg(model) -> float:
    """RMS over level headings of the runtime's calibration heading sigma (what live adds), degrees."""
    rot = r_world_from_housing(np.arange(N_HEADINGS) * 360.0 / N_HEADINGS, 0.0, 0.0)
    fields = rot.apply(world_field(model.dip_deg, model.field_norm), inverse=True)
    own = model.calibration_uncertainty
    return float(np.sqrt(np.mean([own.heading_sigma_deg(m, b) ** 2 for m, b in zip(rot.as_matrix(), fields)])))


def _four_flip_rms_deg(model, joint=None) -> float:
    """The four-flip's own heading sigma (:func:`calibrate.diagnosis.robust.heading_sigma_deg`) from the file's
    numbers: with each channel's joint covariance, or (None) its sigmas taken as independent."""
    return heading_sigma_deg(model.unit_directions, model.direction_covariance, model.response_sigma**2, model.gains,
                             model.dip_deg, model.field_norm, N_HEADINGS, channel_covariance=joint)


def test_the_files_joint_covariance_has_the_files_sigmas_as_marginals(warm_up):
    for name, ch in warm_up["channels"].items():
        joint = np.array(ch["joint_covariance"])
        np.testing.assert_allclose(joint[:3, :3], ch["direction_covariance"], rtol=1e-9, atol=1e-12 * joint[0, 0])
        assert np.sqrt(np.diag(joint)[3:]) == pytest.approx([ch["response_sigma"]["offset"],
                                                             ch["response_sigma"]["gain"]], rel=1e-12)
        assert abs(joint[0:3, 3]).max() > 0  # the warm-up ties the offset to the direction


def test_the_runtime_heading_sigma_with_the_key_is_the_four_flips_own(warm_up):
    """Reference relation: compass live's calibration sigma (per sample, RMS over level headings) is the four-flip's
    own heading sigma from the channels' joint covariances (an implementation in calibrate, not the runtime's);
    the vectorised path (run_filter) and the attitude solver's field covariance give the same numbers."""
    model = from_dict(warm_up).model
    joint = np.stack(model.joint_covariance)
    runtime = _runtime_rms_deg(model)
    assert runtime == pytest.approx(_four_flip_rms_deg(model, joint), rel=1e-9)
    assert abs(runtime / _four_flip_rms_deg(model) - 1.0) > 0.02  # the correlations matter here (4 %)
    fields, own = _assert_paths_agree(model)
    from dataclasses import replace

    quiet = replace(model, noise=None)
    np.testing.assert_allclose(quiet.field_covariance(fields), own.covariance(fields), rtol=1e-12, atol=1e-18)


def test_a_file_without_the_key_gives_todays_number(warm_up):
    old = json.loads(json.dumps(warm_up))
    for ch in old["channels"].values():
        del ch["joint_covariance"]
    model = from_dict(old).model
    assert model.joint_covariance is None
    assert _runtime_rms_deg(model) == pytest.approx(_four_flip_rms_deg(model), rel=1e-9)
    # a channel without it beside channels with it: that channel's three independent, the others' joint
    mixed = json.loads(json.dumps(warm_up))
    first = next(iter(mixed["channels"]))
    del mixed["channels"][first]["joint_covariance"]
    model = from_dict(mixed).model
    joint = np.stack([np.diag(np.r_[0.0, 0.0, 0.0, model.response_sigma[0] ** 2])] + list(model.joint_covariance[1:]))
    joint[0, :3, :3] = model.direction_covariance[0]
    assert model.joint_covariance[0] is None
    assert _runtime_rms_deg(model) == pytest.approx(_four_flip_rms_deg(model, joint), rel=1e-9)


def _bad(doc, how):
    """``doc`` with its first channel's joint covariance spoilt ``how``."""
    out = json.loads(json.dumps(doc))
    ch = next(iter(out["channels"].values()))
    joint = np.array(ch["joint_covariance"])
    if how == "shape":
        ch["joint_covariance"] = joint[:4, :4].tolist()
    elif how == "non-finite":
        joint[3, 3] = np.inf
        ch["joint_covariance"] = joint.tolist()
    elif how == "asymmetric":
        joint[0, 3] += 0.5 * np.sqrt(joint[0, 0] * joint[3, 3])
        ch["joint_covariance"] = joint.tolist()
    elif how == "not PSD":  # the offset and gain correlated beyond 1
        joint[3, 4] = joint[4, 3] = 1.5 * np.sqrt(joint[3, 3] * joint[4, 4])
        ch["joint_covariance"] = joint.tolist()
    elif how == "not the file's sigmas":
        ch["joint_covariance"] = (4.0 * joint).tolist()
    elif how == "text":
        ch["joint_covariance"] = "diagonal"
    return out


@pytest.mark.parametrize("how, words", [
    ("shape", "must be 5x5 nested lists of numbers"), ("non-finite", "must be finite"),
    ("asymmetric", "must be symmetric"), ("not PSD", "must be a covariance (positive semi-definite)"),
    ("not the file's sigmas", "must have the channel's direction_covariance and response_sigma as its marginals"),
    ("text", "must be 5x5 nested lists of numbers")])
def test_a_malformed_key_is_refused_naming_the_file_and_key(warm_up, tmp_path, capsys, how, words):
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(_bad(warm_up, how)))  # json writes inf as Infinity, as a careless tool would
    name = next(iter(warm_up["channels"]))
    with pytest.raises(CalibrationFileError, match="joint_covariance") as info:
        load(cal)
    assert str(info.value).startswith(f"{cal}: channel '{name}': 'joint_covariance' ") and words in str(info.value)
    rec = tmp_path / "rec.csv"
    rec.write_text(",".join(warm_up["channels"]) + "\n1,2,3\n")
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "att.csv")]) == 2
    err = capsys.readouterr().err
    assert str(cal) in err and "joint_covariance" in err and words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "att.csv").exists()


def test_the_model_refuses_a_joint_covariance_that_is_not_its_sigmas(warm_up):
    """``SensorModel`` keeps the invariant too: its sigmas replaced without the joint covariance is an error
    (a stale joint covariance would silently hide the new sigmas from the runtime)."""
    from dataclasses import replace

    model = from_dict(warm_up).model
    with pytest.raises(ValueError, match="joint_covariance must have the channel's direction_covariance"):
        replace(model, response_sigma=2.0 * model.response_sigma)
    assert replace(model, response_sigma=2.0 * model.response_sigma, joint_covariance=None).joint_covariance is None


def test_an_installed_model_keeps_the_correlations_and_its_marginals_are_its_sigmas(warm_up):
    """Through an installation (iron and its covariance, an alignment) each channel's joint covariance goes by the
    same map as its sigmas: its marginals are the installed sigmas (the model checks), and with no iron and no
    alignment the heading sigma is the bench's."""
    from compass.installed import installed_model

    base = from_dict(warm_up).model
    cov = np.diag([0.05**2] * 3 + [0.002**2] * 6)
    turn = r_world_from_housing(30.0, 2.0, -1.0).as_matrix().reshape(3, 3)
    model = installed_model(base, [1.0, -0.5, 0.2], np.eye(3) + 0.01 * np.diag([1.0, -1.0, 0.5]), cov, turn)
    assert all(j is not None for j in model.joint_covariance)
    for c in range(3):
        np.testing.assert_allclose(model.joint_covariance[c][:3, :3], model.direction_covariance[c], rtol=1e-9,
                                   atol=1e-12 * model.direction_covariance[c].max())
    same = installed_model(base, np.zeros(3), np.eye(3))
    assert _runtime_rms_deg(same) == pytest.approx(_runtime_rms_deg(base), rel=1e-9)


@pytest.fixture(scope="module")
def cubic(tmp_path_factory):
    """A four-flip of a saturating sensor (the loop fits a cubic), calibrated; its file's document."""
    from calibrate import calibrate_fourflip
    from compass.io.fourflip import read_fourflip
    from compass.sim.fourflip import simulate_fourflip, write_fourflip

    path, _ = write_fourflip(simulate_fourflip(seed=200, effects=("nonlinear_response",)),
                             tmp_path_factory.mktemp("cubic") / "rec.csv")
    result = calibrate_fourflip(read_fourflip(path), diagnose=True)
    assert "nonlinear_response" in result.diagnosis["effects"]
    return result, json.loads(dumps(result.to_json()))


def _curves(model) -> np.ndarray:
    return np.array([[r.quadratic, r.cubic, r.quintic] for r in model.responses])


def test_a_file_with_a_curve_round_trips_its_8x8_block(cubic):
    """The file's ``curve_joint_covariance`` of a cubic channel is the fit's 8 x 8 (direction, offset, gain,
    quadratic, cubic, quintic in the response's units), its ``joint_covariance`` the top-left 5 x 5; read into the
    model as the 8 x 8, written by ``model_to_dict`` and read again it is unchanged."""
    from compass.calibration import model_to_dict

    result, doc = cubic
    model = from_dict(doc).model
    for c, ch in enumerate(result.channels):
        entry = doc["channels"][ch.name]
        assert np.shape(entry["curve_joint_covariance"]) == (8, 8)
        np.testing.assert_array_equal(entry["joint_covariance"], ch.curve_covariance[:5, :5])
        np.testing.assert_array_equal(model.joint_covariance[c], ch.curve_covariance)
        assert entry["response"]["cubic"] == ch.response.cubic
    again_doc = json.loads(dumps(model_to_dict(model)))
    assert again_doc["channels"] == {k: {n: v[n] for n in again_doc["channels"][k]} for k, v in doc["channels"].items()}
    again = from_dict(again_doc).model
    for a, b in zip(again.joint_covariance, model.joint_covariance):
        np.testing.assert_array_equal(a, b)


def _old_reader_accepts(value) -> bool:
    """The check a reader before ``curve_joint_covariance`` (db2dbd0's ``_read``) made of ``joint_covariance``:
    5 x 5 nested lists of finite numbers."""
    return (isinstance(value, list) and len(value) == 5
            and all(isinstance(row, list) and len(row) == 5 for row in value)
            and np.all(np.isfinite(np.array(value, dtype=float))))


def test_a_file_with_a_curve_passes_an_older_readers_check(cubic):
    """Same format, older runtimes: every channel's ``joint_covariance`` written, by the calibration and by
    ``model_to_dict``, is 5 x 5 (an older reader refused an 8 x 8 and ignores the unknown key)."""
    from compass.calibration import model_to_dict

    _, doc = cubic
    for written in (doc, json.loads(dumps(model_to_dict(from_dict(doc).model)))):
        assert all(_old_reader_accepts(ch["joint_covariance"]) for ch in written["channels"].values())
        assert all("curve_joint_covariance" in ch for ch in written["channels"].values())


def test_the_runtime_heading_sigma_with_a_curve_is_the_four_flips_own(cubic):
    """Reference relation: the runtime's heading sigma (per sample, RMS over level headings) from a file with the
    curve's block is :func:`calibrate.diagnosis.robust.heading_sigma_deg` with the curves; the vectorised path
    agrees; the 5 x 5 block alone (a file without ``curve_joint_covariance``) reads and gives the linear levers'
    number."""
    _, doc = cubic
    model = from_dict(doc).model
    runtime = _runtime_rms_deg(model)
    curved = heading_sigma_deg(model.unit_directions, model.direction_covariance, model.response_sigma**2,
                               model.gains, model.dip_deg, model.field_norm, N_HEADINGS,
                               channel_covariance=np.stack(model.joint_covariance), curves=_curves(model))
    assert runtime == pytest.approx(curved, rel=1e-9)
    _assert_paths_agree(model)
    old = json.loads(json.dumps(doc))
    for ch in old["channels"].values():
        del ch["curve_joint_covariance"]
    linear = from_dict(old).model
    assert linear.calibration_uncertainty.curves is None
    assert _runtime_rms_deg(linear) == pytest.approx(_four_flip_rms_deg(linear, np.stack(linear.joint_covariance)),
                                                     rel=1e-9)
    assert abs(runtime / _runtime_rms_deg(linear) - 1.0) > 0.01  # the curve's errors matter here


@pytest.mark.parametrize("how, key, words", [
    ("6x6", "curve_joint_covariance", "must be 8x8 nested lists of numbers"),
    ("asymmetric", "curve_joint_covariance", "must be symmetric"),
    ("linear", "curve_joint_covariance", "is 8 x 8 (a response curve's coefficients) but the channel's response "
     "has no curve"),
    ("mismatched", "curve_joint_covariance", "must have the channel's joint_covariance as its top-left 5x5"),
    ("alone", "curve_joint_covariance", "comes without the channel's joint_covariance"),
    ("8x8 in the old key", "joint_covariance", "must be 5x5 nested lists of numbers")])
def test_a_malformed_curve_block_is_refused_naming_the_file_channel_and_key(cubic, tmp_path, how, key, words):
    _, doc = cubic
    bad = json.loads(json.dumps(doc))
    name, ch = next(iter(bad["channels"].items()))
    joint = np.array(ch["curve_joint_covariance"])
    if how == "6x6":
        joint = joint[:6, :6]
    elif how == "asymmetric":
        joint[4, 6] += 0.5 * np.sqrt(joint[4, 4] * joint[6, 6])
    elif how == "linear":
        ch["response"] = {k: v for k, v in ch["response"].items() if k not in ("cubic", "quadratic", "quintic")}
        ch["response"]["model"] = "linear"
    elif how == "mismatched":  # a 5 x 5 with the same marginals, the direction's correlations with the rest dropped
        ch["joint_covariance"] = np.block([[joint[:3, :3], np.zeros((3, 2))],
                                           [np.zeros((2, 3)), np.diag(np.diag(joint)[3:5])]]).tolist()
    elif how == "alone":
        del ch["joint_covariance"]
    else:
        ch["joint_covariance"] = joint.tolist()
    ch["curve_joint_covariance"] = joint.tolist()
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(bad))
    with pytest.raises(CalibrationFileError) as info:
        load(cal)
    assert str(info.value).startswith(f"{cal}: channel '{name}': '{key}' ") and words in str(info.value)
