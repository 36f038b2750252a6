"""``compass export`` repeats the calibration's own warnings (stderr and the output's comments) and refuses, unless
``--force``, the classes that make its numbers unusable: a fit that did not converge, a part not determined.  The
x-io recording's calibration (14 % coverage, unexplained) was exported clean, exit 0, no word."""

import json

import numpy as np
import pytest

from compass.cli import main

COVERAGE = "incomplete coverage: the field never pointed along the magnetometer's -X, +Z axes (only 14 % of the sphere)"
UNEXPLAINED = ("structure remains in |m| - F above the noise floor that no modelled effect accounts for: see the "
               "diagnosis; the uncertainties are then optimistic")
TUMBLE = {"format": "compass-calibration/1", "model": "tumble", "hard_iron": [1.0, -2.0, 3.0],
          "soft_iron": np.diag([1.1, 0.9, 1.0]).tolist(), "field_norm": 50.0, "mag_to_accel": None,
          "field_ut": 50.0, "dip_deg": 60.0, "noise_floor": [0.3] * 3}


def write(tmp_path, **extra):
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(TUMBLE | extra))
    return path


@pytest.mark.parametrize(("fmt", "mark"), [("fusion", "// warning: "), ("ardupilot", "# warning: "),
                                           ("motioncal", "# warning: ")])
def test_a_flagged_calibration_is_exported_with_its_warnings_repeated(tmp_path, capsys, fmt, mark):
    cal = write(tmp_path, warnings=[COVERAGE, UNEXPLAINED], diagnosis={"unexplained": True})
    assert main(["export", str(cal), "--format", fmt]) == 0
    captured = capsys.readouterr()
    for words in (COVERAGE, UNEXPLAINED):
        assert f"compass export: warning: {cal}: the calibration warns: {words}" in captured.err.splitlines()
        assert f"{mark}the calibration warns: {words}" in captured.out.splitlines()
    assert "residual diagnosis left structure" not in captured.err  # said once, in the file's words


def test_an_unexplained_diagnosis_no_warning_names_is_said(tmp_path, capsys):
    cal = write(tmp_path, diagnosis={"unexplained": True})
    assert main(["export", str(cal), "--format", "fusion"]) == 0
    assert "the residual diagnosis left structure above the noise floor unexplained" in capsys.readouterr().err


@pytest.mark.parametrize(("words", "kind"), [("the fit did not converge: maxfev reached", "not converged"),
                                             ("the full kind is poorly determined: singular", "undetermined")])
@pytest.mark.parametrize("fmt", ["fusion", "ardupilot", "motioncal"])
def test_a_calibration_its_warnings_call_unusable_is_refused_unless_forced(tmp_path, capsys, fmt, words, kind):
    cal = write(tmp_path, warnings=[COVERAGE, words])
    out = tmp_path / "out"
    assert main(["export", str(cal), "--format", fmt, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"compass export: {cal}: its own warnings say its numbers are not to be used ({kind}): {words}; "
                   f"recalibrate, or export it all the same with --force"]
    assert not out.exists()
    assert main(["export", str(cal), "--format", fmt, "--out", str(out), "--force"]) == 0
    assert f"the calibration warns: {words}" in capsys.readouterr().err and out.exists()


def test_warnings_that_are_not_words_are_refused_naming_the_key(tmp_path, capsys):
    cal = write(tmp_path, warnings="not a list")
    assert main(["export", str(cal), "--format", "fusion"]) == 2
    assert "warnings" in capsys.readouterr().err
