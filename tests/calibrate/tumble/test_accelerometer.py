"""The accelerometer's own calibration (:mod:`calibrate.tumble.accelerometer`): the fit recovers a simulated
``A``, ``b`` within sigmas from the injected noise, says what a cap leaves undetermined, refuses what never rests;
the file round-trips, and the runtime applies it at the filter's one entry (start window and filter alike)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.tumble import calibrate_tumble
from calibrate.tumble.accelerometer import _NAMES, _PAIRS, MIN_REST_ROWS, NoAccelCalibration, fit_accelerometer
from compass.calibration import CalibrationFileError, from_dict
from compass.filter import FilterConfig, FilterStart, run_filter
from compass.frames import world_field
from compass.sim.tumble import simulate_tumble

G, NOISE, RATE_HZ = 9.81, 0.02, 50.0
A_TRUE = np.array([[1.06, 0.01, -0.008], [0.01, 0.93, 0.005], [-0.008, 0.005, 1.04]])
B_TRUE = np.array([0.15, -0.12, 0.2]) * G


def _dwells(directions, seed=0, seconds=1.5):
    """Still dwells (``seconds`` each) at the gravity ``directions`` (housing frame), joined by 0.5 s of fast
    motion (a random walk of 2 m/s^2 a row): the raw readings ``A_TRUE^-1 f + B_TRUE`` with white noise ``NOISE``."""
    rng = np.random.default_rng(seed)
    rows = []
    for u in directions:
        rows.append(np.tile(G * u, (int(seconds * RATE_HZ), 1)))
        rows.append(G * u + np.cumsum(rng.normal(0.0, 2.0, (int(0.5 * RATE_HZ), 3)), axis=0))
    f = np.vstack(rows)
    raw = f @ np.linalg.inv(A_TRUE).T + B_TRUE + rng.normal(0.0, NOISE, f.shape)
    return raw, np.arange(len(raw)) / RATE_HZ


def _directions(n, max_tilt_deg=180.0, seed=0):
    rng = np.random.default_rng(seed)
    tilt = np.arccos(rng.uniform(np.cos(np.radians(max_tilt_deg)), 1.0, n))
    az = rng.uniform(0.0, 2 * np.pi, n)
    return np.column_stack([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])


def _scale(cal):
    """The gauge: the fit's 1 g reads ``one_g``, the truth's ``G``: ``A_fit = A_TRUE * one_g / G``."""
    return cal.one_g / G


def test_full_sphere_recovers_matrix_and_offset_within_sigmas():
    raw, t = _dwells(_directions(40))
    cal = fit_accelerometer(raw, t)
    assert cal.held == ()
    # sigmas from the injected noise: each dwell's 75 rows of 0.02 m/s^2, over 40 directions
    assert np.all(cal.offset_sigma < 0.01) and np.all(cal.matrix_sigma < 0.002)
    assert np.all(np.abs(cal.offset - B_TRUE) < 5 * cal.offset_sigma)
    assert np.all(np.abs(cal.matrix - A_TRUE * _scale(cal)) < 5 * cal.matrix_sigma)
    assert cal.spread_after < 0.2 * cal.spread_before
    assert np.allclose(np.linalg.norm(cal.apply(raw[:50]), axis=1), cal.one_g, atol=4 * NOISE)


def test_a_60_deg_cap_reports_the_offset_along_its_axis_undetermined():
    raw, t = _dwells(_directions(40, max_tilt_deg=60.0))
    cal = fit_accelerometer(raw, t)
    # the offset along the cap's axis trades with the scale along it: one of them held, and said
    held = [name for name in ("offset z", "scale zz") if name in cal.held]
    assert len(held) == 1 and held[0] in cal.words()
    assert (cal.offset[2] == 0.0 and np.isnan(cal.offset_sigma[2])) or (cal.matrix[2, 2] == 1.0
                                                                         and np.isnan(cal.matrix_sigma[2, 2]))
    # |f| at rest is right on the cap, and the direction of gravity closer; not exact: the held parameter (0.2 g of
    # offset along the cap's axis) leaves degrees across it, which |f| alone cannot see
    f_true = G * _directions(200, max_tilt_deg=60.0, seed=5)
    raw_true = f_true @ np.linalg.inv(A_TRUE).T + B_TRUE
    rms = [np.sqrt(np.mean(_angle_deg(x, f_true) ** 2)) for x in (raw_true, cal.apply(raw_true))]
    assert rms[1] < 0.5 * rms[0]
    f = np.linalg.norm(cal.apply(raw), axis=1)
    assert abs(np.median(f) - cal.one_g) < 3 * NOISE
    assert cal.spread_after < 0.2 * cal.spread_before


def _angle_deg(x, y):
    cos = np.sum(x * y, axis=1) / np.linalg.norm(x, axis=1) / np.linalg.norm(y, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_an_accelerometer_that_never_rests_gives_no_calibration_in_words():
    rng = np.random.default_rng(1)
    raw = G * _directions(1)[0] + np.cumsum(rng.normal(0.0, 1.0, (3000, 3)), axis=0)
    t = np.arange(len(raw)) / RATE_HZ
    with pytest.raises(NoAccelCalibration, match="held still"):
        fit_accelerometer(raw, t)
    with pytest.raises(NoAccelCalibration, match=f"at least {MIN_REST_ROWS}"):
        fit_accelerometer(raw[:40], t[:40])


def test_a_tumble_without_rest_says_so_and_still_calibrates():
    sim = simulate_tumble(seed=1, n=1500)
    res = calibrate_tumble(sim.mag, sim.accel, t_s=np.arange(len(sim.mag)) * 1e3)  # rows a long time apart
    assert res.accelerometer is None and "no accelerometer calibration" in res.accelerometer_words
    doc = res.to_json()
    assert doc["accelerometer"]["matrix"] is None and "no accelerometer" in res.report()
    assert from_dict(doc).model.accel_correction is None


def test_the_file_round_trips_and_a_file_without_the_key_reads_as_before():
    sim = simulate_tumble(seed=1, n=1500)
    doc = calibrate_tumble(sim.mag, sim.accel).to_json()
    doc.pop("accelerometer")  # a file from before the key
    assert from_dict(doc).model.accel_correction is None
    raw, t = _dwells(_directions(40))
    cal = fit_accelerometer(raw, t)
    matrix, offset, one_g = from_dict(doc | {"accelerometer": cal.to_json()}).model.accel_correction
    assert np.array_equal(matrix, cal.matrix) and np.array_equal(offset, cal.offset) and one_g == cal.one_g
    bad = cal.to_json() | {"matrix": (cal.matrix + np.triu(np.full((3, 3), 0.1), 1)).tolist()}
    with pytest.raises(CalibrationFileError, match="symmetric"):
        from_dict(doc | {"accelerometer": bad})
    singular = cal.to_json() | {"matrix": [[0.5, 0.5, 0.0], [0.5, 0.5, 0.0], [0.0, 0.0, 1.0]]}
    with pytest.raises(CalibrationFileError, match="positive determinant"):
        from_dict(doc | {"accelerometer": singular})


def _stream(seconds=30.0):
    """A housing swinging slowly (exact gravity and field, 100 Hz), its accelerometer read through ``A_TRUE``,
    ``B_TRUE``: the raw rows and the corrected ones (what 1 g reads: ``G``)."""
    t = np.arange(int(seconds * 100)) / 100.0
    rot = Rotation.from_euler("xyz", np.column_stack([30 * np.sin(0.3 * t), 20 * np.sin(0.2 * t), 40 * t]),
                              degrees=True)
    gyro = np.vstack([(rot[:-1].inv() * rot[1:]).as_rotvec() * 100.0, np.zeros(3)])
    f = rot.apply([0.0, 0.0, G], inverse=True)
    field = rot.apply(world_field(60.0, 50.0), inverse=True)
    return t, f @ np.linalg.inv(A_TRUE).T + B_TRUE, f, gyro, field


def test_the_runtime_applies_the_correction_at_the_one_entry():
    t, raw, f, gyro, field = _stream()
    base = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.3)
    corrected = run_filter(t, f, gyro, field, base).quat
    config = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.3,
                          accel_correction=(tuple(map(tuple, A_TRUE)), tuple(B_TRUE), G))
    # the raw rows through the correction (start window and filter alike) are the corrected rows
    assert np.allclose(run_filter(t, raw, gyro, field, config).quat, corrected, atol=1e-9)
    # the identity and no offset change nothing: a file without the key behaves as before
    identity = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.3,
                            accel_correction=(tuple(map(tuple, np.eye(3))), (0.0, 0.0, 0.0), G))
    assert np.array_equal(run_filter(t, f, gyro, field, identity).quat, corrected)
    # and uncorrected, the raw rows tilt it
    assert not np.allclose(run_filter(t, raw, gyro, field, base).quat, corrected, atol=1e-3)
    with pytest.raises(ValueError, match="accel_correction"):
        FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.3, accel_correction=(np.eye(3), (0.0, 0.0), G))


def test_an_installation_turns_the_correction_into_the_products_frame():
    from compass.installed import installed_model

    sim = simulate_tumble(seed=1, n=1500)
    raw, t = _dwells(_directions(40))
    cal = fit_accelerometer(raw, t)
    base = from_dict(calibrate_tumble(sim.mag, sim.accel).to_json() | {"accelerometer": cal.to_json()}).model
    rot = Rotation.from_euler("xyz", [10.0, -20.0, 35.0], degrees=True).as_matrix()
    matrix, offset, one_g = installed_model(base, np.zeros(3), np.eye(3), alignment=rot).accel_correction
    # the filter reads the module's accelerometer turned into the product's frame, R a: corrected there, R A (a - b)
    assert np.allclose((raw[:20] @ rot.T - offset) @ matrix.T, cal.apply(raw[:20]) @ rot.T)
    assert np.array_equal(installed_model(base, np.zeros(3), np.eye(3)).accel_correction[0], cal.matrix)
    assert one_g == cal.one_g  # the unit does not turn


def test_a_stream_in_another_unit_than_the_correction_is_refused_at_the_start():
    t, raw, f, gyro, field = _stream()
    correction = (tuple(map(tuple, A_TRUE)), tuple(B_TRUE), G)
    config = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.3, accel_correction=correction)
    rows = list(zip(t, raw, gyro, field))
    same = FilterStart(config)
    for i, row in enumerate(rows[:300]):
        same.add(i, *row)
    assert same.done and same.gravity_words is None
    other = FilterStart(config)  # the same board read in m/s^2 where the correction was fitted in g
    for i, (ti, a, w, b) in enumerate(rows[:300]):
        other.add(i, ti, a * 9.80665, w, b)
    assert other.done and "another unit" in other.gravity_words and f"{G:.4g}" in other.gravity_words


def test_the_per_row_path_corrects_as_the_filter_does_and_not_in_another_unit():
    from compass.io.units import RecordingWarning

    sim = simulate_tumble(seed=1, n=1500)
    raw, t = _dwells(_directions(40))
    cal = fit_accelerometer(raw, t)
    model = from_dict(calibrate_tumble(sim.mag, sim.accel).to_json() | {"accelerometer": cal.to_json()}).model
    config = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.3, accel_correction=model.accel_correction)
    corrected = model.corrected_accel(raw[:50])
    assert not np.allclose(corrected, raw[:50], atol=1e-3)  # the correction is not the identity here
    assert np.allclose(corrected, [config.housing_accel(tuple(a)) for a in raw[:50]], atol=1e-12)
    with pytest.warns(RecordingWarning, match="another unit"):
        same = model.corrected_accel(raw[:50] * 9.80665)
    assert np.array_equal(same, raw[:50] * 9.80665)


def test_run_filter_refuses_a_stream_in_another_unit_as_live_does():
    t, raw, f, gyro, field = _stream(seconds=5.0)
    config = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.3,
                          accel_correction=(tuple(map(tuple, A_TRUE)), tuple(B_TRUE), G))
    assert np.all(np.isfinite(run_filter(t, raw, gyro, field, config).quat[-10:]))
    with pytest.raises(ValueError, match="another unit"):
        run_filter(t, raw / 9.80665, gyro, field, config)


def _robot_cap(seed, accel_bias_m_s2=(1.5, -1.2, 1.4), accel_scale=(0.07, -0.06, 0.08)):
    """A robot's calibration path (its gravity within a ~60 deg cap) read by a board with large accelerometer errors
    (the bad-accel board's kind, or those given), the rows at a sixth of the rate: (raw rows, turns, true errors)."""
    from compass.io.tumble import gyro_turns
    from compass.sim.motion import SensorErrors
    from compass.sim.robot import simulate_robot

    errors = SensorErrors(gyro_bias_rad_s=(0.004, -0.006, 0.003), gyro_scale=(0.015, -0.012, 0.018),
                          accel_bias_m_s2=accel_bias_m_s2, accel_scale=accel_scale, gyro_noise=3e-4,
                          accel_noise_m_s2=0.1, mag_latency_s=0.02)
    rec = simulate_robot(seed, errors=errors)
    keep = np.zeros(len(rec.t_s), bool)
    keep[::6] = True
    rows = (rec.mag_ut[keep], rec.accel_m_s2[keep], gyro_turns(rec.t_s, rec.gyro_rad_s, keep), rec.t_s[keep])
    return rec, rows, errors


def test_on_a_robot_cap_the_gyro_aided_fit_pins_the_held_offset():
    import warnings

    from calibrate.tumble.gyro import with_gyro

    rec, (mag, acc, turns, t), errors = _robot_cap(1064)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        alone = calibrate_tumble(mag, acc, t_s=t)
        res = with_gyro(alone, mag, acc, turns, t)
    before, after = alone.accelerometer, res.accelerometer
    assert "offset z" in before.held and after.from_gyro == ("offset z",) and "offset z" not in after.held
    assert "fitted beside the gyro-aided fit" in after.words()
    # the offset along the cap's axis within 4 of its stated sigmas (the still rows' white scatter's) of the truth
    assert abs(after.offset[2] - errors.accel_bias_m_s2[2]) < 4 * after.offset_sigma[2]
    # gravity's direction across the cap (the truth's specific force through the board's errors, noise-free)
    f = rec.specific_force_m_s2[::50]
    read = f * (1.0 + np.asarray(errors.accel_scale)) + np.asarray(errors.accel_bias_m_s2)
    rms = [np.sqrt(np.mean(_angle_deg(c.apply(read), f) ** 2)) for c in (before, after)]
    assert rms[1] < 0.5 * rms[0]
    block = from_dict(res.to_json()).model.accel_correction
    assert np.allclose(block[1], after.offset) and res.to_json()["accelerometer"]["from_gyro"] == ["offset z"]
    # what moved with it is named, its sigma grown by the pinned one's through the step (never left unstated)
    sig_before, sig_after = ([c.matrix_sigma[i, j] for i, j in _PAIRS] + list(c.offset_sigma) for c in (before, after))
    sig_before, sig_after = np.array(sig_before), np.array(sig_after)
    moved = before.params() != after.params()
    assert after.moved and set(after.moved) | {"offset z"} == {n for n, m in zip(_NAMES, moved) if m}
    assert np.all(np.isfinite(sig_after[moved]))
    known = moved & np.isfinite(sig_before)
    assert np.all(sig_after[known] > sig_before[known])
    assert "refitted with it" in after.words()


def test_a_held_offset_smaller_than_the_windows_bias_stays_held():
    """A low-cost board's offsets (0.15 m/s^2 across the cap, 0.01 along it): what the gyro-aided fit reads along the
    axis is below :data:`~calibrate.tumble.gyro.ACCEL_PIN_FLOOR` of g, not told from the windows' bias, and the
    offset along the cap's axis stays held at zero (the still rows' calibration unchanged)."""
    import warnings

    from calibrate.tumble.gyro import with_gyro

    _, (mag, acc, turns, t), _ = _robot_cap(1066, (-0.0135, 0.149, -0.0099), (0.013, 0.002, 0.014))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        alone = calibrate_tumble(mag, acc, t_s=t)
        res = with_gyro(alone, mag, acc, turns, t)
    before, after = alone.accelerometer, res.accelerometer
    assert "offset z" in before.to_pin
    assert after.from_gyro == () and "offset z" in after.held
    np.testing.assert_array_equal(after.offset, before.offset)
    np.testing.assert_array_equal(after.matrix, before.matrix)
