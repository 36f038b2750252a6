"""The calibration file: one validated reader and writer for every command, one frozen value."""

import json
import math

import numpy as np
import pytest

from compass.calibration import CalibrationFileError, dumps, from_dict, kind_of, load, model_to_dict, save
from compass.cli import main
from compass.model import SensorModel
from compass.response import LinearResponse


def channel_doc() -> dict:
    model = SensorModel(("v1", "v2", "v3"), np.eye(3), (LinearResponse(1.0, 2.0, (-1.0, 1.0)),) * 3, 1.0, dip_deg=60.0)
    return model_to_dict(model) | {"noise_floor": [0.01, 0.01, 0.01]}


def tumble_doc() -> dict:
    return {"format": "compass-calibration/1", "model": "tumble", "hard_iron": [1.0, -2.0, 3.0],
            "soft_iron": np.diag([1.1, 0.9, 1.0]).tolist(), "field_norm": 50.0, "mag_to_accel": None,
            "field_ut": 50.0, "dip_deg": 60.0, "noise_floor": [0.3] * 3}


def nested(depth: int) -> str:
    return "[" * depth + "]" * depth


def set_key(doc: dict, dotted: str, value) -> dict:
    *path, last = dotted.split("/")
    d = doc
    for k in path:
        d = d[k]
    d[last] = value
    return doc


BAD_CHANNEL = [  # (change, key named in the message); every one passed or raised KeyError/TypeError on main
    ("channels/v1/response/offset", math.nan, "'response.offset' must be finite"),
    ("channels/v1/response/gain", -2.0, "'response.gain' must be a number in [1e-12, 1e+12]"),
    ("channels/v1/response", {"model": "table", "offset": 0.0, "gain": 1.0, "range": [-1, 1]}, "'response.x'"),
    ("channels/v1/response", {"model": "table", "offset": 0.0, "gain": 1.0, "range": [-1, 1], "x": 5, "v": 3},
     "'response.x'"),
    ("channels/v1/response", {"model": "table", "offset": 0.0, "gain": 1.0, "range": [-1, 1], "x": [0, 1],
                              "v": [1, 0]}, "'response.v' must increase"),
    ("channels/v1/response", {"model": "cubic", "offset": 0.0, "gain": 1.0, "range": [-10, 10], "cubic": -1.0},
     "not monotone"),
    ("channels/v1/response", ["linear", 0, 1], "'response' must be an object"),
    ("channels/v1/response", "linear", "'response' must be an object"),
    ("channels/v1/direction", [1.0, 0.0], "'direction' must be a list of 3 numbers"),
    ("channels/v1/direction", [math.inf, 0.0, 0.0], "'direction' must be finite"),
    ("dip_deg", 500.0, "'dip_deg' must be within [-90, 90]"),
    ("noise_floor", [0.01, -0.01, 0.01], "'noise_floor' must not be negative"),
    ("field_ut", -50.0, "'field_ut' must be a number in [0.001, 100000] uT"),
    ("effects", [{"name": "temperature", "reference": [1], "parameters": {}}], "'effects' is malformed"),
    ("model", "ellipsoid", "unknown calibration model 'ellipsoid'"),
]

BAD_TUMBLE = [
    ("soft_iron", [[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "'soft_iron' must be symmetric"),
    ("soft_iron", np.diag([1.0, -1.0, 1.0]).tolist(), "'soft_iron' must be positive definite"),
    ("mag_to_accel", np.diag([1.0, 1.0, -1.0]).tolist(), "'mag_to_accel' must be a proper rotation"),
    ("mag_to_accel", (2 * np.eye(3)).tolist(), "'mag_to_accel' must be a proper rotation"),
    ("hard_iron", [1.0, math.nan, 0.0], "'hard_iron' must be finite"),
    ("field_norm", 0.0, "'field_norm' must be positive"),
    ("noise_floor", -1.0, "'noise_floor' must not be negative"),
]


@pytest.mark.parametrize("key, value, message", BAD_CHANNEL + [(k, v, m) for k, v, m in BAD_TUMBLE])
def test_every_bad_value_is_refused_naming_the_file_and_key(tmp_path, key, value, message):
    doc = set_key(tumble_doc() if any(key == k for k, _, _ in BAD_TUMBLE) else channel_doc(), key, value)
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))  # json writes NaN/Infinity literals, as a careless tool would
    with pytest.raises(CalibrationFileError) as info:
        load(path)
    assert str(info.value).startswith(f"{path}: ") and message in str(info.value)


