"""Installation calibration: the bench model inside its product, from a tumble or a swing."""

import json
from dataclasses import replace

import numpy as np
import pytest

from calibrate import calibrate_fourflip
from calibrate.contract import CannotCalibrate
from calibrate.installation import InstallationCalibrator, deviation_card
from calibrate.installation.fit import NOT_SEEN_BY_SWING
from compass.attitude import solve_attitude
from compass.cli import main
from compass.installed import installed_model
from compass.io.fourflip import read_fourflip
from compass.io.installation import installation_from_table
from compass.io.table import read_table
from compass.sim.fourflip import simulate_fourflip, write_fourflip
from compass.sim.installation import random_installation, simulate_installation, true_model, write_installation
from compass.sim.runtime import write_runtime
from compass.calibration import model_from_dict


def wrap(d):
    return np.mod(d + 180.0, 360.0) - 180.0


def rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bench")
    session = simulate_fourflip(seed=41, dip_deg=58.0)
    path, _ = write_fourflip(session, folder / "bench.csv")
    cal = calibrate_fourflip(read_fourflip(path), diagnose=True)
    doc = cal.to_json()
    (folder / "bench.json").write_text(json.dumps(doc))
    return model_from_dict(doc), doc, session.truth, folder


def fit(bench, rec, **options):
    model, doc, _, folder = bench
    path, _ = write_installation(rec, folder / f"inst_{rec.kind}_{rec.truth['seed']}.csv", force=True)
    parsed = installation_from_table(read_table(path), model.channels)
    return InstallationCalibrator(base=folder / "bench.json", **options).fit(parsed)


def at_another_site(bench, inst, result, tilt=30.0):
    """Heading RMS at another site (dip 12 deg lower, |B| 10 % lower): installed vs the true installation."""
    model, _, truth, _ = bench
    run = simulate_installation(truth, inst, kind="runtime", n=3000, dip_deg=truth["dip_deg"] - 12.0,
                                field_ut=0.9 * truth["field_ut"], max_tilt_deg=tilt, seed=43)
    best = installed_model(true_model(truth), inst.hard_iron_ut, inst.soft_iron)
    errors = [rms(wrap(solve_attitude(m, run.outputs, accel=run.accel).heading_deg - run.heading_deg))
              for m in (result.model, best, model)]
    return errors, solve_attitude(result.model, run.outputs, accel=run.accel).disturbed.mean()


def test_tumble_finds_the_iron_and_travels(bench):
    _, _, truth, _ = bench
    inst = random_installation(42)
    result = fit(bench, simulate_installation(truth, inst, kind="tumble", n=2000, seed=44))
    z = (result.hard_iron_ut - inst.hard_iron_ut) / result.hard_iron_sigma_ut
    assert np.all(np.abs(z) < 5.0)
    # soft iron: the off-diagonal entries (the diagonal's trace is the assumed scale)
    true_d = inst.soft_iron - np.eye(3)
    for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2)), start=3):
        assert abs(result.soft_iron[i, j] - true_d[i, j]) < 5 * result.soft_iron_sigma[k] + 1e-4
    assert result.diagnosis.block["effects"] == [] and result.diagnosis.unexplained is False
    assert any("scale" in w for w in result.undetermined) and len(result.undetermined) == 1
    assert NOT_SEEN_BY_SWING not in result.report()  # a swing's blind spot, said of swings only
    # trace(S) = 3 holds exactly, in the value and in the covariance (it is assumed, not measured)
    trace = np.array([0, 0, 0, 1, 1, 1, 0, 0, 0.0])
    assert abs(np.trace(result.soft_iron) - 3.0) < 1e-12
    assert trace @ result.covariance @ trace < 1e-12 * np.max(np.diag(result.covariance)[3:6])
    (installed, best, bench_only), disturbed = at_another_site(bench, inst, result)
    assert installed <= 1.3 * best + 0.02 and bench_only > 5 * best and disturbed <= 0.01


