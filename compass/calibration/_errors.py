"""The one error of a calibration file the runtime cannot use (exit status 2 on the command line)."""

from __future__ import annotations

__all__ = ["CalibrationFileError", "NoFieldVector"]


class CalibrationFileError(ValueError):
    """A calibration file (or document) the runtime cannot use: the message names the file and the key.

    Attributes
    ----------
    path : str or None
        The file, when read from one.
    key : str or None
        Dotted path of the offending key (``channels.mx.response.gain``); given as a tuple
        ``("channels", name, "response.gain")`` for a channel's key (names may hold dots).
    reason : str
        What is wrong, in words.
    """

    def __init__(self, reason: str, *, key: str | tuple | None = None, path=None):
        self.reason, self.path, self._key = reason, None if path is None else str(path), key
        self.key = ".".join(key) if isinstance(key, tuple) else key
        if isinstance(key, tuple):  # ("channels", name, sub): "channel 'mx': 'response.gain' must be ..."
            where = f"channel '{key[1]}': '{key[2]}' " if len(key) > 2 else f"channel '{key[1]}' "
        else:
            where = f"'{key}' " if key else ""
        super().__init__((f"{self.path}: " if self.path else "") + where + reason)

    def in_file(self, path) -> "CalibrationFileError":
        """The same error naming ``path``."""
        return type(self)(self.reason, key=self._key, path=path)

    def under(self, prefix: str) -> "CalibrationFileError":
        """The same error for a document nested under ``prefix`` (an installed file's ``base``)."""
        return type(self)(self.reason, key=f"{prefix}.{self.key}" if self.key else prefix)


class NoFieldVector(CalibrationFileError):
    """A valid calibration of channels that cannot give a field vector (fewer than three, or
    coplanar: :class:`compass.model.NotAFieldVector`): written by the calibration, refused on
    reading by everything that solves the field."""
