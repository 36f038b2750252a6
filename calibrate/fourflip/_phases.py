r"""Each flip's field azimuth from its turn alone: a flip whose turntable zero is off the others'.

The Earth's field has one azimuth ``delta`` on the bench (SPEC section 1), in every flip.  Seen by a
channel of direction ``a`` in flip kappa the field in the frame turning with the table is
``Rz(phi)^T B_W``, so the channel's first harmonic over the turn, ``c cos(phi) + s sin(phi)``, is

.. math::

    c - i s = g B_h\, e^{-i\delta_k} (u_x + i u_y), \qquad u = R_x(\kappa) a,

with ``u_x = a_x`` in every flip and ``u_y = a_y, -a_z, -a_y, a_z`` in flips 0, 90, 180, 270.  With
``X = g B_h a_x``, ``Y = g B_h a_y``, ``Z = g B_h a_z`` per channel, the four azimuths ``delta_k``
are fitted (variable projection: given them, X, Y, Z are linear) from the harmonics alone, before any
direction is.  A flip whose turntable angles are off by ``D`` (the table's zero moved, the cube set
down turned about the vertical, that flip's angles read from another reference) has
``delta_k = delta + D``; the joint fit's base model, which has one ``delta``, spreads that over the
directions, the dip and the gains, or calls a healthy channel dead.  A few degrees is the diagnosis's effect
``turntable_zero`` (fitted, from a start at zero); a quarter or half turn (a wrong mark) is refused here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

__all__ = ["FlipAzimuths", "flip_azimuths", "zero_off_words"]

ZERO_OFF_DEG = 15.0
"""A flip's azimuth this far from the others' is a turntable zero off (a cube set square against a fence is off by
a degree or less; a zero read from the wrong mark, by a quarter or half turn), when also beyond
:data:`ZERO_OFF_SIGMAS`.  Not less: a strongly nonlinear response shifts the flips' azimuths by a few degrees with
a misfit one azimuth per flip still explains (the simulator's ``nonlinear_response`` at scale 4: 5.3 deg on seeds 7
and 19, refused at 5 deg; up to 12.3 deg over 2000 seeds, the review's scan; 7.6 at scale 2), and a setting error
of a few degrees is the joint fit's diagnosis's (its effect ``turntable_zero``)."""
ZERO_OFF_SIGMAS = 5.0
MAX_REDUCED_CHI2 = 4.0
"""The azimuths are judged only when one per flip explains the harmonics (a reduced chi-square below
this): an effect the harmonics carry besides (a field gradient, a nonlinear response, drift over a
turn) can move a flip's phase by degrees, and the joint fit's diagnosis is the place for it."""
_STEPS = 360


@dataclass(frozen=True)
class FlipAzimuths:
    """The field's azimuth fitted in each flip on its own.

    Attributes
    ----------
    azimuth_deg, sigma_deg : ndarray, shape (4,)
        ``delta_k`` (from the turntable zero, counterclockwise) and its standard error, degrees.  The
        harmonics cannot tell ``(a, B)`` from ``(-a, -B)``: all four may be 180 deg from the field's
        azimuth together; their differences are the flips' zeros.
    reduced_chi2 : float
        The harmonics' misfit with one azimuth per flip, per degree of freedom.
    """

    azimuth_deg: np.ndarray
    sigma_deg: np.ndarray
    reduced_chi2: float


def _harmonics(platform_deg, flip_index, outputs):
    """Per flip and channel ``c - i s`` and the standard error of c and s, output units."""
    z, sigma = np.empty((4, outputs.shape[1]), complex), np.empty((4, outputs.shape[1]))
    for k in range(4):
        mask = flip_index == k
        phi = np.radians(platform_deg[mask])
        design = np.column_stack([np.ones_like(phi), np.cos(phi), np.sin(phi)])
        coef, *_ = np.linalg.lstsq(design, outputs[mask], rcond=None)
        rms = np.sqrt(np.sum((outputs[mask] - design @ coef) ** 2, axis=0) / max(mask.sum() - design.shape[1], 1))
        factor = np.linalg.pinv(design.T @ design)
        z[k] = coef[1] - 1j * coef[2]
        sigma[k] = rms * np.sqrt(0.5 * (factor[1, 1] + factor[2, 2]))
    return z, np.maximum(sigma, np.finfo(float).tiny)


def _residuals(delta, z, sigma):
    """Misfit of ``z_k e^{i delta_k} = X + i (Y, -Z, -Y, Z)``, each in its sigmas, with X, Y, Z fitted."""
    w = z * np.exp(1j * np.asarray(delta))[..., :, None]
    re, im = w.real, w.imag
    along_x = re - re.mean(axis=-2, keepdims=True)
    pair_0_180 = (im[..., 0, :] + im[..., 2, :]) / 2  # Im w0 - Y and Im w2 + Y, each
    pair_90_270 = (im[..., 1, :] + im[..., 3, :]) / 2
    return np.concatenate([(along_x / sigma).reshape(*along_x.shape[:-2], -1),
                           pair_0_180 / sigma[0], pair_0_180 / sigma[2],
                           pair_90_270 / sigma[1], pair_90_270 / sigma[3]], axis=-1)


def flip_azimuths(platform_deg, flip_index, outputs) -> FlipAzimuths | None:
    """Fit each flip's field azimuth from the harmonics of its turn (see the module's notes).

    Parameters
    ----------
    platform_deg : ndarray, shape (n,)
    flip_index : ndarray of int, shape (n,)
    outputs : ndarray, shape (n, c)

    Returns
    -------
    FlipAzimuths or None
        None when the azimuths are not determined (no horizontal field seen).
    """
    z, sigma = _harmonics(np.asarray(platform_deg, float), np.asarray(flip_index), np.asarray(outputs, float))
    grid = np.linspace(0.0, 2 * np.pi, _STEPS, endpoint=False)
    common = np.sum(_residuals(np.repeat(grid[:, None], 4, axis=1), z, sigma) ** 2, axis=-1)
    delta = np.full(4, grid[int(np.argmin(common))])  # one azimuth for all (an honest recording's), then each its own
    for _ in range(3):  # coordinate descent on a grid: each flip's cost is one period in its own azimuth
        for k in range(4):
            trial = np.repeat(delta[None, :], _STEPS, axis=0)
            trial[:, k] = grid
            cost = np.sum(_residuals(trial, z, sigma) ** 2, axis=-1)
            delta[k] = grid[int(np.argmin(cost))]
    fit = least_squares(_residuals, delta, args=(z, sigma), method="lm")
    reduced_chi2 = 2 * fit.cost / max(len(fit.fun) - 4 - 3 * z.shape[1], 1)
    try:
        covariance = np.linalg.inv(fit.jac.T @ fit.jac) * max(1.0, reduced_chi2)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(covariance)):
        return None
    return FlipAzimuths(np.degrees(np.mod(fit.x, 2 * np.pi)), np.degrees(np.sqrt(np.diag(covariance))), reduced_chi2)


def zero_off_words(path, azimuths: FlipAzimuths) -> str | None:
    """Words naming the flip(s) whose azimuth is off the others' (beyond both thresholds), else None (also when the
    azimuths do not explain the harmonics: :data:`MAX_REDUCED_CHI2`, and when every flip is within the thresholds of
    flip 0's: the diagnosis's ``turntable_zero`` fits those from zero, two flips 8 deg off either way included).

    The others are the largest group that agree among themselves; with no group of three, every pair
    that disagrees is named.
    """
    if not azimuths.reduced_chi2 < MAX_REDUCED_CHI2:
        return None
    a, s = azimuths.azimuth_deg, azimuths.sigma_deg
    diff = np.mod(a[:, None] - a[None, :] + 180.0, 360.0) - 180.0
    off = (np.abs(diff) > ZERO_OFF_DEG) & (np.abs(diff) > ZERO_OFF_SIGMAS * np.hypot(s[:, None], s[None, :]))
    if not off[0].any():  # each flip's zero within reach of flip 0's, where the diagnosis's turntable_zero starts
        return None
    flips = (0, 90, 180, 270)
    agree = (~off).sum(axis=1)  # how many flips (itself included) each agrees with
    best = int(np.argmax(agree))
    group = [k for k in range(4) if not off[best, k]]
    if 3 <= len(group) < 4:
        ref = np.degrees(np.angle(np.mean(np.exp(1j * np.radians(a[group])))))
        named = [k for k in range(4) if k not in group]
        parts = [f"flip {flips[k]}'s turntable angles are {np.mod(a[k] - ref + 180, 360) - 180:+.1f} +- {s[k]:.1g} deg "
                 "off the other flips'" for k in named]
        fix = (f"if its zero is known to have moved, subtract that from flip {flips[named[0]]}'s platform_deg, "
               "else re-record the flip")
    else:
        parts = [f"flip {flips[k]} against flip {flips[j]}: {diff[k, j]:+.1f} deg" for k in range(4) for j in range(k + 1, 4)
                 if off[k, j]]
        fix = "re-record the flips with the turntable's zero fixed"
    return (f"{path}: {'; '.join(parts)} (the field's azimuth from the turntable zero, fitted in each flip on its "
            "own; the Earth's field has one azimuth in every flip): the table's zero moved between flips, the cube was "
            f"set down turned about the vertical, or that flip's platform_deg has another reference; {fix}")
