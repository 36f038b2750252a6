"""Residual diagnosis of tumble fits against simulated truth: clean, drift, temperature, a step it does not model."""

import json

import numpy as np
import pytest

from calibrate.tumble import calibrate_tumble
from calibrate.tumble.diagnosis import diagnose_tumble
from compass.sim.tumble import simulate_tumble
from compass.calibration import load as load_calibration

N = 3000


def run(**options):
    sim = simulate_tumble(n=N, **options)
    return sim, calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s, temp_c=sim.temp_c)


def added(res):
    return [s["added"] for s in res.diagnosis.block["steps"] if "added" in s]


def at_floor(block):
    return abs(block["residual_rms_after"] / block["noise_floor"] - 1.0) < 0.10


def assert_hard_iron(res, truth):
    sigma = res.fit.hard_iron_sigma
    # the tolerance is meaningful only if the noise sets a small sigma (noise 0.3 uT per sample)
    assert np.all(sigma < 0.5 * 0.3)
    assert np.all(np.abs(res.hard_iron - truth) < 4.0 * sigma)


def test_clean_tumble_adds_nothing():
    sim, res = run(seed=21)
    d = res.diagnosis.block
    assert d["effects"] == [] and added(res) == [] and d["unexplained"] is False
    assert abs(d["noise_floor"] / sim.truth["noise_ut"] - 1.0) < 0.1
    # SPEC section 4: the base step, then only added effects; the frames' alignment is beside them
    assert [s.get("model") for s in d["steps"]] == ["base"]
    assert d["alignment"]["applied"] and d["alignment"]["angle_rms_deg_after"] < d["alignment"]["angle_rms_deg_before"]
    assert res.to_json()["effects"] == []
    assert "temperature" in d["not_applicable"]


def test_warm_up_drift_is_found_and_the_hard_iron_is_the_one_at_the_start(tmp_path):
    sim, res = run(seed=22, drift_ut=3.0, drift_tau_s=12.0)
    d = res.diagnosis.block
    assert d["effects"] == ["offset_drift"] and d["unexplained"] is False
    assert d["residual_rms_before"] > 1.2 * d["noise_floor"] and at_floor(d)
    step = d["steps"][1]
    assert step["added"] == "offset_drift" and step["delta_bic"] > 10
    assert_hard_iron(res, np.array(sim.truth["hard_iron"]))
    # the settled change: the simulator's two-stage warm-up is not the estimator's exponential,
    # so within 4 sigma plus 5 % of the change
    change = np.array([step["parameters"][f"{ax}.hard_iron_settled_change"]["value"] for ax in ("mx", "my", "mz")])
    sig = np.array([step["parameters"][f"{ax}.hard_iron_settled_change"]["sigma"] for ax in ("mx", "my", "mz")])
    truth = np.array(sim.truth["drift"]["change_ut"])
    assert np.all(np.abs(change - truth) < 4 * sig + 0.05 * np.linalg.norm(truth))
    # the file carries the effect and still loads; the runtime uses the hard iron at t_ref
    doc = json.loads(json.dumps(res.to_json()))
    assert doc["effects"][0]["name"] == "offset_drift" and doc["effects"][0]["reference"] == {"t_s": 0.0}
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))
    model = load_calibration(path).model
    assert np.allclose([r.offset for r in model.responses], res.hard_iron)


def test_temperature_is_found_with_the_hard_iron_at_the_reference_temperature():
    sim, res = run(seed=23, temp_swing_c=10.0, temp_offset_ut_per_c=0.2, temp_gain_per_c=0.002)
    d = res.diagnosis.block
    assert d["effects"] == ["temperature"] and d["unexplained"] is False and at_floor(d)
    assert d["residual_rms_before"] > 1.5 * d["noise_floor"]
    effect = res.to_json()["effects"][0]
    truth = sim.truth["temperature"]
    t_ref = effect["reference"]["temp_c"]
    assert t_ref == pytest.approx(np.mean(sim.temp_c))
    h_true = np.array(sim.truth["hard_iron"]) + np.array(truth["hard_iron_ut_per_degc"]) * (t_ref - truth["temp_ref_c"])
    assert_hard_iron(res, h_true)
    for ax, k_true in zip(("mx", "my", "mz"), truth["hard_iron_ut_per_degc"]):
        p = effect["parameters"][f"{ax}.hard_iron_per_degc"]
        assert abs(p["value"] - k_true) < 4 * p["sigma"]


def test_hard_iron_step_is_unexplained_and_nothing_is_claimed():
    sim, res = run(seed=24, step_ut=2.0)
    d = res.diagnosis.block
    assert d["unexplained"] is True and d["effects"] == [] and added(res) == []
    assert d["not_claimed"] and "offset_drift" in d["not_claimed"][0]
    assert d["residual_rms_after"] > 1.5 * d["noise_floor"]
    assert any("no modelled effect" in w for w in res.warnings)
    assert res.to_json()["effects"] == []


def test_report_prints_steps_and_before_after():
    _, res = run(seed=22, drift_ut=3.0, drift_tau_s=12.0)
    text = res.report()
    assert "base model (full ellipsoid)" in text and "+ offset_drift (warm-up)" in text
    assert "tau_s = " in text and "residual rms" in text and "->" in text and "mag-to-accel rotation" in text


def test_bad_time_column_is_rejected():
    sim = simulate_tumble(seed=25, n=600)
    res = calibrate_tumble(sim.mag)
    with pytest.raises(ValueError, match="t_s must have one value per magnetometer sample"):
        diagnose_tumble(sim.mag, res.fit, t_s=sim.t_s[:-1])
    with pytest.raises(ValueError, match="unknown tumble effect"):
        diagnose_tumble(sim.mag, res.fit, candidates=["encoder_error"])


def test_cli_passes_time_and_temperature(tmp_path, capsys):
    """`compass calibrate` on a tumble CSV with t_s and temp_c runs the drift and temperature checks."""
    from compass.cli import main
    from compass.sim.tumble import write_tumble

    sim = simulate_tumble(n=N, seed=23, temp_swing_c=10.0, temp_offset_ut_per_c=0.3)
    rec, _ = write_tumble(sim, tmp_path / "tumble.csv")
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(rec), "--out", str(cal)]) == 0
    data = json.loads(cal.read_text())
    assert "temperature" in data["diagnosis"]["effects"]
    assert "temperature" in capsys.readouterr().out
