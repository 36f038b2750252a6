"""The magnetometer's axes against the gyro's (compass.axes.axes_from_gyro, issue 22 item 4): a chip mounted turned
or mirrored against the IMU is named from the gyro's turns, on a robot path that covers a fraction of the sphere,
before any fit; the tumble calibration refuses it with the ``--columns`` remap, and the remap then calibrates."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.axes import axes_from_gyro, signed_permutations
from compass.io.tumble import gyro_turns

MPU9250 = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # AK8963 reads the IMU's (y, x, -z)
ICM20948 = np.diag([1.0, -1.0, -1.0])  # AK09916: a half turn about x
MIRRORED_X = np.diag([-1.0, 1.0, 1.0])  # one axis reversed: left-handed
QUARTER_Z = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # not symmetric: Q and Q^T differ
CYCLIC = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
HARD_IRON = np.array([12.0, -30.0, 8.0])
SOFT_IRON = np.array([[1.04, 0.02, -0.03], [0.02, 0.97, 0.01], [-0.03, 0.01, 1.02]])


@pytest.fixture(scope="module")
def robot():
    """A 40 s robot path (18 % of the sphere), the rows at a sixth of the rate as a tumble file keeps them."""
    from compass.sim.motion import SensorErrors
    from compass.sim.robot import simulate_robot

    errors = SensorErrors(gyro_bias_rad_s=(0.01, -0.015, 0.005), gyro_noise=3e-4, mag_noise_ut=0.7,
                          mag_latency_s=0.02)
    rec = simulate_robot(1000, duration_s=40.0, errors=errors)
    keep = np.zeros(len(rec.t_s), bool)
    keep[::6] = True
    return rec, keep


def _raw(rec, keep, q):
    """The magnetometer as a chip with axes ``q`` of the IMU's reads it: ``h + A Q b``."""
    return HARD_IRON + (rec.mag_ut[keep] @ q.T) @ SOFT_IRON.T


def _verdict(rec, keep, q, **kw):
    turns = gyro_turns(rec.t_s, rec.gyro_rad_s, keep)
    return axes_from_gyro(_raw(rec, keep, q), turns, rec.t_s[keep], up=rec.accel_m_s2[keep], **kw)


def test_there_are_48_signed_permutations_and_the_identity_first():
    qs = signed_permutations()
    assert len(qs) == 48 and np.array_equal(qs[0], np.eye(3))
    assert all(np.array_equal(np.abs(q) @ np.abs(q).T, np.eye(3)) for q in qs)
    assert len({q.tobytes() for q in qs}) == 48


def test_axes_as_the_gyro_s_pass(robot):
    assert _verdict(*robot, np.eye(3)) is None


@pytest.mark.parametrize("q, left", [(MPU9250, False), (ICM20948, False), (MIRRORED_X, True), (QUARTER_Z, False),
                                     (CYCLIC, False), (-CYCLIC, True)])
def test_turned_or_mirrored_axes_are_named_with_the_field_pointing_down(robot, q, left):
    verdict = _verdict(*robot, q)
    assert verdict is not None
    assert np.array_equal(verdict.matrix, q) and verdict.left_handed is left
    # the remap reads the field in the gyro's axes: applied to the raw readings, nothing is left to name
    rec, keep = robot
    remapped = _raw(rec, keep, q) @ verdict.matrix  # v = Q^T m, row by row
    turns = gyro_turns(rec.t_s, rec.gyro_rad_s, keep)
    assert axes_from_gyro(remapped, turns, rec.t_s[keep], up=rec.accel_m_s2[keep]) is None


