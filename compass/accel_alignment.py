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

import numpy as np

__all__ = ["accel_to_housing", "housing_from_accel", "imu_to_model", "read_mag_to_accel"]

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


def accel_to_housing(document: dict, accel):
    """Accelerometer readings (n, 3) in the housing frame H of the calibration's sensor model.

    Unchanged when the calibration has no ``mag_to_accel`` (or folds it into its model) or ``accel`` is None.
    """
    rotation = housing_from_accel(document)
    if accel is None or rotation is None:
        return accel
    return np.asarray(accel, dtype=float) @ rotation.T


def imu_to_model(document: dict) -> np.ndarray | None:
    """The rotation taking the module's accelerometer (and a gyro on the same chip) into the frame of the
    calibration's sensor model: into H by ``mag_to_accel^T``, then into the product by an installed file's
    alignment; None when both are absent."""
    from .installed import alignment_of

    to_housing, to_product = housing_from_accel(document), alignment_of(document)
    if to_housing is None or to_product is None:
        return to_product if to_housing is None else to_housing
    return to_product @ to_housing
