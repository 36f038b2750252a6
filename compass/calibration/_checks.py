"""The value checks of the one calibration-file validator: numbers, arrays, rotations, soft iron.

Every check raises :class:`CalibrationFileError` naming the key; the tolerances are defined once here.
"""

from __future__ import annotations

import json
import math

import numpy as np

from ..io.units import MAX_ABS_VALUE
from ..limits import Range
from ._errors import CalibrationFileError

UNIT_TOLERANCE = 1e-6
"""``| |direction| - 1 |`` accepted for a sensing direction."""
ROTATION_TOLERANCE = 1e-6
"""``R R^T - I`` accepted, element-wise, for a rotation matrix."""
SYMMETRY_TOLERANCE = 1e-6

DEAD_RESPONSE_SIGMAS = 5.0
"""A channel whose gain is smaller than this many of its own standard errors does not respond to the
field (a dead sensor): at 5 sigma a working channel is called dead with a chance of 3e-7.  The
calibrators refuse to write such a channel (:mod:`calibrate.health`); a file holding one is refused."""
"""Asymmetry of a soft-iron matrix accepted, relative to its largest entry."""
OUTPUT = Range(-MAX_ABS_VALUE, MAX_ABS_VALUE)
"""An output (offset, noise floor) in output units: within the recordings' limit
(:data:`compass.io.units.MAX_ABS_VALUE`: no sensor output reaches beyond)."""
GAIN = Range(1 / MAX_ABS_VALUE, MAX_ABS_VALUE)
"""A gain, output units per field unit, or a soft-iron eigenvalue (its inverse): 1e-12..1e12."""
HARD_IRON_FIELDS = 100.0
"""Largest hard iron, in fields: a sensor offset by a hundred times the field it measures reads beyond
the range the filters screen (:data:`compass.sample_check.FIELD_RATIO_LIMIT`): a magnet on it."""


def number(v, key, *, positive=False, nonnegative=False, allow_none=False, low=None, high=None, bounds=None):
    """``v`` as a finite float (or None when allowed), else CalibrationFileError naming ``key``; within
    ``bounds`` (a :class:`compass.limits.Range`) when given."""
    if v is None and allow_none:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise CalibrationFileError(f"must be a number{' or null' if allow_none else ''}, got {show(v)}", key=key)
    v = float(v)
    if not math.isfinite(v):
        raise CalibrationFileError(f"must be finite, got {v}", key=key)
    if bounds is not None and v not in bounds:
        raise CalibrationFileError(f"must be {bounds.describe()}, got {v:g}", key=key)
    if positive and not v > 0:
        raise CalibrationFileError(f"must be positive, got {v:g}", key=key)
    if nonnegative and v < 0:
        raise CalibrationFileError(f"must not be negative, got {v:g}", key=key)
    if (low is not None and v < low) or (high is not None and v > high):
        raise CalibrationFileError(f"must be within [{'-inf' if low is None else f'{low:g}'}, "
                                   f"{'inf' if high is None else f'{high:g}'}], got {v:g}", key=key)
    return v


def array(v, shape: tuple, key, limit: float = np.inf) -> np.ndarray:
    """``v`` as a finite float array of ``shape`` (nested JSON lists of numbers), every value within +-``limit``."""
    what = "a list of 3 numbers" if shape == (3,) else f"{'x'.join(map(str, shape))} nested lists of numbers"
    try:
        out = np.asarray(v, dtype=float) if _all_numbers(v) else None
    except (TypeError, ValueError):
        out = None
    if out is None or out.shape != shape:
        raise CalibrationFileError(f"must be {what}, got {show(v)}", key=key)
    if not np.all(np.isfinite(out)):
        raise CalibrationFileError(f"must be finite, got {show(v)}", key=key)
    if np.any(np.abs(out) > limit):
        raise CalibrationFileError(f"must be within +-{limit:g} (no sensor output reaches beyond), got "
                                   f"{out.flat[np.argmax(np.abs(out))]:g}", key=key)
    return out