def test_the_words_name_each_axis_and_both_forms_of_the_remap(robot):
    verdict = _verdict(*robot, MPU9250)
    assert "mx read as the gyro's +y, my read as the gyro's +x, mz read as the gyro's -z" in verdict.finding
    assert verdict.columns == "--columns mx=COLUMN(my),my=COLUMN(mx),mz=-COLUMN(mz)"
    assert verdict.cells == "my,mx,-mz"
    assert "mounted turned" in verdict.finding and "south of it, every sign in the remap turned" in verdict.remap
    assert verdict.remap.endswith("an accelerometer that reads gravity as down (as read) turns the pick: then every "
                                  "sign in the remap turned is right, or read the accelerometer negated "
                                  "(--accel-sign -1; compass live: -ax,-ay,-az in --columns)")
    quarter = _verdict(*robot, QUARTER_Z)  # m = (-v_y, v_x, v_z): v_x is my, v_y is -mx; the cells read -y, x, z
    assert quarter.columns == "--columns mx=COLUMN(my),my=-COLUMN(mx),mz=COLUMN(mz)" and quarter.cells == "-my,mx,mz"


def test_a_southern_site_picks_the_opposite_sign(robot):
    rec, keep = robot
    south = axes_from_gyro(_raw(rec, keep, MPU9250) * -1.0 + 2 * HARD_IRON, gyro_turns(rec.t_s, rec.gyro_rad_s, keep),
                           rec.t_s[keep], up=rec.accel_m_s2[keep], site_dip_deg=-60.0)
    # the field reversed (as a southern site's points up) with a southern site: the same chip, the same axes
    assert south is not None and np.array_equal(south.matrix, MPU9250) and "south of it" not in south.text


def test_without_an_accelerometer_the_sign_is_left_open(robot):
    rec, keep = robot
    verdict = axes_from_gyro(_raw(rec, keep, MPU9250), gyro_turns(rec.t_s, rec.gyro_rad_s, keep), rec.t_s[keep])
    assert verdict is not None and _same_pair(verdict.matrix, MPU9250) and verdict.left_handed is None
    assert "turned or mirrored" in verdict.finding and "do not say which way the field points" in verdict.remap


def _same_pair(a, b):
    return np.array_equal(a, b) or np.array_equal(a, -b)


def test_turns_about_one_axis_cannot_tell_and_say_nothing():
    """Turned about z only, a swap of x and y with one sign turns the field alike (it commutes with the turn)."""
    n, rate = 3000, 50.0
    t = np.arange(n) / rate
    w = np.zeros((n, 3))
    w[:, 2] = 1.5 * np.sin(2 * np.pi * t / 7.0)
    attitude = Rotation.from_rotvec(np.cumsum(w / rate, axis=0))
    field = attitude.inv().apply([20.0, 0.0, -40.0])
    swapped = field @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T
    turns = gyro_turns(t, w, np.ones(n, bool))
    up = attitude.inv().apply([0.0, 0.0, 1.0])
    assert axes_from_gyro(swapped, turns, t, up=up) is None
    assert axes_from_gyro(field @ MIRRORED_X, turns, t, up=up) is None  # x reversed: tied with a quarter turn


def test_too_few_or_non_finite_rows_are_not_judged(robot):
    rec, keep = robot
    raw, turns, t = _raw(rec, keep, MPU9250), gyro_turns(rec.t_s, rec.gyro_rad_s, keep), rec.t_s[keep]
    assert axes_from_gyro(raw[:15], turns[:15], t[:15]) is None
    raw = raw.copy()
    raw[::3] = np.nan  # a third of the rows unreadable: the others still pair up and name the axes
    verdict = axes_from_gyro(raw, turns, t, up=rec.accel_m_s2[keep])
    assert verdict is not None and np.array_equal(verdict.matrix, MPU9250)


def _write(path, t, mag, accel_m_s2, gyro):
    rows = np.column_stack([t, mag, accel_m_s2 / 9.80665, gyro])
    np.savetxt(path, rows, delimiter=",", header="t_s,mx,my,mz,ax,ay,az,gx,gy,gz", comments="", fmt="%.6f")
    return path