@pytest.mark.parametrize("command", ["attitude", "export", "live", "device"])
def test_every_command_refuses_a_bad_or_deeply_nested_calibration_with_exit_2(tmp_path, capsys, command):
    rec = tmp_path / "rec.csv"
    rec.write_text("mx,my,mz\n1,2,3\n")
    for name, text in (("deep.json", nested(100_000)), ("nan.json", json.dumps(set_key(tumble_doc(), "hard_iron",
                                                                                         [math.nan, 0, 0])))):
        cal = tmp_path / name
        cal.write_text(text)
        argv = {"attitude": ["attitude", str(cal), str(rec), "--out", str(tmp_path / "att.csv")],
                "export": ["export", str(cal), "--format", "fusion"],
                "live": ["live", "--port", "/nonexistent/port", "--cal", str(cal)],
                "device": ["device", "--pty", "--cal", str(cal), "--save-cal", str(tmp_path / "x.json")]}[command]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert name in err and "rec.csv" not in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "att.csv").exists()


def test_older_files_still_load():
    old = channel_doc()
    del old["model"]
    assert kind_of(old) == "fourflip" and from_dict(old).model.channels == ("v1", "v2", "v3")
    assert kind_of(old | {"method": "platform3d"}) == "platform3d"
    assert kind_of(old | {"method": "ml"}) == "fourflip"


def test_tilt_sensor_is_read_with_the_model():
    doc = channel_doc() | {"tilt_sensor": {"columns": ["ax", "ay"], "matrix": [[1, 0, 0], [0, 1, 0]], "offset": [0, 0]}}
    cal = from_dict(doc)
    assert cal.tilt_sensor.columns == ("ax", "ay") and cal.model.channels == ("v1", "v2", "v3")
    doc["tilt_sensor"]["offset"] = [0, math.nan]
    with pytest.raises(CalibrationFileError, match="'tilt_sensor.offset' must be finite"):
        from_dict(doc)


def test_writer_never_writes_nan_or_infinity():
    doc = channel_doc() | {"dip_sigma_deg": math.nan, "diagnosis": {"delta_bic": -math.inf}}
    text = dumps(doc)
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text)["dip_sigma_deg"] is None
    with pytest.raises(CalibrationFileError, match="'response.gain' must be finite"):
        dumps(set_key(channel_doc(), "channels/v2/response/gain", math.inf))


# ------------------------------------------------------------------------------- export (issue 15.1)


def test_c_float_literals_are_valid():
    from compass.commands.export import c_float

    assert [c_float(v) for v in (1.0, 0.0, -2.0, 1.5, 1e-5, 1e20)] == ["1.0f", "0.0f", "-2.0f", "1.5f", "1e-05f", "1e+20f"]


def test_export_says_when_the_field_norm_is_not_in_ut(tmp_path, capsys):
    doc = tumble_doc() | {"field_ut": None, "field_norm": 0.31, "soft_iron": np.eye(3).tolist()}
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(doc))
    assert main(["export", str(cal), "--format", "ardupilot"]) == 0
    captured = capsys.readouterr()
    assert "0.31" in captured.err and "gauss" in captured.err and "# warning:" in captured.out
    assert main(["export", str(cal), "--format", "ardupilot", "--unit", "gauss"]) == 0
    assert "warning" not in capsys.readouterr().err


def installed_doc(bench: dict, **installation) -> dict:
    return {"format": "compass-calibration/1", "model": "installed", "base": bench,
            "installation": {"hard_iron_ut": [1.0, -2.0, 0.5], "soft_iron": np.eye(3).tolist()} | installation}


@pytest.mark.parametrize("make", [channel_doc, tumble_doc, lambda: installed_doc(channel_doc())],
                         ids=["channels", "tumble", "installed"])
def test_a_file_read_and_saved_again_is_the_same_bytes(tmp_path, make):
    first = tmp_path / "first.json"
    save(first, make())
    cal = load(first)
    again = save(tmp_path / "again.json", cal)
    assert again.read_bytes() == first.read_bytes()
    with pytest.raises(FileExistsError):
        save(first, cal)  # never over a file without force


def test_a_calibrate_command_file_reads_back_identically(tmp_path):
    from compass.sim.fourflip import SimAccelerometer, simulate_fourflip, write_fourflip

    rec, _ = write_fourflip(simulate_fourflip(seed=4, accelerometer=SimAccelerometer()), tmp_path / "rec.csv")
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--no-diagnose"]) == 0
    value = load(cal)
    assert save(tmp_path / "copy.json", value).read_bytes() == cal.read_bytes()
    doc = json.loads(cal.read_text())
    assert value.kind == "fourflip" and value.provenance.method == doc["method"]
    np.testing.assert_array_equal(value.imu.mag_to_accel, doc["mag_to_accel"])
    np.testing.assert_array_equal(value.model.directions, [doc["channels"][c]["direction"] for c in value.model.channels])
    assert value.provenance.dip_sigma_deg == doc["dip_sigma_deg"]


