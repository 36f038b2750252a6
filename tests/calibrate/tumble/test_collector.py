"""The live tumble collector's time: a corrupted t_s is left out, a restart of the module's clock is gone across."""

import numpy as np
import pytest

from calibrate.tumble.collector import TumbleCollector
from compass.io.lines import format_line
from compass.serial_reader import Chunk

N, STEP_S = 40, 0.01


def _collect(t_s, seed=0):
    """The collector after a stream of the line protocol at the module's times ``t_s`` (one line a chunk), and every
    event it returned (feed and finish)."""
    mag = np.random.default_rng(seed).normal(scale=30.0, size=(len(t_s), 3))
    collector = TumbleCollector()
    events = collector.feed(Chunk(0.0, format_line(["t_s", "mx", "my", "mz"])))
    for k, (t, m) in enumerate(zip(t_s, mag)):
        events += collector.feed(Chunk(STEP_S * (k + 1), format_line([f"{t:.2f}", *(f"{v:.6f}" for v in m)])))
    events += collector.finish()
    return collector, [text for _, text in events], mag


def _honest():
    return 10.0 + STEP_S * np.arange(N)


@pytest.mark.parametrize("corrupted_s", [1.20, 90.20])  # 10.20 with a digit lost (back) or flipped (ahead)
def test_a_corrupted_time_leaves_its_sample_out_and_the_recording_on_the_modules_clock(corrupted_s):
    honest = _honest()
    t_s = honest.copy()
    t_s[20] = corrupted_s
    collector, events, mag = _collect(t_s)
    kept = np.arange(N) != 20
    np.testing.assert_allclose(collector.samples[:, 0], honest[kept], atol=1e-9)  # no offset after it
    np.testing.assert_allclose(collector.samples[:, 1:4], mag[kept], atol=1e-6)
    assert collector.restarts == [] and len(collector.corrupted) == 1
    c = collector.corrupted[0]
    assert (c.sample, c.t_s, c.last_s, c.next_s) == (21, pytest.approx(corrupted_s), pytest.approx(honest[19]),
                                                     pytest.approx(honest[21]))
    said = [text for text in events if "corrupted time" in text]
    assert said == [c.words()] and "before sample 21" in said[0] and "left out" in said[0]  # said once
    assert "1 sample left out" in collector.clock_words() and "restarted" not in collector.clock_words()


def test_two_samples_on_the_new_clock_are_a_restart_gone_across_after_a_gap(tmp_path):
    """A restart's step is unknown: the recording goes on after RESTART_GAP_S and the median step, a gap over
    the gyro-aided fit's GAP_S, so no turn is integrated across it."""
    from compass.io.clock import RESTART_GAP_S
    from calibrate.tumble.gyro import GAP_S

    t_s = _honest()
    t_s[20:] -= t_s[20]  # a reset: 0, 0.01, ...
    collector, events, _ = _collect(t_s)
    np.testing.assert_allclose(collector.samples[:, 0], _honest() + np.where(np.arange(len(t_s)) >= 20,
                                                                              RESTART_GAP_S, 0.0), atol=1e-9)
    assert np.diff(collector.samples[:, 0])[19] > GAP_S
    assert collector.corrupted == [] and len(collector.restarts) == 1
    r = collector.restarts[0]
    assert (r.sample, r.from_s, r.to_s) == (21, pytest.approx(10.19), 0.0)
    assert [text for text in events if "clock" in text] == [r.words()]
    text = collector.write_recording(tmp_path / "r.csv").read_text()
    assert "# clock: the module's clock restarted 1 time, at sample 21" in text and "left out" not in text


def test_a_real_gap_is_kept_as_it_is():
    t_s = _honest()
    t_s[20:] += 3.0  # the stream paused: every time after it goes on from the new one
    collector, events, _ = _collect(t_s)
    np.testing.assert_allclose(collector.samples[:, 0], t_s, atol=1e-9)
    assert collector.restarts == [] and collector.corrupted == [] and collector.clock_words() is None
    assert not [text for text in events if "clock" in text or "time" in text]


def test_a_sample_kept_aside_when_the_stream_ends_is_left_out_and_said(tmp_path):
    t_s = _honest()
    t_s[-1] = 1.0
    collector, events, _ = _collect(t_s)
    np.testing.assert_allclose(collector.samples[:, 0], _honest()[:-1], atol=1e-9)
    assert len(collector.corrupted) == 1 and collector.corrupted[0].next_s is None
    said = [text for text in events if "stream ended" in text]
    assert len(said) == 1 and "left out" in said[0]
    assert "# clock: 1 sample left out" in collector.write_recording(tmp_path / "e.csv").read_text()


def test_a_stream_slower_than_the_gap_is_recorded_as_it_comes():
    """Every step over max_gap_s (a 1 Hz module): no sample is kept aside (none would come within the gap to tell
    it), none is left out, nothing is said; a time ahead at the end of a running stream is kept (a gap)."""
    slow = 10.0 + 1.0 * np.arange(N)
    collector, events, _ = _collect(slow)
    np.testing.assert_allclose(collector.samples[:, 0], slow, atol=1e-9)
    assert collector.corrupted == [] and collector.restarts == [] and collector.clock_words() is None
    assert not [text for text in events if "clock" in text or "time" in text]
    t_s = _honest()
    t_s[-1] += 5.0
    collector, _, _ = _collect(t_s)
    np.testing.assert_allclose(collector.samples[:, 0], t_s, atol=1e-9)
    assert collector.corrupted == []


def test_the_rows_streamed_as_they_come_are_the_recordings_rows_and_clock(tmp_path):
    """What `live --calibrate tumble` streams while it collects (the file a session killed outright leaves): in pieces,
    across a restart of the module's clock, the same header and rows as the recording written at the end, and its
    # clock: line (the last one said, where the reader takes it)."""
    import io

    from compass.io.table import read_table

    t_s = _honest()
    t_s[20:] -= t_s[20]
    mag = np.random.default_rng(0).normal(scale=30.0, size=(N, 3))
    collector, out = TumbleCollector(), io.StringIO()
    collector.feed(Chunk(0.0, format_line(["t_s", "mx", "my", "mz"])))
    assert collector.stream_rows(out) == 0 and out.getvalue() == ""  # nothing before the first sample
    for k, (t, m) in enumerate(zip(t_s, mag)):
        collector.feed(Chunk(STEP_S * (k + 1), format_line([f"{t:.2f}", *(f"{v:.6f}" for v in m)])))
        if k % 7 == 0:
            collector.stream_rows(out)
    collector.finish()
    assert collector.stream_rows(out) == N
    streamed, written = tmp_path / "streamed.csv", collector.write_recording(tmp_path / "written.csv")
    streamed.write_text(out.getvalue())
    a, b = read_table(streamed), read_table(written)
    assert a.columns == b.columns == ("t_s", "mx", "my", "mz")
    np.testing.assert_array_equal(a.data, b.data)
    assert a.metadata["clock"] == b.metadata["clock"] == collector.clock_words() and "restarted" in a.metadata["clock"]
