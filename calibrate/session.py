"""One recording to one calibration: the path ``compass calibrate`` and ``compass batch`` share.

:func:`find_kind` picks the kind (the registry's sniffer, or a named kind), :func:`fit_recording`
reads the recording into that kind's form, fits it and validates the file text.  Both refuse
with :class:`~calibrate.contract.CannotCalibrate` (in words, naming the file); the command line
turns it into exit status 2, the batch into a failed module.
"""

from __future__ import annotations

__all__ = ["find_kind", "fit_recording"]


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


def fit_recording(found, table, path, options: dict):
    """Read ``table`` as a ``found`` recording and calibrate it.

    Parameters
    ----------
    found : calibrate.kinds.Kind
    table : compass.io.table.Table
    path : str
        The recording, for messages.
    options : dict
        Constructor options of the kind's calibrator (only names it takes).

    Returns
    -------
    recording, result, text
        The kind's recording, its :class:`~calibrate.contract.Calibration` and the calibration
        file's text (validated as the runtime reads it).

    Raises
    ------
    RecordingError
        The table is not a valid recording of this kind.
    CannotCalibrate
        The recording cannot determine a usable calibration.
    """
    from compass.calibration_file import CalibrationFileError, dumps

    from .contract import CannotCalibrate

    rec = found.read(table)
    result = found.calibrator(**options).fit(rec)
    try:
        text = dumps(result.to_json())
    except CalibrationFileError as exc:  # never write a calibration the runtime would refuse
        raise CannotCalibrate(f"{path}: the fit gives an unusable calibration, not written: {exc}") from None
    return rec, result, text
