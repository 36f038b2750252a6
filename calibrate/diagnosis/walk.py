"""A random walk of each channel's offset under a fit: its size from the residual's block sums, its cost.

The model.  Channel ``c``'s offset wanders as a random walk, ``w_c(t)`` with ``E[dw_c^2] = q_c^2 dt``
(``q_c`` in the weighted residual's units per square root of a second: noise sigmas of one sample), the
channels independent.  Taken relative to its mean over the recording's samples (the offset the file
states is the session's mean level: a constant is the channel's offset, which the fit takes whole), its
covariance is the centred minimum kernel

.. math:: K(t, t') = \\min(t, t') - \\bar m(t) - \\bar m(t') + \\bar{\\bar m}, \\qquad
          \\bar m(t) = \\sum_i \\omega_i \\min(t, t_i), \\quad
          \\bar{\\bar m} = \\sum_{ij} \\omega_i \\omega_j \\min(t_i, t_j),

``omega`` each row's share of the samples.  One number per channel, ``q_c``: its shape is known, so what
the fit absorbs of it (the named drift's polynomial takes its lowest part, each flip's mounting part of a
flip's level) is extrapolated by the shape, not estimated band by band from what little is left.

What it does to the parameters.  To first order ``dx = H^-1 J^T (e + s)``, ``H = J^T J``, ``s`` the walk in
the weighted residual (``s_i = d_i w_c(t_i)``, ``d_i`` a row's weight, the square root of its bin's count).
Over a 10 s block the walk moves by ``q sqrt(10 s)``, small against its spread over the session
(``q sqrt(T)``, ``T`` ~ 1600 s on a four-flip): take it constant within a block (``A`` the block sums,
``U`` the block indicator, ``D = diag(d)``).  Then

.. math:: V = (1 + f) H^{-1} + H^{-1} G_d^T (\\mathrm{diag}(q^2) \\otimes K) G_d H^{-1}, \\qquad G_d = U^T D J,

the sandwich, whole: the walk's part the drift's columns or the mountings absorb moves those parameters,
and its correlation with the directions in ``H^-1`` carries it on to them.  Each direction's two components
across the flip axis are read from the level differences between flips (about 420 s apart on a four-flip):
those differ by ``q sqrt(420 s)`` of the walk, and no polynomial of low order in time follows them, so a
walk far below the floor in each sample (tools/bench_loop.py's, 0.004 uT per square root of a second against
0.15 uT of noise) moves the directions by several of their white-noise sigmas.

Its size from the residual.  The block sums ``z = A r`` of the residual ``r = (I - P)(e + s)``, ``P = J H^-1
J^T``: ``z = keep^{(1)} e' + L w``, ``L = A (I - P) D U`` (``A D U - G H^-1 G_d^T``, ``G = A J``), so

.. math:: E[z z^T] = (1 + f)\\, keep + L (\\mathrm{diag}(q^2) \\otimes K) L^T, \\qquad keep = A (I - P) A^T,

``f`` the noise floor's own error (white beyond the floor).  In ``keep``'s range (``keep = U_r Lambda U_r^T``,
``zeta = Lambda^{-1/2} U_r^T z``: white noise's ``zeta`` is ``N(0, I)``) this is a variance-components model,
``cov(zeta) = (1 + f) I + sum_c q_c^2 M_c``, and ``(f, q^2)`` are its restricted maximum likelihood (the fit's
own parameters are projected out: ``zeta`` carries none of them), ``f >= -0.9``, ``q^2 >= 0``.  Maximum
likelihood, not the moment equations at ``K = 0`` (:mod:`calibrate.diagnosis.robust`'s MINQUE): a walk that
the block sums see is far above white noise in the low blocks' differences, where the equations at zero
weigh it as white noise does and lose most of its information.

Checks on paper.  White noise: ``E[zeta zeta^T] = I``, the likelihood is largest near ``f = 0, q = 0`` (at the
boundary half the time), ``V`` is the naive ``H^-1`` up to the floor's factor.  A smooth drift the fit names
(a polynomial in time, a warm-up) lies in the span of ``J``: ``(I - P)`` takes it whole, ``z`` is white noise's,
``q ~ 0`` and nothing is widened.  A smooth drift the fit does not follow leaves a smooth remainder, which the
walk's kernel (largest at the longest periods) takes as a walk of the size that leaves it: the widening is
that of a walk leaving the same block sums, not of the drift (the four-flip asks this only where the block
sums fail the band test, :mod:`calibrate.fourflip.diagnosis`).  A walk common to the channels is taken as
independent walks of the same size in each: the directions' moves from different channels' walks add in
quadrature where they would add with their signs.

A test of no walk (:func:`walk_p_value`).  The band test's family spreads its power over ten bands, each at a
tenth of the family's rate; a walk's power sits in the kernel's few lowest modes (``M_c``'s eigenvalues fall
as the inverse square of their order: on a four-flip the largest holds about 30 % of the trace, the effective
count ``(tr M)^2 / tr M^2`` is about 8).  Against the walk the likelihood ratio of ``q = 0`` is the most
powerful test, and the likelihood is this module's.  Per channel, with ``rho = q_c^2 / (1 + f)`` and the
others at zero, ``cov = (1 + f)(I + rho M_c)``; the floor's factor profiled out, ``-2 ln LR`` is
``max_rho [r ln(|zeta|^2 / (|zeta|^2 - sum_i a_i^2 rho s_i / (1 + rho s_i))) - sum_i ln(1 + rho s_i)]``,
``a = U_c^T zeta``, ``M_c = U_c diag(s) U_c^T``: no floor to trust (a ratio in ``zeta``), and a grid over
``rho`` in place of the maximisation (the null below uses the same grid, so the test's size is exact).  The
statistic is the sum of the channels' ratios, each with its own floor profiled out (the model
:func:`offset_walk` sizes has one walk a channel; not the joint ratio, whose floor is shared, but its null is
simulated alike).  Its null is not the boundary's asymptotic mixture (half chi-square 0, half chi-square 1 a
channel): with so few effective modes the ratio is zero in about 61 % of white-noise draws, not 50 %, and beyond
the mixture's 1 % point in 0.76 %.  So its null is simulated as the band test's is: under white noise
``zeta ~ N(0, I)`` exactly (a linear fit), with a fixed seed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import minimize

from .robust import BLOCK_S, NULL_CHUNK, block_layout

__all__ = ["FLOOR_LOWER", "OffsetWalk", "WALK_NULL_DRAWS", "offset_walk", "walk_p_value"]

FLOOR_LOWER = -0.9
"""The noise floor's own factor ``f`` is bounded below by this (the floor is measured to within a few %)."""

