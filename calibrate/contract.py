"""The calibration contract every kind follows (scikit-learn's estimators, lmfit's one result type).

- A :class:`Calibrator` per kind takes its options as keyword-only constructor arguments (no
  computation there) and fits with ``fit(recording) -> Calibration``.
- A :class:`Calibration` (the kind's frozen result) has ``calibration_kind`` (the file's
  ``"model"``; a tumble result's ``kind`` is its ellipsoid kind), ``parameters`` (name -> (value,
  sigma or None)), ``warnings`` (tuple of str), ``diagnosis`` (the residual diagnosis, SPEC section
  4; its file block is ``to_json()["diagnosis"]``), ``report()``, ``plots(recording, folder)`` and
  ``to_json()`` (the calibration file, written by :func:`compass.calibration.save`).
- :class:`CannotCalibrate` says, in words, why a recording cannot be calibrated (exit 2 on the
  command line).

:mod:`calibrate.kinds` maps every kind to its column sniffer, recording reader and calibrator.
"""

from __future__ import annotations

import abc
import inspect
from pathlib import Path
from typing import ClassVar

__all__ = ["Calibration", "Calibrator", "CannotCalibrate"]


class CannotCalibrate(ValueError):
    """This recording cannot be calibrated: the message says why in words and names the file.

    Raised for bad input (poses that leave parameters undetermined, too few or coplanar fields,
    no determined ellipsoid, a field that changed partway, a channel that does not follow the
    field); the command line reports it with exit status 2.
    """


class Calibration(abc.ABC):
    """Base of every kind's result.

    Besides the methods below, a result has the attributes ``parameters`` (dict name ->
    ``(value, sigma)``, sigma None when the method gives none), ``warnings`` (tuple of str, in
    words) and ``diagnosis`` (the residual diagnosis, or None when not run).
    """

    calibration_kind: ClassVar[str]

    @abc.abstractmethod
    def to_json(self) -> dict:
        """The calibration file (SPEC section 2), JSON-ready; starts with :func:`compass.calibration.header`."""

    @abc.abstractmethod
    def report(self) -> str:
        """A fit report for a person: values +- sigma, warnings and the diagnosis in words."""

    def plots(self, recording, folder) -> list[Path]:
        """Write the kind's report plots into ``folder``; returns their paths (none by default)."""
        return []


class Calibrator(abc.ABC):
    """Base of every kind's calibrator: options in ``__init__`` (keyword-only), ``fit(recording)``.

    Attributes
    ----------
    kind : str
        The calibration kind (the file's ``"model"``).
    plot_files : tuple of str
        The files its results' ``plots()`` write into ``compass calibrate --report DIR`` (none: the
        kind draws no report); the command refuses to overwrite them without ``--force``.
    """

    kind: ClassVar[str]
    plot_files: ClassVar[tuple[str, ...]] = ()

    @abc.abstractmethod
    def fit(self, recording) -> Calibration:
        """Calibrate one recording.

        Raises
        ------
        CannotCalibrate
            The recording cannot determine a usable calibration (the reason in words).
        """

    @classmethod
    def options(cls) -> tuple[str, ...]:
        """Names of the constructor's options (what the command line may pass)."""
        return tuple(p.name for p in inspect.signature(cls.__init__).parameters.values()
                     if p.kind is inspect.Parameter.KEYWORD_ONLY)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={getattr(self, k)!r}' for k in self.options())})"


MIN_EXPLAINED = 0.5
"""Smallest fraction of a channel's output variance its fitted response must explain."""


def require_response(path, columns, outputs, residuals, rows=None) -> None:
    """Refuse a fit in which some channel does not follow the field.

    A channel whose fitted response explains less than :data:`MIN_EXPLAINED` of its output's
    variance (a channel not connected, cells far off, a sensor that saturated) gives an absurd
    gain (4.5e6 for one 1e9 cell); such a fit is refused rather than written.  Run after
    :func:`require_sane_cells`.

    Parameters
    ----------
    path : str
        The recording, for the message.
    columns : sequence of str
        Column names of the channels.
    outputs, residuals : ndarray, shape (n, c)
        Recorded outputs and the fit's residuals (output units).
    rows : ndarray of int, shape (n,), optional
        File line of each row, to name the row of the largest residual.

    Raises
    ------
    CannotCalibrate
        Naming the file and the column.
    """
    import numpy as np

    outputs, residuals = np.asarray(outputs, float), np.asarray(residuals, float)
    with np.errstate(all="ignore"):
        for c, name in enumerate(columns):
            v, r = outputs[:, c], residuals[:, c]
            total, left = np.var(v), np.mean(r**2)
            if np.isfinite(total) and np.isfinite(left) and left <= (1.0 - MIN_EXPLAINED) * total:
                continue
            worst = int(np.nanargmax(np.where(np.isfinite(r), np.abs(r), np.inf)))
            where = f"row {int(rows[worst])}" if rows is not None else f"sample {worst + 1}"
            explained = 1.0 - left / total if np.isfinite(left / total) else 0.0
            raise CannotCalibrate(f"{path}: column '{name}' does not follow the field: the fit explains "
                                  f"{100 * max(explained, 0.0):.0f} % of its variance (largest misfit at {where}, "
                                  f"value {v[worst]:g}); a cell far off or a channel not connected would give an "
                                  "absurd gain")


def metadata_field_ut(path, metadata: dict) -> float | None:
    """The recording's ``# field_ut:`` metadata (|B| in uT), or None when absent.

    Raises
    ------
    CannotCalibrate
        Present but not a positive finite number (``fifty``, ``nan``, ``-50``).
    """
    import math

    text = metadata.get("field_ut")
    if text is None:
        return None
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise CannotCalibrate(f"{path}: metadata 'field_ut' must be a positive number (|B| in uT), got {text!r}")
    return value


FAR_OFF = 100.0
"""A cell farther than this many times its column's spread (MAD about the median) is far off."""


def require_sane_cells(path, columns, outputs, rows=None) -> None:
    """Refuse a recording with a constant column or a cell far off its column, before fitting it.

    A constant channel has no gain to fit (it gave 1.9e-17); one cell of 1e9 among outputs of tens makes a least-squares fit meaningless (or its
    residuals overflow); the message names the row and the column.

    Raises
    ------
    CannotCalibrate
    """
    import numpy as np

    outputs = np.asarray(outputs, float)
    for c, name in enumerate(columns):
        if np.ptp(outputs[:, c]) == 0:
            raise CannotCalibrate(f"{path}: column '{name}' is constant ({outputs[0, c]:g}): the channel does not "
                                  "respond to the field, so it has no gain to calibrate")
    with np.errstate(all="ignore"):
        centre = np.median(outputs, axis=0)
        spread = np.median(np.abs(outputs - centre), axis=0)
        far = np.abs(outputs - centre) > FAR_OFF * np.maximum(spread, np.finfo(float).tiny) + 1e-300
    if np.any(far):
        i, c = np.argwhere(far)[0]
        where = f"row {int(rows[i])}" if rows is not None else f"sample {i + 1}"
        raise CannotCalibrate(f"{path}: {where}, column '{columns[c]}': {outputs[i, c]:g} is far off the column's "
                              f"other values (median {centre[c]:.4g}, spread {spread[c]:.3g}): a cell that is not a "
                              "reading would set the fit")
