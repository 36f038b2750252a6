"""The registry of calibration kinds: column sniffer, recording reader and calibrator of each.

``compass calibrate`` tries the kinds in registration order (SPEC section 3: ``flip_deg`` ->
four-flip, ``platform_z_deg`` -> 3-D platform, ``bx_ref`` -> reference fields, ``mx,my,mz`` ->
tumble) and fits with the first whose sniffer accepts the recording's columns.

A new kind is one :class:`~calibrate.contract.Calibrator` subclass (whose ``fit`` returns a
:class:`~calibrate.contract.Calibration`) and one line here::

    register(Kind("installed", "a --base calibration", sniff=..., read=..., calibrator=InstalledCalibrator))

``sniff(table) -> bool`` looks at a :class:`compass.io.table.Table`'s columns, ``read(table)``
validates it into the kind's recording, and the command line passes the calibrator the options
its constructor names (:meth:`~calibrate.contract.Calibrator.options`).  Register before the more
general kinds when your columns are a superset of theirs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from compass.io.fourflip import fourflip_from_table
from compass.io.installation import installation_from_table
from compass.io.platform3d import platform3d_from_table
from compass.io.reference import reference_from_table
from compass.io.tumble import tumble_from_table

from .contract import Calibrator
from .fourflip import FourFlipCalibrator
from .installation import InstallationCalibrator
from .platform3d import Platform3DCalibrator
from .reference import ReferenceCalibrator
from .tumble import TumbleCalibrator

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
        ``sniff(table) -> bool``: whether a table's columns are this kind's.
    read : callable
        ``read(table) -> recording``: the validated recording (RecordingError for bad input).
    calibrator : type of Calibrator
    """

    name: str
    columns: str
    sniff: Callable[[Any], bool]
    read: Callable[[Any], Any]
    calibrator: type[Calibrator]


KINDS: dict[str, Kind] = {}
"""Name -> kind, in the order the command line tries them."""


def register(kind: Kind) -> Kind:
    """Add a kind to :data:`KINDS` (its calibrator's ``kind`` must be its name)."""
    if kind.calibrator.kind != kind.name:
        raise ValueError(f"kind {kind.name!r}: its calibrator {kind.calibrator.__name__} is for {kind.calibrator.kind!r}")
    KINDS[kind.name] = kind
    return kind


def sniff(table) -> Kind | None:
    """The first registered kind whose sniffer accepts ``table``'s columns, or None."""
    return next((k for k in KINDS.values() if k.sniff(table)), None)


register(Kind("installed", "a bench calibration (--base BENCH.json or '# base:' metadata) and ax,ay,az",
              lambda t: bool(t.metadata.get("base")), installation_from_table, InstallationCalibrator))
register(Kind("fourflip", "flip_deg", lambda t: t.has("flip_deg"), fourflip_from_table, FourFlipCalibrator))
register(Kind("platform3d", "platform_z_deg", lambda t: t.has("platform_z_deg"), platform3d_from_table,
              Platform3DCalibrator))
register(Kind("reference", "bx_ref", lambda t: any(c.endswith("bx_ref") for c in t.columns), reference_from_table,
              ReferenceCalibrator))
register(Kind("tumble", "mx,my,mz", lambda t: all(t.has(c) for c in ("mx", "my", "mz")), tumble_from_table,
              TumbleCalibrator))
