"""The tumble reader and the gyro's unit: judged once by the table reader, one note, the verdict honoured.

The gyro is the simulated tumble's own turn (rad/s, housing frame); the unit faults are injected by
writing it in the other unit (deg/s read as rad/s) or naming the other unit (rad/s named deg/s), so
the verdict expected follows from the 57.3 between them, not from what the code printed.
"""

import warnings

import numpy as np
import pytest

from compass.io import units
from compass.io.table import ReadOptions, read_table
from compass.io.tumble import read_tumble
from compass.io.units import RecordingWarning
from compass.sim.tumble import simulate_tumble

COLUMNS = ["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"]


def _recording(path, factor: float = 1.0, seed: int = 5, n: int = 1500):
    """A tumble with its gyro written ``factor`` times its rad/s rate (57.3: in deg/s)."""
    sim = simulate_tumble(seed=seed, n=n)
    rot = sim.attitude
    gyro = np.vstack([(rot[:-1].inv() * rot[1:]).as_rotvec() / np.diff(sim.t_s)[:, None], np.zeros((1, 3))])
    data = np.column_stack([sim.t_s, sim.mag, sim.accel, factor * gyro])
    np.savetxt(path, data, fmt="%.8f", delimiter=",", header=",".join(COLUMNS), comments="")
    return path


def _read(path, options=None):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = read_tumble(path, options)
    return rec, [str(w.message) for w in caught if issubclass(w.category, RecordingWarning)]


def test_the_table_carries_the_ratio_its_reader_judged(tmp_path):
    path = _recording(tmp_path / "t.csv")
    table = read_table(path)
    expected = units.gyro_turn_ratio(table.column("t_s"), table.group(("gx", "gy", "gz")), table.group(("ax", "ay", "az")))
    assert table.gyro_turn_ratio == expected and 1.0 <= expected < 3.0  # a turn about the vertical tilts nothing
    rec, notes = _read(path)
    assert rec.gyro_turn_rad is not None and notes == []


def test_the_gyro_is_judged_once_per_reading(tmp_path, monkeypatch):
    path = _recording(tmp_path / "t.csv")
    calls = []
    judge = units.gyro_turn_ratio
    monkeypatch.setattr(units, "gyro_turn_ratio", lambda *a, **k: calls.append(1) or judge(*a, **k))
    rec, _ = _read(path)
    assert len(calls) == 1 and rec.gyro_turn_rad is not None


def test_a_deg_per_s_gyro_read_as_rad_per_s_gives_one_note_and_is_not_used(tmp_path):
    rec, notes = _read(_recording(tmp_path / "t.csv", factor=np.degrees(1.0)))
    gyro_notes = [n for n in notes if "gx,gy,gz" in n]
    assert len(gyro_notes) == 1, notes
    assert "times more" in gyro_notes[0] and "--gyro-unit deg/s" in gyro_notes[0]
    assert rec.gyro_turn_rad is None


def test_a_rad_per_s_gyro_named_deg_per_s_is_not_used(tmp_path):
    """The "less" verdict: read as deg/s the gyro turns 57 times less than the housing tilts."""
    rec, notes = _read(_recording(tmp_path / "t.csv"), ReadOptions(gyro_unit="deg/s"))
    gyro_notes = [n for n in notes if "gx,gy,gz" in n]
    assert len(gyro_notes) == 1 and "times less" in gyro_notes[0] and "--gyro-unit rad/s" in gyro_notes[0], notes
    assert rec.gyro_turn_rad is None


@pytest.mark.parametrize("factor, unit", [(np.degrees(1.0), "deg/s"), (1.0, None)])
def test_a_gyro_in_the_unit_named_is_used(tmp_path, factor, unit):
    rec, notes = _read(_recording(tmp_path / "t.csv", factor=factor), ReadOptions(gyro_unit=unit))
    assert not [n for n in notes if "gx,gy,gz" in n], notes
    assert rec.gyro_turn_rad is not None and rec.gyro_turn_rad.shape == rec.mag.shape
