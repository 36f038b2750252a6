"""Sample times of a stream that sends none, from the times its chunks arrive.

A module without a clock in its lines (the PJRC and Adafruit calibration sketches' ``Raw:`` lines, bare
numbers without ``t_s``) sends sample ``k`` at ``s_k = s_0 + k T`` and the host reads the chunk that ends
with sample ``k`` at ``a_k = s_k + d_k``.  The delay ``d_k`` is at least the wire's, and above it varies from
chunk to chunk by up to tens of milliseconds (a USB adapter's latency timer, the reading loop's other
work, a stall); every sample of a chunk arrives at once.  Dated at its chunk's arrival, a steady stream
turns into bursts: steps of zero, then one step over the whole chunk, and the gyro's rate is integrated
over the wrong intervals (a fast turn's heading tens of degrees off: docs/benchmarks.md, "A stream
without a clock").

:class:`SampleClock` dates sample ``k`` as ``min_j (a_j + T (k - k_j))`` over the chunk ends ``j`` of the
last :data:`ENVELOPE_S`: each of them bounds the sample's send time plus the least delay from above, and
the tightest one holds.  The period ``T`` is the slope of the lower convex hull of the chunk ends over the
last :data:`PERIOD_S` at the hull's middle (the line under every point closest to all of them: Moon,
Skelly and Towsley, "Estimation and removal of clock skew from network delay measurements", INFOCOM 1999),
so neither a delay nor a stall biases it.  A chunk later than the envelope foretells by over
:data:`BREAK_S` is a break (the module paused, a disconnect, lines lost), and one earlier by over :data:`EARLY_S` a rate
that went up: the clock starts again at it, so a gap shows as a gap, the period kept until :data:`SETTLE_S`
of new chunks refit it.  A sample is never dated after its chunk's arrival nor before the sample before it
(on one host clock: one that goes back starts the dates again).  Lines known lost (broken lines the decoder
dropped, a ``seq`` gap) are counted at once; lines lost silently under :data:`BREAK_S` are not seen at
once: the samples after them are dated up to their span early until every chunk of the last
:data:`SHIFT_S` shows them; they are then counted (:meth:`SampleClock._follow_a_shift`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np
from scipy.spatial import ConvexHull, QhullError

__all__ = ["SampleClock", "RESTART_GAP_S", "ENVELOPE_S", "PERIOD_S", "BREAK_S", "EARLY_S", "RATE_CHANGE", "SETTLE_S",
           "SHIFT_S"]

ENVELOPE_S = 2.0
"""Span of chunk ends whose lower envelope dates a sample, s of arrival time."""
PERIOD_S = 30.0
"""Span of chunk ends the period is fitted over, s of arrival time."""
BREAK_S = 0.1
"""A chunk this much later than the envelope foretells starts the clock again, s."""
EARLY_S = 0.02
"""A chunk this much earlier than the envelope foretells (its samples sent faster than the period) starts the
clock again, s: at the period no chunk arrives before its last sample's send time plus the least delay."""
RATE_CHANGE = 0.01
"""The period over the last :data:`ENVELOPE_S` off the whole span's by this fraction (over the last four times that,
by a quarter of it): the rate changed, and the clock starts again with it (a rate that went up moves the envelope's
newest point, not its foretelling)."""
SETTLE_S = 0.25
"""Span of chunk ends after a start again before the period is refitted, s: from it a period :data:`RATE_CHANGE` off
the kept one replaces it, from :data:`ENVELOPE_S` any."""
SHIFT_S = 0.25
"""Lines lost under :data:`BREAK_S` are followed once the chunks of this span all show them, s."""
_SHIFT_CHUNKS = 16
"""The fewest chunks a shift is judged on: a few chunks after a stall may all have come late."""
_SHIFT_MIN_S = 0.002
"""The least shift followed, s: below it the recent chunks' least delay varies by itself."""
_TIE_S = 1e-9
"""Envelope offsets this close are equal (rounding): the later point stands, so a steady stream is dated at its
arrivals exactly, s."""
RESTART_GAP_S = 1.0
"""A recording's gap across a restart of the module's clock (its ``t_s`` back to about 0), s, plus the median step:
the real pause is unknown, and a gap over the filter's ``max_gap_s`` (0.5 s) closes the gyro-aided tumble fit's
window (``calibrate.tumble.gyro.GAP_S``), so the turn made during a reset is never taken for one step's; the
four-flip fit reads ``t_s`` only for slow drifts, which see the flips on both sides as one after the other.  The
live tumble collector and the bench station both go on across a restart so."""
_REFIT_S = 1.0
"""The period is refitted once this much arrival time has passed (or a tenth of the span, when shorter), s."""


