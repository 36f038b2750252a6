"""A bench-calibrated module built into a product and used at another site (SPEC section 2).

The sensor is the one behind a four-flip truth (:func:`compass.sim.fourflip.simulate_fourflip`'s
``truth``).  The product adds its own iron, fixed to the housing, and may hold the housing turned
by a yaw angle:

.. math::

    B_{meas,H} = S\\, R_{wh}^T B_W + h, \\qquad v_c = V_{0c} + K_c\\, (a_c \\cdot B_{meas,H}) + n_c,
    \\qquad R_{wh} = R_{w \\leftarrow p}\\, A

with ``S`` the soft iron (a few % from the identity), ``h`` the hard iron (uT, housing frame H),
``A = R_product<-housing`` the alignment and ``R_{w<-p}`` the product's attitude (SPEC section 1's
heading, pitch, roll of the product's forward axis).  The module's accelerometer rides in H.

Kinds of recording: ``tumble`` (every orientation), ``swing`` (heading through 360 degrees, level
or within ``max_tilt_deg``; optional ``heading_ref_deg`` with its noise) and ``runtime`` (random
attitudes within ``max_tilt_deg``, for checking a calibration).  The truth goes beside the
recording in ``<stem>.truth.json``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import heading_pitch_roll, r_world_from_housing, world_field
from ..model import SensorModel
from ..response import LinearResponse
from ._files import csv_text, write_with_truth

__all__ = ["Installation", "InstalledRecording", "random_installation", "true_model", "simulate_installation",
           "write_installation"]

KINDS = ("tumble", "swing", "runtime")


@dataclass(frozen=True)
class Installation:
    """The product's iron and the housing's place in it.

    Attributes
    ----------
    hard_iron_ut : ndarray, shape (3,)
        Field of magnetised parts fixed to the product, in H, microtesla.
    soft_iron : ndarray, shape (3, 3)
        In H: the field the sensor sees is ``soft_iron @ B_H + hard_iron_ut``.
    yaw_deg : float
        The housing turned in the product about the product's up axis, degrees:
        ``R_product<-housing = Rz(yaw)`` (counterclockwise seen from above).
    """

    hard_iron_ut: np.ndarray
    soft_iron: np.ndarray
    yaw_deg: float = 0.0

    @property
    def alignment(self) -> Rotation:
        """``R_product<-housing``."""
        return Rotation.from_euler("z", self.yaw_deg, degrees=True)

    def to_json(self) -> dict:
        return {"hard_iron_ut": np.asarray(self.hard_iron_ut).tolist(), "soft_iron": np.asarray(self.soft_iron).tolist(),
                "yaw_deg": self.yaw_deg, "alignment": self.alignment.as_matrix().tolist()}


def random_installation(seed: int = 0, *, hard_iron_ut: float = 6.0, soft_iron: float = 0.03,
                        yaw_deg: float = 0.0) -> Installation:
    """A product's iron: hard iron of about ``hard_iron_ut`` (random direction, magnitude within
    +-30 %), symmetric soft iron with entries of about ``soft_iron`` off the identity, and the yaw."""
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=3)
    hard = hard_iron_ut * rng.uniform(0.7, 1.3) * direction / np.linalg.norm(direction)
    d = rng.normal(scale=soft_iron, size=(3, 3))
    return Installation(hard, np.eye(3) + (d + d.T) / 2.0, float(yaw_deg))


def true_model(truth: dict) -> SensorModel:
    """The simulated bench sensor as a calibration would give it with no error (linear channels, per uT)."""
    field = truth["field_ut"]
    responses = tuple(LinearResponse(o, g, (-2 * field, 2 * field)) for o, g in zip(truth["offsets"], truth["gains_per_ut"]))
    return SensorModel(tuple(truth["channels"]), np.array(truth["directions"]), responses, field, field,
                       truth["dip_deg"], np.array(truth["noise"]))


@dataclass(frozen=True)
class InstalledRecording:
    """A simulated recording of the installed module.

    Attributes
    ----------
    kind : {"tumble", "swing", "runtime"}
    t_s : ndarray, shape (n,)
    channels : tuple of str
    outputs : ndarray, shape (n, c)
        Channel outputs (the bench sensor's output units).
    accel : ndarray, shape (n, 3)
        The module's accelerometer in H, units of g.
    heading_deg, pitch_deg, roll_deg : ndarray, shape (n,)
        The product's true attitude (magnetic north).
    heading_ref_deg : ndarray, shape (n,), or None
        The known heading written to the recording (true heading plus its noise), when asked for.
    truth : dict
        Installation, site field and the noise of the reference, JSON-ready.
    """

    kind: str
    t_s: np.ndarray
    channels: tuple[str, ...]
    outputs: np.ndarray
    accel: np.ndarray
    heading_deg: np.ndarray
    pitch_deg: np.ndarray
    roll_deg: np.ndarray
    heading_ref_deg: np.ndarray | None
    truth: dict


def simulate_installation(truth: dict, installation: Installation, *, kind: str = "tumble", n: int = 2000,
                          dip_deg: float | None = None, field_ut: float | None = None, max_tilt_deg: float = 10.0,
                          heading_ref_sigma_deg: float | None = None, accel_noise_g: float = 0.002,
                          seed: int = 0, rate_hz: float = 50.0) -> InstalledRecording:
    """Simulate the installed module.

    Parameters
    ----------
    truth : dict
        A four-flip truth (the bench sensor).
    installation : Installation
    kind : {"tumble", "swing", "runtime"}
        ``tumble``: uniformly random orientations; ``swing``: heading in two full turns (ordered,
        the product swung round), pitch and roll within ``max_tilt_deg`` (0: level); ``runtime``:
        heading random, pitch and roll uniform within ``max_tilt_deg``.
    n : int
        Samples.
    dip_deg, field_ut : float, optional
        The site's field; default the bench's (the truth's).
    max_tilt_deg : float
        Swing and runtime: largest pitch and roll, degrees.
    heading_ref_sigma_deg : float, optional
        Write ``heading_ref_deg`` (the product's true heading plus white noise of this sigma).
    accel_noise_g : float
        Accelerometer white noise per axis, g.
    seed : int
    rate_hz : float
        Sample rate for ``t_s``.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    rng = np.random.default_rng(seed)
    if kind == "tumble":
        product = Rotation.random(n, random_state=rng)
        heading, pitch, roll = heading_pitch_roll(product)
    else:
        if kind == "swing":
            heading = np.mod(rng.uniform(0, 360) + np.linspace(0.0, 720.0, n, endpoint=False), 360.0)
            phase = rng.uniform(0, 2 * np.pi, 2)
            turn = np.linspace(0.0, 2 * np.pi * 7.3, n)  # tilts that do not repeat with the heading
            pitch = max_tilt_deg * np.sin(turn + phase[0])
            roll = max_tilt_deg * np.sin(1.37 * turn + phase[1])
        else:
            heading = rng.uniform(0.0, 360.0, n)
            pitch, roll = rng.uniform(-max_tilt_deg, max_tilt_deg, (2, n))
        product = r_world_from_housing(heading, pitch, roll)
    housing = product * installation.alignment
    dip = truth["dip_deg"] if dip_deg is None else dip_deg
    field = truth["field_ut"] if field_ut is None else field_ut
    b_h = housing.apply(world_field(dip, field), inverse=True)
    b_seen = b_h @ np.asarray(installation.soft_iron).T + installation.hard_iron_ut
    x = b_seen @ np.asarray(truth["directions"]).T
    gains = np.asarray(truth["gains_per_ut"])
    outputs = np.asarray(truth["offsets"]) + gains * (x + truth["noise_ut"] * rng.normal(size=x.shape))
    accel = housing.apply([0.0, 0.0, 1.0], inverse=True) + accel_noise_g * rng.normal(size=(n, 3))
    reference = None
    if heading_ref_sigma_deg is not None:
        reference = np.mod(heading + heading_ref_sigma_deg * rng.normal(size=n), 360.0)
    info = {"kind": kind, "installation": installation.to_json(), "dip_deg": dip, "field_ut": field,
            "max_tilt_deg": max_tilt_deg if kind != "tumble" else None, "heading_ref_sigma_deg": heading_ref_sigma_deg,
            "accel_noise_g": accel_noise_g, "seed": seed}
    return InstalledRecording(kind, np.arange(n) / rate_hz, tuple(truth["channels"]), outputs, accel,
                              np.mod(heading, 360.0), pitch, roll, reference, info)


def write_installation(rec: InstalledRecording, path, *, base=None, force: bool = False):
    """Write SPEC's installation recording (``t_s``, channels, ``ax,ay,az``, optional ``heading_ref_deg``)
    and ``<stem>.truth.json`` (installation, site field, the product's attitude per row); ``base``
    (a path relative to the recording) goes into its ``# base:`` metadata."""
    columns = ["t_s", *rec.channels, "ax", "ay", "az"]
    data = [rec.t_s[:, None], rec.outputs, rec.accel]
    formats = ["%.4f"] + ["%.7f"] * (len(rec.channels) + 3)
    if rec.heading_ref_deg is not None:
        columns.append("heading_ref_deg")
        data.append(rec.heading_ref_deg[:, None])
        formats.append("%.4f")
    metadata = {"kind": rec.kind, "source": f"compass.sim.installation ({rec.kind}, seed {rec.truth['seed']})"}
    if base is not None:
        metadata["base"] = str(base)
    text = csv_text(columns, np.hstack(data), formats, metadata)
    truth = rec.truth | {"heading_deg": rec.heading_deg.tolist(), "pitch_deg": np.asarray(rec.pitch_deg).tolist(),
                         "roll_deg": np.asarray(rec.roll_deg).tolist()}
    return write_with_truth(path, text, truth, force=force)
