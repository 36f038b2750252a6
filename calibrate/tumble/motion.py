r"""Fast motion: when the field-gravity angle scatters more the faster the housing turns.

The magnetometer-accelerometer rotation rests on the angle between the field and gravity being the
same at every orientation.  Two things break that in proportion to how fast the housing turns:

- a magnetometer ``tau`` late against the accelerometer reads the field of ``t - tau``: in the
  housing turning at ``w``, ``u(t - tau) = u(t) + tau (w x u(t))`` to first order, the field turned
  by ``tau |w_perp|`` (``w_perp``: ``w`` across the field);
- an accelerometer away from the turn's centre reads ``w x (w x r) + dw/dt x r`` beside gravity, and
  the quasi-static selector ``||a| - g|`` does not see a sideways part.

Neither changes ``|m|``: the ellipsoid (hard and soft iron) is blind to both.  Both add to the
field-gravity angle an error that grows with the rate, so the fitted rotation absorbs whatever of it
correlates with the orientation: on BROAD's fast rotation (trial 06: the field turning at a median
130 deg/s on the quasi-static rows) the rotation came out at 13 deg where the optical reference
says under 1, and the heading spread on the other trials went from 3.5 deg (raw) to 22.7 deg.

Without a gyro ``w`` is not known, but its part across the field is: the field direction's own turn
rate ``r_k = |du/dt|`` (from the magnetometer alone; a latency does not change it).  The check fits
the squared angle residual on the quasi-static rows as ``e_k^2 = s_0^2 + c r_k^2`` (least squares)
and calls the motion fast when ``c`` is positive beyond :data:`MIN_Z` standard errors and the
angle it adds at the median rate, ``sqrt(c) median(r)``, reaches :data:`MIN_GROWTH_DEG`.  The rotation
to the housing is then not fitted from the accelerometer (frames taken as aligned), said in words;
with a gyro the gyro-aided fit (:mod:`calibrate.tumble.gyro`) takes over, which fits the latency.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .alignment import field_gravity_angles, static_mask

__all__ = ["FastMotion", "fast_motion", "field_turn_rate", "FAST_MOTION_WARNING", "MIN_GROWTH_DEG", "MIN_Z"]

MIN_GROWTH_DEG = 2.0
"""Motion is fast when the angle it adds at the median rate reaches this, deg: the size of a typical
mounting rotation between the chips (the simulators' 2 deg), which a motion adding as much to the angle
cannot resolve.  (The simulated hand tumble of :mod:`compass.sim.tumble`, whose hand accelerates as it
turns, adds 0.3-1.1 deg; a 20 ms latency in its fast rotation 2.3-2.4 deg; BROAD's fast rotation 2.5.)"""

MIN_Z = 3.0
"""... and the growth with the rate is this many standard errors above zero."""

FAST_MOTION_WARNING = "fast motion: "
"""How the warning begins (superseded when the gyro-aided fit is used)."""

_MIN_ROWS = 20


@dataclass(frozen=True)
class FastMotion:
    """The evidence that the field-gravity angle grows with the turn rate.

    Attributes
    ----------
    median_rate_deg_s : float
        Median turn rate of the field direction over the quasi-static rows, deg/s.
    growth_deg : float
        ``sqrt(c) median(r)``: the angle scatter the motion adds at the median rate, deg.
    floor_deg : float
        ``s_0``: the scatter at rest, deg.
    z : float
        ``c`` over its standard error.
    n_static : int
    """

    median_rate_deg_s: float
    growth_deg: float
    floor_deg: float
    z: float
    n_static: int

    def words(self) -> str:
        return (f"{FAST_MOTION_WARNING}on the {self.n_static} quasi-static samples the field turns at a median "
                f"{self.median_rate_deg_s:.0f} deg/s and the field-gravity angle scatters more the faster it turns "
                f"({self.growth_deg:.1f} deg at the median rate beside {self.floor_deg:.1f} deg at rest): the "
                "accelerometer reads more than gravity, or the magnetometer lags it (a 14 ms latency turns the field "
                f"by {self.median_rate_deg_s * 0.014:.1f} deg at that rate); no magnetometer-accelerometer rotation "
                "fitted, frames taken as aligned; tumble slower, or record the gyro (gx, gy, gz) so that the "
                "gyro-aided fit estimates the latency")


def field_turn_rate(mag: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Turn rate of the field's direction at each sample, rad/s, shape (n,) (NaN where no time passed).

    The angle between the neighbours' directions over their time apart (one-sided at the ends); any
    calibration of hard and soft iron leaves it nearly unchanged, a latency not at all.
    """
    mag, t_s = np.asarray(mag, float), np.asarray(t_s, float)
    if mag.ndim != 2 or mag.shape[1] != 3 or t_s.shape != (len(mag),):
        raise ValueError(f"mag must have shape (n, 3) and t_s shape (n,), got {mag.shape} and {t_s.shape}")
    if len(mag) < 2:
        return np.full(len(mag), np.nan)
    u = mag / np.linalg.norm(mag, axis=1, keepdims=True)
    before = np.r_[0, np.arange(len(u) - 1)]
    after = np.r_[np.arange(1, len(u)), len(u) - 1]
    angle = np.arccos(np.clip(np.sum(u[before] * u[after], axis=1), -1.0, 1.0))
    span = t_s[after] - t_s[before]
    return np.divide(angle, span, out=np.full(len(u), np.nan), where=span > 0)


def fast_motion(mag_cal: np.ndarray, accel: np.ndarray, t_s: np.ndarray,
                rotation: Rotation | None = None) -> FastMotion | None:
    """The evidence of fast motion (see the module docstring), or None when the motion is not fast.

    Parameters
    ----------
    mag_cal : ndarray, shape (n, 3)
        Calibrated field, magnetometer frame, in time order.
    accel : ndarray, shape (n, 3)
        Accelerometer at the same rows, any unit.
    t_s : ndarray, shape (n,)
        Time, s, non-decreasing.
    rotation : Rotation, optional
        ``mag_to_accel`` fitted on the same rows (the angle residual is taken after it).

    Returns
    -------
    FastMotion or None
        None also with fewer than 20 quasi-static rows with a rate.

    Raises
    ------
    ValueError
        Arrays of different shapes.
    """
    accel = np.asarray(accel, float)
    rate = field_turn_rate(mag_cal, t_s)
    if accel.shape != np.shape(mag_cal):
        raise ValueError(f"accel must have the shape of mag_cal {np.shape(mag_cal)}, got {accel.shape}")
    rows = static_mask(accel) & np.isfinite(rate)
    if np.count_nonzero(rows) < _MIN_ROWS:
        return None
    angle = field_gravity_angles(np.asarray(mag_cal, float)[rows], accel[rows], rotation)
    e2 = (angle - np.median(angle)) ** 2
    r = rate[rows]
    design = np.column_stack([np.ones_like(r), r**2])
    coef, *_ = np.linalg.lstsq(design, e2, rcond=None)
    spread = e2 - design @ coef
    cov = np.linalg.pinv(design.T @ design) * np.var(spread)
    z = float(coef[1] / np.sqrt(cov[1, 1])) if cov[1, 1] > 0 else 0.0
    median = float(np.median(r))
    growth = float(np.sqrt(max(coef[1], 0.0)) * median)
    if not (z > MIN_Z and growth >= MIN_GROWTH_DEG):
        return None
    return FastMotion(float(np.degrees(median)), growth, float(np.sqrt(max(coef[0], 0.0))), z, int(np.count_nonzero(rows)))