def test_level_swing_finds_the_horizontal_hard_iron_and_names_what_it_cannot_see(bench):
    _, _, truth, folder = bench
    inst = random_installation(45)
    result = fit(bench, simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=0.0, seed=46))
    assert result.kind == "swing"
    z = (result.hard_iron_ut[:2] - inst.hard_iron_ut[:2]) / result.hard_iron_sigma_ut[:2]
    assert np.all(np.abs(z) < 2.5)
    assert result.hard_iron_sigma_ut[2] > 10.0  # held at its prior
    assert any("vertical hard iron" in w for w in result.undetermined)
    assert any("S_zz" in w for w in result.undetermined)
    # a slow accelerometer disturbance is not seen by a swing (docs/benchmarks.md): the report says so in words
    assert NOT_SEEN_BY_SWING in result.report()
    # its own site, level: as good as the true installation
    model, _, _, _ = bench
    run = simulate_installation(truth, inst, kind="runtime", n=2000, max_tilt_deg=0.0, seed=47)
    best = installed_model(true_model(truth), inst.hard_iron_ut, inst.soft_iron)
    ours, true = (rms(wrap(solve_attitude(m, run.outputs, accel=run.accel).heading_deg - run.heading_deg))
                  for m in (result.model, best))
    assert ours <= 1.3 * true + 0.02
    # the deviation card: the bench model alone deviates once a turn (hard iron), the plot is written
    card = result.card_before
    assert max(abs(card.coefficients_deg["B"]), abs(card.coefficients_deg["C"])) > 3.0
    assert [p.name for p in result.plots(None, folder / "report")] == ["deviation_card.png"]


def test_tilted_swing_with_heading_reference_fits_the_yaw(bench):
    _, _, truth, _ = bench
    inst = random_installation(48, yaw_deg=4.0)
    rec = simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=10.0, heading_ref_sigma_deg=0.3,
                                seed=49)
    result = fit(bench, rec)
    assert abs(result.yaw_deg - 4.0) < 4 * result.yaw_sigma_deg + 0.01
    assert np.all(np.abs(result.hard_iron_ut - inst.hard_iron_ut) < 5 * result.hard_iron_sigma_ut)
    after = result.card_after
    assert after is not None and after.residual_rms_deg < 0.6 and abs(after.coefficients_deg["A"]) < 0.1
    # compass attitude reads the alignment: the product's heading, not the housing's
    from compass.calibration import dumps

    folder = bench[3]
    (folder / "aligned.json").write_text(dumps(result.to_json()))
    run = simulate_installation(truth, inst, kind="runtime", n=1000, max_tilt_deg=20.0, seed=62)
    run_path, _ = write_installation(run, folder / "aligned_run.csv", force=True)
    assert main(["attitude", str(folder / "aligned.json"), str(run_path), "--out", str(folder / "aligned_att.csv"),
                 "--force"]) == 0
    table = read_table(folder / "aligned_att.csv")
    assert rms(wrap(table.column("heading_deg") - run.heading_deg)) < 0.6
    assert rms(table.column("pitch_deg") - run.pitch_deg) < 0.3


def test_drifting_hard_iron_is_named(bench):
    _, _, truth, _ = bench
    inst = random_installation(50)
    rec = simulate_installation(truth, inst, kind="tumble", n=2000, seed=51)
    gains = np.asarray(truth["gains_per_ut"])
    drift = np.outer(np.linspace(-1.0, 1.0, len(rec.t_s)), [1.5, -1.0, 0.8]) @ np.asarray(truth["directions"]).T
    from dataclasses import replace

    result = fit(bench, replace(rec, outputs=rec.outputs + gains * drift))
    block = result.diagnosis.block
    assert block["effects"] == ["offset_drift"]
    assert block["residual_rms_after"] < 0.5 * block["residual_rms_before"]
    # its parameters reach the file: the drift rate in H, against the injected 2 x (1.5, -1, 0.8) uT over the session
    (effect,) = result.to_json()["effects"]
    rate, sigma = (np.array([effect["parameters"][f"{axis}.hard_iron_rate_per_s"][k] for axis in "xyz"])
                   for k in ("value", "sigma"))
    true_rate = 2.0 * np.array([1.5, -1.0, 0.8]) / np.ptp(rec.t_s)
    assert effect["name"] == "offset_drift" and np.all(np.abs(rate - true_rate) < 4 * sigma + 0.02 * np.abs(true_rate))
    fitted = bench[0].field(rec.outputs + gains * drift)[1]  # the rows inside the bench's range
    assert effect["reference"]["t_s"] == pytest.approx(np.mean(rec.t_s[fitted]))
    # the file reads without this code: the formula names the parameters and the reference
    assert all(n in effect["form"] for n in {p.split(".")[-1] for p in effect["parameters"]} | set(effect["reference"]))
    assert "x.hard_iron_rate_per_s" in result.report() and "offset_drift (linear)" in result.report()
    assert "offset_drift: the hard iron above holds at t_s" in result.report()


