"""``compass export`` writes the matrix and offset in the order the firmware reads its sensor: x, y, z.

A calibration keeps its channels in the recording's column order; a logger that wrote ``my,mx,mz`` gave
a Fusion export 104 deg RMS off in heading (exit 0), an ArduPilot one with a "90 deg rotation" (a swap,
determinant -1) in a comment.  The firmware is fed its sensor's ``(x, y, z)`` here, as a chip reads.
"""

import json
import re

import numpy as np
import pytest

from compass.calibration import load, model_to_dict
from compass.cli import main
from compass.io.motioncal import decode_packet
from compass.model import SensorModel
from compass.response import LinearResponse

GAINS = (1.1, 0.9, 1.05)
OFFSETS = (3.0, -7.0, 12.0)  # uT: channel i reads OFFSETS[i] + GAINS[i] * (a_i . B)


def bench(tmp_path, names, directions, name="cal.json"):
    """A bench calibration in uT of three linear channels ``names`` along the rows of ``directions``."""
    responses = tuple(LinearResponse(o, g) for o, g in zip(OFFSETS, GAINS))
    model = SensorModel(tuple(names), np.asarray(directions, float), responses, 50.0, 50.0, 60.0)
    path = tmp_path / name
    path.write_text(json.dumps(model_to_dict(model) | {"noise_floor": [0.05] * 3}))
    return path


def fields(n=24, dip_deg=60.0):
    """The Earth's field in H (uT) at ``n`` headings of a level housing, shape (n, 3)."""
    psi, dip = np.radians(np.arange(n) * 360.0 / n), np.radians(dip_deg)
    return 50.0 * np.column_stack([np.cos(dip) * np.cos(psi), np.cos(dip) * np.sin(psi),
                                   np.full_like(psi, -np.sin(dip))])


def sensor_xyz(cal_path, field):
    """What the chip reads as its ``(x, y, z)``: the calibration's channels ordered by the axis their name says."""
    model = load(cal_path).model
    raw = np.column_stack([r.output(x) for r, x in zip(model.responses, (field @ model.unit_directions.T).T)])
    return raw[:, [model.channels.index(n) for n in ("mx", "my", "mz")]]


def fusion_field(text, raw):
    element = dict(re.findall(r"\.([xyz]{2}) = ([-0-9.e]+)f", text))
    axis = dict(re.findall(r"\.([xyz]) = ([-0-9.e]+)f", text))
    matrix = np.array([[float(element[r + c]) for c in "xyz"] for r in "xyz"])
    return (raw - np.array([float(axis[a]) for a in "xyz"])) @ matrix.T


def ardupilot_field(text, raw):
    p = {k: float(v) for k, v in re.findall(r"^(COMPASS_\w+),([-0-9.e]+)", text, re.M)}
    x, y, z = (p[f"COMPASS_ODI_{a}"] for a in "XYZ")
    d = [p[f"COMPASS_DIA_{a}"] for a in "XYZ"]
    matrix = np.array([[d[0], x, y], [x, d[1], z], [y, z, d[2]]])
    return (raw * 10.0 + np.array([p[f"COMPASS_OFS_{a}"] for a in "XYZ"])) @ matrix.T  # uT -> milligauss


def heading_deg(b):
    return np.degrees(np.arctan2(b[:, 1], b[:, 0]))


@pytest.fixture()
def swapped(tmp_path):
    """Channels logged as my, mx, mz: their directions Y, X, Z."""
    return bench(tmp_path, ("my", "mx", "mz"), [[0, 1, 0], [1, 0, 0], [0, 0, 1]])


def test_fusion_takes_the_sensors_x_y_z_whatever_the_calibrations_channel_order(swapped, capsys):
    assert main(["export", str(swapped), "--format", "fusion"]) == 0
    text = capsys.readouterr().out
    assert "// sensor x, y, z = the calibration's channels mx, my, mz" in text
    b = fields()
    np.testing.assert_allclose(fusion_field(text, sensor_xyz(swapped, b)), b, atol=1e-4)


def test_ardupilot_takes_the_sensors_x_y_z_and_leaves_no_swap_out_as_a_rotation(swapped, capsys):
    assert main(["export", str(swapped), "--format", "ardupilot"]) == 0
    text = capsys.readouterr().out
    assert "not exported" not in text and "# sensor x, y, z = the calibration's channels mx, my, mz" in text
    b = fields()
    got = ardupilot_field(text, sensor_xyz(swapped, b))
    np.testing.assert_allclose(heading_deg(got), heading_deg(b), atol=1e-3)


def test_motioncal_takes_the_sensors_x_y_z(swapped, tmp_path):
    out = tmp_path / "cal.mc"
    assert main(["export", str(swapped), "--format", "motioncal", "--out", str(out)]) == 0
    packet = decode_packet(out.read_bytes())
    b = fields()
    got = (sensor_xyz(swapped, b) - packet.hard_iron_ut) @ packet.soft_iron.T
    np.testing.assert_allclose(got, b, atol=1e-3)


