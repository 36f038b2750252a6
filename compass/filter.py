"""The live attitude filter (filterpy) with a magnetic-disturbance gate.

Two causal filters share one error convention, the gate and the output:

- **with a gyro**: a multiplicative (error-state) extended Kalman filter.  The nominal attitude
  ``R = R_world<-housing`` (a scipy ``Rotation``, NWU world, FLU housing, SPEC section 1) is
  propagated with the bias-corrected gyro; the filterpy ``KalmanFilter`` carries the error state
  ``x = (eps, db)``: ``eps`` the small rotation in the world frame with ``R_true = Exp(eps) R``
  (rad) and ``db`` the gyro-bias error (rad/s, housing frame).  After every update the error is
  injected into the nominal state and reset to zero.
- **without a gyro**: a filter on the two-vector (TRIAD, gravity first) solutions
  (:func:`compass.attitude.two_vector_rotation`): state ``(eps, omega)``, ``omega`` the world-frame
  angular rate (rad/s), a first-order Gauss-Markov process driven by white angular acceleration; the
  measurement is the rotation vector from the estimate to the two-vector solution, world frame.
  While the gate rejects the field this filter has no heading information: the heading coasts to
  a stop (rate correlation time ``rate_tau_s``), right for a brief disturbance only.

Measurements (both filters):

.. math::

    \\text{gravity:}\\; \\hat a_H = R^T z + R^T [z]_\\times \\epsilon + n_a, \\qquad
    \\text{heading:}\\; \\psi_{meas} = \\epsilon_z + n_\\psi

with ``z`` the world up, ``a_H`` the unit accelerometer vector and ``psi_meas`` minus the azimuth
(toward West) of the measured field rotated into the world by the estimate.  The magnetometer only
corrects heading (as VQF and x-io Fusion do): a disturbed field cannot tilt the estimate.

The **gate** (VQF's and Fusion's magnetic rejection): the field is used only while its magnitude
and its dip against the filter's own up direction match the reference (the calibration's |B| and
dip) within tolerances, and (once the heading is settled) its heading innovation is small.  A
rejection longer than ``gate_timeout_s`` means the environment changed: the current |B| and dip
become the reference and the heading is re-learnt from the field (VQF's ``magRejectMax``).  The
accelerometer is used only while its norm is within ``accel_tolerance`` of gravity.

References: D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation estimation with bias
estimation and magnetic disturbance rejection", Information Fusion 91 (2023); x-io Fusion
(``FusionAhrs``); F. L. Markley, "Attitude error representations for Kalman filtering", JGCA 26 (2003).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import KalmanFilter
from scipy.spatial.transform import Rotation

from .attitude import two_vector_rotation
from .frames import heading_pitch_roll

__all__ = ["FilterConfig", "Estimate", "AttitudeFilter", "FilterTrack", "run_filter", "reference_field"]

_UP = np.array([0.0, 0.0, 1.0])
_UP_CROSS = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # [z]x
_P0_ATTITUDE = [0.05**2, 0.05**2, 0.2**2]  # initial error variance of tilt and heading, rad^2
_P0_RATE = 0.5**2  # two-vector filter: initial angular rate variance, (rad/s)^2


@dataclass(frozen=True)
class FilterConfig:
    """Noise model, gate and reference field of :class:`AttitudeFilter`.

    Nothing here is fitted to a data set: the defaults are generic MEMS figures; pass your
    sensors' data-sheet values where you know them.

    Attributes
    ----------
    field_norm : float
        Reference |B|, field units (the unit of ``field_h``).
    dip_deg : float
        Reference dip, degrees (> 0: field points down).
    mag_noise : float
        White noise of each field component, field units, per sample.
    accel_noise : float
        White noise of each component of the unit accelerometer vector (fraction of g), per sample;
        include small unmodelled accelerations here.
    gyro_noise : float
        Gyro rate noise density, rad/s/sqrt(Hz) (per-sample sigma = density * sqrt(rate)).
    gyro_bias_walk : float
        Gyro bias random walk, rad/s^2/sqrt(Hz).
    gyro_bias_sigma0 : float
        Initial 1-sigma of each bias component, rad/s.
    angular_accel_noise : float
        Without gyro: white angular acceleration driving the constant-rate model, rad/s^2/sqrt(Hz).
    rate_tau_s : float
        Without gyro: correlation time of the angular rate (a first-order Gauss-Markov rate, so a
        heading coasts to a stop while the field is rejected), seconds.
    gravity : float or None
        |a| at rest in the accelerometer's unit; None learns it from the samples (first sample,
        then a 10 s average of accepted samples).
    accel_tolerance : float
        Use the accelerometer only while ``| |a| / gravity - 1 |`` is below this.
    field_tolerance : float
        Gate: largest accepted ``| |B| / field_norm - 1 |``.
    dip_tolerance_deg : float
        Gate: largest accepted dip error, degrees.
    heading_tolerance_deg : float
        Gate: largest accepted heading innovation, degrees, checked once the heading 1-sigma is
        below a third of it.
    gate : bool
        Gate the field at all (False: every field sample updates the heading; for comparisons).
    gate_timeout_s : float
        A continuous rejection this long adopts the current field as the reference, seconds.
    max_gap_s : float
        A time step longer than this restarts the attitude from the next two-vector solution
        (the gyro bias is kept), seconds.
    """

    field_norm: float
    dip_deg: float
    mag_noise: float
    accel_noise: float = 0.005
    gyro_noise: float = 3e-4
    gyro_bias_walk: float = 1e-4
    gyro_bias_sigma0: float = 0.05
    angular_accel_noise: float = 0.1
    rate_tau_s: float = 1.0
    gravity: float | None = None
    accel_tolerance: float = 0.1
    field_tolerance: float = 0.02
    dip_tolerance_deg: float = 2.0
    heading_tolerance_deg: float = 10.0
    gate: bool = True
    gate_timeout_s: float = 20.0
    max_gap_s: float = 0.5

    def __post_init__(self):
        for name in ("field_norm", "mag_noise", "accel_noise", "gyro_noise", "gyro_bias_walk", "gyro_bias_sigma0",
                     "angular_accel_noise", "rate_tau_s", "accel_tolerance", "field_tolerance", "dip_tolerance_deg",
                     "heading_tolerance_deg", "gate_timeout_s", "max_gap_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"FilterConfig.{name} must be a positive number, got {value!r}")
        if not -90.0 < self.dip_deg < 90.0:
            raise ValueError(f"FilterConfig.dip_deg must be in (-90, 90), got {self.dip_deg!r}")
        if self.gravity is not None and not self.gravity > 0:
            raise ValueError(f"FilterConfig.gravity must be positive or None, got {self.gravity!r}")

    @classmethod
    def from_model(cls, model) -> "FilterConfig":
        """Reference field and magnetometer noise from a :class:`compass.model.SensorModel`.

        Change other fields with ``dataclasses.replace``.

        Raises
        ------
        ValueError
            The calibration has no dip or no noise floor.
        """
        if model.dip_deg is None:
            raise ValueError("the calibration has no dip_deg: the filter needs the field's reference direction")
        if model.noise is None:
            raise ValueError("the calibration has no noise_floor: the filter cannot weight the magnetometer")
        noise = float(np.sqrt(np.trace(model.field_covariance(np.zeros(3))) / 3.0))
        return cls(field_norm=model.field_magnitude, dip_deg=model.dip_deg, mag_noise=noise)


@dataclass(frozen=True)
class Estimate:
    """The filter's output after one sample.

    Attributes
    ----------
    t_s : float
        Sample time, seconds.
    rotation : Rotation
        ``R_world<-housing`` (NWU world, FLU housing).
    heading_deg, pitch_deg, roll_deg : float
        SPEC section 1 angles.
    heading_sigma_deg, tilt_sigma_deg : float
        1-sigma of the world-frame error about the vertical and (rms) about a horizontal axis,
        degrees, from the filter covariance.
    field_ratio : float
        Measured |B| over the reference |B|.
    dip_deg : float
        Measured dip against the filter's up direction, degrees.
    mag_used : bool
        The gate let the field in.
    gate : str
        ``"ok"``, or why the field was rejected: ``"norm"``, ``"dip"``, ``"innovation"``.
    accel_used : bool
        The accelerometer update was applied.
    gyro_bias : ndarray, shape (3,), or None
        Estimated gyro bias in H, rad/s (gyro filter only).
    """

    t_s: float
    rotation: Rotation
    heading_deg: float
    pitch_deg: float
    roll_deg: float
    heading_sigma_deg: float
    tilt_sigma_deg: float
    field_ratio: float
    dip_deg: float
    mag_used: bool
    gate: str
    accel_used: bool
    gyro_bias: np.ndarray | None


class AttitudeFilter:
    """Causal attitude filter, one sample at a time (see the module docstring).

    Parameters
    ----------
    config : FilterConfig
    gyro : bool
        Use the gyro filter (samples bring ``gyro``) or the two-vector filter.

    Attributes
    ----------
    events : list of str
        Notes on restarts and reference changes since the last :meth:`drain_events`.

    Examples
    --------
    >>> f = AttitudeFilter(FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1), gyro=True)
    >>> up, b = np.array([0, 0, 9.81]), np.array([25.0, 0.0, -43.3])   # level, facing north
    >>> est = f.step(0.0, up, np.zeros(3), b)
    >>> round(est.heading_deg, 3) % 360, est.mag_used
    (0.0, True)
    """

    def __init__(self, config: FilterConfig, *, gyro: bool):
        self.config = config
        self.gyro = bool(gyro)
        self.events: list[str] = []
        dip = np.radians(config.dip_deg)
        self._tan_dip = np.tan(dip)
        self._unit_mag_var = (config.mag_noise / config.field_norm) ** 2
        self._yaw_var = self._unit_mag_var / np.cos(dip) ** 2
        self._kf = KalmanFilter(dim_x=6, dim_z=4)
        self._kf.P = np.diag(_P0_ATTITUDE + [config.gyro_bias_sigma0**2] * 3)
        self._h_mag = np.array([[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]])
        self._h_tilt = np.eye(6)[:2]
        self._bias = np.zeros(3)
        self._rate = np.zeros(3)  # last gyro reading, held when a sample has none
        self._rotation: Rotation | None = None
        self._t: float | None = None
        self._gravity = config.gravity
        self._ref_norm = config.field_norm
        self._ref_dip = config.dip_deg
        self._rejected_since: float | None = None

    @property
    def initialised(self) -> bool:
        return self._rotation is not None

    def drain_events(self) -> list[str]:
        """Return and clear the pending event notes."""
        events, self.events = self.events, []
        return events

    def step(self, t_s: float, accel, gyro, field_h) -> Estimate | None:
        """Process one sample.

        Parameters
        ----------
        t_s : float
            Sample time, seconds (non-decreasing; a step back is treated as zero).
        accel : array_like, shape (3,), or None
            Accelerometer in H, any unit (specific force, +up at rest).
        gyro : array_like, shape (3,), or None
            Angular rate of H in H, rad/s; None holds the last rate (gyro filter) and is ignored
            by the two-vector filter.
        field_h : array_like, shape (3,)
            Field in H, field units (e.g. :meth:`compass.model.SensorModel.field`).

        Returns
        -------
        Estimate or None
            None until the first sample with an accelerometer reading initialises the attitude.
        """
        field_h = np.asarray(field_h, dtype=float)
        b_norm = float(np.sqrt(field_h @ field_h))
        if gyro is not None:
            self._rate = np.asarray(gyro, dtype=float)
        a_unit, accel_ok = self._accel(accel)
        dt = 0.0 if self._t is None else max(t_s - self._t, 0.0)
        self._t = t_s
        if self._rotation is not None and dt > self.config.max_gap_s:
            self.events.append(f"filter restarted after a {dt:.2f} s gap in the samples")
            self._rotation = None
        if self._rotation is None:
            if a_unit is None or b_norm == 0.0:
                return None
            self._start(a_unit, field_h)
            dt = 0.0
        self._predict(dt)
        matrix = self._rotation.as_matrix()
        if not self.gyro and accel_ok:
            return self._two_vector_update(t_s, a_unit, field_h, b_norm, matrix)
        if accel_ok:
            h = matrix[2]  # R^T z
            h_acc = np.zeros((3, 6))
            h_acc[:, :3] = matrix.T @ _UP_CROSS
            self._kf.update_sequential(0, a_unit - h, self.config.accel_noise**2, h_acc)
            matrix = self._inject()
        m_w = matrix @ field_h
        innovation = -np.arctan2(m_w[1], m_w[0])
        gate, ratio, dip = self._gate(t_s, field_h, b_norm, matrix, innovation)
        mag_ok = gate == "ok" and (self.gyro or accel_ok)
        if mag_ok:
            var = self._yaw_var + self._tan_dip**2 * (self._kf.P[0, 0] + self._kf.P[1, 1]) / 2.0
            self._kf.update_sequential(3, innovation, var, self._h_mag)
            self._inject()
        return self._estimate(t_s, ratio, dip, mag_ok, gate, accel_ok)

    # ------------------------------------------------------------------ internals

    def _start(self, a_unit, field_h) -> None:
        """Attitude from the two-vector solution; attitude (and, without gyro, rate) covariance reset."""
        self._rotation = two_vector_rotation(a_unit, field_h, self._ref_dip, 0.0)[0]
        kf = self._kf
        keep = 3 if self.gyro else 0  # the gyro bias outlives a restart, the rate estimate does not
        p = np.diag(_P0_ATTITUDE + [_P0_RATE] * 3)
        if keep:
            p[3:, 3:] = kf.P[3:, 3:]
        kf.P = p
        kf.x[:] = 0.0

    def _accel(self, accel) -> tuple[np.ndarray | None, bool]:
        """Unit accelerometer vector (None if absent or zero) and whether it may update tilt."""
        if accel is None:
            return None, False
        a = np.asarray(accel, dtype=float)
        norm = float(np.sqrt(a @ a))
        if not norm > 0:
            return None, False
        if self._gravity is None:
            self._gravity = norm
        ok = abs(norm / self._gravity - 1.0) <= self.config.accel_tolerance
        if ok and self.config.gravity is None and self._t is not None:
            self._gravity += (norm - self._gravity) * 1e-3  # ~10 s average at 100 Hz
        return a / norm, ok

    def _predict(self, dt: float) -> None:
        kf, cfg = self._kf, self.config
        if dt == 0.0:
            return
        f = np.eye(6)
        if self.gyro:
            matrix = self._rotation.as_matrix()
            f[:3, 3:] = -matrix * dt
            q = np.diag([cfg.gyro_noise**2 * dt] * 3 + [cfg.gyro_bias_walk**2 * dt] * 3)
            self._rotation = self._rotation * Rotation.from_rotvec((self._rate - self._bias) * dt)
        else:
            decay = np.exp(-dt / cfg.rate_tau_s)
            f[:3, 3:] = np.eye(3) * cfg.rate_tau_s * (1.0 - decay)
            f[3:, 3:] = np.eye(3) * decay
            q = Q_continuous_white_noise(dim=2, dt=dt, spectral_density=cfg.angular_accel_noise**2,
                                         block_size=3, order_by_dim=False)
        kf.predict(F=f, Q=q)
        if not self.gyro:
            self._inject()  # the constant-rate step moved eps: fold it into the nominal attitude

    def _inject(self) -> np.ndarray:
        """Fold the error state into the nominal attitude (and bias); return the new matrix."""
        x = self._kf.x
        self._rotation = Rotation.from_rotvec(x[:3, 0]) * self._rotation
        x[:3] = 0.0
        if self.gyro:
            self._bias = self._bias + x[3:, 0]
            x[3:] = 0.0
        return self._rotation.as_matrix()

    def _gate(self, t_s, field_h, b_norm, matrix, innovation) -> tuple[str, float, float]:
        """Gate reason, |B| ratio and measured dip (degrees) against the current up estimate."""
        cfg = self.config
        ratio = b_norm / self._ref_norm
        dip = float(np.degrees(np.arcsin(np.clip(-(matrix[2] @ field_h) / b_norm, -1.0, 1.0)))) if b_norm else 0.0
        if b_norm == 0.0:
            return "absent", ratio, dip
        if not cfg.gate:
            return "ok", ratio, dip
        settled = np.degrees(np.sqrt(self._kf.P[2, 2])) < cfg.heading_tolerance_deg / 3.0
        if abs(ratio - 1.0) > cfg.field_tolerance:
            gate = "norm"
        elif abs(dip - self._ref_dip) > cfg.dip_tolerance_deg:
            gate = "dip"
        elif settled and abs(np.degrees(innovation)) > cfg.heading_tolerance_deg:
            gate = "innovation"
        else:
            self._rejected_since = None
            return "ok", ratio, dip
        if self._rejected_since is None:
            self._rejected_since = t_s
        elif t_s - self._rejected_since > cfg.gate_timeout_s:
            self.events.append(f"field rejected for {cfg.gate_timeout_s:g} s: adopting |B| = {b_norm:.4g} and "
                               f"dip = {dip:.2f} deg as the new reference")
            self._ref_norm, self._ref_dip = b_norm, dip
            self._kf.P[2, 2] += np.radians(3.0 * cfg.heading_tolerance_deg) ** 2
            self._rejected_since = None
            return "ok", 1.0, dip
        return gate, ratio, dip

    def _two_vector_update(self, t_s, a_unit, field_h, b_norm, matrix) -> Estimate:
        """Two-vector filter: tilt rows always, heading row when the gate lets the field in."""
        solution = two_vector_rotation(a_unit, field_h, self._ref_dip, 0.0)[0]
        z = (solution * self._rotation.inv()).as_rotvec()
        gate, ratio, dip = self._gate(t_s, field_h, b_norm, matrix, z[2])
        tilt_var = self.config.accel_noise**2
        self._kf.update_sequential(0, z[:2], tilt_var, self._h_tilt)
        if gate == "ok":
            self._kf.update_sequential(3, z[2], self._yaw_var + self._tan_dip**2 * tilt_var, self._h_mag)
        self._inject()
        return self._estimate(t_s, ratio, dip, gate == "ok", gate, True)

    def _estimate(self, t_s, ratio, dip, mag_used, gate, accel_used) -> Estimate:
        heading, pitch, roll = heading_pitch_roll(self._rotation)
        p = self._kf.P
        return Estimate(t_s, self._rotation, float(heading[0]), float(pitch[0]), float(roll[0]),
                        float(np.degrees(np.sqrt(p[2, 2]))), float(np.degrees(np.sqrt((p[0, 0] + p[1, 1]) / 2.0))),
                        float(ratio), float(dip), bool(mag_used), gate, bool(accel_used),
                        self._bias.copy() if self.gyro else None)


@dataclass(frozen=True)
class FilterTrack:
    """:func:`run_filter`'s output, one row per sample (NaN before initialisation).

    Attributes
    ----------
    t_s : ndarray, shape (n,)
    quat : ndarray, shape (n, 4)
        ``R_world<-housing`` as scipy quaternions (x, y, z, w).
    heading_deg, pitch_deg, roll_deg, heading_sigma_deg, tilt_sigma_deg, field_ratio, dip_deg : ndarray, shape (n,)
    mag_used, accel_used : ndarray of bool, shape (n,)
    gate : ndarray of str, shape (n,)
    gyro_bias : ndarray, shape (n, 3), or None
    """

    t_s: np.ndarray
    quat: np.ndarray
    heading_deg: np.ndarray
    pitch_deg: np.ndarray
    roll_deg: np.ndarray
    heading_sigma_deg: np.ndarray
    tilt_sigma_deg: np.ndarray
    field_ratio: np.ndarray
    dip_deg: np.ndarray
    mag_used: np.ndarray
    accel_used: np.ndarray
    gate: np.ndarray
    gyro_bias: np.ndarray | None


def run_filter(t_s, accel, gyro, field_h, config: FilterConfig) -> FilterTrack:
    """Run :class:`AttitudeFilter` causally over recorded arrays.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Sample times, seconds.
    accel : array_like, shape (n, 3)
        Accelerometer in H, any unit; rows with NaN count as absent.
    gyro : array_like, shape (n, 3), or None
        Gyro in H, rad/s; None runs the two-vector filter.
    field_h : array_like, shape (n, 3)
        Field in H, field units.
    config : FilterConfig

    Returns
    -------
    FilterTrack
    """
    t_s = np.asarray(t_s, dtype=float)
    accel = np.asarray(accel, dtype=float)
    field_h = np.asarray(field_h, dtype=float)
    n = len(t_s)
    if accel.shape != (n, 3) or field_h.shape != (n, 3):
        raise ValueError(f"expected accel and field_h of shape ({n}, 3), got {accel.shape} and {field_h.shape}")
    if gyro is not None:
        gyro = np.asarray(gyro, dtype=float)
        if gyro.shape != (n, 3):
            raise ValueError(f"expected gyro of shape ({n}, 3), got {gyro.shape}")
    filt = AttitudeFilter(config, gyro=gyro is not None)
    scalars = np.full((n, 7), np.nan)
    quat = np.full((n, 4), np.nan)
    flags = np.zeros((n, 2), dtype=bool)
    gate = np.full(n, "absent", dtype=object)
    bias = None if gyro is None else np.full((n, 3), np.nan)
    for i in range(n):
        a = accel[i] if np.all(np.isfinite(accel[i])) else None
        g = None if gyro is None or not np.all(np.isfinite(gyro[i])) else gyro[i]
        est = filt.step(t_s[i], a, g, field_h[i])
        if est is None:
            continue
        quat[i] = est.rotation.as_quat()
        scalars[i] = (est.heading_deg, est.pitch_deg, est.roll_deg, est.heading_sigma_deg, est.tilt_sigma_deg,
                      est.field_ratio, est.dip_deg)
        flags[i] = est.mag_used, est.accel_used
        gate[i] = est.gate
        if bias is not None:
            bias[i] = est.gyro_bias
    return FilterTrack(t_s, quat, *scalars.T, flags[:, 0], flags[:, 1], gate.astype(str), bias)


def reference_field(accel, field_h) -> tuple[float, float]:
    """Reference |B| and dip from samples taken away from disturbances (e.g. a recording's start).

    For data without a calibration file: medians of ``|B|`` and of the field-gravity angle.

    Parameters
    ----------
    accel, field_h : array_like, shape (n, 3)
        Accelerometer (any unit) and field (field units) in H.

    Returns
    -------
    field_norm : float
        Median |B|, field units.
    dip_deg : float
        Median dip, degrees.
    """
    a = np.asarray(accel, dtype=float)
    b = np.asarray(field_h, dtype=float)
    ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    if not np.any(ok):
        raise ValueError("no sample has both a finite accelerometer and field reading")
    a, b = a[ok], b[ok]
    b_norm = np.linalg.norm(b, axis=1)
    cos = -np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * b_norm)
    return float(np.median(b_norm)), float(np.degrees(np.median(np.arcsin(np.clip(cos, -1.0, 1.0)))))
