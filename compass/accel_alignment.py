"""The accelerometer's alignment with the magnetic housing frame (a calibration's ``mag_to_accel``).

A channel-form calibration (four-flip) gives the sensing directions in the housing frame H, which
the bench defines (the cube).  When its recording had an accelerometer, the calibration also holds
``"mag_to_accel"``: ``R_accel<-H``, the rotation taking a vector in H into the accelerometer's frame
(SPEC section 2).  At runtime the accelerometer is rotated into H, ``a_H = mag_to_accel^T a``, so
that pitch and roll are the housing's and not the accelerometer chip's.

A tumble calibration's ``mag_to_accel`` is already folded into its sensor model (whose frame is the
accelerometer's, :mod:`compass.model`): nothing to do here.  An installed calibration's bench
calibration sits under ``"base"``; its ``mag_to_accel`` applies before the installation's alignment.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

__all__ = ["AccelCorrection", "accel_correction", "accel_in_housing", "accel_to_housing", "housing_from_accel", "imu_to_model",
           "read_mag_to_accel"]

_FOLDED_KINDS = ("tumble",)  # kinds whose sensor model is already in the accelerometer's frame


def read_mag_to_accel(d: dict) -> np.ndarray | None:
    """The validated ``mag_to_accel`` of a calibration document, None when its model folds it in.

    Raises
    ------
    CalibrationFileError
        Not a proper rotation matrix (the message names the key).
    """
    from .calibration_file import _rotation, kind_of

    if kind_of(d) in _FOLDED_KINDS or d.get("mag_to_accel") is None:
        return None
    return _rotation(d["mag_to_accel"], "mag_to_accel")


def housing_from_accel(document: dict) -> np.ndarray | None:
    """``R_H<-accel`` of a calibration document (or of an installed one's base), None when there is none."""
    base = document.get("base") if document.get("model") == "installed" else document
    if not isinstance(base, dict):
        return None
    rotation = read_mag_to_accel(base)
    return None if rotation is None else rotation.T


@dataclass(frozen=True)
class AccelCorrection:
    """The bench accelerometer's offsets and Y/Z scales (the four-flip's ``accelerometer`` block), undone
    at runtime: ``a' = (a - offset) / (1, s_y, s_z)`` (the X scale is not identifiable on the bench: 1).

    They are in the bench recording's unit; a runtime stream in another unit (m/s^2 where the bench had
    g, counts of another range) must not get them: :meth:`fits` asks that the corrected |a| read 1 g
    as the bench's did, within ``[0.7, 1.4]`` (units differ by 4x or more; motion and noise by less).

    Attributes
    ----------
    offset : ndarray, shape (3,)
        Zero offsets, the bench recording's unit.
    scale : ndarray, shape (3,)
        Per-axis scale relative to the bench's 1 g reading (X: 1).
    one_g : float
        The bench's reading of 1 g.
    """

    offset: np.ndarray
    scale: np.ndarray
    one_g: float

    def apply(self, accel) -> np.ndarray:
        """Readings (..., 3) with the offsets and scales undone, the same unit."""
        return (np.asarray(accel, dtype=float) - self.offset) / self.scale

    def fits(self, accel) -> bool:
        """The readings (n, 3), corrected, read 1 g as the bench's did (their median |a| within [0.7, 1.4] of it)."""
        norms = np.linalg.norm(self.apply(np.atleast_2d(accel)), axis=1)
        norms = norms[np.isfinite(norms)]
        return norms.size > 0 and 0.7 <= float(np.median(norms)) / self.one_g <= 1.4

    @property
    def not_fitting(self) -> str:
        """What to tell a user whose readings do not :meth:`fit`."""
        return (f"the accelerometer does not read 1 g as on the bench ({self.one_g:.4g}): another unit? Its bench "
                "offsets and scales are not applied")


def accel_correction(document: dict) -> AccelCorrection | None:
    """The bench accelerometer's correction of a calibration (or of an installed one's base), None without one."""
    base = document.get("base") if document.get("model") == "installed" else document
    block = base.get("accelerometer") if isinstance(base, dict) else None
    try:
        offset, scale_yz, one_g = (np.asarray(block[k], dtype=float) for k in ("offset", "scale_yz", "one_g"))
    except (KeyError, TypeError, ValueError):
        return None
    scale = np.concatenate([[1.0], scale_yz]) if scale_yz.shape == (2,) else None
    if offset.shape != (3,) or scale is None or not (np.all(np.isfinite(offset)) and np.all(scale > 0)
                                                     and float(one_g) > 0):
        return None
    return AccelCorrection(offset, scale, float(one_g))


def accel_in_housing(document: dict, accel) -> tuple:
    """Accelerometer readings (n, 3) in the housing frame H of the calibration's sensor model, and whether
    the bench's offsets and scales were undone.

    They are undone first when the readings are in the bench's unit (:class:`AccelCorrection`; a warning
    when they are not), then the readings are turned by ``mag_to_accel^T``.  Unchanged when the calibration
    has neither (a tumble folds its rotation into its model) or ``accel`` is None.
    """
    if accel is None:
        return accel, False
    correction, undone = accel_correction(document), False
    if correction is not None:
        if correction.fits(accel):
            accel, undone = correction.apply(accel), True
        else:
            from .io.units import RecordingWarning

            warnings.warn(RecordingWarning(correction.not_fitting))
    rotation = housing_from_accel(document)
    return (accel if rotation is None else np.asarray(accel, dtype=float) @ rotation.T), undone


def accel_to_housing(document: dict, accel):
    """:func:`accel_in_housing`'s readings alone."""
    return accel_in_housing(document, accel)[0]


def imu_to_model(document: dict) -> np.ndarray | None:
    """The rotation taking the module's accelerometer (and a gyro on the same chip) into the frame of the
    calibration's sensor model: into H by ``mag_to_accel^T``, then into the product by an installed file's
    alignment; None when both are absent."""
    from .installed import alignment_of

    to_housing, to_product = housing_from_accel(document), alignment_of(document)
    if to_housing is None or to_product is None:
        return to_product if to_housing is None else to_housing
    return to_product @ to_housing
