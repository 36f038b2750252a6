"""The gyro's scale error the filter allows for (``FilterConfig.gyro_scale_error``): what a tumble file's gyro-aided fit
says remains (``tumble.gyro.gyro_matrix`` and its sigma), ``--gyro-scale-error`` over it, bad values refused."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.filter import DEFAULT_GYRO_SCALE_ERROR, FilterConfig

G = np.eye(3) + np.array([[0.03, 0.004, 0.0], [0.0, -0.025, 0.002], [0.001, 0.0, 0.02]])
SIGMA = np.array([[1e-3, 2e-3, 3e-3], [2e-3, 1e-3, 2e-3], [3e-3, 2e-3, 1.5e-3]])


def _doc(g=G, sigma=SIGMA):
    """A tumble calibration of a simulated sensor with a gyro-aided fit block holding ``g`` and ``sigma``."""
    from calibrate.tumble import calibrate_tumble
    from compass.sim.tumble import simulate_tumble

    sim = simulate_tumble(seed=4, n=1500)
    doc = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s).to_json()
    sigma = [[None if not np.isfinite(v) else float(v) for v in row] for row in np.asarray(sigma, float)]
    doc["tumble"]["gyro"] = {"method": "gyro", "used": True, "gyro_matrix": np.asarray(g).tolist(),
                             "gyro_matrix_sigma": sigma}
    return doc


def test_one_number_bounds_the_rate_error_in_every_direction():
    """The estimate's part is the largest singular value of ``E``: ``|E w| / |w|`` never exceeds it and reaches it
    (over 2e5 spread directions, within 1 %), where the RMS over directions ``||E||_F / sqrt 3`` stays below it;
    ``s`` for ``E = s I``."""
    from compass.calibration import gyro_scale_error

    e = np.array([[0.03, 0.012, 0.0], [0.0, -0.025, 0.011], [0.013, 0.0, 0.02]])  # every nonzero entry seen
    w = np.random.default_rng(0).normal(size=(200_000, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    ratio = np.linalg.norm(w @ e.T, axis=1)
    s = gyro_scale_error(np.eye(3) + e, np.full((3, 3), 1e-9))[1]
    assert ratio.max() <= s * (1 + 1e-6) and ratio.max() > 0.99 * s
    assert np.sqrt(np.mean(ratio**2)) < 0.9 * s
    assert gyro_scale_error(1.03 * np.eye(3), np.full((3, 3), 1e-9))[1] == pytest.approx(0.03, rel=1e-6)


def test_the_sigma_part_bounds_the_fit_errors_mean_square_in_every_direction():
    """``max_j sum_i sigma_ij^2`` bounds ``E|D w|^2 / |w|^2`` for a zero-mean ``D`` of independent entries of those
    sigmas, and is reached along the worst column's axis (Monte Carlo, 1e5 draws: within 2 %)."""
    from compass.calibration import gyro_matrix_seen, gyro_scale_error

    g = np.eye(3) + 0.02 * np.array([[1, -1, 1], [1, 1, -1], [-1, 1, 1]])  # every entry beyond 3 of its sigmas
    sigma = np.array([[1e-3, 3e-3, 1e-3], [1e-3, 3e-3, 1e-3], [2e-3, 1e-3, 1e-3]])  # columns 6, 19, 3 e-6; rows not
    assert gyro_matrix_seen(g, sigma).all()
    applied = gyro_scale_error(g, sigma)[0]
    assert applied == pytest.approx(np.sqrt(19e-6), rel=1e-12)
    d = np.random.default_rng(1).normal(size=(100_000, 3, 3)) * sigma
    w = np.random.default_rng(2).normal(size=(50, 3))
    w = np.vstack([np.eye(3), w / np.linalg.norm(w, axis=1)[:, None]])
    mean_square = np.mean(np.sum(np.einsum("nij,kj->nki", d, w) ** 2, axis=2), axis=0)
    assert mean_square.max() <= applied**2 * 1.02
    assert mean_square[1] == pytest.approx(applied**2, rel=0.02)  # along y, the worst column


