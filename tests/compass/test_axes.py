"""Handedness and axis checks (issue 22, item 4): a reversed magnetometer axis is named, for tumble
calibrations and at runtime; the physics (compass.axes) checked on random orientations."""

import io
from itertools import product

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.axes import _dips, check_axes

DIP_DEG = 60.0


@pytest.fixture(scope="module")
def readings():
    """Up (accelerometer) and field (magnetometer) of a right-handed pair at 400 random orientations."""
    rng = np.random.default_rng(4)
    r = Rotation.random(400, random_state=11)
    dip = np.radians(DIP_DEG)
    up = r.inv().apply([0.0, 0.0, 1.0]) + rng.normal(0.0, 0.002, (400, 3))
    field = r.inv().apply(50.0 * np.array([np.cos(dip), 0.0, -np.sin(dip)])) + rng.normal(0.0, 0.1, (400, 3))
    return up, field


def test_a_pattern_and_its_opposite_read_one_spread_with_opposite_dips(readings):
    """The physics the check rests on: s and -s cannot be told apart without the hemisphere."""
    up, field = readings
    for signs in product((1, -1), repeat=3):
        dip, spread = _dips(up, field, signs)
        dip_neg, spread_neg = _dips(up, field, tuple(-s for s in signs))
        assert dip_neg == pytest.approx(-dip, abs=1e-9) and spread_neg == pytest.approx(spread, abs=1e-9)
    # only the right pattern and its opposite are consistent: a reflection makes the angle wander
    spreads = {s: _dips(up, field, s)[1] for s in product((1, -1), repeat=3)}
    assert max(spreads[(1, 1, 1)], spreads[(-1, -1, -1)]) < 0.5
    assert min(v for s, v in spreads.items() if s not in ((1, 1, 1), (-1, -1, -1))) > 10.0


def test_right_handed_readings_pass(readings):
    up, field = readings
    assert check_axes(up, field) is None and check_axes(up, field, site_dip_deg=DIP_DEG) is None
    assert check_axes(up, -field, site_dip_deg=-DIP_DEG) is None  # the southern hemisphere, told by its site


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_reversed_axis_is_named(readings, axis):
    up, field = readings
    flip = np.ones(3)
    flip[axis] = -1.0
    name = ("mx", "my", "mz")[axis]
    verdict = check_axes(up, field * flip, site_dip_deg=DIP_DEG)
    assert verdict.signs == tuple(flip.astype(int)) and verdict.left_handed
    assert verdict.spread_as_read_deg > 10.0 and verdict.spread_deg < 1.0 and verdict.dip_deg == pytest.approx(DIP_DEG, abs=0.5)
    assert f"negate {name} (--columns {name}=-COLUMN" in verdict.text
    # without a site both readings are named: this axis, or (southern hemisphere) the two others
    verdict = check_axes(up, field * flip)
    others = " and ".join(n for k, n in enumerate(("mx", "my", "mz")) if k != axis)
    assert f"negate {name}" in verdict.text and f"southern hemisphere, negate {others}" in verdict.text


def test_a_half_turn_fitted_over_a_reflection_shows_as_the_dip_sign(readings):
    """The best rotation for a reversed mz is a half turn about z (C = -D): consistent, the dip turned over."""
    up, field = readings
    half_turn = np.diag([-1.0, -1.0, 1.0])
    verdict = check_axes(up, field * [1, 1, -1], rotation=half_turn, site_dip_deg=DIP_DEG)
    assert verdict.signs == (1, 1, -1) and "negate mz" in verdict.text and "dip -60" in verdict.text
    assert check_axes(up, field * [1, 1, -1], rotation=half_turn) is None  # no site: a half turn is possible
    assert "southern hemisphere" in check_axes(up, field * [1, 1, -1], rotation=half_turn, note_upward=True).text


