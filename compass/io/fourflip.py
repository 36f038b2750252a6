r"""The four-flip recording of SPEC section 2 (seed 000's bench session).

Which face was down in each flip
--------------------------------
SPEC section 1 puts a housing direction at ``a_W = Rz(phi) Rx(kappa) a_H`` on the bench.  An
accelerometer riding in the housing reads the specific force, +g up, so in the housing frame it reads

.. math::

    f_H = R_x(\kappa)^T R_z(\phi)^T (0, 0, g)^T = g\,(0, \sin\kappa, \cos\kappa)^T,

whatever the turntable angle: +Z, +Y, -Z, -Y up (the -Z, -Y, +Z, +Y face down) in flips 0, 90, 180,
270.  The four directions are distinct, so with an accelerometer whose axes are the housing's (SPEC's
runtime convention; a mounting error is fitted later as ``mag_to_accel``) each flip's label is checked: a
flip whose mean gravity lies within 45 deg of another flip's face had that face down.  Faces in an order no
mounting gives are refused; in an order one turn of the whole accelerometer gives (the same data as a chip
mounted turned) they are said with both readings (:func:`_check_flip_labels`).

Without an accelerometer the labels cannot be checked.  A cube turned the other way about X (flips 90
and 270 exchanged) is an exact symmetry of the magnetic model: with ``Rz(pi)`` the half turn about Z,
``Rx(-kappa) Rz(pi) = Rz(pi) Rx(kappa)``, so the directions ``a' = Rz(pi) a`` under the exchanged
labels give every output of the directions ``a`` under the right ones with the field's azimuth ``delta``
turned to ``delta + 180 deg``; the dip, the gains and the offsets are unchanged, and so is the
turntable's sense (it enters as ``Rz(phi + pi)``).  Likewise a shift of every label by 90 deg is the
directions turned 90 deg about X.  The fit is then as good as with the right labels, and every
direction comes out turned: only the operator's turning the cube as SPEC says (right-hand about +X:
flip 90 brings +Y up) fixes it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .names import RESERVED_NAMES
from .table import ReadOptions, RecordingError, Table, read_table
from .units import looks_like_radians, note

__all__ = ["FourFlipRecording", "read_fourflip", "NOMINAL_FLIPS_DEG", "RESERVED_COLUMNS"]

NOMINAL_FLIPS_DEG = (0.0, 90.0, 180.0, 270.0)
FLIP_TOLERANCE_DEG = 10.0
"""How far a recorded flip may be from its nominal value."""
MAX_GAP_DEG = 90.0
"""Largest turntable gap in one flip that still locates the output minimum."""
MIN_SAMPLES_PER_FLIP = 8
FACE_DOWN = ("-Z", "-Y", "+Z", "+Y")
"""The housing face down in flips 0, 90, 180, 270 (SPEC section 1)."""
UP_IN_HOUSING = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])
"""What a level accelerometer with the housing's axes reads in flips 0, 90, 180, 270, per g."""
_COARSE_SHARE = 0.01
"""Pairs of different consecutive rows at one ``t_s`` above this share of the rows: a ``t_s`` coarser than the samples."""
LABEL_CHECK_DEG = 45.0
"""A flip's mean gravity within this angle of another flip's face: that face was down (faces are 90 deg apart)."""
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
        _check_flip_labels(table, flip_index, accel)
    recording = FourFlipRecording(
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
    repeats = _repeated_rows(table)
    return recording.subset(~repeats) if repeats.any() else recording


def _repeated_rows(table: Table) -> np.ndarray:
    """Rows that repeat the row before exactly, ``t_s`` included (a logger writing a sample twice), said and dropped.

    A repeated sample is no new measurement: kept, it halves the noise the neighbours' differences show (the
    noise floor) and weighs its sample twice.  Without ``t_s``, or with a ``t_s`` coarser than the samples (two
    different rows at one time: whole seconds at 4 Hz), two equal rows can be two readings of a quantised channel at
    one stop, and are kept.
    """
    repeats = np.zeros(len(table.rows), dtype=bool)
    if not table.has("t_s") or len(table.rows) < 2:
        return repeats
    a, b = table.data[1:], table.data[:-1]
    repeats[1:] = np.all((a == b) | (np.isnan(a) & np.isnan(b)), axis=1)
    coarse = np.count_nonzero((np.diff(table.column("t_s")) == 0.0) & ~repeats[1:])
    if coarse > _COARSE_SHARE * len(repeats):  # different rows at one time, not one clock's hiccup
        if repeats.any():
            note(f"{table.path}: {int(repeats.sum())} rows repeat the row before exactly, kept: t_s is coarser than "
                 f"the samples ({coarse} pairs of different rows share a time), so they may be two readings")
        return np.zeros(len(table.rows), dtype=bool)
    if repeats.any():
        first = int(np.flatnonzero(repeats)[0])
        note(f"{table.path}: {int(repeats.sum())} of {len(repeats)} rows repeat the row before exactly, t_s included "
             f"(first: row {int(table.rows[first])} repeats row {int(table.rows[first - 1])}): a logger writing "
             "samples twice; the repeats are dropped (a repeated sample is no new measurement)")
    return repeats


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


def faces_down(flip_index: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """Per flip 0, 90, 180, 270, the index of the flip whose face the accelerometer says was down.

    Parameters
    ----------
    flip_index : ndarray of int, shape (n,)
    accel : ndarray, shape (n, 3)
        Accelerometer in the housing (specific force, any unit).

    Returns
    -------
    ndarray of int, shape (4,)
        ``k`` where flip k's mean gravity is within :data:`LABEL_CHECK_DEG` of what flip k's face gives
        (:data:`UP_IN_HOUSING`), another flip's index where it is within that of another's, -1 where
        of none (a direction along X, an accelerometer whose axes are not the housing's, or no reading).
    """
    out = np.full(4, -1)
    scale = np.median(np.linalg.norm(accel, axis=1))
    for k in range(4):
        mean = accel[flip_index == k].mean(axis=0)
        norm = np.linalg.norm(mean)
        if not (np.isfinite(norm) and norm > 0.1 * scale):
            continue
        cos = UP_IN_HOUSING @ (mean / norm)
        j = int(np.argmax(cos))
        if cos[j] > np.cos(np.radians(LABEL_CHECK_DEG)):
            out[k] = j
    return out


def _turned_labels(seen: np.ndarray) -> bool:
    """Whether the faces ``seen`` down in flips 0, 90, 180, 270 are the right ones under one turn of the whole
    accelerometer: a symmetry of the square of faces about X (a shift of every label, or a reflection of their
    order), which a turn about X, or a half turn about an axis in the YZ plane, gives."""
    k = np.arange(4)
    return any(np.array_equal(seen, (k + s) % 4) or np.array_equal(seen, (s - k) % 4) for s in range(4))


def _check_flip_labels(table: Table, flip_index: np.ndarray, accel: np.ndarray) -> None:
    """Refuse a recording whose accelerometer puts another flip's face down in some flip where no turn of the
    accelerometer explains it (see the module's notes); warn where one does.

    Every flip on a face, in an order one turn of the whole accelerometer gives (:func:`_turned_labels`): the
    same data as an accelerometer mounted turned against the housing, which the fit's ``mag_to_accel`` takes
    into account; said with both readings, not refused.  Left to the accelerometer fit's own words: every flip
    reading the face opposite its own (an accelerometer that reads gravity, not specific force:
    ``--accel-sign -1``), a flip whose gravity is near no face (an accelerometer whose axes are turned otherwise
    against the housing's).
    """
    seen = faces_down(flip_index, accel)
    wrong = [k for k in range(4) if seen[k] >= 0 and seen[k] != k]
    unseen = set(np.flatnonzero(seen < 0).tolist())
    mounted = unseen in ({0, 2}, {1, 3}, {0, 1, 2, 3})  # an accelerometer turned against the housing loses flips in
    # pairs (gravity in a flip and in the flip opposite are opposite); one flip alone near no face is not a mounting
    if not wrong or mounted or np.all(seen == (np.arange(4) + 2) % 4) or np.all(seen == seen[0]):
        return
    said = "; ".join(f"flip {NOMINAL_FLIPS_DEG[k]:g} had the {FACE_DOWN[seen[k]]} face down (flip "
                     f"{NOMINAL_FLIPS_DEG[seen[k]]:g}'s; flip {NOMINAL_FLIPS_DEG[k]:g} puts the {FACE_DOWN[k]} face down)"
                     for k in wrong)
    head = ("flips 90 and 270 look exchanged (the cube turned the other way about X)" if np.array_equal(seen, [0, 3, 2, 1])
            else "the flips look mislabelled")
    where = (f"{head}; the accelerometer (ax, ay, az) reads gravity as: {said}. SPEC turns the cube right-hand about "
             "+X (flip 90 brings +Y up, -Y face down)")
    if not unseen and _turned_labels(seen):
        note(f"{table.path}: {where}. Either the labels are wrong, and every fitted direction and every heading will "
             "be turned (relabel flip_deg to the faces that were down, or re-record), or the accelerometer is mounted "
             "turned against the housing, which the fitted mag_to_accel takes into account: the data cannot tell "
             "which (a magnetometer-only fit neither)")
        return
    rows = table.rows[flip_index == wrong[0]]
    twice = len(set(seen[seen >= 0].tolist())) < np.count_nonzero(seen >= 0)
    cure = ("one face was down in two flips: re-record the flip never made" if twice else
            "relabel flip_deg to the faces that were down, or re-record")
    raise RecordingError(table.path, f"{where}, in an order no mounting of the accelerometer gives: {cure}",
                         row=int(rows[0]), column="flip_deg")