WALK_NULL_DRAWS = 2000
"""Draws of white block sums that give :func:`walk_p_value`'s null (its resolution ``1 / 2001``)."""

WALK_GRID = np.geomspace(1e-2, 1e4, 49)
"""The walk's variance over the floor's in its largest mode (``rho max(s)``) at which the likelihood ratio is
taken: from a walk far below the floor in every mode to one far above it in the lowest."""

WALK_RCOND = 1e-8
"""A channel's walk modes below this fraction of its largest singular value are dropped (they add nothing)."""


class OffsetWalk(NamedTuple):
    """What :func:`offset_walk` found."""

    covariance: np.ndarray
    """(k, k) the parameters' covariance under the walk (module docstring's ``V``), NaN where the bread is."""
    q_per_sqrt_s: np.ndarray
    """(c,) each channel's walk, the weighted residual's units (noise sigmas of one sample) per square root of a
    second."""
    floor_factor: float
    """``f``: the residual's white part is ``1 + f`` times the floor's variance."""


def offset_walk(jac: np.ndarray, weighted: np.ndarray, t_s: np.ndarray, bread: np.ndarray,
                row_weight: np.ndarray | float = 1.0, block_s: float = BLOCK_S) -> OffsetWalk:
    """Covariance of a least-squares fit's parameters with each channel's offset a random walk (module docstring).

    Parameters
    ----------
    jac : ndarray, shape (n * c, k)
        Jacobian of the weighted residual at the solution, rows as ``weighted.ravel()``.
    weighted : ndarray, shape (n, c)
        The weighted residual of ``n`` rows of ``c`` channels over the noise floor (white noise: unit variance).
    t_s : ndarray, shape (n,)
        Time of each row, s.
    bread : ndarray, shape (k, k)
        ``(J^T J)^-1`` (NaN rows and columns for what the data cannot determine).
    row_weight : ndarray, shape (n,) or (n, 1), or float
        Each row's weight in ``weighted``, ``d_i``: the square root of the samples a bin mean holds (1: samples).
    block_s : float
        Length of the time blocks, s: the walk counts as constant within one.

    Returns
    -------
    OffsetWalk

    Raises
    ------
    ValueError
        Mismatched shapes, a non-positive block length or row weight.
    """
    design = _walk_design(jac, weighted, t_s, bread, row_weight, block_s)
    floor, q2 = _restricted_ml(design.zeta, design.factors)
    g_d, nb = design.g_d, design.kernel.shape[0]
    moved = sum(q2[ch] * g_d[ch * nb:(ch + 1) * nb].T @ design.kernel @ g_d[ch * nb:(ch + 1) * nb]
                for ch in range(len(q2)))
    out = np.full(bread.shape, np.nan)
    out[np.ix_(design.good, design.good)] = (1.0 + floor) * design.b + design.b @ moved @ design.b
    return OffsetWalk(out, np.sqrt(q2), floor)


