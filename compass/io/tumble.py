"""The tumble recording of SPEC section 2 (free-motion calibration).

Columns: ``mx,my,mz`` (magnetometer, any unit), optional ``ax,ay,az`` (accelerometer, any
unit), optional ``t_s`` (non-decreasing seconds) and ``temp_c``.  Real logs often repeat a
magnetometer value between its updates (a 20 Hz magnetometer inside 100 Hz rows); those repeats
are not new measurements and are dropped here, before any fit sees them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import units
from .table import ReadOptions, RecordingError, Table, read_table

__all__ = ["TumbleRecording", "read_tumble", "tumble_from_table", "MAG_COLUMNS", "ACCEL_COLUMNS"]

MAG_COLUMNS = ("mx", "my", "mz")
ACCEL_COLUMNS = ("ax", "ay", "az")
MIN_SAMPLES = 12
"""Fewest distinct magnetometer samples a tumble calibration accepts (the full fit has 9 parameters)."""


@dataclass(frozen=True)
class TumbleRecording:
    """A validated tumble recording, repeated magnetometer values removed.

    Attributes
    ----------
    path : str
    mag : ndarray, shape (n, 3)
        Raw magnetometer in its own frame, recording units.
    accel : ndarray, shape (n, 3), or None
        Accelerometer (specific force; reads +1 g up at rest), recording units.
    t_s, temp_c : ndarray, shape (n,), or None
    rows : ndarray of int, shape (n,)
        1-based file line of each kept sample.
    n_repeats : int
        Rows dropped because the magnetometer repeated the previous row's value.
    metadata : dict
    """

    path: str
    mag: np.ndarray
    accel: np.ndarray | None
    t_s: np.ndarray | None
    temp_c: np.ndarray | None
    rows: np.ndarray
    n_repeats: int
    metadata: dict


def read_tumble(path, options: ReadOptions | None = None) -> TumbleRecording:
    """Read and validate a tumble recording; see :func:`tumble_from_table`."""
    return tumble_from_table(read_table(path, options))


def tumble_from_table(table: Table) -> TumbleRecording:
    """Validate a parsed table as a tumble recording.

    Raises
    ------
    RecordingError
        A magnetometer column is missing or constant, the accelerometer columns are incomplete,
        or fewer than ``MIN_SAMPLES`` distinct magnetometer samples remain.

    Warns
    -----
    RecordingWarning
        Columns ignored; an accelerometer that reads -1 g on Z at the start's rest
        (:func:`compass.io.units.check_accel_up`); a field strength that is not the Earth's in the
        magnetometer unit named (:func:`compass.io.units.check_field_norm`).
    """
    mag = np.column_stack([table.column(c) for c in MAG_COLUMNS])
    table.ignore_unknown(MAG_COLUMNS + ACCEL_COLUMNS + ("t_s", "temp_c"), what="a tumble calibration")
    present = [c for c in ACCEL_COLUMNS if table.has(c)]
    if present and len(present) < 3:
        missing = [c for c in ACCEL_COLUMNS if c not in present]
        raise RecordingError(table.path, f"accelerometer needs ax, ay and az; missing {', '.join(missing)}",
                             row=table.header_row, column=missing[0])
    accel = np.column_stack([table.column(c) for c in ACCEL_COLUMNS]) if present else None
    t_s = table.time_s()
    temp_c = table.column("temp_c") if table.has("temp_c") else None

    keep = np.ones(len(mag), dtype=bool)
    keep[1:] = np.any(mag[1:] != mag[:-1], axis=1)
    if accel is not None and not np.any(accel):
        raise RecordingError(table.path, "the accelerometer reads (0, 0, 0) in every row", column="ax")
    if np.count_nonzero(keep) < MIN_SAMPLES:
        raise RecordingError(table.path, f"only {np.count_nonzero(keep)} distinct magnetometer samples "
                             f"(after dropping repeated values); a tumble calibration needs at least {MIN_SAMPLES}",
                             column="mx")
    table.check_constant(MAG_COLUMNS)
    accel, t_s, temp_c = (None if a is None else a[keep] for a in (accel, t_s, temp_c))
    if accel is not None:
        units.check_accel_up(accel, table.rows[keep], where=table.path)
    units.check_field_norm(sphere_radius(mag[keep]), "uT" if "mx" in table.units else None, where=table.path,
                                what="the magnetometer's field strength (sphere fit radius)")
    return TumbleRecording(table.path, mag[keep], accel, t_s, temp_c, table.rows[keep],
                           int(np.count_nonzero(~keep)), dict(table.metadata))


def sphere_radius(mag: np.ndarray) -> float:
    """Radius of the sphere fitted to the samples (algebraic least squares: ``|m|^2 = 2 m.c + k``).

    A first look at the field strength in the recording's unit, for the unit check; the
    calibration proper fits an ellipsoid.
    """
    design = np.column_stack([2.0 * mag, np.ones(len(mag))])
    solution = np.linalg.lstsq(design, np.einsum("ij,ij->i", mag, mag), rcond=None)[0]
    return float(np.sqrt(max(solution[3] + solution[:3] @ solution[:3], 0.0)))
