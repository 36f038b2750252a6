"""The bench accelerometer's alignment with the housing (mag_to_accel) and the turntable's tilt, from the flips."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate import calibrate_fourflip
from calibrate.fourflip.accelerometer import fit_accelerometer
from compass.calibration import CalibrationFileError, from_dict
from compass.sim.fourflip import SimAccelerometer, simulate_fourflip
from compass.sim.runtime import simulate_runtime

PULL = 4.0  # sigmas


def _truth(session, name):
    return next(e["parameters"] for e in session.truth["effects"] if e["name"] == name)


def _rotation_error_deg(result, session):
    """Rotation vector (deg, accelerometer frame) of the estimated mag_to_accel against the injected one."""
    est = Rotation.from_matrix(np.array(result.extra["mag_to_accel"]))
    true = Rotation.from_matrix(np.array(_truth(session, "accelerometer")["mag_to_accel"]))
    return (est * true.inv()).as_rotvec(degrees=True)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_injected_misalignment_recovered_within_its_sigma(seed):
    acc = SimAccelerometer(misalign_deg=1.0, noise_g=0.003, offset_g=0.01, scale_error=0.005)
    session = simulate_fourflip(seed=seed, accelerometer=acc, turntable_tilt_deg=0.3)
    result = calibrate_fourflip(session.recording(), diagnose=False)
    block = result.extra["accelerometer"]
    err = _rotation_error_deg(result, session)
    sigma = np.array(block["mag_to_accel_rotvec_sigma_deg"])
    assert np.all(np.abs(err) < PULL * sigma), (err, sigma)
    # the sigma follows the injected noise: a turn mean of n samples, two flips a pair, 1 g lever
    n = np.sum(session.samples.flip_index == 0)
    assert 0.5 < np.linalg.norm(sigma) / np.degrees(acc.noise_g / np.sqrt(n)) < 3.0
    assert np.allclose(block["offset"], _truth(session, "accelerometer")["offset_g"], atol=PULL * acc.noise_g / np.sqrt(n))


def test_more_noise_more_sigma():
    sigmas = []
    for noise_g in (0.002, 0.008):
        session = simulate_fourflip(seed=4, accelerometer=SimAccelerometer(noise_g=noise_g))
        block = calibrate_fourflip(session.recording(), diagnose=False).extra["accelerometer"]
        sigmas.append(np.linalg.norm(block["mag_to_accel_rotvec_sigma_deg"]))
    assert 3.0 < sigmas[1] / sigmas[0] < 5.0


@pytest.mark.parametrize("seed", [0, 3])
def test_turntable_tilt_measured_and_dip_referred_to_gravity(seed):
    session = simulate_fourflip(seed=seed, accelerometer=SimAccelerometer(), turntable_tilt_deg=0.3)
    result = calibrate_fourflip(session.recording(), diagnose=False)
    block = result.extra["accelerometer"]
    tilt = _truth(session, "turntable_tilt")
    up = np.array(tilt["up_in_turntable_frame"][:2])
    err = np.array(block["turntable_up_xy"]) - up
    cov = np.array(block["turntable_up_xy_covariance"])
    assert err @ np.linalg.solve(cov, err) < PULL**2
    # the magnetic fit measures the dip against the turntable axis; the tilt refers it to gravity
    axis_sigma = float(np.degrees(result.parameters["dip_rad"][1]))
    assert abs(block["dip_turntable_axis_deg"] - tilt["dip_against_axis_deg"]) < PULL * axis_sigma
    assert abs(result.dip_deg - session.truth["dip_deg"]) < PULL * result.dip_sigma_deg
    assert result.dip_deg == block["dip_gravity_deg"]
    shift = abs(tilt["dip_against_axis_deg"] - session.truth["dip_deg"])
    if shift > 10 * axis_sigma:
        assert any("turntable is tilted" in w for w in result.warnings)


def test_level_turntable_reads_level_and_says_nothing():
    session = simulate_fourflip(seed=5, accelerometer=SimAccelerometer(misalign_deg=0.5))
    result = calibrate_fourflip(session.recording(), diagnose=False)
    block = result.extra["accelerometer"]
    assert block["turntable_tilt_deg"] < PULL * block["turntable_tilt_sigma_deg"]
    assert abs(block["dip_gravity_deg"] - result.dip_deg) < PULL * block["dip_gravity_sigma_deg"]
    assert not [w for w in result.warnings if w.startswith("accelerometer")]


def test_accelerometer_leaves_the_magnetic_session_and_fit_alone():
    plain = simulate_fourflip(seed=6)
    with_acc = simulate_fourflip(seed=6, accelerometer=SimAccelerometer())
    assert np.array_equal(plain.outputs, with_acc.outputs)
    a, b = (calibrate_fourflip(s.recording(), diagnose=False) for s in (plain, with_acc))
    assert np.array_equal(a.directions, b.directions)
    assert b.extra["accelerometer"]["dip_turntable_axis_deg"] == a.dip_deg  # the magnetic fit, untouched
    assert "mag_to_accel" not in a.to_json() and "accelerometer" not in a.to_json()


def test_rotating_the_accelerometer_composes_the_rotation():
    session = simulate_fourflip(seed=7, accelerometer=SimAccelerometer(misalign_deg=0.8))
    rec = session.recording()
    q = Rotation.from_euler("xyz", [3.0, -2.0, 5.0], degrees=True)
    base = fit_accelerometer(rec.accel, rec.platform_deg, rec.flip_deg, rec.flip_index)
    turned = fit_accelerometer(q.apply(rec.accel), rec.platform_deg, rec.flip_deg, rec.flip_index)
    expected = q * Rotation.from_matrix(base.mag_to_accel)
    # exact but for the per-axis scales, which a turned accelerometer mixes (second order): far below sigma
    moved = np.degrees(np.linalg.norm((Rotation.from_matrix(turned.mag_to_accel) * expected.inv()).as_rotvec()))
    assert moved < 0.1 * np.linalg.norm(base.rotvec_sigma_deg)
    assert abs(turned.tilt_deg - base.tilt_deg) < 0.1 * base.tilt_sigma_deg


def test_flip_errors_from_the_magnetic_fit_are_used():
    """A cube face off square turns gravity in H: with the fitted flip errors the fit stays square."""
    session = simulate_fourflip(seed=8, effects=("flip_error",), effect_scale=1.5, accelerometer=SimAccelerometer())
    rec = session.recording()
    true_errors = np.array(_truth(session, "flip_error")["flip_rotvec_deg"])[:, 0]
    blind = fit_accelerometer(rec.accel, rec.platform_deg, rec.flip_deg, rec.flip_index)
    told = fit_accelerometer(rec.accel, rec.platform_deg, rec.flip_deg, rec.flip_index, flip_errors_deg=true_errors)
    assert abs(told.orthogonality_deg) < PULL * told.orthogonality_sigma_deg
    assert abs(blind.orthogonality_deg) > PULL * blind.orthogonality_sigma_deg
    assert any("off square" in w for w in blind.warnings)
    result = calibrate_fourflip(rec, diagnose=True)
    assert "flip_error" in [e["name"] for e in result.effects]
    err = _rotation_error_deg(result, session)
    assert np.all(np.abs(err) < PULL * np.array(result.extra["accelerometer"]["mag_to_accel_rotvec_sigma_deg"]))


def test_inconsistent_accelerometer_is_warned_in_words():
    session = simulate_fourflip(seed=9, accelerometer=SimAccelerometer(misalign_deg=0.3))
    rec = session.recording()
    swapped = rec.accel[:, [1, 0, 2]] * [1, -1, 1]  # x and y swapped: 90 deg about z
    fit = fit_accelerometer(swapped, rec.platform_deg, rec.flip_deg, rec.flip_index)
    assert any("not the housing's" in w for w in fit.warnings)
    assert abs(abs(fit.rotvec_deg[2]) - 90.0) < 1.0
    negated = fit_accelerometer(-rec.accel, rec.platform_deg, rec.flip_deg, rec.flip_index)
    assert any("--accel-sign -1" in w for w in negated.warnings)
    shaken = rec.accel * (1 + 0.05 * np.random.default_rng(0).normal(size=(len(rec.accel), 1)))
    assert any("not at rest" in w for w in fit_accelerometer(shaken, rec.platform_deg, rec.flip_deg,
                                                              rec.flip_index).warnings)
    dead = np.tile([0.0, 0.0, 1.0], (len(rec.accel), 1))
    with pytest.raises(ValueError, match="does not see gravity"):
        fit_accelerometer(dead, rec.platform_deg, rec.flip_deg, rec.flip_index)


def test_dead_accelerometer_leaves_the_calibration_with_a_warning():
    session = simulate_fourflip(seed=9)
    rec = session.recording()
    from dataclasses import replace

    rec = replace(rec, accel=np.tile([0.0, 0.0, 1.0], (rec.n_samples, 1)))
    result = calibrate_fourflip(rec, diagnose=False)
    assert "mag_to_accel" not in result.extra
    assert any(w.startswith("accelerometer not used") for w in result.warnings)


def test_attitude_pitch_roll_free_of_the_misalignment(tmp_path):
    """compass attitude rotates the accelerometer into H: pitch and roll errors drop to the noise."""
    from compass.commands.attitude import attitude_file
    from compass.sim.runtime import write_runtime

    session = simulate_fourflip(seed=10, accelerometer=SimAccelerometer(misalign_deg=1.0, noise_g=0.002))
    doc = calibrate_fourflip(session.recording(), diagnose=False).to_json()
    cal, ignored = tmp_path / "cal.json", tmp_path / "ignored.json"
    cal.write_text(json.dumps(doc))
    ignored.write_text(json.dumps({k: v for k, v in doc.items() if k != "mag_to_accel"}))
    runtime = simulate_runtime(session.truth, 300, seed=1, max_tilt_deg=40.0)
    rec, truth = write_runtime(runtime, tmp_path / "att.csv")
    errors = {}
    for name, path in (("after", cal), ("before", ignored)):
        res = attitude_file(path, rec, tmp_path / f"{name}.csv")
        errors[name] = np.sqrt(np.mean(np.concatenate([res.pitch_deg - runtime.pitch_deg,
                                                        res.roll_deg - runtime.roll_deg]) ** 2))
        sigma = np.sqrt(np.mean(np.concatenate([res.pitch_sigma_deg, res.roll_sigma_deg]) ** 2))
    assert "accel_frame: rotated into the housing" in (tmp_path / "after.csv").read_text()
    assert "accel_frame" not in (tmp_path / "before.csv").read_text()
    assert errors["after"] < 1.5 * sigma  # at the noise
    assert errors["before"] > 3 * errors["after"]


def test_mag_to_accel_must_be_a_rotation():
    session = simulate_fourflip(seed=11, accelerometer=SimAccelerometer())
    doc = calibrate_fourflip(session.recording(), diagnose=False).to_json()
    from_dict(doc)  # accepted
    doc["mag_to_accel"] = (2 * np.eye(3)).tolist()
    with pytest.raises(CalibrationFileError, match="mag_to_accel"):
        from_dict(doc)


def test_written_recording_carries_the_accelerometer(write_session):
    rec, truth = write_session(seed=12, accelerometer=SimAccelerometer())
    assert rec.accel is not None and rec.accel.shape == (rec.n_samples, 3)
    assert any(e["name"] == "accelerometer" for e in truth["effects"])
    assert np.allclose(np.linalg.norm(rec.accel, axis=1), 1.0, atol=0.02)


def test_cli_simulates_and_calibrates_the_accelerometer(tmp_path, capsys):
    from compass.cli import main

    rec, cal = tmp_path / "rec.csv", tmp_path / "cal.json"
    assert main(["simulate", "fourflip", "--out", str(rec), "--seed", "2", "--accel-misalign-deg", "1",
                 "--turntable-tilt-deg", "0.3"]) == 0
    assert "ax,ay,az" in rec.read_text()
    assert main(["calibrate", str(rec), "--out", str(cal), "--no-diagnose"]) == 0
    doc = json.loads(cal.read_text())
    truth = json.loads((tmp_path / "rec.truth.json").read_text())
    assert abs(doc["dip_deg"] - truth["dip_deg"]) < PULL * doc["dip_sigma_deg"]
    assert np.array(doc["mag_to_accel"]).shape == (3, 3)
    assert "turntable is tilted" in capsys.readouterr().out


def test_imu_rotation_into_the_model_frame_composes_bench_and_installation():
    from compass.calibration import ImuCorrection

    session = simulate_fourflip(seed=13, accelerometer=SimAccelerometer())
    doc = calibrate_fourflip(session.recording(), diagnose=False).to_json()
    imu = from_dict(doc).imu
    m = np.array(doc["mag_to_accel"])
    assert np.allclose(imu.rotation, m.T)
    a = np.array([[0.1, 0.2, 0.97]])
    # the bench's offsets (none simulated: noise-small) and Y/Z scales undone first
    assert np.all(np.abs(imu.offset) < 0.002) and np.all(np.abs(imu.scale - 1) < 0.002) and imu.scale[0] == 1.0
    assert np.allclose(imu.apply(a), (a - imu.offset) / imu.scale @ m)  # a_H = m^T a
    assert np.allclose(imu.apply(a, bench=False), a @ m)
    align = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    installed = {"format": doc["format"], "model": "installed", "base": doc,
                 "installation": {"hard_iron_ut": [0.0, 0.0, 0.0], "soft_iron": np.eye(3).tolist(),
                                  "alignment": align.tolist()}}
    both = from_dict(installed).imu
    assert np.allclose(both.rotation, align @ m.T) and np.allclose(both.offset, imu.offset)
    assert from_dict({k: v for k, v in doc.items() if k != "mag_to_accel"}).imu.rotation is None
    tumble = from_dict({"format": doc["format"], "model": "tumble", "hard_iron": [0.0, 0.0, 0.0], "field_norm": 50.0,
                        "soft_iron": np.eye(3).tolist(), "mag_to_accel": m.tolist()})  # folded into its model
    assert tumble.imu.rotation is None and np.array_equal(tumble.imu.apply(a), a)
    assert np.allclose(tumble.model.unit_directions, m.T)  # the model itself is in the accelerometer's frame
    with pytest.raises(ValueError, match="offset, scale and one_g together"):
        ImuCorrection(offset=np.zeros(3))


def test_export_puts_the_field_in_the_accelerometer_frame(tmp_path):
    """Fusion expects the magnetometer in the accelerometer's frame: mag_to_accel is folded into the export."""
    from compass.commands.export import firmware_form, read_calibration

    session = simulate_fourflip(seed=14, accelerometer=SimAccelerometer(misalign_deg=1.0))
    doc = calibrate_fourflip(session.recording(), diagnose=False).to_json()
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))
    form = firmware_form(read_calibration(path), ("v1", "v2", "v3"))  # the simulator's channels, along X, Y, Z
    model = from_dict(doc).model
    raw = session.outputs[:5]
    field_accel = (form["mag_to_accel"] @ form["soft_iron"] @ (raw - form["hard_iron"]).T).T
    expected = model.field(raw)[0] @ np.array(doc["mag_to_accel"]).T
    assert np.allclose(field_accel, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


def test_a_knock_is_left_out_and_said():
    session = simulate_fourflip(seed=15, accelerometer=SimAccelerometer(misalign_deg=1.0))
    rec = session.recording()
    knocked = rec.accel.copy()
    knocked[[100, 800], :] += [3.0, -2.0, 4.0]  # two knocks of several g
    fit = fit_accelerometer(knocked, rec.platform_deg, rec.flip_deg, rec.flip_index)
    true = Rotation.from_matrix(np.array(_truth(session, "accelerometer")["mag_to_accel"]))
    err = (Rotation.from_matrix(fit.mag_to_accel) * true.inv()).as_rotvec(degrees=True)
    assert np.all(np.abs(err) < PULL * fit.rotvec_sigma_deg)
    assert fit.glitches_dropped == 2 and any("glitches" in w for w in fit.warnings)
    clean = fit_accelerometer(rec.accel, rec.platform_deg, rec.flip_deg, rec.flip_index)
    assert clean.glitches_dropped == 0  # Gaussian noise: 8 sigma never happens


def test_bench_offsets_and_scales_are_undone_at_runtime_only_in_the_bench_unit():
    """Offsets of 0.02 g, measured on the bench: undone, pitch and roll come back to the aligned accelerometer's
    floor (scale errors would leave the X axis's, which the flips cannot see); the same readings in m/s^2 do not read 1 g as the bench's did, so they only
    get the rotation, with a warning (the bench's offsets are in g)."""
    from compass.attitude import solve_attitude
    from compass.calibration import from_dict
    from compass.io.units import RecordingWarning
    from compass.sim.runtime import simulate_runtime

    session = simulate_fourflip(seed=16, accelerometer=SimAccelerometer(misalign_deg=1.0, offset_g=0.02))
    doc = calibrate_fourflip(session.recording(), diagnose=False).to_json()
    cal = from_dict(doc)
    model, imu = cal.model, cal.imu
    run = simulate_runtime(session.truth, 600, seed=17, max_tilt_deg=40.0)
    aligned = simulate_runtime({**session.truth, "effects": []}, 600, seed=17, max_tilt_deg=40.0)

    def tilt_rms(accel, rt=run):
        att = solve_attitude(model, rt.outputs, accel=accel)
        return float(np.sqrt(np.mean(np.concatenate([att.pitch_deg - rt.pitch_deg, att.roll_deg - rt.roll_deg]) ** 2)))

    floor = tilt_rms(aligned.accel, aligned)
    rotated_only = tilt_rms(imu.apply(run.accel, bench=False))
    corrected, undone = imu.in_model_frame(run.accel)
    assert undone and rotated_only > 3 * floor and tilt_rms(corrected) < 1.2 * floor + 0.01
    with pytest.warns(RecordingWarning, match="does not read 1 g"):
        in_si, undone = imu.in_model_frame(9.80665 * run.accel)
    assert not undone
    np.testing.assert_allclose(in_si, 9.80665 * run.accel @ imu.to_housing.T)
    assert imu.fits(run.accel) and not imu.fits(9.80665 * run.accel)
