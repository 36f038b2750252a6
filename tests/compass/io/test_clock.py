"""A stream without a clock dated from its chunks' arrival (:class:`compass.io.clock.SampleClock`)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from compass.io.clock import BREAK_S, SampleClock

PERIOD_S = 0.01


def _arrivals(t_send, rng, stall_share=0.01):
    """Reads every 1-20 ms (a share after a 50-200 ms stall); each sample arrives with the first read 1 ms after it
    was sent."""
    gaps = rng.uniform(0.001, 0.020, int(2 * (t_send[-1] - t_send[0]) / 0.001) + 10)
    stalls = rng.random(len(gaps)) < stall_share
    gaps[stalls] = rng.uniform(0.05, 0.2, int(stalls.sum()))
    reads = t_send[0] + np.cumsum(gaps)
    return reads[np.searchsorted(reads, t_send + 0.001)]


def _dated(t_rx, clock=None):
    clock = clock or SampleClock()
    out = np.empty_like(t_rx)
    edges = np.concatenate([[0], np.flatnonzero(np.diff(t_rx) != 0.0) + 1, [len(t_rx)]])
    for a, b in zip(edges[:-1], edges[1:]):
        out[a:b] = clock.date(int(b - a), float(t_rx[a]))
    return out


@pytest.mark.parametrize("seed", range(3))
def test_a_bursty_stream_is_dated_at_its_period_within_a_millisecond(seed):
    """A 100 Hz stream read in bursts of 0-20 samples (arrival steps of 0 and of up to 0.2 s) is dated one period
    apart: after the first 2 s within 1 ms of the send times (less a constant delay), its period within 1e-4."""
    t = np.arange(0.0, 60.0, PERIOD_S)
    t_rx = _arrivals(t, np.random.default_rng(seed))
    assert np.max(np.diff(t_rx)) > 0.04 and np.mean(np.diff(t_rx) == 0.0) > 0.3  # the arrivals are bursts
    clock = SampleClock()
    dated = _dated(t_rx, clock)
    late = t >= 2.0
    error = (dated - t)[late]
    assert np.percentile(np.abs(error - np.median(error)), 99) < 1e-3
    assert np.max(np.abs(error - np.median(error))) < 5e-3
    assert abs(clock.period_s / PERIOD_S - 1.0) < 1e-4
    np.testing.assert_allclose(np.diff(dated[late]), PERIOD_S, atol=2e-3)


@given(st.lists(st.tuples(st.integers(1, 30), st.floats(-0.05, 0.3), st.integers(-2, 40), st.booleans()),
                min_size=1, max_size=200))
@settings(max_examples=60, deadline=None)
def test_no_sample_is_dated_after_its_arrival_or_before_the_one_before(chunks):
    """Whatever the chunks, lines counted lost and reconnects: the dates never decrease (but on a host clock that
    goes back) and never pass the arrival."""
    clock = SampleClock()
    t_rx, last = 0.0, -np.inf
    for m, gap, lost, reconnect in chunks:
        if reconnect:
            clock.restart()
        back = gap < 0.0
        t_rx += gap
        counts = np.zeros(m, int)
        counts[m // 2] = lost
        times = clock.date(m, t_rx, counts)
        assert times.shape == (m,) and np.all(np.isfinite(times))
        assert np.all(np.diff(times) >= 0.0) and np.all(times <= t_rx)
        assert back or times[0] >= last
        last = times[-1]


def test_a_stream_read_one_sample_a_read_on_time_is_dated_at_its_arrivals():
    """Arrivals exactly one period apart (Qhull's degenerate case: every point on one line) are the dates."""
    t = 5.0 + np.arange(500) * PERIOD_S
    np.testing.assert_allclose(_dated(t), t, atol=1e-9)


def test_a_module_that_pauses_is_dated_with_the_gap():
    """The module sends nothing for 1 s (a pause, a disconnect): the dates show the gap (the filter restarts on it)
    rather than running the samples after it on from the samples before."""
    t = np.arange(0.0, 20.0, PERIOD_S)
    t = t[(t < 10.0) | (t >= 11.0)]
    dated = _dated(_arrivals(t, np.random.default_rng(4)))
    steps = np.diff(dated)
    k = np.argmax(steps)
    assert t[k] < 10.0 <= t[k + 1]
    assert 0.95 < steps[k] < 1.05
    assert BREAK_S < 1.0


@pytest.mark.parametrize("lost", [1, 3, 9])
def test_lines_lost_put_the_dates_back_on_the_send_times_within_half_a_second(lost):
    """A few lines lost (under the break's 0.1 s): from 0.5 s after them the dates are back within 1 ms of the send
    times (less the delay before the loss), where the envelope alone would take its 2 s."""
    t = np.arange(0.0, 20.0, PERIOD_S)
    t = np.delete(t, np.arange(1000, 1000 + lost))
    dated = _dated(_arrivals(t, np.random.default_rng(5), stall_share=0.0))
    before = np.median((dated - t)[500:1000])
    after = (dated - t)[t > 10.0 + lost * PERIOD_S + 0.5] - before
    assert np.max(np.abs(after)) < 1e-3


def test_a_restart_keeps_the_period_until_new_chunks_refit_it():
    """After a reconnect the period stands (two chunks 16 ms apart do not refit it) until SETTLE_S of chunks."""
    clock = SampleClock()
    _dated(np.arange(0.0, 5.0, PERIOD_S), clock)
    clock.restart()
    times = clock.date(5, 100.0)
    np.testing.assert_allclose(np.diff(times), PERIOD_S, rtol=1e-6)
    assert times[-1] == 100.0
    times = clock.date(2, 100.016)  # 1.6 periods after, two samples: a chord of 8 ms
    assert clock.period_s == pytest.approx(PERIOD_S, rel=1e-6)
    np.testing.assert_allclose(np.diff(times), PERIOD_S, rtol=1e-6)


@pytest.mark.parametrize("after_s", [0.02, 0.005, 0.0095])
def test_a_rate_that_changes_is_followed_within_seconds(after_s):
    """100 Hz, then another rate at 20 s (slower, faster, 5 % faster): from 3 s after the change the steps are the new
    period (median within 1 %, 98 % of them within 5 %)."""
    t = np.concatenate([np.arange(0.0, 20.0, PERIOD_S), 20.0 + np.arange(0.0, 20.0, after_s)])
    dated = _dated(_arrivals(t, np.random.default_rng(7), stall_share=0.0))
    steps = np.diff(dated)[t[1:] >= 23.0] / after_s - 1.0
    assert abs(np.median(steps)) < 0.01 and np.percentile(np.abs(steps), 98) < 0.05


def test_an_empty_chunk_and_a_host_clock_that_goes_back():
    clock = SampleClock()
    assert clock.date(0, 1.0).shape == (0,)
    _dated(np.arange(0.0, 3.0, PERIOD_S), clock)
    times = clock.date(3, 1.0)  # another host clock: dated on it, never after the arrival
    assert np.all(times <= 1.0)


@pytest.mark.parametrize("seed", range(5))
def test_the_period_is_the_line_under_every_chunk_end_closest_to_all(seed):
    """The hull's slope at the middle is the linear programme's answer: the line below every (k, a) with the least
    summed distance (Moon, Skelly and Towsley 1999), here scipy's linprog."""
    from scipy.optimize import linprog

    from compass.io.clock import _period

    rng = np.random.default_rng(seed)
    k = np.sort(rng.choice(5000, 300, replace=False)).astype(float)
    a = 3.0 + 0.01 * k + rng.exponential(0.004, len(k))
    x = k - k.mean()  # centred, so the two unknowns are of one scale
    lp = linprog(c=[-len(k), -x.sum()], A_ub=np.column_stack([np.ones_like(x), x]), b_ub=a, bounds=[(None, None)] * 2)
    assert lp.success
    assert _period(np.column_stack([k, a])) == pytest.approx(lp.x[1], rel=1e-9)


def test_lines_lost_are_counted_in_their_place_in_the_chunk():
    """A chunk of ten samples on time with the fourth one's line lost (``lost`` 1 before it): the three before it keep
    their period, the six after it are a period later, as sent."""
    clock = SampleClock()
    _dated(np.arange(0.0, 5.0, PERIOD_S), clock)  # 500 samples read one at a time, on time
    t_send = 5.0 + PERIOD_S * np.delete(np.arange(11), 3)
    lost = np.zeros(10, int)
    lost[3] = 1
    times = clock.date(10, float(t_send[-1]), lost)
    np.testing.assert_allclose(times, t_send, atol=1e-9)


def test_a_count_of_lines_lost_that_were_not_restarts_a_settling_clock():
    """Right after a restart (a reconnect: the clock settles, the period kept) a chunk counted 50 lines lost that
    were not (noise taken for broken lines) would date it half a second early and refit the period to it: it starts
    the clock again instead, so the period and the next dates stand."""
    clock = SampleClock()
    _dated(np.arange(0.0, 5.0, PERIOD_S), clock)
    clock.restart()
    for j in range(5):
        clock.date(1, 10.0 + PERIOD_S * j)
    lost = np.zeros(1, int)
    lost[0] = 50
    times = clock.date(1, 10.0 + PERIOD_S * 5, lost)
    assert times[-1] == pytest.approx(10.0 + PERIOD_S * 5)
    later = _dated(10.0 + PERIOD_S * np.arange(6, 300), clock)
    assert clock.period_s == pytest.approx(PERIOD_S, rel=1e-3)
    np.testing.assert_allclose(np.diff(later), PERIOD_S, atol=1e-6)


@pytest.mark.parametrize("lost", [0, [0, 0], [[0, 0, 0]]])
def test_lost_counts_must_be_one_a_sample(lost):
    with pytest.raises(ValueError, match="one count a sample"):
        SampleClock().date(3, 1.0, lost)
