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
from ._slow import TEMP_REF_C, chamber_temperature, check_session, drift_profile, session_clock

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
        JSON-ready, per sensor: ``G`` (= K^-1, output units per uT), ``offset`` (at ``t_s = 0`` and
        25 degC), ``drift_change`` and ``temp_offset_per_degc`` (output units; None when not
        simulated); and ``noise``, ``drift`` (``tau_s``, ``form``), ``temp_ref_c``.
    t_s : ndarray, shape (n,), or None
        Time of every row, s (with ``session_s``).
    temp_c : ndarray, shape (n,), or None
        Array temperature as recorded (0.01 degC steps), with ``temp_swing_c``.
    """

    reference: np.ndarray
    outputs: dict
    truth: dict
    t_s: np.ndarray | None = None
    temp_c: np.ndarray | None = None


def simulate_reference(*, seed: int = 0, n_sensors: int = 2, n_fields: int = 12, field_ut: float = 50.0,
                       fields: str = "random", gain: float = 1.0, nonorthogonality_deg: float = 1.0,
                       misalign_deg: float = 3.0, noise: float = 0.05, repeats: int = 1,
                       session_s: float | None = None, drift: float = 0.0, drift_tau_s: float | None = None,
                       temp_swing_c: float = 0.0, temp_offset_per_c: float = 0.0) -> SimulatedArray:
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
    repeats : int
        Rows per applied field, one after the other (their scatter measures the noise).
    session_s : float, optional
        Length of the session, s: the rows get a ``t_s`` column, evenly spaced over it.
    drift : float
        Size of each sensor's offset drift (random direction), output units: the change over the
        session when ``drift_tau_s`` is None (constant rate), else the settled change of a warm-up
        ``1 - exp(-t / drift_tau_s)``.  Needs ``session_s``.
    drift_tau_s : float, optional
    temp_swing_c : float
        Amplitude of a temperature cycle, degC, recorded as ``temp_c``: ``25 + swing sin(4 pi i / (n - 1))``
        over the rows (two cycles, so temperature is not a function of time).
    temp_offset_per_c : float
        Size of each sensor's offset temperature coefficient (random direction), output units per degC.

    Returns
    -------
    SimulatedArray
    """
    if fields not in FIELD_SETS:
        raise ValueError(f"fields must be one of {FIELD_SETS}, got {fields!r}")
    if repeats < 1:
        raise ValueError(f"repeats must be at least 1, got {repeats}")
    check_session(session_s, drift, "drift")
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
    reference = np.repeat(directions * field_ut * rng.uniform(0.7, 1.3, (n_fields, 1)), repeats, axis=0)
    n = len(reference)
    # effects beyond the linear model draw from their own generator: the plain session of a seed stays as it was
    extra = np.random.default_rng([seed, 1])
    t_s = session_clock(n, session_s)
    temp_true = chamber_temperature(n, temp_swing_c)
    profile = None
    if drift:
        profile, form = drift_profile(t_s, session_s, drift_tau_s)
        truth["drift"] = {"tau_s": drift_tau_s, "form": form}
    if temp_swing_c:
        truth["temp_ref_c"] = TEMP_REF_C
    for name, g, v0 in sensors:
        outputs[name] = reference @ g.T + v0 + rng.normal(scale=noise, size=(n, 3))
        truth["sensors"][name] = {"G": g.tolist(), "offset": v0.tolist(), "drift_change": None,
                                  "temp_offset_per_degc": None}
        if drift:
            change = extra.normal(size=3)
            change *= drift / np.linalg.norm(change)
            outputs[name] = outputs[name] + np.outer(profile, change)
            truth["sensors"][name]["drift_change"] = change.tolist()
        if temp_swing_c:
            k = extra.normal(size=3)
            k *= temp_offset_per_c / np.linalg.norm(k)
            outputs[name] = outputs[name] + np.outer(temp_true - TEMP_REF_C, k)
            truth["sensors"][name]["temp_offset_per_degc"] = k.tolist()
    temp_c = np.round(temp_true, 2) if temp_swing_c else None
    return SimulatedArray(reference, outputs, truth, t_s, temp_c)


def write_reference(sim: SimulatedArray, path, *, force: bool = False) -> tuple[Path, Path]:
    """Write the recording CSV and its truth side file ``<stem>.truth.json``.

    Raises
    ------
    FileExistsError
        If either file exists and ``force`` is False.
    """
    names = list(sim.outputs)
    header = ["bx_ref", "by_ref", "bz_ref"] + [f"{s}_{a}" for s in names for a in "xyz"]
    extra = [(name, v) for name, v in (("t_s", sim.t_s), ("temp_c", sim.temp_c)) if v is not None]
    header += [name for name, _ in extra]
    data = np.column_stack([sim.reference] + [sim.outputs[s] for s in names] + [v for _, v in extra])
    text = csv_text(header, data, "%.6f", {"source": "compass simulate reference"})
    return write_with_truth(path, text, sim.truth, force=force)
