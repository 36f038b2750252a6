"""Geometry helpers of compass/frames.py."""

import numpy as np

from compass.frames import row_norms


def test_row_norms_are_numpys_to_rounding():
    """``row_norms`` against ``np.linalg.norm(axis=1)``: within an ulp or two over magnitudes from 1e-150 to 1e150."""
    rng = np.random.default_rng(9)
    v = rng.normal(size=(2000, 3)) * 10.0 ** rng.uniform(-150, 150, size=(2000, 1))
    np.testing.assert_allclose(row_norms(v), np.linalg.norm(v, axis=1), rtol=4e-16, atol=0)
    assert row_norms(np.zeros((3, 3))).tolist() == [0.0, 0.0, 0.0]
