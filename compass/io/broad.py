"""Trials of the BROAD benchmark (real IMU data with optical ground truth) as toolkit arrays.

BROAD (Berlin Robust Orientation Estimation Assessment Dataset): D. Laidig, M. Caruso,
A. Cereatti, T. Seel, "BROAD - A Benchmark for Robust Inertial Orientation Estimation", Data 6(7):72,
2021, https://doi.org/10.3390/data6070072; data under CC BY 4.0.

A trial is a MATLAB v5 file with ``imu_gyr`` (rad/s), ``imu_acc`` (m/s^2, specific force),
``imu_mag`` (uT), all in the IMU body frame; ``opt_quat`` (body -> ENU unit quaternion, scalar
first, NaN rows where the optical system lost the body), ``opt_pos`` (m), ``movement`` (1 in the
motion phase the benchmark scores) and ``sampling_rate`` (Hz).  The body frame is the toolkit's
housing frame H; the toolkit's world frame is NWU (SPEC section 1), BROAD's is ENU with the local
*magnetic* north along +Y, so ``R_NWU<-ENU = Rz(-90 deg)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..limits import RATE_HZ
from .table import RecordingError
from .units import MAX_ABS_VALUE

__all__ = ["BroadTrial", "read_broad", "NWU_FROM_ENU", "enu_to_nwu", "nwu_to_enu"]

NWU_FROM_ENU = Rotation.from_euler("z", -90.0, degrees=True)
"""``R_NWU<-ENU``: East (1, 0, 0) goes to (0, -1, 0) (minus West), North (0, 1, 0) to (1, 0, 0)."""
_REQUIRED = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos", "movement", "sampling_rate")
_VECTORS = {"imu_gyr": 3, "imu_acc": 3, "imu_mag": 3, "opt_quat": 4, "opt_pos": 3}
_UNIT_TOLERANCE = 1e-3


@dataclass(frozen=True, eq=False)
class BroadTrial:
    """One BROAD trial in the toolkit's units and frames.

    Attributes
    ----------
    path : str
    name : str
        File stem, e.g. ``32_disturbed_attached_magnet_1cm``.
    rate_hz : float
        Sampling rate.
    gyro_rad_s : ndarray, shape (n, 3)
        Angular rate in H, rad/s.
    accel_m_s2 : ndarray, shape (n, 3)
        Specific force in H, m/s^2 (+9.81 along up at rest).
    mag_ut : ndarray, shape (n, 3)
        Magnetometer in H, uT (already calibrated by the IMU's maker).
    ref_quat_enu : ndarray, shape (n, 4)
        Ground truth ``R_ENU<-H`` as unit quaternions, scalar first (w, x, y, z); NaN rows are optical
        dropouts.
    ref_pos_m : ndarray, shape (n, 3)
        Position of the marker body, m (NaN rows possible).
    movement : ndarray of bool, shape (n,)
        The motion phase BROAD's metric scores.
    info : str
        The file's own description.
    """

    path: str
    name: str
    rate_hz: float
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    mag_ut: np.ndarray
    ref_quat_enu: np.ndarray
    ref_pos_m: np.ndarray
    movement: np.ndarray
    info: str

    def __len__(self) -> int:
        return len(self.mag_ut)

    @property
    def t_s(self) -> np.ndarray:
        """Sample times from the first sample, s, shape (n,)."""
        return np.arange(len(self)) / self.rate_hz

    @property
    def ref_valid(self) -> np.ndarray:
        """True where the optical reference exists, shape (n,)."""
        return np.all(np.isfinite(self.ref_quat_enu), axis=1)

    def reference(self, world: str = "nwu") -> Rotation:
        """Ground truth ``R_world<-H`` on the rows where it exists (see :attr:`ref_valid`).

        Parameters
        ----------
        world : {"nwu", "enu"}
            NWU is the toolkit's world frame (SPEC section 1), ENU is BROAD's.
        """
        if world not in ("nwu", "enu"):
            raise ValueError(f"world must be 'nwu' or 'enu', got {world!r}")
        r = Rotation.from_quat(self.ref_quat_enu[self.ref_valid], scalar_first=True)
        return enu_to_nwu(r) if world == "nwu" else r


def enu_to_nwu(r_enu: Rotation) -> Rotation:
    """``R_NWU<-H`` from ``R_ENU<-H`` (same body frame, world axes renamed)."""
    return NWU_FROM_ENU * r_enu


def nwu_to_enu(r_nwu: Rotation) -> Rotation:
    """``R_ENU<-H`` from ``R_NWU<-H``."""
    return NWU_FROM_ENU.inv() * r_nwu


def read_broad(path) -> BroadTrial:
    """Read one BROAD trial (``.mat``) and validate it.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    BroadTrial

    Raises
    ------
    RecordingError
        Unreadable or not a MATLAB file, a variable missing, wrong shapes, non-finite IMU samples,
        non-unit reference quaternions, a non-positive rate, or no movement phase; the message
        names the file and the variable (as the column) and, where it applies, the row (1-based).

    Examples
    --------
    >>> trial = read_broad("../shared/data/broad/01_undisturbed_slow_rotation_A.mat")  # doctest: +SKIP
    >>> trial.rate_hz, trial.mag_ut.shape  # doctest: +SKIP
    (285.714..., (56940, 3))
    """
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, "no such file")
    try:
        d = loadmat(path, squeeze_me=True)
    except (OSError, ValueError, TypeError, NotImplementedError, MatReadError) as exc:
        raise RecordingError(path, f"not a readable MATLAB v5 BROAD trial ({exc})") from None
    missing = [k for k in _REQUIRED if k not in d]
    if missing:
        raise RecordingError(path, f"missing {', '.join(missing)}: expected a BROAD trial with "
                                   f"{', '.join(_REQUIRED)}", column=missing[0])
    arrays = {}
    n = None
    for key, width in _VECTORS.items():
        try:
            a = np.asarray(d[key], dtype=float)
        except (TypeError, ValueError):
            raise RecordingError(path, "expected numbers", column=key) from None
        if a.ndim != 2 or a.shape[1] != width:
            raise RecordingError(path, f"expected shape (n, {width}), got {a.shape}", column=key)
        if n is not None and len(a) != n:
            raise RecordingError(path, f"expected {n} rows like imu_gyr, got {len(a)}", column=key)
        n = len(a)
        arrays[key] = a
    for key in ("imu_gyr", "imu_acc", "imu_mag"):
        with np.errstate(invalid="ignore"):
            bad = ~np.all(np.abs(arrays[key]) <= MAX_ABS_VALUE, axis=1)  # True for NaN
        if bad.any():
            raise RecordingError(path, f"IMU sample not finite or beyond {MAX_ABS_VALUE:g} in magnitude (no sensor "
                                       "reads it)", row=int(np.argmax(bad)) + 1, column=key)
    quat = arrays["opt_quat"]
    norm = np.linalg.norm(quat, axis=1)
    bad = np.isfinite(norm) & (np.abs(norm - 1.0) > _UNIT_TOLERANCE)
    if bad.any():
        raise RecordingError(path, f"expected unit quaternions (w, x, y, z) or NaN rows, got norm "
                                   f"{norm[np.argmax(bad)]:.4g}", row=int(np.argmax(bad)) + 1, column="opt_quat")
    quat = np.where(np.isfinite(norm)[:, None], quat, np.nan)  # a partly-NaN row is a dropout
    movement = np.asarray(d["movement"]).reshape(-1)
    if movement.shape != (n,):
        raise RecordingError(path, f"expected {n} values, got {movement.shape}", column="movement")
    movement = movement.astype(bool)
    if not movement.any():
        raise RecordingError(path, "no sample marked as movement: nothing to score", column="movement")
    try:
        rate = RATE_HZ.check(float(d["sampling_rate"]), "the rate")
    except (TypeError, ValueError) as exc:
        what = str(exc) if isinstance(exc, ValueError) and "rate" in str(exc) else "expected one number (Hz)"
        raise RecordingError(path, what, column="sampling_rate") from None
    info = d.get("info", "")
    return BroadTrial(path=str(path), name=path.stem, rate_hz=rate, gyro_rad_s=arrays["imu_gyr"],
                      accel_m_s2=arrays["imu_acc"], mag_ut=arrays["imu_mag"], ref_quat_enu=quat,
                      ref_pos_m=arrays["opt_pos"], movement=movement, info=str(info))
