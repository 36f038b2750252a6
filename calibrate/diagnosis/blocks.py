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

A hard iron that walks (the sensor's offsets moving with its temperature) is a process in the
parameters, not in the residual, and is widened by its own model where the kind names the hard
iron's columns (``hard`` of :func:`widened_in_time`).  With the walk about constant within each
block, ``u_b`` (field units, the same for every row of block ``b``), it adds ``J_h u_b`` to the
block's residual (``J_h`` the hard iron's columns of the Jacobian) and moves the fit by
``sum_b B H_bh u_b`` (``B`` the bread, ``H_bh = J_b^T J_bh`` the block's share of the information
about the hard iron).  The estimand is the session's mean hard iron, ``sum_b (n_b / N) u_b``, so the
error is ``sum_b A_b u_b`` with ``A_b = B H_bh - (n_b / N) B H_h`` (``H_h = sum_b H_bh``; without
priors ``B H_h`` is the identity on the hard iron's columns).  ``sum_b A_b = 0``: a level common to
every block costs nothing, so only the walk's spread between blocks enters.  Taking the blocks'
levels as independent draws of one covariance ``V``, the walk's covariance is
``sum_b A_b V A_b^T``.  The limits: where the orientations do not follow time (a random one every
row) each block carries its count's share of the information, ``H_bh = (n_b / N) H_h``, and
``A_b = 0``: the walk averages out of the fit and nothing is added; where one block alone sees
some orientations, ``B H_bh`` is the identity along them and the others' shares vanish, so that
block's level moves the fit by ``(1 - n_b / N) u_b``, about as CR2 counts it (CR2's
``(I - P_gg)^{-1/2}`` restores it whole).  ``V`` is read from the residual by refitting it with a
hard-iron level per block beside the fit's own columns (what the fit absorbed of each level comes
back: the regression holds every column the fit has), the last block's level held at zero (the
common part is the fit's hard iron), taking the levels' spread about their mean less what the
noise alone gives it (the regression's covariance), over ``G - 3`` rather than ``G - 1``: the spread
has ``G - 1`` degrees of freedom, ``E[1 / V^] = (G - 1) / ((G - 3) V)``, and it is ``err^2 / sigma^2``
that should be one on average.  What the block levels do not explain is left in that
regression's residual and widened by CR2 as before; the two add.

A structure that is not a walk can put part of itself into the hard iron's levels: a field
wandering in the world frame shifts a tumble's radial residual by ``B^ . dB(t)``, the same for every
row of a block whatever the orientation; a gain drifting scales it.  Their competitor is a level
per block of each sort of row (``row_sort``: the installation's |B|, angle and heading rows), the
last block's held at zero too (a tumble's residual ``|L z| - F`` lies in the span of the fit's
columns and a constant, ``L z`` being homogeneous of degree one in the shape parameters).  The walk
model is used where the hard iron's levels leave a smaller residual than the sorts' levels do
(each refitted with the fit's columns; the same as: they explain more beyond the sorts' levels
than those explain beyond them); elsewhere the widening is CR2's alone, as it was.  Where the
two are collinear (a swing within a few degrees of level: a block's hard-iron level is nearly a
constant) the rule may take either, and either widening then counts the same block levels.
"""

from __future__ import annotations

import numpy as np

from .robust import cluster_covariance, widened

__all__ = ["TIME_BLOCKS", "time_blocks", "widened_in_time", "level_heading_sigma_deg"]

TIME_BLOCKS = 8
"""Blocks of consecutive samples that are the clusters of the widening."""

COLLINEAR = 1e-9
"""Relative singular value under which a combination of the walk's regression is not determined
(the blocks' levels of each sort sum to a constant the fit may hold already)."""


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
                    bread: np.ndarray | None = None, hard=None, row_sort=None) -> np.ndarray:
    """The naive covariance widened by the CR2 sandwich over blocks of time, where that is larger.

    With ``hard`` the hard iron's walk between blocks is taken out of the residual first and
    propagated as a process in the parameters (the module docstring); CR2 widens for the rest.

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
    hard : sequence of int, optional
        The columns of ``jac`` that are the hard iron (a constant offset of the reading); None:
        CR2 alone, as for a kind that does not say.
    row_sort : ndarray of int, shape (m,), optional
        The sort of each row (the installation's |B|, angle and heading rows; default: one sort):
        a level per block of each sort competes with the hard iron's levels (module docstring).

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
    weighted, blocks = np.asarray(weighted, dtype=float), np.asarray(blocks)
    walk = np.zeros(naive.shape)
    if hard is not None and np.all(good[np.asarray(hard)]):
        sort = np.zeros(weighted.size, dtype=int) if row_sort is None else np.asarray(row_sort)
        split = _walk_split(jac[:, good], weighted, blocks, bread[np.ix_(good, good)],
                            np.flatnonzero(good).searchsorted(hard), sort)
        if split is not None:
            weighted, walk[np.ix_(good, good)] = split
    robust = cluster_covariance(jac, weighted, blocks, bread)
    out = np.array(naive, dtype=float, copy=True)
    out[np.ix_(good, good)] = widened(naive[np.ix_(good, good)], robust[np.ix_(good, good)]) + walk[np.ix_(good, good)]
    return out


def _block_levels(jac: np.ndarray, weighted: np.ndarray, index: np.ndarray,
                  hard: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The residual refitted on the fit's columns and a hard-iron level per block but the last.

    Returns the levels, shape (G, h) (the last zero: their common part is the fit's hard iron), their
    covariance under unit white noise, shape ((G - 1) h, (G - 1) h), and the refit's residual sum of
    squares.  Built from per-block sums (no (m, G h) design is held).
    """
    n_blocks, h = index.max() + 1, len(hard)
    top = jac.shape[1]
    size = top + h * (n_blocks - 1)
    normal, score = np.zeros((size, size)), np.zeros(size)
    normal[:top, :top], score[:top] = jac.T @ jac, jac.T @ weighted
    for b in range(n_blocks - 1):
        rows, cols = index == b, slice(top + h * b, top + h * (b + 1))
        jh = jac[rows][:, hard]
        normal[:top, cols] = jac[rows].T @ jh
        normal[cols, :top] = normal[:top, cols].T
        normal[cols, cols] = jh.T @ jh
        score[cols] = jh.T @ weighted[rows]
    scale = 1.0 / np.sqrt(np.maximum(np.diag(normal), np.finfo(float).tiny))  # columns of unit norm
    inverse = scale[:, None] * np.linalg.pinv(normal * np.outer(scale, scale), rcond=COLLINEAR, hermitian=True) * scale
    beta = inverse @ score
    levels = np.vstack([beta[top:].reshape(n_blocks - 1, h), np.zeros(h)])
    return levels, inverse[top:, top:], float(weighted @ weighted - score @ beta)


def _stepped_rss(jac: np.ndarray, weighted: np.ndarray, step: np.ndarray, n_steps: int) -> float:
    """Residual sum of squares of ``weighted`` refitted on the fit's columns and a level per step (each row's
    ``step``; the steps from ``n_steps`` on held at zero), from per-step sums (no (m, steps) design is held)."""
    top = jac.shape[1]
    kept = step < n_steps
    normal, score = np.zeros((top + n_steps, top + n_steps)), np.zeros(top + n_steps)
    normal[:top, :top], score[:top] = jac.T @ jac, jac.T @ weighted
    sums = np.zeros((n_steps, top))
    np.add.at(sums, step[kept], jac[kept])
    normal[top:, :top], normal[:top, top:] = sums, sums.T
    normal[top:, top:] = np.diag(np.bincount(step[kept], minlength=n_steps).astype(float))
    score[top:] = np.bincount(step[kept], weights=weighted[kept], minlength=n_steps)
    scale = 1.0 / np.sqrt(np.maximum(np.diag(normal), np.finfo(float).tiny))  # columns of unit norm
    beta = scale * (np.linalg.pinv(normal * np.outer(scale, scale), rcond=COLLINEAR, hermitian=True) @ (scale * score))
    return float(weighted @ weighted - score @ beta)


def _walk_split(jac: np.ndarray, weighted: np.ndarray, blocks: np.ndarray, bread: np.ndarray,
                hard: np.ndarray, row_sort: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The residual less a hard-iron level per block, and the covariance those levels' walk gives the fit.

    Parameters
    ----------
    jac : ndarray, shape (m, k)
        Jacobian of the weighted residual (determined columns only).
    weighted : ndarray, shape (m,)
    blocks : ndarray of int, shape (m,)
    bread : ndarray, shape (k, k)
    hard : ndarray of int
        The hard iron's columns of ``jac``.
    row_sort : ndarray of int, shape (m,)
        The sort of each row (a level per block and sort is the walk's competitor).

    Returns
    -------
    (rest, covariance) or None
        None where the blocks' structure is not the hard iron's walk (the levels of each sort
        leave a residual no larger than the hard iron's levels do);
        else ``weighted`` less the levels' part (as the fit would leave it), shape (m,), and
        ``sum_b A_b V A_b^T`` of the module docstring, shape (k, k), in the parameters' units.
    """
    _, index = np.unique(blocks, return_inverse=True)
    index = index.ravel()
    n_blocks, h = index.max() + 1, len(hard)
    _, sort = np.unique(row_sort, return_inverse=True)
    n_sorts = sort.max() + 1
    stepped_rss = _stepped_rss(jac, weighted, index * n_sorts + sort.ravel(), (n_blocks - 1) * n_sorts)
    levels, noise_cov, walked_rss = _block_levels(jac, weighted, index, hard)
    if stepped_rss <= walked_rss:  # the sorts' levels explain the blocks' structure at least as well
        return None
    walked = np.zeros(weighted.size)  # the levels' part of the residual, as the fit would leave it
    for b in range(n_blocks - 1):
        rows = index == b
        walked[rows] = jac[rows][:, hard] @ levels[b]
    walked -= jac @ np.linalg.lstsq(jac, walked, rcond=None)[0]
    # the levels' spread about their mean, less the part the noise alone gives it
    noise = np.zeros((n_blocks * h, n_blocks * h))
    noise[:-h, :-h] = noise_cov
    centre = np.kron(np.eye(n_blocks) - 1.0 / n_blocks, np.eye(h))
    noise = centre @ noise @ centre
    spread = levels - levels.mean(axis=0)
    level_cov = spread.T @ spread - sum(noise[b * h:(b + 1) * h, b * h:(b + 1) * h] for b in range(n_blocks))
    # (G - 1) V^ / V is chi-square with G - 1 dof along any direction, so E[1 / V^] = (G - 1) / ((G - 3) V):
    # V^ / (G - 3) makes the walk's err^2 / sigma^2 one on average (a t, not a normal, ratio)
    w, v = np.linalg.eigh(0.5 * (level_cov + level_cov.T) / max(n_blocks - 3, 1))
    level_cov = (v * np.maximum(w, 0.0)) @ v.T
    shares = np.array([jac[index == b].T @ jac[index == b][:, hard] for b in range(n_blocks)])  # H_bh
    counts = np.bincount(index, minlength=n_blocks).astype(float)
    moves = np.einsum("ij,bjl->bil", bread, shares)  # B H_bh
    maps = moves - counts[:, None, None] / counts.sum() * moves.sum(axis=0)  # A_b
    return weighted - walked, np.einsum("bil,lm,bjm->ij", maps, level_cov, maps)


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
