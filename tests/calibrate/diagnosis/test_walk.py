"""A random walk of each channel's offset under a linear fit (calibrate/diagnosis/walk.py).

A four-flip-like design in time (4 turns of 180 rows, 2 s a row, 60 s between turns), per channel: an offset,
``cos phi`` and ``sin phi`` of the turn, a level read from the turns' level differences (``+1, -1, +1, -1`` by
turn: what tells a direction's two components across the flip axis from the offset) and a quadratic drift in
time.  White noise of unit variance (the weighted residual's units) plus, where said, a walk of ``Q`` per
square root of a second in each channel.
"""

import numpy as np
import pytest

from calibrate.diagnosis.robust import BAND_P_VALUE, band_p_values, family_p_value
from calibrate.diagnosis.walk import offset_walk, walk_p_value

ROWS, TURNS, DT_S, GAP_S, Q = 180, 4, 2.0, 60.0, 0.03
LEVEL = 3  # the column read from the turns' level differences


def _design(channels: int = 2):
    turn = np.repeat(np.arange(TURNS), ROWS)
    t_s = np.arange(turn.size) * DT_S + turn * GAP_S
    phi = 2 * np.pi * (np.arange(turn.size) % ROWS) / ROWS
    tau = (t_s - t_s.mean()) / np.ptp(t_s)
    own = np.column_stack([np.ones_like(phi), np.cos(phi), np.sin(phi), np.array([1.0, -1.0, 1.0, -1.0])[turn],
                           tau, tau**2])
    jac = np.zeros((turn.size * channels, own.shape[1] * channels))
    for ch in range(channels):
        jac[ch::channels, ch * own.shape[1]:(ch + 1) * own.shape[1]] = -own  # d(residual)/d(parameter)
    return t_s, own, jac, np.linalg.inv(jac.T @ jac)


def _walk(rng, t_s, channels, q=Q):
    steps = rng.normal(size=(t_s.size, channels)) * np.sqrt(np.diff(t_s, prepend=t_s[0]))[:, None]
    return q * np.cumsum(steps, axis=0)


def _fit(jac, bread, data):
    """The least-squares parameters (the truth is zero) and the weighted residual."""
    x = -bread @ jac.T @ data.ravel()
    return x, (data.ravel() + jac @ x).reshape(data.shape)


def test_a_walk_is_sized_from_the_block_sums_and_its_move_covered():
    """Over replicates the walk's estimated size is about the true one, and the stated covariance covers the
    turn-level parameter's error (err/sig RMS near 1; 1.30 here: a variance estimated from one realisation per
    channel states too little as often as too much, and ``E[1 / q^2]`` is above ``1 / E[q^2]``) where the
    white-noise covariance does not (over 2.5): the walk moves the level differences the fit reads that
    parameter from."""
    t_s, own, jac, bread = _design()
    rng = np.random.default_rng(7)
    k = own.shape[1]
    q, ratio, naive = [], [], []
    for _ in range(30):
        data = rng.normal(size=(t_s.size, 2)) + _walk(rng, t_s, 2)
        x, weighted = _fit(jac, bread, data)
        walk = offset_walk(jac, weighted, t_s, bread)
        # the truth the offset refers to is the walk's mean over the rows: the level's truth is zero whatever it is
        at = [LEVEL, k + LEVEL]
        ratio.append(x[at] / np.sqrt(np.diag(walk.covariance)[at]))
        naive.append(x[at] / np.sqrt(np.diag(bread)[at]))
        q.append(walk.q_per_sqrt_s)
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))  # noqa: E731
    assert rms(naive) > 2.5
    assert 0.75 < rms(ratio) < 1.4, rms(ratio)
    assert 0.7 < rms(q) / Q < 1.3, rms(q) / Q


def test_white_noise_and_a_drift_the_fit_takes_whole_are_not_a_walk():
    """Without a walk the stated sigmas stay near the naive ones; a drift in the fit's span (a quadratic in time,
    any size) changes nothing: the residual, the walk's size and the covariance are white noise's alone."""
    t_s, own, jac, bread = _design()
    rng = np.random.default_rng(11)
    grown, zero = [], 0
    for _ in range(12):
        noise = rng.normal(size=(t_s.size, 2))
        _, weighted = _fit(jac, bread, noise)
        walk = offset_walk(jac, weighted, t_s, bread)
        grown.append(np.sqrt(np.diag(walk.covariance) / np.diag(bread)))
        zero += int(np.sum(walk.q_per_sqrt_s == 0.0))
        drift = np.outer(own[:, 4] * 40.0 + own[:, 5] * 25.0, [1.0, -2.0])  # 25-80 noise sigmas
        _, drifted = _fit(jac, bread, noise + drift)
        other = offset_walk(jac, drifted, t_s, bread)
        np.testing.assert_allclose(other.q_per_sqrt_s, walk.q_per_sqrt_s, atol=1e-4 * Q)
        np.testing.assert_allclose(other.covariance, walk.covariance, rtol=1e-3,
                                   atol=1e-3 * np.max(np.diag(walk.covariance)))
    assert np.median(grown) < 1.15 and zero >= 6, (np.median(grown), zero)


