"""LiveSession computes what is not sequential once per chunk: the same outputs as sample by sample."""

import dataclasses
import io
import time

import numpy as np

from compass.io.lines import format_line
from compass.live import LiveSession
from compass.serial_reader import Chunk
from compass.sim.device import default_model, simulate_device
from compass.temperature import TemperatureCompensation


class _Collect:
    """A sink that keeps the field each sample was logged with."""

    def __init__(self):
        self.fields = []

    def log(self, t_s, sample, estimate, field_h, accel, **_):
        self.fields.append(np.array(field_h))

    def set_reference(self, *_):
        pass

    def event(self, *_):
        pass

    def close(self):
        pass


def _stream(model, n, temps, hold=1):
    """A header with temp_c, then ``n`` samples; ``temps[i]`` None leaves the cell empty; the magnetometer's
    reading held on ``hold`` rows (a magnetometer slower than the stream)."""
    s = simulate_device(model, np.arange(n) / 100.0, seed=6)
    mag = s.raw[np.arange(n) // hold * hold]
    lines = [format_line(["t_s", "seq", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz", "temp_c"])]
    for i in range(n):
        cells = [f"{s.t_s[i]:.4f}", i] + [f"{v:.7g}" for v in mag[i]] + [f"{v:.5f}" for v in s.accel[i]]
        lines.append(format_line(cells + [f"{v:.5f}" for v in s.gyro[i]] + ["" if temps[i] is None else temps[i]]))
    return b"".join(lines), np.array([[float(f"{v:.7g}") for v in row] for row in mag])  # as sent


def test_a_chunk_s_field_is_each_sample_s_with_the_last_temperature_carried():
    """Temperature-compensated fields computed for a whole chunk at once equal the calibration's field of
    each sample alone, at the last temperature sent (none yet: as at the reference), in and after seeding."""
    base = default_model()
    gains = np.array([r.gain for r in base.responses])
    effect = TemperatureCompensation(25.0, 2e-3 * gains, np.array([1e-3, -2e-3, 1.5e-3]))
    model = dataclasses.replace(base, temperature=effect)
    n = 400
    rng = np.random.default_rng(2)
    temps = [None] * 30 + [f"{t:.2f}" if rng.random() < 0.7 else None for t in 25.0 + 10.0 * rng.random(n - 30)]
    stream, raw = _stream(model, n, temps)
    sink = _Collect()
    session = LiveSession(model, out=io.StringIO(), sink=sink)
    for k in range(0, len(stream), 900):  # chunks of ~8 lines, boundaries anywhere
        session.feed(Chunk(time.perf_counter(), stream[k:k + 900]))
    session.close()
    assert session.samples == n and len(sink.fields) == n
    last, expected = None, []
    for i in range(n):
        last = last if temps[i] is None else float(temps[i])
        expected.append(model.field(raw[i][None, :], last)[0][0])
    np.testing.assert_allclose(np.array(sink.fields) * session.config.field_norm, expected, rtol=1e-12, atol=1e-12)
    assert not np.allclose(expected, model.field(raw)[0])  # the temperature mattered


def test_a_held_reading_keeps_its_field_while_the_temperature_moves():
    """A magnetometer reading repeated on the rows after it (its conversion held) is compensated at the temperature
    of the row it came on: its field repeats too, which is how the filter knows it held (compass.filter._gyro)."""
    base = default_model()
    gains = np.array([r.gain for r in base.responses])
    model = dataclasses.replace(base, temperature=TemperatureCompensation(25.0, 2e-3 * gains, np.zeros(3)))
    n, hold = 300, 3
    temps = [f"{25.0 + 0.05 * i:.2f}" for i in range(n)]  # a new temperature on every row
    stream, raw = _stream(model, n, temps, hold)
    sink = _Collect()
    session = LiveSession(model, out=io.StringIO(), sink=sink)
    for k in range(0, len(stream), 700):
        session.feed(Chunk(time.perf_counter(), stream[k:k + 700]))
    session.close()
    fields = np.array(sink.fields)
    assert len(fields) == n
    held = np.arange(n) % hold != 0
    np.testing.assert_array_equal(fields[held], fields[np.flatnonzero(held) - 1])
    new = np.flatnonzero(~held)
    expected = [model.field(raw[i][None, :], float(temps[i]))[0][0] for i in new]
    np.testing.assert_allclose(fields[new] * session.config.field_norm, expected, rtol=1e-12, atol=1e-12)


def test_a_magnetometer_slower_than_the_stream_is_said_once_with_its_rate():
    model = default_model()
    said = {}
    for hold in (1, 5):
        stream, _ = _stream(model, 400, [None] * 400, hold)
        events = []
        session = LiveSession(model, out=io.StringIO(), on_event=lambda level, text: events.append((level, text)))
        session.feed(Chunk(time.perf_counter(), stream))
        session.close()
        said[hold] = [(level, text) for level, text in events if "repeats its last reading" in text]
    assert said[1] == []
    (level, text), = said[5]  # once
    assert level == "info"
    assert "80 % of the first 200 rows" in text and "every 50 ms, at 100 Hz rows" in text
