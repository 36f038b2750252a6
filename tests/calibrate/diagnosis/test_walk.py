"""A random walk of each channel's offset under a linear fit (calibrate/diagnosis/walk.py).

A four-flip-like design in time (4 turns of 180 rows, 2 s a row, 60 s between turns), per channel: an offset,
``cos phi`` and ``sin phi`` of the turn, a level read from the turns' level differences (``+1, -1, +1, -1`` by
turn: what tells a direction's two components across the flip axis from the offset) and a quadratic drift in
time.  White noise of unit variance (the weighted residual's units) plus, where said, a walk of ``Q`` per
square root of a second in each channel.
"""

import numpy as np
import pytest

from calibrate.diagnosis.walk import offset_walk

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
    turn-level parameter's error: the mean of err^2 / stated variance is 1 within its Monte Carlo tolerance (three
    of its standard errors; sized with the estimate itself it read 1.30^2 on the first 30: ``E[q^2 / q_hat^2]``
    exceeds 1, which the size's posterior mean undoes), where the white-noise covariance does not (over 2.5):
    the walk moves the level differences the fit reads that parameter from."""
    t_s, own, jac, bread = _design()
    rng = np.random.default_rng(7)
    k = own.shape[1]
    q, ratio, naive = [], [], []
    for _ in range(60):
        data = rng.normal(size=(t_s.size, 2)) + _walk(rng, t_s, 2)
        x, weighted = _fit(jac, bread, data)
        walk = offset_walk(jac, weighted, t_s, bread)
        # the truth the offset refers to is the walk's mean over the rows: the level's truth is zero whatever it is
        at = [LEVEL, k + LEVEL]
        ratio.append(x[at] / np.sqrt(np.diag(walk.covariance)[at]))
        naive.append(x[at] / np.sqrt(np.diag(bread)[at]))
        q.append(walk.q_per_sqrt_s)
    square = np.square(ratio).ravel()
    assert np.sqrt(np.mean(np.square(naive))) > 2.5
    assert abs(np.mean(square) - 1.0) < 3.0 * np.std(square) / np.sqrt(square.size), np.mean(square)
    assert 0.7 < np.sqrt(np.mean(np.square(q))) / Q < 1.3


def test_white_noise_and_a_drift_the_fit_takes_whole_are_not_a_walk():
    """Without a walk the estimate is at zero about half the time and the covariance states only the walk the
    block sums cannot exclude (below the walk this design measures to 30 %, ``Q``); a drift in the fit's span (a
    quadratic in time, any size) changes nothing: the residual, the walk's size and the covariance are white
    noise's alone."""
    t_s, own, jac, bread = _design()
    rng = np.random.default_rng(11)
    stated, zero = [], 0
    for _ in range(12):
        noise = rng.normal(size=(t_s.size, 2))
        _, weighted = _fit(jac, bread, noise)
        walk = offset_walk(jac, weighted, t_s, bread)
        stated.append(walk.stated_q_per_sqrt_s)
        zero += int(np.sum(walk.q_per_sqrt_s == 0.0))
        drift = np.outer(own[:, 4] * 40.0 + own[:, 5] * 25.0, [1.0, -2.0])  # 25-80 noise sigmas
        _, drifted = _fit(jac, bread, noise + drift)
        other = offset_walk(jac, drifted, t_s, bread)
        np.testing.assert_allclose(other.q_per_sqrt_s, walk.q_per_sqrt_s, atol=1e-4 * Q)
        np.testing.assert_allclose(other.stated_q_per_sqrt_s, walk.stated_q_per_sqrt_s, rtol=1e-3)
        np.testing.assert_allclose(other.covariance, walk.covariance, rtol=1e-3,
                                   atol=1e-3 * np.max(np.diag(walk.covariance)))
    assert zero >= 6 and 0.0 < np.min(stated) and np.max(stated) < Q, (zero, np.min(stated), np.max(stated))


def test_the_stated_size_is_the_estimate_where_many_modes_hold_the_walk():
    """The size's posterior mean exceeds its estimate where few of the block sums' modes hold the walk (``Q``:
    median over 1.15) and is the estimate where many do (ten times the walk: within 5 %, the large-sample
    limit)."""
    t_s, own, jac, bread = _design()
    rng = np.random.default_rng(5)
    excess = {}
    for scale in (1.0, 10.0):
        walks = [offset_walk(jac, _fit(jac, bread, rng.normal(size=(t_s.size, 2)) + _walk(rng, t_s, 2, scale * Q))[1],
                             t_s, bread) for _ in range(6)]
        excess[scale] = np.concatenate([(w.stated_q_per_sqrt_s / w.q_per_sqrt_s) ** 2 for w in walks])
    assert np.median(excess[1.0]) > 1.15 and np.all(excess[10.0] < 1.05), excess


def test_the_posterior_mean_is_the_inverse_gamma_mean_far_above_the_floor():
    """Reference relation: a walk held in ``m`` modes each far above a unit floor (``mu`` 1e6) has the likelihood
    of a scaled chi-square with ``m`` degrees of freedom and Jeffreys' prior ``1 / t``, so the posterior mean of
    ``q^2`` is ``S / (m - 2)``, ``S = sum_i y_i^2 / mu_i``, where the estimate is ``S / m``."""
    from calibrate.diagnosis.walk import _posterior_mean_q2

    rng = np.random.default_rng(2)
    m, r = 6, 40
    basis = np.linalg.qr(rng.normal(size=(r, m)))[0]
    zeta = basis @ rng.normal(size=m) * 1e3 * np.sqrt(0.8) + rng.normal(size=r)  # q^2 = 0.8, mu = 1e6
    factor = basis * 1e3
    s = np.sum((basis.T @ zeta) ** 2) / 1e6
    mean = _posterior_mean_q2(zeta, [factor], 0.0, np.array([s / m]), 0)
    np.testing.assert_allclose(mean, s / (m - 2), rtol=1e-3)


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


@pytest.mark.parametrize("change, match", [
    (dict(t_s=np.arange(5.0)), "expected"),
    (dict(block_s=0.0), "block_s must be positive"),
    (dict(row_weight=-1.0), "row weights must be positive"),
])
def test_bad_input_is_refused(change, match):
    t_s, own, jac, bread = _design()
    weighted = np.zeros((t_s.size, 2))
    args = dict(jac=jac, weighted=weighted, t_s=t_s, bread=bread) | change
    with pytest.raises(ValueError, match=match):
        offset_walk(**args)