def test_temperature_dependent_hard_iron_is_claimed_with_its_coefficients(bench):
    from compass.io.installation import InstallationRecording

    _, _, truth, folder = bench
    rec = simulate_installation(truth, random_installation(67), kind="tumble", n=2000, seed=68)
    temp_c = 25.0 + 5.0 * np.sin(2 * np.pi * 3 * rec.t_s / np.ptp(rec.t_s))  # not a drift in time
    per_c = np.array([0.2, -0.1, 0.15])  # uT per degC
    shift = np.outer(temp_c - temp_c.mean(), per_c) @ np.asarray(truth["directions"]).T
    outputs = rec.outputs + np.asarray(truth["gains_per_ut"]) * shift
    recording = InstallationRecording("sim", "tumble", rec.channels, outputs, rec.accel, rec.t_s, temp_c, None, False,
                                      np.arange(len(rec.t_s)), {})
    result = InstallationCalibrator(base=folder / "bench.json").fit(recording)
    assert result.diagnosis.block["effects"] == ["temperature"] and result.diagnosis.unexplained is False
    (effect,) = result.diagnosis.effects
    found, sigma = (np.array([effect["parameters"][f"{axis}.hard_iron_per_degc"][k] for axis in "xyz"])
                    for k in ("value", "sigma"))
    assert np.all(np.abs(found - per_c) < 4 * sigma)
    fitted = bench[0].field(outputs)[1]
    assert effect["reference"]["temp_c"] == pytest.approx(np.mean(temp_c[fitted]))


