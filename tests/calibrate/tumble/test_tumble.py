"""Free-motion (tumble) calibration against simulated truth, bad input, and the CLI end to end."""

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.tumble import calibrate_tumble, field_gravity_angles, static_mask
from compass.cli import main
from tests.conftest import assert_calibrate_refuses
from compass.io.tumble import read_tumble
from compass.sim.tumble import simulate_tumble, write_tumble


def shape(s):
    s = np.asarray(s, float)
    return s / np.cbrt(np.linalg.det(s))


def test_full_ellipsoid_recovers_truth_despite_outliers():
    sim = simulate_tumble(seed=3, n=3000, outlier_fraction=0.05, motion_g=0.0)
    res = calibrate_tumble(sim.mag, sim.accel)
    assert res.ellipsoid == "full"
    tol_h = 4 * res.fit.hard_iron_sigma + 1e-3
    assert np.all(np.abs(res.hard_iron - sim.truth["hard_iron"]) < tol_h)
    assert np.all(np.abs(res.fit.soft_iron - shape(sim.truth["soft_iron"])) < 4 * res.fit.soft_iron_sigma + 1e-4)
    # the noise sets the residual: rms within 20 % of the injected noise
    assert abs(np.sqrt(np.mean(res.fit.residuals[res.fit.inliers] ** 2)) / sim.truth["noise_ut"] - 1) < 0.2
    # most disturbed samples are rejected
    flagged = ~res.fit.inliers
    assert flagged[sim.truth["outlier_rows"]].mean() > 0.5
    # misalignment: the rotation error within 4 sigma (largest axis sigma)
    mis = res.misalignment
    err = Rotation.from_matrix(sim.truth["mag_to_accel"]).inv() * mis.rotation
    assert np.degrees(err.magnitude()) < 4 * np.linalg.norm(mis.rotvec_sigma_deg)
    assert abs(mis.dip_deg - sim.truth["dip_deg"]) < 4 * mis.dip_sigma_deg + 0.05
    eig = np.linalg.eigvalsh(res.soft_iron)
    assert np.all(eig > 0)


def test_sphere_truth_chooses_offset_kind():
    sim = simulate_tumble(seed=4, n=1500, soft_iron=0.0, misalign_deg=0.0)
    res = calibrate_tumble(sim.mag)
    assert res.ellipsoid == "offset"
    assert np.all(np.abs(res.hard_iron - sim.truth["hard_iron"]) < 4 * res.fit.hard_iron_sigma + 1e-3)
    assert res.misalignment is None and res.mag_to_accel is None


def test_poor_coverage_warns_in_words_and_falls_back():
    sim = simulate_tumble(seed=5, n=2000, coverage="upright")
    res = calibrate_tumble(sim.mag, sim.accel)
    assert res.ellipsoid != "full"
    assert "+Z" in res.coverage.missing
    text = " ".join(res.warnings)
    assert "never pointed along" in text and "+Z" in text
    assert np.all(np.linalg.eigvalsh(res.soft_iron) > 0) and np.linalg.det(res.soft_iron) > 0
    # do no harm on the field-gravity angle
    st = static_mask(sim.accel)
    raw = np.std(field_gravity_angles(sim.mag - np.mean(sim.mag, axis=0), sim.accel)[st])
    cal = np.std(field_gravity_angles(res.calibrated(sim.mag), sim.accel, res.misalignment.rotation)[st])
    assert cal < raw


def test_forced_kind_and_known_field():
    sim = simulate_tumble(seed=6, n=1500)
    res = calibrate_tumble(sim.mag, ellipsoid="diagonal", field_ut=50.0)
    assert res.ellipsoid == "diagonal" and [c.ellipsoid for c in res.candidates] == ["offset", "diagonal"]
    norms = np.linalg.norm(res.calibrated(sim.mag), axis=1)
    assert abs(np.median(norms) - 50.0) < 1.0
    with pytest.raises(ValueError, match="ellipsoid must be"):
        calibrate_tumble(sim.mag, ellipsoid="sphere")


def test_repeated_values_are_dropped(tmp_path):
    sim = simulate_tumble(seed=7, n=600, hold=5)
    path, _ = write_tumble(sim, tmp_path / "rec.csv")
    rec = read_tumble(path)
    assert len(rec.mag) == 120 and rec.n_repeats == 480


def test_cli_end_to_end_and_exports(tmp_path, capsys):
    sim = simulate_tumble(seed=8, n=1500)
    rec, _ = write_tumble(sim, tmp_path / "rec.csv")
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(rec), "--out", str(cal)]) == 0
    data = json.loads(cal.read_text())
    assert data["format"] == "compass-calibration/1" and data["model"] == "tumble"
    h, s = np.array(data["hard_iron"]), np.array(data["soft_iron"])
    assert s.shape == (3, 3) and h.shape == (3,) and data["field_norm"] > 0
    c = np.array(data["mag_to_accel"])
    np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-9)
    m = (sim.mag - h) @ s.T
    assert np.std(np.linalg.norm(m, axis=1)) / data["field_norm"] < 0.02
    capsys.readouterr()
    # the simulated mag-to-accel rotation is a few degrees: left out beyond the default 1 deg only when asked
    assert main(["export", str(cal), "--format", "ardupilot", "--max-rotation-deg", "10"]) == 0
    out = capsys.readouterr().out
    params = dict(line.split(",") for line in out.splitlines() if not line.startswith("#"))
    np.testing.assert_allclose([float(params[f"COMPASS_OFS_{a}"]) for a in "XYZ"], -10 * h, atol=1e-3)
    assert set(params) == {f"COMPASS_{k}_{a}" for k in ("OFS", "DIA", "ODI") for a in "XYZ"}
    assert main(["export", str(cal), "--format", "fusion"]) == 0
    assert "softIronMatrix" in capsys.readouterr().out


