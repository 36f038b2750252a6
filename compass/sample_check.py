"""Readings that must never be fused: not finite, or beyond anything the sensors can read.

A well-formed line can still carry a reading no filter should see: ``1e300`` from a firmware bug,
a NaN from a calibration, a field a thousand times the Earth's.  :func:`skip_codes` flags them per
sample, with the reason; the callers (``compass live``, ``compass attitude``) skip those samples,
count the reasons and say so.  The limits are deliberately far from any physical reading, so a
real disturbance (a magnet, a shock) is never skipped here: judging those is the filter's and the
disturbance flag's job.

- field: ``|B|`` more than :data:`FIELD_RATIO_LIMIT` times the expected ``|B|`` (the Earth's field
  is 25-65 uT; a hundred times that is a magnet on the sensor, far beyond its calibrated range);
- accelerometer (any unit): ``|a|`` more than :data:`ACCEL_RATIO_LIMIT` times its typical
  magnitude (gravity, in whatever unit the module sends), or zero;
- gyro (rad/s): ``|w|`` above :data:`GYRO_LIMIT_RAD_S` (MEMS gyros saturate below 70 rad/s).
"""

from __future__ import annotations

import numpy as np

__all__ = ["SKIP_REASONS", "FIELD_RATIO_LIMIT", "ACCEL_RATIO_LIMIT", "GYRO_LIMIT_RAD_S", "RAIL_MIN_RAD_S",
           "RAIL_SAMPLES", "skip_codes", "new_readings", "GyroRail"]

SKIP_REASONS = ("ok", "field not finite", "field out of range", "accel not finite or out of range",
                "gyro not finite or out of range")
"""Reason of each code :func:`skip_codes` returns (index = code)."""
FIELD_RATIO_LIMIT = 100.0
ACCEL_RATIO_LIMIT = 1000.0
GYRO_LIMIT_RAD_S = 1e4
RAIL_MIN_RAD_S = 2.0
"""Smallest |rate| a gyro's rail can be, rad/s: below the smallest full scale of MEMS gyros (125 deg/s, 2.18 rad/s)."""
RAIL_SAMPLES = 10
"""Samples in a row holding one rate of at least :data:`RAIL_MIN_RAD_S` that make a rail: a turning gyro's noise
(0.1 deg/s, more than a 16-bit count at 2000 deg/s full scale) changes its reading from sample to sample."""


def skip_codes(field, field_scale: float, accel=None, accel_scale: float | None = None, gyro=None) -> np.ndarray:
    """Per sample: 0 when it may be fused, else the code of the first reason (:data:`SKIP_REASONS`).

    Parameters
    ----------
    field : array_like, shape (n, 3)
        Field in the housing frame H, the calibration's unit.
    field_scale : float
        Expected ``|B|``, same unit (the reference's, or a robust typical value); NaN: only
        non-finite fields are flagged.
    accel : array_like, shape (n, 3), optional
        Accelerometer in H, any unit; rows of NaN mean "not measured" and pass.
    accel_scale : float, optional
        Typical ``|a|`` (gravity) in the accelerometer's unit; without it only non-finite and zero
        readings are flagged.
    gyro : array_like, shape (n, 3), optional
        Angular rate, rad/s; rows of NaN mean "not measured" and pass.

    Returns
    -------
    ndarray of int, shape (n,)

    Examples
    --------
    >>> skip_codes([[20.0, 0, -40], [1e300, 0, 0], [np.nan, 0, 0]], 50.0).tolist()
    [0, 2, 1]
    """
    field = np.atleast_2d(np.asarray(field, dtype=float))
    codes = np.zeros(len(field), dtype=int)
    with np.errstate(over="ignore", invalid="ignore"):
        b = np.linalg.norm(field, axis=1)
        if np.isfinite(field_scale) and field_scale > 0:
            codes[~(b <= FIELD_RATIO_LIMIT * field_scale)] = 2
        codes[~np.all(np.isfinite(field), axis=1)] = 1
        for values, code, bad in ((accel, 3, _accel_bad(accel, accel_scale)), (gyro, 4, _gyro_bad(gyro))):
            if values is not None:
                codes[(codes == 0) & bad] = code
    return codes