def test_from_model_takes_what_the_fit_saw():
    from compass.calibration import from_dict, gyro_matrix_seen

    model = from_dict(_doc()).model
    assert gyro_matrix_seen(G, SIGMA).sum() == 3  # the three diagonal entries: beyond 3 sigma, sigma under 0.5 %
    # by hand: the seen entries' sigmas count, one per column, the worst z's 1.5e-3; the seen diagonal's largest
    # singular value is its largest |entry|, 0.03
    applied = 1.5e-3
    as_read = np.sqrt(0.03**2 + applied**2)
    assert model.gyro_scale_error == pytest.approx((applied, as_read), rel=1e-12)
    floor = DEFAULT_GYRO_SCALE_ERROR
    assert FilterConfig.from_model(model).gyro_scale_error == pytest.approx(np.hypot(floor, as_read), rel=1e-12)
    assert FilterConfig.from_model(model, gyro_matrix=True).gyro_scale_error == pytest.approx(np.hypot(floor, applied),
                                                                                              rel=1e-12)


def test_the_default_stays_without_a_fit_or_where_it_saw_nothing():
    from compass.calibration import from_dict, gyro_scale_error
    from compass.sim.device import default_model

    assert FilterConfig.from_model(default_model()).gyro_scale_error == DEFAULT_GYRO_SCALE_ERROR
    # within 3 sigma of the identity, a sigma the prior made (2 %), a model mismatch (12 %): nothing seen, nothing
    # beyond the default's prior counted (not even the precise sigmas: gyro_scale_error's docstring)
    unseen = from_dict(_doc(np.eye(3) + np.diag([0.002, 0.02, 0.12]), np.diag([1e-3, 0.02, 1e-3]) + 1e-3)).model
    assert unseen.gyro_scale_error == (0.0, 0.0)
    assert FilterConfig.from_model(unseen).gyro_scale_error == DEFAULT_GYRO_SCALE_ERROR
    doc = _doc()
    doc["tumble"]["gyro"]["used"] = False  # a fit the calibration refused says nothing
    assert FilterConfig.from_model(from_dict(doc).model).gyro_scale_error == DEFAULT_GYRO_SCALE_ERROR
    sigma = SIGMA.copy()
    sigma[0, 0] = np.inf  # no sigma: not seen, not counted; yy and zz remain
    assert gyro_scale_error(G, sigma) == pytest.approx((1.5e-3, np.sqrt(0.025**2 + 1.5e-3**2)), rel=1e-12)


def test_garbage_gyro_block_is_refused_by_the_scale_error_alone():
    """``_gyro_scale_error`` checks the block itself (not relying on ``_gyro_matrix`` having run first)."""
    from compass.calibration import CalibrationFileError
    from compass.calibration._read import _gyro_scale_error

    with pytest.raises(CalibrationFileError, match="tumble.gyro"):
        _gyro_scale_error(["not", "a", "block"])
    assert _gyro_scale_error(None) is None


FIELD_UT, DIP_DEG, RATE_HZ, MAG_NOISE_UT = 50.0, 60.0, 100.0, 0.3


