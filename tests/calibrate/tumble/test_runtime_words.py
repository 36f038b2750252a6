"""The tumble report says what the runtime will make of the file (compass.iron_uncertainty): a part left
undetermined makes the heading sigma not known (inf), said in the report as the runtime says it."""

import numpy as np

from calibrate.tumble import calibrate_tumble
from compass.calibration import from_dict
from compass.sim.tumble import simulate_tumble


def test_the_report_says_the_heading_sigma_is_not_known_when_no_rotation_was_fitted():
    sim = simulate_tumble(seed=9, n=2000)
    without = calibrate_tumble(sim.mag, None, t_s=sim.t_s)
    own = from_dict(without.to_json()).model.calibration_uncertainty
    assert own.undetermined and np.isinf(own.heading_sigma_deg(np.eye(3), [20.0, 0.0, -40.0]))
    line = [text for text in without.report().splitlines() if text.strip().startswith("at runtime:")]
    assert len(line) == 1 and "rotation from the magnetometer to the accelerometer" in line[0]
    assert "reported as inf" in line[0]
    with_accel = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s)
    own = from_dict(with_accel.to_json()).model.calibration_uncertainty
    assert not own.undetermined and np.isfinite(own.heading_sigma_deg(np.eye(3), [20.0, 0.0, -40.0]))
    assert "at runtime:" not in with_accel.report()
