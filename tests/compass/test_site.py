"""The site's field at runtime: WMM values, the reference a recording is solved against, true north."""

import json

import numpy as np
import pytest

from calibrate import calibrate_fourflip
from compass.attitude import solve_attitude
from compass.cli import main
from compass.io.fourflip import read_fourflip
from compass.io.table import read_table
from compass.sim.fourflip import simulate_fourflip, write_fourflip
from compass.sim.installation import true_model
from compass.sim.runtime import simulate_runtime, write_runtime
from compass.site import Site, known_reference, reference_from_recording, wmm_field
from compass.calibration import model_from_dict
from compass.calibration import model_to_dict

# NOAA's WMM2025 test values (WMM2025_TEST_VALUES.txt): decimal year, height km, lat, lon, declination deg
WMM2025_DECLINATION = [
    (2025.0, 0, 80, 0, 1.28), (2025.0, 0, 0, 120, -0.16), (2025.0, 0, -80, 240, 68.78),
    (2025.0, 100, 80, 0, 0.85), (2025.0, 100, 0, 120, -0.15), (2025.0, 100, -80, 240, 68.21),
    (2027.5, 0, 80, 0, 2.59), (2027.5, 0, 0, 120, -0.24), (2027.5, 0, -80, 240, 68.49),
    (2027.5, 100, 80, 0, 2.16), (2027.5, 100, 0, 120, -0.23), (2027.5, 100, -80, 240, 67.93),
]


def wrap(d):
    return np.mod(d + 180.0, 360.0) - 180.0


def rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


@pytest.mark.parametrize("year, height_km, lat, lon, declination", WMM2025_DECLINATION)
def test_declination_equals_wmm_official_test_values(year, height_km, lat, lon, declination):
    f = wmm_field(lat, lon if lon <= 180 else lon - 360, year, height_km)
    assert f.declination_deg == pytest.approx(declination, abs=0.006)  # the table's rounding
    assert f.model == "WMM2025" and 0.25 < f.declination_sigma_deg < 1.0 and f.dip_sigma_deg == pytest.approx(0.20)


@pytest.mark.parametrize("text, message", [("31.8", "LAT,LON"), ("a,b", "LAT,LON"), ("95,10", "latitude"),
                                           ("1,2,3,4", "LAT,LON")])
def test_bad_site_text(text, message):
    with pytest.raises(ValueError, match=message):
        Site.parse(text, "2026-01-01")
    with pytest.raises(ValueError, match="YYYY-MM-DD"):
        Site.parse("31.8,117.3", "1/2/2026")


@pytest.fixture(scope="module")
def benches(tmp_path_factory):
    """A clean bench and one with a field fixed to the turntable (biases the calibration's dip)."""
    folder = tmp_path_factory.mktemp("bench")
    out = {}
    for name, effects in (("clean", ()), ("platform", ("platform_field",))):
        session = simulate_fourflip(seed=21, effects=effects, dip_deg=62.0)
        path, _ = write_fourflip(session, folder / f"{name}.csv")
        cal = calibrate_fourflip(read_fourflip(path), diagnose=True)
        out[name] = (model_from_dict(cal.to_json()), session.truth)
    return out


def elsewhere(truth):
    """The same sensor at another site: dip 12 deg lower, |B| 10 % lower."""
    return {**truth, "dip_deg": truth["dip_deg"] - 12.0, "field_ut": 0.9 * truth["field_ut"]}


def test_another_site_with_nothing_said(benches):
    model, truth = benches["clean"]
    site = elsewhere(truth)
    run = simulate_runtime(site, 4000, seed=22)
    att = solve_attitude(model, run.outputs, accel=run.accel)
    best = solve_attitude(true_model(truth), run.outputs, accel=run.accel,
                          reference=known_reference(site["dip_deg"], site["field_ut"]))
    assert att.reference.source == "recording"
    assert abs(att.reference.dip_deg - site["dip_deg"]) < 0.1
    assert rms(wrap(att.heading_deg - run.heading_deg)) <= 1.3 * rms(wrap(best.heading_deg - run.heading_deg)) + 0.02
    assert att.disturbed.mean() <= 0.01
    # the bench's field taken for the world's (what the runtime did before): every row disturbed; their field
    # then votes for heading only, so the tilt is gravity's (a fixed field weight pulled it by degrees)
    bench = solve_attitude(model, run.outputs, accel=run.accel, reference=known_reference(model.dip_deg, model.field_ut))
    assert bench.disturbed.mean() > 0.9 and rms(bench.pitch_deg - run.pitch_deg) < 1.3 * rms(att.pitch_deg - run.pitch_deg)