def test_diagnosis_is_the_shared_record_and_withdraws_a_drift_when_structure_remains(bench):
    """A hard iron that steps halfway is partly a drift: the shared loop claims nothing, says so, keeps the base fit."""
    from dataclasses import replace

    from calibrate.diagnosis.report import Diagnosis

    _, _, truth, _ = bench
    rec = simulate_installation(truth, random_installation(50), kind="tumble", n=2000, seed=51)
    gains = np.asarray(truth["gains_per_ut"])
    step = np.outer(np.arange(len(rec.t_s)) >= len(rec.t_s) // 2, [3.0, -2.0, 1.5]) @ np.asarray(truth["directions"]).T
    result = fit(bench, replace(rec, outputs=rec.outputs + gains * step))
    assert isinstance(result.diagnosis, Diagnosis)
    block = result.diagnosis.block
    assert block["effects"] == [] and result.to_json()["effects"] == [] and block["unexplained"] is True
    assert len(block["steps"]) == 1 and block["residual_rms_after"] == block["residual_rms_before"]
    assert any(line.startswith("offset_drift (linear; delta-BIC") and "not claimed" in line
               for line in block["not_claimed"])
    assert block["not_applicable"] == {"temperature": "the recording has no temp_c column"}
    assert "not claimed: offset_drift" in result.report() and any("above the bench's noise floor" in w
                                                                   for w in result.warnings)


@pytest.fixture(scope="module")
def bench_cubic(bench, tmp_path_factory):
    """The bench of ``bench`` with every channel's response a cubic (a vanishing one) over +-50 uT:
    beyond that range its curve is extrapolated, not trusted."""
    _, doc, truth, _ = bench
    folder = tmp_path_factory.mktemp("bench_cubic")
    doc = json.loads(json.dumps(doc))
    for channel in doc["channels"].values():
        channel["response"] |= {"model": "cubic", "cubic": 1e-9, "range": [-50.0, 50.0]}
    (folder / "bench.json").write_text(json.dumps(doc))
    return model_from_dict(doc), doc, truth, folder


def test_rows_outside_a_nonlinear_bench_range_are_left_out_and_counted(bench_cubic):
    """A sensor that clips beyond the field its bench calibration saw: those rows would bend the iron."""
    from dataclasses import replace

    model, _, truth, _ = bench_cubic
    inst = random_installation(65, hard_iron_ut=10.0)
    rec = simulate_installation(truth, inst, kind="tumble", n=2000, seed=66)
    offsets, gains = np.asarray(truth["offsets"]), np.asarray(truth["gains_per_ut"])
    x = (rec.outputs - offsets) / gains
    clipped = replace(rec, outputs=offsets + gains * np.clip(x, -54.0, 54.0))  # a rail past 50 uT + 2 %
    outside = int(np.sum(~model.field(clipped.outputs)[1]))
    assert outside > 50
    result = fit(bench_cubic, clipped)
    assert result.n_rows == 2000 - outside and result.n_rows_out_of_range == outside
    assert np.all(np.abs(result.hard_iron_ut - inst.hard_iron_ut) < 5 * result.hard_iron_sigma_ut)
    assert result.diagnosis.unexplained is False
    assert result.to_json()["installation"]["n_rows_out_of_range"] == outside
    assert any(f"{outside} rows" in w and "left out" in w for w in result.warnings)
    assert f"{outside} rows" in result.report()


def test_rows_beyond_a_linear_channel_s_range_are_fitted_and_named(bench):
    """A line beyond its range is the same line (compass.response): kept, and the channels named, as
    compass attitude does."""
    model, _, truth, _ = bench
    rec = simulate_installation(truth, random_installation(73, hard_iron_ut=10.0), kind="tumble", n=2000, seed=74)
    x, _ = model.components(rec.outputs)
    beyond = np.any([r.beyond_range(x[:, c]) for c, r in enumerate(model.responses)], axis=0)
    assert beyond.sum() > 50
    result = fit(bench, rec)
    assert result.n_rows == 2000 and result.n_rows_out_of_range == 0
    assert result.extrapolated.startswith(f"{int(beyond.sum())} fitted rows read a linear channel beyond")
    assert result.extrapolated in result.warnings and "extrapolated linearly" in result.report()


def test_a_field_stronger_than_the_bench_s_everywhere_is_fitted_with_a_warning(bench_cubic):
    """A level swing where the vertical field always exceeds what the bench saw: no row is inside the
    nonlinear bench's range; all are fitted (the response extrapolated), and the warning says so."""
    model, _, truth, _ = bench_cubic
    inst = random_installation(69)
    rec = simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=0.0, dip_deg=75.0, field_ut=62.0,
                                seed=70)
    assert not np.any(model.field(rec.outputs)[1])
    result = fit(bench_cubic, rec)
    assert result.n_rows == 2000 and result.n_rows_out_of_range == 2000
    z = (result.hard_iron_ut[:2] - inst.hard_iron_ut[:2]) / result.hard_iron_sigma_ut[:2]
    assert np.all(np.abs(z) < 2.5)
    assert any("2000 rows" in w and "extrapolated" in w for w in result.warnings)
    assert result.to_json()["installation"]["out_of_range_fitted"] is True


@pytest.fixture(scope="module")
def bench_normalized(tmp_path_factory):
    """The bench of ``bench`` calibrated without |B| in uT: its field unit is the bench's |B|."""
    from dataclasses import replace

    folder = tmp_path_factory.mktemp("bench_normalized")
    session = simulate_fourflip(seed=41, dip_deg=58.0)
    path, _ = write_fourflip(session, folder / "bench.csv")
    rec = read_fourflip(path)
    rec = replace(rec, metadata={k: v for k, v in rec.metadata.items() if k != "field_ut"})
    doc = calibrate_fourflip(rec, diagnose=True).to_json()
    assert doc["field_ut"] is None
    (folder / "bench.json").write_text(json.dumps(doc))
    return model_from_dict(doc), doc, session.truth, folder


