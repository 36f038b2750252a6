"""The score test's chi-square drop, summed over chunks of rows, against the whole projected block at once
and against the drop a refit actually buys in a linear model (where the first order is exact)."""

import numpy as np
import pytest

from calibrate.diagnosis import evidence
from calibrate.diagnosis.evidence import SINGULAR_RCOND, linear_score, unit_columns


def _whole(j_b: np.ndarray, j_e: np.ndarray, r0: np.ndarray) -> tuple[float, np.ndarray]:
    """The score of the projected block formed over every row at once (the formula before chunking)."""
    absorbed, *_ = np.linalg.lstsq(j_b.T @ j_b, j_b.T @ j_e, rcond=SINGULAR_RCOND**2)
    j_tilde = j_e - j_b @ absorbed
    scale = np.linalg.norm(j_tilde, axis=0)
    scale[scale == 0] = 1.0
    w, v = np.linalg.eigh((j_tilde / scale).T @ (j_tilde / scale))
    keep = w > SINGULAR_RCOND**2 * max(w.max(), 1e-300)
    projected = (j_tilde / scale).T @ r0
    coef = (v[:, keep] / w[keep]) @ (v[:, keep].T @ projected)
    return float(projected @ coef), -coef / scale


def _linear_problem(n: int, seed: int):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, n)
    base = np.column_stack([np.ones(n), np.sin(7 * t), t])
    extra = np.column_stack([t * t, np.cos(3 * t), np.zeros(n)])  # a dead column: dropped, left at its start
    y = base @ [1.0, 0.5, -2.0] + extra @ [0.8, -0.3, 0.0] + rng.normal(scale=0.1, size=n)
    return base, extra, y


@pytest.mark.parametrize("chunk_rows", [7, 1000, 10**6])
def test_chunked_score_equals_the_whole_block(monkeypatch, chunk_rows):
    base, extra, y = _linear_problem(2500, seed=3)
    x_b, *_ = np.linalg.lstsq(base, y, rcond=None)
    j_b, j_e = unit_columns(-base), -extra
    residual = lambda p: y - np.column_stack([base, extra]) @ p  # noqa: E731
    x = np.concatenate([x_b, np.zeros(3)])
    r0 = residual(x)
    monkeypatch.setattr(evidence, "SCORE_CHUNK_ROWS", chunk_rows)
    drop, step = linear_score(residual, x, 3, j_b, block_jacobian=j_e)
    given = linear_score(residual, x, 3, j_b, block_jacobian=j_e, r0=r0, normal_b=j_b.T @ j_b)
    whole_drop, whole_step = _whole(j_b, j_e, r0)
    np.testing.assert_allclose([drop, given[0]], whole_drop, rtol=1e-12)
    np.testing.assert_allclose(step, whole_step, rtol=1e-10, atol=1e-13)
    np.testing.assert_array_equal(given[1], step)
    assert step[2] == 0.0  # the dead column carries no evidence and stays where it was


def test_score_is_the_refits_drop_in_a_linear_model():
    """In a linear model the score's drop is exactly what the refit removes from the chi-square."""
    base, extra, y = _linear_problem(3000, seed=4)
    x_b, *_ = np.linalg.lstsq(base, y, rcond=None)
    r0 = y - base @ x_b
    drop, _ = linear_score(lambda p: y - np.column_stack([base, extra]) @ p, np.concatenate([x_b, np.zeros(3)]), 3,
                           unit_columns(-base), block_jacobian=-extra)
    both = np.column_stack([base, extra[:, :2]])
    x_all, *_ = np.linalg.lstsq(both, y, rcond=None)
    r1 = y - both @ x_all
    np.testing.assert_allclose(drop, r0 @ r0 - r1 @ r1, rtol=1e-9)
    assert drop > 100 * 0.1**2  # the added columns explain far more than the noise's share
