"""Seed 001's 3-D platform recording, and the runtime reader of its tilt-sensor calibration.

Recording (CSV in the style of SPEC section 2; ``# key: value`` metadata, one header row):

- ``platform_z_deg, platform_y_deg, platform_x_deg`` (required): the platform's three gimbal
  angles, degrees.  The housing frame H (SPEC section 1; the housing's X and Y edges pressed
  against the platform's X and Y axes, as the seed mounts it) is seen in the bench frame W
  (Z up) as

  .. math:: a_W = R_z(z)\\, R_y(y)\\, R_x(x)\\, a_H,

  each angle right-handed about its axis: the outer gimbal turns about the bench's vertical +Z,
  the middle one about its own +Y, the inner one about the housing's +X.  With ``platform_y_deg
  = 0`` this is the four-flip bench's ``Rz(phi) Rx(kappa)``.  In scipy:
  ``Rotation.from_euler("ZYX", [z, y, x], degrees=True)`` is ``R_W<-H``.  The zero of ``z`` is
  arbitrary: the field's azimuth from it is fitted.
- ``mx, my, mz`` (required): magnetometer outputs, any unit.
- ``ax, ay`` (required) and ``az`` (optional): tilt sensor (two-axis inclinometer of the seed) or
  accelerometer, outputs linear in the specific force (+1 g up at rest), any unit.
- ``t_s`` (optional, non-decreasing seconds), ``temp_c`` (optional).

Rows with the same three angles are repeated samples of one pose; their spread gives the noise
floor.  Metadata ``field_ut`` gives |B| (gains then per microtesla).

The calibration file written from such a recording keeps the magnetometer in SPEC's channel form
and the tilt sensor under ``"tilt_sensor"``; :class:`TiltSensor` reads that key at runtime and
turns tilt-sensor outputs into the up direction in H for :func:`compass.attitude.solve_attitude`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .table import ReadOptions, RecordingError, Table, read_table
from .units import looks_like_radians, note

__all__ = ["ANGLE_COLUMNS", "MAG_COLUMNS", "Platform3DRecording", "TiltSensor", "platform3d_from_table",
           "read_platform3d", "platform_rotation"]

ANGLE_COLUMNS = ("platform_z_deg", "platform_y_deg", "platform_x_deg")
MAG_COLUMNS = ("mx", "my", "mz")
MIN_POSES = 12
"""Fewest distinct platform poses accepted (the joint fit has up to 28 parameters)."""


def platform_rotation(z_deg, y_deg, x_deg) -> Rotation:
    """``R_W<-H = Rz(z) Ry(y) Rx(x)`` from the platform angles (degrees), one rotation per sample."""
    angles = np.column_stack(np.broadcast_arrays(np.asarray(z_deg, float), np.asarray(y_deg, float),
                                                 np.asarray(x_deg, float)))
    return Rotation.from_euler("ZYX", angles, degrees=True)


@dataclass(frozen=True)
class Platform3DRecording:
    """A validated 3-D platform recording.

    Attributes
    ----------
    path : str
    angles_deg : ndarray, shape (n, 3)
        ``platform_z_deg, platform_y_deg, platform_x_deg`` of every row.
    mag : ndarray, shape (n, 3)
        Magnetometer outputs ``mx, my, mz``, recording units.
    tilt : ndarray, shape (n, 2) or (n, 3)
        Tilt-sensor outputs (``ax, ay[, az]``), recording units.
    tilt_columns : tuple of str
    pose : ndarray of int, shape (n,)
        Index of each row's distinct pose (rows with equal angles share it).
    rows : ndarray of int, shape (n,)
        1-based file line of every row.
    t_s, temp_c : ndarray, shape (n,), or None
    metadata : dict
    """

    path: str
    angles_deg: np.ndarray
    mag: np.ndarray
    tilt: np.ndarray
    tilt_columns: tuple
    pose: np.ndarray
    rows: np.ndarray
    t_s: np.ndarray | None
    temp_c: np.ndarray | None
    metadata: dict

    @property
    def rotation(self) -> Rotation:
        """``R_W<-H`` of every row."""
        return platform_rotation(*self.angles_deg.T)


def read_platform3d(path, options: ReadOptions | None = None) -> Platform3DRecording:
    """Read and validate a 3-D platform recording; see :func:`platform3d_from_table`."""
    return platform3d_from_table(read_table(path, options))


def platform3d_from_table(table: Table) -> Platform3DRecording:
    """Validate a parsed table as a 3-D platform recording.

    Raises
    ------
    RecordingError
        A required column is missing, ``az`` without ``ax, ay``, a magnetometer or tilt channel
        that never changes, or fewer than ``MIN_POSES`` distinct poses.

    Warns
    -----
    RecordingWarning
        Columns ignored; platform angles that never leave 2*pi (radians?).
    """
    angles = np.column_stack([table.column(c) for c in ANGLE_COLUMNS])
    mag = np.column_stack([table.column(c) for c in MAG_COLUMNS])
    tilt_columns = ("ax", "ay", "az") if table.has("az") else ("ax", "ay")
    tilt = np.column_stack([table.column(c) for c in tilt_columns])
    table.ignore_unknown(ANGLE_COLUMNS + MAG_COLUMNS + tilt_columns + ("t_s", "temp_c"), what="a 3-D platform calibration")
    if looks_like_radians(angles) and np.ptp(angles[:, 0]) > 1.0:
        note(f"{table.path}: the platform angles never leave 0..2*pi: radians? The columns are in degrees; convert "
             "them, or name the unit with --angle-unit rad")
    t_s = table.time_s()
    _, pose = np.unique(np.round(angles, 6), axis=0, return_inverse=True)
    pose = pose.ravel()
    if pose.max() + 1 < MIN_POSES:
        raise RecordingError(table.path, f"only {pose.max() + 1} distinct platform poses; the 3-D platform "
                             f"calibration needs at least {MIN_POSES}", column=ANGLE_COLUMNS[0])
    table.check_constant(MAG_COLUMNS + tilt_columns)
    return Platform3DRecording(table.path, angles, mag, tilt, tilt_columns, pose, np.asarray(table.rows),
                               t_s, table.column("temp_c") if table.has("temp_c") else None, dict(table.metadata))


@dataclass(frozen=True)
class TiltSensor:
    """The tilt sensor of a 3-D platform calibration: outputs -> up direction in H.

    Model: ``raw = offset + matrix @ f_H`` with ``f_H`` the specific force in H in g (``+z`` up
    for a level housing at rest); row ``c`` of ``matrix`` is the channel's scale (output units
    per g) times its unit sensing direction in H.

    Attributes
    ----------
    columns : tuple of str
        ``("ax", "ay")`` or ``("ax", "ay", "az")``.
    matrix : ndarray, shape (c, 3)
    offset : ndarray, shape (c,)
    """

    columns: tuple
    matrix: np.ndarray
    offset: np.ndarray

    @classmethod
    def from_json(cls, d: dict) -> "TiltSensor":
        """Read the ``"tilt_sensor"`` key of a calibration file's dictionary.

        Raises
        ------
        ValueError
            No ``tilt_sensor`` key, or a matrix/offset of the wrong shape.
        """
        t = d.get("tilt_sensor") if isinstance(d, dict) else None
        if not isinstance(t, dict):
            raise ValueError("the calibration has no 'tilt_sensor' (it is not a 3-D platform calibration)")
        try:
            columns = tuple(t["columns"])
            matrix = np.asarray(t["matrix"], dtype=float)
            offset = np.asarray(t["offset"], dtype=float)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"'tilt_sensor' needs columns, matrix and offset ({exc})") from None
        c = len(columns)
        if c not in (2, 3) or matrix.shape != (c, 3) or offset.shape != (c,) or not np.all(np.isfinite(matrix)):
            raise ValueError(f"'tilt_sensor': expected 2 or 3 columns with a (c, 3) matrix and c offsets, got "
                             f"{c} columns, matrix {matrix.shape}, offset {offset.shape}")
        if np.linalg.svd(matrix, compute_uv=False)[-1] <= 1e-9 * np.abs(matrix).max():
            raise ValueError("'tilt_sensor': the sensing directions are parallel")
        return cls(columns, matrix, offset)

    def up(self, raw) -> np.ndarray:
        """Specific force in H from tilt-sensor outputs, g, shape (n, 3).

        Three axes: ``matrix^-1 (raw - offset)``.  Two axes: the minimum-norm solution plus the
        component along the axes' common normal ``n`` that makes ``|f| = 1 g``, taken on the
        housing's upper side (``n`` oriented with ``n . z_H > 0``): a two-axis sensor cannot tell
        an upright housing from one upside down.

        Parameters
        ----------
        raw : array_like, shape (n, c)
            Outputs in the order of :attr:`columns`.
        """
        x = np.atleast_2d(np.asarray(raw, dtype=float)) - self.offset
        if x.shape[1] != len(self.columns):
            raise ValueError(f"expected tilt outputs of shape (n, {len(self.columns)}), got {x.shape}")
        if len(self.columns) == 3:
            return np.linalg.solve(self.matrix, x.T).T
        p, normal, height = self._two_axis(x)
        return p + height[:, None] * normal

    def _two_axis(self, x):
        """Minimum-norm part, the axes' common normal (``n . z_H > 0``) and the height along it."""
        p = x @ np.linalg.pinv(self.matrix).T
        normal = np.cross(self.matrix[0], self.matrix[1])
        normal /= np.linalg.norm(normal) * (1.0 if normal[2] >= 0 else -1.0)
        return p, normal, np.sqrt(np.clip(1.0 - np.sum(p**2, axis=1), 0.0, None))

    def upside_down_rows(self, raw, field_h, dip_deg: float, *, tolerance_deg: float = 5.0) -> int:
        """How many rows a two-axis sensor reads upright but the field says are upside down.

        For each row the dip ``asin(-B.f / |B||f|)`` is computed with the upright solution of
        :meth:`up` and with its mirror (``az < 0``); a row counts when the upright dip misses the
        calibration's by more than ``tolerance_deg`` and the mirror's is closer.  Always 0 for a
        three-axis sensor.

        Parameters
        ----------
        raw : array_like, shape (n, 2)
        field_h : ndarray, shape (n, 3)
            Field in H (the calibration's sensor model), any unit.
        dip_deg : float
            The calibration's dip.
        """
        if len(self.columns) == 3 or dip_deg is None:
            return 0
        p, normal, height = self._two_axis(np.atleast_2d(np.asarray(raw, dtype=float)) - self.offset)
        b = field_h / np.linalg.norm(field_h, axis=1, keepdims=True)

        def miss(f):
            f = f / np.linalg.norm(f, axis=1, keepdims=True)
            return np.abs(np.degrees(np.arcsin(np.clip(-np.sum(b * f, axis=1), -1, 1))) - dip_deg)

        upright, mirror = miss(p + height[:, None] * normal), miss(p - height[:, None] * normal)
        return int(np.count_nonzero((upright > tolerance_deg) & (mirror < upright)))