def test_hard_iron_prior_is_in_the_bench_field_unit(bench_normalized):
    """Field unit |B| (no field_ut on the bench): the prior of a held hard iron is 20 uT in that unit, not 20 |B|."""
    from calibrate.installation.model import PRIOR_HARD_IRON_UT, TYPICAL_FIELD_UT

    _, _, truth, _ = bench_normalized
    inst = random_installation(45)
    result = fit(bench_normalized, simulate_installation(truth, inst, kind="swing", n=2000, max_tilt_deg=0.0,
                                                         seed=46))
    field_ut = truth["field_ut"]
    assert result.field_magnitude == pytest.approx(1.0, abs=0.05)  # in units of the bench's |B|
    z = (result.hard_iron_ut[:2] - inst.hard_iron_ut[:2] / field_ut) / result.hard_iron_sigma_ut[:2]
    assert np.all(np.abs(z) < 2.5)
    assert result.hard_iron_sigma_ut[2] == pytest.approx(PRIOR_HARD_IRON_UT / TYPICAL_FIELD_UT, rel=0.01)
    assert "x |B_bench|" in result.report() and any("vertical hard iron" in w for w in result.undetermined)


def test_a_site_cannot_set_the_soft_iron_scale_of_a_bench_without_ut(bench_normalized):
    from compass.site import Site

    _, _, truth, _ = bench_normalized
    result = fit(bench_normalized, simulate_installation(truth, random_installation(71), kind="tumble", n=1500,
                                                         seed=72), site=Site.parse("47.6,-122.3", "2026-06-01"))
    (scale,) = [w for w in result.undetermined if "overall scale" in w]
    assert "knows no |B| in uT" in scale and "give --site" not in scale


def test_deviation_card_coefficients():
    psi = np.arange(0.0, 360.0, 5.0)
    truth = {"A": 0.5, "B": -3.0, "C": 2.0, "D": 0.7, "E": -0.4}
    r = np.radians(psi)
    dev = (truth["A"] + truth["B"] * np.sin(r) + truth["C"] * np.cos(r) + truth["D"] * np.sin(2 * r)
           + truth["E"] * np.cos(2 * r))
    card = deviation_card(psi + dev, psi)
    for k, v in truth.items():
        assert card.coefficients_deg[k] == pytest.approx(v, abs=1e-9)


def test_refuses_a_recording_without_a_turn(bench):
    _, _, truth, _ = bench
    rec = simulate_installation(truth, random_installation(52), kind="swing", n=200, max_tilt_deg=0.0, seed=53)
    from dataclasses import replace

    still = replace(rec, outputs=np.repeat(rec.outputs[:1], 200, axis=0) + 1e-4 * np.arange(200)[:, None],
                    accel=np.repeat(rec.accel[:1], 200, axis=0))
    with pytest.raises(CannotCalibrate, match="turned through only"):
        fit(bench, still)


def test_cli_installation_end_to_end(bench, tmp_path, capsys):
    model, doc, truth, folder = bench
    inst = random_installation(54)
    from compass.site import Site

    wmm = Site.parse("47.6,-122.3", "2026-06-01").field()  # the installation is done where the product is used
    rec_path, _ = write_installation(simulate_installation(truth, inst, kind="tumble", n=1500, seed=55,
                                                           dip_deg=wmm.dip_deg, field_ut=wmm.field_ut),
                                     tmp_path / "install.csv")
    out = tmp_path / "installed.json"
    assert main(["calibrate", str(rec_path), "--base", str(folder / "bench.json"), "--out", str(out),
                 "--site", "47.6,-122.3", "--date", "2026-06-01", "--quiet"]) == 0
    installed = json.loads(out.read_text())
    assert installed["model"] == "installed" and installed["base"] == doc and installed["site"]["model"] == "WMM2025"
    assert installed["installation"]["kind"] == "tumble"
    # the runtime reads it: at the site, true north from the file's site block
    wmm_there = {"dip_deg": installed["site"]["dip_deg"], "field_ut": installed["site"]["field_ut"]}
    run = simulate_installation(truth, inst, kind="runtime", n=1000, max_tilt_deg=40.0, seed=56, **wmm_there)
    from compass.sim.runtime import RuntimeSession

    session = RuntimeSession(run.t_s, run.channels, run.outputs, run.accel, run.heading_deg, run.pitch_deg,
                             run.roll_deg, np.zeros((len(run.t_s), 3)))
    att_rec, _ = write_runtime(session, tmp_path / "run.csv")
    assert main(["attitude", str(out), str(att_rec), "--out", str(tmp_path / "att.csv")]) == 0
    table = read_table(tmp_path / "att.csv")
    assert table.metadata["reference_field"].startswith("calibration site")
    assert rms(wrap(table.column("heading_deg") - run.heading_deg)) < 0.6
    assert table.column("disturbed").mean() <= 0.01 and "heading_true_deg" in table.columns