def test_too_little_turning_or_too_few_rows_is_not_judged(readings):
    up, field = readings
    level = np.tile([0.0, 0.0, 1.0], (400, 1))  # a swing: level throughout
    r = Rotation.from_euler("z", np.linspace(0, 360, 400)[:, None], degrees=True)
    dip = np.radians(DIP_DEG)
    swing = r.inv().apply(50.0 * np.array([np.cos(dip), 0.0, -np.sin(dip)]))
    assert check_axes(level, swing * [1, 1, -1]) is None  # consistent, sign unknown
    assert "negate mz" in check_axes(level, swing * [1, 1, -1], site_dip_deg=DIP_DEG).text  # the site tells
    assert check_axes(up[:10], field[:10] * [1, 1, -1]) is None


def test_a_tumble_with_a_reversed_mz_is_refused_at_a_site_and_warned_without():
    from calibrate.tumble import calibrate_tumble
    from compass.sim.tumble import simulate_tumble

    sim = simulate_tumble(seed=1, n=1500)
    assert calibrate_tumble(sim.mag, sim.accel, site_dip_deg=60.0).refused == ""
    reversed_z = sim.mag * [1, 1, -1]
    refused = calibrate_tumble(reversed_z, sim.accel, site_dip_deg=60.0).refused
    assert "left-handed" in refused and "negate mz" in refused
    warned = calibrate_tumble(reversed_z, sim.accel)
    assert warned.refused == "" and any("negate mz" in w for w in warned.warnings)


def test_a_live_session_names_the_reversed_axis():
    from compass.live import LiveSession
    from compass.replay import replay
    from compass.sim.device import default_model, simulate_device, tumble_motion

    model = default_model()
    t = np.arange(0.0, 60.0, 0.02)
    s = simulate_device(model, t, motion=tumble_motion, seed=3)
    events = []
    right = replay(LiveSession(model, on_event=lambda level, text: events.append(text)), t, s.raw, s.accel, s.gyro)
    assert right.axes is None
    wrong = replay(LiveSession(model, out=io.StringIO()), t, s.raw, s.accel * [1, 1, -1], s.gyro)
    assert wrong.axes is not None and "left-handed" in wrong.axes and "negate mz" in wrong.axes


def test_an_installation_with_a_reversed_accelerometer_axis_is_refused_at_a_site(tmp_path):
    """A reversed accelerometer z is the same reflection as a reversed magnetometer z (the check cannot tell
    which chip): named as mz, or the accelerometer's same axis."""
    import json
    from dataclasses import replace

    from calibrate import calibrate_fourflip
    from calibrate.contract import CannotCalibrate
    from calibrate.installation import InstallationCalibrator
    from compass.io.fourflip import read_fourflip
    from compass.io.installation import installation_from_table
    from compass.io.table import read_table
    from compass.io.units import RecordingWarning
    from compass.sim.fourflip import simulate_fourflip, write_fourflip
    from compass.sim.installation import random_installation, simulate_installation, write_installation

    session = simulate_fourflip(seed=41, dip_deg=58.0)
    path, _ = write_fourflip(session, tmp_path / "bench.csv")
    doc = calibrate_fourflip(read_fourflip(path), diagnose=False).to_json()
    (tmp_path / "bench.json").write_text(json.dumps(doc))
    rec = simulate_installation(session.truth, random_installation(42), kind="tumble", n=2000, seed=44)
    flipped = replace(rec, accel=rec.accel * [1, 1, -1])
    path, _ = write_installation(flipped, tmp_path / "inst.csv", force=True)
    parsed = installation_from_table(read_table(path), tuple(doc["channels"]))
    with pytest.raises(CannotCalibrate, match="left-handed.*accelerometer's same axis"):
        InstallationCalibrator(base=tmp_path / "bench.json", site="52.5,13.4", date="2026-01-01").fit(parsed)
    with pytest.warns(RecordingWarning, match="left-handed"):
        InstallationCalibrator(base=tmp_path / "bench.json").fit(parsed)