def _yaw_recording(gyro_scale, seconds=60.0, seed=0):
    """Turning at 60 deg/s about the vertical, the sense reversed every 8 s, with a tilt wobble; exact accelerometer,
    the field with white noise; the gyro ``diag(1 + gyro_scale)`` times the true rate.  The true heading, deg."""
    from compass.frames import world_field

    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    yaw_rate = np.radians(60.0) * np.where((t // 8.0) % 2 == 0, 1.0, -1.0)
    omega = np.column_stack([0.3 * np.sin(2 * np.pi * 0.2 * t), 0.3 * np.cos(2 * np.pi * 0.13 * t), yaw_rate])
    truth = [Rotation.identity()]
    for w in omega[1:] / RATE_HZ:
        truth.append(truth[-1] * Rotation.from_rotvec(w))
    truth = Rotation.concatenate(truth)
    accel = truth.apply([0.0, 0.0, 9.81], inverse=True)
    field = truth.apply(world_field(DIP_DEG, FIELD_UT), inverse=True) + rng.normal(0.0, MAG_NOISE_UT, (len(t), 3))
    return t, accel, omega * (1.0 + np.asarray(gyro_scale)), field, truth.as_euler("ZYX", degrees=True)[:, 0]


def test_a_board_with_one_axis_off_is_allowed_for_in_turns_about_it():
    """Only the yaw axis reads 5 % high: the fitted number is at least 5 % (it bounds yaw turns), and on yaw turns the
    heading is closer to the truth with it than with the RMS over directions (2.9 %) or the default (0.5 %)."""
    from compass.calibration import from_dict
    from compass.filter import run_filter

    g = np.diag([1.0, 1.0, 1.05])
    model = from_dict(_doc(g, np.full((3, 3), 1e-3))).model
    fitted = FilterConfig.from_model(model).gyro_scale_error
    assert fitted >= 0.05
    t, accel, gyro, field, heading = _yaw_recording([0.0, 0.0, 0.05])
    rms = {}
    for name, s in (("default", DEFAULT_GYRO_SCALE_ERROR), ("over directions", np.hypot(0.005, 0.05 / np.sqrt(3))),
                    ("fitted", fitted)):
        config = FilterConfig(field_norm=FIELD_UT, dip_deg=DIP_DEG, mag_noise=MAG_NOISE_UT, gyro_scale_error=s)
        track = run_filter(t, accel, gyro, field, config, reference="config")
        error = (Rotation.from_quat(track.quat).as_euler("ZYX", degrees=True)[:, 0] - heading + 180.0) % 360.0 - 180.0
        rms[name] = np.sqrt(np.mean(error**2))
    assert rms["fitted"] < rms["over directions"] < rms["default"], rms


def test_an_installation_keeps_the_fitted_value():
    from compass.calibration import from_dict
    from compass.installed import installed_model
    from scipy.spatial.transform import Rotation

    base = from_dict(_doc()).model
    rot = Rotation.from_euler("ZYX", [30.0, -10.0, 5.0], degrees=True).as_matrix()
    product = installed_model(base, np.zeros(3), np.eye(3), alignment=rot)
    assert product.gyro_scale_error == base.gyro_scale_error
    with pytest.raises(ValueError, match="gyro_scale_error must be 2 non-negative numbers"):
        dataclasses.replace(base, gyro_scale_error=(0.01, -0.01))


def test_the_option_overrides_the_fit_live_and_replay_alike(tmp_path):
    """``--gyro-scale-error`` reaches the filter in ``compass attitude --filter`` as in a live session (identical rows),
    and changes them against the fitted value."""
    from compass.calibration import from_dict, save
    from compass.sim.device import simulate_device
    from tests.compass.filter.test_latency import _write_recording, attitude_and_live_rows

    doc = _doc()
    cal = save(tmp_path / "cal.json", doc)
    model = from_dict(doc).model
    assert FilterConfig.from_model(model, gyro_scale_error=0.08).gyro_scale_error == 0.08
    t = np.arange(0.0, 15.0, 0.01)
    s = simulate_device(model, t, seed=6)
    rec = _write_recording(tmp_path / "rec.csv", model, t, s)
    fitted = attitude_and_live_rows(tmp_path, cal, rec, model, t, s, None, FilterConfig.from_model(model))
    given = attitude_and_live_rows(tmp_path, cal, rec, model, t, s, "--gyro-scale-error=0.08",
                                   FilterConfig.from_model(model, gyro_scale_error=0.08))
    assert given != fitted


@pytest.mark.parametrize("bad", ["0", "-0.01", "nan", "inf", "0.5", "abc"])
def test_bad_values_are_refused_in_one_line(tmp_path, capsys, bad):
    from compass.cli import main

    for argv in (["attitude", "cal.json", "rec.csv", "--out", str(tmp_path / "a.csv"), "--filter"],
                 ["live", "--port", "/dev/null", "--cal", "cal.json"]):
        assert main(argv + [f"--gyro-scale-error={bad}"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--gyro-scale-error" in err[0] and "(0, 0.2]" in err[0]


def test_the_option_goes_with_the_filter_only(tmp_path, capsys):
    from compass.calibration import save
    from compass.cli import main

    cal = save(tmp_path / "cal.json", _doc())
    rec = tmp_path / "rec.csv"
    rec.write_text("t_s,mx,my,mz,ax,ay,az\n0,1,2,3,0,0,1\n")
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "a.csv"), "--gyro-scale-error", "0.03"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--gyro-scale-error goes with --filter" in err[0]
    with pytest.raises(ValueError, match="FilterConfig.gyro_scale_error must be a positive number"):
        FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1, gyro_scale_error=0.0)