def test_platform_field_biases_the_bench_dip_but_not_the_runtime(benches):
    model, truth = benches["platform"]
    assert abs(model.dip_deg - truth["dip_deg"]) > 0.1  # the bench cannot see the field's vertical part
    run = simulate_runtime(truth, 4000, seed=23)  # at the bench's own site
    att = solve_attitude(model, run.outputs, accel=run.accel)
    at_truth = solve_attitude(model, run.outputs, accel=run.accel,
                              reference=known_reference(truth["dip_deg"], truth["field_ut"]))
    for a, b in ((att.heading_deg, at_truth.heading_deg), (att.pitch_deg, at_truth.pitch_deg)):
        assert rms(wrap(a - run.heading_deg if a is att.heading_deg else a - run.pitch_deg)) == pytest.approx(
            rms(wrap(b - run.heading_deg if b is at_truth.heading_deg else b - run.pitch_deg)), rel=0.05)
    assert att.disturbed.mean() <= 0.01


def test_reference_dip_uncertainty_in_the_weights_and_the_sigmas(benches):
    """Monte Carlo over reference dips drawn with their sigma: the propagated sigmas stay honest, and an
    uncertain dip weighs the field less, so it pulls the tilt less."""
    _, truth = benches["clean"]
    model, s, noise_g = true_model(truth), 0.5, 0.01  # noisy accelerometer: the field's vote matters
    rng = np.random.default_rng(27)
    z = {"heading": [], "pitch": [], "roll": []}
    for k in range(150):
        run = simulate_runtime(truth, 20, seed=100 + k, max_tilt_deg=60.0, accel_noise_g=noise_g)
        reference = known_reference(truth["dip_deg"] + rng.normal(scale=s), truth["field_ut"], dip_sigma_deg=s)
        att = solve_attitude(model, run.outputs, accel=run.accel, accel_noise_g=noise_g, reference=reference)
        for name in z:
            z[name].append(wrap(getattr(att, f"{name}_deg") - getattr(run, f"{name}_deg")) / getattr(att, f"{name}_sigma_deg"))
    for name, values in z.items():
        assert rms(np.concatenate(values)) == pytest.approx(1.0, abs=0.12), name
    run = simulate_runtime(truth, 200, seed=28, accel_noise_g=noise_g)
    pulls = []
    for sigma in (0.0, s):
        tilt = [solve_attitude(model, run.outputs, accel=run.accel, accel_noise_g=noise_g, reference=known_reference(
            truth["dip_deg"] + d, truth["field_ut"], dip_sigma_deg=sigma)).pitch_deg for d in (0.0, 1.0)]
        pulls.append(rms(tilt[1] - tilt[0]))
    assert pulls[1] < 0.8 * pulls[0]


def test_too_few_quiet_rows_refuses():
    rng = np.random.default_rng(0)
    field, up = rng.normal(size=(20, 3)), np.tile([0.0, 0.0, 1.0], (20, 1))
    with pytest.raises(ValueError, match="--site"):
        reference_from_recording(field, up, accel_norm=np.linspace(0.5, 1.5, 20))


