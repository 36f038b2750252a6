"""A tilted swing: with no noise the fit returns the product's iron; with noise its sigma is honest.

A swing within a few degrees of level fits the vertical hard iron along a weak direction, where the
noise's second-order (errors-in-variables) bias of least squares is several sigma and does not fall
with more rows (calibrate/installation/model.py's docstring, docs/benchmarks.md "Why the clean
swing's sigma under-covers"); :func:`calibrate.installation.model.debiased` takes it out.
"""

import numpy as np

from calibrate.installation import InstallationCalibrator
from compass.calibration import from_dict, model_to_dict
from compass.io.installation import InstallationRecording
from compass.sim.fourflip import simulate_fourflip
from compass.sim.installation import random_installation, simulate_installation, true_model


def _swing(seed: int, tilt_deg: float, noise: float, n: int):
    """A clean swing of a simulated product, fitted on the true bench model stating ``noise`` times its noise."""
    truth = simulate_fourflip(seed=seed).truth
    stated = truth | {"noise": (max(noise, 1e-4) * np.asarray(truth["noise"])).tolist()}
    bench = from_dict(model_to_dict(true_model(stated)) | {"format": "compass-calibration/1", "model": "channels"})
    inst = random_installation(500 + seed)
    accel_g = 0.002 * noise
    sim = simulate_installation(truth | {"noise_ut": truth["noise_ut"] * noise}, inst, kind="swing", n=n,
                                max_tilt_deg=tilt_deg, seed=700 + seed, accel_noise_g=accel_g)
    rec = InstallationRecording("sim", sim.kind, sim.channels, sim.outputs, sim.accel, sim.t_s, None, None, False,
                                np.arange(len(sim.t_s)), {})
    return InstallationCalibrator(base=bench, accel_noise_g=max(accel_g, 1e-6)).fit(rec), inst, truth


def test_noise_free_tilted_swing_returns_the_installation_exactly():
    for seed, tilt in ((0, 10.0), (3, 5.0)):
        result, inst, truth = _swing(seed, tilt, 0.0, 1000)
        # the bench's noise would give the vertical hard iron a sigma of 0.05-0.2 uT; the priors on h and D
        # pull it by under 0.01 uT where the tilt is small
        assert np.all(np.abs(result.hard_iron_ut - inst.hard_iron_ut) < 0.02), seed
        scale = np.trace(inst.soft_iron) / 3.0  # trace(S) = 3 without a site: the scale goes into |B|
        assert np.allclose(result.soft_iron, inst.soft_iron / scale, atol=3e-4)  # their sigmas: 2e-4 to 3e-3
        assert abs(result.dip_deg - truth["dip_deg"]) < 1e-3
        assert abs(result.field_magnitude - truth["field_ut"] * scale) < 0.01


def test_small_swing_hard_iron_error_over_sigma_is_honest():
    # +-5 deg, 2000 rows: before the correction the vertical hard iron was 0.4 uT high for a sigma of ~0.13
    # (err/sig 3.3 on seeds 0-11); 16 seeds give the RMS over 48 components to about +-10 %
    ratios = []
    for seed in range(16):
        result, inst, _ = _swing(seed, 5.0, 1.0, 2000)
        ratios.append((result.hard_iron_ut - inst.hard_iron_ut) / result.hard_iron_sigma_ut)
    ratios = np.array(ratios)
    # after the correction these seeds read 0.77 (0.79 at +-10 deg), low as the benchmark's 0.76 is (the lowest
    # 20-seed group of seeds 0-199, which read 0.91 together, unexplained); the sigma at a fixed design is honest
    # (the next test; docs/benchmarks.md, "The clean swing's 0.76"), so the lower edge is 0.7
    assert 0.7 <= np.sqrt(np.mean(ratios**2)) <= 1.25
    assert abs(ratios[:, 2].mean()) < 3.0 / np.sqrt(len(ratios))  # no bias along the vertical, to 3 s.e.


def test_clean_swing_sigma_is_the_spread_of_its_error_over_redrawn_noise():
    # one design (seed 0's sensor, product and path, +-10 deg, 1000 rows), its noise drawn afresh each time: the
    # stated sigma of each hard-iron component against the error's spread over the draws.  The benchmark's 0.76
    # on seeds 0-19 is the lowest 20-seed group of a population at 0.91 (docs/benchmarks.md, "The clean swing's
    # 0.76"); here the sigma itself is judged.  48 draws x 3 components: the pooled RMS of err/sig to about +-7 %.
    truth = simulate_fourflip(seed=0).truth
    bench = from_dict(model_to_dict(true_model(truth)) | {"format": "compass-calibration/1", "model": "channels"})
    inst = random_installation(500)
    sim = simulate_installation(truth | {"noise_ut": 0.0}, inst, kind="swing", n=1000, max_tilt_deg=10.0, seed=700,
                                accel_noise_g=0.0)
    gains = np.asarray(truth["gains_per_ut"])
    rng = np.random.default_rng(11)
    ratios = []
    for _ in range(48):
        out = sim.outputs + gains * truth["noise_ut"] * rng.normal(size=sim.outputs.shape)
        accel = sim.accel + 0.002 * rng.normal(size=sim.accel.shape)
        rec = InstallationRecording("sim", sim.kind, sim.channels, out, accel, sim.t_s, None, None, False,
                                    np.arange(len(sim.t_s)), {})
        result = InstallationCalibrator(base=bench, accel_noise_g=0.002).fit(rec)
        assert not result.diagnosis.block["unexplained"]  # the naive sigma is what is judged
        ratios.append((result.hard_iron_ut - inst.hard_iron_ut) / result.hard_iron_sigma_ut)
    ratios = np.array(ratios)
    assert 0.8 <= np.sqrt(np.mean(ratios**2)) <= 1.2
    assert np.all(np.sqrt(np.mean(ratios**2, axis=0)) >= 0.7)  # no one component over-stated by a third
    assert np.all(np.sqrt(np.mean(ratios**2, axis=0)) <= 1.4)
