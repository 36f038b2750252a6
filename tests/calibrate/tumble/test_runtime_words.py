"""The tumble report says what the runtime will make of the file (compass.iron_uncertainty): a part left
undetermined counts with a stated prior in the heading sigma, said in the report as the runtime says it."""

from calibrate.tumble import calibrate_tumble
from compass.calibration import from_dict
from compass.sim.tumble import simulate_tumble


def test_the_report_says_what_the_prior_adds_when_no_rotation_was_fitted():
    sim = simulate_tumble(seed=9, n=2000)
    without = calibrate_tumble(sim.mag, None, t_s=sim.t_s)
    own = from_dict(without.to_json()).model.calibration_uncertainty
    assert own.undetermined and own.cost_deg(without.field_norm, 60.0) > 0.5  # 2 deg about each axis, tilted 60 deg
    line = [text for text in without.report().splitlines() if text.strip().startswith("at runtime:")]
    assert len(line) == 1 and "rotation from the magnetometer to the accelerometer" in line[0]
    assert "stated priors (not measured) add" in line[0] and "at 60 deg dip" in line[0]
    with_accel = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s)
    own = from_dict(with_accel.to_json()).model.calibration_uncertainty
    assert not own.undetermined and own.cost_deg(with_accel.field_norm, 60.0) == 0.0
    assert "at runtime:" not in with_accel.report()
