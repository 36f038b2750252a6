"""The registry of calibration kinds: column sniffer, recording reader and calibrator of each.

``compass calibrate`` tries the kinds in registration order (SPEC section 3: ``flip_deg`` ->
four-flip, ``platform_z_deg`` -> 3-D platform, ``bx_ref`` -> reference fields, ``mx,my,mz`` ->
tumble) and fits with the first whose sniffer accepts the recording's columns.

A new kind is one :class:`~calibrate.contract.Calibrator` subclass (whose ``fit`` returns a
:class:`~calibrate.contract.CalibrationResult`) and one line here::

    register(Kind("installed", "a --base calibration", sniff=...,
                  reader="compass.io.installation:installation_from_table",
                  calibrator_name="calibrate.installation:InstallationCalibrator"))

``sniff(table) -> bool`` looks at a :class:`compass.io.table.Table`'s columns, ``read(table)``
validates it into the kind's recording, and the command line passes the calibrator the options
its constructor names (:meth:`~calibrate.contract.Calibrator.options`).  Register before the more
general kinds when your columns are a superset of theirs.

The reader and the calibrator are named, not imported: a kind's modules are imported when it is
used, so calibrating a four-flip recording imports the four-flip's modules and no other kind's.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import import_module
from typing import Any, Callable

__all__ = ["KINDS", "Kind", "register", "sniff"]


@dataclass(frozen=True)
class Kind:
    """One calibration kind.

    Attributes
    ----------
    name : str
        The kind (``--kind``, and the calibration file's ``"model"``).
    columns : str
        What identifies its recordings, in words (for the message when no kind matches).
    sniff : callable
        ``sniff(table) -> bool``: whether a table's columns are this kind's (imports nothing).
    reader : str
        ``"module:function"`` of :attr:`read`.
    calibrator_name : str
        ``"module:class"`` of :attr:`calibrator`.
    """

    name: str
    columns: str
    sniff: Callable[[Any], bool]
    reader: str
    calibrator_name: str

    @property
    def read(self) -> Callable[[Any], Any]:
        """``read(table) -> recording``: the validated recording (RecordingError for bad input)."""
        return _resolve(self.reader)

    @property
    def calibrator(self) -> type:
        """The kind's :class:`~calibrate.contract.Calibrator` subclass (its ``kind`` is :attr:`name`).

        Raises
        ------
        ValueError
            The class calibrates another kind (a wrong registry line).
        """
        calibrator = _resolve(self.calibrator_name)
        if calibrator.kind != self.name:
            raise ValueError(f"kind {self.name!r}: its calibrator {calibrator.__name__} is for {calibrator.kind!r}")
        return calibrator


def _resolve(dotted: str):
    """The object ``"module:attribute"`` names, its module imported now."""
    module, _, attribute = dotted.partition(":")
    return getattr(import_module(module), attribute)


KINDS: dict[str, Kind] = {}
"""Name -> kind, in the order the command line tries them."""


def register(kind: Kind) -> Kind:
    """Add a kind to :data:`KINDS` (its calibrator's ``kind`` must be its name: checked when it is used)."""
    KINDS[kind.name] = kind
    return kind


def sniff(table) -> Kind | None:
    """The first registered kind whose sniffer accepts ``table``'s columns, or None."""
    return next((k for k in KINDS.values() if k.sniff(table)), None)


register(Kind("installed", "a bench calibration (--base BENCH.json or '# base:' metadata) and ax,ay,az",
              lambda t: bool(t.metadata.get("base")), "compass.io.installation:installation_from_table",
              "calibrate.installation:InstallationCalibrator"))
register(Kind("fourflip", "flip_deg", lambda t: t.has("flip_deg"), "compass.io.fourflip:fourflip_from_table",
              "calibrate.fourflip:FourFlipCalibrator"))
register(Kind("platform3d", "platform_z_deg", lambda t: t.has("platform_z_deg"),
              "compass.io.platform3d:platform3d_from_table", "calibrate.platform3d:Platform3DCalibrator"))
register(Kind("reference", "bx_ref", lambda t: any(c.endswith("bx_ref") for c in t.columns),
              "compass.io.reference:reference_from_table", "calibrate.reference:ReferenceCalibrator"))
register(Kind("tumble", "mx,my,mz", lambda t: all(t.has(c) for c in ("mx", "my", "mz")),
              "compass.io.tumble:tumble_from_table", "calibrate.tumble:TumbleCalibrator"))
