"""Slow changes of a simulated session, shared by the simulators: its clock, an offset drift, a temperature cycle."""

from __future__ import annotations

import numpy as np

TEMP_REF_C = 25.0
"""Centre of the simulated temperature cycle, degC (where the truth's offsets hold)."""


def check_session(session_s: float | None, drift: float, option: str) -> None:
    """ValueError for a drift without a session length, or a session length that is not positive."""
    if drift and session_s is None:
        raise ValueError(f"{option} needs session_s (the drift is a function of t_s)")
    if session_s is not None and not session_s > 0:
        raise ValueError(f"session_s must be positive, got {session_s}")


def session_clock(n: int, session_s: float | None) -> np.ndarray | None:
    """``t_s`` of ``n`` rows evenly spaced over the session, s; None without a session length."""
    return None if session_s is None else np.linspace(0.0, session_s, n)


def drift_profile(t_s: np.ndarray, session_s: float, tau_s: float | None) -> tuple[np.ndarray, str]:
    """Fraction of a drift's change reached at each ``t_s``, and the form in words.

    Constant rate over the session when ``tau_s`` is None, else a warm-up ``1 - exp(-t / tau_s)``.
    """
    if tau_s is None:
        return t_s / session_s, "linear over the session"
    return -np.expm1(-t_s / tau_s), "exponential warm-up"


def chamber_temperature(n: int, swing_c: float) -> np.ndarray:
    """True temperature of ``n`` rows, degC: two cycles of ``TEMP_REF_C + swing sin``, so not a function of time."""
    return TEMP_REF_C + swing_c * np.sin(4.0 * np.pi * np.arange(n) / max(n - 1, 1))