class SampleClock:
    """Dates the samples of a stream without a module clock from the chunks' arrival times.

    Feed every chunk in arrival order (:meth:`date`); :meth:`restart` after a reconnect.

    Attributes
    ----------
    period_s : float or None
        The sample period, s (None until two chunks have arrived).
    lost_unseen : int
        Lines lost without a trace (no broken line, no ``seq``) that the arrival times showed
        (:meth:`_follow_a_shift`), so far: an estimate (a rate drifting by under :data:`RATE_CHANGE` reads as a
        line lost now and then until the period's fit follows it).
    """

    def __init__(self):
        self.period_s: float | None = None
        self.lost_unseen = 0
        self._ends: deque = deque()  # (index of a chunk's last sample, its arrival time): the period's span
        self._envelope: deque = deque()  # (a_j, k_j, a_j - T k_j) of the envelope's span, the last increasing
        self._recent: deque = deque()  # the arrivals of the chunks of the last SHIFT_S (at least _SHIFT_CHUNKS)
        self._count = 0
        self._last_t: float | None = None
        self._fitted_at = -np.inf
        self._settling = False  # started again with the period kept: breaks judged from the chunk before

    def restart(self) -> None:
        """Forget the chunks so far (a reconnect, a break: the samples go on, their delays may not); the period is
        kept until :data:`SETTLE_S` of new chunks refit it."""
        self._ends.clear()
        self._envelope.clear()
        self._recent.clear()
        self._settling = self.period_s is not None
        self._fitted_at = -np.inf

    def dated(self, samples: list, t_rx: float, t0: float) -> list:
        """The decoder's samples, those without ``t_s`` dated (seconds since ``t0``, on ``t_rx``'s clock), the samples
        known lost before each (``Sample.lost_before``) counted in their place.

        Parameters
        ----------
        samples : list of compass.io.lines.Sample
            In arrival order; one the decoder held back carries its own arrival (``Sample.t_rx``).
        t_rx : float
            When the chunk they came out of arrived, s.
        t0 : float
            The session's first arrival, s.
        """
        dated, run = list(samples), []
        for k, sample in enumerate(samples + [None]):  # runs of clockless samples that arrived together
            arrival = None if sample is None or sample.t_s is not None else \
                (t_rx if sample.t_rx is None else sample.t_rx)
            if run and arrival != run[0][1]:
                times = self.date(len(run), run[0][1], [samples[j].lost_before for j, _ in run]) - t0
                for (j, _), t_s in zip(run, times.tolist()):
                    dated[j] = replace(dated[j], t_s=t_s)
                run = []
            if arrival is not None:
                run.append((k, arrival))
        return dated

    def date(self, m: int, t_rx: float, lost=None) -> np.ndarray:
        """Times of the ``m`` samples of a chunk, seconds on ``t_rx``'s clock, shape (m,) (empty for ``m`` 0).

        Parameters
        ----------
        m : int
            Samples in the chunk, in order.
        t_rx : float
            When the chunk arrived, s (chunks in arrival order; one earlier than the last starts the dates again).
        lost : array_like of int, shape (m,), optional
            Samples known lost before each (broken lines the decoder dropped, a ``seq`` gap), counted at once; one
            counted that was not (a line of noise) only dates the next samples at their chunk's arrival.  Negative
            counts as 0.
        """
        t_rx = float(t_rx)
        if m <= 0:
            return np.empty(0)
        steps = np.ones(m, dtype=int)
        if lost is not None:
            lost = np.asarray(lost, dtype=int)
            if lost.shape != (m,):
                raise ValueError(f"lost: one count a sample, shape ({m},), got shape {lost.shape}")
            steps += np.maximum(lost, 0)
        index = self._count - 1 + np.cumsum(steps)
        k = int(index[-1])
        self._count = k + 1
        before = self._ends[-1][1] if self._ends else self._last_t  # after a restart the last date tells
        if before is not None and t_rx < before:  # the host's clock went back: dates on the new one
            self.restart()
            self._last_t = None
        elif self._ends and self.period_s is not None:
            if self._settling:  # from the chunk before alone: the period kept may be another rate's
                k_last, a_last = self._ends[-1]
                late = t_rx - (a_last + self.period_s * (k - k_last))
            else:
                late = t_rx - self._foretold(k, self._ends[-1][1])
            if late > BREAK_S or (late < -EARLY_S and (not self._settling or k - self._ends[-1][0] > m)):
                self.restart()  # a gap (the module paused, lines lost), or a chunk before its time: the rate went up,
                # or lines counted lost that were not (a settling clock judges no rate, but a count it can)
        self._ends.append((k, t_rx))
        while t_rx - self._ends[0][1] > PERIOD_S:
            self._ends.popleft()
        if self._fit_period():
            self._envelope.clear()
            for kj, aj in [end for end in self._ends if t_rx - end[1] <= ENVELOPE_S]:
                self._add_to_envelope(kj, aj)
        elif self.period_s is not None:
            self._add_to_envelope(k, t_rx)
            index = index + self._follow_a_shift(t_rx)
        if self.period_s is None:
            times = np.full(m, t_rx)
        else:
            times = np.minimum(self._foretold(index, t_rx), t_rx)
        if self._last_t is not None:
            times = np.maximum(times, self._last_t)
        times = np.maximum.accumulate(times)
        self._last_t = float(times[-1])
        return times

    def _add_to_envelope(self, k: int, a: float) -> None:
        offset = a - self.period_s * k
        while self._envelope and self._envelope[-1][2] >= offset - _TIE_S:
            self._envelope.pop()  # never the least again: a later, lower (or, within rounding, equal) point outlives it
        self._envelope.append((a, k, offset))

    def _follow_a_shift(self, now: float) -> int:
        """Lines lost: every chunk of the last :data:`SHIFT_S` (or of the last :data:`_SHIFT_CHUNKS`, when they span
        more) sits above the envelope's older points by half a period or more (at least :data:`_SHIFT_MIN_S`).
        The samples since are then counted with the lines lost, ``round(shift / T)`` (at least one), the envelope
        keeps those recent chunks and the period's span drops the chunks between (they may be either side of the
        loss).  A period drifting by under :data:`RATE_CHANGE` is counted so too until the period's fit follows
        it.  Returns the count of lines lost (0: none seen)."""
        env, chunks = self._envelope, self._recent
        chunks.append(now)
        while len(chunks) > _SHIFT_CHUNKS and chunks[0] < now - SHIFT_S:
            chunks.popleft()
        since = chunks[0]
        if len(chunks) < _SHIFT_CHUNKS or env[0][0] >= since:
            return 0
        recent = next(point for point in env if point[0] >= since)  # the least offset of the recent chunks
        shift_s = recent[2] - env[0][2]
        if shift_s <= max(0.5 * self.period_s, _SHIFT_MIN_S):
            return 0
        lost, before = max(1, round(shift_s / self.period_s)), env[0][0]
        self._envelope = deque((a, k + lost, b - self.period_s * lost) for a, k, b in env if a >= since)
        self._ends = deque([(k, a) for k, a in self._ends if a <= before]
                           + [(k + lost, a) for k, a in self._ends if a >= since])
        self._count += lost
        self.lost_unseen += lost
        return lost

    def _foretold(self, k, now: float):
        """``min_j (a_j + T (k - k_j))`` over the chunk ends of the :data:`ENVELOPE_S` before ``now`` (a sliding
        minimum of ``a_j - T k_j``, increasing from the envelope's oldest point), from that point's own arrival
        (so a sample at a point is dated at its arrival exactly)."""
        while now - self._envelope[0][0] > ENVELOPE_S:
            self._envelope.popleft()
        a, kj, _ = self._envelope[0]
        return a + self.period_s * (k - kj)

    def _fit_period(self) -> bool:
        """The period from the chunk ends: their lower hull's slope at its middle (the first-to-last slope of two);
        True when it was refitted."""
        (k0, a0), (k1, a1) = self._ends[0], self._ends[-1]
        if k1 == k0 or a1 - a0 <= _TIE_S or (self._settling and a1 - a0 < SETTLE_S) \
                or a1 - self._fitted_at < min(_REFIT_S, 0.1 * (a1 - a0)):
            return False  # no span to read a period from, or not yet time to read it again
        self._fitted_at = a1
        ends = np.array(self._ends, dtype=float)
        period = _period(ends)
        if self._settling:
            if a1 - a0 < ENVELOPE_S and abs(period / self.period_s - 1.0) <= RATE_CHANGE:
                return False  # the period kept is as good as a short span tells
            self._settling = False
            self.period_s = period
            return True
        self.period_s = period
        for span_s, change in ((ENVELOPE_S, RATE_CHANGE), (4.0 * ENVELOPE_S, 0.25 * RATE_CHANGE)):
            recent = ends[ends[:, 1] >= a1 - span_s]
            if a1 - a0 > 2.0 * span_s and len(recent) >= 3 and recent[-1, 1] - recent[0, 1] > 0.5 * span_s:
                period = _period(recent)
                if abs(period / self.period_s - 1.0) > change:  # the rate changed within the span: start again
                    self.period_s = period                     # from this chunk at the recent period
                    self.restart()
                    self._ends.append((k1, a1))
                    break
        return True


