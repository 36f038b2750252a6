"""Noise floor of a recording, estimated from the data itself: the one module every kind takes it from.

Second differences of neighbouring samples (along the turntable angle, or in time) cancel every
smooth signal (the field's harmonics, slow drifts, any smooth model error) and keep white noise:
for i.i.d. noise of variance sigma^2, ``d_i = r_{i-1} - 2 r_i + r_{i+1}`` has variance
``6 sigma^2``.  A robust scale (normalised median absolute deviation) keeps rare spikes from
inflating it (:func:`second_difference_sigma`).  With coarse turntable steps (10 degrees and more)
the curvature of the field's first harmonics no longer cancels, so each flip's low harmonics are
fitted and removed first.

Quantised outputs (integer codes, an ADC's step ``q``: :func:`lattice_step`).  A reading is the
noisy value rounded to the lattice; while the field sweeps across codes, the rounding error is
close to uniform on ``[-q/2, q/2]`` and independent of the noise, so the residual's variance is
Sheppard's ``sigma^2 + q^2 / 12``: that is the floor the fit's residual reaches.  The MAD breaks
on a lattice: the second differences are multiples of ``q``, so their median absolute value is
too, and the MAD floor can only take the values ``0, 0.605 q, 1.21 q, ...``
(``q / (0.6745 sqrt 6)`` apart).  Where ``q`` is small against the noise that rounding is
negligible; where it is not (``q`` above :data:`COARSE_LATTICE` of the MAD floor, e.g. 0.60 q
read at ``q = 3 sigma`` where the truth is ``sqrt(sigma^2 + q^2/12) = 0.44 q``, or 0 at
``q = 6-10 sigma``, where over half the second differences are 0), the variance of the second
differences is taken instead (their mean square over 6, spikes beyond :data:`SPIKE_SIGMAS`
left out), never below ``q^2 / 12``.
"""

from __future__ import annotations

import numpy as np
from scipy.special import chdtrc, ndtri

__all__ = ["COARSE_LATTICE", "DITHER_FRACTION", "dithered", "noise_floor", "quantisation_note", "find_spikes", "lattice_step", "robust_sigma", "chi2_sf",
           "second_difference_sigma", "second_differences", "SPIKE_SIGMAS"]

_NORMAL_MAD = ndtri(0.75)  # the MAD of a unit normal

SPIKE_SIGMAS = 8.0
"""A sample this many noise sigmas off its neighbours' median is a spike (a glitch, not noise)."""
COARSE_LATTICE = 0.5
"""A lattice step above this fraction of the MAD floor makes the floor the second differences' variance."""
_LATTICE_TOLERANCE = 1e-3
"""How far (in steps) a value may lie off the lattice and still be on it (floating-point rounding)."""


def lattice_step(values) -> np.ndarray:
    """The step of the lattice each column's values lie on (an ADC's code step), 0 where they do not.

    Parameters
    ----------
    values : ndarray, shape (n,) or (n, c)

    Returns
    -------
    ndarray, shape () or (c,)
        The smallest gap between distinct values when every value is a whole number of such gaps
        from the smallest (within :data:`_LATTICE_TOLERANCE` of a gap), else 0.

    Examples
    --------
    >>> float(lattice_step(np.array([3.0, 5.0, 4.0, 7.0])))
    1.0
    >>> float(lattice_step(np.array([0.1, 0.25, 0.3])))
    0.0
    """
    v = np.asarray(values, dtype=float)
    if v.ndim == 2:
        return np.array([lattice_step(col) for col in v.T])
    levels = np.unique(v[np.isfinite(v)])
    if levels.size < 2:
        return np.array(0.0)
    step = float(np.min(np.diff(levels)))
    k = (levels - levels[0]) / step
    return np.array(step if np.all(np.abs(k - np.round(k)) < _LATTICE_TOLERANCE) else 0.0)


def second_differences(values: np.ndarray) -> np.ndarray:
    """``r[i-1] - 2 r[i] + r[i+1]`` along the first axis (the interior samples)."""
    return values[:-2] - 2.0 * values[1:-1] + values[2:]