@pytest.mark.parametrize("lat, lon", [(47.6, -122.3), (-33.87, 151.21)], ids=["seattle", "sydney"])
def test_cli_site_gives_true_north_and_the_calibration_site_block(benches, tmp_path, lat, lon):
    """Declination about +15 deg (Seattle) and +13 deg (Sydney, a southern latitude written as
    ``--site -33.87,151.21``, which argparse alone refuses as an option)."""
    model, truth = benches["clean"]
    date = "2026-06-01"
    wmm = Site.parse(f"{lat},{lon}", date).field()
    site = {**truth, "dip_deg": wmm.dip_deg, "field_ut": wmm.field_ut}
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(model_to_dict(model)))
    rec, truth_file = write_runtime(simulate_runtime(site, 1500, seed=25), tmp_path / "rec.csv")
    out = tmp_path / "att.csv"
    assert main(["attitude", str(cal), str(rec), "--out", str(out), "--site", f"{lat},{lon}", "--date", date]) == 0
    table, true = read_table(out), json.loads(truth_file.read_text())
    assert table.metadata["reference_field"].startswith("site ")
    heading, heading_true = table.column("heading_deg"), table.column("heading_true_deg")
    np.testing.assert_allclose(wrap(heading_true - heading), wmm.declination_deg, atol=2e-4)
    sigma = table.column("heading_true_sigma_deg")
    assert np.all(sigma >= wmm.declination_sigma_deg - 1e-4)
    assert rms(wrap(heading - np.array(true["heading_deg"]))) < 1.0 and table.column("disturbed").mean() <= 0.01
    # the same site written into the calibration file: used when nothing is said
    with_site = tmp_path / "cal_site.json"
    with_site.write_text(json.dumps(model_to_dict(model) | {"site": Site.parse(f"{lat},{lon}", date).to_json()}))
    assert main(["attitude", str(with_site), str(rec), "--out", str(tmp_path / "b.csv")]) == 0
    other = read_table(tmp_path / "b.csv")
    assert other.metadata["reference_field"].startswith("calibration site")
    np.testing.assert_allclose(other.column("heading_true_deg"), heading_true, atol=1e-3)
    # nothing said: magnetic only, the reference from the recording
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "c.csv")]) == 0
    plain = read_table(tmp_path / "c.csv")
    assert "heading_true_deg" not in plain.columns and plain.metadata["reference_field"].startswith("recording")


@pytest.mark.parametrize("args, message", [(["--site", "95,0"], "latitude"), (["--date", "2026-01-01"], "--site"),
                                           (["--site", "1,2", "--date", "x"], "YYYY-MM-DD")])
def test_cli_bad_site_exit_2(benches, tmp_path, capsys, args, message):
    model, truth = benches["clean"]
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(model_to_dict(model)))
    rec, _ = write_runtime(simulate_runtime(truth, 50, seed=26), tmp_path / "rec.csv")
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "o.csv"), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_simulated_installation_frames():
    """A clean product (no iron) gives back the product's attitude; a yaw of the housing in the product
    (counterclockwise seen from above) lowers the housing's heading by yaw when level."""
    from compass.frames import heading_pitch_roll, r_world_from_housing
    from compass.sim.installation import Installation, simulate_installation

    truth = simulate_fourflip(seed=29).truth
    model = true_model(truth)
    for yaw in (0.0, 7.0):
        rec = simulate_installation(truth, Installation(np.zeros(3), np.eye(3), yaw), kind="runtime", n=2000,
                                    max_tilt_deg=30.0, seed=30)
        att = solve_attitude(model, rec.outputs, accel=rec.accel)
        housing = r_world_from_housing(rec.heading_deg, rec.pitch_deg, rec.roll_deg) * Installation(
            np.zeros(3), np.eye(3), yaw).alignment
        assert rms(wrap(att.heading_deg - heading_pitch_roll(housing)[0])) < 1.2 * rms(att.heading_sigma_deg)
    level = heading_pitch_roll(r_world_from_housing(100.0, 0.0, 0.0) * Installation(np.zeros(3), np.eye(3), 7.0).alignment)
    assert level[0][0] == pytest.approx(93.0)


@pytest.mark.parametrize("calibrated, measured, stopped", [(60.0, -60.2, True), (64.0, -68.0, True),
                                                           (12.0, -2.0, False), (65.0, -45.0, False),
                                                           (60.0, 58.0, False)])
def test_the_calibrations_own_dip_judges_only_a_mirrored_field(calibrated, measured, stopped):
    """Against the dip a calibration measured (no site), only a dip within 10 deg of the mirrored one is a field
    turned over (an accelerometer reading gravity mirrors it where the module was calibrated); one merely of the
    other sign, a module near or across the magnetic equator whose headings are right, is not."""
    from compass.site import ReferenceField, upside_down

    reference = ReferenceField(calibrated, 0.0, 50.0, 0.0, "calibration", "the calibration's dip")
    words = upside_down(np.full(100, measured), reference, bench_sign_ambiguous=False)
    assert (words is not None) == stopped
    assert words is None or "--accel-sign -1" in words
