"""The unexplained-residual widening for kinds without flips: clusters that are stretches of time.

:func:`calibrate.diagnosis.robust.cluster_covariance` takes the clusters from the kind's physics.
A four-flip's are its flips (one mounting, one stretch of time).  A tumble, a swing or an
installation tumble has no flips: the device is turned by hand through every orientation, and
what the model lacks there (the local field wandering as something iron moves nearby, a hard
iron walking with the board's temperature, a gain drifting as the room warms) is a function of
*time*, nearly the same from one sample to the next and less alike the further apart they are.
The clusters are therefore :data:`TIME_BLOCKS` blocks of consecutive samples of equal count:
within a block an unmodelled slow effect moves the parameters one way, between blocks it is
taken as independent (for a wander over the whole session it is not quite: the widening then
errs low, which the benchmark measures, ``tools/bench_kinds_loop.py``).

The number of blocks trades two errors.  Few blocks keep each block's share of a slow structure
whole (the independence assumption holds better) but leave the meat a sum of few terms (a noisy
variance: with G blocks it has about G - k_eff degrees of freedom); many blocks cut a slow
structure into pieces whose correlation the sandwich then ignores.  Eight is also the tumble's residual
structure test's blocking (its ``STRUCTURE_BLOCKS`` is this constant): the stretch of time over which
the verdict already looked for a changed hard iron or field.
"""

from __future__ import annotations

import numpy as np

from .robust import cluster_covariance, widened

__all__ = ["TIME_BLOCKS", "time_blocks", "widened_in_time", "level_heading_sigma_deg"]

TIME_BLOCKS = 8
"""Blocks of consecutive samples that are the clusters of the widening."""


def time_blocks(order: np.ndarray, n_blocks: int = TIME_BLOCKS) -> np.ndarray:
    """The block of each sample: ``n_blocks`` runs of equal count along ``order`` (``t_s`` or the row index).

    Parameters
    ----------
    order : ndarray, shape (n,)
        Time of each sample, s (or any key that orders them in time).
    n_blocks : int
        Blocks (at least 2; fewer when there are fewer samples).

    Returns
    -------
    ndarray of int, shape (n,)

    Raises
    ------
    ValueError
        ``n_blocks`` under 2, or fewer than 2 samples.
    """
    order = np.asarray(order, dtype=float)
    if n_blocks < 2 or order.size < 2:
        raise ValueError(f"time blocks need at least 2 blocks and 2 samples, got {n_blocks} and {order.size}")
    n = order.size
    return np.argsort(np.argsort(order, kind="stable"), kind="stable") * min(n_blocks, n) // n


def widened_in_time(jac: np.ndarray, weighted: np.ndarray, blocks: np.ndarray, naive: np.ndarray,
                    bread: np.ndarray | None = None) -> np.ndarray:
    """The naive covariance widened by the CR2 sandwich over blocks of time, where that is larger.

    Parameters
    ----------
    jac : ndarray, shape (m, k)
        Jacobian of the weighted residual at the solution (rows of the data only, no priors).
    weighted : ndarray, shape (m,)
        The weighted residual (white noise at the floor has unit variance).
    blocks : ndarray of int, shape (m,)
        The block of each row (:func:`time_blocks`; rows of one sample share its block).
    naive : ndarray, shape (k, k)
        The fit's covariance (non-finite where the data do not determine a parameter: kept so).
    bread : ndarray, shape (k, k), optional
        ``(J^T J)^-1`` of the whole fit (default from ``jac``; give it when the fit has rows beyond
        ``jac``'s, such as priors, that inform the parameters but carry no structure).

    Returns
    -------
    ndarray, shape (k, k)
        ``naive`` grown to the sandwich (:func:`calibrate.diagnosis.robust.widened`), in the
        parameters' units.
    """
    jac = np.asarray(jac, dtype=float)
    good = np.isfinite(np.diag(naive))
    if not good.any():  # nothing determined: nothing to widen
        return np.array(naive, dtype=float, copy=True)
    if bread is None:
        bread = np.full(naive.shape, np.nan)
        j = jac[:, good]
        bread[np.ix_(good, good)] = np.linalg.pinv(j.T @ j)
    else:
        bread = np.where(np.outer(good, good), bread, np.nan)
    robust = cluster_covariance(jac, np.asarray(weighted, dtype=float), np.asarray(blocks), bread)
    out = np.array(naive, dtype=float, copy=True)
    out[np.ix_(good, good)] = widened(naive[np.ix_(good, good)], robust[np.ix_(good, good)])
    return out


def level_heading_sigma_deg(sigma_x: float, sigma_y: float, field_norm: float, dip_deg: float) -> float:
    """RMS heading sigma of a level housing over every heading from a hard iron's horizontal sigmas.

    A hard-iron error ``dh`` adds ``-dh`` to the field read; at heading ``psi`` the heading turns by
    the part across the horizontal field, ``(sin psi, cos psi) . dh_xy / B_h``, ``B_h = |B| cos(dip)``;
    averaged over ``psi`` its variance is ``(sigma_x^2 + sigma_y^2) / (2 B_h^2)``.

    Parameters
    ----------
    sigma_x, sigma_y : float
        The hard iron's sigma along the housing's x and y (level: horizontal), field units.
    field_norm : float
        |B| in the same units.
    dip_deg : float
        The field's dip.

    Returns
    -------
    float
        Degrees.
    """
    horizontal = field_norm * np.cos(np.radians(dip_deg))
    return float(np.degrees(np.sqrt(0.5 * (sigma_x**2 + sigma_y**2)) / horizontal))
