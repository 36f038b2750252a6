"""Procedures that estimate a sensor model from recordings.

Seed 000's four-flip bench (:func:`calibrate_fourflip`, with the residual diagnosis), free
motion (:func:`calibrate_tumble`), seed 001's 3-D platform (:func:`calibrate_platform3d`) and
seed 003's reference fields (:func:`calibrate_reference`).  Data flows one way: recordings ->
``calibrate`` -> calibration file -> :mod:`compass`.
"""

from importlib import import_module

_HOMES = {"METHODS": "fourflip", "FourFlipResult": "fourflip", "ChannelCalibration": "fourflip",
          "calibrate_fourflip": "fourflip", "calibrate_platform3d": "platform3d",
          "calibrate_reference": "reference", "calibrate_tumble": "tumble"}
"""Name -> the kind's package: imported on first use, so using one kind imports no other."""

__all__ = [
    "METHODS",
    "FourFlipResult",
    "ChannelCalibration",
    "calibrate_fourflip",
    "calibrate_platform3d",
    "calibrate_reference",
    "calibrate_tumble",
]


def __getattr__(name):
    if name not in _HOMES:
        raise AttributeError(f"module 'calibrate' has no attribute {name!r}")
    return getattr(import_module(f".{_HOMES[name]}", __name__), name)


def __dir__():
    return sorted(set(globals()) | set(_HOMES))
