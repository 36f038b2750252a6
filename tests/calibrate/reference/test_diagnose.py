"""Residual diagnosis of the K-matrix fit (seed 003, SPEC section 4): floor from repeated fields, effects named."""

import json

import numpy as np
import pytest

from calibrate.reference import calibrate_reference
from compass.cli import main
from compass.io.reference import read_reference
from compass.sim.reference import simulate_reference, write_reference

SESSION_S = 1800.0
N_SIGMA = 4.5
REPEATED = dict(n_fields=24, repeats=3, noise=0.05)


def fit(tmp_path, sim, name="rec.csv"):
    path, _ = write_reference(sim, tmp_path / name)
    return calibrate_reference(read_reference(path))


def offsets_within_sigma(res, sim, temp_ref=None):
    for s in res.sensors:
        t = sim.truth["sensors"][s.name]
        truth = np.array(t["offset"])
        if temp_ref is not None:
            truth = truth + np.array(t["temp_offset_per_degc"]) * (temp_ref - sim.truth["temp_ref_c"])
        assert np.all(np.abs(s.offset - truth) < N_SIGMA * s.offset_sigma), s.name


def test_clean_recording_adds_nothing_and_is_explained(tmp_path):
    sim = simulate_reference(seed=31, session_s=SESSION_S, temp_swing_c=10.0, **REPEATED)
    block = fit(tmp_path, sim).to_json()["diagnosis"]
    assert block["effects"] == [] and len(block["steps"]) == 1
    assert block["unexplained"] is False and block["not_applicable"] == {}
    n_values = sum(v.size for v in sim.outputs.values())
    assert block["noise_floor"] == pytest.approx(sim.truth["noise"], rel=5.0 / np.sqrt(2.0 * n_values * 2 / 3))


def test_drift_is_named_and_offsets_hold_at_the_first_row(tmp_path):
    sim = simulate_reference(seed=32, session_s=SESSION_S, drift=0.5, **REPEATED)
    res = fit(tmp_path, sim)
    data = res.to_json()
    block = data["diagnosis"]
    assert block["effects"] == ["offset_drift"] and block["unexplained"] is False
    assert data["effects"][0]["reference"] == {"t_s": 0.0}
    offsets_within_sigma(res, sim)
    # the offsets of the base fit are off by about half the drift: the diagnosis moved them
    assert max(abs(v) for v in block["offset_change"]["value"]) > 0.1


def test_warm_up_drift_is_named(tmp_path):
    sim = simulate_reference(seed=33, session_s=SESSION_S, drift=0.5, drift_tau_s=300.0, **REPEATED)
    res = fit(tmp_path, sim)
    assert res.to_json()["diagnosis"]["effects"] == ["offset_drift"]
    offsets_within_sigma(res, sim)


def test_temperature_is_named_with_its_coefficients(tmp_path):
    sim = simulate_reference(seed=34, session_s=SESSION_S, temp_swing_c=10.0, temp_offset_per_c=0.03, **REPEATED)
    res = fit(tmp_path, sim)
    data = res.to_json()
    assert data["diagnosis"]["effects"] == ["temperature"] and data["diagnosis"]["unexplained"] is False
    (effect,) = data["effects"]
    temp_ref = float(np.mean(sim.temp_c))
    assert effect["reference"]["temp_c"] == pytest.approx(temp_ref)
    for s in res.sensors:
        k = sim.truth["sensors"][s.name]["temp_offset_per_degc"]
        for c, ch in enumerate(s.channels):
            got = effect["parameters"][f"{ch}.offset_per_degc"]
            assert abs(got["value"] - k[c]) < N_SIGMA * got["sigma"], ch
    offsets_within_sigma(res, sim, temp_ref)


def test_without_time_and_temperature_those_effects_are_not_applicable(tmp_path):
    block = fit(tmp_path, simulate_reference(seed=35, **REPEATED)).to_json()["diagnosis"]
    assert block["not_applicable"]["offset_drift"] == "the recording has no t_s column"
    assert block["not_applicable"]["temperature"] == "the recording has no temp_c column"
    assert block["effects"] == [] and block["unexplained"] is False


