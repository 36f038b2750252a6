"""The one report formatter (calibrate.contract.fit_report) and the declared statistics it reads."""

from dataclasses import dataclass

import numpy as np
import pytest

from calibrate.contract import NO_JOINT_FIT, CalibrationResult, FitStatistics, fit_report


@dataclass(frozen=True)
class _Result(CalibrationResult):
    statistics: FitStatistics
    warnings: tuple = ()
    parameters: dict = None
    diagnosis: object = None
    calibration_kind = "test"

    def to_json(self):
        return {}

    def report(self):
        return fit_report(self, ["Test calibration", "  a 1 +- 0.1"], diagnosis="Residual diagnosis ...",
                          tail=["  closing section"])


def _stats(cov, success=True, message="converged"):
    names = tuple(f"p{i}" for i in range(len(cov)))
    return FitStatistics(names, np.zeros(len(cov)), np.asarray(cov, float), 120.0, 100, 120.0 + len(cov) * np.log(102),
                         success, message)


def test_the_report_is_head_statistics_correlations_warnings_diagnosis_tail_in_that_order():
    cov = [[1.0, 0.95, 0.0], [0.95, 1.0, -0.2], [0.0, -0.2, 4.0]]
    text = _Result(_stats(cov), warnings=("first", "second")).report()
    lines = text.splitlines()
    assert lines[:2] == ["Test calibration", "  a 1 +- 0.1"]
    assert lines[2] == f"  chi2/dof 1.200 (100 dof), BIC {120.0 + 3 * np.log(102):.1f}"
    assert lines[3] == "  correlations above 0.9: p1/p0 +0.95"  # -0.2 is not strong
    assert lines[4:] == ["  warning: first", "  warning: second", "Residual diagnosis ...", "  closing section"]


def test_a_fit_that_did_not_converge_says_so_and_a_rule_has_no_statistics_line():
    text = _Result(_stats(np.eye(2), success=False, message="max iterations")).report()
    assert "; not converged: max iterations" in text
    rule = _Result(NO_JOINT_FIT).report()
    assert "chi2" not in rule and "correlations" not in rule and NO_JOINT_FIT.names == ()


def test_statistics_give_sigma_reduced_chi2_and_skip_singular_correlations():
    stats = _stats([[4.0, 0.0], [0.0, np.inf]])
    np.testing.assert_allclose(stats.sigma, [2.0, np.inf])
    assert stats.reduced_chi2 == pytest.approx(1.2) and stats.correlations() == []
    negative = _stats([[1.0, -0.99], [-0.99, 1.0]])
    assert negative.correlations() == [("p1", "p0", pytest.approx(-0.99))]
    assert negative.correlations(threshold=0.995) == []
