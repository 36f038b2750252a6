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

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

_NO_GATE = 1e9
"""Gate tolerances that let every field sample in (|B| ratio, degrees, seconds)."""

__all__ = ["METRIC", "ErrorSeries", "PipelineResult", "orientation_errors", "error_series", "initial_field", "RestNoise", "rest_noise",
           "run_pipeline"]

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


@dataclass(frozen=True)
class PipelineResult:
    """The toolkit's attitude for a recording with IMU columns, and what went into it.

    Attributes
    ----------
    quat_enu : ndarray, shape (n, 4)
        Estimated ``R_ENU<-H``, scalar first (BROAD's convention; NWU is ``Rz(-90 deg)`` of it).
    field_h_ut : ndarray, shape (n, 3)
        Field in H after the calibration and the hard-iron track, uT.
    field_ut, dip_deg : float
        Reference |B| and dip: from the calibration when it has them, else the initial rest.
    hard_iron : HardIronTrack or None
        None when hard-iron tracking was off.
    disturbed : ndarray of bool, shape (n,)
        Rows whose field the filter did not use (gate closed, or before it started).
    method : str
        Which attitude estimator ran, in words.
    """

    quat_enu: np.ndarray
    field_h_ut: np.ndarray
    field_ut: float
    dip_deg: float
    hard_iron: object
    disturbed: np.ndarray
    method: str


def initial_field(mag_ut, accel, still) -> tuple[float, float, float]:
    """|B|, dip and per-axis noise of the field over the first half of the initial rest.

    Only the first half is used: a rest phase can end with the set-up for what follows (in BROAD,
    a magnet attached seconds before the movement starts).

    Parameters
    ----------
    mag_ut, accel : array_like, shape (n, 3)
        Field in H (uT) and specific force in H (any unit).
    still : array_like of bool, shape (n,)
        Samples at rest; the first half of the first contiguous run is used.

    Returns
    -------
    field_ut, dip_deg, noise_ut : float

    Raises
    ------
    ValueError
        Fewer than 20 samples at rest at the start.
    """
    half = _first_half_of_rest(still, "to fix |B| and dip")
    m = np.asarray(mag_ut, dtype=float)[half]
    a = np.asarray(accel, dtype=float)[half]
    m_mean, up = m.mean(axis=0), a.mean(axis=0) / np.linalg.norm(a.mean(axis=0))
    field = float(np.linalg.norm(m_mean))
    dip = float(np.degrees(np.arcsin(np.clip(-m_mean @ up / field, -1.0, 1.0))))
    noise = float(np.median(np.std(m, axis=0)))
    return field, dip, max(noise, 1e-3 * field)


@dataclass(frozen=True)
class RestNoise:
    """White noise of the three sensors measured on a recording's initial rest (:func:`rest_noise`).

    Attributes
    ----------
    gyro_noise : float
        Gyro rate noise density, rad/s/sqrt(Hz): the per-axis standard deviation times ``sqrt(dt)``
        (white noise of density ``n`` sampled at ``1/dt`` has ``sigma = n / sqrt(dt)``), median of the axes.
    accel_noise : float
        Accelerometer noise per axis as a fraction of |a| at rest (of g), median of the axes.
    mag_noise : float
        Magnetometer noise per axis, field units, median of the axes.
    samples : int
        Rest samples used.
    """

    gyro_noise: float
    accel_noise: float
    mag_noise: float
    samples: int


def rest_noise(gyro_rad_s, accel, mag, still, rate_hz: float) -> RestNoise:
    """Sensor noise from the first half of the initial rest (as :func:`initial_field`), causal.

    The standard deviation about the mean over a few seconds includes the slow part of the noise
    (bias instability, tremor of a hand-held rest) only to the extent it moves within them.

    Raises
    ------
    ValueError
        Fewer than 20 samples at rest at the start.
    """
    half = _first_half_of_rest(still, "to measure the noise")
    g, a, m = (np.asarray(v, dtype=float)[half] for v in (gyro_rad_s, accel, mag))
    return RestNoise(gyro_noise=float(np.median(np.std(g, axis=0))) / np.sqrt(rate_hz),
                     accel_noise=float(np.median(np.std(a, axis=0)) / np.linalg.norm(a.mean(axis=0))),
                     mag_noise=float(np.median(np.std(m, axis=0))), samples=half.stop)


