"""The field's unit against the calibration once the housing turns (compass.io.streams.field_scale_check's words after
the housing turned, compass.live.LiveSession.wrong_field): a field read in a unit too small stays put in the housing,
another board's calibration is not a unit, an honest field is never refused.

The fake board of tools/bench_field_unit.py: |B| 50 uT, dip 60 deg, 0.15 uT noise, heading turning at 20 deg/s with
pitch and roll sines of 15 and 10 deg (gravity turns by up to 36 deg in the housing within 5 s)."""

import io

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.io.lines import format_line
from compass.io.sample_log import SampleLog
from compass.io.streams import (FIXED_SHARE, JUDGE_SAMPLES, StreamDecoder, field_scale_check, gravity_pairs,
                                turn_share)
from compass.live import LiveSession
from compass.model import SensorModel
from compass.replay import replay
from compass.response import LinearResponse
from compass.serial_reader import Chunk
from compass.sim.device import simulate_device

CHANNELS = ("mx", "my", "mz")
HARD_IRON = np.array([18.0, -11.0, 32.0])  # 38.4 uT, 0.77 |B|: gauss read as uT gives 0.77 |B|


def _turns(t):
    t = np.asarray(t, float)
    return (np.mod(30 + 20.0 * t, 360.0), 15.0 * np.sin(2 * np.pi * t / 7.0), 10.0 * np.sin(2 * np.pi * t / 5.0),
            np.zeros(t.shape))


def _still(t):
    t = np.asarray(t, float)
    return np.full(t.shape, 30.0), np.zeros(t.shape), np.zeros(t.shape), np.zeros(t.shape)


def _board(hard_iron=HARD_IRON, gain=1.0):
    directions = Rotation.from_rotvec([0.004, -0.006, 0.003]).apply(np.eye(3))
    responses = tuple(LinearResponse(o, k * gain, (-1e4, 1e4)) for o, k in zip(hard_iron, (0.96, 1.04, 1.01)))
    return SensorModel(CHANNELS, directions, responses, 50.0, 50.0, 60.0, noise=np.full(3, 0.15 * gain))


def _run(device, cal, scale, motion=_turns, seconds=10.0, seed=0):
    t = np.arange(int(100 * seconds)) / 100.0
    s = simulate_device(device, t, motion=motion, seed=seed, gyro_bias=[0.005, -0.004, 0.003])
    return replay(LiveSession(cal, out=io.StringIO()), t, s.raw * scale, s.accel, s.gyro), s


def test_gauss_read_as_ut_stops_once_the_housing_turns_and_names_the_gauss():
    """|W h| 0.77 |B|: read as uT the field is about -W h, 0.77 |B| (the decoder's norm check passes it) and turns
    0.01 |B| / |W h| of what a field turns: stopped, with the factor 100 that makes it |B| and turning."""
    board = _board()
    session, _ = _run(board, board, 0.01)
    words = session.wrong_field
    assert words is not None and "stays put in the housing" in words
    assert "scaled by 100" in words and "G taken as uT" in words and "--mag-unit" in words
    assert session.samples < 600  # within the first seconds of turns, not at the end


@pytest.mark.parametrize("share", [0.9, 1.0, 1.1])
def test_an_honest_field_whose_hard_iron_is_about_b_is_taken(share):
    """The mirror of gauss read as uT: scaled by 0.01 such a stream is near |B| too, but as read it turns."""
    board = _board(HARD_IRON / np.linalg.norm(HARD_IRON) * 50.0 * share)
    session, s = _run(board, board, 1.0)
    assert session.wrong_field is None and session.samples == len(s.t_s)
    i, j, alpha = gravity_pairs(s.accel)
    assert turn_share(board.field(s.raw)[0], i, j, alpha) > 0.87  # a tilt about a horizontal axis: sin(60 deg) at
    # least; the heading's turn adds more
    assert turn_share(board.field(0.01 * s.raw)[0], i, j, alpha) < FIXED_SHARE


