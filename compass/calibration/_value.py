"""The calibration value: everything the runtime needs from a calibration file, typed, validated, frozen."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from ._imu import ImuCorrection

__all__ = ["Calibration", "Installation", "Provenance", "TumbleForm"]


@dataclass(frozen=True, eq=False)
class Provenance:
    """Where the calibration came from, as far as the runtime acts on it.

    Attributes
    ----------
    method : str or None
        The file's ``method`` (a four-flip's ``ml``, ``harmonic`` or ``patent``); None when absent.
    hemisphere_assumed : bool
        A four-flip bench (also as an installed file's base) whose hemisphere was assumed, not given:
        its data cannot tell ``(a, B)`` from ``(-a, -B)``, so a field read turned over points there.
    dip_sigma_deg : float or None
        The reported standard error of ``dip_deg``, degrees; None when the file gives none.
    warnings : tuple of str
        The calibration's warnings in words (the file's ``warnings``; an installed file's own, then its
        base's, marked ``base calibration:``); what a firmware export repeats.
    unexplained : bool or None
        The diagnosis's ``unexplained`` (an installed file's installation's, else its own); None when absent.
    """

    method: str | None = None
    hemisphere_assumed: bool = False
    dip_sigma_deg: float | None = None
    warnings: tuple[str, ...] = ()
    unexplained: bool | None = None


@dataclass(frozen=True, eq=False)
class TumbleForm:
    """A tumble calibration as written: ``m = soft_iron @ (raw - hard_iron)``, then ``mag_to_accel @ m``.

    Attributes
    ----------
    hard_iron : ndarray, shape (3,)
        Offsets, the recording's unit.
    soft_iron : ndarray, shape (3, 3)
        Symmetric positive definite.
    mag_to_accel : ndarray, shape (3, 3), or None
        ``R_accel<-mag``; folded into the sensor model.
    field_norm : float
        |B| of the fitted sphere, field units.
    field_norm_recording_units : float or None
        |B| in the recording's unit, when the file says (or when it knows no ``field_ut``).
    ellipsoid : str or None
        The fitted ellipsoid (``offset``, ``diagonal``, ``full``) when the file says.
    """

    hard_iron: np.ndarray
    soft_iron: np.ndarray
    mag_to_accel: np.ndarray | None
    field_norm: float
    field_norm_recording_units: float | None = None
    ellipsoid: str | None = None


@dataclass(frozen=True, eq=False)
class Installation:
    """An installed calibration's product iron on top of its bench calibration (SPEC section 2).

    Attributes
    ----------
    base : Calibration
        The bench calibration (housing frame H).
    hard_iron_ut : ndarray, shape (3,)
        ``h`` in H, the base model's field units.
    soft_iron : ndarray, shape (3, 3)
        ``S`` in H.
    covariance : ndarray, shape (9, 9), or None
        Of ``(h_x, h_y, h_z, d_xx, d_yy, d_zz, d_xy, d_xz, d_yz)``.
    alignment : ndarray, shape (3, 3), or None
        ``R_product<-H``: the installed model is in the product's frame.
    """

    base: "Calibration"
    hard_iron_ut: np.ndarray
    soft_iron: np.ndarray
    covariance: np.ndarray | None = None
    alignment: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Calibration:
    """A validated calibration file: what every command and the live session read.

    Built by :func:`compass.calibration.load` / :func:`compass.calibration.from_dict` only; written
    by :func:`compass.calibration.save`.  Nothing outside :mod:`compass.calibration` reads the JSON.

    Attributes
    ----------
    kind : str
        The calibration kind (the file's ``"model"``): ``fourflip``, ``platform3d``, ``reference``,
        ``channels``, ``tumble`` or ``installed``.
    model : compass.model.SensorModel
        The magnetic sensor: field in the model's frame (H, or an installed file's product frame).
    imu : ImuCorrection
        The accelerometer (and gyro) into the model's frame; does nothing when the file says nothing.
    tilt_sensor : compass.io.platform3d.TiltSensor or None
        A 3-D platform calibration's tilt sensor.
    site : compass.site.Site or None
        The file's ``site`` block.
    provenance : Provenance
    installation : Installation or None
        An installed file's product iron and its bench calibration.
    tumble : TumbleForm or None
        A tumble file's matrices as written (for firmware export).
    path : str or None
        The file it was read from.
    """

    kind: str
    model: Any
    imu: ImuCorrection = field(default_factory=ImuCorrection)
    tilt_sensor: Any = None
    site: Any = None
    provenance: Provenance = field(default_factory=Provenance)
    installation: Installation | None = None
    tumble: TumbleForm | None = None
    path: str | None = None
    document: Mapping = field(default_factory=dict, repr=False)
    """The document as read, read-only all the way down (objects as mappings, lists as tuples): for
    :func:`compass.calibration.save`, which writes every reported key as it was."""

    def __post_init__(self):
        object.__setattr__(self, "document", _frozen(self.document))


def _frozen(value):
    """A JSON value that cannot be changed: objects as read-only mappings, lists as tuples."""
    if isinstance(value, Mapping):
        return MappingProxyType({k: _frozen(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value