def rotation(v, key: str) -> np.ndarray:
    """A proper rotation matrix (orthonormal within :data:`ROTATION_TOLERANCE`, determinant +1)."""
    r = array(v, (3, 3), key)
    if not np.allclose(r @ r.T, np.eye(3), atol=ROTATION_TOLERANCE) or np.linalg.det(r) < 0:
        raise CalibrationFileError(f"must be a proper rotation matrix (orthonormal, determinant +1), got "
                                   f"determinant {np.linalg.det(r):.6g}", key=key)
    return r


def soft_iron(v, key: str) -> np.ndarray:
    """A soft-iron matrix: symmetric (within :data:`SYMMETRY_TOLERANCE`) and positive definite."""
    soft = array(v, (3, 3), key, limit=GAIN.hi)
    scale = np.abs(soft).max()
    if not np.allclose(soft, soft.T, rtol=0.0, atol=SYMMETRY_TOLERANCE * scale):
        raise CalibrationFileError("must be symmetric (a soft-iron matrix is)", key=key)
    eig = np.linalg.eigvalsh(soft)
    if not eig[0] > 1e-9 * scale:
        raise CalibrationFileError(f"must be positive definite, its eigenvalues are {np.round(eig, 6).tolist()}",
                                   key=key)
    if not (eig[0] >= GAIN.lo and eig[-1] <= GAIN.hi):  # the inverse of a gain: field units per output unit
        raise CalibrationFileError(f"must have eigenvalues in [{GAIN.lo:g}, {GAIN.hi:g}], got {eig[0]:.4g} to "
                                   f"{eig[-1]:.4g}", key=key)
    return soft


def hard_iron(v, field_norm: float, key: str) -> np.ndarray:
    """A hard-iron offset (3,) within :data:`HARD_IRON_FIELDS` times ``field_norm`` in size (same unit)."""
    hard = array(v, (3,), key, limit=MAX_ABS_VALUE)
    size = math.hypot(*hard)
    if not size <= HARD_IRON_FIELDS * field_norm:
        raise CalibrationFileError(f"must be within {HARD_IRON_FIELDS:g} times the field's {field_norm:.4g} in size "
                                   f"(a magnet on the sensor saturates it), got {size:.4g}", key=key)
    return hard


def obj(v, key) -> dict:
    """``v`` if it is a JSON object."""
    if not isinstance(v, dict):
        raise CalibrationFileError(f"must be an object, got {show(v)}", key=key)
    return v


def noise(value, n: int, key: str = "noise_floor") -> np.ndarray | None:
    """A per-channel noise floor (a list of ``n``, or one number for all), non-negative; None if absent."""
    if value is None:
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * n
    out = array(value, (n,), key, limit=OUTPUT.hi)
    if np.any(out < 0):
        raise CalibrationFileError(f"must not be negative, got {show(value)}", key=key)
    return out


def sub(key, name: str):
    """The key of ``name`` inside ``key`` (a dotted string, or a channel's tuple)."""
    if isinstance(key, tuple):
        return key[:2] + (f"{key[2]}.{name}" if len(key) > 2 else name,)
    return f"{key}.{name}"


def words(exc: Exception) -> str:
    """An exception of a block's own reader, as a reason."""
    text = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
    return f"is malformed ({text})"


def json_type(v) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "true/false", type(None): "null"}.get(
        type(v), "a number")


def show(v) -> str:
    """A short rendering of a JSON value for a message."""
    text = json.dumps(v) if isinstance(v, (int, float, str, type(None), bool)) else json_type(v)
    return text if len(text) < 60 else text[:57] + "..."


def _all_numbers(v) -> bool:
    if isinstance(v, list):
        return all(_all_numbers(x) for x in v)
    return isinstance(v, (int, float)) and not isinstance(v, bool)
