"""Procedures that estimate a sensor model from recordings.

Seed 000's four-flip bench (:func:`calibrate_fourflip`, with the residual diagnosis), free
motion (:func:`calibrate_tumble`), seed 001's 3-D platform (:func:`calibrate_platform3d`) and
seed 003's reference fields (:func:`calibrate_reference`).  Data flows one way: recordings ->
``calibrate`` -> calibration file -> :mod:`compass`.
"""

from .fourflip import METHODS, CalibrationResult, ChannelCalibration, calibrate_fourflip
from .platform3d import calibrate_platform3d
from .reference import calibrate_reference
from .tumble import calibrate_tumble

__all__ = [
    "METHODS",
    "CalibrationResult",
    "ChannelCalibration",
    "calibrate_fourflip",
    "calibrate_platform3d",
    "calibrate_reference",
    "calibrate_tumble",
]