@pytest.mark.parametrize(
    "text, expected",
    [
        ("mx,my\n1,2\n", "column 'mz'"),
        ("mx,my,mz,ax,ay\n" + "1,2,3,0,0\n" * 3, "column 'az'"),
        ("mx,my,mz\n" + "".join(f"{i},1,1\n" for i in range(5)), "at least 12"),
        ("t_s,mx,my,mz\n" + "".join(f"{t},{t},1,1\n" for t in (0, 1, 2, 1, 4)), "row 5, column 't_s'"),
        ("mx,my,mz\n1,2,x\n", "row 2, column 'mz'"),
    ],
)
def test_bad_tumble_recordings_exit_2(tmp_path, capsys, text, expected):
    assert_calibrate_refuses(tmp_path, capsys, text, expected, "--kind", "tumble")


def test_export_rejects_other_files(tmp_path, capsys):
    bad = tmp_path / "cal.json"
    bad.write_text(json.dumps({"format": "other/2"}))
    assert main(["export", str(bad), "--format", "fusion"]) == 2
    assert "unknown calibration format" in capsys.readouterr().err
    bad.write_text(json.dumps({"format": "compass-calibration/1", "channels": {}}))
    assert main(["export", str(bad), "--format", "fusion"]) == 2


def test_hard_iron_step_partway_is_refused_not_written(tmp_path, capsys):
    # a magnet attached halfway through: two spheres, no ellipsoid; the fit must not pass off a huge sphere
    sim = simulate_tumble(seed=9, n=1500)
    mag = sim.mag.copy()
    mag[750:] += np.array([0.6, -0.5, 0.62]) * 150.0
    res = calibrate_tumble(mag, sim.accel)
    assert res.refused and "field changed during the recording" in res.refused
    assert res.refused in res.warnings and res.fit.degenerate and res.misalignment is None
    stepped = dataclasses.replace(sim, mag=mag)
    rec, _ = write_tumble(stepped, tmp_path / "step.csv")
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(rec), "--out", str(cal)]) == 2
    err = capsys.readouterr().err
    assert "step.csv" in err and "no usable calibration" in err and not cal.exists()
    # the same device without the magnet is fine
    assert not calibrate_tumble(sim.mag, sim.accel).refused


def test_fit_that_widens_the_field_gravity_angle_is_refused():
    # an already calibrated device carried where the field is 20 % weaker halfway through: the raw
    # readings keep the dip exactly, any single ellipsoid through both spheres bends it
    sim = simulate_tumble(seed=0, n=2000, hard_iron_ut=0.0, soft_iron=0.0, misalign_deg=0.0, motion_g=0.01)
    mag = sim.mag.copy()
    mag[1000:] *= 0.8
    res = calibrate_tumble(mag, sim.accel)
    assert "widens the spread of the field-gravity angle" in res.refused and res.refused in res.warnings
    static = static_mask(sim.accel)
    raw = np.std(field_gravity_angles(mag[static], sim.accel[static]))
    fitted = np.std(field_gravity_angles(res.calibrated(mag)[static], sim.accel[static], res.misalignment.rotation))
    assert fitted > 1.05 * raw
    # the same device in one field is not refused (do no harm cuts both ways)
    assert not calibrate_tumble(sim.mag, sim.accel).refused


def test_uncalibrated_accelerometer_alone_does_not_refuse_a_right_calibration():
    # a platform recording (constant field, accelerometer with 2 % gains and 0.04 g offsets): the right
    # magnetometer calibration agrees worse with this accelerometer than the raw readings do, but
    # |m| shows no structure, so nothing says the field changed
    from compass.sim.platform3d import simulate_platform3d

    sim = simulate_platform3d(seed=47, tilt_axes=3)
    res = calibrate_tumble(sim.mag, sim.tilt)
    static = static_mask(sim.tilt)
    raw = np.std(field_gravity_angles(sim.mag[static], sim.tilt[static]))
    fitted = np.std(field_gravity_angles(res.calibrated(sim.mag)[static], sim.tilt[static]))
    assert fitted > 1.05 * raw and not res.diagnosis.block["unexplained"]
    assert not res.refused


def test_a_final_fit_that_did_not_converge_is_a_warning_the_export_refuses(monkeypatch):
    from calibrate.tumble import diagnosis
    from compass.production.figures import classify_warning

    fitted = diagnosis.plain_fit

    def stopped(*args, **kwargs):  # the diagnosis's fit, stopped still on its way
        res = fitted(*args, **kwargs)
        res.success, res.message = False, ("Number of calls to function has reached maxfev = 1000.; the next "
                                           "Gauss-Newton step would still move it 3 standard errors")
        return res

    sim = simulate_tumble(seed=1, n=1500)
    assert not any(w.startswith(diagnosis.NOT_CONVERGED_WARNING) for w in calibrate_tumble(sim.mag, sim.accel).warnings)
    monkeypatch.setattr(diagnosis, "plain_fit", stopped)
    res = calibrate_tumble(sim.mag, sim.accel)
    words = [w for w in res.warnings if w.startswith(diagnosis.NOT_CONVERGED_WARNING)]
    assert len(words) == 1 and "maxfev = 1000" in words[0], res.warnings
    assert classify_warning(words[0]) == "not_converged"
    assert words[0] in res.to_json()["warnings"] and "not converged" in res.report()