def test_a_tumble_file_with_turned_axes_is_refused_with_the_remap_which_then_calibrates(robot, tmp_path):
    import json

    from compass.cli import BadInput
    from compass.commands.calibrate import calibrate_file
    from compass.io.table import ReadOptions

    rec, keep = robot
    path = _write(tmp_path / "robot.csv", rec.t_s[keep], _raw(rec, keep, MPU9250), rec.accel_m_s2[keep],
                  rec.gyro_rad_s[keep])
    with pytest.raises(BadInput, match=r"--columns mx=COLUMN\(my\),my=COLUMN\(mx\),mz=-COLUMN\(mz\)"):
        calibrate_file(path, tmp_path / "cal.json", quiet=True)
    assert not (tmp_path / "cal.json").exists()
    options = ReadOptions(columns={"mx": "my", "my": "mx", "mz": "-mz"})
    calibrate_file(path, tmp_path / "cal.json", quiet=True, read_options=options)
    doc = json.loads((tmp_path / "cal.json").read_text())
    # read in the gyro's axes, the chip is the IMU's up to the mounting: the fitted rotation is small
    turn = Rotation.from_matrix(np.asarray(doc["mag_to_accel"]) if doc.get("mag_to_accel") else np.eye(3))
    assert turn.magnitude() < np.radians(5.0)
    np.testing.assert_allclose(doc["hard_iron"], MPU9250.T @ HARD_IRON, atol=3.0)  # v = Q^T m: h too


def test_a_quarter_turn_the_gyro_aided_fit_finds_stands_with_a_warning(robot, tmp_path):
    """The gyro-aided fit's rotation to the accelerometer takes a quarter turn about z into the gyro's axes."""
    from calibrate.tumble import TumbleCalibrator
    from compass.io.tumble import read_tumble

    rec, keep = robot
    path = _write(tmp_path / "robot.csv", rec.t_s[keep], _raw(rec, keep, QUARTER_Z), rec.accel_m_s2[keep],
                  rec.gyro_rad_s[keep])
    result = TumbleCalibrator().fit(read_tumble(path))
    assert any("not the gyro's" in w and "turns them into the gyro's" in w for w in result.warnings)
    assert Rotation.from_matrix(result.misalignment.rotation.as_matrix() @ QUARTER_Z).magnitude() < np.radians(10.0)


def _whole_sphere(path, q, metadata=""):
    """A simulated tumble over the whole sphere (dip +60 deg) read by a chip with axes ``q``, with its gyro."""
    from compass.sim.tumble import simulate_tumble

    sim = simulate_tumble(seed=5, n=1500)
    gyro = np.zeros((len(sim.t_s), 3))  # row i's rate turns the housing over (t_i-1, t_i]
    gyro[1:] = (sim.attitude[:-1].inv() * sim.attitude[1:]).as_rotvec() / np.diff(sim.t_s)[:, None]
    rows = np.column_stack([sim.t_s, sim.mag @ q.T, sim.accel, gyro])
    np.savetxt(path, rows, delimiter=",", header=metadata + "t_s,mx,my,mz,ax,ay,az,gx,gy,gz", comments="", fmt="%.6f")
    return path


def test_a_mirrored_chip_over_the_whole_sphere_stands_as_a_half_turn_only_without_a_site(tmp_path):
    """The fit takes a mirrored x as the half turn -Q^T with the field pointing up: right in the south, so without a
    site it stands (check_axes says the field points up); at a northern site it is refused with the remap."""
    from calibrate.contract import CannotCalibrate
    from calibrate.tumble import TumbleCalibrator
    from compass.io.tumble import read_tumble

    result = TumbleCalibrator().fit(read_tumble(_whole_sphere(tmp_path / "t.csv", MIRRORED_X)))
    assert any("the field points up" in w for w in result.warnings)
    assert any("mirrored" in w and "right only south of the magnetic equator" in w for w in result.warnings)
    north = "# site_lat_deg: 52.5\n# site_lon_deg: 13.4\n# date: 2026-11-27\n"
    with pytest.raises(CannotCalibrate, match="mirrored against the gyro"):
        TumbleCalibrator().fit(read_tumble(_whole_sphere(tmp_path / "north.csv", MIRRORED_X, north)))


