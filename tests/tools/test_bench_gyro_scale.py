"""tools/bench_gyro_scale.py's ``--candidates`` columns: a bench_broad candidate on top of the calibration file's
scale error, and unknown names refused."""

import importlib.util
import sys

import pytest

from tests._paths import ROOT


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(ROOT / "tools"))  # the script imports bench_broad and _doc_table from its folder
    spec = importlib.util.spec_from_file_location("bench_gyro_scale", ROOT / "tools" / "bench_gyro_scale.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_candidate_column_is_its_changes_on_top_of_the_fitted_scale_error(bench):
    """The column runs the pipeline the calibration file gives ("fitted") with the candidate's changes."""
    name = "accel_time_constant_s 4"
    assert bench._changes(name, {"rms": 0.012}) == {"gyro_scale_error": 0.012, "accel_time_constant_s": 4.0}
    assert bench._changes(name, {"rms": bench.DEFAULT_GYRO_SCALE_ERROR}) == {"accel_time_constant_s": 4.0}


@pytest.mark.parametrize("name", ["no such candidate", "noise from rest", "mag_latency_s fitted"])
def test_a_candidate_that_is_not_a_plain_filter_change_is_refused(bench, capsys, name):
    """Unknown names, and candidates that are not FilterConfig changes alone (the rest's noise, a value from another
    file), exit 2 naming them."""
    with pytest.raises(SystemExit) as stop:
        bench.main(["--candidates", name, "--broad", "none", "--levels", ""])
    assert stop.value.code == 2
    assert f"--candidates: unknown (or not a FilterConfig change) ['{name}']" in capsys.readouterr().err
