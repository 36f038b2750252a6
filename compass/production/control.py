"""An EWMA control chart over session time: is the line drifting?

The chart of one figure over the sessions in time order (Montgomery, *Introduction to Statistical
Quality Control*, ch. 9; NIST/SEMATECH e-Handbook 6.3.2.4):

.. math::

    z_t = \\lambda x_t + (1 - \\lambda) z_{t-1},\\quad z_0 = \\mu_0,\\qquad
    \\mu_0 \\pm L \\sigma_0 \\sqrt{\\frac{\\lambda}{2 - \\lambda}\\left[1 - (1 - \\lambda)^{2t}\\right]}

with the in-control level and spread from the first ``baseline`` sessions (phase I): the median,
and the median moving range over 0.954 (Montgomery's robust estimate of an individuals chart's
sigma: a module's difference from the one before, so a slow drift inside the baseline barely
moves it, and one bad module moves it not at all).  lambda 0.2 with L = 3 detects a shift of one
sigma in about 10 sessions and of two in about 4, with an in-control average run length of several
hundred sessions (Lucas and Saccucci 1990; ``tools/bench_batch.py`` counts the false alarms).

A bad module is not a drift: each value enters the average clipped to ``mu0 +- clip sigma0``
(a Huber-type EWMA), so one dead channel cannot sound the alarm alone; a line whose values all
moved does.
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


def ewma_chart(values, *, baseline: int = 20, lam: float = 0.2, width_sigmas: float = 3.0,
               clip_sigmas: float = 4.0) -> EwmaChart:
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
    centre = float(np.median(phase1))
    sigma = float(np.median(np.abs(np.diff(phase1))) / _MR_MEDIAN_TO_SIGMA)
    if not sigma > 0:  # a constant baseline: any change is a change
        sigma = float(np.finfo(float).eps * max(1.0, abs(centre)))
    clipped = np.clip(x, centre - clip_sigmas * sigma, centre + clip_sigmas * sigma)
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
