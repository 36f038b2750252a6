"""Seed 000's four-flip bench: single-axis channels on a turntable, flipped about its X axis.

One module per concern: :mod:`~calibrate.fourflip.fit` (the ``patent``, ``harmonic`` and ``ml``
estimators, :class:`FourFlipCalibrator`), :mod:`~calibrate.fourflip._harmonic` (first-harmonic fits
and the seed's closed forms), :mod:`~calibrate.fourflip._mlfit` (the joint maximum-likelihood fit),
:mod:`~calibrate.fourflip.effects` (what the base model lacks), :mod:`~calibrate.fourflip.diagnosis`
(the residual diagnosis) and :mod:`~calibrate.fourflip.result` (:class:`FourFlipResult`).  The
forward model is :mod:`compass.sim.bench`, shared with the simulator.
"""

from .diagnosis import UNEXPLAINED_WARNING, diagnose_fourflip, examine_residual
from .effects import EFFECTS, VARIANTS
from .fit import METHODS, FourFlipCalibrator, calibrate_fourflip, physics_from_harmonics, result_from_ml
from .result import FourFlipResult, ChannelCalibration

__all__ = ["EFFECTS", "METHODS", "UNEXPLAINED_WARNING", "VARIANTS", "FourFlipResult", "ChannelCalibration",
           "FourFlipCalibrator", "calibrate_fourflip", "diagnose_fourflip", "examine_residual",
           "physics_from_harmonics", "result_from_ml"]
