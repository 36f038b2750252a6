"""Blocks of time as the clusters of the unexplained widening."""

import numpy as np
import pytest

from calibrate.diagnosis.blocks import time_blocks, widened_in_time


def test_time_blocks_are_runs_of_equal_count_along_time():
    t_s = np.random.default_rng(0).permutation(np.arange(80.0))
    blocks = time_blocks(t_s, 8)
    assert np.bincount(blocks).tolist() == [10] * 8
    assert np.all(np.diff(blocks[np.argsort(t_s)]) >= 0)


@pytest.mark.parametrize("order, n_blocks", [(np.arange(10.0), 1), (np.arange(1.0), 8)])
def test_time_blocks_refuse_too_few(order, n_blocks):
    with pytest.raises(ValueError, match="at least 2 blocks and 2 samples"):
        time_blocks(order, n_blocks)


def test_white_noise_keeps_the_naive_covariance_on_average_and_structure_widens_it():
    rng = np.random.default_rng(1)
    n = 800
    t = np.linspace(-1, 1, n)
    jac = np.column_stack([np.ones(n), np.cos(9 * t)])
    bread = np.linalg.inv(jac.T @ jac)
    blocks = time_blocks(t)
    ratios = []
    for _ in range(200):
        r = rng.normal(size=n)
        r -= jac @ (bread @ (jac.T @ r))  # the residual a fit leaves
        ratios.append(widened_in_time(jac, r, blocks, bread)[0, 0] / bread[0, 0])
    assert np.mean(ratios) < 1.6  # never below 1 (widening only), near it without structure
    slow = rng.normal(size=n) + 3.0 * np.repeat(rng.normal(size=8), n // 8)  # a level per stretch of time
    slow -= jac @ (bread @ (jac.T @ slow))
    assert widened_in_time(jac, slow, blocks, bread)[0, 0] > 3.0 * bread[0, 0]


def test_level_heading_sigma_against_monte_carlo():
    from calibrate.diagnosis.blocks import level_heading_sigma_deg

    rng = np.random.default_rng(2)
    psi = rng.uniform(0, 2 * np.pi, 20000)
    dh = rng.normal(size=(20000, 2)) * [0.3, 0.1]
    b_h = 50.0 * np.cos(np.radians(60.0))
    field = b_h * np.column_stack([np.cos(psi), -np.sin(psi)])
    read = field - dh
    turned = np.degrees(np.angle((read[:, 0] - 1j * read[:, 1]) * np.exp(-1j * psi)))
    assert level_heading_sigma_deg(0.3, 0.1, 50.0, 60.0) == pytest.approx(np.sqrt(np.mean(turned**2)), rel=0.03)


def test_an_undetermined_fit_is_left_as_it_was():
    naive = np.full((2, 2), np.inf)
    out = widened_in_time(np.ones((10, 2)), np.ones(10), time_blocks(np.arange(10.0)), naive)
    assert np.all(np.isinf(out))