def test_a_whole_sphere_tumble_whose_rotation_covers_the_axes_stands_with_a_warning(tmp_path):
    from calibrate.tumble import TumbleCalibrator
    from compass.io.tumble import read_tumble

    path = _whole_sphere(tmp_path / "tumble.csv", ICM20948)
    result = TumbleCalibrator().fit(read_tumble(path))
    assert any("not the gyro's" in w and "turns them into the gyro's" in w for w in result.warnings)
    assert Rotation.from_matrix(result.misalignment.rotation.as_matrix() @ ICM20948).magnitude() < np.radians(10.0)


def test_a_live_stream_read_with_other_columns_than_the_calibration_is_named():
    """A calibration made with a remap and a stream replayed without it: the session says so, once."""
    from compass.live import GYRO_AXES_ROWS, LiveSession
    from compass.replay import replay
    from compass.sim.device import default_model, simulate_device, tumble_motion

    model = default_model()
    t = np.arange(0.0, 60.0, 0.01)
    assert len(t) >= GYRO_AXES_ROWS
    s = simulate_device(model, t, motion=tumble_motion, seed=3)
    right_events, wrong_events = [], []
    right = replay(LiveSession(model, on_event=lambda level, text: right_events.append(text)), t, s.raw, s.accel,
                   s.gyro)
    assert right.axes is None and not any("not the gyro's" in e for e in right_events)
    swapped = s.raw[:, [1, 0, 2]] * [1.0, 1.0, -1.0]  # the chip's columns as an MPU-9250 sends them
    wrong = replay(LiveSession(model, on_event=lambda level, text: wrong_events.append(text)), t, swapped, s.accel,
                   s.gyro)
    assert wrong.axes is not None and "mounted turned against the gyro" in wrong.axes
    said = [e for e in wrong_events if "not the gyro's" in e]
    assert len(said) == 1 and "the remap its calibration was made with" in said[0] and "cells my,mx,-mz" in said[0]


def test_a_module_left_at_rest_for_longer_than_the_check_s_rows_is_judged_once_it_turns():
    """A session that starts with more than GYRO_AXES_ROWS rows at rest (a module on the desk while the user gets
    ready): the check waits for the turns instead of judging the rest, and says the swapped columns once."""
    from compass.live import GYRO_AXES_ROWS, LiveSession
    from compass.replay import replay
    from compass.sim.device import default_model, simulate_device, tumble_motion

    rest_s = 70.0

    def still_then_tumble(t):
        t = np.asarray(t, dtype=float)
        heading, pitch, roll, magnitude = tumble_motion(np.maximum(t - rest_s, 0.0))
        still = t < rest_s
        return np.where(still, 0.0, heading), np.where(still, 0.0, pitch), np.where(still, 0.0, roll), magnitude

    model = default_model()
    t = np.arange(0.0, rest_s + 30.0, 0.01)
    assert np.count_nonzero(t < rest_s) > GYRO_AXES_ROWS
    s = simulate_device(model, t, motion=still_then_tumble, seed=3)
    events = []
    swapped = s.raw[:, [1, 0, 2]] * [1.0, 1.0, -1.0]
    session = replay(LiveSession(model, on_event=lambda level, text: events.append(text)), t, swapped, s.accel, s.gyro)
    said = [e for e in events if "not the gyro's" in e]
    assert session.axes is not None and len(said) == 1 and "cells my,mx,-mz" in said[0]


