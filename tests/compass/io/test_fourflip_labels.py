"""A four-flip recording's flip labels against the faces its accelerometer says were down."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate import calibrate_fourflip
from compass.cli import main
from compass.io.fourflip import faces_down, read_fourflip
from compass.sim.fourflip import SimAccelerometer, simulate_fourflip, write_fourflip

EXCHANGE_90_270 = {0: 0, 90: 270, 180: 180, 270: 90}


def _relabelled(tmp_path, session, mapping, name="relabelled.csv", negate=()):
    """The session written, then its flip_deg cells mapped (and the ``negate`` columns negated)."""
    path, _ = write_fourflip(session, tmp_path / f"honest_{name}")
    lines = path.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    columns = lines[head].split(",")
    flip, signs = columns.index("flip_deg"), [columns.index(c) for c in negate]
    out = lines[:head + 1]
    for line in lines[head + 1:]:
        cells = line.split(",")
        cells[flip] = f"{mapping[round(float(cells[flip]))]:g}"
        for j in signs:
            cells[j] = repr(-float(cells[j]))
        out.append(",".join(cells))
    target = tmp_path / name
    target.write_text("\n".join(out) + "\n")
    return target


def _first_row_of_flip(path, flip_deg):
    lines = path.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    column = lines[head].split(",").index("flip_deg")
    return next(i + 1 for i, line in enumerate(lines) if i > head and float(line.split(",")[column]) == flip_deg)


@pytest.mark.parametrize("seed", [2, 3])
def test_flips_90_and_270_exchanged_are_said_naming_the_flips_faces_and_both_readings(tmp_path, capsys, seed):
    """The same data as an accelerometer mounted half-turned about Z (which the fit's mag_to_accel takes into
    account, and calibrated right before): said, first, with both readings, not refused."""
    session = simulate_fourflip(seed=seed, accelerometer=SimAccelerometer(misalign_deg=2.0, offset_g=0.02))
    path = _relabelled(tmp_path, session, EXCHANGE_90_270)
    assert main(["calibrate", str(path), "--out", str(tmp_path / "c.json")]) == 0
    err = capsys.readouterr().err
    said = [line for line in err.splitlines() if "look exchanged" in line]
    assert len(said) == 1 and str(path) in said[0] and "Traceback" not in err
    assert "flip 90 had the +Y face down" in said[0] and "flip 270 had the -Y face down" in said[0]
    assert "every heading will be turned" in said[0] and "mounted turned against the housing" in said[0]
    assert err.index("look exchanged") < err.find("not the housing's") or "not the housing's" not in err


def test_flips_in_an_order_no_mounting_gives_are_refused(tmp_path):
    """Flips 0 and 90 exchanged: no turn of the accelerometer puts the faces so, only mislabelled flips."""
    session = simulate_fourflip(seed=4, accelerometer=SimAccelerometer(misalign_deg=1.0))
    path = _relabelled(tmp_path, session, {0: 90, 90: 0, 180: 180, 270: 270})
    with pytest.raises(ValueError, match="flip 0 had the -Y face down .*flip 90 had the -Z face down.*no mounting"):
        read_fourflip(path)


def test_no_mounting_of_the_accelerometer_is_refused(tmp_path):
    """Each of the 24 turns of the accelerometer's axes onto the housing's (a chip mounted turned, by design):
    read, never refused as mislabelled flips (the fit's mag_to_accel takes them into account)."""
    session = simulate_fourflip(seed=1, accelerometer=SimAccelerometer(misalign_deg=1.0))
    for k, turn in enumerate(Rotation.create_group("O")):
        turned = replace(session, accel=turn.apply(session.accel))
        read_fourflip(write_fourflip(turned, tmp_path / f"turned_{k}.csv")[0])


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_honest_recordings_have_every_face_where_their_labels_say(write_session, seed):
    rec, _ = write_session(seed=seed, accelerometer=SimAccelerometer(misalign_deg=3.0, offset_g=0.02,
                                                                      scale_error=0.01))
    assert faces_down(rec.flip_index, rec.accel).tolist() == [0, 1, 2, 3]


def test_a_chip_turned_half_round_about_z_is_calibrated_and_said(tmp_path, capsys):
    """A recording the accelerometer cannot tell from exchanged labels: calibrated, said with both readings."""
    session = simulate_fourflip(seed=5, accelerometer=SimAccelerometer(misalign_deg=1.0))
    path = _relabelled(tmp_path, session, {k: k for k in (0, 90, 180, 270)}, negate=("ax", "ay"))
    assert main(["calibrate", str(path), "--out", str(tmp_path / "c.json")]) == 0
    assert "mounted turned against the housing" in capsys.readouterr().err


def test_left_to_the_accelerometer_fit_a_negated_or_stuck_accelerometer(tmp_path):
    """Every flip reading the opposite face (gravity, not specific force: --accel-sign -1) or one face (stuck):
    the reader passes them on to the accelerometer fit, whose words name those causes."""
    session = simulate_fourflip(seed=6, accelerometer=SimAccelerometer(misalign_deg=1.0))
    same = {k: k for k in (0, 90, 180, 270)}
    negated = read_fourflip(_relabelled(tmp_path, session, same, negate=("ax", "ay", "az")))
    assert faces_down(negated.flip_index, negated.accel).tolist() == [2, 3, 0, 1]
    stuck = _relabelled(tmp_path, session, same, name="stuck.csv")
    lines = stuck.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    az = lines[head].split(",").index("az")
    lines[head + 1:] = [",".join("1.0" if j == az else "0.0" if j in (az - 1, az - 2) else c
                                 for j, c in enumerate(line.split(","))) for line in lines[head + 1:]]
    stuck.write_text("\n".join(lines) + "\n")
    assert faces_down(read_fourflip(stuck).flip_index, read_fourflip(stuck).accel).tolist() == [0, 0, 0, 0]


@pytest.mark.parametrize("seed", [1, 7])
def test_without_an_accelerometer_the_exchange_is_a_symmetry(write_session, seed):
    """Flips 90 and 270 exchanged fit exactly as well, with every direction turned 180 deg about Z and the field's
    azimuth by 180 deg, the dip unchanged: a magnetometer-only recording cannot tell (docs/calibration.md)."""
    rec, _ = write_session(seed=seed)
    index = np.array([0, 3, 2, 1])[rec.flip_index]
    swapped = replace(rec, flip_index=index, flip_deg=np.mod(360.0 - rec.flip_deg, 360.0))
    honest, turned = calibrate_fourflip(rec), calibrate_fourflip(swapped)
    half_turn = Rotation.from_euler("z", 180, degrees=True)
    for a, b in zip(honest.channels, turned.channels):
        moved = np.degrees(np.arccos(np.clip(half_turn.apply(a.direction) @ b.direction, -1, 1)))
        assert moved < 0.05 * a.direction_sigma_deg
    assert abs(turned.dip_deg - honest.dip_deg) < 0.05 * honest.dip_sigma_deg
    assert abs(np.mod(turned.azimuth_deg - honest.azimuth_deg, 360.0) - 180.0) < 0.01
    assert turned.statistics.chi2 == pytest.approx(honest.statistics.chi2, rel=1e-6)


@pytest.mark.parametrize("seed", [1, 7])
def test_without_an_accelerometer_channels_reversed_by_a_relabelling_are_said(write_session, seed):
    """The channels' layout is the one clue left: v1, v2, v3 come out along -X, -Y, +Z."""
    rec, _ = write_session(seed=seed)
    index = np.array([0, 3, 2, 1])[rec.flip_index]
    swapped = calibrate_fourflip(replace(rec, flip_index=index, flip_deg=np.mod(360.0 - rec.flip_deg, 360.0)))
    said = [w for w in swapped.warnings if "relabelled" in w]
    assert len(said) == 1 and "v1 -X, v2 -Y, v3 +Z" in said[0] and "90 -> 270, 270 -> 90" in said[0]
    assert "flips 90 and 270 exchanged" in said[0]
    assert not any("relabelled" in w for w in calibrate_fourflip(rec).warnings)


@pytest.mark.parametrize("layout, said", [((-1, -1, 1), True), ((1, -1, -1), False), ((1, 1, -1), False),
                                          ((-1, 1, 1), False)])
def test_the_relabelling_words_only_for_the_exchange_that_puts_each_channel_right_on_its_own_axis(layout, said):
    """-X -Y +Z is +X +Y +Z with flips 90/270 exchanged; FRD's +X -Y -Z (a half turn about X) and a left-handed set
    (+X +Y -Z: no relabelling keeps each channel on its axis) are honest layouts, not told to relabel."""
    from calibrate.fourflip.fit import relabelling_warning

    words = relabelling_warning(np.diag(np.array(layout, float)), ("mx", "my", "mz"))
    assert (words is not None) == said


def test_one_flip_near_no_face_does_not_hide_mislabelled_others(tmp_path):
    """Flips 0 and 90 exchanged, flip 270's accelerometer near zero: refused (a mounting loses flips in opposite
    pairs, never one alone)."""
    session = simulate_fourflip(seed=4, accelerometer=SimAccelerometer(misalign_deg=1.0))
    accel = np.where((session.samples.flip_index == 3)[:, None], 0.01, session.accel)
    path = _relabelled(tmp_path, replace(session, accel=accel), {0: 90, 90: 0, 180: 180, 270: 270})
    with pytest.raises(ValueError, match="no mounting"):
        read_fourflip(path)


def test_the_calibrations_words_name_the_labels_beside_the_mounting(tmp_path, capsys):
    """Flips 90/270 exchanged (the same data as a half-turned chip): the calibration file's own warnings name the
    labels, not only the wiring."""
    import json

    session = simulate_fourflip(seed=2, accelerometer=SimAccelerometer(misalign_deg=2.0))
    path = _relabelled(tmp_path, session, EXCHANGE_90_270)
    assert main(["calibrate", str(path), "--out", str(tmp_path / "c.json"), "--quiet"]) == 0
    words = " ".join(json.loads((tmp_path / "c.json").read_text())["warnings"])
    assert "the flips are mislabelled" in words and "check the flips' labels" in words