def _measured(values) -> tuple[np.ndarray, np.ndarray]:
    """(rows, norms) with rows all-NaN ('not measured') given norm NaN."""
    v = np.atleast_2d(np.asarray(values, dtype=float))
    with np.errstate(over="ignore", invalid="ignore"):  # a 1e300 reading: its norm inf, flagged by the caller
        return v, np.linalg.norm(v, axis=1)


def _accel_bad(accel, scale) -> np.ndarray | None:
    if accel is None:
        return None
    a, norm = _measured(accel)
    absent = np.all(np.isnan(a), axis=1)
    bad = ~np.all(np.isfinite(a), axis=1) | (norm == 0)
    if scale is not None and np.isfinite(scale) and scale > 0:
        bad |= norm > ACCEL_RATIO_LIMIT * scale
    return bad & ~absent


def _gyro_bad(gyro) -> np.ndarray | None:
    if gyro is None:
        return None
    w, norm = _measured(gyro)
    absent = np.all(np.isnan(w), axis=1)
    return (~np.all(np.isfinite(w), axis=1) | (norm > GYRO_LIMIT_RAD_S)) & ~absent


def new_readings(readings) -> np.ndarray:
    """Rows whose reading differs from the row before's in some component (the first row is new), shape (n,): a
    sensor slower than the stream repeats its last reading until its next conversion, and a repeat is no new
    measurement.

    Parameters
    ----------
    readings : array_like, shape (n, c)
        One sensor's readings as sent, in order.
    """
    readings = np.asarray(readings)
    return np.r_[True, np.any(readings[1:] != readings[:-1], axis=1)]


class GyroRail:
    """Watch a gyro for an axis held at its range (saturated): the same rate of at least :data:`RAIL_MIN_RAD_S`
    in :data:`RAIL_SAMPLES` samples in a row.

    A gyro turned faster than its full scale reads the full scale: the turn beyond it is lost, and the attitude
    is off by it (a 565 deg/s flick on a 250 deg/s gyro: 35 deg of heading) until the field and the
    accelerometer correct it; the gyro filter learns the rail by the same rule and takes the hidden turn as noise
    (:mod:`compass.filter._rail`).  Nothing here changes the samples: :meth:`feed` says it, once.

    Examples
    --------
    >>> rail = GyroRail()
    >>> rail.feed([[0.1, 0.0, 4.3633]] * 12, [0.01 * k for k in range(12)])[:47]
    "the gyro's z axis reads 4.363 rad/s (250 deg/s)"
    >>> rail.feed([[0.1, 0.0, 4.3633]] * 12, [0.01 * k for k in range(12)]) is None  # said once
    True
    """

    def __init__(self):
        self.said = False
        self._last = np.full(3, np.nan)  # the last sample fed
        self._run = np.zeros(3, dtype=int)  # repeats of it ending there, per axis

    def feed(self, gyro, t_s) -> str | None:
        """The next samples, in order: words the first time an axis holds a rail, else None.

        Parameters
        ----------
        gyro : array_like, shape (n, 3)
            Angular rate as the module sends it (its axes), rad/s.
        t_s : array_like, shape (n,)
            The samples' times, seconds (for the words).
        """
        g = np.asarray(gyro, dtype=float).reshape(-1, 3)
        if self.said or len(g) == 0:
            return None
        held = (g == np.vstack([self._last, g[:-1]])) & (np.abs(g) >= RAIL_MIN_RAD_S)  # repeats the sample before
        k = np.arange(len(g))[:, None]
        since = np.maximum.accumulate(np.where(held, -1, k), axis=0)  # the last sample that repeated nothing
        run = np.where(held, k - since + np.where(since < 0, self._run, 0), 0)  # repeats ending at each sample
        self._last, self._run = g[-1].copy(), run[-1]
        hits = np.argwhere(run + 1 >= RAIL_SAMPLES)
        if len(hits) == 0:
            return None
        i, axis = hits[0]
        self.said = True
        rate = float(g[i, axis])
        return (f"the gyro's {'xyz'[axis]} axis reads {rate:.4g} rad/s ({np.degrees(rate):.0f} deg/s) in "
                f"{RAIL_SAMPLES} samples in a row by t_s {float(np.asarray(t_s, dtype=float)[i]):.2f} s: saturated at "
                "its range? The turn beyond the range is lost, and the attitude is off by it until the field and the "
                "accelerometer bring it back")
