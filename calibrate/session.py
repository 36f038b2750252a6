"""One recording to one calibration: the path ``compass calibrate`` and ``compass batch`` share.

:func:`find_kind` picks the kind (the registry's sniffer, or a named kind), :func:`fit_recording`
reads the recording into that kind's form and fits it (``compass calibrate`` takes its two steps
itself, to let the table go before the fit), :func:`file_text` gives the calibration
file's text, validated (``compass calibrate`` writes the same document through
:func:`compass.calibration.save`).  They refuse with :class:`~calibrate.contract.CannotCalibrate`
(in words, naming the file); the command line turns it into exit status 2, the batch into a
refused module.
"""

from __future__ import annotations

__all__ = ["file_text", "find_kind", "fit_recording"]


def find_kind(table, path, kind: str | None = None):
    """The :class:`~calibrate.kinds.Kind` of a recording: ``kind`` when named, else from its columns.

    Raises
    ------
    CannotCalibrate
        An unknown ``kind``, or columns no kind recognises.
    """
    from .contract import CannotCalibrate
    from .kinds import KINDS, sniff

    if kind is not None:
        if kind not in KINDS:
            raise CannotCalibrate(f"--kind {kind}: unknown kind; known: {', '.join(KINDS)}")
        return KINDS[kind]
    found = sniff(table)
    if found is None:
        raise CannotCalibrate(f"{path}: cannot tell the recording kind from its columns "
                              f"({', '.join(table.columns)}); " + ", ".join(f"a {k.name} recording has {k.columns}"
                                                                            for k in KINDS.values()))
    return found


def fit_recording(found, table, options: dict):
    """Read ``table`` as a ``found`` recording and calibrate it.

    Parameters
    ----------
    found : calibrate.kinds.Kind
    table : compass.io.table.Table
    options : dict
        Constructor options of the kind's calibrator (only names it takes).

    Returns
    -------
    recording, result
        The kind's recording and its :class:`~calibrate.contract.Calibration`.

    Raises
    ------
    RecordingError
        The table is not a valid recording of this kind.
    CannotCalibrate
        The recording cannot determine a calibration.
    """
    rec = found.read(table)
    return rec, found.calibrator(**options).fit(rec)


def file_text(document: dict, path) -> str:
    """The calibration file's text of a result's document (``result.to_json()``), validated as the
    runtime reads it.

    Raises
    ------
    CannotCalibrate
        The runtime would refuse the calibration (``compass calibrate`` does not write it either).
    """
    from compass.calibration import CalibrationFileError, dumps

    from .contract import CannotCalibrate

    try:
        return dumps(document)
    except CalibrationFileError as exc:
        raise CannotCalibrate(f"{path}: the fit gives an unusable calibration, not written: {exc}") from None
