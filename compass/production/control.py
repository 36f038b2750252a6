"""An EWMA control chart over session time: is the line drifting?

The chart of one figure over the sessions in time order (Montgomery, *Introduction to Statistical
Quality Control*, ch. 9; NIST/SEMATECH e-Handbook 6.3.2.4):

.. math::

    z_t = \\lambda x_t + (1 - \\lambda) z_{t-1},\\quad z_0 = \\mu_0,\\qquad
    \\mu_0 \\pm L \\sigma_0 \\sqrt{\\frac{\\lambda}{2 - \\lambda}\\left[1 - (1 - \\lambda)^{2t}\\right]}

with the in-control level and spread from the first ``baseline`` sessions (phase I): the mean of
the clipped values (below), and the median moving range over 0.954 (Montgomery's robust estimate
of an individuals chart's sigma: a module's difference from the one before, so a slow drift inside
the baseline barely moves it, and one bad module moves it not at all).

The defaults are wider than the textbook's lambda 0.2, L = 3 (in-control average run length near
500 sessions with known parameters): a line charts several figures over hundreds of sessions, with
limits estimated from a finite baseline, and L = 3 with a 20-session baseline raised an alarm in
about half of 250 in-control sessions of normal noise (seeded simulation).  L = 4 from 50
sessions raised one in about one run in ten, and still caught a step of two sigmas in about 5
sessions and a ramp of half a sigma a session in about 6 (``docs/production.md``;
``tools/bench_batch.py`` counts the false alarms and the delay on the simulated line).

A bad module is not a drift: each value enters the average clipped to ``median +- clip sigma0``
(a Huber-type EWMA), so one dead channel cannot sound the alarm alone (it moves the average by
``lambda clip`` = 0.6 sigma at most, against limits of 4 sqrt(lambda / (2 - lambda)) = 1.3 sigma);
a line whose values all moved does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["EwmaChart", "ewma_chart"]

_MR_MEDIAN_TO_SIGMA = 0.954
"""Median moving range of two normal values over their sigma (Montgomery)."""


@dataclass(frozen=True)
class EwmaChart:
    """One figure's EWMA chart.

    Attributes
    ----------
    values : ndarray, shape (n,)
        The figure in session order.
    ewma, low, high : ndarray, shape (n,)
        The average and its control limits.
    centre, sigma : float
        Phase-I level and individual sigma.
    baseline : int
        Sessions the limits come from.
    out : ndarray of bool, shape (n,)
        Sessions where the average is outside its limits (never in the baseline).
    first_alarm : int or None
        Index of the first such session.
    """

    values: np.ndarray
    ewma: np.ndarray
    low: np.ndarray
    high: np.ndarray
    centre: float
    sigma: float
    baseline: int
    out: np.ndarray
    first_alarm: int | None


def ewma_chart(values, *, baseline: int = 50, lam: float = 0.2, width_sigmas: float = 4.0,
               clip_sigmas: float = 3.0) -> EwmaChart:
    """The EWMA chart of ``values`` (session order), limits from the first ``baseline``.

    Raises
    ------
    ValueError
        Fewer values than ``baseline + 1`` (nothing to judge), or non-finite values.
    """
    x = np.asarray(values, dtype=float)
    if len(x) <= baseline:
        raise ValueError(f"a control chart needs more than its {baseline} baseline sessions, got {len(x)}")
    if not np.all(np.isfinite(x)):
        raise ValueError("control chart values must be finite")
    phase1 = x[:baseline]
    median = float(np.median(phase1))
    sigma = float(np.median(np.abs(np.diff(phase1))) / _MR_MEDIAN_TO_SIGMA)
    if not sigma > 0:  # a constant baseline: any change is a change
        sigma = float(np.finfo(float).eps * max(1.0, abs(median)))
    low_clip, high_clip = median - clip_sigmas * sigma, median + clip_sigmas * sigma
    clipped = np.clip(x, low_clip, high_clip)
    centre = float(np.mean(clipped[:baseline]))  # what the average of clipped values tends to (skewed figures)
    z = np.empty_like(x)
    previous = centre
    for t, v in enumerate(clipped):
        previous = lam * v + (1.0 - lam) * previous
        z[t] = previous
    t = np.arange(1, len(x) + 1)
    half = width_sigmas * sigma * np.sqrt(lam / (2.0 - lam) * (1.0 - (1.0 - lam) ** (2 * t)))
    low, high = centre - half, centre + half
    out = (z < low) | (z > high)
    out[:baseline] = False
    hits = np.flatnonzero(out)
    return EwmaChart(x, z, low, high, centre, sigma, baseline, out, int(hits[0]) if len(hits) else None)
