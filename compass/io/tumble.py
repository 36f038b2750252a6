"""The tumble recording of SPEC section 2 (free-motion calibration).

Columns: ``mx,my,mz`` (magnetometer, any unit), optional ``ax,ay,az`` (accelerometer, any
unit), optional ``t_s`` (non-decreasing seconds), ``temp_c`` and ``gx,gy,gz`` (gyro, rad/s, or
``--gyro-unit deg/s``).  Real logs often repeat a magnetometer value between its updates (a 20 Hz
magnetometer inside 100 Hz rows); those repeats are not new measurements and are dropped here,
before any fit sees them; the gyro's rows in between are integrated into the turn from one kept
sample to the next (:func:`gyro_turns`), which the gyro-aided fit uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..sample_check import new_readings
from . import units
from .table import ReadOptions, RecordingError, Table, read_table

__all__ = ["TumbleRecording", "read_tumble", "tumble_from_table", "gyro_turns", "MAG_COLUMNS", "ACCEL_COLUMNS",
           "GYRO_COLUMNS", "MAX_GYRO_RAD_S"]

MAG_COLUMNS = ("mx", "my", "mz")
ACCEL_COLUMNS = ("ax", "ay", "az")
GYRO_COLUMNS = ("gx", "gy", "gz")
MAX_GYRO_RAD_S = 70.0
"""A rate beyond this (4000 deg/s, beyond any MEMS gyro's range) is not a reading: RecordingError."""
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
    mag_unit : str or None
        The magnetometer unit the user or the header named (``mag`` was converted from it to uT);
        None when the unit is free.
    gyro_turn_rad : ndarray, shape (n, 3), or None
        The housing's turn from the previous kept sample to each (rotation vector, rad, housing
        frame; row 0 zero), from ``gx,gy,gz`` (:func:`gyro_turns`); None without a gyro and ``t_s``,
        or when the gyro's unit looks wrong (the reader's warning says so, :func:`_gyro`).
    """

    path: str
    mag: np.ndarray
    accel: np.ndarray | None
    t_s: np.ndarray | None
    temp_c: np.ndarray | None
    rows: np.ndarray
    n_repeats: int
    metadata: dict
    mag_unit: str | None = None
    gyro_turn_rad: np.ndarray | None = None


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
    table.ignore_unknown(MAG_COLUMNS + ACCEL_COLUMNS + GYRO_COLUMNS + ("t_s", "temp_c"), what="a tumble calibration")
    present = [c for c in ACCEL_COLUMNS if table.has(c)]
    if present and len(present) < 3:
        missing = [c for c in ACCEL_COLUMNS if c not in present]
        raise RecordingError(table.path, f"accelerometer needs ax, ay and az; missing {', '.join(missing)}",
                             row=table.header_row, column=missing[0])
    accel = np.column_stack([table.column(c) for c in ACCEL_COLUMNS]) if present else None
    t_s = table.time_s()
    temp_c = table.column("temp_c") if table.has("temp_c") else None

    keep = new_readings(mag)
    if accel is not None and not np.any(accel):
        raise RecordingError(table.path, "the accelerometer reads (0, 0, 0) in every row", column="ax")
    if np.count_nonzero(keep) < MIN_SAMPLES:
        raise RecordingError(table.path, f"only {np.count_nonzero(keep)} distinct magnetometer samples "
                             f"(after dropping repeated values); a tumble calibration needs at least {MIN_SAMPLES}",
                             column="mx")
    table.check_constant(MAG_COLUMNS)
    table.check_clipped(MAG_COLUMNS, keep)
    turns = _gyro(table, accel, t_s, keep)
    accel, t_s, temp_c = (None if a is None else a[keep] for a in (accel, t_s, temp_c))
    if accel is not None:
        units.check_accel_up(accel, table.rows[keep], where=table.path)
    named = table.units.get("mx")  # the data are in uT when a unit was named: judge it in the unit named
    radius = sphere_radius(mag[keep]) / (units.MAG_UNITS[named] if named else 1.0)
    units.check_field_norm(radius, named, where=table.path,
                                what="the magnetometer's field strength (sphere fit radius)")
    return TumbleRecording(table.path, mag[keep], accel, t_s, temp_c, table.rows[keep],
                           int(np.count_nonzero(~keep)), dict(table.metadata), named, turns)


def _gyro(table: Table, accel, t_s, keep) -> np.ndarray | None:
    """The gyro's turns between kept samples, or None (no gyro, no time, no accelerometer, a wrong unit).

    The unit is judged once, by the reader (:attr:`compass.io.table.Table.gyro_turn_ratio`, whose note
    names the fault and the option that fixes it): a gyro turning :data:`compass.io.units.GYRO_UNIT_RATIO`
    times more or less than the accelerometer sees the housing tilt is not used, whether its unit was
    named or not (a deg/s gyro read as rad/s, a rad/s gyro named deg/s: either would only be tried and
    rejected by the gyro-aided fit).

    Raises
    ------
    RecordingError
        A rate beyond :data:`MAX_GYRO_RAD_S`, or a gyro reading (0, 0, 0) in every row.
    """
    gyro = table.group(GYRO_COLUMNS)
    if gyro is None:
        return None
    if t_s is None or accel is None:
        units.note(f"{table.path}: gx,gy,gz not used: the gyro-aided tumble fit needs t_s and ax,ay,az too")
        return None
    if not np.any(gyro):
        raise RecordingError(table.path, "the gyro reads (0, 0, 0) in every row", column="gx")
    if units.gyro_unit_verdict(table.gyro_turn_ratio) is not None:  # the reader's one note named the fault and the fix
        return None
    too_fast = np.abs(gyro) > MAX_GYRO_RAD_S
    if np.any(too_fast):
        i, j = np.argwhere(too_fast)[0]
        raise RecordingError(table.path, f"gyro rate {gyro[i, j]:.6g} rad/s is beyond any MEMS gyro's range "
                                         f"({MAX_GYRO_RAD_S:g} rad/s, {np.degrees(MAX_GYRO_RAD_S):.0f} deg/s)",
                             row=int(table.rows[i]), column=GYRO_COLUMNS[j])
    return gyro_turns(t_s, gyro, keep)


def gyro_turns(t_s, gyro_rad_s, keep) -> np.ndarray:
    """The housing's turn from one kept sample to the next, from every row's angular rate.

    Row ``i``'s rate turns the housing over ``(t_i-1, t_i]`` (as the runtime filter integrates it);
    the turns of the rows from a kept sample (exclusive) to the next (inclusive) are summed.  Over
    the few rows a magnetometer value is held the sum differs from the composed rotation by half
    the cross products of the rows' turns: second order, 3e-4 deg for 1 deg steps.

    Parameters
    ----------
    t_s : ndarray, shape (n_rows,)
        Non-decreasing time, s.
    gyro_rad_s : ndarray, shape (n_rows, 3)
        Angular rate, rad/s, housing frame.
    keep : ndarray of bool, shape (n_rows,)
        The kept rows (the first kept row's turn is zero).

    Returns
    -------
    ndarray, shape (n_kept, 3)
        Rotation vectors, rad, housing frame; the first kept row's is zero.
    """
    t_s, gyro = np.asarray(t_s, dtype=float), np.asarray(gyro_rad_s, dtype=float)
    step = gyro * np.diff(t_s, prepend=t_s[0])[:, None]
    kept = np.flatnonzero(keep)
    cum = np.cumsum(step, axis=0)
    out = np.zeros((len(kept), 3))
    out[1:] = cum[kept[1:]] - cum[kept[:-1]]  # rows kept_(k-1)+1 .. kept_k
    return out


def sphere_radius(mag: np.ndarray) -> float:
    """Radius of the sphere fitted to the samples (algebraic least squares: ``|m|^2 = 2 m.c + k``).

    A first look at the field strength in the recording's unit, for the unit check; the
    calibration proper fits an ellipsoid.
    """
    design = np.column_stack([2.0 * mag, np.ones(len(mag))])
    solution = np.linalg.lstsq(design, np.einsum("ij,ij->i", mag, mag), rcond=None)[0]
    return float(np.sqrt(max(solution[3] + solution[:3] @ solution[:3], 0.0)))
