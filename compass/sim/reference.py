"""Simulated reference-field sessions for a magnetic sensor array (seed 003) with known truth.

Each sensor ``s`` reads ``v = G_s b + v0_s + n`` for a known field ``b`` in the array frame:
row ``c`` of ``G_s = K_s^-1`` is the axis' scale factor times its direction cosines
``(cos alpha_c1, cos alpha_c2, cos alpha_c3)`` in the array frame (unit norm: the seed's
constraint).  The axes are tipped from the array's axes by about ``nonorthogonality_deg`` each
and the sensor as a whole is turned by about ``misalign_deg``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ._files import csv_text, write_with_truth

__all__ = ["FIELD_SETS", "SimulatedArray", "simulate_reference", "write_reference"]

FIELD_SETS = ("random", "coplanar")
"""``random``: directions uniform on the sphere; ``coplanar``: all in one plane (degenerate)."""


@dataclass(frozen=True)
class SimulatedArray:
    """A simulated session and its truth.

    Attributes
    ----------
    reference : ndarray, shape (n, 3)
        Applied fields, array frame, uT.
    outputs : dict of str to ndarray, shape (n, 3)
        Each sensor's outputs.
    truth : dict
        JSON-ready, per sensor: ``G`` (= K^-1, output units per uT), ``offset``; and ``noise``.
    """

    reference: np.ndarray
    outputs: dict
    truth: dict


def simulate_reference(*, seed: int = 0, n_sensors: int = 2, n_fields: int = 12, field_ut: float = 50.0,
                       fields: str = "random", gain: float = 1.0, nonorthogonality_deg: float = 1.0,
                       misalign_deg: float = 3.0, noise: float = 0.05) -> SimulatedArray:
    """Simulate reference fields applied to an array.

    Parameters
    ----------
    seed : int
    n_sensors : int
        Three-axis sensors ``s1, s2, ...``.
    n_fields : int
        Reference fields applied.
    field_ut : float
        Field magnitude, uT (each within +-30 % of it).
    fields : {"random", "coplanar"}
    gain : float
        Nominal scale factor, output units per uT (each axis within +-5 %).
    nonorthogonality_deg, misalign_deg : float
    noise : float
        White output noise, output units.

    Returns
    -------
    SimulatedArray
    """
    if fields not in FIELD_SETS:
        raise ValueError(f"fields must be one of {FIELD_SETS}, got {fields!r}")
    rng = np.random.default_rng(seed)
    truth, outputs = {"noise": noise, "sensors": {}}, {}
    sensors = []
    for s in range(n_sensors):
        axes = np.eye(3) + rng.normal(scale=np.radians(nonorthogonality_deg), size=(3, 3))
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        rot = Rotation.from_rotvec(np.radians(misalign_deg) * rng.normal(size=3) / np.sqrt(3))
        g = gain * rng.uniform(0.95, 1.05, 3)[:, None] * (axes @ rot.as_matrix().T)
        sensors.append((f"s{s + 1}", g, gain * rng.uniform(-5.0, 5.0, 3)))
    directions = rng.normal(size=(n_fields, 3))
    if fields == "coplanar":
        directions[:, 2] = 0.0
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    reference = directions * field_ut * rng.uniform(0.7, 1.3, (n_fields, 1))
    for name, g, v0 in sensors:
        outputs[name] = reference @ g.T + v0 + rng.normal(scale=noise, size=(n_fields, 3))
        truth["sensors"][name] = {"G": g.tolist(), "offset": v0.tolist()}
    return SimulatedArray(reference, outputs, truth)


def write_reference(sim: SimulatedArray, path, *, force: bool = False) -> tuple[Path, Path]:
    """Write the recording CSV and its truth side file ``<stem>.truth.json``.

    Raises
    ------
    FileExistsError
        If either file exists and ``force`` is False.
    """
    names = list(sim.outputs)
    header = ["bx_ref", "by_ref", "bz_ref"] + [f"{s}_{a}" for s in names for a in "xyz"]
    data = np.column_stack([sim.reference] + [sim.outputs[s] for s in names])
    text = csv_text(header, data, "%.6f", {"source": "compass simulate reference"})
    return write_with_truth(path, text, sim.truth, force=force)