@pytest.mark.parametrize("args, message", [
    (["--site", "1,2"], "cannot tell the recording kind"),
    (["--base", "MISSING.json"], "cannot read calibration"),
    (["--base", "BENCH", "--site", "95,0"], "latitude"),
    (["--base", "BENCH", "--date", "2026-01-01"], "--date needs --site"),
])
def test_cli_installation_bad_input(bench, tmp_path, capsys, args, message):
    _, _, truth, folder = bench
    rec_path, _ = write_installation(simulate_installation(truth, random_installation(57), n=100, seed=58),
                                     tmp_path / "install.csv")
    args = [str(folder / "bench.json") if a == "BENCH" else str(tmp_path / a) if a.endswith(".json") else a
            for a in args]
    assert main(["calibrate", str(rec_path), "--out", str(tmp_path / "o.json"), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_export_of_the_installed_calibration_reproduces_its_field(bench, tmp_path, capsys):
    import re

    from compass.calibration import load

    _, _, truth, folder = bench
    rec_path, _ = write_installation(simulate_installation(truth, random_installation(59), n=1500, seed=60),
                                     tmp_path / "install.csv", base=folder / "bench.json")
    out = tmp_path / "installed.json"
    assert main(["calibrate", str(rec_path), "--out", str(out), "--quiet"]) == 0  # '# base:' names the bench
    capsys.readouterr()
    assert main(["export", str(out), "--format", "fusion", "--axes", "v1,v2,v3"]) == 0  # the bench simulator: v1 is x
    numbers = [float(v) for v in re.findall(r"-?\d+\.\d*(?:e-?\d+)?(?=f)", capsys.readouterr().out)]
    matrix, offset = np.array(numbers[:9]).reshape(3, 3), np.array(numbers[9:12])
    model = load(out).model
    raw = np.asarray(truth["offsets"]) + np.random.default_rng(61).normal(scale=0.5, size=(20, 3))
    np.testing.assert_allclose((raw - offset) @ matrix.T, model.field(raw)[0], rtol=2e-5, atol=2e-4)
    # a bench accelerometer off the housing (its mag_to_accel under "base"): Fusion gets the field in its frame
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_rotvec(np.radians([10.0, -15.0, 20.0]))
    doc = json.loads(out.read_text())
    doc["base"]["mag_to_accel"] = turn.as_matrix().tolist()
    turned = tmp_path / "installed_turned.json"
    turned.write_text(json.dumps(doc))
    assert main(["export", str(turned), "--format", "fusion", "--axes", "v1,v2,v3"]) == 0
    numbers = [float(v) for v in re.findall(r"-?\d+\.\d*(?:e-?\d+)?(?=f)", capsys.readouterr().out)]
    matrix, offset = np.array(numbers[:9]).reshape(3, 3), np.array(numbers[9:12])
    np.testing.assert_allclose((raw - offset) @ matrix.T, turn.apply(model.field(raw)[0]), rtol=2e-5, atol=2e-4)


def test_level_swing_with_a_site_fits_the_same_iron(bench):
    """A level swing holds its vertical iron: the site's |B| and dip are not bent into the horizontal soft iron."""
    from compass.site import Site

    _, _, truth, _ = bench
    site = Site.parse("47.6,-122.3", "2026-06-01")
    wmm = site.field()
    inst = random_installation(63)
    rec = simulate_installation(truth, inst, kind="swing", n=1500, max_tilt_deg=0.0, seed=64, dip_deg=wmm.dip_deg,
                                field_ut=wmm.field_ut)
    plain, with_site = fit(bench, rec), fit(bench, rec, site=site)
    np.testing.assert_allclose(with_site.hard_iron_ut, plain.hard_iron_ut, atol=1e-6)
    np.testing.assert_allclose(with_site.soft_iron, plain.soft_iron, atol=1e-9)
    assert with_site.site["model"] == "WMM2025" and any("vertical hard iron" in w for w in with_site.undetermined)
    # the soft iron's scale: the words say why the site given did not set it (not "give --site")
    (plain_scale,), (site_scale,) = ([w for w in r.undetermined if "overall scale" in w] for r in (plain, with_site))
    assert "give --site" in plain_scale
    assert "give --site" not in site_scale and "level swing" in site_scale and "not used" in site_scale


def test_simulate_installation_command_and_calibrate_on_top_of_the_bench(tmp_path, capsys):
    """`compass simulate installation` writes SPEC's installation recording for a bench truth; the
    installed calibration finds the product's iron and yaw within 4 sigma of the truth beside it."""
    bench_csv, bench_cal = tmp_path / "bench.csv", tmp_path / "bench.json"
    assert main(["simulate", "fourflip", "--out", str(bench_csv), "--seed", "3"]) == 0
    assert main(["calibrate", str(bench_csv), "--out", str(bench_cal), "--quiet"]) == 0
    swing = tmp_path / "swing.csv"
    assert main(["simulate", "installation", "--truth", str(tmp_path / "bench.truth.json"), "--base", str(bench_cal),
                 "--kind", "swing", "--max-tilt-deg", "10", "--heading-ref-sigma-deg", "0.3", "--yaw-deg", "3",
                 "--out", str(swing), "--seed", "4"]) == 0
    report = tmp_path / "rep"
    assert main(["calibrate", str(swing), "--out", str(tmp_path / "inst.json"), "--base", str(bench_cal),
                 "--report", str(report), "--quiet"]) == 0
    card = (report / "deviation_card.png").read_bytes()
    capsys.readouterr()
    assert main(["calibrate", str(swing), "--out", str(tmp_path / "inst2.json"), "--base", str(bench_cal),
                 "--report", str(report), "--quiet"]) == 2  # the card is never overwritten without --force
    assert "deviation_card.png" in capsys.readouterr().err and (report / "deviation_card.png").read_bytes() == card
    truth = json.loads((tmp_path / "swing.truth.json").read_text())["installation"]
    inst = json.loads((tmp_path / "inst.json").read_text())["installation"]
    found = np.array(inst["hard_iron_ut"])
    sigma = np.array([inst["sigma"][f"hard_iron_{axis}"] for axis in "xyz"])
    assert np.all(np.abs(found - truth["hard_iron_ut"]) < 4 * sigma)
    assert abs(inst["yaw_deg"] - truth["yaw_deg"]) < 4 * inst["yaw_sigma_deg"]
    # bad options: exit 2, one line, nothing written
    capsys.readouterr()
    assert main(["simulate", "installation", "--out", str(tmp_path / "bad.csv"), "--soft-iron", "0.9"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1 and not (tmp_path / "bad.csv").exists()


def test_the_bench_accelerometer_alignment_is_applied_before_the_fit(bench, tmp_path):
    """A bench whose accelerometer sat 1-2 deg off the housing (its mag_to_accel) and a product recording
    read through that accelerometer: the installation must be the same as with an aligned one (the fit's
    up is the housing's, as at runtime); ignoring mag_to_accel moves the soft iron by the tilt error."""
    from scipy.spatial.transform import Rotation

    model, doc, truth, folder = bench
    inst = random_installation(42)
    rec = simulate_installation(truth, inst, kind="tumble", n=2000, seed=44)
    aligned = fit(bench, rec)
    turn = Rotation.from_rotvec(np.radians([1.0, -1.5, 2.0]))  # R_accel<-H
    misaligned_doc = doc | {"mag_to_accel": turn.as_matrix().tolist()}
    (tmp_path / "bench.json").write_text(json.dumps(misaligned_doc))
    path, _ = write_installation(replace(rec, accel=turn.apply(rec.accel)), tmp_path / "inst.csv")
    parsed = installation_from_table(read_table(path), model.channels)
    result = InstallationCalibrator(base=tmp_path / "bench.json").fit(parsed)
    np.testing.assert_allclose(result.hard_iron_ut, aligned.hard_iron_ut, atol=0.1 * aligned.hard_iron_sigma_ut.min())
    np.testing.assert_allclose(result.soft_iron, aligned.soft_iron, atol=0.1 * aligned.soft_iron_sigma.min())
