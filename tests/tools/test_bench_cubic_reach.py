"""tools/bench_cubic_reach.py's physics: a 1 % cubic's noncentrality against a linear fit follows 1000 cos^6(dip) where
its third harmonic is all that shows, and a linear fit that misses it states the best linear gain, not the slope at
zero (docs/benchmarks.md, "An odd cubic the loop did not name")."""

import importlib.util
import sys

import numpy as np
import pytest

from tests._paths import ROOT


@pytest.fixture(scope="module")
def reach():
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        spec = importlib.util.spec_from_file_location("bench_cubic_reach", ROOT / "tools" / "bench_cubic_reach.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(str(ROOT / "tools"))


def test_the_noiseless_recording_is_the_noisy_one_without_its_noise(reach):
    noisy, truth = reach.bl.session(75, "odd cubic")
    clean, _ = reach.bl.session(75, "odd cubic", noise_ut=0.0)
    spread = np.std(noisy.outputs - clean.outputs, axis=0) / truth.gains
    assert np.allclose(spread, reach.bl.NOISE_UT, rtol=0.1)
    assert np.array_equal(noisy.platform_deg, clean.platform_deg)


def test_a_shallow_dip_shows_the_cubic_as_its_third_harmonic(reach):
    """Seed 75 (dip 40.7 deg): the linear fit leaves lam within 15 % of 1000 cos^6(dip); the tilts add little."""
    _, truth = reach.bl.session(75, "odd cubic")
    _, lam = reach.best_linear("odd cubic", 75, truth)
    assert lam == pytest.approx(1000 * np.cos(np.radians(truth.dip_deg)) ** 6, rel=0.15)


def test_a_missed_cubic_states_the_best_linear_gain(reach):
    """Seed 68 (dip 68.4 deg): lam under the 32 a decisive delta-BIC needs; the loop names nothing, and the gains
    sit within 4 sigmas of the noiseless linear fit's and over 15 from the slope at zero; the dip takes the
    vertical's scale (-sin cos c (Z^2 - 3 H^2 / 4) / |B|^2 = -0.14 deg)."""
    from calibrate import calibrate_fourflip

    rec, truth = reach.bl.session(68, "odd cubic")
    linear, lam = reach.best_linear("odd cubic", 68, truth)
    assert lam < 32
    result = calibrate_fourflip(rec, diagnose=True)
    assert result.diagnosis["effects"] == []
    gain = np.array([c.response.gain for c in result.channels])
    sigma = np.array([c.gain_sigma for c in result.channels])
    best = np.array([c.response.gain for c in linear.channels])
    assert np.all(np.abs(gain - best) < 4 * sigma)
    assert np.all(np.abs(gain - truth.gains) > 15 * sigma)
    dip = np.radians(truth.dip_deg)
    shift = -np.degrees(np.sin(dip) * np.cos(dip) * 0.01 * (np.sin(dip) ** 2 - 0.75 * np.cos(dip) ** 2))
    assert linear.dip_deg - truth.dip_deg == pytest.approx(shift, rel=0.2)
