"""The one writer of calibration files: validated, no NaN or Infinity, atomic, never over a file without force."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ._errors import NoFieldVector
from ._read import from_dict
from ._value import Calibration

__all__ = ["dumps", "save", "to_dict"]


def dumps(cal) -> str:
    """The file's text of a :class:`Calibration` or of a calibrator's document (``result.to_json()``).

    A document is validated as :func:`compass.calibration.from_dict` reads it.  Numbers the runtime
    reads must be finite (else :class:`CalibrationFileError` naming the key); a non-finite number in
    a reported-only key (an undefined sigma, a BIC) is written as null, JSON's "not available".

    Raises
    ------
    CalibrationFileError
    """
    if isinstance(cal, Calibration):
        doc = _thawed(cal.document)
    else:
        doc = cal
        try:
            from_dict(doc)
        except NoFieldVector:
            pass  # single-axis channels (or coplanar ones): a valid calibration the vector runtime refuses on reading
    return json.dumps(_finite_or_null(doc), indent=2, allow_nan=False) + "\n"


def save(path, cal, *, force: bool = False) -> Path:
    """Write a calibration atomically to ``path`` (refused without ``force`` if it exists).

    Parameters
    ----------
    path : str or Path
    cal : Calibration or dict
        The value (written as it was read, every reported key kept), or a calibrator's document,
        validated first (:func:`dumps`).
    force : bool
        Replace an existing file.

    Returns
    -------
    Path

    Raises
    ------
    CalibrationFileError, FileExistsError, OutputError
    """
    from ..io.atomic import atomic_write_text, check_writable

    text = dumps(cal)
    out = check_writable(path, force)
    atomic_write_text(out, text)
    return out


def to_dict(cal: Calibration) -> dict:
    """The calibration's document, a plain copy JSON-ready (to nest it: an installed file's ``base``)."""
    return json.loads(dumps(cal))


def _thawed(value):
    """A frozen document (:attr:`Calibration.document`) back as plain dicts and lists."""
    if isinstance(value, Mapping):
        return {k: _thawed(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return [_thawed(v) for v in value]
    return value


def _finite_or_null(value):
    if isinstance(value, dict):
        return {k: _finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_null(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite_or_null(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value
