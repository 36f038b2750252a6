"""Orientation error against a ground truth, with BROAD's metric.

BROAD's metric (Laidig et al., Data 6(7):72, 2021, https://doi.org/10.3390/data6070072): with
``q_est`` and ``q_ref`` unit quaternions mapping body to ENU (scalar first), the error quaternion
``e = q_est q_ref^-1`` is a rotation in the world frame; its part about the vertical is the heading
error and the rest the inclination error,

.. math::

    \\epsilon_h = 2 \\arctan \\left| \\frac{e_z}{e_w} \\right|, \\qquad
    \\epsilon_i = 2 \\arccos \\sqrt{e_w^2 + e_z^2},

RMS over the samples with ``movement == 1`` whose reference exists, no offset removed; a group's
figure is the mean of its trials' RMS.  Both angles depend only on the world's vertical axis, so
they are the same for an NWU world (the toolkit's) as for ENU, once both quaternions share the world.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["METRIC", "ErrorSeries", "orientation_errors", "error_series"]

METRIC = ("BROAD metric: e = q_est * q_ref^-1 (body->ENU, scalar first); heading 2 atan|e_z/e_w|, "
          "inclination 2 acos sqrt(e_w^2 + e_z^2); RMS over movement == 1, NaN reference rows skipped")


def orientation_errors(estimate: Rotation, reference: Rotation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heading, signed heading and inclination error of each sample, degrees.

    Parameters
    ----------
    estimate, reference : Rotation, n rotations each
        ``R_world<-body`` in one world frame with +Z up (ENU or NWU).

    Returns
    -------
    heading_deg : ndarray, shape (n,)
        ``2 atan(|e_z / e_w|)`` in [0, 180].
    signed_heading_deg : ndarray, shape (n,)
        The same angle with the sign of the error rotation about +Z (estimate turned
        counterclockwise seen from above is positive), in (-180, 180].
    inclination_deg : ndarray, shape (n,)
        ``2 acos(sqrt(e_w^2 + e_z^2))`` in [0, 180].

    Examples
    --------
    >>> ref = Rotation.from_euler("ZYX", [30, 10, 5], degrees=True)
    >>> est = Rotation.from_euler("z", 2, degrees=True) * ref
    >>> [round(float(v[0]), 6) for v in orientation_errors(est, ref)]
    [2.0, 2.0, 0.0]
    """
    e = (estimate * reference.inv()).as_quat(canonical=True, scalar_first=True).reshape(-1, 4)
    w, z = e[:, 0], e[:, 3]  # canonical: w >= 0
    signed = np.degrees(2.0 * np.arctan2(z, w))
    inclination = np.degrees(2.0 * np.arccos(np.clip(np.hypot(w, z), 0.0, 1.0)))
    return np.abs(signed), signed, inclination


@dataclass(frozen=True)
class ErrorSeries:
    """Errors of one trial over time and their RMS on the scored samples (BROAD's metric).

    Attributes
    ----------
    t_s : ndarray, shape (n,)
        Sample times, s.
    scored : ndarray of bool, shape (n,)
        ``movement == 1`` and the reference exists.
    heading_deg, signed_heading_deg, inclination_deg : ndarray, shape (n,)
        Per-sample errors (NaN where the reference is missing), degrees, offset kept.
    heading_offset_deg : float
        The constant heading offset: circular mean of the signed heading error over the scored samples.
    heading_rms_deg, inclination_rms_deg : float
        BROAD's figures: RMS over the scored samples, offset kept.
    heading_rms_offset_removed_deg : float
        Heading RMS after removing ``heading_offset_deg`` (fitted on the same samples it is scored on:
        a best case, not BROAD's figure).
    """

    t_s: np.ndarray
    scored: np.ndarray
    heading_deg: np.ndarray
    signed_heading_deg: np.ndarray
    inclination_deg: np.ndarray
    heading_offset_deg: float
    heading_rms_deg: float
    inclination_rms_deg: float
    heading_rms_offset_removed_deg: float

    @property
    def heading_offset_removed_deg(self) -> np.ndarray:
        """``|signed heading error - offset|`` per sample, wrapped to [0, 180], degrees."""
        return np.abs(np.mod(self.signed_heading_deg - self.heading_offset_deg + 180.0, 360.0) - 180.0)


def error_series(estimate_quat_enu, reference_quat_enu, movement, rate_hz: float) -> ErrorSeries:
    """BROAD's errors of one trial.

    Parameters
    ----------
    estimate_quat_enu : array_like, shape (n, 4)
        Estimated ``R_ENU<-body``, scalar first; must be finite wherever the sample is scored.
    reference_quat_enu : array_like, shape (n, 4)
        Ground truth, scalar first; NaN rows are skipped.
    movement : array_like of bool, shape (n,)
    rate_hz : float

    Returns
    -------
    ErrorSeries

    Raises
    ------
    ValueError
        Shapes differ, no scored sample, or a scored estimate is not finite.
    """
    est = np.asarray(estimate_quat_enu, dtype=float)
    ref = np.asarray(reference_quat_enu, dtype=float)
    movement = np.asarray(movement, dtype=bool)
    n = len(ref)
    if est.shape != (n, 4) or ref.shape != (n, 4) or movement.shape != (n,):
        raise ValueError(f"expected estimate (n, 4), reference (n, 4), movement (n,), got {est.shape}, "
                         f"{ref.shape}, {movement.shape}")
    valid = np.all(np.isfinite(ref), axis=1)
    scored = movement & valid
    if not scored.any():
        raise ValueError("no sample is both in the movement phase and has a reference")
    if not np.all(np.isfinite(est[scored])):
        raise ValueError(f"estimate is not finite at scored sample {int(np.argmax(~np.isfinite(est[scored]).all(1)))}")
    heading = np.full(n, np.nan)
    signed = np.full(n, np.nan)
    inclination = np.full(n, np.nan)
    ok = valid & np.all(np.isfinite(est), axis=1)
    heading[ok], signed[ok], inclination[ok] = orientation_errors(
        Rotation.from_quat(est[ok], scalar_first=True), Rotation.from_quat(ref[ok], scalar_first=True))
    s = np.radians(signed[scored])
    offset = float(np.degrees(np.arctan2(np.mean(np.sin(s)), np.mean(np.cos(s)))))
    removed = np.mod(signed[scored] - offset + 180.0, 360.0) - 180.0
    return ErrorSeries(
        t_s=np.arange(n) / rate_hz, scored=scored, heading_deg=heading, signed_heading_deg=signed,
        inclination_deg=inclination, heading_offset_deg=offset,
        heading_rms_deg=_rms(heading[scored]), inclination_rms_deg=_rms(inclination[scored]),
        heading_rms_offset_removed_deg=_rms(removed))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))
