"""The calibration contract every kind follows (scikit-learn's estimators, lmfit's one result type).

- A :class:`Calibrator` per kind takes its options as keyword-only constructor arguments (no
  computation there) and fits with ``fit(recording) -> CalibrationResult``.
- A :class:`CalibrationResult` (the kind's frozen result: ``FourFlipResult``, ``TumbleResult``,
  ``Platform3DResult``, ``ReferenceResult``, ``InstallationResult``) has ``calibration_kind`` (the
  file's ``"model"``), ``parameters`` (name -> (value, sigma or None)), ``statistics`` (the fit's
  :class:`FitStatistics`: names, values, covariance, chi2, dof, bic, success, message, as lmfit's
  ``MinimizerResult``), ``warnings`` (tuple of str), ``diagnosis`` (the residual diagnosis, SPEC
  section 4; its file block is ``to_json()["diagnosis"]``), ``report()`` (built by
  :func:`fit_report`, as lmfit's ``fit_report``), ``plots(recording, folder)`` and ``to_json()``
  (the calibration file, written by :func:`compass.calibration.save`).
- :class:`CannotCalibrate` says, in words, why a recording cannot be calibrated (exit 2 on the
  command line).

:mod:`calibrate.kinds` maps every kind to its column sniffer, recording reader and calibrator.
"""

from __future__ import annotations

import abc
import inspect
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Sequence

import numpy as np

__all__ = ["CalibrationResult", "Calibrator", "CannotCalibrate", "FitStatistics", "NO_JOINT_FIT", "fit_report"]

STRONG_CORRELATION = 0.9
"""Parameter pairs correlated beyond this are named in every report."""


class CannotCalibrate(ValueError):
    """This recording cannot be calibrated: the message says why in words and names the file.

    Raised for bad input (poses that leave parameters undetermined, too few or coplanar fields,
    no determined ellipsoid, a field that changed partway, a channel that does not follow the
    field); the command line reports it with exit status 2.
    """


@dataclass(frozen=True)
class FitStatistics:
    """What every kind's fit declares about itself (lmfit's ``MinimizerResult``).

    Attributes
    ----------
    names : tuple of str
        The fitted parameters, in the fit's own coordinates (each kind's docstring names their units).
    values : ndarray, shape (p,)
    covariance : ndarray, shape (p, p)
        Of ``values`` (inf where singular).
    chi2 : float
        Sum of the squared residuals over their noise floor (NaN when the kind has no floor).
    dof : int
        Residuals minus parameters.
    bic : float
        ``chi2 + p ln n`` with the noise floor known (NaN with ``chi2``).
    success : bool
        The minimiser converged.
    message : str
        The minimiser's own words.
    """

    names: tuple
    values: np.ndarray
    covariance: np.ndarray
    chi2: float
    dof: int
    bic: float
    success: bool
    message: str

    @property
    def sigma(self) -> np.ndarray:
        """Standard errors of :attr:`values`."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / max(self.dof, 1)

    def correlations(self, threshold: float = STRONG_CORRELATION) -> list[tuple[str, str, float]]:
        """``(name_i, name_j, r)`` of the pairs correlated beyond ``threshold`` (finite covariances only)."""
        sig = self.sigma
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = self.covariance / np.outer(sig, sig)
        return [(self.names[i], self.names[j], float(corr[i, j])) for i in range(len(sig)) for j in range(i)
                if np.isfinite(corr[i, j]) and abs(corr[i, j]) > threshold]


NO_JOINT_FIT = FitStatistics((), np.zeros(0), np.zeros((0, 0)), float("nan"), 0, float("nan"), True,
                             "a rule, not a fit: no joint statistics")
"""The statistics of a result no least-squares fit made (the four-flip's seed rules)."""


class CalibrationResult(abc.ABC):
    """Base of every kind's result.

    Besides the methods below, a result has the attributes ``parameters`` (dict name ->
    ``(value, sigma)``, sigma None when the method gives none), ``statistics`` (:class:`FitStatistics`),
    ``warnings`` (tuple of str, in words) and ``diagnosis`` (the residual diagnosis, or None when not run).
    """

    calibration_kind: ClassVar[str]
    statistics: FitStatistics

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
    def fit(self, recording) -> CalibrationResult:
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


def fit_report(result: CalibrationResult, head: Sequence[str], *, warnings: Sequence[str] | None = None,
               diagnosis: str | None = None, tail: Sequence[str] = ()) -> str:
    """A result's report for a person: the kind's own lines, then the shared parts, in one order.

    Parameters
    ----------
    result : CalibrationResult
    head : sequence of str
        The kind's title line and its values with +- sigma.
    warnings : sequence of str, optional
        The warnings to print (default ``result.warnings``; a kind that lists some in ``head`` leaves them out).
    diagnosis : str, optional
        The diagnosis in words (:func:`calibrate.diagnosis.report.format_diagnosis`), or why it did not run.
    tail : sequence of str
        The kind's sections after the diagnosis (the four-flip's accelerometer and site check).

    Returns
    -------
    str
        ``head``; the fit's chi2/dof, BIC and convergence (when it has residuals to count) and the
        parameter pairs correlated beyond :data:`STRONG_CORRELATION`; every warning; the diagnosis;
        ``tail``.
    """
    stats = result.statistics
    lines = list(head)
    if stats.dof > 0 and np.isfinite(stats.chi2):
        converged = "" if stats.success else f"; not converged: {stats.message}"
        lines.append(f"  chi2/dof {stats.reduced_chi2:.3f} ({stats.dof} dof), BIC {stats.bic:.1f}{converged}")
    strong = stats.correlations()
    if strong:
        lines.append(f"  correlations above {STRONG_CORRELATION:g}: "
                     + "; ".join(f"{a}/{b} {c:+.2f}" for a, b, c in strong))
    lines += [f"  warning: {w}" for w in (result.warnings if warnings is None else warnings)]
    if diagnosis:
        lines.append(diagnosis)
    lines += tail
    return "\n".join(lines)


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
