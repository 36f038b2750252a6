"""A tumble that covers only part of the sphere, with a gyro: hand-held motion through iron, cut short.

The motion and the IMU are :func:`compass.sim.motion.simulate_motion`'s (gyro bias, scale error and
noise; accelerometer noise; the truth's attitude); the magnetometer then reads the field through
the iron of :mod:`compass.sim.tumble`'s model,

.. math:: \\mathrm{raw}_k = W C^T R_k^T B_W + h + n_k,

(``W`` symmetric soft iron, ``C`` = ``mag_to_accel``, ``h`` hard iron), so the calibration that
undoes it is ``soft_iron = W^-1``, ``hard_iron = h``, ``mag_to_accel = C``.  The recording is cut
where the field's directions first cover ``coverage`` of the sphere (the cells of
:func:`calibrate`'s coverage, :func:`compass.frames.sphere_cells`), after a still start.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import heading_pitch_roll, sphere_cells, world_field
from ._files import csv_text, write_with_truth
from .motion import GRAVITY, SensorErrors, simulate_motion

__all__ = ["PartialTumble", "simulate_partial_tumble", "write_partial_tumble"]

_N_CELLS = 200  # as calibrate.tumble.coverage


@dataclass(frozen=True)
class PartialTumble:
    """A simulated partial tumble with a gyro, and its truth.

    Attributes
    ----------
    t_s : ndarray, shape (n,)
    mag : ndarray, shape (n, 3)
        Raw magnetometer, uT.
    accel : ndarray, shape (n, 3)
        Accelerometer, g.
    gyro : ndarray, shape (n, 3)
        Gyro, rad/s, housing frame.
    attitude : Rotation
        ``R_world<-housing`` of every sample.
    heading_deg : ndarray, shape (n,)
    coverage : float
        Fraction of the sphere's cells the true field directions visited.
    truth : dict
        ``hard_iron``, ``soft_iron`` (W^-1), ``mag_to_accel``, ``field_ut``, ``dip_deg``, ``noise_ut``,
        ``gyro_bias_rad_s``, ``gyro_scale``, ``kind``, ``coverage``, ``outlier_rows`` (none).
    """

    t_s: np.ndarray
    mag: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    attitude: Rotation
    heading_deg: np.ndarray
    coverage: float
    truth: dict


def _covered(field_h: np.ndarray) -> np.ndarray:
    """Running fraction of the sphere's cells visited by the directions, per sample."""
    u = field_h / np.linalg.norm(field_h, axis=1, keepdims=True)
    cell = np.argmax(u @ sphere_cells(_N_CELLS).T, axis=1)
    first = np.full(_N_CELLS, len(u))
    np.minimum.at(first, cell, np.arange(len(u)))  # the sample that first visits each cell
    new = np.zeros(len(u))
    new[first[first < len(u)]] = 1.0
    return np.cumsum(new) / _N_CELLS


def simulate_partial_tumble(kind: str = "slow_rotation", *, seed: int = 0, coverage: float | None = 0.3,
                            duration_s: float = 120.0, rate_hz: float = 50.0, field_ut: float = 50.0,
                            dip_deg: float = 60.0, hard_iron_ut: float = 20.0, soft_iron: float = 0.08,
                            misalign_deg: float = 2.0, noise_ut: float = 0.3,
                            gyro_bias_deg_s: float = 0.5, gyro_scale: float = 0.005,
                            gyro_noise_deg_s: float = 0.01) -> PartialTumble:
    """Simulate a hand-held motion of ``kind`` (:data:`compass.sim.motion.KINDS`) cut at ``coverage``.

    Parameters
    ----------
    kind : str
    seed : int
    coverage : float or None
        Fraction of the sphere at which the recording ends (None: the whole motion).
    duration_s, rate_hz : float
        Of the motion simulated before the cut.
    field_ut, dip_deg, hard_iron_ut, soft_iron, misalign_deg, noise_ut :
        As :func:`compass.sim.tumble.simulate_tumble`.
    gyro_bias_deg_s, gyro_scale, gyro_noise_deg_s : float
        Scale of the random per-axis gyro bias (deg/s) and scale error (relative), and the rate
        noise density (deg/s/sqrt(Hz)).

    Returns
    -------
    PartialTumble

    Raises
    ------
    ValueError
        The motion never reaches ``coverage``.
    """
    rng = np.random.default_rng([seed, 22])
    errors = SensorErrors(gyro_bias_rad_s=tuple(np.radians(rng.uniform(-1, 1, 3) * gyro_bias_deg_s)),
                          gyro_scale=tuple(rng.uniform(-1, 1, 3) * gyro_scale),
                          gyro_noise=float(np.radians(gyro_noise_deg_s)), accel_noise_m_s2=0.05, mag_noise_ut=0.0)
    rec = simulate_motion(kind, duration_s=duration_s, rate_hz=rate_hz, seed=seed, errors=errors,
                          field_ut=field_ut, dip_deg=dip_deg)
    field_h = rec.rotation.apply(world_field(dip_deg, field_ut), inverse=True)
    reached = _covered(field_h)
    n = len(field_h)
    if coverage is not None:
        hit = np.flatnonzero(reached >= coverage)
        if hit.size == 0:
            raise ValueError(f"the {kind} motion of seed {seed} covers only {100 * reached[-1]:.0f} % of the sphere, "
                             f"not {100 * coverage:.0f} %")
        n = int(hit[0]) + 1
    h = rng.uniform(-1.0, 1.0, 3) * hard_iron_ut
    sym = rng.normal(size=(3, 3)) * soft_iron
    w = np.eye(3) + (sym + sym.T) / 2.0
    axis = rng.normal(size=3)
    c = Rotation.from_rotvec(np.radians(misalign_deg) * axis / np.linalg.norm(axis))
    mag = c.apply(field_h[:n], inverse=True) @ w.T + h + rng.normal(scale=noise_ut, size=(n, 3))
    attitude = rec.rotation[:n]
    truth = {"hard_iron": h.tolist(), "soft_iron": np.linalg.inv(w).tolist(), "mag_to_accel": c.as_matrix().tolist(),
             "field_ut": field_ut, "dip_deg": dip_deg, "noise_ut": noise_ut, "kind": kind,
             "coverage": float(reached[n - 1]), "gyro_bias_rad_s": list(errors.gyro_bias_rad_s),
             "gyro_scale": list(errors.gyro_scale), "outlier_rows": []}
    return PartialTumble(rec.t_s[:n], mag, rec.accel_m_s2[:n] / GRAVITY, rec.gyro_rad_s[:n], attitude,
                         heading_pitch_roll(attitude)[0], float(reached[n - 1]), truth)


def write_partial_tumble(sim: PartialTumble, path, *, force: bool = False, gyro_unit: str = "rad/s") -> tuple[Path, Path]:
    """Write the recording (``t_s, mx.., ax.., gx..``; the gyro in ``gyro_unit``) and its truth side file."""
    gyro = sim.gyro if gyro_unit == "rad/s" else np.degrees(sim.gyro)
    text = csv_text(["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"],
                    np.column_stack([sim.t_s, sim.mag, sim.accel, gyro]), "%.6f",
                    {"source": f"compass.sim.partial_tumble {sim.truth['kind']}"})
    return write_with_truth(path, text, sim.truth, force=force)
