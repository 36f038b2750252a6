"""tools/bench_loop.py's truth and runtime heading error: zero for the truth itself, a rigid turn read back exactly,
a recording's gains and heading within their sigmas."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.response import Response
from tests._paths import load_tool


@pytest.fixture(scope="module")
def bench():
    return load_tool("bench_loop")


def _as_result(directions, offsets, gains):
    """A stand-in for a calibration result: fitted directions and each channel's linear response."""
    channels = [SimpleNamespace(response=Response(float(o), float(g))) for o, g in zip(offsets, gains)]
    return SimpleNamespace(directions=np.asarray(directions), channels=channels)


@pytest.mark.parametrize("case", ["clean", "gain walk"])
def test_the_truth_read_back_has_no_heading_error(bench, case):
    _, truth = bench.session(3, case)
    offsets = truth.output(np.zeros((1, 3)))[0]  # a linear response: the output at zero field is the offset
    result = _as_result(truth.directions, offsets, truth.gains)
    assert bench.heading_error_deg(result, truth) < 1e-9


@pytest.mark.parametrize("turn_deg", [0.05, -0.3])
def test_directions_turned_rigidly_about_the_vertical_turn_every_heading_by_that_angle(bench, turn_deg):
    _, truth = bench.session(4, "clean")
    offsets = truth.output(np.zeros((1, 3)))[0]
    turned = Rotation.from_euler("z", turn_deg, degrees=True).apply(truth.directions)
    result = _as_result(turned, offsets, truth.gains)
    assert bench.heading_error_deg(result, truth) == pytest.approx(abs(turn_deg), rel=1e-6)


@pytest.mark.parametrize("case", ["clean", "gain drift", "warm-up"])
def test_a_recording_reads_its_gains_and_heading_within_their_sigmas(bench, case):
    # the truth's conventions: the session's mean gain under a gain drift, the settled offset after a warm-up
    row = bench.with_heading_sigma(bench.run_one(case, 5))
    assert not row["unexplained"]
    # each ratio is a standard normal's size (3 gains) or a heading's RMS error over its sigma: 5 sigma bounds
    assert np.all(np.abs(row["gain_ratio"]) < 5.0)
    assert 0.0 < row["heading_err_deg"] < 5.0 * row["heading_sigma_deg"]
    # the runtime's heading sigma from the file (rt e/s) is the four-flip's own but for the offsets' correlation
    # across channels, which the file does not keep
    assert row["runtime_sigma_deg"] == pytest.approx(row["heading_sigma_deg"], rel=0.01)


def test_the_summary_leaves_out_a_gain_without_sigma_and_counts_it(bench):
    row = {"effects": [], "unexplained": False, "ratio": [1.0, 1.0, 1.0], "err_deg": [0.01] * 3, "time_s": 0.1,
           "cpu_s": 0.1, "heading_cost_deg": None, "gain_ratio": [3.0, float("nan"), 4.0],
           "heading_err_deg": 0.02, "heading_sigma_deg": 0.01, "runtime_sigma_deg": 0.04}
    summary = bench._summary([row])
    assert summary["gain"] == pytest.approx(np.sqrt(12.5))
    assert summary["no_gain_sigma"] == 1
    assert summary["heading_ratio"] == pytest.approx(2.0)
    assert summary["runtime_ratio"] == pytest.approx(0.5)
    assert "heading_ratio" not in row  # the input rows are left as they were