def walk_p_value(jac: np.ndarray, weighted: np.ndarray, t_s: np.ndarray, bread: np.ndarray,
                 row_weight: np.ndarray | float = 1.0, block_s: float = BLOCK_S) -> float:
    """The p-value of "no channel's offset walks" against white block sums: the restricted likelihood ratio of
    ``q = 0`` (module docstring, "A test of no walk"), summed over the channels, its null by simulation.

    Parameters and raises as :func:`offset_walk`.

    Returns
    -------
    float
        ``(1 + exceed) / (1 + WALK_NULL_DRAWS)``, ``exceed`` the null draws whose statistic is at least the
        residual's; under white noise uniform on its grid.
    """
    design = _walk_design(jac, weighted, t_s, bread, row_weight, block_s)
    r = design.zeta.size
    # each channel's M_c = F_c F_c^T = U_c diag(s_c^2) U_c^T: the likelihood depends on zeta through U_c^T zeta
    # and |zeta|^2 alone
    modes = []
    for f in design.factors:
        u, s, _ = np.linalg.svd(f, full_matrices=False)
        kept = s > s.max(initial=0.0) * WALK_RCOND
        modes.append((u[:, kept], s[kept] ** 2))

    def statistic(zeta):  # (draws, r) -> (draws,)
        total = np.sum(zeta**2, axis=1)
        return np.sum([_likelihood_ratio(zeta @ u, total, s2, r) for u, s2 in modes], axis=0)

    if not np.any(design.zeta):  # a residual of zero: nothing to test
        return 1.0
    observed = statistic(design.zeta[None])[0]
    if observed <= 0.0:  # no walk better than none: every null draw is at least as large
        return 1.0
    rng = np.random.default_rng(0)  # the fit is deterministic, so is its test
    exceed = 0
    for start in range(0, WALK_NULL_DRAWS, NULL_CHUNK):
        exceed += int(np.sum(statistic(rng.standard_normal((min(NULL_CHUNK, WALK_NULL_DRAWS - start), r)))
                             >= observed))
    return (1.0 + exceed) / (1.0 + WALK_NULL_DRAWS)


def _likelihood_ratio(projected: np.ndarray, total: np.ndarray, s2: np.ndarray, r: int) -> np.ndarray:
    """``-2 ln`` of the restricted likelihood ratio of ``q = 0`` against its best ``q^2 >= 0`` in one channel, the
    floor's factor profiled out, on the grid ``WALK_GRID`` of the walk's ratio to the floor in its largest mode.

    ``projected`` (draws, m) ``U^T zeta``, ``total`` (draws,) ``|zeta|^2``, ``s2`` (m,) ``M``'s eigenvalues.
    With ``rho = q^2 / (1 + f)``: ``cov = (1 + f) (I + rho M)``, the floor's factor at its best
    ``(|zeta|^2 - sum_i a_i^2 rho s_i / (1 + rho s_i)) / r``, so ``-2 ln LR = max_rho [r ln(|zeta|^2 /
    that r) - sum_i ln(1 + rho s_i)]`` (zero at ``rho = 0``).
    """
    rho = WALK_GRID / s2.max()
    gain = rho[:, None] * s2[None, :]  # (grid, m)
    taken = (projected**2) @ (gain / (1.0 + gain)).T  # (draws, grid)
    ratio = r * np.log(total[:, None] / (total[:, None] - taken)) - np.sum(np.log1p(gain), axis=1)[None, :]
    return np.maximum(ratio.max(axis=1), 0.0)


class _WalkDesign(NamedTuple):
    """The block sums in ``keep``'s range and the walk's factors there (module docstring, "Its size from the
    residual")."""

    zeta: np.ndarray
    """(r,) the whitened block sums: white noise's are N(0, I)."""
    factors: list
    """Each channel's ``F_c`` (r, nb): ``M_c = F_c F_c^T``."""
    g_d: np.ndarray
    """(c nb, k) ``G_d = U^T D J``, rows channel-major."""
    kernel: np.ndarray
    """(nb, nb) the centred walk's covariance per unit ``q^2``."""
    good: np.ndarray
    """(k,) the parameters the bread determines."""
    b: np.ndarray
    """The bread on them."""


