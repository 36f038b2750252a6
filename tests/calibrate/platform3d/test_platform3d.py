"""Seed 001's 3-D platform method: conventions by hand, simulated truth, identifiability, runtime heading, CLI."""

import dataclasses
import json

import numpy as np
import pytest

from calibrate.contract import CannotCalibrate as NotIdentifiable
from calibrate.platform3d import axis_geometry, calibrate_platform3d
from compass.attitude import solve_attitude
from compass.cli import main
from tests.conftest import assert_calibrate_refuses
from compass.io.platform3d import TiltSensor, platform_rotation, read_platform3d
from compass.sim.platform3d import simulate_platform3d, write_platform3d
from compass.calibration import load as load_calibration, model_from_dict


def fit(tmp_path, name="rec.csv", **kwargs):
    sim = simulate_platform3d(**kwargs)
    path, _ = write_platform3d(sim, tmp_path / name)
    return sim, read_platform3d(path), calibrate_platform3d(read_platform3d(path))


def test_platform_angles_follow_spec_frames():
    # right-handed about bench +Z, the middle gimbal's +Y, the housing's +X (SPEC section 1)
    np.testing.assert_allclose(platform_rotation(90, 0, 0).apply([1, 0, 0])[0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(platform_rotation(0, 90, 0).apply([1, 0, 0])[0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(platform_rotation(0, 0, 90).apply([0, 1, 0])[0], [0, 0, 1], atol=1e-12)
    # z outermost: the housing X, tipped down by y = 90, stays vertical whatever z
    np.testing.assert_allclose(platform_rotation(40, 90, 0).apply([1, 0, 0])[0], [0, 0, -1], atol=1e-12)


def test_axis_geometry_of_known_axes():
    rot = np.radians(3.0)
    q = np.array([[np.cos(rot), np.sin(rot), 0], [-np.sin(rot), np.cos(rot), 0], [0, 0, 1]])  # v_sensor = q v_H
    g = axis_geometry(np.diag([2.0, 3.0, 4.0]) @ q)
    np.testing.assert_allclose(g[:3], [2, 3, 4])
    np.testing.assert_allclose(g[3:6], 0, atol=1e-12)
    np.testing.assert_allclose(g[6:], [0, 0, -3.0], atol=1e-9)  # q turns H vectors by -3 deg about Z
    tipped = np.array([[1.0, np.tan(np.radians(1.0)), 0], [0, 1, 0]])
    np.testing.assert_allclose(axis_geometry(tipped)[2], -1.0, atol=1e-9)  # 89 deg between the axes


@pytest.mark.parametrize("tilt_axes", [2, 3])
def test_recovers_simulated_truth_within_sigma(tmp_path, tilt_axes):
    sim, rec, res = fit(tmp_path, seed=11, tilt_axes=tilt_axes)
    t = sim.truth
    # residuals at the injected noise; chi2 near 1 because repeats give the noise independently
    np.testing.assert_allclose(np.sqrt(np.mean(res.residuals_mag**2)), t["noise_mag"], rtol=0.15)
    np.testing.assert_allclose(np.sqrt(np.mean(res.residuals_tilt**2)), t["noise_tilt"], rtol=0.15)
    sig = res.sigma
    assert np.all(np.abs(res.mag_matrix.ravel() - np.ravel(t["mag_matrix"])) < 4.5 * sig[:9])
    assert np.all(np.abs(res.mag_offset - t["mag_offset"]) < 4.5 * sig[9:12])
    k = 14 + 3 * tilt_axes
    assert np.all(np.abs(res.tilt_matrix.ravel() - np.ravel(t["tilt_matrix"])) < 4.5 * sig[14:k])
    d = res.derived
    for name, truth in (("dip_deg", t["dip_deg"]), ("field_azimuth_deg", np.mod(t["azimuth_deg"], 360)),
                        ("base_tilt_x_deg", t["base_tilt_deg"][0]), ("base_tilt_y_deg", t["base_tilt_deg"][1])):
        assert abs(d[name][0] - truth) < 4.5 * d[name][1], name
    # derived geometry against the same quantities of the true matrices
    geo_true = np.concatenate([axis_geometry(np.array(t["mag_matrix"])), axis_geometry(np.array(t["tilt_matrix"]))])
    names = [n for n in d if n.startswith(("mag_scale", "mag_non", "mag_rotvec", "tilt_"))]
    err = np.array([d[n][0] for n in names]) - geo_true
    assert np.all(np.abs(err) < 4.5 * np.array([d[n][1] for n in names]))


def test_doubling_noise_doubles_sigma(tmp_path):
    _, _, one = fit(tmp_path, "a.csv", seed=12, noise_ut=0.1, noise_g=0.001)
    _, _, two = fit(tmp_path, "b.csv", seed=12, noise_ut=0.2, noise_g=0.002)
    ratio = two.sigma / one.sigma
    np.testing.assert_allclose(np.median(ratio), 2.0, rtol=0.1)


def test_platform_zero_is_a_gauge_of_the_field_azimuth(tmp_path):
    _, rec, res = fit(tmp_path, seed=13)
    turned = dataclasses.replace(rec, angles_deg=rec.angles_deg + [30.0, 0.0, 0.0])
    res2 = calibrate_platform3d(turned)
    shift = np.mod(res2.derived["field_azimuth_deg"][0] - res.derived["field_azimuth_deg"][0] + 180, 360) - 180
    # the base level error turns with the platform zero too, so only M, A and the dip are unchanged
    assert abs(shift - 30.0) < 1e-4  # readings 30 deg higher: the zero moved back by 30 deg
    np.testing.assert_allclose(res2.mag_matrix, res.mag_matrix, atol=1e-6)
    assert abs(res2.dip_deg - res.dip_deg) < 1e-6


def test_turntable_only_is_refused_in_words(tmp_path):
    with pytest.raises(NotIdentifiable, match="never tilted"):
        fit(tmp_path, seed=14, poses="turntable")


def test_heading_through_the_runtime_solver(tmp_path):
    _, _, res = fit(tmp_path, seed=15, tilt_axes=2)
    data = res.to_json()
    model, tilt = model_from_dict(data), TiltSensor.from_json(data)
    check = simulate_platform3d(seed=15, tilt_axes=2, poses="random", repeats=1)  # same sensors, new poses
    upright = check.pitch_deg**2 + check.roll_deg**2 < 60.0**2  # a two-axis sensor needs the upper hemisphere
    att = solve_attitude(model, check.mag[upright], accel=tilt.up(check.tilt[upright]), accel_noise_g=0.001)
    err = np.mod(att.heading_deg - check.heading_deg[upright] + 180, 360) - 180
    # heading error consistent with its propagated sigma, and far below an uncalibrated reading's
    assert np.sqrt(np.mean((err / att.heading_sigma_deg) ** 2)) < 1.5
    assert np.max(np.abs(err)) < 1.0
    np.testing.assert_allclose(att.pitch_deg, check.pitch_deg[upright], atol=0.3)


def test_cli_end_to_end(tmp_path, capsys):
    rec = tmp_path / "p3.csv"
    assert main(["simulate", "platform3d", "--out", str(rec), "--seed", "3", "--tilt-axes", "3"]) == 0
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(rec), "--out", str(cal)]) == 0
    out = capsys.readouterr().out
    assert "3-D platform calibration" in out and "dip" in out
    data = json.loads(cal.read_text())
    assert data["method"] == "platform3d" and set(data["channels"]) == {"mx", "my", "mz"}
    assert len(data["tilt_sensor"]["matrix"]) == 3 and data["platform3d"]["parameters"]["dip_deg"]["sigma"] > 0
    load_calibration(cal).model
    bad = tmp_path / "flat.csv"
    assert main(["simulate", "platform3d", "--out", str(bad), "--poses", "turntable"]) == 0
    assert main(["calibrate", str(bad), "--out", str(tmp_path / "c2.json")]) == 2
    err = capsys.readouterr().err
    assert "flat.csv" in err and "never tilted" in err


@pytest.mark.parametrize(
    "text, expected",
    [
        ("platform_z_deg,platform_y_deg,mx,my,mz,ax,ay\n0,0,1,2,3,0,0\n", "column 'platform_x_deg'"),
        ("platform_z_deg,platform_y_deg,platform_x_deg,mx,my,mz,ax\n0,0,0,1,2,3,0\n", "column 'ay'"),
        ("platform_z_deg,platform_y_deg,platform_x_deg,mx,my,mz,ax,ay\n"
         + "".join(f"{z},0,0,1,2,3,0,0\n" for z in range(5)), "at least 12"),
        ("platform_z_deg,platform_y_deg,platform_x_deg,mx,my,mz,ax,ay\n0,0,0,1,2,x,0,0\n", "row 2, column 'mz'"),
    ],
)
def test_bad_recordings_exit_2(tmp_path, capsys, text, expected):
    assert_calibrate_refuses(tmp_path, capsys, text, expected)


def test_attitude_command_reads_the_tilt_sensor(tmp_path):
    """`compass attitude` with a platform calibration turns ax, ay into 'up' through its tilt sensor."""
    import csv

    _, _, res = fit(tmp_path, seed=16, tilt_axes=2)
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(res.to_json()))
    check = simulate_platform3d(seed=16, tilt_axes=2, poses="random", repeats=1)
    upright = check.pitch_deg**2 + check.roll_deg**2 < 60.0**2
    rec = tmp_path / "run.csv"
    with rec.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["mx", "my", "mz", "ax", "ay"])
        w.writerows(np.hstack([check.mag[upright], check.tilt[upright]]).tolist())
    out = tmp_path / "att.csv"
    assert main(["attitude", str(cal), str(rec), "--out", str(out), "--accel-noise-g", "0.001"]) == 0
    from compass.io.table import read_table

    heading = read_table(out).column("heading_deg")
    err = np.mod(heading - check.heading_deg[upright] + 180, 360) - 180
    assert np.max(np.abs(err)) < 1.0


def test_attitude_command_bad_tilt_sensor_exits_2(tmp_path, capsys):
    _, _, res = fit(tmp_path, seed=16, tilt_axes=2)
    data = res.to_json()
    data["tilt_sensor"]["matrix"] = [[1.0]]
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(data))
    rec = tmp_path / "run.csv"
    rec.write_text("mx,my,mz,ax,ay\n1,2,3,0,0\n")
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "att.csv")]) == 2
    err = capsys.readouterr().err
    assert "cal.json: 'tilt_sensor'" in err and "failed" not in err