@pytest.mark.parametrize("scale", [1.0, 0.01])
def test_a_still_board_is_not_refused(scale):
    """Gravity never turns: nothing tells a field that stays put from one that would turn (gauss too: taken)."""
    board = _board()
    session, s = _run(board, board, scale, motion=_still)
    assert session.wrong_field is None and session.samples == len(s.t_s)


def test_another_boards_calibration_is_not_named_a_unit():
    """Hard iron (40, 20, -10) and gain 1.5 read with the fake board's calibration: 2.6 |B| as read, 0.87 scaled by
    0.1, but the scaled field turns 0.15 |B| of it with the housing (a unit's would all turn): the calibration."""
    cal, board = _board(), _board((40.0, 20.0, -10.0), 1.5)
    t = np.arange(1000) / 100.0
    s = simulate_device(board, t, motion=_turns, seed=0)
    lines = format_line(["mx", "my", "mz", "ax", "ay", "az"]) + b"".join(
        format_line([f"{v:.6g}" for v in (*m, *a)]) for m, a in zip(s.raw, s.accel))
    d = StreamDecoder(CHANNELS, field_check=field_scale_check(cal))
    assert d.feed(lines) == []
    assert d.fatal is not None and "this board's calibration" in d.fatal and "mG taken as uT" in d.fatal
    assert "name the stream's unit" not in d.fatal


def test_mg_read_as_ut_is_named_once_the_housing_turns_and_its_samples_are_recorded():
    board = _board()
    t = np.arange(1000) / 100.0
    s = simulate_device(board, t, motion=_turns, seed=1)
    lines = [format_line(["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"])] + [
        format_line([f"{v:.7g}" for v in (tk, *(10.0 * m), *a, *g)]) for tk, m, a, g in zip(t, s.raw, s.accel, s.gyro)]
    out, said = io.StringIO(), []
    session = LiveSession(board, record=SampleLog(out, CHANNELS, "test"), on_event=lambda level, text: said.append(text))
    for k, line in enumerate(lines):
        session.feed(Chunk(float(k) / 100.0, line))
        if session.decoder.fatal is not None:
            break
    fatal = session.decoder.fatal
    assert fatal is not None and "scaled by 0.1" in fatal and "mG taken as uT" in fatal and "--mag-unit" in fatal
    received = session.decoder.stats.samples
    assert JUDGE_SAMPLES < received < 1000 and session.record.rows == received  # kept, as before any other stop
    held = [text for text in said if "samples held until the module turns" in text]
    assert len(held) == 1 and "turn the module" in held[0]  # said once as the hold begins: not a stalled session


@pytest.mark.parametrize("dip_deg", [5.0, 10.0, 60.0])
@pytest.mark.parametrize("axis", ["roll", "pitch"])
def test_an_honest_field_at_low_dip_rolled_facing_north_is_taken(dip_deg, axis):
    """Near the magnetic equator a roll about North turns the field by sin(dip) of gravity's turn (0.09 at 5 deg):
    against gravity it read as a field that stays put and stopped an honest session; against the turn the gyro gives
    a field fixed in the world it turns as it should.  Gauss read as uT, rolled the same way, still stops."""
    directions = Rotation.from_rotvec([0.004, -0.006, 0.003]).apply(np.eye(3))
    responses = tuple(LinearResponse(o, k, (-1e4, 1e4)) for o, k in zip(HARD_IRON, (0.96, 1.04, 1.01)))
    board = SensorModel(CHANNELS, directions, responses, 40.0, 40.0, dip_deg, noise=np.full(3, 0.15))

    def facing_north(t):
        t = np.asarray(t, float)
        swing = 25.0 * np.sin(2 * np.pi * t / 6.0)
        zero = np.zeros(t.shape)
        return zero, (swing if axis == "pitch" else zero), (swing if axis == "roll" else zero), zero

    session, s = _run(board, board, 1.0, motion=facing_north, seconds=30.0)
    assert session.wrong_field is None and session.samples == len(s.t_s)
    gauss, _ = _run(board, board, 0.01, motion=facing_north, seconds=30.0)
    assert gauss.wrong_field is not None and "G taken as uT" in gauss.wrong_field