def test_bin_means_weigh_the_walk_by_their_counts():
    """Rows that are means of several samples (weights the square root of their counts) give the same walk
    size as the samples themselves would, within its noise: the walk is in each mean whole, the noise
    shrinks."""
    t_s, own, jac, bread = _design(channels=1)
    rng = np.random.default_rng(3)
    counts = rng.integers(1, 5, size=t_s.size).astype(float)
    d = np.sqrt(counts)
    weighted_jac = jac * d[:, None]
    weighted_bread = np.linalg.inv(weighted_jac.T @ weighted_jac)
    q = []
    for _ in range(15):
        data = (rng.normal(size=(t_s.size, 1)) / d[:, None] + _walk(rng, t_s, 1)) * d[:, None]
        _, weighted = _fit(weighted_jac, weighted_bread, data)
        q.append(offset_walk(weighted_jac, weighted, t_s, weighted_bread, row_weight=d).q_per_sqrt_s)
    assert 0.7 < np.sqrt(np.mean(np.square(q))) / Q < 1.3


def test_the_walk_test_and_its_family_hold_their_size_on_white_noise():
    """Under white noise the walk test's p-value is uniform where its statistic is not zero (its null is simulated
    from the same N(0, I) the block sums follow): it passes at 0.1 in 10 % of replicates, within three binomial
    standard errors; the Bonferroni family with the band test (the four-flip's ``block_test``) passes at 0.2 in at
    most 20 %, within the same tolerance (at 0.01 on a four-flip's design: 9 of 1000, tools/bench_walktest.py)."""
    t_s, own, jac, bread = _design()
    rng = np.random.default_rng(17)
    n, walk, family = 150, 0, 0
    for _ in range(n):
        _, weighted = _fit(jac, bread, rng.normal(size=(t_s.size, 2)))
        p = walk_p_value(jac, weighted, t_s, bread)
        walk += p <= 0.1
        family += family_p_value(np.array([family_p_value(band_p_values(jac, weighted, t_s, bread)), p])) <= 0.2
    assert abs(walk / n - 0.1) < 3 * np.sqrt(0.1 * 0.9 / n), walk
    assert family / n < 0.2 + 3 * np.sqrt(0.2 * 0.8 / n), family


def test_a_residual_of_zero_is_no_walk():
    """Degenerate case: a fit that leaves nothing (every block sum zero) shows no walk: p = 1, not the null's
    smallest p-value (a ratio of 0 / 0 compared with every draw)."""
    t_s, _, jac, bread = _design()
    assert walk_p_value(jac, np.zeros((t_s.size, 2)), t_s, bread) == 1.0


def test_the_walk_test_sees_a_walk_more_often_than_the_band_family():
    """On the same walks (two thirds of the size above: seen in about half the replicates) the walk's
    likelihood-ratio test at half ``BAND_P_VALUE`` passes more often than the band family at the whole of it (53
    and 44 of 100 here; on a four-flip's design 0.53 and 0.44 of 200 at 0.015 noise sigmas per square root of a
    second, tools/bench_walktest.py): the walk's power sits in the lowest modes, which the family spreads over ten
    bands."""
    t_s, own, jac, bread = _design()
    rng = np.random.default_rng(2)
    walk, bands = 0, 0
    for _ in range(100):
        _, weighted = _fit(jac, bread, rng.normal(size=(t_s.size, 2)) + _walk(rng, t_s, 2, q=0.02))
        walk += walk_p_value(jac, weighted, t_s, bread) <= BAND_P_VALUE / 2
        bands += family_p_value(band_p_values(jac, weighted, t_s, bread)) <= BAND_P_VALUE
    assert walk >= bands + 5, (walk, bands)


@pytest.mark.parametrize("change, match", [
    (dict(t_s=np.arange(5.0)), "expected"),
    (dict(block_s=0.0), "block_s must be positive"),
    (dict(row_weight=-1.0), "row weights must be positive"),
])
@pytest.mark.parametrize("function", [offset_walk, walk_p_value])
def test_bad_input_is_refused(change, match, function):
    t_s, own, jac, bread = _design()
    weighted = np.zeros((t_s.size, 2))
    args = dict(jac=jac, weighted=weighted, t_s=t_s, bread=bread) | change
    with pytest.raises(ValueError, match=match):
        function(**args)