def _period(ends: np.ndarray) -> float:
    """The slope of chunk ends (n, 2): their lower hull's at the middle, the first-to-last slope of two."""
    chord = (ends[-1, 1] - ends[0, 1]) / (ends[-1, 0] - ends[0, 0])
    return chord if len(ends) < 3 else _hull_slope(ends, chord)


def _hull_slope(ends: np.ndarray, chord: float) -> float:
    """The slope of the lower convex hull of the points ``ends`` (n, 2) at their mean abscissa; ``chord`` when
    the points lie on one line (Qhull refuses them)."""
    k, a = ends[:, 0], ends[:, 1]
    x = (k - k[0]) / (k[-1] - k[0])
    y = (a - a[0] - chord * (k - k[0])) / chord  # the delays above the chord, in samples: the hull's scale near 1
    try:
        hull = ConvexHull(np.column_stack([x, y]))
    except QhullError:
        return chord
    x_mean = float(np.mean(x))
    for (i, j), (_, ny, _) in zip(hull.simplices, hull.equations):
        if ny >= 0.0:
            continue  # an upper facet: its outward normal points up
        lo, hi = sorted((x[i], x[j]))
        if lo <= x_mean <= hi and hi > lo:
            return chord * (1.0 + (y[j] - y[i]) / (x[j] - x[i]) / (k[-1] - k[0]))
    return chord
