"""The gyro's scale and axis errors (``FilterConfig.gyro_matrix``, a tumble file's ``tumble.gyro.gyro_matrix``):
each gyro reading ``w`` is taken as the housing-frame rate ``G w`` before anything else uses it."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.filter import FilterConfig, run_filter
from compass.frames import world_field

FIELD_UT, DIP_DEG, RATE_HZ = 50.0, 60.0, 100.0
SCALE = np.array([0.03, -0.02, 0.025])  # the gyro reads (1 + s) times the true rate about each axis
MAG_NOISE_UT = 0.3


def _recording(seconds=40.0, seed=0):
    """A housing swung back and forth about all three axes (up to ~250 deg/s), exact accelerometer, the field with
    white noise, the gyro ``(1 + SCALE)`` times the true rate; the true ``R_world<-H`` of every row."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    omega = np.column_stack([4.0 * np.sin(2 * np.pi * f * t + p) for f, p in ((0.31, 0.0), (0.23, 1.0), (0.37, 2.0))])
    truth = [Rotation.from_euler("ZYX", [20.0, 10.0, -15.0], degrees=True)]
    for w in omega[1:] / RATE_HZ:
        truth.append(truth[-1] * Rotation.from_rotvec(w))
    truth = Rotation.concatenate(truth)
    accel = truth.apply([0.0, 0.0, 9.81], inverse=True)
    field = truth.apply(world_field(DIP_DEG, FIELD_UT), inverse=True) + rng.normal(0.0, MAG_NOISE_UT, (len(t), 3))
    return t, accel, omega * (1.0 + SCALE), field, truth


def _error_deg(gyro_matrix) -> float:
    """RMS of the whole attitude error (deg) over the second half, the filter given ``gyro_matrix``."""
    t, accel, gyro, field, truth = _recording()
    config = FilterConfig(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=MAG_NOISE_UT, gyro_matrix=gyro_matrix)
    est = Rotation.from_quat(run_filter(t, accel, gyro, field, config, reference="config").quat)
    err = (est * truth.inv()).magnitude()[len(t) // 2:]
    return float(np.degrees(np.sqrt(np.mean(err**2))))


def test_the_gyro_matrix_corrects_a_scaled_gyro():
    as_read = _error_deg(None)
    corrected = _error_deg(tuple(map(tuple, np.diag(1.0 / (1.0 + SCALE)))))
    # 2-3 % of a 250 deg/s swing is several deg/s the filter takes for motion; corrected, the attitude is much closer
    assert corrected < 0.5 * as_read
    # the matrix the other way round (the scale applied twice) is worse than none: it is applied, and its sense matters
    assert _error_deg(tuple(map(tuple, np.diag(1.0 + SCALE)))) > as_read


def test_the_start_window_turns_its_rows_by_the_corrected_gyro():
    """The start's first attitude integrates the gyro over its window (up to 10 s of swinging here): with the matrix
    it does so as the filter does, ``G w``, and the first row's up and field come out as the truth's."""
    from compass.filter._start import FilterStart

    t, accel, gyro, field, truth = _recording(seconds=12.0)
    up_true = truth[0].apply([0.0, 0.0, 1.0], inverse=True)
    field_true = truth[0].apply(world_field(DIP_DEG, FIELD_UT), inverse=True)
    errors = {}
    for name, g in (("as read", None), ("corrected", tuple(map(tuple, np.diag(1.0 / (1.0 + SCALE)))))):
        config = FilterConfig(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=MAG_NOISE_UT, gyro_matrix=g)
        start = FilterStart(config)
        for i in range(len(t)):
            assert start.add(i, t[i], accel[i], gyro[i], field[i]) is None
            if start.done:
                break
        assert start.done and start.values.rows > 100
        up, b = np.array(start.values.up_h), np.array(start.values.field_h)
        errors[name] = (np.degrees(np.arccos(np.clip(up @ up_true, -1.0, 1.0))),
                        np.degrees(np.arccos(np.clip(b @ field_true / np.linalg.norm(b) / FIELD_UT, -1.0, 1.0))))
    # 2-3 % of a swing of ~2 rad about every axis tilts the window's later rows by degrees as read; corrected, the
    # gyro is exact and what is left is the field's noise (0.3 uT on 50: a fraction of a degree, the median)
    assert errors["corrected"][0] < 0.05 and errors["corrected"][1] < 0.3
    assert errors["as read"][0] > 5 * errors["corrected"][0] and errors["as read"][1] > 2 * errors["corrected"][1]


def test_bad_gyro_matrices_are_refused():
    base = dict(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=MAG_NOISE_UT)
    for bad in (((1.0, 0.0), (0.0, 1.0)), ((np.nan, 0, 0), (0, 1, 0), (0, 0, 1)), ((-1, 0, 0), (0, 1, 0), (0, 0, 1))):
        with pytest.raises(ValueError, match="FilterConfig.gyro_matrix must be a finite 3 x 3 matrix"):
            FilterConfig(**base, gyro_matrix=bad)
    assert FilterConfig(**base, gyro_matrix=np.eye(3)).gyro_matrix == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def test_the_filter_takes_the_calibrations_gyro_matrix():
    from compass.sim.device import default_model

    g = np.diag(1.0 / (1.0 + SCALE))
    model = dataclasses.replace(default_model(), gyro_matrix=g)
    np.testing.assert_array_equal(FilterConfig.from_model(model, gyro_matrix=True).gyro_matrix, g)
    assert FilterConfig.from_model(model).gyro_matrix is None  # off by default (BROAD: docs/benchmarks.md)
    assert FilterConfig.from_model(default_model(), gyro_matrix=True).gyro_matrix is None  # a file without one
    with pytest.raises(ValueError, match="gyro_matrix must be a finite 3 x 3 matrix"):
        dataclasses.replace(default_model(), gyro_matrix=-np.eye(3))


def test_live_and_the_replay_apply_the_files_gyro_matrix_alike(tmp_path, capsys):
    """``compass attitude --filter`` and a live session on the same samples: identical with the file's gyro matrix
    (``--gyro-matrix``) and without it (the default), and the two differ."""
    from calibrate.tumble import calibrate_tumble
    from compass.calibration import from_dict, save
    from compass.cli import main
    from compass.sim.device import simulate_device
    from compass.sim.tumble import simulate_tumble
    from tests.compass.filter.test_latency import _write_recording, attitude_and_live_rows

    sim = simulate_tumble(seed=4, n=1500)
    doc = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s).to_json()
    g = np.eye(3) + np.array([[0.02, 0.004, 0.0], [0.0, -0.015, 0.0], [0.0, 0.0, 0.01]])
    sigma = [[1e-3, 1e-3, 0.02], [1e-3, 1e-3, 0.02], [1e-3, 1e-3, None]]  # the z column unseen (the prior's or none)
    doc["tumble"]["gyro"] = {"method": "gyro", "used": True, "gyro_matrix": g.tolist(), "gyro_matrix_sigma": sigma}
    cal = save(tmp_path / "cal.json", doc)
    model = from_dict(doc).model
    np.testing.assert_array_equal(model.gyro_matrix, [[1.02, 0.004, 0.0], [0.0, 0.985, 0.0], [0.0, 0.0, 1.0]])
    t = np.arange(0.0, 15.0, 0.01)
    s = simulate_device(model, t, seed=6)
    rec = _write_recording(tmp_path / "rec.csv", model, t, s)

    outputs = {flag: attitude_and_live_rows(tmp_path, cal, rec, model, t, s, "--gyro-matrix" if flag else None,
                                            FilterConfig.from_model(model, gyro_matrix=flag))
               for flag in (True, False)}
    assert outputs[True] != outputs[False]
    said = capsys.readouterr().err  # the replay says what --gyro-matrix applies, once, only with the flag
    assert said.count("[info] --gyro-matrix: each gyro reading corrected") == 1
    assert "scale x, y, z +2.00, -1.50, +0.00 %, axes up to 0.40 %" in said
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "att.csv"), "--gyro-matrix"]) == 2
    assert "--gyro-matrix goes with --filter" in capsys.readouterr().err


