"""What an unexplained residual costs: a covariance that covers it, in the units a user reads.

When structure remains that no effect explains (SPEC section 4, ``unexplained: true``), the fit's
covariance ``(J^T J)^-1 chi2/dof`` assumes residuals independent from sample to sample: a smooth
structure, correlated over many samples, moves the parameters far more than that says.

Derivation.  Write the weighted residual as ``r = e + s``: white noise ``e`` at the floor and a
structure ``s`` the model lacks.  To first order the fitted parameters move by
``dx = (J^T J)^-1 J^T (e + s)``; the part of ``s`` in the span of ``J`` is absorbed (it moved the
parameters and left the residual), the rest is what the residual shows.  Taking ``s`` as a
realisation of a process whose correlation is local in the recording's natural order (the
turntable angle within a flip: neighbouring samples see nearly the same field, so an unmodelled
effect of the field or of time is nearly the same there) and whose absorbed part is like the part
that shows, the covariance of ``dx`` is the sandwich

.. math:: V = H^{-1} \\Big( \\frac{G}{G-1} \\sum_g s_g s_g^T \\Big) H^{-1}, \\qquad
          s_g = \\sum_{i \\in g} J_i^T r_i, \\qquad H = J^T J,

with clusters ``g`` longer than the structure's correlation and short enough to be several (half
a turn of one flip for the four-flip: 8 clusters): the cluster-robust (batch-means)
estimate of ``var(J^T r)`` with the small-sample factor ``G/(G-1)``.  With white noise alone,
``E[sum_g s_g s_g^T] = H``: ``V`` is the naive covariance.  The file takes the larger of the two
in every direction of parameter space (:func:`widened`), so a widened sigma never shrinks.

Its limit: structure that the model absorbs whole (e.g. a constant tilt of the turntable axis
per flip) leaves nothing in the residual to measure; no residual-based bound sees it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cluster_covariance", "widened", "extra_sigma", "heading_sigma_deg"]


def cluster_covariance(jac: np.ndarray, weighted: np.ndarray, clusters: np.ndarray,
                       bread: np.ndarray) -> np.ndarray:
    """Cluster-robust (sandwich) covariance of a least-squares fit's parameters.

    Parameters
    ----------
    jac : ndarray, shape (m, k)
        Jacobian of the weighted residual at the solution.
    weighted : ndarray, shape (m,)
        The weighted residual (over the noise floor, so white noise has unit variance).
    clusters : ndarray of int, shape (m,)
        The cluster of each residual row.
    bread : ndarray, shape (k, k)
        ``(J^T J)^-1`` (NaN rows and columns for what the data cannot determine).

    Returns
    -------
    ndarray, shape (k, k)
        ``bread meat bread`` with the meat of the module docstring; NaN where ``bread`` is.

    Raises
    ------
    ValueError
        Fewer than two clusters, or mismatched shapes.
    """
    jac = np.asarray(jac, dtype=float)
    if jac.shape[0] != weighted.size or clusters.size != weighted.size:
        raise ValueError(f"expected {jac.shape[0]} residuals and clusters, got {weighted.size} and {clusters.size}")
    _, index = np.unique(clusters, return_inverse=True)
    groups = int(index.max()) + 1
    if groups < 2:
        raise ValueError("a cluster-robust covariance needs at least two clusters")
    contributions = np.nan_to_num(jac) * weighted[:, None]
    sums = np.zeros((groups, jac.shape[1]))
    np.add.at(sums, index.ravel(), contributions)
    meat = sums.T @ sums * (groups / (groups - 1))
    undetermined = ~np.isfinite(np.diag(bread))
    b = np.nan_to_num(bread)
    out = b @ meat @ b
    out[undetermined, :] = np.nan
    out[:, undetermined] = np.nan
    return out


def widened(naive: np.ndarray, robust: np.ndarray) -> np.ndarray:
    """The naive covariance grown to the robust one where that is larger: ``naive + max(robust - naive, 0)``.

    The difference's negative eigenvalues are dropped, so the result is positive semi-definite and
    at least ``naive`` in every direction.  NaN rows and columns of ``naive`` stay NaN.
    """
    bad = ~np.isfinite(np.diag(naive))
    good = ~bad
    out = np.array(naive, dtype=float, copy=True)
    diff = robust[np.ix_(good, good)] - naive[np.ix_(good, good)]
    w, v = np.linalg.eigh(0.5 * (diff + diff.T))
    out[np.ix_(good, good)] += (v * np.maximum(w, 0.0)) @ v.T
    return out


def extra_sigma(wide: np.ndarray, naive: np.ndarray) -> np.ndarray:
    """``sqrt(wide^2 - naive^2)`` elementwise (the part of a widened sigma the structure adds), NaN kept."""
    return np.sqrt(np.maximum(np.asarray(wide) ** 2 - np.asarray(naive) ** 2, 0.0))


def heading_sigma_deg(directions: np.ndarray, direction_covariance: np.ndarray, response_var: np.ndarray,
                      gains: np.ndarray, dip_deg: float, field_norm: float, n_headings: int = 72) -> float:
    """RMS heading sigma of a level housing over every heading, from the calibration's uncertainty alone.

    The runtime solves the field ``m = P x`` from each channel's component ``x_c = B_H . a_c``
    (``P`` the pseudo-inverse of the directions); an error ``dx_c`` of a component turns the
    heading by ``(e_perp . P_c) dx_c / |B_h|``, ``e_perp`` the horizontal unit vector across the
    horizontal field.  Per channel ``var(dx_c) = B^T Sigma_a B + (var V0 + x^2 var K) / K^2``
    (the terms of :meth:`compass.model.SensorModel.component_variance`); the noise of one sample
    is left out (it averages down at runtime, the calibration's error does not).

    Parameters
    ----------
    directions : ndarray, shape (c, 3)
        Unit sensing directions in H.
    direction_covariance : ndarray, shape (c, 3, 3)
        rad^2.
    response_var : ndarray, shape (c, 2)
        Variances of each channel's offset and gain (output units^2, (output units per field unit)^2).
    gains : ndarray, shape (c,)
        Output units per field unit.
    dip_deg : float
        The field's dip.
    field_norm : float
        |B| in the gains' field unit.
    n_headings : int
        Headings averaged over.

    Returns
    -------
    float
        Degrees.
    """
    psi = np.linspace(0.0, 2 * np.pi, n_headings, endpoint=False)
    dip = np.radians(dip_deg)
    b = field_norm * np.column_stack([np.cos(dip) * np.cos(psi), -np.cos(dip) * np.sin(psi),
                                           np.full_like(psi, -np.sin(dip))])
    across = np.column_stack([np.sin(psi), np.cos(psi), np.zeros_like(psi)])  # horizontal, perpendicular to b's
    solver = np.linalg.pinv(directions)  # (3, c): m = solver @ x
    x = b @ directions.T  # (h, c)
    var = (np.einsum("hi,cij,hj->hc", b, np.nan_to_num(direction_covariance), b)
           + (np.nan_to_num(response_var[:, 0]) + x**2 * np.nan_to_num(response_var[:, 1])) / gains**2)
    lever = (across @ solver) ** 2  # (h, c)
    return float(np.degrees(np.sqrt(np.mean(np.sum(lever * var, axis=1))) / (field_norm * np.cos(dip))))
