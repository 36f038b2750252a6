"""Sphere coverage: the k-d tree's nearest cells are the cells of the largest dot product, and faces never seen are named."""

import numpy as np
import pytest

from calibrate.tumble.coverage import _N_CELLS, sphere_coverage
from compass.frames import sphere_cells


def _brute_force_fraction(directions):
    u = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    return np.unique(np.argmax(u @ sphere_cells(_N_CELLS).T, axis=1)).size / _N_CELLS


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_fraction_is_the_brute_force_one(seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(3000, 3)) * [1.0, 3.0, 0.3] * 50.0  # unequal axes: some cells empty, scale arbitrary
    cov = sphere_coverage(d)
    assert 0.0 < cov.fraction < 1.0
    assert cov.fraction == _brute_force_fraction(d)


def test_upper_hemisphere_misses_minus_z_and_half_the_cells():
    rng = np.random.default_rng(4)
    d = rng.normal(size=(20000, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.8  # the field never within 45 deg of -Z
    cov = sphere_coverage(d)
    assert cov.missing == ["-Z"]
    assert cov.fraction == _brute_force_fraction(d) and cov.fraction < 0.5


@pytest.mark.parametrize("bound_of_spacing", [0.75, 0.05])
def test_bounded_search_gives_every_sample_its_nearest_cell(monkeypatch, bound_of_spacing):
    """The search bounded near the cells' spacing (a tight bound leaves most samples to the unbounded lookup)
    finds the cells the unbounded nearest-centre search finds: the same fraction covered."""
    from scipy.spatial import cKDTree

    from calibrate.tumble import coverage
    from compass.frames import sphere_cells

    rng = np.random.default_rng(8)
    u = rng.normal(size=(5000, 3)) * [1.0, 1.0, 0.2] + [0.0, 0.0, 0.6]  # a belt and a cap: part of the sphere
    monkeypatch.setattr(coverage, "_BOUND_OF_SPACING", bound_of_spacing)
    unit = u / np.linalg.norm(u, axis=1, keepdims=True)
    hit = np.unique(cKDTree(sphere_cells(coverage._N_CELLS)).query(unit)[1])
    got = coverage.sphere_coverage(u)
    assert got.fraction == len(hit) / coverage._N_CELLS < 1.0
