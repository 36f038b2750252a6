import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.attitude import level_heading_bound_deg, solve_attitude, two_vector_rotation
from compass.cli import main
from compass.frames import heading_pitch_roll, r_world_from_housing, world_field
from compass.io.table import read_table
from compass.model import SensorModel
from compass.response import LinearResponse
from compass.sim.fourflip import simulate_fourflip
from compass.site import known_reference
from compass.sim.runtime import simulate_runtime, write_runtime
from compass.calibration import model_to_dict


@pytest.fixture(scope="module")
def truth():
    return simulate_fourflip(seed=4, dip_deg=60.0).truth


def true_model(truth, noise_scale=1.0) -> SensorModel:
    """The simulator's sensor as a calibration would give it with no calibration error."""
    field = truth["field_ut"]
    responses = tuple(LinearResponse(o, g, (-field, field)) for o, g in zip(truth["offsets"], truth["gains_per_ut"]))
    return SensorModel(tuple(truth["channels"]), np.array(truth["directions"]), responses, field, field,
                       truth["dip_deg"], noise_scale * np.array(truth["noise"]))


def wrap(d):
    return np.mod(d + 180.0, 360.0) - 180.0


def rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def test_closed_form_equals_align_vectors():
    rng = np.random.default_rng(0)
    up, field = rng.normal(size=(40, 3)), rng.normal(size=(40, 3))
    unit = lambda v: v / np.linalg.norm(v)  # noqa: E731
    for f in (0.0, 0.2, 0.7):
        ours = two_vector_rotation(up, field, 55.0, f)
        for i in range(len(up)):
            weights = [np.inf, 1.0] if f == 0 else [1.0 - f, f]
            ref, _ = Rotation.align_vectors([[0, 0, 1], world_field(55.0)], [unit(up[i]), unit(field[i])], weights=weights)
            assert (ref.inv() * ours[i]).magnitude() < 1e-9


def test_spec_angles_round_trip_through_scipy_euler(truth):
    rng = np.random.default_rng(1)
    h, p, r = rng.uniform(0, 360, 300), rng.uniform(-85, 85, 300), rng.uniform(-179, 179, 300)
    rot = Rotation.from_euler("ZYX", np.column_stack([-h, -p, r]), degrees=True)  # SPEC 1 in scipy
    assert np.allclose((rot.inv() * r_world_from_housing(h, p, r)).magnitude(), 0.0, atol=1e-12)
    model = true_model(truth)
    x = rot.apply(world_field(truth["dip_deg"], truth["field_ut"]), inverse=True) @ model.unit_directions.T
    raw = np.asarray(truth["offsets"]) + np.asarray(truth["gains_per_ut"]) * x
    att = solve_attitude(model, raw, accel=rot.apply([0.0, 0.0, 9.81], inverse=True),  # any accel unit
                         reference=known_reference(truth["dip_deg"], truth["field_ut"]))
    np.testing.assert_allclose(wrap(att.heading_deg - h), 0.0, atol=1e-7)
    np.testing.assert_allclose(att.pitch_deg, p, atol=1e-7)
    np.testing.assert_allclose(wrap(att.roll_deg - r), 0.0, atol=1e-7)
    assert att.mode == "accelerometer" and not att.disturbed.any()


def test_sign_conventions_of_spec():
    # heading 90: +X points east, so the field (north) lies along housing +Y (left)
    b = r_world_from_housing(90.0, 0.0, 0.0).apply(world_field(0.0), inverse=True)[0]
    np.testing.assert_allclose(b, [0.0, 1.0, 0.0], atol=1e-12)
    # pitch +30 (nose up): the up direction has a +X component in the housing
    up = r_world_from_housing(0.0, 30.0, 0.0).apply([0, 0, 1.0], inverse=True)[0]
    np.testing.assert_allclose(up, [0.5, 0.0, np.cos(np.radians(30))], atol=1e-12)
    # roll +30 (right side, -Y, down): -Y points below the horizon, so up has a +Y component
    up = r_world_from_housing(0.0, 0.0, 30.0).apply([0, 0, 1.0], inverse=True)[0]
    np.testing.assert_allclose(up, [0.0, 0.5, np.cos(np.radians(30))], atol=1e-12)
    h, p, r = heading_pitch_roll(r_world_from_housing(10.0, 20.0, 30.0))
    np.testing.assert_allclose([h[0], p[0], r[0]], [10.0, 20.0, 30.0])


