"""Installation calibration: the bench-calibrated module inside its product (SPEC section 2).

:class:`InstallationCalibrator` fits the product's hard and soft iron in the housing frame (and,
with a known heading, the housing's yaw in the product) on top of a bench calibration, from a
tumble or a swing; :class:`InstallationResult` is the result (report, deviation-card plot,
the installed calibration file); :mod:`.model` is the least squares and :mod:`.diagnosis` its
residual diagnosis on the shared evidence loop.
"""

from .card import DeviationCard, deviation_card
from .diagnosis import InstallationDiagnosis
from .fit import InstallationResult, InstallationCalibrator

__all__ = ["DeviationCard", "deviation_card", "InstallationResult", "InstallationCalibrator",
           "InstallationDiagnosis"]
