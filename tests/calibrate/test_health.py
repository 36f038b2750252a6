"""A broken module is said, on every kind: a dead channel refused, a drowned one and a gross mounting
error warned about, each channel's signal-to-noise ratio and axis angle kept in the file."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.contract import CannotCalibrate
from calibrate.fourflip import FourFlipCalibrator
from calibrate.health import AXIS_TOLERANCE_DEG, DEAD_SIGMAS, ChannelHealth, check_channels
from calibrate.platform3d import Platform3DCalibrator
from calibrate.reference import ReferenceCalibrator
from calibrate.tumble import TumbleCalibrator
from compass.io.platform3d import read_platform3d
from compass.io.reference import read_reference
from compass.io.tumble import read_tumble
from compass.sim.platform3d import simulate_platform3d, write_platform3d
from compass.sim.reference import simulate_reference, write_reference
from compass.sim.tumble import simulate_tumble, write_tumble

HEALTH_WORDS = ("signal-to-noise", "housing axis", "does not respond")


def health_warnings(result) -> list[str]:
    return [w for w in result.warnings if any(word in w for word in HEALTH_WORDS)]


def tilted(direction, toward, angle_deg):
    """``direction`` turned by ``angle_deg`` toward ``toward`` (both unit, H)."""
    axis = np.cross(direction, toward)
    return Rotation.from_rotvec(np.radians(angle_deg) * axis / np.linalg.norm(axis)).apply(direction)


@pytest.mark.parametrize("method", ["ml", "harmonic", "patent"])
def test_fourflip_dead_channel_is_refused_naming_it(write_session, method):
    rec, truth = write_session(seed=21)
    rng = np.random.default_rng(0)
    outputs = rec.outputs.copy()
    outputs[:, 1] = truth["offsets"][1] + rng.normal(0.0, truth["noise"][1] / 3, len(outputs))  # constant + noise
    with pytest.raises(CannotCalibrate, match=r"channel 'v2' does not respond to the field.*dead"):
        FourFlipCalibrator(method=method, diagnose=False).fit(replace(rec, outputs=outputs))


def test_a_responding_channel_whose_direction_the_fit_cannot_place_is_not_called_dead():
    """37 sigma of response and a direction +- 15 deg (a flip's turntable counting the other way: round hH) was
    'a dead or disconnected sensor'; the words now point at the recording's angles."""
    healthy = ChannelHealth("v1", 1.0, 0.025, 0.003, np.array([1.0, 0.0, 0.0]), 0.02)
    unplaced = ChannelHealth("v3", 0.943, 0.025, 0.003, np.array([0.0, 0.0, 1.0]), 15.5)
    with pytest.raises(CannotCalibrate, match=r"channel 'v3' responds to the field but its direction is not "
                                              r"determined: .*37.7 sigma from zero.*platform_deg") as info:
        check_channels("rec.csv", [healthy, unplaced])
    assert "dead" not in str(info.value)


def test_fourflip_drowned_channel_is_warned_with_its_snr(write_session):
    rec, truth = write_session(seed=22)
    rng = np.random.default_rng(1)
    outputs = rec.outputs.copy()
    outputs[:, 2] += rng.normal(0.0, 20 * truth["noise"][2], len(outputs))  # 20x the noise: a broken front end
    result = FourFlipCalibrator(diagnose=False).fit(replace(rec, outputs=outputs))
    warned = health_warnings(result)
    assert len(warned) == 1 and warned[0].startswith("channel v3: signal-to-noise"), warned
    snr = {name: h["snr"] for name, h in result.to_json()["channel_health"].items()}
    # the injected noise is 20x, with 1/sqrt(21) from the added and the own: SNR down by sqrt(401) = 20.0
    ratio = np.median([snr["v1"], snr["v2"]]) / snr["v3"]
    assert 14 < ratio < 28, snr


def test_fourflip_channel_20_deg_off_its_axis_is_warned(write_session):
    directions = np.eye(3)
    directions[1] = tilted(directions[1], directions[2], 20.0)
    rec, _ = write_session(seed=23, directions=directions)
    result = FourFlipCalibrator(diagnose=False).fit(rec)
    warned = health_warnings(result)
    assert len(warned) == 1 and warned[0].startswith("channel v2: 20.0 deg from the nearest housing axis (+Y)"), warned
    entry = result.to_json()["channel_health"]["v2"]
    assert entry["nearest_axis"] == "+Y" and entry["axis_angle_deg"] == pytest.approx(20.0, abs=0.1)
    oblique = FourFlipCalibrator(diagnose=False, axis_tolerance_deg=25.0).fit(rec)
    assert health_warnings(oblique) == []


def test_fourflip_clean_says_nothing_and_keeps_the_figures(write_session):
    for seed in (31, 32, 33):
        rec, truth = write_session(f"rec{seed}.csv", seed=seed)
        result = FourFlipCalibrator(diagnose=False).fit(rec)
        assert health_warnings(result) == []
        block = result.to_json()["channel_health"]
        truth_dirs = np.asarray(truth["directions"])
        for c, (name, entry) in enumerate(block.items()):
            # the stated SNR is the truth's: gain |B| over the injected noise, within the noise estimate's spread
            expected = truth["gains_per_ut"][c] * truth["field_ut"] / truth["noise"][c]
            assert entry["snr"] == pytest.approx(expected, rel=0.15)
            true_angle = np.degrees(np.arccos(np.max(np.abs(truth_dirs[c]))))
            assert entry["axis_angle_deg"] == pytest.approx(true_angle, abs=0.2)


def test_fourflip_direction_accuracy_says_the_snr_it_needs(write_session):
    rec, _ = write_session(seed=24)
    result = FourFlipCalibrator(diagnose=False, direction_accuracy_deg=0.001).fit(rec)
    warned = [w for w in result.warnings if "0.001 deg needs" in w]
    assert len(warned) == 3
    sigma = result.channels[0].direction_sigma_deg
    snr = result.to_json()["channel_health"]["v1"]["snr"]
    assert f"needs {snr * sigma / 0.001:.3g}" in warned[0]


def test_check_channels_relations():
    ok = [ChannelHealth(n, 1.0, 1e-3, 0.01, np.eye(3)[i]) for i, n in enumerate("abc")]
    assert check_channels("r.csv", ok) == ()
    dead = ok[:2] + [ChannelHealth("c", 0.04, 0.01, 0.01, np.eye(3)[2])]  # 4 sigma: not distinguishable
    with pytest.raises(CannotCalibrate, match="r.csv: channel 'c' does not respond"):
        check_channels("r.csv", dead)
    alive = ok[:2] + [ChannelHealth("c", 1.01 * DEAD_SIGMAS * 0.01, 0.01, 0.01, np.eye(3)[2])]
    assert any("channel c: signal-to-noise" in w for w in check_channels("r.csv", alive))  # alive, but drowned
    vague = ok[:2] + [ChannelHealth("c", 1.0, 1e-3, 0.01, np.eye(3)[2], direction_sigma_deg=12.0)]
    with pytest.raises(CannotCalibrate, match="direction \\+- 12 deg"):
        check_channels("r.csv", vague)
    tip = ok[:2] + [ChannelHealth("c", 1.0, 1e-3, 0.01, tilted(np.eye(3)[2], np.eye(3)[0], AXIS_TOLERANCE_DEG + 0.5))]
    assert len(check_channels("r.csv", tip)) == 1 and check_channels("r.csv", tip, axis_tolerance_deg=None) == ()


def test_the_command_default_is_the_library_default():
    from compass.commands import calibrate as command

    assert command.AXIS_TOLERANCE_DEG == AXIS_TOLERANCE_DEG


def _tumble(tmp_path, seed, change=None):
    sim = simulate_tumble(seed=seed, n=1500)
    if change is not None:
        sim = replace(sim, mag=change(sim.mag.copy(), np.random.default_rng(seed)))
    path, _ = write_tumble(sim, tmp_path / f"tumble{seed}.csv", force=True)
    return read_tumble(path), sim


def test_tumble_dead_axis_is_refused(tmp_path):
    def dead(mag, rng):
        mag[:, 2] = 3.0 + rng.normal(0.0, 0.1, len(mag))
        return mag
    rec, _ = _tumble(tmp_path, 41, dead)
    with pytest.raises(CannotCalibrate, match="column 'mz' never varied beyond its noise"):
        TumbleCalibrator().fit(rec)


def test_tumble_drowned_axis_is_warned_and_clean_is_not(tmp_path):
    def drowned(mag, rng):
        mag[:, 0] += rng.normal(0.0, 20 * 0.3, len(mag))  # the simulator's noise is 0.3 uT
        return mag
    rec, _ = _tumble(tmp_path, 42, drowned)
    warned = health_warnings(TumbleCalibrator().fit(rec))
    assert len(warned) == 1 and warned[0].startswith("channel mx: signal-to-noise"), warned
    clean, sim = _tumble(tmp_path, 43)
    result = TumbleCalibrator().fit(clean)
    assert health_warnings(result) == []
    block = result.to_json()["channel_health"]
    # the axes' angles in the housing are the fitted rotation's (the soft iron left out): none farther
    # from its axis than the rotation's angle, which turns every vector by at most that
    turn = np.linalg.norm(result.misalignment.rotvec_deg)
    assert all(entry["axis_angle_deg"] <= turn + 1e-9 for entry in block.values()), (block, turn)


def test_platform3d_and_reference_keep_the_figures_and_refuse_a_dead_channel(tmp_path):
    path, _ = write_platform3d(simulate_platform3d(seed=5), tmp_path / "p.csv")
    rec = read_platform3d(path)
    result = Platform3DCalibrator(diagnose=False).fit(rec)
    assert health_warnings(result) == [] and set(result.to_json()["channel_health"]) == {"mx", "my", "mz"}
    mag = rec.mag.copy()
    mag[:, 1] = np.median(mag[:, 1]) + np.random.default_rng(5).normal(0.0, 1e-3, len(mag))
    with pytest.raises(CannotCalibrate, match="'my' does not (respond to|follow) the field"):
        Platform3DCalibrator(diagnose=False).fit(replace(rec, mag=mag))
    path, _ = write_reference(simulate_reference(seed=6), tmp_path / "r.csv")
    ref = read_reference(path)
    result = ReferenceCalibrator(diagnose=False).fit(ref)
    assert health_warnings(result) == [] and len(result.to_json()["channel_health"]) == 6


def test_calibrate_command_refuses_a_dead_channel_in_one_line(write_session, tmp_path, capsys):
    from compass.cli import main

    rec, truth = write_session(seed=25)
    text = rec.path.read_text() if hasattr(rec.path, "read_text") else open(rec.path).read()
    lines = text.splitlines()
    header_at = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    column = lines[header_at].split(",").index("v3")
    rng = np.random.default_rng(2)
    for i in range(header_at + 1, len(lines)):
        cells = lines[i].split(",")
        cells[column] = f"{truth['offsets'][2] + rng.normal(0.0, 1e-3):.7f}"
        lines[i] = ",".join(cells)
    bad = tmp_path / "dead.csv"
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "dead.json"
    assert main(["calibrate", str(bad), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "dead.csv" in err[0] and "channel 'v3' does not respond" in err[0]
    assert not out.exists()
    assert main(["calibrate", str(bad), "--out", str(out), "--axis-tolerance-deg", "0"]) == 2
    assert "argument --axis-tolerance-deg: must be a number in (0, 180) deg, got 0" in capsys.readouterr().err


def test_a_file_with_a_dead_channel_is_refused_by_every_runtime_command(write_session, tmp_path, capsys):
    import json

    from compass.cli import main

    rec, truth = write_session(seed=26)
    good = tmp_path / "good.json"
    assert main(["calibrate", str(rec.path), "--out", str(good), "--quiet", "--no-diagnose"]) == 0
    capsys.readouterr()
    doc = json.loads(good.read_text())
    entry = doc["channels"]["v2"]
    entry["response"]["gain"] = 3.0 * entry["response_sigma"]["gain"]  # within 5 sigma of zero: dead
    bad = tmp_path / "dead.json"
    bad.write_text(json.dumps(doc))
    for args in (["attitude", str(bad), str(rec.path), "--out", str(tmp_path / "att.csv")],
                 ["export", str(bad), "--format", "fusion", "--out", str(tmp_path / "cal.h")]):
        assert main(args) == 2, args
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "dead.json" in err[0] and "channel 'v2'" in err[0] and "does not respond" in err[0], err
    assert not (tmp_path / "att.csv").exists() and not (tmp_path / "cal.h").exists()


def test_platform3d_drowned_channel_is_warned(tmp_path):
    path, _ = write_platform3d(simulate_platform3d(seed=7), tmp_path / "p.csv")
    rec = read_platform3d(path)
    mag = rec.mag.copy()
    mag[:, 2] += np.random.default_rng(7).normal(0.0, 20 * 0.1, len(mag))  # 20x the simulator's 0.1 uT
    warned = health_warnings(Platform3DCalibrator(diagnose=False).fit(replace(rec, mag=mag)))
    assert len(warned) == 1 and warned[0].startswith("channel mz: signal-to-noise"), warned


def test_reference_dead_and_drowned_channels(tmp_path):
    sim = simulate_reference(seed=8, n_fields=24)
    path, _ = write_reference(sim, tmp_path / "r.csv")
    ref = read_reference(path)
    sensor = ref.sensors[0]
    rng = np.random.default_rng(8)
    drowned = {k: v.copy() for k, v in ref.outputs.items()}
    drowned[sensor][:, 1] += rng.normal(0.0, 20 * 0.05, len(drowned[sensor]))  # 20x the simulator's noise
    warned = health_warnings(ReferenceCalibrator(diagnose=False).fit(replace(ref, outputs=drowned)))
    name = ref.channels[sensor][1]
    assert len(warned) == 1 and warned[0].startswith(f"channel {name}: signal-to-noise"), warned
    dead = {k: v.copy() for k, v in ref.outputs.items()}
    dead[sensor][:, 1] = 1.0 + rng.normal(0.0, 0.01, len(dead[sensor]))
    with pytest.raises(CannotCalibrate, match=f"'{name}' does not (respond to|follow) the field"):
        ReferenceCalibrator(diagnose=False).fit(replace(ref, outputs=dead))
