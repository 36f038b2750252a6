"""Offline use of the filter: :func:`run_filter` over recorded arrays, :func:`reference_field`."""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from itertools import repeat

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import heading_pitch_roll
from ..iron_uncertainty import undetermined_words, with_calibration_sigma_many
from ._records import SKIP_REASONS, FilterConfig, SkipCounts
from ._start import FilterStart

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
    heading_sigma_deg : ndarray, shape (n,)
        As ``compass live`` reports it: the filter's with the config's ``calibration_uncertainty`` at each
        attitude, in quadrature (:func:`compass.iron_uncertainty.with_calibration_sigma`; a part the calibration
        left undetermined counts with a stated prior, said in ``events``).
    tilt_sigma_deg, field_heading_sigma_deg, field_ratio, dip_deg : ndarray, shape (n,)
        As in :class:`Estimate`.
    mag_used, accel_used : ndarray of bool, shape (n,)
    gate : ndarray of str, shape (n,)
    gyro_bias : ndarray, shape (n, 3), or None
    skipped : SkipCounts
        Bad input skipped, by reason.
    events : tuple of (float, str)
        The filter's notes (restarts, reference changes: a new place, a timeout), with the time of
        the sample that gave each, s.
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
    events: tuple = ()


def run_filter(t_s, accel, gyro, field_h, config: FilterConfig, *, reference=None) -> FilterTrack:
    """Run the filter causally over recorded arrays, as ``compass live`` runs it.

    The start is :class:`FilterStart`'s, the one ``compass live`` and the replay use: the first
    samples are held until the stream's first quiet second gives the reference field (unless one is
    given), gravity's size and the first attitude, then run through the filter's public per-sample
    :meth:`~AttitudeFilter.update` like every later sample.  On the same samples the attitudes are
    those of :class:`compass.live.LiveSession` (tested).

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
        Its ``field_norm`` and ``dip_deg`` (e.g. :meth:`FilterConfig.from_model`'s, the bench's) only
        screen absurd fields until the reference is seeded: the bench's field is not the user's.
    reference : compass.site.ReferenceField or "config", optional
        The reference field when it is known (a site: :func:`compass.site.reference_from_site`;
        ``"config"``: the config's ``field_norm`` and ``dip_deg``); None seeds it from the recording.

    Returns
    -------
    FilterTrack

    Raises
    ------
    ValueError
        Shapes that do not match; a ``config.gravity`` or an accelerometer correction whose unit is not the
        stream's (:attr:`FilterStart.gravity_words`), as ``compass live`` and the replay refuse them.
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
    if isinstance(reference, str):
        if reference != "config":
            raise ValueError(f"reference must be a ReferenceField, 'config' or None, got {reference!r}")
        from ..site import known_reference

        reference = known_reference(config.dip_deg, config.field_norm)
    start = FilterStart(config, reference)
    start_skips = SkipCounts()
    filt = None
    # per sample with an attitude: its index, the matrix (9), heading, tilt and field heading variance,
    # field ratio, dip, mag_used, accel_used (7), the gyro bias (3); flat float buffers, no per-sample object
    # kept (57,000 kept tuples cost more in the garbage collector and in np.array than the filter's arithmetic)
    done, matrices, scalars, bias, events = [], array("d"), array("d"), array("d"), []
    own = config.calibration_uncertainty  # the calibration's own heading sigma, added after the loop as live adds it
    gate = ["absent"] * n
    # rows as Python floats once, vectorised (the per-sample step is scalar arithmetic); each row's
    # vectors are short-lived tuples (57,000 kept lists of three would slow the garbage collector)
    rows = zip(t_s.tolist(), zip(*accel.T.tolist()), repeat(None) if gyro is None else zip(*gyro.T.tolist()),
               zip(*field_h.T.tolist()))
    with_bias = gyro is not None

    def record(i, t, a, g, b):
        if not update(t, a, g, b):
            return
        if filt.events:
            events.extend((t, text) for text in filt.drain_events())
        done.append(i)
        matrices.extend(filt.matrix)
        scalars.extend((filt.heading_var, filt.tilt_var, filt.field_heading_var, d.field_ratio, d.dip_deg,
                        d.mag_used, d.accel_used))
        gate[i] = d.gate
        if with_bias:
            bias.extend(filt.gyro_bias)

    def begin():
        """The filter from the start window, and the held samples through it."""
        nonlocal filt, update, d
        if start.gravity_words is not None:  # as compass live and the replay refuse it
            raise ValueError(start.gravity_words)
        filt = start.make_filter(gyro is not None)
        for name in SKIP_REASONS:  # what the start skipped counts with the filter's own skips
            for _ in range(getattr(start_skips, name.replace(" ", "_"))):
                filt.skipped.count(name)
        update, d = filt.update, filt.diagnostics
        held = start.take_held()
        words = undetermined_words(own, config.field_norm, config.dip_deg)
        if words is not None and held:
            events.append((t_s[held[0]].item(), words))
        for j in held:
            record(j, t_s[j].item(), tuple(accel[j].tolist()), None if gyro is None else tuple(gyro[j].tolist()),
                   tuple(field_h[j].tolist()))

    update = d = None
    for i, (t, a, g, b) in enumerate(rows):
        if filt is not None:
            record(i, t, a, g, b)
            continue
        reason = start.add(i, t, a, g, b)
        if reason is not None:
            start_skips.count(reason)
        if start.done:
            begin()
    if filt is None and start.finish():  # the recording ended inside the start window
        begin()
    if filt is None:  # too few rows to seed the reference: nothing fused; the held rows' bad parts counted
        for j in start.take_held():
            for name, values in (("gyro", gyro), ("accel", accel), ("field", field_h)):
                if values is not None and not np.all(np.isfinite(values[j])):
                    start_skips.count(f"{name} not finite")
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
    if own is not None:  # the reported heading sigma as compass live reports it, for every estimate at once
        sigma[done, 0] = with_calibration_sigma_many(sigma[done, 0], own, matrices[done], field_h[done])
    return FilterTrack(t_s, quat, *angles.T, *sigma.T, scalars[:, 3], scalars[:, 4], flags[:, 0], flags[:, 1],
                       np.array(gate, dtype=str), _rows(bias, done, n, 3) if with_bias else None,
                       start_skips if filt is None else filt.skipped, tuple(events))


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
