"""What an unexplained residual costs: the cluster-robust covariance, its widening, the heading it costs."""

import numpy as np
import pytest

from calibrate.diagnosis.robust import cluster_covariance, extra_sigma, heading_sigma_deg, widened


def _line_fit(rng, structure):
    """y = a + b t + white noise + ``structure(t)``, a = 1, b = 0.5: t, the fit's Jacobian, weighted
    residual, bread and parameter error."""
    t = np.linspace(-1.0, 1.0, 400)
    jac = np.column_stack([np.ones_like(t), t])
    y = 1.0 + 0.5 * t + rng.normal(size=t.size) + structure(t)
    x, *_ = np.linalg.lstsq(jac, y, rcond=None)
    return t, jac, y - jac @ x, np.linalg.inv(jac.T @ jac), x - [1.0, 0.5]


def test_white_noise_gives_the_naive_covariance_on_average():
    rng = np.random.default_rng(0)
    ratios = []
    for _ in range(200):
        t, jac, r, bread, _ = _line_fit(rng, lambda t: 0.0)
        clusters = np.floor((t + 1.0) * 8).astype(int)  # 16 clusters
        ratios.append(np.diag(cluster_covariance(-jac, r, clusters, bread)) / np.diag(bread))
    # E[meat] = H (G/(G-1) offsets the cluster sums' lost dof): ratio 1 within its Monte Carlo error
    assert np.mean(ratios, axis=0) == pytest.approx([1.0, 1.0], abs=0.1)


def test_correlated_structure_widens_what_it_moves():
    """A structure correlated over a sixteenth of the record moves the slope more than white noise says."""
    rng = np.random.default_rng(1)
    errors, sigmas = [], []
    for _ in range(200):
        wiggle = rng.normal(size=16)
        t, jac, r, bread, error = _line_fit(rng, lambda t: 1.5 * wiggle[np.minimum((t + 1.0) * 8, 15).astype(int)])
        clusters = np.floor((t + 1.0) * 4).astype(int)  # clusters longer than the structure's correlation
        cov = widened(bread, cluster_covariance(-jac, r, clusters, bread))
        assert np.all(np.linalg.eigvalsh(cov - bread) > -1e-12)
        sigmas.append(np.sqrt(np.diag(cov)))
        errors.append(error)
    honest = np.sqrt(np.mean(np.square(errors), axis=0)) / np.sqrt(np.mean(np.square(sigmas), axis=0))
    naive = np.sqrt(np.mean(np.square(errors), axis=0)) / np.sqrt(np.diag(bread))
    assert np.all(naive > 2.0)  # what the naive covariance would claim
    assert np.all((honest > 0.7) & (honest < 1.4)), honest


def test_bad_clusters_are_refused():
    with pytest.raises(ValueError, match="at least two clusters"):
        cluster_covariance(np.ones((4, 1)), np.ones(4), np.zeros(4, dtype=int), np.eye(1))
    with pytest.raises(ValueError, match="expected 4 residuals"):
        cluster_covariance(np.ones((4, 1)), np.ones(3), np.zeros(3, dtype=int), np.eye(1))


def test_widened_keeps_undetermined_and_never_shrinks():
    naive = np.diag([1.0, np.nan, 2.0])
    naive[1, :] = naive[:, 1] = np.nan
    robust = np.diag([0.5, 7.0, 5.0])
    out = widened(naive, robust)
    assert np.isnan(out[1, 1]) and out[0, 0] == pytest.approx(1.0) and out[2, 2] == pytest.approx(5.0)
    assert extra_sigma(np.array([5.0, 1.0]), np.array([3.0, 2.0])) == pytest.approx([4.0, 0.0])


def test_heading_sigma_of_one_tilted_direction():
    """A triad along the axes, only X's direction uncertain (s rad, toward Y): RMS heading sigma s sqrt(3/8).

    At heading psi the field in H is ``|B| (cos(dip) cos(psi), -cos(dip) sin(psi), -sin(dip))``; X's error
    ``e y`` adds ``-e |B| cos(dip) sin(psi)`` to the X component, which turns the heading by ``-e sin^2(psi)``
    (the across-field direction is ``(sin psi, cos psi, 0)``): RMS ``s sqrt(mean sin^4) = s sqrt(3/8)``.
    """
    s = 1e-3
    cov = np.zeros((3, 3, 3))
    cov[0, 1, 1] = s**2  # X's direction moves toward Y
    got = heading_sigma_deg(np.eye(3), cov, np.zeros((3, 2)), np.ones(3), dip_deg=60.0, field_norm=50.0)
    assert got == pytest.approx(np.degrees(s * np.sqrt(3.0 / 8.0)), rel=1e-6)
