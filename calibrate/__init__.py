"""Procedures that estimate a sensor model from recordings (seed 000's four-flip bench first).

Data flows one way: recordings -> ``calibrate`` -> calibration file -> :mod:`compass`.
"""

from .fourflip import METHODS, calibrate_fourflip
from .result import FORMAT, CalibrationResult, ChannelCalibration

__all__ = ["METHODS", "FORMAT", "calibrate_fourflip", "CalibrationResult", "ChannelCalibration"]