def test_the_gyro_aided_fit_of_axes_it_cannot_match_refuses_in_words_not_a_traceback(tmp_path):
    """The fit behind the check (switched off here), on a turned chip where no accelerometer row survives its
    outlier test: a result or a refusal (CannotCalibrate), not a ValueError from an empty Jacobian block."""
    from unittest import mock

    from calibrate.contract import CannotCalibrate
    from calibrate.tumble import TumbleCalibrator
    from compass.io.tumble import read_tumble
    from compass.sim.motion import SensorErrors
    from compass.sim.robot import simulate_robot

    rng = np.random.default_rng(1000)  # a low-cost board (tools/bench_broad.py's, seed 0)
    sign = rng.choice([-1.0, 1.0], 3)
    errors = SensorErrors(gyro_bias_rad_s=tuple(rng.normal(0.0, np.radians(0.5), 3)),
                          gyro_scale=tuple(sign * rng.uniform(0.01, 0.02, 3)),
                          accel_bias_m_s2=tuple(rng.uniform(-0.15, 0.15, 3)),
                          accel_scale=tuple(rng.uniform(-0.02, 0.02, 3)),
                          gyro_noise=3e-4, accel_noise_m_s2=0.1, mag_latency_s=0.02)
    rec = simulate_robot(1000, errors=errors)
    keep = np.zeros(len(rec.t_s), bool)
    keep[::6] = True
    iron = np.random.default_rng(0)
    hard = iron.uniform(-20.0, 20.0, 3)
    soft = np.eye(3) + 0.03 * iron.normal(size=(3, 3))
    mag = hard + (rec.mag_ut[keep] @ ICM20948.T) @ ((soft + soft.T) / 2.0).T
    path = _write(tmp_path / "robot.csv", rec.t_s[keep], mag, rec.accel_m_s2[keep], rec.gyro_rad_s[keep])
    with mock.patch("calibrate.tumble.fit.axes_from_gyro", return_value=None):
        try:
            TumbleCalibrator().fit(read_tumble(path))
        except CannotCalibrate:
            pass


def test_a_live_stream_s_own_dip_does_not_pick_the_sign():
    """Without a site the session's reference is the stream's first quiet second, read through the wrong axes: its
    dip (here far above the 10 deg cut) must not be taken for the site's; the pick stays the field pointing down."""
    from compass.live import LiveSession
    from compass.replay import replay
    from compass.sim.device import default_model, simulate_device, tumble_motion

    def still_then_tumble(t):
        t = np.asarray(t, dtype=float)
        heading, pitch, roll, magnitude = tumble_motion(np.maximum(t - 3.0, 0.0))
        still = t < 3.0
        return np.where(still, 0.0, heading), np.where(still, 0.0, pitch), np.where(still, 0.0, roll), magnitude

    model = default_model()
    t = np.arange(0.0, 63.0, 0.01)
    s = simulate_device(model, t, motion=still_then_tumble, seed=3)
    events = []
    session = replay(LiveSession(model, on_event=lambda level, text: events.append(text)), t, s.raw @ CYCLIC.T, s.accel,
                     s.gyro)
    assert session.reference.source == "recording" and abs(session.reference.dip_deg) >= 10.0
    said = [e for e in events if "not the gyro's" in e]
    assert len(said) == 1 and "mounted turned against the gyro" in said[0] and "cells my,mz,mx" in said[0]


@pytest.mark.parametrize("accel_axes, gyro_axes, reversed_turns", [
    (np.diag([1.0, 1.0, -1.0]), np.eye(3), False),  # an accelerometer axis reversed
    (CYCLIC, np.eye(3), False),  # the accelerometer's columns in another order
    (np.eye(3), np.diag([1.0, 1.0, -1.0]), True),  # a gyro axis reversed: every turn backwards
    (np.eye(3), MPU9250 @ MIRRORED_X, True),  # the gyro's x and y swapped
])
def test_an_accelerometer_or_gyro_axis_reversed_or_swapped_is_said(robot, accel_axes, gyro_axes, reversed_turns):
    """Gravity turns against the gyro's turns as a field does: the robot path's still rows tell a reversed or
    swapped axis of either sensor (the gyro's mirrored turns tried too), and the axes as read say nothing."""
    from compass.axes import accel_axes_from_gyro

    rec, _ = robot
    every = np.ones(len(rec.t_s), bool)
    assert accel_axes_from_gyro(rec.accel_m_s2, gyro_turns(rec.t_s, rec.gyro_rad_s, every), rec.t_s) is None
    words = accel_axes_from_gyro(rec.accel_m_s2 @ accel_axes.T,
                                 gyro_turns(rec.t_s, rec.gyro_rad_s @ gyro_axes.T, every), rec.t_s)
    assert words is not None and "the accelerometer's axes are not the gyro's" in words
    assert ("the gyro's turns reversed" in words) == reversed_turns
