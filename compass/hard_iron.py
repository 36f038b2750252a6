"""Causal detection and estimation of hard-iron steps (a magnet or steel part fixed to the housing).

A magnetised part that moves with the housing adds a constant field ``b`` in the housing frame:
the magnetometer reads ``m = B_H + b``.  Turned through many orientations, ``m`` then lies on a
sphere of radius ``|B|`` about ``b``, and ``(m - b)`` keeps the calibrated dip to gravity.  In each
window of the last ``window_s`` seconds (re-examined every ``hop_s``) the offset is fitted to both,

.. math::

    \\min_b \\sum_i \\big(|m_i - b| - F\\big)^2 + \\big(\\hat u_i \\cdot (m_i - b) + F \\sin\\delta\\big)^2,

with ``delta`` the calibrated dip, ``u_i`` the accelerometer's up direction and the norm ``F``
fitted with ``b`` (the norm drifts by a few percent across a room; a fixed one would pass for a step).  A *step* is declared when the window's fit is good (rms below ``fit_rms_ut``), its
offset is determined (every standard error below ``sigma_ut``), it differs from the offset in use
by more than ``min_step_ut``, and the offset in use explains the window at least ``ratio`` times
worse.  After a step the offset is refined on all data since the step (up to ``max_window_s``);
when that fit turns poor and no offset explains the data better than none, the offset is dropped.
The step back (the part removed) is found like the step.  Only samples up to the window's
end are used, so the estimate at time ``t`` is causal; it lags the physical step by up to
``window_s + hop_s``, during which a disturbance gate must carry the attitude.

A field disturbance fixed in the room (a magnet on the table) does not follow the housing: no
constant ``b`` explains it, the window's fit stays poor and no step is declared.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

__all__ = ["HardIronTrack", "track_hard_iron"]


@dataclass(frozen=True)
class HardIronTrack:
    """Result of :func:`track_hard_iron`.

    Attributes
    ----------
    offset_ut : ndarray, shape (n, 3)
        Offset in use at every sample, housing frame, uT (zero until the first step).
    step_t_s : ndarray, shape (k,)
        Times at which a step was declared (end of the window that showed it), s.
    step_offset_ut : ndarray, shape (k, 3)
        The offset adopted at each step, uT.
    window_rms_ut : ndarray, shape (w,)
        Fit rms of each examined window (NaN where the window was not determined), uT.
    window_end_t_s : ndarray, shape (w,)
    """

    offset_ut: np.ndarray
    step_t_s: np.ndarray
    step_offset_ut: np.ndarray
    window_rms_ut: np.ndarray
    window_end_t_s: np.ndarray

    def corrected(self, mag_ut) -> np.ndarray:
        """``m - offset``, shape (n, 3), uT."""
        return np.asarray(mag_ut, dtype=float) - self.offset_ut


def _norm_for(d: np.ndarray, u: np.ndarray, sin_dip: float) -> float:
    """Field norm that best explains offset-free vectors ``d`` at a fixed offset (closed form)."""
    return float((np.sum(np.linalg.norm(d, axis=1)) - sin_dip * np.sum(np.einsum("ij,ij->i", u, d)))
                 / (len(d) * (1.0 + sin_dip**2)))


def _residuals(d: np.ndarray, u: np.ndarray, norm: float, sin_dip: float) -> np.ndarray:
    """Norm residuals, then dip residuals, field units."""
    return np.concatenate([np.linalg.norm(d, axis=1) - norm, np.einsum("ij,ij->i", u, d) + norm * sin_dip])


def _fit_window(m: np.ndarray, u: np.ndarray, sin_dip: float, start: np.ndarray, min_spread: float):
    """Offset and field-norm fit of one window: (offset, rms, offset sigma per axis), field units.

    Sigma is infinite when the window's field spans less than ``min_spread`` (rms about its mean)
    along some axis: the housing did not turn enough to locate the sphere's centre.
    """
    spread = np.linalg.svd(m - m.mean(axis=0), compute_uv=False)[-1] / np.sqrt(len(m))
    if spread < min_spread:
        return start, np.inf, np.full(3, np.inf)
    sol = least_squares(lambda p: _residuals(m - p[:3], u, p[3], sin_dip),
                        np.r_[start, _norm_for(m - start, u, sin_dip)], method="lm")
    rms = float(np.sqrt(np.sum(sol.fun**2) / max(2 * len(m) - 4, 1)))
    try:
        sigma = rms * np.sqrt(np.diag(np.linalg.inv(sol.jac.T @ sol.jac))[:3])
    except np.linalg.LinAlgError:
        sigma = np.full(3, np.inf)
    return sol.x[:3], rms, sigma


def _rms_at(m: np.ndarray, u: np.ndarray, sin_dip: float, offset: np.ndarray) -> float:
    d = m - offset
    return float(np.sqrt(np.mean(_residuals(d, u, _norm_for(d, u, sin_dip), sin_dip) ** 2)))


def track_hard_iron(mag_ut, accel, rate_hz: float, *, dip_deg: float, window_s: float = 4.0,
                    hop_s: float = 0.5, max_window_s: float = 30.0, fit_rms_ut: float = 2.5, sigma_ut: float = 1.0,
                    min_step_ut: float = 3.0, ratio: float = 2.0, min_spread_ut: float = 5.0,
                    max_points: int = 600) -> HardIronTrack:
    """Track the housing-fixed offset of a magnetometer through time, causally.

    Parameters
    ----------
    mag_ut : array_like, shape (n, 3)
        Calibrated magnetometer in the housing frame, uT (other units: scale the ``*_ut`` options).
    accel : array_like, shape (n, 3)
        Accelerometer in the same frame, specific force (+up at rest), any unit.
    rate_hz : float
        Sampling rate.
    dip_deg : float
        The undisturbed field's dip (> 0 down), degrees.
    window_s, hop_s : float
        Length of the window that detects a step and the spacing of window ends, s.
    max_window_s : float
        After a step, the offset is refined on every sample since the step, up to this many
        seconds back, s.
    fit_rms_ut, sigma_ut, min_step_ut, ratio : float
        Acceptance of a step (see the module docstring); field units.  Defaults follow the
        floor of |B| constancy in a real room (about 1.5 uT) and are not tuned per recording.
        A step back to within ``min_step_ut`` of zero returns to the calibration's zero offset.
    min_spread_ut : float
        A window counts only when its field spreads by this much (rms) along every axis: the
        housing turned enough to locate the offset.
    max_points : int
        Windows are decimated to at most this many samples (speed; neighbours are nearly equal).

    Returns
    -------
    HardIronTrack

    Raises
    ------
    ValueError
        Shapes differ, or a non-positive rate, window or hop.
    """
    m = np.asarray(mag_ut, dtype=float)
    a = np.asarray(accel, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3 or a.shape != m.shape:
        raise ValueError(f"expected mag and accel of the same shape (n, 3), got {m.shape} and {a.shape}")
    for name, value in (("rate_hz", rate_hz), ("window_s", window_s), ("hop_s", hop_s)):
        if not value > 0:
            raise ValueError(f"{name} must be positive, got {value}")
    u = a / np.linalg.norm(a, axis=1, keepdims=True)
    sin_dip = float(np.sin(np.radians(dip_deg)))
    n = len(m)
    width = max(int(round(window_s * rate_hz)), 12)
    longest = max(int(round(max_window_s * rate_hz)), width)
    hop = max(int(round(hop_s * rate_hz)), 1)
    current = np.zeros(3)
    since = None  # first sample of the current step's data, None while no step is in use
    offset = np.zeros((n, 3))
    steps_t, steps_b, rms_all, ends = [], [], [], []
    for end in range(width, n + 1, hop):
        sl = slice(end - width, end, max(width // max_points, 1))
        b, rms, sigma = _fit_window(m[sl], u[sl], sin_dip, current, min_spread_ut)
        ends.append(end / rate_hz)
        determined = bool(np.all(sigma < sigma_ut))
        rms_all.append(rms if determined else np.nan)
        if (determined and rms < fit_rms_ut and np.linalg.norm(b - current) > min_step_ut
                and _rms_at(m[sl], u[sl], sin_dip, current) > ratio * rms):
            current, since = (b, end - width) if np.linalg.norm(b) > min_step_ut else (np.zeros(3), None)
            steps_t.append(end / rate_hz)
            steps_b.append(b)
        elif since is not None and end - since > width:  # refine the step's offset on all its data
            start = max(since, end - longest)
            sl = slice(start, end, max((end - start) // max_points, 1))
            b, rms, sigma = _fit_window(m[sl], u[sl], sin_dip, current, min_spread_ut)
            if np.all(sigma < sigma_ut) and rms < fit_rms_ut:
                current = b
            elif _rms_at(m[sl], u[sl], sin_dip, np.zeros(3)) < _rms_at(m[sl], u[sl], sin_dip, current):
                current, since = np.zeros(3), None  # the step's offset no longer explains the field
                steps_t.append(end / rate_hz)
                steps_b.append(current)
        offset[end:] = current
    return HardIronTrack(offset_ut=offset, step_t_s=np.array(steps_t), step_offset_ut=np.array(steps_b).reshape(-1, 3),
                         window_rms_ut=np.array(rms_all), window_end_t_s=np.array(ends))
