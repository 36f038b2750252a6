"""Simulated 3-D platform sessions (seed 001) with known truth.

Forward model (shared with :mod:`calibrate.platform3d`'s prediction), with ``R_i = R_W<-H`` from
the platform angles (:func:`compass.io.platform3d.platform_rotation`):

.. math::

    m_i = M R_i^T b_W + o_m + n_i, \\qquad t_i = A R_i^T u_W + o_t + e_i

``M`` (3x3, rows ``k_c a_c``: gain times unit sensing direction in H) and ``o_m`` are the
magnetometer's sensing matrix and offsets; ``b_W = |B| (cos dip cos delta, cos dip sin delta,
-sin dip)`` the field in W; ``A`` (2x3 or 3x3) and ``o_t`` the tilt sensor's; ``u_W`` the true up
direction seen in W, ``(0, 0, 1)`` turned by the platform base's level error.  Both ``M`` and ``A``
are built as scales times a non-orthogonal unit-axis set turned by a small rotation relative to H,
so the truth names every quantity the calibration reports.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import heading_pitch_roll
from ._files import csv_text, write_with_truth
from ._slow import TEMP_REF_C, chamber_temperature, check_session, drift_profile, session_clock
from ..io.platform3d import ANGLE_COLUMNS, platform_rotation

__all__ = ["POSE_SETS", "SimulatedPlatform3D", "predict", "up_in_bench", "simulate_platform3d", "write_platform3d",
           "world_from_bench"]

POSE_SETS = ("grid", "random", "turntable")
"""``grid``: z every 30 deg x y in (-45, 0, 45) x x in (0, 90, 180, 270); ``random``: uniform
attitudes; ``turntable``: z only (never tilted; leaves the vertical axes undetermined)."""


def up_in_bench(base_tilt_deg) -> np.ndarray:
    """True up seen in W for a base level error (rotation vector ``(tx, ty, 0)`` in degrees), shape (3,)."""
    tx, ty = base_tilt_deg
    return Rotation.from_rotvec([tx, ty, 0.0], degrees=True).apply([0.0, 0.0, 1.0])


def predict(rotation: Rotation, mag_matrix, mag_offset, field_w, tilt_matrix, tilt_offset, up_w):
    """Noise-free outputs of the magnetometer and the tilt sensor.

    Parameters
    ----------
    rotation : Rotation
        ``R_W<-H`` per sample (n).
    mag_matrix : array_like, shape (3, 3)
        ``M``, output units per field unit.
    mag_offset : array_like, shape (3,)
    field_w : array_like, shape (3,)
        Field in W, field units.
    tilt_matrix : array_like, shape (c, 3)
        ``A``, output units per g.
    tilt_offset : array_like, shape (c,)
    up_w : array_like, shape (3,)
        Unit up direction in W (the specific force at rest is +1 g along it).

    Returns
    -------
    mag : ndarray, shape (n, 3)
    tilt : ndarray, shape (n, c)
    """
    b_h = rotation.apply(field_w, inverse=True)
    u_h = rotation.apply(up_w, inverse=True)
    return b_h @ np.asarray(mag_matrix).T + mag_offset, u_h @ np.asarray(tilt_matrix).T + tilt_offset


def world_from_bench(field_w, up_w) -> Rotation:
    """``R_world<-W`` for the NWU world of SPEC section 1: north = the field's horizontal part."""
    up = np.asarray(up_w, float) / np.linalg.norm(up_w)
    north = np.asarray(field_w, float) - np.dot(field_w, up) * up
    north /= np.linalg.norm(north)
    return Rotation.from_matrix(np.array([north, np.cross(up, north), up]))


@dataclass(frozen=True)
class SimulatedPlatform3D:
    """A simulated platform session and its truth.

    Attributes
    ----------
    angles_deg : ndarray, shape (n, 3)
        ``platform_z_deg, platform_y_deg, platform_x_deg``.
    mag : ndarray, shape (n, 3)
    tilt : ndarray, shape (n, c)
    heading_deg, pitch_deg, roll_deg : ndarray, shape (n,)
        True attitude of the housing (SPEC section 1, NWU world about the true vertical).
    truth : dict
        JSON-ready: ``mag_matrix``, ``mag_offset``, ``tilt_matrix``, ``tilt_offset``, ``field_ut``,
        ``dip_deg`` (from the true vertical), ``azimuth_deg`` (field in W from the platform zero),
        ``base_tilt_deg`` (rotation vector ``(tx, ty, 0)`` of the base's level error),
        ``noise_mag``, ``noise_tilt`` (output units); ``drift`` and ``temperature`` (None when not
        simulated, see :func:`simulate_platform3d`).  ``mag_offset`` holds at ``t_s = 0`` and 25 degC.
    t_s : ndarray, shape (n,), or None
        Time of every sample, s (with ``session_s``).
    temp_c : ndarray, shape (n,), or None
        Sensor temperature as recorded (0.01 degC steps), with ``temp_swing_c``.
    """

    angles_deg: np.ndarray
    mag: np.ndarray
    tilt: np.ndarray
    heading_deg: np.ndarray
    pitch_deg: np.ndarray
    roll_deg: np.ndarray
    truth: dict
    t_s: np.ndarray | None = None
    temp_c: np.ndarray | None = None


