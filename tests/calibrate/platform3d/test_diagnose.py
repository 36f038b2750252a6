"""Residual diagnosis of the 3-D platform fit (seed 001, SPEC section 4): floor from pose repeats, effects named."""

import dataclasses
import json

import numpy as np
import pytest

from calibrate.diagnosis import forms
from calibrate.diagnosis.offsets import SampleGroups, same_inputs
from calibrate.platform3d import calibrate_platform3d
from compass.cli import main
from compass.io.platform3d import read_platform3d
from compass.sim.platform3d import simulate_platform3d, write_platform3d
from tests.conftest import every_row_alone

SESSION_S = 1800.0
N_SIGMA = 4.5  # as the platform's other truth tests


def fit(tmp_path, sim, name="rec.csv"):
    path, _ = write_platform3d(sim, tmp_path / name)
    return calibrate_platform3d(read_platform3d(path))


def rms_tolerance(sim) -> float:
    """Relative tolerance of a residual rms against the injected noise: 5 standard errors of an rms."""
    return 5.0 / np.sqrt(2.0 * sim.mag.size)


def test_clean_recording_adds_nothing_and_is_explained(tmp_path):
    sim = simulate_platform3d(seed=21, session_s=SESSION_S, temp_swing_c=10.0)
    block = fit(tmp_path, sim).to_json()["diagnosis"]
    assert block["effects"] == [] and len(block["steps"]) == 1
    assert block["unexplained"] is False
    assert block["not_applicable"] == {}
    assert block["noise_floor"] == pytest.approx(sim.truth["noise_mag"], rel=rms_tolerance(sim))


def test_drift_is_named_and_offsets_hold_at_the_first_sample(tmp_path):
    sim = simulate_platform3d(seed=22, session_s=SESSION_S, drift_ut=2.0, temp_swing_c=10.0)
    res = fit(tmp_path, sim)
    data = res.to_json()
    block = data["diagnosis"]
    assert block["effects"] == ["offset_drift"] and block["unexplained"] is False
    assert block["residual_rms_before"] > 2 * block["residual_rms_after"]
    assert block["residual_rms_after"] == pytest.approx(sim.truth["noise_mag"], rel=rms_tolerance(sim))
    (effect,) = data["effects"]
    assert effect["reference"] == {"t_s": 0.0}
    # the file's offsets are those at t_s = 0, where the simulator's truth holds
    err = res.mag_offset - np.array(sim.truth["mag_offset"])
    assert np.all(np.abs(err) < N_SIGMA * res.mag_response_sigma[:, 0])
    if effect["form"] == "linear":
        rate = np.array(sim.truth["drift"]["change_ut"]) / SESSION_S
        p = effect["parameters"]
        for c, axis in enumerate(("mx", "my", "mz")):
            got = p[f"{axis}.offset_rate_per_s"]
            assert abs(got["value"] - rate[c]) < N_SIGMA * got["sigma"]


def test_temperature_is_named_with_its_coefficients(tmp_path):
    sim = simulate_platform3d(seed=23, session_s=SESSION_S, temp_swing_c=10.0, temp_offset_ut_per_c=0.1)
    res = fit(tmp_path, sim)
    data = res.to_json()
    assert data["diagnosis"]["effects"] == ["temperature"] and data["diagnosis"]["unexplained"] is False
    (effect,) = data["effects"]
    temp_ref = float(np.mean(sim.temp_c))
    assert effect["reference"]["temp_c"] == pytest.approx(temp_ref)
    k = np.array(sim.truth["temperature"]["offset_ut_per_degc"])
    for c, axis in enumerate(("mx", "my", "mz")):
        got = effect["parameters"][f"{axis}.offset_per_degc"]
        assert abs(got["value"] - k[c]) < N_SIGMA * got["sigma"]
    # offsets at the mean recorded temperature
    truth = np.array(sim.truth["mag_offset"]) + k * (temp_ref - sim.truth["temperature"]["temp_ref_c"])
    assert np.all(np.abs(res.mag_offset - truth) < N_SIGMA * res.mag_response_sigma[:, 0])


def test_cubic_response_is_identifiable_on_the_platform(tmp_path):
    sim = simulate_platform3d(seed=24)
    t = sim.truth
    linear = sim.mag - np.array(t["mag_offset"])  # the noisy linear response (noise 0.1 uT of 50) scales the cubic
    bent = sim.mag + 0.5 * (linear / t["field_ut"]) ** 3  # 0.5 uT at full field: 5 times the noise
    res = fit(tmp_path, dataclasses.replace(sim, mag=bent))
    block = res.to_json()["diagnosis"]
    assert block["effects"] == ["nonlinear_response"] and block["unexplained"] is False
    assert "offset_drift" in block["not_applicable"] and "temperature" in block["not_applicable"]


