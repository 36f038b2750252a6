"""The calibration file (SPEC section 2), read and written in one place: one frozen value.

:func:`load` (or :func:`from_dict`) validates a calibration file once and returns a
:class:`Calibration`: the calibration kind, the :class:`~compass.model.SensorModel`, the inertial
correction (:class:`ImuCorrection`, one value with ``apply(a)``), the tilt sensor, the site, the
provenance, an installed file's :class:`Installation` and a tumble file's :class:`TumbleForm`.
:func:`save` writes a value (or a calibrator's document) atomically.  Nothing outside this package
reads or writes the JSON; calibrators build their documents with :func:`header` and
:func:`channel_entry`.

Examples
--------
>>> from compass.calibration import load
>>> cal = load("cal.json")                                  # doctest: +SKIP
>>> field_h, ok = cal.model.field(raw)                      # doctest: +SKIP
>>> accel_h = cal.imu.apply(accel)                          # doctest: +SKIP
"""

from ._checks import DEAD_RESPONSE_SIGMAS
from ._errors import CalibrationFileError, NoFieldVector
from ._format import FORMAT, KIND_KEY, channel_entry, header, model_to_dict
from ._imu import ImuCorrection
from ._read import KINDS, MAX_GYRO_MATRIX_ERROR, from_dict, gyro_matrix_mismatch, gyro_matrix_seen, gyro_scale_error, kind_of, latency_seen, load, loads, model_from_dict
from ._value import Calibration, Installation, Provenance, TumbleForm
from ._write import dumps, save, to_dict

__all__ = ["DEAD_RESPONSE_SIGMAS", "FORMAT", "KINDS", "KIND_KEY", "Calibration", "CalibrationFileError", "ImuCorrection", "Installation",
           "NoFieldVector", "Provenance", "TumbleForm", "channel_entry", "dumps", "from_dict", "header", "kind_of",
           "gyro_matrix_mismatch", "gyro_matrix_seen", "gyro_scale_error", "latency_seen", "load", "MAX_GYRO_MATRIX_ERROR", "loads", "model_from_dict", "model_to_dict", "save", "to_dict"]
