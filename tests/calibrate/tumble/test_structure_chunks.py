"""The tumble's structure regression, summed in chunks, equals the least squares on the whole design."""

import numpy as np

from calibrate.tumble import diagnosis
from calibrate.tumble.diagnosis import _structure_design, residual_structure


def test_chunked_structure_regression_matches_whole_design_least_squares(monkeypatch):
    rng = np.random.default_rng(3)
    n = 5000
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    weighted = rng.normal(size=n) + 0.3 * directions[:, 0] ** 3
    bands = [np.arange(n, dtype=float), rng.normal(size=n)]
    monkeypatch.setattr(diagnosis, "_STRUCTURE_CHUNK_ROWS", 700)  # several chunks, the last one short
    drop, rank, _ = residual_structure(weighted, directions, bands)
    n_blocks = diagnosis.STRUCTURE_BLOCKS
    blocks = [np.argsort(np.argsort(key, kind="stable")) * n_blocks // n for key in bands]
    design = _structure_design(directions, blocks, n_blocks)
    coef, _, rank_whole, _ = np.linalg.lstsq(design, weighted, rcond=None)
    # the unit-sphere identities (x^2 + y^2 + z^2 = 1) and the blocks summing to a constant make the
    # design rank deficient: both must see the same rank
    assert rank == rank_whole < design.shape[1]
    # chi-square drops of order rank (~80) agree to rounding (eps times the condition of the kept part)
    assert abs(drop - float(np.sum((design @ coef) ** 2))) < 1e-8 * max(drop, 1.0)