@pytest.mark.parametrize("fmt", ["fusion", "ardupilot", "motioncal"])
def test_names_that_say_no_axis_are_taken_in_column_order_and_said_and_axes_says_another(tmp_path, capsys, fmt):
    """A bench's v1,v2,v3 are the order the module sent them: the firmware's x, y, z, said in the output; --axes
    names another; names that say some axes but not each once are refused."""
    cal = bench(tmp_path, ("v1", "v2", "v3"), [[0, 1, 0], [1, 0, 0], [0, 0, 1]])
    out = tmp_path / "out"
    code = main(["export", str(cal), "--format", fmt, "--out", str(out)])
    said = capsys.readouterr()
    assert code == (0 if fmt == "fusion" else 2), said.err
    if fmt == "fusion":  # the matrix folds in the swap the directions say: the field comes back whatever the order
        assert "channels v1, v2, v3 in the recording's column order" in out.read_text()
        b = fields()
        model = load(cal).model
        raw = np.column_stack([r.output(x) for r, x in zip(model.responses, (b @ model.unit_directions.T).T)])
        np.testing.assert_allclose(fusion_field(out.read_text(), raw), b, atol=1e-4)
    else:  # v1 along Y, v2 along X read as x, y: a left-handed set, refused in words that name the order
        assert "v1, v2, v3" in said.err and "Traceback" not in said.err and not out.exists()
    out.unlink(missing_ok=True)
    assert main(["export", str(cal), "--format", fmt, "--out", str(out), "--axes", "v2,v1,v3"]) == 0
    if fmt == "fusion":  # v2 is the sensor's x: along X, as the directions say
        b = fields()
        model = load(cal).model
        raw = np.column_stack([r.output(x) for r, x in zip(model.responses, (b @ model.unit_directions.T).T)])
        np.testing.assert_allclose(fusion_field(out.read_text(), raw[:, [1, 0, 2]]), b, atol=1e-4)
    capsys.readouterr()
    partly = bench(tmp_path, ("mx", "v2", "v3"), [[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert main(["export", str(partly), "--format", fmt, "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "name some of the sensor's axes but not each of x, y and z once" in err[0]
    assert "--axes" in err[0] and not (tmp_path / "p").exists()


@pytest.mark.parametrize(("axes", "words"), [("v1,v2", "expected three different channel names"),
                                             ("v1,v1,v3", "expected three different channel names"),
                                             ("v1,v2,mx", "--axes names mx, which the calibration does not have")])
def test_a_wrong_axes_option_is_refused_in_one_line(tmp_path, capsys, axes, words):
    cal = bench(tmp_path, ("v1", "v2", "v3"), np.eye(3))
    assert main(["export", str(cal), "--format", "fusion", "--axes", axes]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]


@pytest.mark.parametrize("fmt", ["ardupilot", "motioncal"])
def test_a_left_handed_set_is_refused_by_a_symmetric_matrix_never_commented_as_a_rotation(tmp_path, capsys, fmt):
    cal = bench(tmp_path, ("mx", "my", "mz"), [[1, 0, 0], [0, 1, 0], [0, 0, -1]])  # z read with its sign turned
    assert main(["export", str(cal), "--format", fmt]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "left-handed set" in err[0] and "--format fusion" in err[0]


def test_fusion_holds_a_left_handed_set_in_its_full_matrix(tmp_path, capsys):
    cal = bench(tmp_path, ("mx", "my", "mz"), [[1, 0, 0], [0, 1, 0], [0, 0, -1]])
    assert main(["export", str(cal), "--format", "fusion"]) == 0
    b = fields()
    np.testing.assert_allclose(fusion_field(capsys.readouterr().out, sensor_xyz(cal, b)), b, atol=1e-4)


@pytest.mark.parametrize("fmt", ["fusion", "motioncal"])
def test_a_tumble_without_accelerometer_in_another_axis_order_comes_back_in_that_order(tmp_path, capsys, fmt):
    """Without an accelerometer a tumble's field is in the sensor's own frame: read as y, x, z (--axes my,mx,mz) it
    comes back as y, x, z; its matrix's columns alone were permuted, a mirrored field (review)."""
    rec, cal, out = tmp_path / "t.csv", tmp_path / "t.json", tmp_path / "out"
    assert main(["simulate", "tumble", "--out", str(rec), "--no-accel", "--seed", "2"]) == 0
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet"]) == 0
    t = load(cal).tumble
    raw = t.hard_iron + fields() @ np.linalg.inv(t.soft_iron).T  # what the sensor reads (mx, my, mz) of these fields
    order = [1, 0, 2]
    assert main(["export", str(cal), "--format", fmt, "--out", str(out), "--axes", "my,mx,mz"]) == 0
    if fmt == "fusion":
        got = fusion_field(out.read_text(), raw[:, order])
    else:
        packet = decode_packet(out.read_bytes())
        got = (raw[:, order] - packet.hard_iron_ut) @ packet.soft_iron.T
    np.testing.assert_allclose(got, fields()[:, order], atol=1e-3 * 50.0)