def test_the_gyro_matrix_note_says_what_is_applied_or_why_nothing():
    from compass.replay import gyro_matrix_note
    from compass.sim.device import default_model

    model = dataclasses.replace(default_model(), gyro_matrix=np.eye(3) + np.array([[0.01, 0, 0], [0, 0, -0.012], [0] * 3]))
    level, text = gyro_matrix_note(model)
    assert level == "info" and "scale x, y, z +1.00, +0.00, +0.00 %, axes up to 1.20 %" in text
    level, text = gyro_matrix_note(default_model())
    assert level == "warn" and "no gyro matrix entry its fit saw" in text and "the gyro as read" in text
    assert gyro_matrix_note(model, has_gyro=False) == ("warn", "--gyro-matrix: the recording has no gyro (gx,gy,gz) "
                                                               "to correct: nothing applied")


def test_an_installed_model_carries_the_gyro_matrix_into_the_products_frame():
    # the product's frame reads the gyro turned by the alignment R: its matrix must give R (G w) from R w
    from compass.installed import installed_model
    from compass.sim.device import default_model

    g = np.eye(3) + np.array([[0.02, 0.004, 0.0], [0.0, -0.015, 0.003], [0.001, 0.0, 0.01]])
    base = dataclasses.replace(default_model(), gyro_matrix=g)
    rot = Rotation.from_euler("ZYX", [30.0, -10.0, 5.0], degrees=True).as_matrix()
    w = np.array([0.3, -1.2, 2.0])
    product = installed_model(base, np.zeros(3), np.eye(3), alignment=rot)
    np.testing.assert_allclose(product.gyro_matrix @ (rot @ w), rot @ (g @ w), atol=1e-12)
    np.testing.assert_array_equal(installed_model(base, np.zeros(3), np.eye(3)).gyro_matrix, g)  # no alignment: as is
