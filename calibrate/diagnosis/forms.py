"""Small helpers every kind's diagnosis shares: the session's time bins and the numbers of its blocks.

The effects themselves, and their forms in time and temperature, are :mod:`calibrate.effects`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TIME_BINS", "json_float", "rms", "session_bin"]

TIME_BINS = 10000
"""Equal bins of the session within which a fit may take samples as simultaneous (:func:`session_bin`).

A warm-up of size ``A`` differs over a bin ``w`` from its value at the bin's mean time by
``A (w / tau)^2 / 24``: 5e-7 A at the shortest time constant the score tests start from (3 % of the
session), 7e-5 A at the shortest a fit allows (0.25 %); a drift linear in time not at all."""


def session_bin(t_s) -> np.ndarray | None:
    """Each sample's bin of the session (:data:`TIME_BINS` equal bins), None without a changing ``t_s``."""
    if t_s is None or not np.ptp(t_s) > 0:
        return None
    return np.minimum((t_s - np.min(t_s)) * (TIME_BINS / np.ptp(t_s)), TIME_BINS - 1).astype(int)


def json_float(v: float) -> float | None:
    """``v`` for a JSON block: None when not finite."""
    return float(v) if np.isfinite(v) else None


def rms(values: np.ndarray) -> float:
    """Root mean square of every element."""
    return float(np.sqrt(np.mean(values**2)))
