"""Simulated free-motion (tumble) recordings with known hard iron, soft iron and misalignment.

The housing is turned along a smooth random path (a random walk of angular velocity), so the
samples come as a hand-held tumble does: in runs, not independently over the sphere.  The
magnetometer sees the Earth field through a symmetric soft-iron distortion, a hard-iron offset
and a small rotation relative to the accelerometer (= housing) frame; the accelerometer sees
gravity plus the path's own linear accelerations.  Disturbances are short bursts of an extra
field (a passing magnet), not independent single-sample spikes.

Effects the plain ellipsoid lacks can be switched on (for the residual diagnosis): a hard iron
that drifts with time (a linear wander, or a warm-up integrated sample by sample as a first-order
thermal lag), a temperature profile that rises and falls with a hard iron and per-axis gains that
follow it, and a hard-iron step partway (a magnetised part attached), which no effect models.

Model, with ``R_i = R_world<-housing`` (SPEC section 1, NWU world, FLU housing) and ``C`` the
rotation taking magnetometer-frame vectors into the housing frame:

.. math:: \\mathrm{raw}_i = G_i W C^T R_i^T B_W + h + d(t_i) + k (T_i - T_0) + s_i + n_i,
          \\qquad a_i = R_i^T (0, 0, g) + \\ell_i + e_i

with ``G_i = diag(1 + g (T_i - T_0))`` the temperature gains, ``d`` the drift (``d(0) = 0``), ``k``
the hard iron's temperature coefficient and ``s_i`` the step (zero before it), so the calibration
that undoes it at ``t = 0`` and ``T_0`` is ``soft_iron = W^{-1}``, ``hard_iron = h``,
``mag_to_accel = C``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import heading_pitch_roll, world_field
from ._files import csv_text, write_with_truth

__all__ = ["SimulatedTumble", "simulate_tumble", "write_tumble", "COVERAGES"]

COVERAGES = ("full", "upright")
"""``full``: every orientation; ``upright``: never tilted beyond 60 degrees (never turned over)."""


@dataclass(frozen=True)
class SimulatedTumble:
    """A simulated tumble and its truth.

    Attributes
    ----------
    t_s : ndarray, shape (n,)
    mag : ndarray, shape (n, 3)
        Raw magnetometer, microtesla-like units (the simulator's unit is uT).
    accel : ndarray, shape (n, 3)
        Accelerometer, g.
    attitude : Rotation
        ``R_world<-housing`` of every sample.
    heading_deg : ndarray, shape (n,)
        True heading of every sample.
    truth : dict
        JSON-ready: ``hard_iron`` (at ``t = 0`` and ``temp_ref_c``), ``soft_iron`` (W^{-1}, output in
        uT), ``mag_to_accel``, ``field_ut``, ``dip_deg``, ``noise_ut``, ``outlier_rows`` (0-based
        sample indices); ``drift`` (``change_ut`` over the session or to the settled value, ``tau_s``),
        ``temperature`` (``temp_ref_c``, ``hard_iron_ut_per_degc``, ``gain_rel_per_degc``) and
        ``step`` (``change_ut``, ``first_row``), each None when not simulated.
    temp_c : ndarray, shape (n,), or None
        Sensor temperature as recorded (0.01 degC steps), when a temperature swing is simulated.
    """

    t_s: np.ndarray
    mag: np.ndarray
    accel: np.ndarray
    attitude: Rotation
    heading_deg: np.ndarray
    truth: dict
    temp_c: np.ndarray | None = None


def _path(rng, n, rate_hz, coverage):
    """Smooth random attitudes: angular velocity as a damped random walk, rad/s."""
    dt = 1.0 / rate_hz
    omega = np.zeros(3)
    r = Rotation.from_euler("ZYX", [rng.uniform(0, 360), 0, 0], degrees=True)
    out = []
    for _ in range(n):
        omega = 0.98 * omega + rng.normal(scale=0.35, size=3)
        step = Rotation.from_rotvec(omega * dt)
        nxt = r * step
        if coverage == "upright":
            up = nxt.apply([0.0, 0.0, 1.0], inverse=True)  # world up seen in the housing
            if up[2] < np.cos(np.radians(60.0)):
                omega = -omega
                nxt = r * Rotation.from_rotvec(omega * dt)
        r = nxt
        out.append(r.as_quat())
    return Rotation.from_quat(np.array(out))


def simulate_tumble(*, seed: int = 0, n: int = 3000, rate_hz: float = 50.0, field_ut: float = 50.0,
                    dip_deg: float = 60.0, hard_iron_ut: float = 20.0, soft_iron: float = 0.08,
                    misalign_deg: float = 2.0, noise_ut: float = 0.3, accel_noise_g: float = 0.005,
                    motion_g: float = 0.05, outlier_fraction: float = 0.0, outlier_ut: float = 25.0,
                    coverage: str = "full", hold: int = 1, drift_ut: float = 0.0, drift_tau_s: float | None = None,
                    temp_swing_c: float = 0.0, temp_offset_ut_per_c: float = 0.0, temp_gain_per_c: float = 0.0,
                    step_ut: float = 0.0, step_fraction: float = 0.5) -> SimulatedTumble:
    """Simulate a tumble.

    Parameters
    ----------
    seed : int
    n : int
        Rows written (including held repeats).
    rate_hz : float
        Row rate.
    field_ut, dip_deg : float
        Earth field magnitude (uT) and dip (deg, > 0 down).
    hard_iron_ut : float
        Scale of the random hard-iron offset per axis, uT.
    soft_iron : float
        Scale of the symmetric soft-iron distortion ``W - I`` (dimensionless).
    misalign_deg : float
        Rotation angle between magnetometer and accelerometer frames, deg (random axis).
    noise_ut, accel_noise_g : float
        White noise per axis.
    motion_g : float
        Scale of the linear accelerations of the hand (smoothed), g.
    outlier_fraction : float
        Fraction of samples inside disturbance bursts (a magnet passing by, 20-sample bursts).
    outlier_ut : float
        Size of the disturbing field, uT.
    coverage : {"full", "upright"}
    hold : int
        Magnetometer sample-and-hold: each value repeated on ``hold`` rows (1: no repeats).
    drift_ut : float
        Size of the hard iron's change with time (random direction), uT: over the whole session
        when ``drift_tau_s`` is None (a linear wander), else the settled change of a warm-up.
    drift_tau_s : float, optional
        Time constant of the warm-up, s: the offset follows the die temperature of a two-stage
        thermal path (see :func:`_drift_profile`) toward its settled value.
    temp_swing_c : float
        Amplitude of the temperature profile, degC: from 25 degC it rises by this much and falls to
        this much below (``25 + swing sin(1.5 pi t / T)``), so temperature is not a function of time.
    temp_offset_ut_per_c : float
        Size of the hard iron's temperature coefficient (random direction), uT/degC.
    temp_gain_per_c : float
        Scale of the per-axis gain temperature coefficients (random, signed), 1/degC.
    step_ut : float
        Size of a hard-iron step (random direction), uT: a magnetised part attached partway.
    step_fraction : float
        Where the step happens, as a fraction of the rows.

    Returns
    -------
    SimulatedTumble
    """
    if coverage not in COVERAGES:
        raise ValueError(f"coverage must be one of {COVERAGES}, got {coverage!r}")
    rng = np.random.default_rng(seed)
    att = _path(rng, n, rate_hz, coverage)
    b_world = world_field(dip_deg, field_ut)
    h = rng.uniform(-1.0, 1.0, 3) * hard_iron_ut
    sym = rng.normal(size=(3, 3)) * soft_iron
    w = np.eye(3) + (sym + sym.T) / 2.0
    c = Rotation.from_rotvec(misalign_deg * np.radians(1.0) * _unit(rng.normal(size=3)))
    b_housing = att.apply(b_world, inverse=True)
    b_mag = c.apply(b_housing, inverse=True)
    mag = b_mag @ w.T + h + rng.normal(scale=noise_ut, size=(n, 3))
    t_s = np.arange(n) / rate_hz
    # effects beyond the ellipsoid draw from their own generator: the plain tumble of a seed stays as it was
    extra = np.random.default_rng([seed, 1])
    drift, temperature, step, temp_c = None, None, None, None
    if drift_ut:
        change = _unit(extra.normal(size=3)) * drift_ut
        mag += np.outer(_drift_profile(t_s, drift_tau_s), change)
        drift = {"change_ut": change.tolist(), "tau_s": drift_tau_s,
                 "form": "linear over the session" if drift_tau_s is None else "two-stage thermal warm-up"}
    if temp_swing_c:
        temp_true = 25.0 + temp_swing_c * np.sin(1.5 * np.pi * t_s / max(t_s[-1], 1e-9))
        k_offset = _unit(extra.normal(size=3)) * temp_offset_ut_per_c
        k_gain = extra.uniform(-1.0, 1.0, 3) * temp_gain_per_c
        delta = temp_true - 25.0
        mag += (b_mag @ w.T) * (k_gain[None, :] * delta[:, None]) + np.outer(delta, k_offset)
        temp_c = np.round(temp_true, 2)
        temperature = {"temp_ref_c": 25.0, "hard_iron_ut_per_degc": k_offset.tolist(),
                       "gain_rel_per_degc": k_gain.tolist()}
    if step_ut:
        first = int(round(step_fraction * n))
        change = _unit(extra.normal(size=3)) * step_ut
        mag[first:] += change
        step = {"change_ut": change.tolist(), "first_row": first}

    outliers = np.zeros(n, dtype=bool)
    n_bursts = int(round(outlier_fraction * n / 20))
    for start in rng.integers(0, max(n - 20, 1), size=n_bursts):
        mag[start:start + 20] += _unit(rng.normal(size=3)) * outlier_ut * rng.uniform(0.5, 1.5)
        outliers[start:start + 20] = True
    if hold > 1:
        mag = mag[(np.arange(n) // hold) * hold]

    kernel = np.hanning(25)
    kernel /= kernel.sum()
    motion = np.column_stack([np.convolve(rng.normal(size=n), kernel, "same") for _ in range(3)])
    motion *= motion_g / max(np.std(motion), 1e-12)
    accel = att.apply([0.0, 0.0, 1.0], inverse=True) + motion + rng.normal(scale=accel_noise_g, size=(n, 3))

    heading, _, _ = heading_pitch_roll(att)
    truth = {
        "hard_iron": h.tolist(),
        "soft_iron": np.linalg.inv(w).tolist(),
        "mag_to_accel": c.as_matrix().tolist(),
        "misalign_deg": misalign_deg,
        "field_ut": field_ut,
        "dip_deg": dip_deg,
        "noise_ut": noise_ut,
        "coverage": coverage,
        "outlier_rows": np.flatnonzero(outliers).tolist(),
        "drift": drift,
        "temperature": temperature,
        "step": step,
    }
    return SimulatedTumble(t_s, mag, accel, att, heading, truth, temp_c)


def write_tumble(sim: SimulatedTumble, path, *, force: bool = False, accel: bool = True) -> tuple[Path, Path]:
    """Write the recording CSV (SPEC section 2) and its truth side file ``<stem>.truth.json``.

    Raises
    ------
    FileExistsError
        If either file exists and ``force`` is False.
    """
    columns = ["t_s", "mx", "my", "mz"] + (["ax", "ay", "az"] if accel else [])
    data = [sim.t_s, sim.mag] + ([sim.accel] if accel else [])
    if sim.temp_c is not None:
        columns.append("temp_c")
        data.append(sim.temp_c)
    text = csv_text(columns, np.column_stack(data), "%.5f", {"source": "compass simulate tumble"})
    return write_with_truth(path, text, sim.truth, force=force)


def _drift_profile(t_s: np.ndarray, tau_s: float | None) -> np.ndarray:
    """Fraction of the drift reached at each sample.

    A linear ramp over the session, or a warm-up through two thermal stages: the heat source
    settles with ``tau_s / 30`` and the sensor's die follows it with ``tau_s``, both integrated by
    Euler steps between samples (an S-shaped start; not the estimator's single exponential).
    """
    if tau_s is None:
        return (t_s - t_s[0]) / max(t_s[-1] - t_s[0], 1e-9)
    source, die = 0.0, np.zeros(len(t_s))
    for i in range(1, len(t_s)):
        dt = t_s[i] - t_s[i - 1]
        source += (1.0 - source) * min(dt * 30.0 / tau_s, 1.0)
        die[i] = die[i - 1] + (source - die[i - 1]) * min(dt / tau_s, 1.0)
    return die


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)
