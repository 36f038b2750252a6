"""Noise floor of a recording, estimated from the data itself.

Second differences of neighbouring samples along the turntable angle cancel every smooth
signal (the field's harmonics, slow drifts, any smooth model error) and keep white noise:
for i.i.d. noise of variance sigma^2, ``d_i = r_{i-1} - 2 r_i + r_{i+1}`` has variance
``6 sigma^2``.  A robust scale (normalised median absolute deviation) keeps rare spikes from
inflating it.  With coarse turntable steps (10 degrees and more) the curvature of the field's
first harmonics no longer cancels, so each flip's low harmonics are fitted and removed first.
"""

from __future__ import annotations

import numpy as np
from scipy.special import chdtrc, ndtri

__all__ = ["noise_floor", "find_spikes", "robust_sigma", "chi2_sf", "SPIKE_SIGMAS"]

_NORMAL_MAD = ndtri(0.75)  # the MAD of a unit normal

SPIKE_SIGMAS = 8.0
"""A sample this many noise sigmas off its neighbours' median is a spike (a glitch, not noise)."""


def noise_floor(platform_deg: np.ndarray, flip_index: np.ndarray, values: np.ndarray) -> np.ndarray:
    """White-noise sigma per channel from second differences within each flip.

    Parameters
    ----------
    platform_deg : ndarray, shape (n,)
        Turntable reading, degrees (samples are ordered by it within each flip).
    flip_index : ndarray of int, shape (n,)
    values : ndarray, shape (n, c)
        Outputs or residuals, output units.

    Returns
    -------
    ndarray, shape (c,)
        Estimated noise sigma in the units of ``values``.
    """
    diffs = []
    for k in np.unique(flip_index):
        idx = np.flatnonzero(flip_index == k)
        order = idx[np.argsort(np.mod(platform_deg[idx], 360.0), kind="stable")]
        v = _without_low_harmonics(platform_deg[order], values[order])
        if len(v) >= 3:  # a turn is a circle: difference across the wrap too
            diffs.append(np.roll(v, 1, axis=0) - 2.0 * v + np.roll(v, -1, axis=0))
    d = np.concatenate(diffs, axis=0)
    return robust_sigma(d) / np.sqrt(6.0)


def chi2_sf(stat: float, dof: float) -> float:
    """``scipy.stats.chi2.sf(stat, dof)`` (the p-value of a chi-square statistic) through ``scipy.special``.

    As scipy.stats: NaN without degrees of freedom, 1 for a negative statistic.
    """
    if not dof > 0:
        return float("nan")
    return 1.0 if stat < 0 else float(chdtrc(dof, stat))


def robust_sigma(x, axis: int = 0) -> np.ndarray | float:
    """Normal-consistent median absolute deviation about the median along ``axis``.

    ``scipy.stats.median_abs_deviation(x, axis, scale="normal")`` computed the same way, without
    importing ``scipy.stats`` (0.8 s of the package's import time).
    """
    x = np.asarray(x, dtype=float)
    return np.median(np.abs(x - np.expand_dims(np.median(x, axis=axis), axis)), axis=axis) / _NORMAL_MAD


def _without_low_harmonics(platform_deg: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Values minus a least-squares fit of harmonics 0..m of the turntable angle.

    ``m = min(3, (n - 1) // 4)`` keeps at least three quarters of the samples' freedom for the
    noise, so the fit cannot swallow it.
    """
    n_harmonics = min(3, (len(platform_deg) - 1) // 4)
    phi = np.radians(platform_deg)
    cols = [np.ones_like(phi)]
    for h in range(1, n_harmonics + 1):
        cols += [np.cos(h * phi), np.sin(h * phi)]
    design = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(design, values, rcond=None)
    return values - design @ coef


def find_spikes(platform_deg: np.ndarray, flip_index: np.ndarray, values: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """Samples that jump away from their neighbours: glitches of the line or the sensor.

    Within each flip, in turntable order, a sample is compared with the median of itself and its
    two neighbours on each side; the smooth signal cancels (as in :func:`noise_floor`), white
    noise stays within a few sigma, a glitch does not.

    Returns
    -------
    ndarray of bool, shape (n,)
        True for a sample whose deviation exceeds :data:`SPIKE_SIGMAS` noise sigmas in any channel.
    """
    from scipy.ndimage import median_filter

    spikes = np.zeros(len(values), dtype=bool)
    for k in np.unique(flip_index):
        idx = np.flatnonzero(flip_index == k)
        order = idx[np.argsort(np.mod(platform_deg[idx], 360.0), kind="stable")]
        v = _without_low_harmonics(platform_deg[order], values[order])
        local = median_filter(v, size=(5, 1), mode="wrap")
        spikes[order] = np.any(np.abs(v - local) > SPIKE_SIGMAS * noise[None, :], axis=1)
    return spikes
