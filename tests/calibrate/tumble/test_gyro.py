"""The gyro-aided tumble fit: identifiability, recovery on partial motions, the reader's gyro, bad gyros."""

import json
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.tumble import TumbleCalibrator, calibrate_tumble
from calibrate.tumble import gyro
from calibrate.tumble.diagnosis import diagnose_tumble
from calibrate.tumble.gyro import (_Problem, _robust_rows, _windows, falls_back, fit_with_gyro, turn_rates,
                                    with_gyro)
from compass.cli import main
from compass.filter import FilterConfig
from compass.io.table import ReadOptions, RecordingError
from compass.io.tumble import gyro_turns, read_tumble
from compass.io.units import RecordingWarning
from compass.sim.partial_tumble import simulate_partial_tumble, write_partial_tumble


def _shape(s):
    s = np.asarray(s, float)
    return s / np.cbrt(np.linalg.det(s))


def _turning(axes, *, tilt_deg=0.0, n=1500, rate_hz=50.0, seed=0):
    """Noise-free samples of a housing turning about the housing ``axes`` (indices), and the truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    omega = np.zeros((n, 3))
    for i, a in enumerate(axes):
        omega[:, a] = np.radians(40.0) * np.sin(2 * np.pi * (0.1 + 0.07 * i) * t + i)
    turns = np.vstack([np.zeros(3), omega[1:] / rate_hz])
    att = [Rotation.from_euler("ZYX", [30.0, tilt_deg, 0.0], degrees=True)]
    for step in Rotation.from_rotvec(turns[1:]):
        att.append(att[-1] * step)
    att = Rotation.concatenate(att)
    b_w = np.array([np.cos(np.radians(60.0)), 0.0, -np.sin(np.radians(60.0))])
    d = 50.0 * np.eye(3) + rng.normal(size=(3, 3))
    h = rng.normal(size=3) * 10.0
    return t, turns, att, att.apply(b_w, inverse=True) @ d.T + h, att.apply([0.0, 0.0, 1.0], inverse=True), d, h


def _problem(axes, *, tilt_deg=0.0, noise=0.0, f_scale=None, seed=1):
    """The model's problem on the samples of :func:`_turning` (noise in uT), its windows started at the truth;
    the true global parameters."""
    t, turns, att, mag, acc, d, h = _turning(axes, tilt_deg=tilt_deg)
    mag = mag + np.random.default_rng(seed).normal(scale=noise, size=mag.shape)
    dt = np.diff(t, prepend=t[0])
    window = _windows(turns, dt)
    starts = np.r_[0, np.flatnonzero(np.diff(window)) + 1]
    prob = _Problem(mag, turns, dt, window, acc, np.ones(len(t), bool), att[starts], 0.3, 0.01, turn_rates(turns, dt),
                    f_scale=f_scale)
    return prob, np.concatenate([d.ravel(), h, [np.radians(60.0)], np.zeros(3), [0.0], np.zeros(9)])


def _stacked(prob, rows, q):
    r_m, r_a = prob.residuals(rows, q)
    return np.concatenate([r_m.ravel(), r_a.ravel()])


def _window_columns(prob, rows, q, step=1e-6):
    """The residual's derivative w.r.t. each window's turn (``Q -> Exp(d) Q``), central differences."""
    cols = []
    for j in range(len(q)):
        for i in range(3):
            turn = Rotation.from_rotvec(np.eye(3)[i] * step).as_matrix()
            plus, minus = q.copy(), q.copy()
            plus[j], minus[j] = turn @ q[j], turn.T @ q[j]
            cols.append((_stacked(prob, rows, plus) - _stacked(prob, rows, minus)) / (2 * step))
    return np.column_stack(cols)


def _null_dimension(axes, tilt_deg=0.0, gyro_prior=True):
    """Directions the joint Jacobian (global parameters and every window's turn) at the truth cannot see
    (columns normalised; singular values < 1e-7 of the largest); ``gyro_prior`` False: without the gyro matrix's
    prior (what the data alone determine of it)."""
    prob, p = _problem(axes, tilt_deg=tilt_deg)
    rows = prob.rows(p)
    q = prob.orientation.as_matrix()
    j_m, j_a = prob.global_jacobian(rows, q)
    k = prob.N_GLOBAL
    joint = np.hstack([np.vstack([j_m.reshape(-1, k), j_a.reshape(-1, k)]), _window_columns(prob, rows, q)])
    prior = np.zeros((10, joint.shape[1]))
    prior[0, 16] = 1.0 / prob.tau_prior_s  # the latency's prior, as in the residual
    if gyro_prior:
        prior[1:, 17:26] = np.diag(1.0 / prob.gyro_prior)
    joint = np.vstack([joint, prior])
    norm = np.linalg.norm(joint, axis=0)
    sv = np.linalg.svd(joint / np.where(norm > 0, norm, 1.0), compute_uv=False)  # a column never exercised is zero
    return int(np.sum(sv < 1e-7 * sv[0]))


def test_jacobian_matches_finite_differences():
    # the analytic derivative w.r.t. the global parameters at fixed window orientations
    sim = simulate_partial_tumble("fast_rotation", seed=1, coverage=0.2)
    n = len(sim.t_s)
    turns = gyro_turns(sim.t_s, sim.gyro, np.ones(n, bool))
    dt = np.diff(sim.t_s, prepend=sim.t_s[0])
    window = _windows(turns, dt)
    n_w = window[-1] + 1
    a_unit = sim.accel / np.linalg.norm(sim.accel, axis=1, keepdims=True)
    rng = np.random.default_rng(0)
    prob = _Problem(sim.mag, turns, dt, window, a_unit, np.ones(n, bool), Rotation.random(n_w, random_state=1), 0.3, 0.02,
                    turn_rates(turns, dt))
    p = np.concatenate([(50 * np.eye(3) + rng.normal(size=(3, 3))).ravel(), [1, 2, 3], [1.0], [0.01, -0.02, 0.005],
                        [0.012], rng.normal(scale=0.02, size=9)])  # a gyro matrix off the identity too
    q = Rotation.random(n_w, random_state=2).as_matrix()
    j_m, j_a = prob.global_jacobian(prob.rows(p), q)
    jac = np.vstack([j_m.reshape(-1, prob.N_GLOBAL), j_a.reshape(-1, prob.N_GLOBAL)])
    num = np.empty_like(jac)
    for j in range(p.size):
        e = np.zeros_like(p)
        e[j] = 1e-6
        num[:, j] = (_stacked(prob, prob.rows(p + e), q) - _stacked(prob, prob.rows(p - e), q)) / 2e-6
    assert np.max(np.abs(jac - num)) < 1e-5 * np.max(np.abs(num))


def test_reduced_jacobian_is_the_derivative_with_the_windows_solved():
    # noise-free samples at the truth (zero residual): the variable-projection Jacobian is the exact derivative
    # of the residual whose window orientations are solved anew at each point
    prob, p = _problem([0, 2])
    r0 = prob.residual(p)
    assert np.max(np.abs(r0)) < 1e-6
    jac = prob.jacobian(p)
    steps = np.r_[np.full(9, 1e-4), np.full(3, 1e-4), 1e-7, np.full(3, 1e-8), 1e-8, np.full(9, 1e-7)]
    num = np.empty_like(jac)
    for j in range(p.size):
        e = np.zeros_like(p)
        e[j] = steps[j]
        num[:, j] = (prob.residual(p + e) - prob.residual(p - e)) / (2 * steps[j])
    assert np.all(np.abs(jac - num) <= 1e-4 * np.max(np.abs(num), axis=0))


@pytest.mark.parametrize("f_scale", [None, 3.0])
def test_windows_are_solved_and_the_gradient_follows(f_scale):
    # noisy samples away from the optimum, the windows started 3 deg off: each window's orientation is the
    # minimum of its loss (within 1e-8 rad by its gradient over its curvature), and the reduced gradient
    # J^T rho'(r) r is the loss's derivative (the windows held at their minimum)
    prob, p = _problem([0, 1, 2], noise=0.3, f_scale=f_scale)
    prob.mag[::97] += 8.0  # outliers for the robust loss
    prob.orientation = Rotation.from_rotvec(np.full((prob.n_w, 3), np.radians(3.0) / np.sqrt(3))) * prob.orientation
    p = p + np.r_[np.full(9, 0.05), [0.2, -0.1, 0.1], 0.01, [1e-3, -1e-3, 5e-4], 2e-3, np.linspace(-0.01, 0.01, 9)]

    def total(r):
        return 0.5 * np.sum(r**2 if f_scale is None else 2 * f_scale**2 * (np.sqrt(1 + (r / f_scale) ** 2) - 1))

    r = prob.residual(p)
    rows, q = prob.rows(p), prob.orientation.as_matrix()
    step = 1e-5
    for j in range(len(q)):
        for i in range(3):
            turn = Rotation.from_rotvec(np.eye(3)[i] * step).as_matrix()
            costs = []
            for m in (turn, np.eye(3), turn.T):
                turned = q.copy()
                turned[j] = m @ q[j]
                costs.append(total(_stacked(prob, rows, turned)))
            slope, curvature = (costs[0] - costs[2]) / (2 * step), (costs[0] - 2 * costs[1] + costs[2]) / step**2
            assert curvature > 0 and abs(slope / curvature) < 1e-8
    weight = np.ones_like(r) if f_scale is None else 1 / np.sqrt(1 + (r / f_scale) ** 2)
    grad = prob.jacobian(p)[:-10].T @ (weight * r)[:-10]
    steps = np.r_[np.full(12, 1e-5), 1e-7, np.full(3, 1e-8), 1e-7, np.full(9, 1e-7)]
    num = np.array([(total(prob.residual(p + e)[:-10]) - total(prob.residual(p - e)[:-10])) / (2 * h)
                    for h, e in zip(steps, np.diag(steps))])
    assert np.allclose(grad, num, rtol=1e-4, atol=1e-4 * np.max(np.abs(num)))


def test_identifiability_as_derived():
    # the module docstring: turns about two or more axes determine everything; about one axis five
    # combinations stay free, whether the axis is vertical or tilted
    assert _null_dimension([0, 2]) == 0
    assert _null_dimension([0, 1, 2]) == 0
    assert _null_dimension([2]) == 5
    assert _null_dimension([2], tilt_deg=30.0) == 5


def test_what_the_turns_determine_of_the_gyro_matrix():
    # the module docstring, "Gyro errors": without G's prior, turns about every axis leave nothing free, about two axes
    # the 3 numbers of G across both, about one axis the 6 of G across it (and the 5 of the magnetometer's fit)
    assert _null_dimension([0, 1, 2], gyro_prior=False) == 0
    assert _null_dimension([0, 2], gyro_prior=False) == 3
    assert _null_dimension([2], gyro_prior=False) == 5 + 6
    assert _null_dimension([2], tilt_deg=30.0, gyro_prior=False) == 5 + 6


def _gyro_fit(sim, **kw):
    """The gyro-aided fit of a simulated recording from the present fit's values."""
    turns = gyro_turns(sim.t_s, sim.gyro, np.ones(len(sim.t_s), bool))
    res = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s)
    mis = res.misalignment
    return fit_with_gyro(sim.mag, sim.accel, turns, sim.t_s, hard_iron=res.fit.hard_iron, soft_iron=res.fit.soft_iron,
                         field_norm=res.fit.field_norm, mag_to_accel=res.mag_to_accel,
                         dip_deg=None if mis is None else mis.dip_deg, noise=res.noise, **kw)