def test_without_repeated_fields_the_verdict_is_not_judged(tmp_path):
    # the floor is then the base residual: conservative, and 'unexplained' cannot be judged
    sim = simulate_reference(seed=36, n_fields=24, session_s=SESSION_S, drift=1.0)
    res = fit(tmp_path, sim)
    block = res.to_json()["diagnosis"]
    assert block["unexplained"] is None and block["structure_test"] is None
    assert "no repeated samples" in block["noise_floor_source"]
    assert block["effects"] == ["offset_drift"]
    offsets_within_sigma(res, sim)


def test_defaults_leave_the_simulation_unchanged():
    plain = simulate_reference(seed=37)
    timed = simulate_reference(seed=37, session_s=SESSION_S, temp_swing_c=5.0)
    for name in plain.outputs:
        np.testing.assert_array_equal(plain.outputs[name], timed.outputs[name])
    assert plain.t_s is None and plain.temp_c is None


def test_bad_simulator_options_are_refused():
    with pytest.raises(ValueError, match="drift needs session_s"):
        simulate_reference(drift=1.0)
    with pytest.raises(ValueError, match="repeats must be at least 1"):
        simulate_reference(repeats=0)


def test_cli_prints_before_and_after(tmp_path, capsys):
    sim = simulate_reference(seed=38, session_s=SESSION_S, temp_swing_c=10.0, temp_offset_per_c=0.03, **REPEATED)
    path, _ = write_reference(sim, tmp_path / "rec.csv")
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal.json")]) == 0
    out = capsys.readouterr().out
    assert "Residual diagnosis" in out and "+ temperature" in out and "residual rms" in out
    assert json.loads((tmp_path / "cal.json").read_text())["diagnosis"]["effects"] == ["temperature"]


def test_cli_no_diagnose_keeps_the_base_fit(tmp_path, capsys):
    sim = simulate_reference(seed=38, session_s=SESSION_S, temp_swing_c=10.0, temp_offset_per_c=0.03, **REPEATED)
    path, _ = write_reference(sim, tmp_path / "rec.csv")
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal.json"), "--no-diagnose"]) == 0
    assert json.loads((tmp_path / "cal.json").read_text())["diagnosis"]["effects"] == []


def test_fitting_field_means_is_fitting_every_sample(tmp_path, monkeypatch):
    # repeats of one applied field carry their mean and count: the diagnosis block from the fits on the
    # means must be the one from the fits on every sample
    from calibrate.diagnosis.offsets import SampleGroups
    from tests.conftest import every_row_alone

    sim = simulate_reference(seed=36, n_fields=24, repeats=4, noise=0.05)
    grouped = fit(tmp_path, sim).to_json()["diagnosis"]

    monkeypatch.setattr(SampleGroups, "of", staticmethod(every_row_alone))
    per_sample = fit(tmp_path, sim, "again.csv").to_json()["diagnosis"]
    for key in ("residual_rms_before", "residual_rms_after", "noise_floor"):
        assert grouped[key] == pytest.approx(per_sample[key], rel=1e-9), key
    assert grouped["structure_test"]["p_value"] == pytest.approx(per_sample["structure_test"]["p_value"], rel=1e-6)
    np.testing.assert_allclose(grouped["offset_change"]["sigma"], per_sample["offset_change"]["sigma"], rtol=1e-6)
    np.testing.assert_allclose(grouped["offset_change"]["value"], per_sample["offset_change"]["value"],
                               atol=1e-3 * min(per_sample["offset_change"]["sigma"]))


def test_gain_drift_is_named(tmp_path):
    """Every sensor's gain grows 2 % over the session (a room warming, no temp_c): gain_drift, not offset_drift."""
    from dataclasses import replace

    sim = simulate_reference(seed=34, session_s=SESSION_S, **REPEATED)
    tau = (sim.t_s - sim.t_s[0]) / np.ptp(sim.t_s)
    outputs = {}
    for name, out in sim.outputs.items():
        offset = np.array(sim.truth["sensors"][name]["offset"])
        outputs[name] = offset + (out - offset) * (1.0 + 0.02 * tau[:, None])
    res = fit(tmp_path, replace(sim, outputs=outputs))
    block = res.to_json()["diagnosis"]
    assert block["effects"] == ["gain_drift"] and block["unexplained"] is False
    rates = [p["value"] for k, p in block["steps"][1]["parameters"].items() if k.endswith("gain_rel_per_s")]
    assert rates == pytest.approx([0.02 / np.ptp(sim.t_s)] * len(rates), rel=0.2)
