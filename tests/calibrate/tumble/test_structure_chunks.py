"""The tumble's structure regression, summed in chunks, equals the least squares on the whole design."""

import numpy as np
import pytest

from calibrate.tumble import diagnosis
from calibrate.tumble.diagnosis import _structure_design, residual_structure


def _whole_design_fit(weighted, directions, bands):
    """The structure regression on the whole design at once: ``(design, coefficients, rank)``."""
    n, n_blocks = len(weighted), diagnosis.STRUCTURE_BLOCKS
    blocks = [np.argsort(np.argsort(key, kind="stable")) * n_blocks // n for key in bands]
    design = _structure_design(directions, blocks, n_blocks)
    coef, _, rank, _ = np.linalg.lstsq(design, weighted, rcond=None)
    return design, coef, rank


def test_chunked_structure_regression_matches_whole_design_least_squares(monkeypatch):
    rng = np.random.default_rng(3)
    n = 5000
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    weighted = rng.normal(size=n) + 0.3 * directions[:, 0] ** 3
    bands = [np.arange(n, dtype=float), rng.normal(size=n)]
    monkeypatch.setattr(diagnosis, "_STRUCTURE_CHUNK_ROWS", 700)  # several chunks, the last one short
    drop, rank, _ = residual_structure(weighted, directions, bands)
    design, coef, rank_whole = _whole_design_fit(weighted, directions, bands)
    # the unit-sphere identities (x^2 + y^2 + z^2 = 1) and the blocks summing to a constant make the
    # design rank deficient: both must see the same rank
    assert rank == rank_whole < design.shape[1]
    # chi-square drops of order rank (~80) agree to rounding (eps times the condition of the kept part)
    assert abs(drop - float(np.sum((design @ coef) ** 2))) < 1e-8 * max(drop, 1.0)


@pytest.mark.parametrize("with_temperature", [False, True])
def test_chunks_within_a_few_blocks_still_give_the_whole_design_least_squares(monkeypatch, with_temperature):
    """Time (and a temperature that rises and falls with it): most chunks lie in a few blocks and update only
    their rows of R; a temperature block seen before with a time block is reached through R."""
    rng = np.random.default_rng(4)
    n = 6000
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    t_s = np.arange(n, dtype=float)
    bands = [t_s] + ([np.sin(3.0 * np.pi * t_s / n) + 0.05 * rng.normal(size=n)] if with_temperature else [])
    weighted = rng.normal(size=n) + 0.5 * (t_s > 2500) * directions[:, 1]  # a change partway: block structure
    monkeypatch.setattr(diagnosis, "_STRUCTURE_CHUNK_ROWS", 400)  # blocks of 750 rows: chunks within and across
    drop, rank, p_value = residual_structure(weighted, directions, bands)
    design, coef, rank_whole = _whole_design_fit(weighted, directions, bands)
    assert rank == rank_whole < design.shape[1]
    assert abs(drop - float(np.sum((design @ coef) ** 2))) < 1e-8 * drop
    assert p_value < 1e-6  # the change is found


def test_design_columns_are_the_block_terms_then_the_monomials():
    """The design written by its definition, column by column: for each band and block ``1, x, y, z`` on the
    block's rows (zero elsewhere), then ``prod(d[:, idx])`` of every cubic and quartic monomial; ``extra`` last."""
    from itertools import combinations_with_replacement

    rng = np.random.default_rng(6)
    n, n_blocks = 300, 4
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    blocks = [np.repeat(np.arange(n_blocks), n // n_blocks), rng.integers(0, n_blocks, size=n)]
    blocks[0][:20] = 2  # a block seen in two places
    local = np.column_stack([np.ones(n), directions])
    expected = [np.where(block == b, local[:, j], 0.0) for block in blocks for b in range(n_blocks) for j in range(4)]
    expected += [np.prod(directions[:, list(idx)], axis=1)
                 for degree in (3, 4) for idx in combinations_with_replacement(range(3), degree)]
    extra = rng.normal(size=n)
    design = _structure_design(directions, blocks, n_blocks, extra)
    np.testing.assert_array_equal(design, np.column_stack(expected + [extra]))
    np.testing.assert_array_equal(_structure_design(directions[:7], [b[:7] for b in blocks], n_blocks),
                                  np.column_stack(expected)[:7])
