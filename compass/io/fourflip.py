"""The four-flip recording of SPEC section 2 (seed 000's bench session)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .names import RESERVED_NAMES
from .table import ReadOptions, RecordingError, Table, read_table
from .units import looks_like_radians

__all__ = ["FourFlipRecording", "read_fourflip", "NOMINAL_FLIPS_DEG", "RESERVED_COLUMNS"]

NOMINAL_FLIPS_DEG = (0.0, 90.0, 180.0, 270.0)
FLIP_TOLERANCE_DEG = 10.0
"""How far a recorded flip may be from its nominal value."""
MAX_GAP_DEG = 90.0
"""Largest turntable gap in one flip that still locates the output minimum."""
MIN_SAMPLES_PER_FLIP = 8
_RADIANS_HINT = ("; {column} never leaves 0..2*pi: radians? The column is in degrees; convert it, or name the "
                 "unit with --angle-unit rad")
RESERVED_COLUMNS = RESERVED_NAMES  # every other column is a channel


@dataclass(frozen=True)
class FourFlipRecording:
    """A validated four-flip recording.

    Attributes
    ----------
    flip_deg : ndarray, shape (n,)
        Recorded flip angle kappa, degrees (as recorded, near 0/90/180/270).
    flip_index : ndarray of int, shape (n,)
        0..3 for the nominal flips 0, 90, 180, 270.
    platform_deg : ndarray, shape (n,)
        Turntable reading phi, degrees.
    outputs : ndarray, shape (n, n_channels)
        Magnetic channel outputs, any unit.
    channels : tuple of str
    t_s, temp_c : ndarray, shape (n,), or None
    accel : ndarray, shape (n, 3), or None
        Accelerometer in the housing, if recorded (not used by the magnetic fit).
    metadata : dict
    path : str
    """

    flip_deg: np.ndarray
    flip_index: np.ndarray
    platform_deg: np.ndarray
    outputs: np.ndarray
    channels: tuple[str, ...]
    t_s: np.ndarray | None
    temp_c: np.ndarray | None
    accel: np.ndarray | None
    metadata: dict
    path: str = "<memory>"

    @property
    def n_samples(self) -> int:
        return self.outputs.shape[0]

    def subset(self, keep: np.ndarray) -> "FourFlipRecording":
        """The recording restricted to the samples where ``keep`` is True."""
        pick = (lambda a: None if a is None else a[keep])
        return FourFlipRecording(self.flip_deg[keep], self.flip_index[keep], self.platform_deg[keep],
                                 self.outputs[keep], self.channels, pick(self.t_s), pick(self.temp_c),
                                 pick(self.accel), self.metadata, self.path)

    @property
    def field_ut(self) -> float | None:
        """``# field_ut:`` metadata, |B| in uT (validated positive by the reader), None when absent."""
        value = self.metadata.get("field_ut")
        return float(value) if value is not None else None


def read_fourflip(path, options: ReadOptions | None = None) -> FourFlipRecording:
    """Read and validate a four-flip recording CSV.

    Raises
    ------
    RecordingError
        Any problem, naming file, row and column: missing ``flip_deg``/``platform_deg``, no
        magnetic channel, a non-numeric cell, a flip far from 0/90/180/270, a flip missing or with
        too little turntable coverage, a channel that never changes.
    """
    return fourflip_from_table(read_table(path, options))


def fourflip_from_table(table: Table) -> FourFlipRecording:
    """Validate a parsed table as a four-flip recording (see :func:`read_fourflip`)."""
    flip = table.column("flip_deg")
    platform = table.column("platform_deg")
    channels = tuple(c for c in table.columns if c not in RESERVED_COLUMNS)
    if not channels:
        raise RecordingError(
            table.path,
            "no magnetic channel column: every column other than "
            f"{', '.join(RESERVED_COLUMNS)} is a channel",
            row=table.header_row,
        )
    nominal = np.asarray(NOMINAL_FLIPS_DEG)
    wrapped = np.mod(flip[:, None] - nominal[None, :] + 180.0, 360.0) - 180.0
    flip_index = np.argmin(np.abs(wrapped), axis=1)
    off = np.abs(wrapped[np.arange(len(flip)), flip_index])
    bad = np.flatnonzero(off > FLIP_TOLERANCE_DEG)
    if bad.size:
        i = bad[0]
        raise RecordingError(
            table.path,
            f"flip {flip[i]:g} deg is not within {FLIP_TOLERANCE_DEG:g} deg of 0, 90, 180 or 270"
            + (_RADIANS_HINT.format(column="flip_deg") if looks_like_radians(flip) else ""),
            row=int(table.rows[i]),
            column="flip_deg",
        )
    _check_coverage(table, flip_index, platform, looks_like_radians(flip), looks_like_radians(platform))
    table.check_constant(channels)
    table.check_clipped(channels)
    outputs = np.column_stack([table.column(c) for c in channels])
    optional = {c: table.column(c) if table.has(c) else None for c in ("t_s", "temp_c")}
    accel = None
    if all(table.has(c) for c in ("ax", "ay", "az")):
        accel = np.column_stack([table.column(c) for c in ("ax", "ay", "az")])
    return FourFlipRecording(
        flip_deg=nominal[flip_index] + wrapped[np.arange(len(flip)), flip_index],
        flip_index=flip_index,
        platform_deg=platform,
        outputs=outputs,
        channels=channels,
        t_s=optional["t_s"],
        temp_c=optional["temp_c"],
        accel=accel,
        metadata=dict(table.metadata),
        path=table.path,
    )


def _check_coverage(table: Table, flip_index: np.ndarray, platform: np.ndarray, flip_radians: bool,
                    platform_radians: bool) -> None:
    for k, nominal in enumerate(NOMINAL_FLIPS_DEG):
        mask = flip_index == k
        rows = table.rows[mask]
        if mask.sum() < MIN_SAMPLES_PER_FLIP:
            raise RecordingError(
                table.path,
                f"flip {nominal:g} has {mask.sum()} samples; need at least {MIN_SAMPLES_PER_FLIP} "
                "over a full turn of the turntable" + (_RADIANS_HINT.format(column="flip_deg") if flip_radians else ""),
                column="flip_deg",
            )
        angles = np.sort(np.mod(platform[mask], 360.0))
        gaps = np.diff(np.concatenate([angles, angles[:1] + 360.0]))
        worst = int(np.argmax(gaps))
        if gaps[worst] > MAX_GAP_DEG:
            start = angles[worst]
            raise RecordingError(
                table.path,
                f"flip {nominal:g}: the turntable never visits {start:.0f}..{(start + gaps[worst]) % 360:.0f} deg "
                f"(a {gaps[worst]:.0f} deg gap; at most {MAX_GAP_DEG:g} deg allowed to locate the minimum)"
                + (_RADIANS_HINT.format(column="platform_deg") if platform_radians else ""),
                row=int(rows[0]),
                column="platform_deg",
            )
