"""The gyro-unit verdict (compass/io/units.py): one threshold for the table reader, the stream decoder and the replay."""

import warnings

import numpy as np
import pytest

from compass.io import units
from compass.io.units import GYRO_UNIT_RATIO, RecordingWarning, check_gyro_unit, gyro_turn_ratio, gyro_unit_verdict

DEG_PER_RAD = 180.0 / np.pi


def _tilting(rate_deg_s: float = 30.0, seconds: float = 10.0, rate_hz: float = 100.0):
    """A housing turning about its X axis at a constant rate: times, the gyro (rad/s), the accelerometer (g)."""
    t_s = np.arange(0.0, seconds, 1.0 / rate_hz)
    angle = np.radians(rate_deg_s) * t_s
    accel = np.column_stack([np.zeros_like(t_s), np.sin(angle), np.cos(angle)])  # gravity-up turning about X
    gyro = np.column_stack([np.full_like(t_s, -np.radians(rate_deg_s)), np.zeros_like(t_s), np.zeros_like(t_s)])
    return t_s, gyro, accel


@pytest.mark.parametrize("ratio, verdict", [(DEG_PER_RAD, "more"), (1.0 / DEG_PER_RAD, "less"), (1.0, None),
                                            (GYRO_UNIT_RATIO, None), (1.0 / GYRO_UNIT_RATIO, None),
                                            (GYRO_UNIT_RATIO * 1.001, "more"), (0.999 / GYRO_UNIT_RATIO, "less"),
                                            (None, None), (float("nan"), None)])
def test_verdict_of_a_ratio(ratio, verdict):
    assert gyro_unit_verdict(ratio) == verdict


def test_a_gyro_in_its_unit_turns_as_the_accelerometer_tilts():
    t_s, gyro, accel = _tilting()
    ratio = gyro_turn_ratio(t_s, gyro, accel)
    assert ratio == pytest.approx(1.0, rel=0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecordingWarning)
        assert check_gyro_unit(t_s, gyro, accel, named=False, where="rec.csv") == pytest.approx(ratio)


@pytest.mark.parametrize("factor, words", [(DEG_PER_RAD, "times more .* --gyro-unit deg/s"),
                                           (1.0 / DEG_PER_RAD, "times less .* --gyro-unit rad/s")])
def test_a_gyro_in_the_other_unit_is_named_by_the_reader(factor, words):
    t_s, gyro, accel = _tilting()
    with pytest.warns(RecordingWarning, match=f"rec.csv: the gyro gx,gy,gz read in rad/s .*{words}"):
        ratio = check_gyro_unit(t_s, gyro * factor, accel, named=False, where="rec.csv")
    assert gyro_unit_verdict(ratio) == ("more" if factor > 1 else "less")


def test_the_stream_decoder_judges_by_the_same_verdict(monkeypatch):
    """The live stream's fault follows the verdict's threshold: moved above 57, a deg/s gyro passes there too."""
    from compass.io.streams import StreamDecoder, StreamOptions
    from compass.sim.device import simulate_device, tumble_motion
    from compass.sim.stream_formats import board_model

    t = np.arange(1200) / 100.0
    smp = simulate_device(board_model(), t, seed=3, motion=tumble_motion)  # tilts of 5 deg in 0.25 s
    columns = ("t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz")

    def warned(gyro) -> list:
        d = StreamDecoder(("mx", "my", "mz"), StreamOptions(columns=columns))
        rows = np.column_stack([t, smp.raw, smp.accel, gyro])
        d.feed(b"".join((",".join(f"{v:.7g}" for v in r) + "\r\n").encode() for r in rows))
        return [text for level, text in d.drain_events() if level == "warn" and "gyro" in text] \
            + ([] if d.gyro_fault is None else [d.gyro_fault])

    assert len(warned(np.degrees(smp.gyro))) == 1
    monkeypatch.setattr(units, "GYRO_UNIT_RATIO", 100.0)
    assert warned(np.degrees(smp.gyro)) == []
    assert len(warned(np.degrees(np.degrees(smp.gyro)))) == 1  # 57^2 times too much
