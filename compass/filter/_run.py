"""Offline use of the filter: :func:`run_filter` over recorded arrays, :func:`reference_field`."""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from itertools import repeat

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import heading_pitch_roll
from ._base import AttitudeFilter
from ._records import FilterConfig, SkipCounts

__all__ = ["FilterTrack", "run_filter", "reference_field"]


@dataclass(frozen=True)
class FilterTrack:
    """:func:`run_filter`'s output, one row per sample (NaN before initialisation).

    Attributes
    ----------
    t_s : ndarray, shape (n,)
    quat : ndarray, shape (n, 4)
        ``R_world<-housing`` as scipy quaternions (x, y, z, w).
    heading_deg, pitch_deg, roll_deg : ndarray, shape (n,)
    heading_sigma_deg, tilt_sigma_deg, field_heading_sigma_deg, field_ratio, dip_deg : ndarray, shape (n,)
        As in :class:`Estimate`.
    mag_used, accel_used : ndarray of bool, shape (n,)
    gate : ndarray of str, shape (n,)
    gyro_bias : ndarray, shape (n, 3), or None
    skipped : SkipCounts
        Bad input skipped, by reason.
    """

    t_s: np.ndarray
    quat: np.ndarray
    heading_deg: np.ndarray
    pitch_deg: np.ndarray
    roll_deg: np.ndarray
    heading_sigma_deg: np.ndarray
    tilt_sigma_deg: np.ndarray
    field_heading_sigma_deg: np.ndarray
    field_ratio: np.ndarray
    dip_deg: np.ndarray
    mag_used: np.ndarray
    accel_used: np.ndarray
    gate: np.ndarray
    gyro_bias: np.ndarray | None
    skipped: SkipCounts


def run_filter(t_s, accel, gyro, field_h, config: FilterConfig) -> FilterTrack:
    """Run the filter causally over recorded arrays, on its public per-sample :meth:`~AttitudeFilter.update`.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Sample times, seconds.
    accel : array_like, shape (n, 3)
        Accelerometer in H, any unit; rows with NaN are skipped (counted in ``skipped``).
    gyro : array_like, shape (n, 3), or None
        Gyro in H, rad/s; None runs the two-vector filter.
    field_h : array_like, shape (n, 3)
        Field in H, field units.
    config : FilterConfig

    Returns
    -------
    FilterTrack
    """
    t_s = np.asarray(t_s, dtype=float)
    accel = np.asarray(accel, dtype=float)
    field_h = np.asarray(field_h, dtype=float)
    n = len(t_s)
    if accel.shape != (n, 3) or field_h.shape != (n, 3):
        raise ValueError(f"expected accel and field_h of shape ({n}, 3), got {accel.shape} and {field_h.shape}")
    if gyro is not None:
        gyro = np.asarray(gyro, dtype=float)
        if gyro.shape != (n, 3):
            raise ValueError(f"expected gyro of shape ({n}, 3), got {gyro.shape}")
    filt = AttitudeFilter(config, gyro=gyro is not None)
    # per sample with an attitude: its index, the matrix (9), heading, tilt and field heading variance,
    # field ratio, dip, mag_used, accel_used (7), the gyro bias (3); flat float buffers, no per-sample object
    # kept (57,000 kept tuples cost more in the garbage collector and in np.array than the filter's arithmetic)
    done, matrices, scalars, bias = [], array("d"), array("d"), array("d")
    gate = ["absent"] * n
    # rows as Python floats once, vectorised (the per-sample step is scalar arithmetic); each row's
    # vectors are short-lived tuples (57,000 kept lists of three would slow the garbage collector)
    rows = zip(t_s.tolist(), zip(*accel.T.tolist()), repeat(None) if gyro is None else zip(*gyro.T.tolist()),
               zip(*field_h.T.tolist()))
    update, d, with_bias = filt.update, filt.diagnostics, gyro is not None
    for i, (t, a, g, b) in enumerate(rows):
        if not update(t, a, g, b):
            continue
        done.append(i)
        matrices.extend(filt.matrix)
        scalars.extend((filt.heading_var, filt.tilt_var, filt.field_heading_var, d.field_ratio, d.dip_deg,
                        d.mag_used, d.accel_used))
        gate[i] = d.gate
        if with_bias:
            bias.extend(filt.gyro_bias)
    done = np.array(done, dtype=int)
    matrices = _rows(matrices, done, n, 9).reshape(n, 3, 3)
    ok = np.all(np.isfinite(matrices.reshape(n, 9)), axis=1)
    quat = np.full((n, 4), np.nan)
    angles = np.full((n, 3), np.nan)
    if ok.any():
        rotation = Rotation.from_matrix(matrices[ok])
        quat[ok] = rotation.as_quat()
        angles[ok] = np.column_stack(heading_pitch_roll(rotation))
    scalars = _rows(scalars, done, n, 7)
    flags = np.zeros((n, 2), dtype=bool)
    flags[done] = scalars[done, 5:] != 0.0
    sigma = np.degrees(np.sqrt(scalars[:, :3]))
    return FilterTrack(t_s, quat, *angles.T, *sigma.T, scalars[:, 3], scalars[:, 4], flags[:, 0], flags[:, 1],
                       np.array(gate, dtype=str), _rows(bias, done, n, 3) if with_bias else None,
                       filt.skipped)


def _rows(buffer: array, done: np.ndarray, n: int, width: int) -> np.ndarray:
    """``(n, width)`` array: the buffer's rows at the indices ``done``, NaN elsewhere."""
    out = np.full((n, width), np.nan)
    out[done] = np.frombuffer(buffer, dtype=float).reshape(len(done), width)
    return out


def reference_field(accel, field_h) -> tuple[float, float]:
    """Reference |B| and dip from samples taken away from disturbances (e.g. a recording's start).

    For data without a calibration file: medians of ``|B|`` and of the field-gravity angle.

    Parameters
    ----------
    accel, field_h : array_like, shape (n, 3)
        Accelerometer (any unit) and field (field units) in H.

    Returns
    -------
    field_norm : float
        Median |B|, field units.
    dip_deg : float
        Median dip, degrees.
    """
    a = np.asarray(accel, dtype=float)
    b = np.asarray(field_h, dtype=float)
    ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    if not np.any(ok):
        raise ValueError("no sample has both a finite accelerometer and field reading")
    a, b = a[ok], b[ok]
    b_norm = np.linalg.norm(b, axis=1)
    cos = -np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * b_norm)
    return float(np.median(b_norm)), float(np.degrees(np.median(np.arcsin(np.clip(cos, -1.0, 1.0)))))
