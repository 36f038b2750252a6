"""The installation recording of SPEC section 2: the bench-calibrated module turned inside its product.

Columns: the bench calibration's channel columns, ``ax,ay,az`` (the module's accelerometer, any
unit), optional ``t_s``, ``temp_c`` and ``heading_ref_deg`` (a known magnetic heading of the
product's forward axis for that row; ``# heading_ref: true`` says it is a true heading).  The kind
is ``# kind: tumble|swing`` in the metadata, else told from the accelerometer: a swing keeps the up
direction within 30 degrees of its mean.  ``# base: BENCH.json`` may name the bench calibration
(relative to the recording) when ``--base`` does not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .table import RecordingError, Table, read_table

__all__ = ["InstallationRecording", "read_installation", "installation_from_table", "KINDS"]

KINDS = ("tumble", "swing")
_SWING_TILT_DEG = 30.0
_ACCEL = ("ax", "ay", "az")
_OTHER = ("t_s", "temp_c", "heading_ref_deg", "gx", "gy", "gz")
MIN_SAMPLES = 30


@dataclass(frozen=True)
class InstallationRecording:
    """A validated installation recording.

    Attributes
    ----------
    path : str
    kind : {"tumble", "swing"}
    channels : tuple of str
        The bench calibration's channels, in its order.
    raw : ndarray, shape (n, c)
    accel : ndarray, shape (n, 3)
        The module's accelerometer in H, recording units.
    t_s, temp_c : ndarray, shape (n,), or None
    heading_ref_deg : ndarray, shape (n,), or None
        Known heading of the product's forward axis.
    heading_ref_true : bool
        ``heading_ref_deg`` is from true north (needs a site for the declination).
    rows : ndarray of int, shape (n,)
        1-based file line of each sample.
    metadata : dict
    """

    path: str
    kind: str
    channels: tuple[str, ...]
    raw: np.ndarray
    accel: np.ndarray
    t_s: np.ndarray | None
    temp_c: np.ndarray | None
    heading_ref_deg: np.ndarray | None
    heading_ref_true: bool
    rows: np.ndarray
    metadata: dict


def read_installation(path, channels=None) -> InstallationRecording:
    """Read and validate an installation recording (see :func:`installation_from_table`)."""
    return installation_from_table(read_table(path), channels)


def installation_from_table(table: Table, channels=None) -> InstallationRecording:
    """Validate a parsed table as an installation recording.

    ``channels``: the bench calibration's channel names; default every column that is not
    ``ax,ay,az,t_s,temp_c,heading_ref_deg`` (or a gyro), in file order (the calibrator matches
    them to its bench calibration's).

    Raises
    ------
    RecordingError
        A channel or accelerometer column missing, an unknown column, a zero accelerometer row,
        fewer than 30 rows, or a ``kind``/``heading_ref`` metadata value not understood.
    """
    if channels is None:
        channels = tuple(c for c in table.columns if c not in _ACCEL and c not in _OTHER)
        if not channels:
            raise RecordingError(table.path, "no channel columns besides ax,ay,az", row=table.header_row)
    known = set(channels) | set(_ACCEL) | set(_OTHER)
    for name in table.columns:
        if name not in known:
            raise RecordingError(table.path, f"column '{name}' is neither a channel of the bench calibration "
                                             f"({', '.join(channels)}) nor ax,ay,az,t_s,temp_c,heading_ref_deg",
                                 row=table.header_row, column=name)
    raw = np.column_stack([table.column(c) for c in channels])
    accel = np.column_stack([table.column(c) for c in _ACCEL])
    norm = np.linalg.norm(accel, axis=1)
    if np.any(norm == 0):
        raise RecordingError(table.path, "accelerometer reads zero: expected gravity",
                             row=int(table.rows[np.argmax(norm == 0)]), column="ax")
    if len(raw) < MIN_SAMPLES:
        raise RecordingError(table.path, f"only {len(raw)} rows; an installation calibration needs at least "
                             f"{MIN_SAMPLES}", column=channels[0])
    kind = table.metadata.get("kind", "").strip().lower() or _kind(accel / norm[:, None])
    if kind not in KINDS:
        raise RecordingError(table.path, f"metadata 'kind' must be tumble or swing, got {kind!r}")
    ref_kind = table.metadata.get("heading_ref", "magnetic").strip().lower()
    if ref_kind not in ("magnetic", "true"):
        raise RecordingError(table.path, f"metadata 'heading_ref' must be magnetic or true, got {ref_kind!r}")
    heading_ref = table.column("heading_ref_deg") if table.has("heading_ref_deg") else None
    return InstallationRecording(table.path, kind, tuple(channels), raw, accel, table.time_s(),
                                 table.column("temp_c") if table.has("temp_c") else None, heading_ref,
                                 ref_kind == "true", table.rows, dict(table.metadata))


def _kind(up: np.ndarray) -> str:
    mean = up.mean(axis=0)
    mean /= np.linalg.norm(mean)
    worst = np.degrees(np.arccos(np.clip(up @ mean, -1.0, 1.0))).max()
    return "swing" if worst < _SWING_TILT_DEG else "tumble"