def _poses(rng, poses: str, repeats: int) -> np.ndarray:
    if poses == "grid":
        z, y, x = np.meshgrid(np.arange(0.0, 360.0, 30.0), (-45.0, 0.0, 45.0), (0.0, 90.0, 180.0, 270.0), indexing="ij")
        grid = np.column_stack([z.ravel(), y.ravel(), x.ravel()])
    elif poses == "random":
        grid = Rotation.random(150, random_state=rng.integers(2**31)).as_euler("ZYX", degrees=True)
    elif poses == "turntable":
        grid = np.column_stack([np.arange(0.0, 360.0, 10.0), np.zeros(36), np.zeros(36)])
    else:
        raise ValueError(f"poses must be one of {POSE_SETS}, got {poses!r}")
    return np.repeat(grid, repeats, axis=0)


def _axes(rng, nonorthogonality_deg: float, misalign_deg: float, n: int) -> np.ndarray:
    """Unit sensing directions in H: identity rows tipped by ~nonorthogonality, then turned by a rotation."""
    axes = np.eye(3)[:n] + rng.normal(scale=np.radians(nonorthogonality_deg), size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    rot = Rotation.from_rotvec(np.radians(misalign_deg) * rng.normal(size=3) / np.sqrt(3))
    return axes @ rot.as_matrix().T


def simulate_platform3d(*, seed: int = 0, poses: str = "grid", repeats: int = 3, field_ut: float = 50.0,
                        dip_deg: float = 60.0, mag_gain: float = 1.0, tilt_axes: int = 2, tilt_gain: float = 1.0,
                        nonorthogonality_deg: float = 1.0, misalign_deg: float = 2.0, base_tilt_deg: float = 0.2,
                        noise_ut: float = 0.1, noise_g: float = 0.001, session_s: float | None = None,
                        drift_ut: float = 0.0, drift_tau_s: float | None = None, temp_swing_c: float = 0.0,
                        temp_offset_ut_per_c: float = 0.0) -> SimulatedPlatform3D:
    """Simulate a 3-D platform session.

    Parameters
    ----------
    seed : int
    poses : {"grid", "random", "turntable"}
        See :data:`POSE_SETS`.
    repeats : int
        Samples per pose.
    field_ut, dip_deg : float
        |B| (uT) and dip (deg, > 0 down) about the true vertical.
    mag_gain, tilt_gain : float
        Nominal gains: magnetometer output units per uT, tilt output units per g (each axis
        within +-5 % of it).
    tilt_axes : {2, 3}
        A two-axis inclinometer (the seed's) or a three-axis accelerometer.
    nonorthogonality_deg, misalign_deg : float
        Scale of the axes' random tips and of each sensor's rotation relative to H, degrees.
    base_tilt_deg : float
        Scale of the platform base's level error, degrees.
    noise_ut, noise_g : float
        White noise per axis, uT and g (in output units: times the gains).
    session_s : float, optional
        Length of the session, s: the samples get a ``t_s`` column, evenly spaced over it in pose
        order (a pose's repeats follow each other).
    drift_ut : float
        Size of a magnetometer offset drift (random direction), uT: the change over the session
        when ``drift_tau_s`` is None (constant rate), else the settled change of a warm-up
        ``1 - exp(-t / drift_tau_s)``.  Needs ``session_s``.
    drift_tau_s : float, optional
    temp_swing_c : float
        Amplitude of a temperature cycle, degC, recorded as ``temp_c``: ``25 + swing sin(4 pi i / (n - 1))``
        over the samples (two cycles of a chamber, so temperature is not a function of time).
    temp_offset_ut_per_c : float
        Size of the magnetometer offsets' temperature coefficient (random direction), uT/degC.

    Returns
    -------
    SimulatedPlatform3D
    """
    if tilt_axes not in (2, 3):
        raise ValueError(f"tilt_axes must be 2 or 3, got {tilt_axes}")
    check_session(session_s, drift_ut, "drift_ut")
    rng = np.random.default_rng(seed)
    mag_axes = _axes(rng, nonorthogonality_deg, misalign_deg, 3)
    tilt_axes_h = _axes(rng, nonorthogonality_deg, misalign_deg, tilt_axes)
    m = mag_gain * rng.uniform(0.95, 1.05, 3)[:, None] * mag_axes
    a = tilt_gain * rng.uniform(0.95, 1.05, tilt_axes)[:, None] * tilt_axes_h
    o_m = mag_gain * rng.uniform(-10.0, 10.0, 3)
    o_t = tilt_gain * rng.uniform(-0.05, 0.05, tilt_axes)
    base = rng.normal(scale=base_tilt_deg, size=2)
    up_w = up_in_bench(base)
    azimuth = rng.uniform(0.0, 360.0)
    # field at the given dip from the true vertical, azimuth measured in W's horizontal plane
    horiz = np.array([np.cos(np.radians(azimuth)), np.sin(np.radians(azimuth)), 0.0])
    horiz = horiz - np.dot(horiz, up_w) * up_w
    horiz /= np.linalg.norm(horiz)
    field_w = field_ut * (np.cos(np.radians(dip_deg)) * horiz - np.sin(np.radians(dip_deg)) * up_w)
    angles = _poses(rng, poses, repeats)  # after the sensors: one seed, the same sensors for every pose set
    rot = platform_rotation(*angles.T)
    mag, tilt = predict(rot, m, o_m, field_w, a, o_t, up_w)
    mag = mag + rng.normal(scale=noise_ut * mag_gain, size=mag.shape)
    tilt = tilt + rng.normal(scale=noise_g * tilt_gain, size=tilt.shape)
    # effects beyond the linear model draw from their own generator: the plain session of a seed stays as it was
    extra = np.random.default_rng([seed, 1])
    n = len(mag)
    t_s = session_clock(n, session_s)
    drift, temperature, temp_c = None, None, None
    if drift_ut:
        change = _unit(extra.normal(size=3)) * drift_ut
        profile, form = drift_profile(t_s, session_s, drift_tau_s)
        mag = mag + np.outer(profile, change * mag_gain)
        drift = {"change_ut": change.tolist(), "tau_s": drift_tau_s, "form": form}
    if temp_swing_c:
        temp_true = chamber_temperature(n, temp_swing_c)
        k_offset = _unit(extra.normal(size=3)) * temp_offset_ut_per_c
        mag = mag + np.outer(temp_true - TEMP_REF_C, k_offset * mag_gain)
        temp_c = np.round(temp_true, 2)
        temperature = {"temp_ref_c": TEMP_REF_C, "offset_ut_per_degc": k_offset.tolist()}
    heading, pitch, roll = heading_pitch_roll(world_from_bench(field_w, up_w) * rot)
    truth = {
        "mag_matrix": m.tolist(), "mag_offset": o_m.tolist(), "tilt_matrix": a.tolist(), "tilt_offset": o_t.tolist(),
        "field_ut": field_ut, "dip_deg": dip_deg, "azimuth_deg": float(np.degrees(np.arctan2(field_w[1], field_w[0]))),
        "base_tilt_deg": base.tolist(),
        "noise_mag": noise_ut * mag_gain, "noise_tilt": noise_g * tilt_gain, "poses": poses,
        "drift": drift, "temperature": temperature,
    }
    return SimulatedPlatform3D(angles, mag, tilt, heading, pitch, roll, truth, t_s, temp_c)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def write_platform3d(sim: SimulatedPlatform3D, path, *, force: bool = False,
                     field_ut_metadata: bool = True) -> tuple[Path, Path]:
    """Write the recording CSV and its truth side file ``<stem>.truth.json``.

    Raises
    ------
    FileExistsError
        If either file exists and ``force`` is False.
    """
    tilt_cols = ["ax", "ay", "az"][: sim.tilt.shape[1]]
    metadata = {"source": "compass simulate platform3d"}
    if field_ut_metadata:
        metadata["field_ut"] = sim.truth["field_ut"]
    extra = [(name, v) for name, v in (("t_s", sim.t_s), ("temp_c", sim.temp_c)) if v is not None]
    columns = list(ANGLE_COLUMNS) + ["mx", "my", "mz"] + tilt_cols + [name for name, _ in extra]
    data = np.column_stack([sim.angles_deg, sim.mag, sim.tilt] + [v for _, v in extra])
    return write_with_truth(path, csv_text(columns, data, "%.6f", metadata), sim.truth, force=force)
