"""Runtime recordings: a calibrated sensor moved through random attitudes, with the truth.

The sensor is the one behind a four-flip truth (:func:`compass.sim.fourflip.simulate_fourflip`'s
``truth``): its directions, offsets and gains per microtesla, and its saturation when the truth
has ``nonlinear_response``.  An accelerometer reads gravity (+1 g up, in units of g) with white
noise: aligned with the housing, or, when the truth has an ``accelerometer`` entry (the bench's
accelerometer, :class:`compass.sim.fourflip.SimAccelerometer`), with its misalignment, scales and offsets.  Written as SPEC section 2's attitude recording, with the true
angles beside it in ``<stem>.truth.json``, as every simulator's truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..frames import r_world_from_housing, world_field
from ._files import csv_text, write_with_truth

__all__ = ["RuntimeSession", "simulate_runtime", "write_runtime"]


@dataclass(frozen=True)
class RuntimeSession:
    """A simulated attitude recording.

    Attributes
    ----------
    t_s : ndarray, shape (n,)
    channels : tuple of str
    outputs : ndarray, shape (n, c)
        Channel outputs, output units (volts).
    accel : ndarray, shape (n, 3) or None
        Accelerometer in H, units of g.
    heading_deg, pitch_deg, roll_deg : ndarray, shape (n,)
        True attitude (SPEC section 1).
    field_h : ndarray, shape (n, 3)
        True field in H, microtesla (Earth field plus any disturbance).
    """

    t_s: np.ndarray
    channels: tuple[str, ...]
    outputs: np.ndarray
    accel: np.ndarray | None
    heading_deg: np.ndarray
    pitch_deg: np.ndarray
    roll_deg: np.ndarray
    field_h: np.ndarray


def simulate_runtime(
    truth: dict,
    n: int,
    *,
    seed: int = 0,
    max_tilt_deg: float = 80.0,
    noise_ut: float | None = None,
    accel_noise_g: float | None = 0.002,
    extra_field_ut=None,
    rate_hz: float = 100.0,
) -> RuntimeSession:
    """Simulate ``n`` samples at random attitudes.

    Parameters
    ----------
    truth : dict
        A four-flip truth: ``directions``, ``offsets``, ``gains_per_ut``, ``dip_deg``, ``field_ut``,
        ``channels``, ``noise_ut`` and ``effects``.
    n : int
        Number of samples.
    seed : int
        Seeds the attitudes and the noise.
    max_tilt_deg : float
        Pitch and roll are uniform in [-max_tilt_deg, max_tilt_deg]; heading uniform in [0, 360).
    noise_ut : float, optional
        Channel white noise in microtesla; default the truth's ``noise_ut`` (the bench's).
    accel_noise_g : float or None
        Accelerometer noise per axis, g; None records no accelerometer.
    extra_field_ut : array_like, shape (3,) or (n, 3), optional
        A disturbance added to the Earth field, NWU world frame, microtesla.
    rate_hz : float
        Sample rate for ``t_s``.
    """
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    if not 0 <= max_tilt_deg <= 90:
        raise ValueError(f"max_tilt_deg must be in [0, 90], got {max_tilt_deg}")
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0.0, 360.0, n)
    pitch = rng.uniform(-max_tilt_deg, max_tilt_deg, n)
    roll = rng.uniform(-max_tilt_deg, max_tilt_deg, n)
    rot = r_world_from_housing(heading, pitch, roll)
    field_w = world_field(truth["dip_deg"], truth["field_ut"]) + np.zeros((n, 3))
    if extra_field_ut is not None:
        field_w = field_w + np.asarray(extra_field_ut, dtype=float)
    field_h = rot.apply(field_w, inverse=True)
    directions = np.asarray(truth["directions"], dtype=float)
    gains = np.asarray(truth["gains_per_ut"], dtype=float)
    x = np.einsum("ni,ci->nc", field_h, directions)
    for effect in truth.get("effects", ()):
        if effect["name"] == "nonlinear_response":
            saturation = np.asarray(effect["parameters"]["tanh_saturation_ut"], dtype=float)
            x = saturation * np.tanh(x / saturation)
    noise = truth["noise_ut"] if noise_ut is None else noise_ut
    outputs = np.asarray(truth["offsets"]) + gains * (x + noise * rng.normal(size=x.shape))
    accel = None
    if accel_noise_g is not None:
        accel = rot.apply(np.array([0.0, 0.0, 1.0]), inverse=True) + accel_noise_g * rng.normal(size=(n, 3))
        for effect in truth.get("effects", ()):
            if effect["name"] == "accelerometer":  # the bench's accelerometer: misaligned with H
                p = effect["parameters"]
                accel = np.asarray(p["scale"]) * (accel @ np.asarray(p["mag_to_accel"]).T) + np.asarray(p["offset_g"])
    return RuntimeSession(np.arange(n) / rate_hz, tuple(truth["channels"]), outputs, accel, heading, pitch,
                          roll, field_h)


def write_runtime(session: RuntimeSession, path, *, force: bool = False) -> tuple[Path, Path]:
    """Write the attitude recording and its truth ``<stem>.truth.json``: ``t_s`` and the true
    ``heading_deg``, ``pitch_deg``, ``roll_deg`` per row (as ``compass simulate installation --kind runtime``'s).

    Raises
    ------
    FileExistsError
        If either file exists and ``force`` is False.
    """
    columns = ["t_s", *session.channels]
    data = [session.t_s[:, None], session.outputs]
    if session.accel is not None:
        columns += ["ax", "ay", "az"]
        data.append(session.accel)
    recording = csv_text(columns, np.hstack(data), ["%.4f"] + ["%.7f"] * (len(columns) - 1))
    truth = {"kind": "runtime", "channels": list(session.channels), "t_s": session.t_s.tolist(),
             "heading_deg": session.heading_deg.tolist(), "pitch_deg": np.asarray(session.pitch_deg).tolist(),
             "roll_deg": np.asarray(session.roll_deg).tolist()}
    return write_with_truth(path, recording, truth, force=force)

