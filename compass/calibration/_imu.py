"""The module's accelerometer (and gyro) into the frame of the calibration's sensor model: one value.

As x-io Fusion's ``FusionCalibrationInertial`` (``misalignment * ((uncalibrated - offset) * sensitivity)``),
:class:`ImuCorrection` applies everything a calibration file says about the inertial sensor in one pure
function, :meth:`ImuCorrection.apply`:

.. math:: a_{model} = R \\, \\frac{a - o}{s}, \\qquad R = A \\, M^T

- ``o``, ``s``: the bench accelerometer's offsets and per-axis scales (a four-flip's ``accelerometer``
  block: ``offset``, ``scale_yz``; the X scale is not identifiable on the bench: 1), in the bench
  recording's unit;
- ``M`` = ``mag_to_accel``, ``R_accel<-H``: the accelerometer's alignment with the magnetic housing
  frame H (a tumble folds it into its sensor model: then absent here);
- ``A`` = an installed file's ``alignment``, ``R_product<-H``: the model is then in the product's frame.

The offsets and scales are in the bench's unit: a runtime stream in another unit (m/s^2 where the bench
had g, counts of another range) must not get them.  :meth:`ImuCorrection.fits` asks that the corrected
|a| read 1 g as the bench's did, within ``[0.7, 1.4]`` (units differ by 4x or more; motion and noise by
less).  A gyro gets the rotation only (:meth:`ImuCorrection.rotate`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..limits import reads_one_g

__all__ = ["ImuCorrection"]


@dataclass(frozen=True, eq=False)
class ImuCorrection:
    """The inertial half of a calibration: bench offsets and scales, then the rotation into the model's frame.

    Attributes
    ----------
    mag_to_accel : ndarray, shape (3, 3), or None
        ``R_accel<-H`` of the bench calibration; None when it has none or its model folds it in (tumble).
    alignment : ndarray, shape (3, 3), or None
        ``R_product<-H`` of an installed calibration with an alignment, else None.
    offset : ndarray, shape (3,), or None
        The bench accelerometer's zero offsets, the bench recording's unit; None without the block.
    scale : ndarray, shape (3,), or None
        Its per-axis scales relative to the bench's 1 g reading (X: 1).
    one_g : float or None
        The bench's reading of 1 g.

    Examples
    --------
    >>> imu = ImuCorrection(offset=np.array([0.01, 0.0, 0.0]), scale=np.ones(3), one_g=1.0)
    >>> imu.apply([1.01, 0.0, 0.0])
    array([1., 0., 0.])
    """

    mag_to_accel: np.ndarray | None = None
    alignment: np.ndarray | None = None
    offset: np.ndarray | None = None
    scale: np.ndarray | None = None
    one_g: float | None = None

    def __post_init__(self):
        given = [v is not None for v in (self.offset, self.scale, self.one_g)]
        if any(given) and not all(given):
            raise ValueError("the bench accelerometer's correction needs offset, scale and one_g together")

    @property
    def has_bench_correction(self) -> bool:
        """The calibration carries the bench accelerometer's offsets and scales."""
        return self.offset is not None

    @cached_property
    def to_housing(self) -> np.ndarray | None:
        """``R_H<-accel`` (``mag_to_accel^T``), None without ``mag_to_accel``."""
        return None if self.mag_to_accel is None else self.mag_to_accel.T

    @cached_property
    def rotation(self) -> np.ndarray | None:
        """``R_model<-imu``: into H by ``mag_to_accel^T``, then into the product by the alignment; None
        when both are absent (the readings are already in the model's frame)."""
        if self.to_housing is None or self.alignment is None:
            return self.alignment if self.to_housing is None else self.to_housing
        return self.alignment @ self.to_housing

    def undo_bench(self, accel) -> np.ndarray:
        """Readings (..., 3) with the bench's offsets and scales undone, the same unit (unchanged without them)."""
        accel = np.asarray(accel, dtype=float)
        return accel if self.offset is None else (accel - self.offset) / self.scale

    def rotate(self, vector) -> np.ndarray:
        """Vectors (..., 3) of the module's inertial frame (a gyro's rates) in the model's frame."""
        vector = np.asarray(vector, dtype=float)
        return vector if self.rotation is None else vector @ self.rotation.T

    def apply(self, accel, *, bench: bool = True) -> np.ndarray:
        """Accelerometer readings (..., 3) in the frame of the calibration's sensor model.

        Parameters
        ----------
        accel : array_like, shape (..., 3)
            The module's accelerometer, any unit (the bench's for ``bench=True`` to make sense).
        bench : bool
            Undo the bench's offsets and scales first (when the calibration has them).

        Returns
        -------
        ndarray, shape (..., 3)
            Same unit; the model's frame (H, or an installed file's product frame).
        """
        return self.rotate(self.undo_bench(accel) if bench else accel)

    def fits(self, accel) -> bool:
        """The readings (n, 3), corrected, read 1 g as the bench's did (median |a| within
        :data:`compass.limits.ONE_G_RATIO` of it: :func:`compass.limits.reads_one_g`).

        Always True without a bench correction (nothing to judge).
        """
        if self.offset is None:
            return True
        return reads_one_g(self.undo_bench(np.atleast_2d(accel)), self.one_g)

    @property
    def not_fitting(self) -> str:
        """What to tell a user whose readings do not :meth:`fits`."""
        return (f"the accelerometer does not read 1 g as on the bench ({self.one_g:.4g}): another unit? Its bench "
                "offsets and scales are not applied")

    def in_model_frame(self, accel) -> tuple:
        """Readings (n, 3) in the model's frame, and whether the bench's offsets and scales were undone.

        They are undone when the readings :meth:`fits` (a :class:`compass.io.units.RecordingWarning`
        when they do not); ``accel`` None stays None.
        """
        if accel is None:
            return None, False
        undone = self.has_bench_correction and self.fits(accel)
        if self.has_bench_correction and not undone:
            from ..io.units import RecordingWarning

            warnings.warn(RecordingWarning(self.not_fitting))
        return self.apply(accel, bench=undone), undone
