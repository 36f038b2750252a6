"""The effect forms every kind's diagnosis shares: when a recording can show a time or temperature
effect, the warm-up's settling curve, and the small numeric helpers of the diagnosis blocks.

Each kind writes its effects against its own model (the four-flip changes the bench physics, the
fits against known inputs add to the predicted outputs, the tumble corrects the readings), but the
forms in time and temperature are the same functions, here once:

- warm-up: ``1 - exp(-(t - t_ref) / tau)`` with ``tau = session exp(q)``, the log-ratio ``q``
  clipped so the fit cannot run to a step or a line (:func:`settled`, :func:`warm_up_tau_s`);
- drift and temperature: polynomials in ``(t - t_ref) / session`` and ``(T - T_ref) / span``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TIME_BINS", "WARMUP_TAU_FRACTIONS", "json_float", "rms", "session_bin", "settled", "warm_up_tau_s",
           "why_no_temperature", "why_no_time"]

WARMUP_TAU_FRACTIONS = (0.03, 0.07, 0.15, 0.3, 0.6)
"""Time constants (fractions of the session) at which a warm-up's score test is evaluated."""
TIME_BINS = 10000
"""Equal bins of the session within which a fit may take samples as simultaneous (:func:`session_bin`).

A warm-up of size ``A`` differs over a bin ``w`` from its value at the bin's mean time by
``A (w / tau)^2 / 24``: 5e-7 A at the shortest time constant the score tests start from (3 % of the
session), 7e-5 A at the shortest a fit allows (0.25 %); a drift linear in time not at all."""


def why_no_time(t_s) -> str | None:
    """Why a recording cannot show an effect in time (no ``t_s``, or one that never changes), else None."""
    if t_s is None:
        return "the recording has no t_s column"
    if not np.ptp(t_s) > 0:
        return "t_s never changes"
    return None


def why_no_temperature(temp_c) -> str | None:
    """Why a recording cannot show a temperature effect (no ``temp_c``, or under 0.5 degC of change), else None."""
    if temp_c is None:
        return "the recording has no temp_c column"
    if np.ptp(temp_c) < 0.5:
        return "temp_c varies by less than 0.5 degC"
    return None


def session_bin(t_s) -> np.ndarray | None:
    """Each sample's bin of the session (:data:`TIME_BINS` equal bins), None without a changing ``t_s``."""
    if t_s is None or not np.ptp(t_s) > 0:
        return None
    return np.minimum((t_s - np.min(t_s)) * (TIME_BINS / np.ptp(t_s)), TIME_BINS - 1).astype(int)


def warm_up_tau_s(session_s: float, log_ratio: float, low: float = -6.0, high: float = 3.0) -> float:
    """A warm-up's time constant, s: ``session_s exp(log_ratio)`` with the log-ratio clipped to [low, high]."""
    return session_s * np.exp(np.clip(log_ratio, low, high))


def settled(t_s: np.ndarray, t_ref_s: float, tau_s: float) -> np.ndarray:
    """The fraction of a warm-up's change reached at ``t_s``: ``1 - exp(-(t - t_ref) / tau)``."""
    return -np.expm1(-(t_s - t_ref_s) / tau_s)


def json_float(v: float) -> float | None:
    """``v`` for a JSON block: None when not finite."""
    return float(v) if np.isfinite(v) else None


def rms(values: np.ndarray) -> float:
    """Root mean square of every element."""
    return float(np.sqrt(np.mean(values**2)))
