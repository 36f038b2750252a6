"""gain_drift and the unexplained widening of the installation's diagnosis."""


import numpy as np
import pytest

from calibrate.installation import InstallationCalibrator
from compass.calibration import from_dict, model_to_dict
from compass.io.installation import InstallationRecording
from compass.sim.fourflip import simulate_fourflip
from compass.sim.installation import random_installation, simulate_installation, true_model


@pytest.fixture(scope="module")
def sensor():
    """The true bench model of a simulated sensor (no bench error) and its truth."""
    truth = simulate_fourflip(seed=7).truth
    doc = model_to_dict(true_model(truth)) | {"format": "compass-calibration/1", "model": "channels"}
    return from_dict(doc), truth


def _fit(sensor, sim, outputs):
    bench, _ = sensor
    rec = InstallationRecording("sim", sim.kind, sim.channels, outputs, sim.accel, sim.t_s, None, None, False,
                                np.arange(len(sim.t_s)), {})
    return InstallationCalibrator(base=bench).fit(rec)


def _gain_drift(truth, sim, per_channel):
    """Each channel's gain changing linearly in time, zero at the mean time (the fit's reference)."""
    off = np.asarray(truth["offsets"])
    tau = (sim.t_s - sim.t_s.mean()) / np.ptp(sim.t_s)
    return off + (sim.outputs - off) * (1.0 + np.outer(tau, per_channel))


def test_a_gain_drift_is_named_with_its_rate_and_explains_the_residual(sensor):
    _, truth = sensor
    sim = simulate_installation(truth, random_installation(11), kind="tumble", n=2000, seed=12)
    per_channel = np.array([0.02, -0.015, 0.01])
    result = _fit(sensor, sim, _gain_drift(truth, sim, per_channel))
    block = result.diagnosis.block
    assert block["effects"] == ["gain_drift"] and block["unexplained"] is False
    # the |B| residual down to the bench's noise, from well above it
    assert block["residual_rms_after"] < 1.1 * block["noise_floor"] < 0.8 * block["residual_rms_before"]
    (effect,) = result.to_json()["effects"]
    rate, sigma = (np.array([effect["parameters"][f"{axis}.gain_rate_rel_per_s"][k] for axis in "xyz"])
                   for k in ("value", "sigma"))
    # the channels are within a few degrees of the axes of H: each axis's rate is its channel's, to 5 %
    true_rate = per_channel / np.ptp(sim.t_s)
    assert np.all(np.abs(rate - true_rate) < 4 * sigma + 0.05 * np.abs(true_rate))
    assert all(n in effect["form"] for n in {p.split(".")[-1] for p in effect["parameters"]} | set(effect["reference"]))


def test_a_clean_recording_names_nothing(sensor):
    _, truth = sensor
    for seed in (21, 22, 23):
        sim = simulate_installation(truth, random_installation(seed), kind="swing", max_tilt_deg=10.0, n=2000,
                                    seed=seed)
        block = _fit(sensor, sim, sim.outputs).diagnosis.block
        assert block["effects"] == [] and block["unexplained"] is False and "unexplained_cost" not in block


def test_a_level_swing_says_why_gain_drift_is_not_tried(sensor):
    _, truth = sensor
    sim = simulate_installation(truth, random_installation(31), kind="swing", max_tilt_deg=0.0, n=2000, seed=32)
    block = _fit(sensor, sim, _gain_drift(truth, sim, np.array([0.0, 0.0, 0.02]))).diagnosis.block
    assert "level swing" in block["not_applicable"]["gain_drift"]
    # the vertical gain change of a level swing is a vertical offset drift: that is what is named
    assert "gain_drift" not in block["effects"]


def test_an_unexplained_residual_widens_the_hard_iron_sigma(sensor):
    _, truth = sensor
    inst = random_installation(41)
    sim = simulate_installation(truth, inst, kind="tumble", n=2000, seed=42)
    rng = np.random.default_rng(43)
    walk = np.cumsum(rng.normal(size=(len(sim.t_s), 3)), axis=0)
    walk = 0.5 * (walk - walk.mean(axis=0)) / walk.std()  # an offset wandering by 0.5 uT: not in the vocabulary
    outputs = sim.outputs + np.asarray(truth["gains_per_ut"]) * walk
    result = _fit(sensor, sim, outputs)
    block = result.diagnosis.block
    assert block["unexplained"] is True
    cost = block["unexplained_cost"]["hard_iron"]
    naive = np.array([cost[a]["naive"] for a in "xyz"])
    wide = np.array([cost[a]["widened"] for a in "xyz"])
    noise = np.array([cost[a]["noise_only"] for a in "xyz"])
    # the naive's chi-square scale took the walk's residual for white noise; the walk model scales the noise's
    # part by what the walk leaves and adds the walk's own: above the noise's alone, not twice the walk
    assert np.all(noise < naive) and np.all(wide > noise)
    # a random orientation every row: the walk averages out of the hard iron (calibrate.diagnosis.blocks),
    # so the widened sigma covers the error without growing to the walk's per-block size (CR2's 16x)
    assert np.all(np.abs(result.hard_iron_ut - inst.hard_iron_ut) < 4.0 * wide)
    assert np.all(wide < 3.0 * naive)
    assert np.allclose(result.hard_iron_sigma_ut, wide)
    report = result.report()
    assert "hard-iron sigmas stated" in report and "heading sigma of a level housing" in report
    # here under the naive on every axis (the walk averages out of the fit), and the report says why
    assert np.all(wide < naive) and "under the naive where its chi-square scale counted the walk" in report
    heading = block["unexplained_cost"]["heading_sigma_deg"]
    assert 0 < heading["widened"] < heading["naive"] and "(under the naive, as the hard iron's)" in report