@pytest.mark.parametrize("pitch", [89.0, 89.9, 89.999, 90.0, -89.99, -90.0])
def test_gimbal_lock_neighbourhood_has_no_nan(truth, pitch):
    model = true_model(truth)
    rot = r_world_from_housing(np.array([40.0, 200.0]), pitch, np.array([10.0, -30.0]))
    x = rot.apply(world_field(truth["dip_deg"], truth["field_ut"]), inverse=True) @ model.unit_directions.T
    raw = np.asarray(truth["offsets"]) + np.asarray(truth["gains_per_ut"]) * x
    att = solve_attitude(model, raw, accel=rot.apply([0.0, 0.0, 1.0], inverse=True),
                         reference=known_reference(truth["dip_deg"], truth["field_ut"]))
    for name, column in att.columns().items():
        assert not np.any(np.isnan(column.astype(float))), name
    np.testing.assert_allclose(att.pitch_deg, pitch, atol=1e-5)
    # the attitude itself is right even where heading and roll trade off
    est = r_world_from_housing(att.heading_deg, att.pitch_deg, att.roll_deg)
    assert np.all(np.degrees((est.inv() * rot).magnitude()) < 1e-5)
    # heading is undefined at the pole: its sigma says so
    assert np.all(att.heading_sigma_deg > 10 * att.pitch_sigma_deg)


def test_seed_field_only_system_has_rank_two(truth):
    """Seed 000 solves heading, pitch, roll from d(phi, phi', phi'') = B: the Jacobian has rank 2."""
    rng = np.random.default_rng(2)
    b_w = world_field(truth["dip_deg"])
    step = 1e-3  # degrees
    for h, p, r in zip(rng.uniform(0, 360, 5), rng.uniform(-80, 80, 5), rng.uniform(-80, 80, 5)):
        def f(angles):
            return r_world_from_housing(*angles).apply(b_w, inverse=True)[0]
        jac = np.column_stack([(f(np.array([h, p, r]) + step * e) - f(np.array([h, p, r]) - step * e)) / (2 * step)
                               for e in np.eye(3)])
        s = np.linalg.svd(jac, compute_uv=False)
        assert s[1] > 0.1 * s[0] and s[2] < 1e-7 * s[0]
        # the blind direction: turning about the field itself changes no output
        base = r_world_from_housing(h, p, r)
        turned = Rotation.from_rotvec(np.radians(25.0) * b_w) * base
        np.testing.assert_allclose(turned.apply(b_w, inverse=True), base.apply(b_w, inverse=True), atol=1e-12)


def test_field_only_is_refused_naming_what_is_missing(truth):
    model = true_model(truth)
    raw = np.tile(truth["offsets"], (3, 1))
    with pytest.raises(ValueError, match="fixes only two of heading, pitch and roll.*ax,ay,az.*pitch_deg.*--level"):
        solve_attitude(model, raw)
    with pytest.raises(ValueError, match="one source of tilt"):
        solve_attitude(model, raw, accel=np.ones((3, 3)), level=True)


def test_propagated_sigma_matches_monte_carlo(truth):
    model = true_model(truth)
    session = simulate_runtime(truth, 40000, seed=3, accel_noise_g=0.002)
    att = solve_attitude(model, session.outputs, accel=session.accel, accel_noise_g=0.002)
    # RMS of z-scores: 1 within the sampling error of 40000 draws (~0.4 %) plus linearisation
    for est, true, sigma in ((att.heading_deg, session.heading_deg, att.heading_sigma_deg),
                             (att.pitch_deg, session.pitch_deg, att.pitch_sigma_deg),
                             (att.roll_deg, session.roll_deg, att.roll_sigma_deg)):
        assert rms(wrap(est - true) / sigma) == pytest.approx(1.0, abs=0.03)
    assert att.in_range.all() and att.disturbed.mean() < 1e-3


def test_doubling_noise_doubles_sigma(truth):
    # noiseless readings: each row's weight then depends on the noise model alone (a row whose dip is
    # off by more than twice its sigma also lowers its field's weight, which noisy data would change)
    session = simulate_runtime(truth, 200, seed=8, noise_ut=0.0, accel_noise_g=0.0)
    site = known_reference(truth["dip_deg"], truth["field_ut"])
    one = solve_attitude(true_model(truth), session.outputs, accel=session.accel, accel_noise_g=0.002, reference=site)
    two = solve_attitude(true_model(truth, 2.0), session.outputs, accel=session.accel, accel_noise_g=0.004,
                         reference=site)
    np.testing.assert_allclose(two.heading_sigma_deg, 2 * one.heading_sigma_deg, rtol=1e-9)
    np.testing.assert_allclose(two.roll_sigma_deg, 2 * one.roll_sigma_deg, rtol=1e-9)