@pytest.mark.parametrize("scale", [0.02, 0.0])
def test_the_gyros_scale_is_recovered_within_its_sigma(scale):
    # the gyro reads (1 + s) w + b per axis (s up to 2 %, or a perfect scale): G = diag(1 / (1 + s)), every entry
    # within 4 of its sigma (the noise's: ~0.05 % on a minute of hand tumbling)
    sim = simulate_partial_tumble("fast_rotation", seed=11, coverage=None, duration_s=60.0, gyro_scale=scale)
    g = _gyro_fit(sim)
    truth = np.diag(1.0 / (1.0 + np.array(sim.truth["gyro_scale"])))
    assert np.all(g.gyro_matrix_sigma < 0.2 * gyro.GYRO_CROSS_PRIOR)  # the data, not the prior
    assert np.all(np.abs(g.gyro_matrix - truth) < 4 * g.gyro_matrix_sigma)
    if scale:  # the error is there (0.3-1.5 % on this seed): the fit takes all but a fifth of it away
        assert np.linalg.norm(g.gyro_matrix - truth) < 0.2 * np.linalg.norm(truth - np.eye(3))
        assert "the gyro's scale x, y, z" in g.words()
    # held at the identity (the model before it), the gyro's scale goes into the rest: a larger residual
    assert _gyro_fit(sim, fit_gyro_matrix=False).mag_rms >= g.mag_rms