def _walk_design(jac, weighted, t_s, bread, row_weight, block_s) -> _WalkDesign:
    """:func:`offset_walk`'s block sums, whitened, and the walk's factors (raises as it does)."""
    jac, weighted, t_s, good, b, block, nb = block_layout(jac, weighted, t_s, bread, block_s)
    n, c = weighted.shape
    d = np.broadcast_to(np.asarray(row_weight, dtype=float).ravel(), (n,))
    if not np.all(d > 0):
        raise ValueError("row weights must be positive")
    rows_j = np.nan_to_num(jac[:, good]).reshape(n, c, -1)

    def block_sum(values):  # (n, ...) -> (nb, ...)
        out = np.zeros((nb,) + values.shape[1:])
        np.add.at(out, block, values)
        return out

    g = block_sum(rows_j).transpose(1, 0, 2).reshape(c * nb, -1)  # G = A J, rows channel-major
    g_d = block_sum(d[:, None, None] * rows_j).transpose(1, 0, 2).reshape(c * nb, -1)  # G_d = U^T D J
    count, weight = np.bincount(block, minlength=nb).astype(float), np.bincount(block, weights=d, minlength=nb)
    keep = np.diag(np.tile(count, c)) - g @ b @ g.T  # A (I - P) A^T
    lift = np.diag(np.tile(weight, c)) - g @ b @ g_d.T  # L = A (I - P) D U
    y = block_sum(weighted).T.ravel()
    kernel = _centred_walk_kernel(np.bincount(block, weights=t_s, minlength=nb) / count,
                                  np.bincount(block, weights=d**2, minlength=nb))
    lam, u = np.linalg.eigh(keep)
    positive = lam > lam.max(initial=0.0) * keep.shape[0] * np.finfo(float).eps
    to_white = u[:, positive] / np.sqrt(lam[positive])  # zeta = to_white^T z: white noise's is N(0, I)
    w, v = np.linalg.eigh(kernel)
    kernel_root = v * np.sqrt(np.maximum(w, 0.0))
    factors = [to_white.T @ lift[:, ch * nb:(ch + 1) * nb] @ kernel_root for ch in range(c)]  # M_c = F_c F_c^T
    return _WalkDesign(to_white.T @ y, factors, g_d, kernel, good, b)


def _centred_walk_kernel(t_block: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """The walk's covariance between blocks at ``t_block`` (s, per unit ``q^2``), relative to its mean over the
    samples (``samples`` each block's share of them), (nb, nb)."""
    kernel = np.minimum.outer(t_block, t_block) - t_block.min()
    omega = samples / samples.sum()
    centre = np.eye(len(t_block)) - omega[None, :]  # w - sum_i omega_i w_i
    return centre @ kernel @ centre.T


def _restricted_ml(zeta: np.ndarray, factors: list) -> tuple[float, np.ndarray]:
    """``(f, q^2)`` maximising the likelihood of ``zeta ~ N(0, (1 + f) I + sum_c q_c^2 F_c F_c^T)`` within
    ``f >= FLOOR_LOWER``, ``q^2 >= 0`` (L-BFGS-B, analytic gradient; each ``q_c^2`` scaled by its ``M_c``'s mean
    eigenvalue so the variables are alike in size)."""
    r = zeta.size
    scale = np.array([max(np.sum(f**2) / r, np.finfo(float).tiny) for f in factors])
    products = [f @ f.T for f in factors]

    def objective(theta):
        f, q2 = theta[0], theta[1:] / scale
        cov = (1.0 + f) * np.eye(r) + sum(q * m for q, m in zip(q2, products))
        chol = cho_factor(cov, lower=True)
        alpha = cho_solve(chol, zeta)
        inverse = cho_solve(chol, np.eye(r))
        value = 2.0 * np.sum(np.log(np.diag(chol[0]))) + zeta @ alpha
        grad = [np.trace(inverse) - alpha @ alpha]
        grad += [(np.sum(inverse * m) - alpha @ m @ alpha) / s for m, s in zip(products, scale)]
        return 0.5 * value, 0.5 * np.array(grad)

    start = np.zeros(1 + len(factors))
    bounds = [(FLOOR_LOWER, None)] + [(0.0, None)] * len(factors)
    solution = minimize(objective, start, jac=True, method="L-BFGS-B", bounds=bounds).x
    return float(solution[0]), solution[1:] / scale
