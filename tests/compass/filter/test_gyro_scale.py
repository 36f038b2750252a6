"""The gyro's scale error the filter allows for (``FilterConfig.gyro_scale_error``): what a tumble file's gyro-aided fit
says remains (``tumble.gyro.gyro_matrix`` and its sigma), ``--gyro-scale-error`` over it, bad values refused."""

import dataclasses

import numpy as np
import pytest

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


def test_one_number_is_the_rate_errors_rms_over_directions():
    """``sqrt(||E||_F^2 / 3)`` is the RMS of ``|E w| / |w|`` over uniformly spread rate directions (the reference
    relation the reduction to one number rests on), and ``s`` for ``E = s I``."""
    from compass.calibration import gyro_scale_error

    e = np.array([[0.03, 0.012, 0.0], [0.0, -0.025, 0.011], [0.013, 0.0, 0.02]])  # every nonzero entry seen
    w = np.random.default_rng(0).normal(size=(200_000, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    rms = np.sqrt(np.mean(np.sum((w @ e.T) ** 2, axis=1)))
    # the sampling error of a mean of 2e5 squares of a bounded quantity: well under 1 % of it
    assert gyro_scale_error(np.eye(3) + e, np.full((3, 3), 1e-9))[1] == pytest.approx(rms, rel=0.01)
    assert gyro_scale_error(1.03 * np.eye(3), np.full((3, 3), 1e-9))[1] == pytest.approx(0.03, rel=1e-6)


def test_from_model_takes_what_the_fit_saw():
    from compass.calibration import from_dict, gyro_matrix_seen

    model = from_dict(_doc()).model
    assert gyro_matrix_seen(G, SIGMA).sum() == 3  # the three diagonal entries: beyond 3 sigma, sigma under 0.5 %
    # by hand: the seen diagonal (0.03, -0.025, 0.02) and its sigmas (1, 1, 1.5 e-3); the rest counts nothing
    applied = np.sqrt((1e-3**2 + 1e-3**2 + 1.5e-3**2) / 3.0)
    as_read = np.sqrt((0.03**2 + 0.025**2 + 0.02**2 + 1e-3**2 + 1e-3**2 + 1.5e-3**2) / 3.0)
    assert model.gyro_scale_error == pytest.approx((applied, as_read), rel=1e-12)
    floor = DEFAULT_GYRO_SCALE_ERROR
    assert FilterConfig.from_model(model).gyro_scale_error == pytest.approx(np.hypot(floor, as_read), rel=1e-12)
    assert FilterConfig.from_model(model, gyro_matrix=True).gyro_scale_error == pytest.approx(np.hypot(floor, applied),
                                                                                              rel=1e-12)
    assert applied < 0.1 * as_read  # the fit knows the scale far better than its size


def test_an_error_on_one_axis_counts_its_share_over_directions():
    """A board whose z axis alone reads 5 % high (every sigma 1e-3, only zz seen): the RMS over directions,
    ``sqrt((0.05^2 + 1e-6) / 3)`` (2.9 %; the bound over directions, 5 %, was measured and not kept)."""
    from compass.calibration import from_dict, gyro_matrix_seen

    g = np.diag([1.0, 1.0, 1.05])
    assert gyro_matrix_seen(g, np.full((3, 3), 1e-3)).sum() == 1
    model = from_dict(_doc(g, np.full((3, 3), 1e-3))).model
    assert model.gyro_scale_error == pytest.approx((np.sqrt(1e-6 / 3.0), np.sqrt((0.05**2 + 1e-6) / 3.0)), rel=1e-12)


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
    sigma[0, 0] = np.inf  # no sigma: not seen
    assert gyro_scale_error(G, sigma)[1] == pytest.approx(np.sqrt((0.025**2 + 1e-3**2 + 0.02**2 + 1.5e-3**2) / 3), rel=1e-12)


def test_garbage_gyro_block_is_refused_by_the_scale_error_alone():
    """``_gyro_scale_error`` checks the block itself (not relying on ``_gyro_matrix`` having run first)."""
    from compass.calibration import CalibrationFileError
    from compass.calibration._read import _gyro_scale_error

    with pytest.raises(CalibrationFileError, match="tumble.gyro"):
        _gyro_scale_error(["not", "a", "block"])
    assert _gyro_scale_error(None) is None


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
