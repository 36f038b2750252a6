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
noise alone gives it (the regression's covariance), over ``G - 1``.  Why ``G - 1`` and not the
``G - 3`` of ``E[1 / V^]``: the error is itself part of the spread it is judged by.  Along one axis,
with the levels independent draws of ``V`` and ``a = (A_b)`` (``sum_b A_b = 0``, so ``a`` lies in the
centred levels' space), the spread is ``(a . u)^2 / |a|^2`` plus an independent ``V chi^2_{G-2}``, so
``err^2 / sigma^2 = (G - 1) z^2 / (z^2 + chi^2_{G-2})``, a ``(G - 1) Beta(1/2, (G - 2)/2)`` of mean one
for every design along that axis (per axis: the argument takes one axis's ``A_b`` and level at a time; a
design whose ``A_b`` mixes the axes is not covered by it); ``G - 3`` over-covered by ``sqrt(7/5)`` in
sigma (``tests/calibrate/diagnosis/test_blocks.py``: a noise-free Monte Carlo of the level covariance
alone, mean one within its standard errors, ``G - 3`` far off).  Where the noise's share of an axis's
spread is not small (a block that sees a narrow band of orientations determines its level poorly) the
spread has fewer degrees of freedom than ``G - 1`` (Satterthwaite's ``nu``, from the noise's covariance
and the spread less it) and the axis is grown by ``nu / (nu - 2) (G - 3) / (G - 1)`` (one without noise,
``nu`` held at :data:`MIN_DOF` or more).  That factor is an interpolation, not a derivation: it is one in
the no-noise limit (the Beta argument above) and ``nu / (nu - 2)``, a t's variance inflation over the
``G - 3`` of ``E[1 / V^]``, in the noise-dominated limit, where the spread's scatter is mostly not the
error's own; between them it is supported only by the Monte Carlo of the tests (the smooth spiral with
the levels' noise a large share of their spread) and the benchmark (``tools/bench_kinds_loop.py``).
The levels are taken as independent across blocks although a walk's are
correlated: where the orientations do not follow time the design's ``A_b`` scatter about zero from
block to block and ``E[sum_bc A_b C_bc A_c^T]`` over that scatter is the same for any ``C`` with the
same spread, so the correlation does not enter; where they follow time it does (a random-walk model
of the levels, ``C`` from their steps, is exact for a random walk) but measured on the benchmark's
swing it under-covered more than the independent model (``tools/bench_kinds_loop.py``), so it is not
used.

What the block levels do not explain is left in that regression's residual and widened by CR2 as
before; the two add.  The noise's own part is then the bread scaled by what the levels leave
(``max(1, rest^2 / dof)``, dof less the levels'), not the caller's naive covariance, whose
chi-square over its degrees of freedom took the walk's residual for white noise: for a random
orientation every row that residual moves the fit about as ``sum_b A_b u_b`` does, so the naive's
scale and the walk's covariance counted the walk twice (the installation tumble's err/sig 0.51).  The
widened covariance is therefore at least the bread (the noise floor's covariance) but may be under
the caller's naive one when a walk is modelled; without a walk model it is the naive grown to
CR2's, never under it (:func:`calibrate.diagnosis.robust.widened`).

A structure that is not a walk can put part of itself into the hard iron's levels: a field
wandering in the world frame shifts a tumble's radial residual by ``B^ . dB(t)``, the same for every
row of a block whatever the orientation; a gain drifting scales it.  Their competitor is a level
per block of each sort of row (``row_sort``: the installation's |B|, angle and heading rows), the
last block's held at zero too (a tumble's residual ``|L z| - F`` lies in the span of the fit's
columns and a constant, ``L z`` being homogeneous of degree one in the shape parameters).  The walk
model is used where the hard iron's levels leave a smaller residual than the sorts' levels do
(each refitted with the fit's columns; the same as: they explain more beyond the sorts' levels
than those explain beyond them) and where most of what they explain (over :data:`OWN_SHARE`) is
theirs alone, beyond what the sorts' levels explain beside them; elsewhere the widening is CR2's
alone, as it was.  The second condition is for a swing within a few degrees of level: a block's
hard-iron level is there nearly a constant of each sort (79-97 % of what the hard iron's levels
explained on the benchmark's swings, walk or field wander, seeds 0-4, the sorts' levels explained
too; under 1 % on the installation tumble's walk, 5-37 % on the tumble's), the data cannot tell a walk from a level
per block, and CR2, which does not say what moved, is kept.  The larger of the two widenings
there, tried, over-covered real walks: 0.79 on the test's time-following spiral, whose polar blocks
make the same ambiguity, and 0.81 on the swing's walk (seeds 0-19).
"""

from __future__ import annotations

import numpy as np

from .robust import bread_root, cluster_covariance, cr2_factor, widened

__all__ = ["TIME_BLOCKS", "time_blocks", "widened_in_time", "sandwich_dof", "level_heading_sigma_deg"]

TIME_BLOCKS = 8
"""Blocks of consecutive samples that are the clusters of the widening."""

OWN_SHARE = 0.5
"""Share of what the hard iron's block levels explain that must be theirs alone (not also explained by
a level per block of each sort) for the structure to be taken as the hard iron's walk."""

MIN_DOF = 3.0
"""Fewest degrees of freedom the levels' spread is credited with (its t factor ``nu / (nu - 2)`` stays finite)."""

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

    With ``hard`` the hard iron's walk between blocks, where the blocks' structure is one, is taken
    out of the residual first and propagated as a process in the parameters (the module docstring);
    CR2 widens for the rest, and the noise's part is then ``bread`` scaled by what the walk leaves
    instead of ``naive`` (whose chi-square scale counted the walk as white noise).

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
        parameters' units; with a walk modelled, the noise's part grown to the sandwich of the rest
        plus the walk's covariance: at least ``bread``, possibly under ``naive``.
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
    walk, base = np.zeros(naive.shape), naive
    if hard is not None and np.all(good[np.asarray(hard)]):
        sort = np.zeros(weighted.size, dtype=int) if row_sort is None else np.asarray(row_sort)
        split = _walk_split(jac[:, good], weighted, blocks, bread[np.ix_(good, good)],
                            np.flatnonzero(good).searchsorted(hard), sort)
        if split is not None:  # the noise's part scaled by what the levels leave, not by the walk's residual
            weighted, walk[np.ix_(good, good)], dof = split
            base = bread * max(1.0, float(weighted @ weighted) / max(dof, 1))
    robust = cluster_covariance(jac, weighted, blocks, bread)
    out = np.array(naive, dtype=float, copy=True)
    out[np.ix_(good, good)] = widened(base[np.ix_(good, good)], robust[np.ix_(good, good)]) + walk[np.ix_(good, good)]
    return out


def sandwich_dof(jac: np.ndarray, blocks: np.ndarray, bread: np.ndarray) -> np.ndarray:
    """Bell and McCaffrey's degrees of freedom of the CR2 variance of each parameter over blocks.

    CR2's variance of parameter ``k`` is ``sum_g (q_g^T r)^2`` with ``q_g = J_g F_g e_k`` on block
    ``g``'s rows (``F_g = B^{1/2} (I - M_g)^{-1/2} B^{1/2}``, the bias reduction of
    :func:`calibrate.diagnosis.robust.cluster_covariance`) and ``r = (I - J B J^T) e`` the residual of
    white noise ``e``: a quadratic form ``e^T M Q Q^T M e`` whose weights are the eigenvalues ``lambda``
    of ``W = Q^T M Q = diag(|q_g|^2) - (Q^T J) B (J^T Q)`` (G x G).  Matched to a scaled chi-square,
    ``nu = (sum lambda)^2 / sum lambda^2``: at most ``rank(W) <= G`` (``G - 1`` when the blocks' factors
    are proportional, as for white noise of equal blocks), fewer where one block carries most of a
    parameter's information (a swing's quarter turn carries most of one horizontal hard-iron component's).
    The ratio of an error to a sigma whose variance has ``nu`` degrees of freedom has t tails: its RMS
    is about ``sqrt(nu / (nu - 2))`` even where the variance is unbiased.  Measured, not applied
    (``tools/bench_swing_sigma.py`` prints it; docs/benchmarks.md says why a growth by ``nu / (nu - 2)``
    was not kept: the block sandwich's independence over-counts slow structure on other designs).

    Parameters
    ----------
    jac : ndarray, shape (m, k)
        Jacobian of the weighted residual (determined columns only), in the units of the bread.
    blocks : ndarray of int, shape (m,)
        The block of each residual row.
    bread : ndarray, shape (k, k)
        ``(J^T J)^-1`` of the same columns, finite.

    Returns
    -------
    ndarray, shape (k,)
        ``nu`` per parameter (infinite where the parameter takes nothing from the blocks).

    Raises
    ------
    ValueError
        Fewer than two blocks, mismatched shapes, or a bread that is not finite (leave the undetermined
        columns out first).
    """
    jac = np.asarray(jac, dtype=float)
    blocks = np.asarray(blocks)
    if blocks.size != jac.shape[0] or np.shape(bread) != (jac.shape[1], jac.shape[1]):
        raise ValueError(f"expected {jac.shape[0]} blocks and a {jac.shape[1]} x {jac.shape[1]} bread, "
                         f"got {blocks.size} and {np.shape(bread)}")
    if not np.all(np.isfinite(bread)):
        raise ValueError("the bread is not finite: leave the undetermined columns out")
    _, index = np.unique(blocks, return_inverse=True)
    index = index.ravel()
    if index.max(initial=0) < 1:
        raise ValueError("degrees of freedom over blocks need at least two blocks")
    root = bread_root(bread)
    own, cross = [], []  # F_g H_g F_g and F_g H_g per block (H_g = J_g^T J_g)
    for g in range(index.max() + 1):
        jg = jac[index == g]
        info = jg.T @ jg
        f = cr2_factor(root, info)
        own.append(np.diag(f @ info @ f))
        cross.append(f @ info)
    own, cross = np.array(own), np.array(cross)  # (G, k), (G, k, k)
    nu = np.full(jac.shape[1], np.inf)
    for k in range(jac.shape[1]):
        q = cross[:, k, :]  # row g: q_g^T J (block g's rows only)
        weights = np.linalg.eigvalsh(np.diag(own[:, k]) - q @ bread @ q.T)
        if np.sum(weights**2) > 0.0:
            nu[k] = np.sum(weights) ** 2 / np.sum(weights**2)
    return nu


def _block_levels(jac: np.ndarray, weighted: np.ndarray, index: np.ndarray, hard: np.ndarray,
                  step: np.ndarray | None = None, n_steps: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """The residual refitted on the fit's columns and a hard-iron level per block but the last.

    With ``step`` (each row's step, those from ``n_steps`` on held at zero) a level per step is
    refitted beside them (the sorts' levels of :func:`_walk_split`).  Returns the hard iron's levels,
    shape (G, h) (the last zero: their common part is the fit's hard iron), their covariance under
    unit white noise, shape ((G - 1) h, (G - 1) h), and the refit's residual sum of squares.  Built
    from per-block and per-step sums (no (m, G h) design is held).
    """
    n_blocks, h = index.max() + 1, len(hard)
    top = jac.shape[1]
    size = top + n_steps + h * (n_blocks - 1)
    normal, score = np.zeros((size, size)), np.zeros(size)
    normal[:top, :top], score[:top] = jac.T @ jac, jac.T @ weighted
    if n_steps:
        kept = step < n_steps
        sums = np.zeros((n_steps, top))
        np.add.at(sums, step[kept], jac[kept])
        normal[top:top + n_steps, :top], normal[:top, top:top + n_steps] = sums, sums.T
        normal[top:top + n_steps, top:top + n_steps] = np.diag(np.bincount(step[kept], minlength=n_steps).astype(float))
        score[top:top + n_steps] = np.bincount(step[kept], weights=weighted[kept], minlength=n_steps)
    first = top + n_steps
    for b in range(n_blocks - 1):
        rows, cols = index == b, slice(first + h * b, first + h * (b + 1))
        jh = jac[rows][:, hard]
        normal[:top, cols] = jac[rows].T @ jh
        if n_steps:
            on = rows & kept
            cross = np.zeros((n_steps, h))
            np.add.at(cross, step[on], jac[on][:, hard])
            normal[top:first, cols] = cross
        normal[cols, :first] = normal[:first, cols].T
        normal[cols, cols] = jh.T @ jh
        score[cols] = jh.T @ weighted[rows]
    scale = 1.0 / np.sqrt(np.maximum(np.diag(normal), np.finfo(float).tiny))  # columns of unit norm
    inverse = scale[:, None] * np.linalg.pinv(normal * np.outer(scale, scale), rcond=COLLINEAR, hermitian=True) * scale
    beta = inverse @ score
    levels = np.vstack([beta[first:].reshape(n_blocks - 1, h), np.zeros(h)])
    return levels, inverse[first:, first:], float(weighted @ weighted - score @ beta)


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


def _level_covariance(levels: np.ndarray, noise_cov: np.ndarray) -> np.ndarray:
    """``V``, the covariance of one block's walk level, from the levels' spread less the noise's share.

    Parameters
    ----------
    levels : ndarray, shape (G, h)
        The blocks' levels (the last zero).
    noise_cov : ndarray, shape ((G - 1) h, (G - 1) h)
        Their covariance under the noise alone.

    Returns
    -------
    ndarray, shape (h, h)
        Positive semi-definite, in the levels' units squared (module docstring: over ``G - 1``, each
        axis grown by ``nu / (nu - 2) (G - 3) / (G - 1)`` where the noise leaves its spread ``nu``
        degrees of freedom).
    """
    n_blocks, h = levels.shape
    noise = np.zeros((n_blocks * h, n_blocks * h))
    noise[:-h, :-h] = noise_cov
    centre = np.kron(np.eye(n_blocks) - 1.0 / n_blocks, np.eye(h))
    noise = centre @ noise @ centre
    spread = levels - levels.mean(axis=0)
    shares = sum(noise[b * h:(b + 1) * h, b * h:(b + 1) * h] for b in range(n_blocks))
    free = n_blocks - 1
    cov = (spread.T @ spread - shares) / free
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    cov = (v * np.maximum(w, 0.0)) @ v.T
    grow = np.ones(h)
    # Satterthwaite's degrees of freedom of each axis's spread (the noise's share in it); the growth is an
    # interpolation between the no-noise limit (1) and the noise-dominated one (a t's nu / (nu - 2) over G - 3),
    # supported by Monte Carlo, not derived (module docstring)
    for a in range(h):
        axis, var = noise[a::h, a::h], cov[a, a]
        spread_var = free * var**2 + 2.0 * var * np.trace(axis) + np.sum(axis * axis)
        nu = min(max(free**2 * var**2 / spread_var if spread_var > 0 else free, MIN_DOF), free)
        grow[a] = nu / (nu - 2.0) * (free - 2.0) / free
    return cov * np.sqrt(np.outer(grow, grow))


def _walk_split(jac: np.ndarray, weighted: np.ndarray, blocks: np.ndarray, bread: np.ndarray,
                hard: np.ndarray, row_sort: np.ndarray) -> tuple[np.ndarray, np.ndarray, int] | None:
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
    (rest, covariance, dof) or None
        None where the blocks' structure is not the hard iron's walk (module docstring: the levels
        of each sort leave a residual no larger than the hard iron's levels do, or explain most of
        what those explain); else ``weighted`` less the levels' part (as the fit would leave it),
        shape (m,), ``sum_b A_b V A_b^T`` of the module docstring, shape (k, k), in the parameters'
        units, and the degrees of freedom the levels' refit leaves.
    """
    _, index = np.unique(blocks, return_inverse=True)
    index = index.ravel()
    n_blocks, h = index.max() + 1, len(hard)
    if n_blocks <= MIN_DOF:  # too few levels to tell a walk's spread from the noise's: CR2 alone
        return None
    _, sort = np.unique(row_sort, return_inverse=True)
    n_sorts = sort.max() + 1
    step, n_steps = index * n_sorts + sort.ravel(), (n_blocks - 1) * n_sorts
    stepped_rss = _stepped_rss(jac, weighted, step, n_steps)
    levels, noise_cov, walked_rss = _block_levels(jac, weighted, index, hard)
    if stepped_rss <= walked_rss:  # the sorts' levels explain the blocks' structure at least as well
        return None
    both_rss = _block_levels(jac, weighted, index, hard, step, n_steps)[2]
    if stepped_rss - both_rss <= OWN_SHARE * (weighted @ weighted - walked_rss):
        return None  # most of what the hard iron's levels explain, the sorts' levels explain too
    walked = np.zeros(weighted.size)  # the levels' part of the residual, as the fit would leave it
    for b in range(n_blocks - 1):
        rows = index == b
        walked[rows] = jac[rows][:, hard] @ levels[b]
    walked -= jac @ np.linalg.lstsq(jac, walked, rcond=None)[0]
    level_cov = _level_covariance(levels, noise_cov)
    shares = np.array([jac[index == b].T @ jac[index == b][:, hard] for b in range(n_blocks)])  # H_bh
    counts = np.bincount(index, minlength=n_blocks).astype(float)
    moves = np.einsum("ij,bjl->bil", bread, shares)  # B H_bh
    maps = moves - counts[:, None, None] / counts.sum() * moves.sum(axis=0)  # A_b
    return (weighted - walked, np.einsum("bil,lm,bjm->ij", maps, level_cov, maps),
            weighted.size - jac.shape[1] - h * (n_blocks - 1))


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