def run_pipeline(trial, model=None, *, gate: bool = True, hard_iron: bool = True) -> PipelineResult:
    """Attitude of a BROAD-like trial through the toolkit: calibration, hard-iron track, live filter.

    Parameters
    ----------
    trial : compass.io.broad.BroadTrial
        Only its IMU arrays and the ``movement`` flag (to find the initial rest) are used, never the
        reference.
    model : SensorModel, optional
        Calibration of the magnetometer (three channels, in the order x, y, z of ``mag_ut``); its
        housing frame must be the accelerometer's.  None: the readings are taken as calibrated.
    gate : bool
        Keep the filter's magnetic-disturbance gate (False: every field sample is used).
    hard_iron : bool
        Track housing-fixed offsets (:func:`compass.hard_iron.track_hard_iron`).

    Returns
    -------
    PipelineResult

    Notes
    -----
    |B|, dip and the magnetometer noise come from the trial's initial rest (the calibration's dip
    when it has one); the filter (:func:`compass.filter.run_filter`) runs causally on gyro,
    accelerometer and the field with :class:`compass.filter.FilterConfig` defaults otherwise.
    """
    from .filter import FilterConfig, run_filter
    from .hard_iron import track_hard_iron
    from .io.broad import nwu_to_enu

    field = trial.mag_ut if model is None else model.field(trial.mag_ut)[0]
    field_ut, dip_deg, noise_ut = initial_field(field, trial.accel_m_s2, ~trial.movement)
    if model is not None and model.dip_deg is not None:
        dip_deg = model.dip_deg
    config = FilterConfig(field_norm=field_ut, dip_deg=dip_deg, mag_noise=noise_ut)
    if not gate:
        config = replace(config, field_tolerance=_NO_GATE, dip_tolerance_deg=_NO_GATE, heading_tolerance_deg=_NO_GATE,
                         gate_timeout_s=_NO_GATE)
    track = None
    if hard_iron:
        track = track_hard_iron(field, trial.accel_m_s2, trial.rate_hz, dip_deg=dip_deg)
        field = track.corrected(field)
    # the reference measured above (the trial's rest, the calibration's dip), not re-seeded by the filter's start
    out = run_filter(trial.t_s, trial.accel_m_s2, trial.gyro_rad_s, field, config, reference="config")
    ok = np.all(np.isfinite(out.quat), axis=1)
    quat = np.full((len(field), 4), np.nan)
    quat[ok] = nwu_to_enu(Rotation.from_quat(out.quat[ok])).as_quat(scalar_first=True)
    words = "gyro filter" + (" with magnetic gate" if gate else " without gate") + (" + hard-iron track" if hard_iron else "")
    return PipelineResult(quat_enu=quat, field_h_ut=field, field_ut=field_ut, dip_deg=dip_deg, hard_iron=track,
                          disturbed=~out.mag_used, method=words + (", calibrated" if model is not None else ""))


def _first_half_of_rest(still, purpose: str) -> slice:
    """The first half of the trial's initial rest (the other half is left to the filter's start-up).

    Raises
    ------
    ValueError
        Fewer than 20 samples at rest at the start (``purpose`` says what for).
    """
    still = np.asarray(still, dtype=bool)
    n_rest = int(np.argmin(still)) if not still.all() else len(still)
    if n_rest < 20:
        raise ValueError(f"needs at least 20 samples at rest at the start {purpose}, got {n_rest}")
    return slice(0, n_rest // 2)
