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
140 deg/s on the quasi-static rows) the rotation came out at 13 deg where the optical reference
says under 1, and the heading spread on the other trials went from 3.5 deg (raw) to 22.7 deg.
Measured there against the optical attitude: the accelerometer's direction is 7 deg from gravity's
at the median quasi-static row (3.4 on the slow trial 01), and the magnetometer is 12-14 ms late;
the field-gravity angle against the true gravity scatters 4.2 deg, 1.45 deg once the magnetometer
is moved 14 ms earlier.  The latency is estimated here too, as the shift of the magnetometer
(:data:`LATENCY_SCAN_S`) that makes the angle most constant (:func:`angle_latency`; 20 ms on
simulated fast rotations 20 ms late, 12 ms on BROAD 06, where the gyro-aided fit says 12.7).

Without a gyro ``w`` is not known, but its part across the field is: the field direction's own turn
rate ``r_k = |du/dt|`` (from the magnetometer alone; a latency does not change it).  The check fits
the squared angle residual on the quasi-static rows as ``e_k^2 = s_0^2 + c r_k^2`` (least squares)
and calls the motion fast when ``c`` is positive beyond :data:`MIN_Z` standard errors and the
angle it adds at the median rate, ``sqrt(c) median(r)``, reaches :data:`MIN_GROWTH_DEG`.  The rotation
to the housing is then not fitted from the accelerometer (frames taken as aligned), said in words
with the latency; with a gyro the gyro-aided fit (:mod:`calibrate.tumble.gyro`) takes over, which fits
the latency and pins each window's tilt with many rows.  A latency alone (no acceleration) would leave
a rotation within 0.3-0.5 deg on the simulated fast rotations, which withholding turns into the whole
2 deg: the price of not fitting 13 deg on BROAD 06, where latency and acceleration come together and
the growth alone cannot tell them apart (its latency, once removed, leaves the growth below the limit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from compass.frames import row_norms

from .alignment import field_gravity_angles, static_mask

__all__ = ["FastMotion", "angle_latency", "fast_motion", "field_turn_rate", "shifted", "FAST_MOTION_WARNING",
           "LATENCY_SCAN_S", "MIN_GROWTH_DEG", "MIN_Z"]

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
    latency_s : float
        The magnetometer's latency against the accelerometer that makes the field-gravity angle most
        constant (:func:`angle_latency`), s.
    growth_after_deg : float
        ``growth_deg`` once the magnetometer is moved ``latency_s`` earlier (0 when no longer significant).
    """

    median_rate_deg_s: float
    growth_deg: float
    floor_deg: float
    z: float
    n_static: int
    latency_s: float
    growth_after_deg: float

    def words(self) -> str:
        after = (f"moved that much earlier, the angle still grows by {self.growth_after_deg:.1f} deg: the "
                 "accelerometer also reads more than gravity" if self.growth_after_deg > 0 else
                 "moved that much earlier, the angle no longer grows with the rate")
        return (f"{FAST_MOTION_WARNING}on the {self.n_static} quasi-static samples the field turns at a median "
                f"{self.median_rate_deg_s:.0f} deg/s and the field-gravity angle scatters more the faster it turns "
                f"({self.growth_deg:.1f} deg at the median rate beside {self.floor_deg:.1f} deg at rest); the "
                f"magnetometer reads about {1e3 * self.latency_s:.0f} ms late against the accelerometer ({after}); "
                "no magnetometer-accelerometer rotation fitted, frames taken as aligned (in fast motion the rotation "
                "takes up what the accelerometer reads beside gravity); tumble slower, or record the gyro "
                "(gx, gy, gz) so that the gyro-aided fit pins the rotation and fits the latency")


def field_turn_rate(mag: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Turn rate of the field's direction at each sample, rad/s, shape (n,) (NaN where no time passed).

    The angle between the neighbours' directions over their time apart (one-sided at the ends); any
    calibration of hard and soft iron leaves it nearly unchanged, a latency not at all.

    Raises
    ------
    ValueError
        ``mag`` not of shape (n, 3) or ``t_s`` not of shape (n,).
    """
    mag, t_s = np.asarray(mag, float), np.asarray(t_s, float)
    if mag.ndim != 2 or mag.shape[1] != 3 or t_s.shape != (len(mag),):
        raise ValueError(f"mag must have shape (n, 3) and t_s shape (n,), got {mag.shape} and {t_s.shape}")
    if len(mag) < 2:
        return np.full(len(mag), np.nan)
    u = mag / row_norms(mag)[:, None]
    before = np.r_[0, np.arange(len(u) - 1)]
    after = np.r_[np.arange(1, len(u)), len(u) - 1]
    angle = np.arccos(np.clip(np.sum(u[before] * u[after], axis=1), -1.0, 1.0))
    span = t_s[after] - t_s[before]
    return np.divide(angle, span, out=np.full(len(u), np.nan), where=span > 0)


LATENCY_SCAN_S = np.arange(-0.06, 0.0605, 0.002)
"""Latencies tried by :func:`angle_latency`, s."""


def shifted(mag: np.ndarray, t_s: np.ndarray, latency_s: float) -> np.ndarray:
    """The readings of a magnetometer ``latency_s`` late moved onto the accelerometer's time: ``mag(t + latency)``
    (linear interpolation; held at the ends)."""
    return np.column_stack([np.interp(t_s + latency_s, t_s, mag[:, i]) for i in range(3)])


def angle_latency(mag_cal, accel, t_s, rows, rotation=None) -> float:
    """The latency (s, in :data:`LATENCY_SCAN_S`) that makes the field-gravity angle over ``rows`` most constant."""
    spread = [np.std(field_gravity_angles(shifted(mag_cal, t_s, tau)[rows], accel[rows], rotation))
              for tau in LATENCY_SCAN_S]
    return float(LATENCY_SCAN_S[int(np.argmin(spread))])


def _growth(mag_cal, accel, rate, rows, rotation):
    """(growth deg, floor deg, z) of ``e^2 = s_0^2 + c r^2`` over ``rows``."""
    angle = field_gravity_angles(mag_cal[rows], accel[rows], rotation)
    e2 = (angle - np.median(angle)) ** 2
    r = rate[rows]
    design = np.column_stack([np.ones_like(r), r**2])
    coef, *_ = np.linalg.lstsq(design, e2, rcond=None)
    spread = e2 - design @ coef
    cov = np.linalg.pinv(design.T @ design) * np.var(spread)
    z = float(coef[1] / np.sqrt(cov[1, 1])) if cov[1, 1] > 0 else 0.0
    return float(np.sqrt(max(coef[1], 0.0)) * np.median(r)), float(np.sqrt(max(coef[0], 0.0))), z


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
    mag_cal, t_s = np.asarray(mag_cal, float), np.asarray(t_s, float)
    growth, floor, z = _growth(mag_cal, accel, rate, rows, rotation)
    if not (z > MIN_Z and growth >= MIN_GROWTH_DEG):
        return None
    tau = angle_latency(mag_cal, accel, t_s, rows, rotation)
    after, _, z_after = _growth(shifted(mag_cal, t_s, tau), accel, rate, rows, rotation)
    return FastMotion(float(np.degrees(np.median(rate[rows]))), growth, floor, z, int(np.count_nonzero(rows)), tau,
                      after if z_after > MIN_Z else 0.0)
