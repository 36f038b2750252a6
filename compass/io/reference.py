"""Seed 003's reference-field recording: known applied fields and the outputs of a sensor array.

CSV in the style of SPEC section 2 (``# key: value`` metadata, one header row, one row a
reference field):

- ``bx_ref, by_ref, bz_ref``: the known field applied (a coil, or a magnet at a known position),
  in the array's orthogonal frame, any field unit (the calibration's gains are per that unit);
- one three-axis sensor as ``mx, my, mz``, or several as ``<name>_x, <name>_y, <name>_z``
  (``s1_x, s1_y, s1_z, s2_x, ...``), outputs in any unit;
- ``<name>_bx_ref, <name>_by_ref, <name>_bz_ref`` (optional): the field at that sensor when it
  differs from the common one (a magnet source is not uniform over the array);
- ``t_s``, ``temp_c`` (optional).

Any other column is ignored, with a warning.  At least ``MIN_FIELDS`` rows; whether the fields span enough
directions is checked by the fit (:func:`calibrate.reference.calibrate_reference`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .table import ReadOptions, RecordingError, Table, read_table
from .units import note

__all__ = ["MIN_FIELDS", "ReferenceRecording", "read_reference", "reference_from_table"]

MIN_FIELDS = 4
"""Fewest reference fields: K (9 numbers) and 3 offsets need 4 fields of 3 components."""
_REF = ("bx_ref", "by_ref", "bz_ref")
_OPTIONAL = ("t_s", "temp_c")


@dataclass(frozen=True)
class ReferenceRecording:
    """A validated reference-field recording.

    Attributes
    ----------
    path : str
    sensors : tuple of str
        Sensor names (``m`` for ``mx, my, mz``).
    channels : dict of str to tuple of str
        Each sensor's three output columns, x, y, z.
    outputs : dict of str to ndarray, shape (n, 3)
        Each sensor's outputs, recording units.
    reference : dict of str to ndarray, shape (n, 3)
        The known field at each sensor, array frame, field units.
    rows : ndarray of int, shape (n,)
        1-based file line of every row.
    metadata : dict
    t_s, temp_c : ndarray, shape (n,), or None
        The optional time (s, non-decreasing) and temperature (degC) columns.
    """

    path: str
    sensors: tuple
    channels: dict
    outputs: dict
    reference: dict
    rows: np.ndarray
    metadata: dict
    t_s: np.ndarray | None = None
    temp_c: np.ndarray | None = None


def read_reference(path, options: ReadOptions | None = None) -> ReferenceRecording:
    """Read and validate a reference-field recording; see :func:`reference_from_table`."""
    return reference_from_table(read_table(path, options))


def reference_from_table(table: Table) -> ReferenceRecording:
    """Validate a parsed table as a reference-field recording.

    Raises
    ------
    RecordingError
        A sensor or reference column is missing, a sensor output that never changes, no
        sensor, or fewer than ``MIN_FIELDS`` rows.
    """
    cols = set(table.columns)
    groups: dict[str, dict] = {}
    ignored = []
    for name in table.columns:
        if name in _REF or name in _OPTIONAL:
            continue
        if name in ("mx", "my", "mz"):
            groups.setdefault("m", {})[name[1]] = name
            continue
        stem, sep, suffix = name.rpartition("_")
        if sep and suffix in ("x", "y", "z") and stem:
            groups.setdefault(stem, {})[suffix] = name
        elif not (name.endswith(_REF) and name[: -len("bx_ref")].rstrip("_")):
            ignored.append(name)
    if ignored:
        note(f"{table.path}: ignored column{'s' * (len(ignored) > 1)} {', '.join(ignored)} (expected bx_ref,by_ref,"
             "bz_ref, sensor columns mx,my,mz or <name>_x,<name>_y,<name>_z, <name>_bx_ref.., t_s, temp_c)")
    if not groups:
        raise RecordingError(table.path, "no sensor columns (mx,my,mz or <name>_x,<name>_y,<name>_z)",
                             row=table.header_row)
    channels, outputs, reference = {}, {}, {}
    for sensor, axes in groups.items():
        names = tuple(axes.get(a, ("m" + a) if sensor == "m" else f"{sensor}_{a}") for a in "xyz")
        missing = [n for n in names if n not in cols]
        if missing:
            raise RecordingError(table.path, f"sensor '{sensor}' needs three columns {', '.join(names)}",
                                 row=table.header_row, column=missing[0])
        own = tuple(f"{sensor}_{r}" for r in _REF)
        ref_cols = own if any(c in cols for c in own) else _REF
        ref = np.column_stack([table.column(c) for c in ref_cols])
        channels[sensor], outputs[sensor], reference[sensor] = names, np.column_stack(
            [table.column(c) for c in names]), ref
    for name in table.columns:
        if name.endswith("_bx_ref") and name[: -len("_bx_ref")] not in groups:
            raise RecordingError(table.path, "reference columns for a sensor that has no output columns",
                                 row=table.header_row, column=name)
    if len(table.rows) < MIN_FIELDS:
        raise RecordingError(table.path, f"only {len(table.rows)} reference fields: K and the offsets need at least "
                             f"{MIN_FIELDS} (and more to estimate their uncertainty)", column=_REF[0])
    table.check_constant([c for names in channels.values() for c in names])
    return ReferenceRecording(table.path, tuple(groups), channels, outputs, reference, np.asarray(table.rows),
                              dict(table.metadata), table.time_s(),
                              table.column("temp_c") if table.has("temp_c") else None)