def test_a_cross_coupled_and_turned_gyro_is_recovered_within_its_sigma():
    # the gyro reads M w + noise, M off the identity only across its axes (1-2 %: a rotation of the gyro's frame in
    # the housing, the antisymmetric part, and a cross-axis sensitivity, the symmetric one), no scale error: the fit
    # finds G = M^-1 within 4 of its sigmas, and the runtime's rule sees every off-diagonal entry off the identity
    import dataclasses

    from compass.calibration import gyro_matrix_mismatch, gyro_matrix_seen

    sim = simulate_partial_tumble("fast_rotation", seed=11, coverage=None, duration_s=60.0, gyro_scale=0.0)
    m = np.eye(3) + np.array([[0.0, 0.015, -0.01], [-0.012, 0.0, 0.02], [0.018, -0.014, 0.0]])
    g = _gyro_fit(dataclasses.replace(sim, gyro=sim.gyro @ m.T))
    truth = np.linalg.inv(m)
    assert np.all(g.gyro_matrix_sigma < 0.2 * gyro.GYRO_CROSS_PRIOR)  # the data, not the prior
    assert np.all(np.abs(g.gyro_matrix - truth) < 4 * g.gyro_matrix_sigma)
    off = ~np.eye(3, dtype=bool)
    assert gyro_matrix_seen(g.gyro_matrix, g.gyro_matrix_sigma)[off].all() and not gyro_matrix_mismatch(g.gyro_matrix).any()
    assert "its axes off by up to" in g.words()