def second_difference_sigma(d: np.ndarray, step=0.0) -> np.ndarray | float:
    """White-noise sigma from second differences of samples on a lattice of step ``step`` (0: none).

    ``MAD(d) / sqrt(6)`` (normalised) where the lattice is fine; where it is coarse (see the module
    docstring) ``sqrt(mean(d^2) / 6)`` over the differences within :data:`SPIKE_SIGMAS` of that
    floor, at least ``step / sqrt(12)``: Sheppard's ``sqrt(sigma^2 + q^2 / 12)``.

    Parameters
    ----------
    d : ndarray, shape (m,) or (m, c)
        Second differences (:func:`second_differences`), output units.
    step : float or ndarray, shape (c,)
        The values' lattice step (:func:`lattice_step`), output units.

    Returns
    -------
    float or ndarray, shape (c,)
    """
    d = np.asarray(d, dtype=float)
    robust = robust_sigma(d) / np.sqrt(6.0)
    step = np.broadcast_to(np.asarray(step, dtype=float), np.shape(robust))
    coarse = step > COARSE_LATTICE * robust
    if not np.any(coarse):
        return robust
    quantum = step / np.sqrt(12.0)
    keep = np.abs(d) <= SPIKE_SIGMAS * np.sqrt(6.0) * np.maximum(robust, quantum)
    kept = np.sqrt(np.sum(np.where(keep, d**2, 0.0), axis=0) / np.maximum(np.sum(keep, axis=0), 1) / 6.0)
    out = np.where(coarse, np.maximum(kept, quantum), robust)
    return out if np.ndim(out) else float(out)


DITHER_FRACTION = 1.0 / 3.0
"""Gaussian noise of at least this fraction of the code step dithers the rounding (Widrow: the
rounding error's dependence on the signal is ``exp(-2 pi^2 sigma^2 / q^2)``, 0.11 here)."""


def dithered(step, floor) -> np.ndarray:
    """Whether each channel's noise dithers its ADC's rounding (True without a lattice).

    The Gaussian part of the floor, ``sqrt(floor^2 - q^2 / 12)``, against :data:`DITHER_FRACTION` of the
    step ``q``.  Undithered rounding is a deterministic sawtooth of the field: structured, so a
    residual's structure test cannot judge it against white noise.
    """
    step = np.broadcast_to(np.asarray(step, dtype=float), np.shape(floor))
    gaussian = np.sqrt(np.maximum(np.asarray(floor, dtype=float) ** 2 - step**2 / 12.0, 0.0))
    return ~(step > 0) | (gaussian >= DITHER_FRACTION * step)


def quantisation_note(step, floor, channels) -> dict | None:
    """What an ADC's step does to the noise floor, when it matters: None unless a channel's rounding
    (``q^2 / 12``) is at least a quarter of its floor's variance.

    Returns
    -------
    dict or None
        ``{"step": {channel: q}, "share_of_floor_variance": {channel: share}, "words": str}``, output
        units; ``words`` says that the ADC limits the calibration.
    """
    step = np.broadcast_to(np.asarray(step, dtype=float), np.shape(floor))
    share = step**2 / 12.0 / np.maximum(np.asarray(floor, dtype=float) ** 2, 1e-300)
    if not np.any(share >= 0.25):
        return None
    named = ", ".join(f"{ch} {q:.3g} ({100 * min(s, 1.0):.0f} %)" for ch, q, s in zip(channels, step, share) if s >= 0.25)
    return {"step": {ch: float(q) for ch, q in zip(channels, step)},
            "share_of_floor_variance": {ch: float(min(s, 1.0)) for ch, s in zip(channels, share)},
            "words": (f"the outputs are quantised (code step, and its share of the noise floor's variance: {named}): "
                      "the ADC's resolution limits the calibration (a finer ADC, or more samples, would narrow it)")}


def noise_floor(platform_deg: np.ndarray, flip_index: np.ndarray, values: np.ndarray,
                step: np.ndarray | float = 0.0) -> np.ndarray:
    """White-noise sigma per channel from second differences within each flip.

    Parameters
    ----------
    platform_deg : ndarray, shape (n,)
        Turntable reading, degrees (samples are ordered by it within each flip).
    flip_index : ndarray of int, shape (n,)
    values : ndarray, shape (n, c)
        Outputs or residuals, output units.
    step : float or ndarray, shape (c,)
        The outputs' lattice step (:func:`lattice_step`; 0: not quantised).

    Returns
    -------
    ndarray, shape (c,)
        Estimated noise sigma in the units of ``values`` (Sheppard's with the quantisation, see the
        module docstring).
    """
    diffs = []
    for k in np.unique(flip_index):
        idx = np.flatnonzero(flip_index == k)
        order = idx[np.argsort(np.mod(platform_deg[idx], 360.0), kind="stable")]
        v = _without_low_harmonics(platform_deg[order], values[order])
        if len(v) >= 3:  # a turn is a circle: difference across the wrap too
            diffs.append(np.roll(v, 1, axis=0) - 2.0 * v + np.roll(v, -1, axis=0))
    return np.asarray(second_difference_sigma(np.concatenate(diffs, axis=0), step))


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