def test_disturbance_flag_on_injected_field_change(truth):
    n = 4000
    extra = np.zeros((n, 3))
    extra[n // 2:] = [0.0, 4.0, -3.0]  # 5 uT (10 % of |B|) from a magnet, second half only
    session = simulate_runtime(truth, n, seed=9, extra_field_ut=extra)
    att = solve_attitude(true_model(truth), session.outputs, accel=session.accel,
                         reference=known_reference(truth["dip_deg"], truth["field_ut"]))
    assert att.disturbed[: n // 2].mean() < 0.01
    assert att.disturbed[n // 2:].mean() > 0.99
    # with nothing said, the reference comes from the recording: robust while the magnet is there for
    # less than half of it (with half and half, which field is the site's cannot be told)
    third = simulate_runtime(truth, n, seed=9, extra_field_ut=np.where(np.arange(n)[:, None] < n // 3, extra[-1], 0.0))
    att = solve_attitude(true_model(truth), third.outputs, accel=third.accel)
    assert att.reference.source == "recording"
    assert att.disturbed[n // 3:].mean() < 0.01 and att.disturbed[: n // 3].mean() > 0.99


def test_level_mode_error_within_bound(truth):
    tilt = 3.0
    session = simulate_runtime(truth, 3000, seed=10, max_tilt_deg=tilt / np.sqrt(2), accel_noise_g=None)
    att = solve_attitude(true_model(truth), session.outputs, level=True, max_tilt_deg=tilt)
    assert att.mode == "level" and np.all(att.pitch_deg == 0) and np.all(att.roll_deg == 0)
    error = np.abs(wrap(att.heading_deg - session.heading_deg))
    assert np.all(error <= att.heading_bound_deg + 4 * att.heading_sigma_deg)
    assert np.max(error) > 0.5 * att.heading_bound_deg[0]  # the bound is not loose by much
    # first order: tan(dip) * tilt
    assert level_heading_bound_deg(60.0, 0.5) == pytest.approx(np.tan(np.radians(60.0)) * 0.5, rel=0.02)
    # the field shows a tilt it cannot hide: tilt_min is a lower bound of the real tilt at 95 % or more (the
    # apparent dip moves by at most the tilt): above it on at most 4.6 % of rows, +3 binomial sigmas of 3000
    real_tilt = np.degrees(np.arccos(np.cos(np.radians(session.pitch_deg)) * np.cos(np.radians(session.roll_deg))))
    assert np.mean(att.tilt_min_deg > real_tilt) < 0.046 + 3 * np.sqrt(0.046 * 0.954 / 3000)
    assert np.mean(att.tilt_min_deg > 0.5) > 0.3  # and it shows the tilt where the tilt is along the meridian


def test_level_mode_when_really_level_is_noise_limited(truth):
    session = simulate_runtime(truth, 3000, seed=11, max_tilt_deg=0.0, accel_noise_g=None)
    att = solve_attitude(true_model(truth), session.outputs, level=True)
    assert np.mean(att.tilt_min_deg > 0) < 0.046 + 3 * np.sqrt(0.046 * 0.954 / 3000)  # a lower bound: 0 when level
    assert rms(wrap(att.heading_deg - session.heading_deg) / att.heading_sigma_deg) == pytest.approx(1.0, abs=0.1)
    assert att.disturbed.mean() < 0.01


def test_known_tilt_columns(truth):
    session = simulate_runtime(truth, 3000, seed=12, accel_noise_g=None)
    att = solve_attitude(true_model(truth), session.outputs, pitch_deg=session.pitch_deg, roll_deg=session.roll_deg)
    np.testing.assert_allclose(att.pitch_deg, session.pitch_deg, atol=1e-9)
    assert rms(wrap(att.heading_deg - session.heading_deg) / att.heading_sigma_deg) == pytest.approx(1.0, abs=0.1)


# ----------------------------------------------------------------------------- command line


@pytest.fixture(scope="module")
def files(tmp_path_factory, truth):
    folder = tmp_path_factory.mktemp("att")
    cal = folder / "cal.json"
    cal.write_text(json.dumps(model_to_dict(true_model(truth))))
    rec, truth_csv = write_runtime(simulate_runtime(truth, 2000, seed=13), folder / "rec.csv")
    return folder, cal, rec, truth_csv


def test_cli_end_to_end(files, capsys):
    folder, cal, rec, truth_csv = files
    out = folder / "att.csv"
    assert main(["attitude", str(cal), str(rec), "--out", str(out)]) == 0
    table, truth = read_table(out), read_table(truth_csv)
    assert table.metadata["mode"] == "accelerometer"
    assert table.columns[:4] == ("t_s", "heading_deg", "pitch_deg", "roll_deg")
    error = wrap(table.column("heading_deg") - truth.column("heading_deg"))
    assert rms(error / table.column("heading_sigma_deg")) == pytest.approx(1.0, abs=0.1)
    # never overwrite without --force
    assert main(["attitude", str(cal), str(rec), "--out", str(out)]) == 2
    assert "use --force" in capsys.readouterr().err
    assert main(["attitude", str(cal), str(rec), "--out", str(out), "--force"]) == 0


def test_solve_recording_is_the_library_call_the_command_writes(files, tmp_path):
    """The command is a thin adapter: its CSV is solve_recording's, which solves the rows as solve_attitude does."""
    from compass.errors import BadInput
    from compass.recording import solve_recording

    folder, cal, rec, _ = files
    solved = solve_recording(cal, rec)
    table = read_table(rec)
    raw = np.column_stack([table.column(c) for c in solved.model.channels])
    accel = np.column_stack([table.column(c) for c in ("ax", "ay", "az")])
    direct = solve_attitude(solved.model, raw, accel=accel)  # an uncorrected model file: the IMU is left as is
    np.testing.assert_array_equal(solved.attitude.heading_deg, direct.heading_deg)
    out = tmp_path / "att.csv"
    assert main(["attitude", str(cal), str(rec), "--out", str(out)]) == 0
    assert out.read_text() == solved.to_csv()
    with pytest.raises(BadInput, match=r"--accel-noise-g must be a number in \(0, 1\] g, got 0"):
        solve_recording(cal, rec, accel_noise_g=0.0)


def test_cli_level_mode_columns(files, tmp_path):
    folder, cal, rec, _ = files
    lines = rec.read_text().splitlines()
    keep = [0, 1, 2, 3]  # t_s and the three channels, no accelerometer
    (tmp_path / "flat.csv").write_text("\n".join(",".join(line.split(",")[i] for i in keep) for line in lines) + "\n")
    out = tmp_path / "att.csv"
    assert main(["attitude", str(cal), str(tmp_path / "flat.csv"), "--out", str(out), "--level"]) == 0
    table = read_table(out)
    assert {"heading_bound_deg", "tilt_min_deg"} <= set(table.columns) and table.metadata["mode"] == "level"


@pytest.mark.parametrize("edit, args, message", [
    (lambda lines: [lines[0].replace("v2", "w2")] + lines[1:], [], "column 'v2': missing required column 'v2'"),
    (lambda lines: lines[:5] + [lines[5].replace(lines[5].split(",")[2], "abc", 1)] + lines[6:], [],
     "row 6, column 'v2': expected a number"),
    (lambda lines: [",".join(line.split(",")[:4]) for line in lines], [], "fixes only two of heading, pitch and roll"),
    (lambda lines: [",".join(line.split(",")[:5]) for line in lines], [], "column 'ay'"),
    (lambda lines: lines[:3] + [",".join(lines[3].split(",")[:4] + ["0", "0", "0"])] + lines[4:], [],
     "row 4, column 'ax': accelerometer reads zero"),
    (lambda lines: lines, ["--level"], "one source of tilt"),
])
def test_cli_bad_input_exit_2_names_row_and_column(files, tmp_path, capsys, edit, args, message):
    folder, cal, rec, _ = files
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(edit(rec.read_text().splitlines())) + "\n")
    assert main(["attitude", str(cal), str(bad), "--out", str(tmp_path / "o.csv"), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_cli_rejects_unknown_calibration_format(files, tmp_path, capsys):
    folder, cal, rec, _ = files
    doc = json.loads(cal.read_text()) | {"format": "compass-calibration/9"}
    (tmp_path / "cal.json").write_text(json.dumps(doc))
    assert main(["attitude", str(tmp_path / "cal.json"), str(rec), "--out", str(tmp_path / "o.csv")]) == 2
    assert "unknown calibration format 'compass-calibration/9'" in capsys.readouterr().err


def test_cli_applies_or_warns_about_the_temperature_effect(files, tmp_path, capsys):
    folder, cal, rec, truth_csv = files
    d = json.loads(cal.read_text())
    d["effects"] = [{"name": "temperature", "reference": {"temp_c": 20.0}, "parameters": {
        f"{c}.offset_per_degc": {"value": 0.01} for c in d["channels"]}}]
    hot_cal = tmp_path / "cal.json"
    hot_cal.write_text(json.dumps(d))
    # the same sensor read at 30 degC: every output 0.1 higher than at the reference
    lines = rec.read_text().splitlines()
    header = lines[0].split(",")
    shifted = [lines[0] + ",temp_c"]
    for line in lines[1:]:
        cells = line.split(",")
        shifted.append(",".join(f"{float(v) + 0.1:.9g}" if name in d["channels"] else v
                                for name, v in zip(header, cells)) + ",30")
    hot = tmp_path / "hot.csv"
    hot.write_text("\n".join(shifted) + "\n")
    assert main(["attitude", str(hot_cal), str(hot), "--out", str(tmp_path / "a.csv")]) == 0
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "b.csv")]) == 0
    compensated, plain = read_table(tmp_path / "a.csv"), read_table(tmp_path / "b.csv")
    assert "compensated to 20.00 degC" in compensated.metadata["temperature"]
    np.testing.assert_allclose(compensated.column("heading_deg"), plain.column("heading_deg"), atol=1e-3)
    capsys.readouterr()
    assert main(["attitude", str(hot_cal), str(rec), "--out", str(tmp_path / "c.csv")]) == 0
    assert "no temp_c column" in capsys.readouterr().err
    assert "NOT compensated" in read_table(tmp_path / "c.csv").metadata["temperature"]


@pytest.mark.parametrize("case", ["magnet", "wrong_dip"])
def test_a_disturbed_or_wrong_field_does_not_pull_the_tilt(truth, case):
    """The field votes on tilt only through the dip; a magnet on some rows (their dip off by degrees) or a
    reference dip 10 deg off must leave pitch and roll at the accelerometer's own precision, with
    honest sigmas (a fixed-weight solution is pulled by a quarter of the dip error: about 2 deg,
    20 sigma)."""
    n, hit = 4000, slice(0, 1000)
    extra = np.zeros((n, 3))
    if case == "magnet":
        extra[hit] = (8.0, -6.0, 10.0)  # uT, NWU
    session = simulate_runtime(truth, n, seed=31, extra_field_ut=extra)
    dip = truth["dip_deg"] + (10.0 if case == "wrong_dip" else 0.0)
    att = solve_attitude(true_model(truth), session.outputs, accel=session.accel, accel_noise_g=0.002,
                         reference=known_reference(dip, truth["field_ut"]))
    quiet = simulate_runtime(truth, n, seed=31)  # the same attitudes and noise, no magnet
    clean = solve_attitude(true_model(truth), quiet.outputs, accel=quiet.accel, accel_noise_g=0.002,
                           reference=known_reference(truth["dip_deg"], truth["field_ut"]))
    for name in ("pitch", "roll"):
        error = wrap(getattr(att, f"{name}_deg")[hit] - getattr(session, f"{name}_deg")[hit])
        sigma = getattr(clean, f"{name}_sigma_deg")
        # RMS of z-scores against the clean rows' sigmas: 1 +- 3 sampling errors (1000 draws) + 5 %
        assert np.allclose(getattr(quiet, f"{name}_deg"), getattr(session, f"{name}_deg"))
        # honest sigmas (1 +- 3 sampling errors of 1000 draws + 5 % linearisation), and no worse than
        # gravity alone: the field's help on tilt is at most 1/sqrt(1 - f), f ~ 0.3, over the clean rows
        assert rms(error / getattr(att, f"{name}_sigma_deg")[hit]) < 1.0 + 3 / np.sqrt(2 * 1000) + 0.05
        assert rms(error) < 1.3 * rms(sigma[hit])
        if case == "magnet":
            assert att.disturbed[hit].mean() > 0.9