def test_the_value_is_frozen_and_its_document_read_only():
    import dataclasses

    cal = from_dict(channel_doc())
    with pytest.raises(dataclasses.FrozenInstanceError):
        cal.kind = "tumble"
    with pytest.raises(TypeError):
        cal.document["dip_deg"] = 0.0
    with pytest.raises(TypeError):
        cal.document["channels"]["v1"]["direction"][0] = 0.5  # read-only all the way down


@pytest.mark.parametrize("change, key", [
    ({"soft_iron": [[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}, "'installation.soft_iron' must be symmetric"),
    ({"soft_iron": (-np.eye(3)).tolist()}, "'installation.soft_iron' must be positive definite"),
    ({"alignment": (2 * np.eye(3)).tolist()}, "'installation.alignment' must be a proper rotation"),
    ({"hard_iron_ut": [1.0, 2.0]}, "'installation.hard_iron_ut' must be a list of 3 numbers"),
])
def test_an_installed_file_is_checked_by_the_same_validator_as_a_tumble(tmp_path, change, key):
    path = tmp_path / "installed.json"
    path.write_text(json.dumps(installed_doc(channel_doc(), **change)))
    with pytest.raises(CalibrationFileError, match=f"^{path}: {key}"):
        load(path)


def test_a_bad_base_is_named_under_base(tmp_path):
    bench = channel_doc()
    bench["dip_deg"] = 91.0
    with pytest.raises(CalibrationFileError, match="'base.dip_deg' must be within"):
        from_dict(installed_doc(bench))


def test_an_installed_file_carries_its_bench_imu_and_hemisphere():
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_rotvec([0.01, -0.02, 0.03]).as_matrix()
    align = Rotation.from_euler("z", 20, degrees=True).as_matrix()
    bench = channel_doc() | {"model": "fourflip", "mag_to_accel": turn.tolist(),
                             "accelerometer": {"offset": [0.01, 0.0, -0.01], "scale_yz": [1.01, 0.99], "one_g": 1.0}}
    cal = from_dict(installed_doc(bench, alignment=align.tolist()))
    assert cal.kind == "installed" and cal.installation.base.kind == "fourflip"
    assert cal.provenance.hemisphere_assumed  # a four-flip base without a given hemisphere
    a = np.array([[0.1, -0.2, 0.95]])
    expected = ((a - [0.01, 0.0, -0.01]) / [1.0, 1.01, 0.99]) @ turn @ align.T  # a_model = A M^T (a - o) / s
    np.testing.assert_allclose(cal.imu.apply(a), expected, rtol=1e-12)
    # the bench's directions (the identity) turned into the product's frame; the soft iron is the identity
    np.testing.assert_allclose(cal.model.unit_directions, np.eye(3) @ align.T, atol=1e-12)


def _tumble_with_gyro(gyro: dict) -> dict:
    """A tumble calibration document whose gyro-aided block is ``gyro``."""
    from calibrate.tumble import calibrate_tumble
    from compass.sim.tumble import simulate_tumble

    sim = simulate_tumble(seed=4, n=600)
    doc = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s).to_json()
    doc["tumble"]["gyro"] = {"method": "gyro", "used": True} | gyro
    return doc


def test_the_files_gyro_matrix_reaches_the_model_where_the_fit_saw_it():
    from compass.calibration._read import GYRO_MATRIX_SIGMA_SEEN

    g = np.eye(3) + np.array([[0.02, 0.003, -0.004], [0.001, -0.015, 0.002], [0.03, -0.03, 0.01]])
    seen, unseen = 0.1 * GYRO_MATRIX_SIGMA_SEEN, 2.0 * GYRO_MATRIX_SIGMA_SEEN
    sigma = [[seen, seen, seen], [seen, seen, seen], [unseen, None, seen]]  # the prior's or none: held at I
    model = from_dict(_tumble_with_gyro({"gyro_matrix": g.tolist(), "gyro_matrix_sigma": sigma})).model
    expected = g.copy()
    expected[2, :2] = 0.0
    expected[1, 0] = 0.0  # 0.1 %: precise (sigma 0.05 %) but within 3 sigmas of the identity's, not seen off it
    np.testing.assert_array_equal(model.gyro_matrix, expected)
    # nothing seen, no sigma, no matrix: none
    for block in ({"gyro_matrix": g.tolist(), "gyro_matrix_sigma": [[unseen] * 3] * 3}, {"gyro_matrix": g.tolist()},
                  {}):
        assert from_dict(_tumble_with_gyro(block)).model.gyro_matrix is None


def test_a_gyro_matrix_entry_beyond_three_prior_sigmas_is_a_mismatch_and_not_applied():
    from calibrate.tumble.gyro import GYRO_MATRIX_PRIOR
    from compass.calibration import gyro_matrix_mismatch
    from compass.calibration._read import GYRO_MATRIX_MISMATCH

    np.testing.assert_array_equal(GYRO_MATRIX_MISMATCH, 3.0 * GYRO_MATRIX_PRIOR.reshape(3, 3))  # one rule, both sides
    g = np.eye(3) + np.array([[0.02, 0.07, 0.0], [0.0, -0.1, 0.0], [0.0, 0.0, 0.085]])  # 3.5 and 3.3 prior sigmas
    sigma = [[0.001] * 3] * 3
    assert gyro_matrix_mismatch(g).tolist() == [[False, True, False], [False, True, False], [False] * 3]
    model = from_dict(_tumble_with_gyro({"gyro_matrix": g.tolist(), "gyro_matrix_sigma": sigma})).model
    np.testing.assert_array_equal(model.gyro_matrix, np.diag([1.02, 1.0, 1.085]))  # precise however wrong: not applied


def test_a_gyro_block_the_calibration_did_not_use_reaches_no_runtime():
    g = (np.eye(3) + np.diag([0.02, -0.015, 0.01])).tolist()
    block = {"gyro_matrix": g, "gyro_matrix_sigma": [[0.0005] * 3] * 3, "mag_latency_s": 0.012,
             "mag_latency_sigma_s": 0.0003}
    used = from_dict(_tumble_with_gyro(block)).model
    assert used.gyro_matrix is not None and used.mag_latency_s == 0.012  # the same block, used: taken
    for flag in (False, None, "true", 1):
        doc = _tumble_with_gyro(block)
        doc["tumble"]["gyro"]["used"] = flag
        if flag is None:
            del doc["tumble"]["gyro"]["used"]
        model = from_dict(doc).model
        assert model.gyro_matrix is None and model.mag_latency_s == 0.0


@pytest.mark.parametrize("key, value, words", [
    ("gyro_matrix", [[1, 0, 0], [0, 1, 0]], "3x3 nested lists"),
    ("gyro_matrix", "eye", "3x3 nested lists"),
    ("gyro_matrix", [[1, 0, 0], [0, 1, 0], [0, 0, 57.3]], "within 20 % of the identity"),
    ("gyro_matrix", [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "within 20 % of the identity"),
    ("gyro_matrix_sigma", [[0.001] * 3] * 2, "3x3 nested lists"),
    ("gyro_matrix_sigma", [[0.001, 0.001, -0.001]] * 3, "must not be negative"),
    ("gyro_matrix_sigma", [[0.001, 0.001, "x"]] * 3, "must be a number"),
    ("gyro_matrix", [[1, 0, 0], [0, True, 0], [0, 0, 1]], r"\[1\]\[1\].*must be a number"),
    ("gyro_matrix", [[1, 0, 0], [0, 1, 0], [0, "0", 1]], r"\[2\]\[1\].*must be a number"),
    ("gyro_matrix_sigma", [[0.001, 0.001, False]] * 3, r"\[0\]\[2\].*must be a number"),
])
def test_bad_gyro_matrices_in_the_file_are_refused_naming_the_key(key, value, words):
    block = {"gyro_matrix": np.eye(3).tolist(), "gyro_matrix_sigma": [[0.001] * 3] * 3} | {key: value}
    with pytest.raises(CalibrationFileError, match=rf"tumble\.gyro\.{key}.*{words}"):
        from_dict(_tumble_with_gyro(block))


def test_garbage_gyro_matrix_sigma_is_refused_even_without_a_matrix():
    block = {"gyro_matrix": None, "gyro_matrix_sigma": "garbage"}
    with pytest.raises(CalibrationFileError, match=r"tumble\.gyro\.gyro_matrix_sigma.*3x3 nested lists"):
        from_dict(_tumble_with_gyro(block))
    assert from_dict(_tumble_with_gyro({"gyro_matrix": None, "gyro_matrix_sigma": None})).model.gyro_matrix is None