def test_fitting_pose_means_is_fitting_every_sample(tmp_path, monkeypatch):
    # repeats of one pose carry their mean and count (sufficient statistics of a model constant over
    # the group): the base fit and the diagnosis on the means must land where the fits on every sample do

    sim = simulate_platform3d(seed=24, repeats=4)
    keep = np.arange(len(sim.mag)) % 7 != 0  # poses with 2, 3 and 4 samples: the weights matter
    sim = dataclasses.replace(sim, **{k: getattr(sim, k)[keep] for k in
                                      ("angles_deg", "mag", "tilt", "heading_deg", "pitch_deg", "roll_deg")})
    assert len(np.unique(sim.angles_deg, axis=0)) < 0.4 * len(sim.mag)  # the fit runs on means of 2-4 samples
    linear = sim.mag - np.array(sim.truth["mag_offset"])
    bent = dataclasses.replace(sim, mag=sim.mag + 0.5 * (linear / sim.truth["field_ut"]) ** 3)
    grouped = fit(tmp_path, bent)

    monkeypatch.setattr(SampleGroups, "of", staticmethod(every_row_alone))
    per_sample = fit(tmp_path, bent, "again.csv")
    assert grouped.diagnosis.block["effects"] == per_sample.diagnosis.block["effects"] == ["nonlinear_response"]
    assert np.all(np.abs(grouped.values - per_sample.values) < 1e-3 * per_sample.sigma)
    np.testing.assert_allclose(grouped.sigma, per_sample.sigma, rtol=1e-4)
    assert grouped.chi2 == pytest.approx(per_sample.chi2, rel=1e-7) and grouped.dof == per_sample.dof
    np.testing.assert_allclose(grouped.residuals_mag, per_sample.residuals_mag, atol=1e-6)


def test_fitting_means_over_short_times_is_fitting_every_sample(tmp_path, monkeypatch):
    # 15 samples a pose, 2160 in all, and 1000 time bins (a tenth of the fit's): two samples a bin; a
    # warm-up (curved in time) to find: the diagnosis on the bin means must land where the per-sample one does

    sim = simulate_platform3d(seed=27, repeats=15, session_s=SESSION_S, drift_ut=2.0, drift_tau_s=300.0)
    monkeypatch.setattr(forms, "TIME_BINS", 1000)
    _, pose = np.unique(sim.angles_deg, axis=0, return_inverse=True)
    assert len(same_inputs(pose.ravel(), sim.t_s, sim.temp_c).counts) < 0.6 * len(sim.t_s)  # means of ~2 samples
    grouped = fit(tmp_path, sim)
    assert grouped.diagnosis.block["effects"] == ["offset_drift"]

    monkeypatch.setattr(SampleGroups, "of", staticmethod(every_row_alone))
    per_sample = fit(tmp_path, sim, "again.csv")
    assert [s["form"] for s in grouped.diagnosis.block["steps"][1:]] == \
        [s["form"] for s in per_sample.diagnosis.block["steps"][1:]]
    assert np.all(np.abs(grouped.values - per_sample.values) < 1e-2 * per_sample.sigma)
    np.testing.assert_allclose(grouped.sigma, per_sample.sigma, rtol=1e-3)
    assert grouped.chi2 == pytest.approx(per_sample.chi2, rel=1e-6)


def test_without_time_and_temperature_those_effects_are_not_applicable(tmp_path):
    block = fit(tmp_path, simulate_platform3d(seed=25)).to_json()["diagnosis"]
    assert block["not_applicable"]["offset_drift"] == "the recording has no t_s column"
    assert block["not_applicable"]["temperature"] == "the recording has no temp_c column"
    assert block["effects"] == [] and block["unexplained"] is False


def test_without_repeats_the_verdict_is_not_judged(tmp_path):
    sim = simulate_platform3d(seed=26, repeats=1, session_s=SESSION_S)
    block = fit(tmp_path, sim).to_json()["diagnosis"]
    assert block["unexplained"] is None and block["structure_test"] is None
    assert "no repeated samples" in block["noise_floor_source"]


def test_defaults_leave_the_simulation_unchanged():
    plain, with_options = simulate_platform3d(seed=27), simulate_platform3d(seed=27, session_s=SESSION_S,
                                                                            temp_swing_c=5.0)
    np.testing.assert_array_equal(plain.mag, with_options.mag)  # no coefficient: time and temperature only recorded
    assert plain.t_s is None and plain.temp_c is None and plain.truth["drift"] is None


def test_drift_without_session_is_refused():
    with pytest.raises(ValueError, match="drift_ut needs session_s"):
        simulate_platform3d(drift_ut=1.0)


def test_cli_prints_before_and_after(tmp_path, capsys):
    sim = simulate_platform3d(seed=28, session_s=SESSION_S, drift_ut=2.0)
    path, _ = write_platform3d(sim, tmp_path / "rec.csv")
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal.json")]) == 0
    out = capsys.readouterr().out
    assert "Residual diagnosis" in out and "+ offset_drift" in out and "explained: the residual is at the noise floor" in out
    data = json.loads((tmp_path / "cal.json").read_text())
    assert data["diagnosis"]["effects"] == ["offset_drift"] and data["effects"][0]["name"] == "offset_drift"


def test_report_plots_the_residuals_and_names_the_effect(tmp_path, monkeypatch, capsys):
    """`compass calibrate P3.csv --report DIR` (issue 15.6: it was refused for the 3-D platform)."""
    import matplotlib.figure

    titles = []
    suptitle = matplotlib.figure.Figure.suptitle
    monkeypatch.setattr(matplotlib.figure.Figure, "suptitle",
                        lambda self, text, **kw: titles.append(text) or suptitle(self, text, **kw))
    sim = simulate_platform3d(seed=28, session_s=SESSION_S, drift_ut=2.0)
    path, _ = write_platform3d(sim, tmp_path / "rec.csv")
    report = tmp_path / "report"
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal.json"), "--report", str(report), "--quiet"]) == 0
    plot = report / "platform_residuals.png"
    assert plot.read_bytes().startswith(b"\x89PNG") and "effects added: offset_drift" in titles[-1]
    # never overwritten without --force, refused before the fit
    before = plot.read_bytes()
    capsys.readouterr()
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal2.json"), "--report", str(report), "--quiet"]) == 2
    assert "platform_residuals.png" in capsys.readouterr().err and plot.read_bytes() == before
    assert not (tmp_path / "cal2.json").exists()
