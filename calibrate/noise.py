"""Noise floor of a recording, estimated from the data itself.

Second differences of neighbouring samples along the turntable angle cancel every smooth
signal (the field's harmonics, slow drifts, any smooth model error) and keep white noise:
for i.i.d. noise of variance sigma^2, ``d_i = r_{i-1} - 2 r_i + r_{i+1}`` has variance
``6 sigma^2``.  A robust scale (normalised median absolute deviation) keeps rare spikes from
inflating it.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import median_abs_deviation

__all__ = ["noise_floor"]


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
        v = values[order]
        if len(v) >= 3:
            diffs.append(v[:-2] - 2.0 * v[1:-1] + v[2:])
    d = np.concatenate(diffs, axis=0)
    return median_abs_deviation(d, axis=0, scale="normal") / np.sqrt(6.0)