def test_the_words_name_a_gyro_matrix_entry_beyond_three_prior_sigmas_a_mismatch_and_do_not_apply_it():
    error = np.array([[0.01, 0.07, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # xy 7 %: 3.5 of the prior's 2 %
    fit = gyro.GyroFit(*([None] * 15), np.eye(3) + error, np.full((3, 3), 1e-3), *([None] * 9))
    words = fit._gyro_matrix_words()
    assert "a model mismatch in the gyro matrix: xy +7.00 % is beyond 3 of the prior's sigmas" in words
    assert "not applied" in words and "scale x, y, z +1.00, unseen, unseen %" in words
    assert "its axes off by" not in words  # the mismatched entry is not among what the runtime applies


def test_a_turn_about_one_axis_leaves_the_gyro_matrix_across_it_at_the_prior():
    # the model's problem on a turn about z with noise, from the truth: its least-squares step and covariance by the
    # pseudo-inverse (the magnetometer's fit keeps the 5 free combinations of a one-axis turn, module docstring; the
    # whole fit is then undetermined and not used, test_one_axis_leaves_the_fit_undetermined_and_says_what)
    prob, p = _problem([2], noise=0.3)
    r, jac = prob.residual(p), prob.jacobian(p)
    cov = np.linalg.pinv(jac.T @ jac, rcond=1e-12, hermitian=True)
    fitted = p - cov @ jac.T @ r
    e, sigma = fitted[17:26].reshape(3, 3), np.sqrt(np.diag(cov)[17:26]).reshape(3, 3)
    prior = gyro.GYRO_MATRIX_PRIOR.reshape(3, 3)
    # G x and G y (the response to turns about x and y, never made): the prior's value (the identity) and sigma
    assert np.all(np.abs(e[:, :2]) < 1e-6 * prior[:, :2])
    np.testing.assert_allclose(sigma[:, :2], prior[:, :2], rtol=1e-6)
    # G z (the turn's axis): precise enough to be seen (the runtime's rule), the identity (an exact gyro) within 4
    # sigma, so not seen off it; a G z off by 10 of its sigmas would be, the rest never
    from compass.calibration import gyro_matrix_seen
    from compass.calibration._read import GYRO_MATRIX_SIGMA_SEEN

    assert np.all(sigma[:, 2] < GYRO_MATRIX_SIGMA_SEEN) and np.all(sigma[:, :2] > GYRO_MATRIX_SIGMA_SEEN)
    assert np.all(np.abs(e[:, 2]) < 4 * sigma[:, 2])
    off = np.eye(3) + e + 10 * sigma
    seen = gyro_matrix_seen(off, sigma)
    assert seen[:, 2].all() and not seen[:, :2].any()


def test_the_words_name_the_turn_axes_the_gyro_matrix_did_not_see():
    fit = gyro.GyroFit(*([None] * 15), np.eye(3) + np.diag([0.01, 0.0, 0.0]),
                       np.array([[1e-4, 0.03, 0.03], [1e-4, 0.03, 0.03], [1e-4, 0.03, 0.03]]), *([None] * 9))
    words = fit._gyro_matrix_words()
    assert "scale x, y, z +1.00, unseen, unseen %" in words and "turns about y, z not seen" in words


@pytest.fixture(scope="module")
def partial(tmp_path_factory):
    """A 25 % tumble with a gyro, written and read back; the present fit of it."""
    sim = simulate_partial_tumble("fast_rotation", seed=3, coverage=0.25)
    path, _ = write_partial_tumble(sim, tmp_path_factory.mktemp("gyro") / "partial.csv")
    return sim, path


def test_partial_motion_recovered_where_the_present_fit_falls_back(partial):
    sim, path = partial
    rec = read_tumble(path)
    present = calibrate_tumble(rec.mag, rec.accel, t_s=rec.t_s)
    assert falls_back(present)  # the present fit cannot: hard iron only, no rotation
    h_true = np.array(sim.truth["hard_iron"])
    assert np.linalg.norm(present.hard_iron - h_true) > 2.0
    res = TumbleCalibrator().fit(rec)
    assert res.gyro["used"] and res.ellipsoid == "full"
    fit = res.fit
    # within 4 sigma of the truth (the gyro's 0.5 % scale error is not modelled: a floor of 0.1 % / 0.1 deg)
    assert np.all(np.abs(fit.hard_iron - h_true) < 4 * fit.hard_iron_sigma + 0.05)
    assert np.all(np.abs(fit.soft_iron - _shape(sim.truth["soft_iron"])) < 4 * fit.soft_iron_sigma + 1e-3)
    err = Rotation.from_matrix(sim.truth["mag_to_accel"]).inv() * res.misalignment.rotation
    assert np.degrees(err.magnitude()) < 4 * np.linalg.norm(res.misalignment.rotvec_sigma_deg) + 0.1
    assert abs(res.misalignment.dip_deg - sim.truth["dip_deg"]) < 4 * res.misalignment.dip_sigma_deg + 0.1
    bias = np.array(sim.truth["gyro_bias_rad_s"])
    assert np.all(np.abs(np.array(res.gyro["gyro_bias_rad_s"]) - bias) < 4 * np.array(res.gyro["gyro_bias_sigma_rad_s"]) + 2e-4)
    # the words say what the gyro determined; the present fit's fallback warnings are gone
    text = " ".join(res.warnings)
    assert "with the gyro's turns" in text and "determined" in text
    assert "used the offset kind" not in text and "no magnetometer-accelerometer rotation" not in text
    assert res.diagnosis.block["unexplained"] is False
    doc = res.to_json()
    assert doc["tumble"]["method"] == "gyro" and doc["mag_to_accel"] is not None


def test_one_axis_leaves_the_fit_undetermined_and_says_what():
    t, turns, att, mag, acc, _, _ = _turning([2], n=600)
    mag = mag + np.random.default_rng(1).normal(scale=0.3, size=mag.shape)
    g = fit_with_gyro(mag, acc, turns, t, hard_iron=np.median(mag, axis=0), soft_iron=np.eye(3), field_norm=50.0)
    assert not g.determined
    words = g.words()
    assert "about one axis only" in words and "still undetermined" in words and "hard iron" in words


def test_a_gyro_in_deg_s_is_handled_as_today(partial, tmp_path):
    sim, _ = partial
    path, _ = write_partial_tumble(sim, tmp_path / "deg.csv", gyro_unit="deg/s")
    with pytest.warns(UserWarning, match="gx,gy,gz read in rad/s .* times more .* --gyro-unit deg/s"):
        rec = read_tumble(path)  # the reader's one note: not used (tests/compass/io/test_tumble_gyro.py)
    assert rec.gyro_turn_rad is None
    res = TumbleCalibrator().fit(rec)
    assert res.gyro is None and falls_back(res)
    # named, it is used
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        named = read_tumble(path, ReadOptions(gyro_unit="deg/s"))
    assert np.allclose(named.gyro_turn_rad[1:], sim.gyro[1:] / 50.0, atol=1e-5)


def test_without_a_gyro_nothing_changes(partial, tmp_path):
    sim, _ = partial
    path = tmp_path / "nogyro.csv"
    rows = np.column_stack([sim.t_s, sim.mag, sim.accel])
    path.write_text("t_s,mx,my,mz,ax,ay,az\n" + "\n".join(",".join(f"{v:.6f}" for v in r) for r in rows) + "\n")
    rec = read_tumble(path)
    assert rec.gyro_turn_rad is None
    assert TumbleCalibrator().fit(rec).gyro is None


def test_gyro_turns_integrate_the_rows_between_kept_samples():
    t = np.arange(6) * 0.1
    gyro = np.arange(18, dtype=float).reshape(6, 3)
    keep = np.array([True, False, True, True, False, False])
    out = gyro_turns(t, gyro, keep)
    assert np.allclose(out[0], 0.0)
    assert np.allclose(out[1], 0.1 * (gyro[1] + gyro[2]))
    assert np.allclose(out[2], 0.1 * gyro[3])


def _with_gyro_cell(partial, tmp_path, value, row=40):
    sim, _ = partial
    bad = sim.gyro.copy()
    bad[row, 1] = value
    path = tmp_path / "bad.csv"
    rows = np.column_stack([sim.t_s, sim.mag, sim.accel, bad])
    path.write_text("t_s,mx,my,mz,ax,ay,az,gx,gy,gz\n" + "\n".join(",".join(f"{v:.6f}" for v in r) for r in rows) + "\n")
    return path


def test_a_gyro_beyond_any_range_is_refused_naming_row_and_column(partial, tmp_path):
    path = _with_gyro_cell(partial, tmp_path, 250.0)
    with pytest.raises(RecordingError, match=r"row 42.*column 'gy'.*beyond any MEMS gyro's range|beyond any MEMS gyro's range"):
        read_tumble(path)


def test_a_gyro_reading_zero_everywhere_is_refused(partial, tmp_path):
    sim, _ = partial
    path = tmp_path / "zero.csv"
    rows = np.column_stack([sim.t_s, sim.mag, sim.accel, np.zeros_like(sim.gyro)])
    path.write_text("t_s,mx,my,mz,ax,ay,az,gx,gy,gz\n" + "\n".join(",".join(f"{v:.6f}" for v in r) for r in rows) + "\n")
    # the reader's unit check says it first (a dead gyro?), then the tumble refuses it
    with pytest.warns(RecordingWarning, match="a dead gyro"), \
            pytest.raises(RecordingError, match=r"gyro reads \(0, 0, 0\) in every row"):
        read_tumble(path)


def test_cli_bad_gyro_is_one_line_exit_2(partial, tmp_path, capsys):
    path = _with_gyro_cell(partial, tmp_path, 250.0)
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "gy" in err[0] and "42" in err[0]


def test_cli_writes_the_gyro_aided_calibration(partial, tmp_path, capsys):
    _, path = partial
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(path), "--out", str(out), "--quiet"]) == 0
    doc = json.loads(out.read_text())
    assert doc["tumble"]["method"] == "gyro" and doc["tumble"]["gyro"]["used"] is True


def test_forced_kind_is_not_overridden(partial):
    _, path = partial
    res = TumbleCalibrator(ellipsoid="offset").fit(read_tumble(path))
    assert res.ellipsoid == "offset" and res.gyro is None


def test_with_gyro_refuses_bad_arrays(partial):
    sim, _ = partial
    present = calibrate_tumble(sim.mag, sim.accel)
    turns = np.full_like(sim.gyro, np.nan)
    with pytest.raises(ValueError, match="turns_rad holds non-finite values"):
        with_gyro(present, sim.mag, sim.accel, turns, sim.t_s)


def test_a_gyro_that_disagrees_with_the_magnetometer_is_not_used(partial):
    # the gyro of another motion: the turns do not explain the field's; the present fit stays, said in words
    sim, _ = partial
    present = calibrate_tumble(sim.mag, sim.accel)
    other = simulate_partial_tumble("fast_rotation", seed=9, coverage=None, duration_s=30.0)
    turns = gyro_turns(other.t_s, other.gyro, np.ones(len(other.t_s), bool))[:len(sim.t_s)]
    res = with_gyro(present, sim.mag, sim.accel, turns, sim.t_s)
    assert res.gyro["used"] is False and res.fit is present.fit
    assert any(w.startswith("gyro-aided fit not used") for w in res.warnings)


def test_an_accelerometer_row_reading_zero_leaves_the_present_fit_said(partial):
    # a zero row has no gravity direction for a window's tilt: the gyro-aided fit steps aside, in words
    sim, _ = partial
    accel = sim.accel.copy()
    accel[0] = 0.0
    present = calibrate_tumble(sim.mag, accel)
    turns = gyro_turns(sim.t_s, sim.gyro, np.ones(len(sim.t_s), bool))
    res = with_gyro(present, sim.mag, accel, turns, sim.t_s)
    assert res.gyro["used"] is False and res.fit is present.fit
    assert any("accelerometer rows read zero (the first is sample 0)" in w for w in res.warnings)


@pytest.mark.parametrize("lengths, k", [((100, 150), 3), ((10, 10), 2)])
def test_robust_rows_thin_each_window_from_its_first_row(lengths, k):
    # 10000 rows: every 3rd would leave 4000 (ROBUST_ROWS); windows of 10 rows keep 5 (MIN_WINDOW_SAMPLES): every 2nd
    n_w = 2 * 10000 // sum(lengths)
    window = np.repeat(np.arange(n_w), np.tile(lengths, n_w // 2))
    assert len(window) == 10000 and gyro.ROBUST_ROWS == 4000
    rows = _robust_rows(window)
    starts = np.r_[0, np.flatnonzero(np.diff(window)) + 1]
    assert np.all(np.isin(starts, rows))  # every window keeps its first row, where its integration starts
    assert np.all(np.diff(rows)[np.diff(window[rows]) == 0] == k)
    assert len(rows) <= len(window) / k + n_w
    assert np.array_equal(_robust_rows(window[:gyro.ROBUST_ROWS]), np.arange(gyro.ROBUST_ROWS))  # few rows: all


def test_thinning_the_robust_fit_leaves_the_fit_within_a_fraction_of_sigma(partial, monkeypatch):
    # the robust fit only starts the plain fit and sets the outlier test; the plain fit uses every inlier
    sim, _ = partial
    turns = gyro_turns(sim.t_s, sim.gyro, np.ones(len(sim.t_s), bool))
    present = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s)
    start = dict(hard_iron=present.fit.hard_iron, soft_iron=present.fit.soft_iron, field_norm=present.fit.field_norm,
                 mag_to_accel=present.mag_to_accel, noise=present.noise)
    whole = fit_with_gyro(sim.mag, sim.accel, turns, sim.t_s, **start)
    monkeypatch.setattr(gyro, "ROBUST_ROWS", len(sim.t_s) // 4)
    thinned = fit_with_gyro(sim.mag, sim.accel, turns, sim.t_s, **start)
    assert np.array_equal(thinned.inliers, whole.inliers)
    for name in ("hard_iron", "soft_iron", "rotvec_deg", "gyro_bias_rad_s"):
        sigma = getattr(whole, name.replace("_deg", "_sigma_deg").replace("_rad_s", "_sigma_rad_s")
                        if name.endswith(("_deg", "_rad_s")) else name + "_sigma")
        assert np.all(np.abs(getattr(thinned, name) - getattr(whole, name)) < 0.05 * sigma)


def test_a_gyro_matrix_the_reader_would_refuse_is_not_written():
    # a fit that wandered where the turns saw nothing (BROAD 10, a translation: G - I near -100 %, no sigma) writes no
    # matrix, and its file loads; a usable one is written and read back
    from compass.calibration import from_dict
    from compass.sim.tumble import simulate_tumble

    sim = simulate_tumble(seed=4, n=600)
    doc = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s).to_json()
    for g, sigma, written in ((0.01 * np.eye(3), np.full((3, 3), np.inf), False),
                              (1.3 * np.eye(3), np.full((3, 3), 1e-3), False),
                              (1.01 * np.eye(3), np.full((3, 3), 1e-3), True)):
        fit = gyro.GyroFit(np.zeros(3), np.full(3, 0.1), np.eye(3), np.full((3, 3), 1e-3), 50.0, 0.1,
                           Rotation.identity(), np.zeros(3), np.full(3, 0.1), 60.0, 0.1, np.zeros(3), np.full(3, 1e-4),
                           0.0, 1e-3, g, sigma, 10, 100, np.ones(600, bool), 0.3, 0.3, (), "turned 500 deg in all",
                           True, "converged")
        doc["tumble"]["gyro"] = fit.to_json() | {"used": True}
        assert (doc["tumble"]["gyro"]["gyro_matrix"] is not None) == written
        assert (from_dict(doc).model.gyro_matrix is not None) == written
        assert ("the gyro's scale and axes not seen" in fit.words()) != written


def test_a_step_over_the_gap_limit_closes_a_window_and_the_rate_beside_it_is_one_sided():
    # 0.1 rad a step at 50 Hz (5 rad/s), then 2 s without samples: the turn the gyro's rate gives over the gap is not
    # the turn made, so the window closes before the first sample after it, however young, and the rate at the
    # samples beside the gap is their other side's
    dt = np.r_[0.0, np.full(3, 0.02), 2.0, np.full(3, 0.02)]
    turns = np.outer(np.r_[0.0, np.full(3, 0.1), 0.5, np.full(3, 0.01)], [0.0, 0.0, 1.0])
    assert gyro.GAP_S == FilterConfig.max_gap_s  # the runtime filter's limit
    np.testing.assert_array_equal(_windows(turns, dt), [0, 0, 0, 0, 1, 1, 1, 1])
    np.testing.assert_allclose(turn_rates(turns, dt)[:, 2], [5.0, 5.0, 5.0, 5.0, 0.5, 0.5, 0.5, 0.5])


def _lines_lost(sim, lost_s, kept_s):
    """Which of ``sim``'s rows arrive when ``lost_s`` of lines are lost after every ``kept_s`` that arrived (a link
    dropping bursts of lines)."""
    hz = 1.0 / np.median(np.diff(sim.t_s))
    period = int(round((lost_s + kept_s) * hz))
    return np.arange(len(sim.t_s)) % period < int(round(kept_s * hz))


def test_lines_lost_while_turning_leave_the_gyro_aided_fit_on_the_truth(partial):
    # the partial tumble with 0.6 s of lines lost after every second that arrived: the module turned in each gap,
    # which the gyro's rate times the gap does not give.  Integrated across the gaps, the windows tied samples with a
    # made-up turn, and the fit rejected 45 of the 276 samples as outliers (16 %; with the gaps 0.04 s later it kept
    # them, its residual 0.50 uT against the 0.3 uT injected); with the windows closed at each gap every sample is
    # kept (a right model's rejects beyond 4 sigma in 3 axes: ~1e-10 a sample), the fit on the noise and the truth
    sim, _ = partial
    keep = _lines_lost(sim, 0.6, 1.0)
    t_s, mag, accel = sim.t_s[keep], sim.mag[keep], sim.accel[keep]
    turns = gyro_turns(t_s, sim.gyro[keep], np.ones(len(t_s), bool))
    res = with_gyro(calibrate_tumble(mag, accel, t_s=t_s), mag, accel, turns, t_s)
    assert res.gyro["used"] and res.gyro["n_outliers"] == 0
    # the rms of 3 n residuals of a right model: the noise, within 15 % (its sampling spread is 1 / sqrt(6 n) ~ 2.5 %)
    assert res.gyro["mag_residual_rms"] < 1.15 * sim.truth["noise_ut"]
    fit, h_true = res.fit, np.array(sim.truth["hard_iron"])
    assert np.all(np.abs(fit.hard_iron - h_true) < 4 * fit.hard_iron_sigma + 0.05)
    assert np.all(np.abs(fit.soft_iron - _shape(sim.truth["soft_iron"])) < 4 * fit.soft_iron_sigma + 1e-3)
    err = Rotation.from_matrix(sim.truth["mag_to_accel"]).inv() * res.misalignment.rotation
    assert np.degrees(err.magnitude()) < 4 * np.linalg.norm(res.misalignment.rotvec_sigma_deg) + 0.1


def test_a_trial_step_the_fit_rejects_leaves_no_window_half_a_turn_off():
    # a slow partial tumble whose link lost a second or more of lines every 2 s, each burst ending as the hand slowed
    # (below 25 deg/s): the robust fit's first trial step (the hard iron 18 uT off) turned one window's solution
    # 178 deg, and as each solve started from the last one, that window stayed there at the fit's own iterate: the
    # fit stopped where it started and rejected 820 of the 1592 samples (GyroMismatch).  Started from the solution at
    # the lowest loss so far, the fit keeps every sample and lands on the truth
    sim = simulate_partial_tumble("slow_rotation", seed=0, coverage=0.3)
    rate_deg_s = np.degrees(np.linalg.norm(sim.gyro, axis=1))
    keep, start = np.ones(len(sim.t_s), bool), 100
    while True:
        end = start + 50 + int(np.argmax(rate_deg_s[start + 50:] < 25.0))
        if end >= len(keep) - 10 or rate_deg_s[end] >= 25.0:
            break
        keep[start:end] = False
        start = end + 100
    t_s, mag, accel = sim.t_s[keep], sim.mag[keep], sim.accel[keep]
    turns = gyro_turns(t_s, sim.gyro[keep], np.ones(len(t_s), bool))
    res = with_gyro(calibrate_tumble(mag, accel, t_s=t_s), mag, accel, turns, t_s)
    assert res.gyro["used"] and res.gyro["n_outliers"] == 0
    assert np.all(np.abs(res.hard_iron - sim.truth["hard_iron"]) < 4 * res.fit.hard_iron_sigma + 0.05)


def test_the_diagnosis_of_a_gyro_aided_fit_is_of_that_fit_in_recording_units(tmp_path):
    # 15 % of the sphere: |m| alone does not determine the full ellipsoid there; refitted to |m| alone from the gyro's
    # point it grew without bound and its residual, scaled by the gyro fit's F, was reported as the base's
    noise_ut = 0.3
    sim = simulate_partial_tumble("fast_rotation", seed=3, coverage=0.15, noise_ut=noise_ut)
    path, _ = write_partial_tumble(sim, tmp_path / "cap.csv")
    res = TumbleCalibrator().fit(read_tumble(path))
    assert res.gyro["used"]
    block = res.diagnosis.block
    fit = res.fit
    own = float(np.sqrt(np.mean(fit.residuals[fit.inliers] ** 2)))  # |S (x - h)| - F of the fit the file holds
    # one residual: the rotation to the housing leaves |m| as it is, so before and after are the same number
    assert block["residual_rms_before"] == pytest.approx(own, rel=1e-9)
    assert block["residual_rms_after"] == pytest.approx(own, rel=1e-9)
    # at the injected noise: the rms of ~300 residuals is within 5 of its sigmas (1 / sqrt(2 n)) of it
    n = int(np.count_nonzero(fit.inliers))
    assert abs(own / noise_ut - 1.0) < 5.0 / np.sqrt(2.0 * n)
    assert abs(block["noise_floor"] / noise_ut - 1.0) < 0.2
    stats = res.statistics
    assert stats.success, stats.message
    assert abs(stats.reduced_chi2 - 1.0) < 5.0 * np.sqrt(2.0 / stats.dof)
    assert block["unexplained"] is False
    assert block["steps"][0]["refitted"] is False and "not refitted to |m|" in res.report()


def test_a_fit_diagnosed_as_it_is_tries_no_effect(partial):
    sim, _ = partial
    fit = calibrate_tumble(sim.mag, sim.accel).fit
    with pytest.raises(ValueError, match="refit=False"):
        diagnose_tumble(sim.mag, fit, candidates=("offset_drift",), refit=False)


def _walked(sim, seed, rms_ut):
    """``sim``'s magnetometer with a hard iron that walks (a random walk smoothed over 2 s, ``rms_ut`` about its mean,
    per axis), and the hard iron the fit should find: the session's mean."""
    rng = np.random.default_rng([seed, 99])
    path = np.cumsum(rng.normal(size=(len(sim.t_s), 3)), axis=0)
    width = int(2.0 / np.median(np.diff(sim.t_s)))
    path = np.column_stack([np.convolve(p, np.ones(width) / width, mode="same") for p in path.T])
    path -= path.mean(axis=0)
    path *= rms_ut / np.sqrt(np.mean(path**2))
    return sim.mag + path, np.array(sim.truth["hard_iron"]) + path.mean(axis=0)


def test_an_unexplained_gyro_aided_fit_states_sigmas_that_cover_its_error():
    # a hard iron walking 1 uT rms through a minute of fast tumbling: the gyro-aided model has no drift, the diagnosis
    # finds structure, and the naive sigmas (~0.015 uT, the noise's) miss the error by ~10 of them; widened over the
    # time blocks they cover it (error over sigma rms ~0.5 on these seeds, 0.6 on seeds 0-7)
    ratios_naive, ratios = [], []
    for seed in (0, 1, 2):
        sim = simulate_partial_tumble("fast_rotation", seed=seed, coverage=None, duration_s=60.0)
        mag, h_true = _walked(sim, seed, 1.0)
        turns = gyro_turns(sim.t_s, sim.gyro, np.ones(len(sim.t_s), bool))
        res = with_gyro(calibrate_tumble(mag, sim.accel, t_s=sim.t_s), mag, sim.accel, turns, sim.t_s)
        block = res.diagnosis.block
        assert res.gyro["used"] and block["unexplained"] is True
        cost = block["unexplained_cost"]
        naive = np.array([cost["hard_iron"][a]["naive"] for a in ("mx", "my", "mz")])
        wide = res.fit.hard_iron_sigma
        np.testing.assert_allclose([cost["hard_iron"][a]["widened"] for a in ("mx", "my", "mz")], wide)
        assert np.all(wide > naive) and cost["heading_sigma_deg"]["widened"] > cost["heading_sigma_deg"]["naive"]
        assert set(cost["direction_sigma_deg"]) == {"mag_to_accel.x", "mag_to_accel.y", "mag_to_accel.z"}
        assert block["hard_iron_change"]["sigma"] == pytest.approx(list(wide))
        ratios_naive.append((res.fit.hard_iron - h_true) / naive)
        ratios.append((res.fit.hard_iron - h_true) / wide)
    assert np.sqrt(np.mean(np.square(ratios_naive))) > 3.0
    assert np.sqrt(np.mean(np.square(ratios))) < 2.0


def test_a_clean_gyro_aided_fit_is_not_widened():
    sim = simulate_partial_tumble("fast_rotation", seed=0, coverage=None, duration_s=60.0)
    turns = gyro_turns(sim.t_s, sim.gyro, np.ones(len(sim.t_s), bool))
    res = with_gyro(calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s), sim.mag, sim.accel, turns, sim.t_s)
    assert res.gyro["used"] and res.diagnosis.block["unexplained"] is False
    assert "unexplained_cost" not in res.diagnosis.block
    g = _gyro_fit(sim)
    np.testing.assert_allclose(res.fit.hard_iron_sigma, g.hard_iron_sigma, rtol=1e-6)
