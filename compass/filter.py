"""The live attitude filter (filterpy) with a magnetic-disturbance gate.

Two causal filters share one error convention, the gate and the output:

- **with a gyro**: a multiplicative (error-state) extended Kalman filter.  The nominal attitude
  ``R = R_world<-housing`` (NWU world, FLU housing, SPEC section 1) is propagated with the
  bias-corrected gyro by the exact exponential of each step's rotation; the filterpy
  ``KalmanFilter`` carries the error state ``x = (eps, db)``: ``eps`` the small rotation in the
  world frame with ``R_true = Exp(eps) R`` (rad) and ``db`` the gyro-bias error (rad/s, housing
  frame).  After every update the error is injected into the nominal state and reset to zero.
- **without a gyro**: a filter on the two-vector (TRIAD, gravity first) solutions
  (:func:`compass.attitude.two_vector_rotation`): state ``(eps, omega)``, ``omega`` the world-frame
  angular rate (rad/s), a first-order Gauss-Markov process driven by white angular acceleration; the
  measurement is the rotation vector from the estimate to the two-vector solution, world frame.
  While the gate rejects the field this filter has no heading information: the heading coasts to
  a stop (rate correlation time ``rate_tau_s``), right for a brief disturbance only.

**Model of the gyro filter.**  Process noise: the gyro's white rate noise (density ``gyro_noise``)
plus its scale-factor and cross-axis error, a rate error proportional to the turn rate that
persists (correlation time ~1 s), and the bias random walk:

.. math::

    Q_\\epsilon = \\big(\\sigma_g^2 + s^2 |\\omega|^2 \\tau_s\\big)\\,\\Delta t\\; I, \\qquad
    Q_b = \\sigma_{bw}^2 \\Delta t\\; I .

Accelerometer: it reads specific force ``f = R^T (g z + a_motion)``.  Hand-held motion has bounded
velocity, so ``a_motion`` has no power at low frequency: the specific force is low-passed (time
constant ``accel_time_constant_s``, tau) in the gyro-propagated inertial frame, as VQF does, which
leaves gravity plus ``(v - LP v) / tau``, a residual that varies on the velocity's time scale
``tau_v``.  That low-passed direction is the tilt measurement,

.. math::

    \\hat f_{LP} = R^T z + R^T [z]_\\times \\epsilon + n, \\qquad
    \\operatorname{var} n = \\sigma_a^2 + \\frac{2 \\tau_v}{\\Delta t}\\,\\sigma_r^2,

with ``sigma_r^2`` the residual's variance, measured from the data: the low-passed vector's norm
error ``(|f_LP| / g - 1)^2`` (the residual along gravity) plus the raw motion ``|f - f_LP|^2 / g^2``
attenuated by the low-pass at the motion's time scale, ``(tau_v / 2 pi tau)^2``, both averaged
over ``tau_v``.  The factor ``2 tau_v / dt`` turns a noise correlated over ``tau_v`` into its
per-sample white equivalent, so the filter never takes more tilt information from the
accelerometer than it has: still, the tilt converges in about a second; in violent motion the
correction slows to many seconds and the gyro carries the tilt.

Magnetometer: it corrects heading only (as VQF and x-io Fusion do; a disturbed field cannot tilt
the estimate): ``psi_meas = eps_z + n_psi``, ``psi_meas`` minus the azimuth (toward West) of the
field rotated into the world by the estimate, with the sensor noise, the tilt error seen through
``tan(dip)`` and the environment's heading error (field inhomogeneity, calibration residue,
latency; correlated over ``tau_v``) in ``var n_psi``.  The gyro filter measures that heading error
as it runs: an error that turns the field's direction by ``delta`` moves its dip by the component in
the vertical plane and its azimuth by the horizontal one over ``cos(dip)``; for an error with no
preferred direction the two components have one variance, so

.. math:: \\sigma_\\psi^2 = \\max\\Big(\\sigma_{floor}^2,\\;
          \\big\\langle (dip - dip_{ref})^2 - \\sigma_n^2 / |B|^2 - P_{tilt} \\big\\rangle / \\cos^2(dip)\\Big),

the deviation of each accepted sample's dip from the gate's slowly following reference, less what
the sensor noise and the filter's own tilt error (``P_tilt``, the mean of the two horizontal
variances) put there, averaged with time constant ``field_reference_tau_s``.  A field that keeps
its dip as the housing turns is trusted; one whose dip wanders is not.  ``mag_heading_sigma_deg``
is the floor: errors that leave the dip alone are invisible to this measurement (a hard-iron residue
fixed in a housing held level moves the dip by ``e sin(dip)`` but the heading by ``e / cos(dip)``, so
near the equator it is under-estimated by up to ``1 / sin(dip)``).  The two-vector filter has no
such measurement.  The heading follows the field with a time constant of seconds while the housing
turns and slower when still.

At **rest** (gyro and accelerometer steady within 2 deg/s and 0.05 g for 1.5 s and the gyro's
low-passed rate below 2 deg/s, VQF's rest detector and bias bound) the gyro reads its bias: a
direct bias measurement on every axis, so the heading does not drift while the field is rejected.

The **gate** (VQF's and Fusion's magnetic rejection): the field is used only while its magnitude
and its dip against the filter's own up direction match a reference within tolerances, and (once
the heading is settled) its heading innovation is small.  The reference starts from the
calibration's |B| and dip and follows the accepted field slowly (``field_reference_tau_s``), so a
field that changes across a room is followed while a fast change (a magnet) is rejected.  A
rejection longer than ``gate_timeout_s`` means the environment changed: the current |B| and dip
become the reference and the heading is re-learnt from the field (VQF's ``magNewTime``).

References: D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation estimation with bias
estimation and magnetic disturbance rejection", Information Fusion 91 (2023); x-io Fusion
(``FusionAhrs``); F. L. Markley, "Attitude error representations for Kalman filtering", JGCA 26 (2003).
"""

from __future__ import annotations

import math
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
_SCALE_CORRELATION_S = 1.0  # a scale-factor error persists while the housing keeps turning
_REST_GYRO = math.radians(2.0)  # VQF's rest detector: rate deviation, rad/s
_REST_ACCEL = 0.05  # and specific-force deviation, fraction of g
_REST_TAU_S = 0.5  # low-pass of the rest detector
_REST_MIN_S = 1.5  # how long both must hold
_REST_RATE_SIGMA = 1e-3  # residual true rate "at rest" (tremor, Earth's rotation), rad/s
_ORTHONORMALISE_EVERY = 1000  # samples between re-orthonormalisations of the nominal matrix


def _exp(v) -> np.ndarray:
    """Rotation matrix of the rotation vector ``v`` (rad), Rodrigues' formula."""
    x, y, z = v.tolist() if isinstance(v, np.ndarray) else v
    th2 = x * x + y * y + z * z
    if th2 < 1e-10:
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    c = 1.0 - b * th2
    return np.array([[c + b * x * x, b * x * y - a * z, b * x * z + a * y],
                     [b * x * y + a * z, c + b * y * y, b * y * z - a * x],
                     [b * x * z - a * y, b * y * z + a * x, c + b * z * z]])


@dataclass(frozen=True)
class FilterConfig:
    """Noise model, gate and reference field of :class:`AttitudeFilter`.

    Nothing here is fitted to a data set: the defaults are generic MEMS figures and VQF's published
    time constants and thresholds; pass your sensors' data-sheet values where you know them.

    Attributes
    ----------
    field_norm : float
        Reference |B|, field units (the unit of ``field_h``).
    dip_deg : float
        Reference dip, degrees (> 0: field points down).
    mag_noise : float
        White noise of each field component, field units, per sample.
    accel_noise : float
        White noise of each component of the unit accelerometer vector (fraction of g), per sample.
    gyro_noise : float
        Gyro rate noise density, rad/s/sqrt(Hz) (per-sample sigma = density * sqrt(rate)).
    gyro_bias_walk : float
        Gyro bias random walk, rad/s^2/sqrt(Hz).
    gyro_bias_sigma0 : float
        Initial 1-sigma of each bias component, rad/s.
    gyro_scale_error : float
        Relative scale-factor and cross-axis error of the gyro (fraction of the rate).
    accel_time_constant_s : float
        Low-pass of the specific force in the inertial frame, seconds (VQF's ``tauAcc``).
    motion_time_s : float
        Time scale on which the housing's velocity varies (hand-held motion), seconds: the
        correlation time of what the low-pass leaves of the motion acceleration, and of the
        environment's heading error as the housing moves.
    mag_heading_sigma_deg : float
        Heading error of the undisturbed field itself (inhomogeneity across the working volume,
        calibration residue), degrees: the floor; the gyro filter uses the larger of it and the
        error it measures from the wander of the field's dip (module docstring).
    field_reference_tau_s : float
        Time constant with which the gate's reference |B| and dip follow the accepted field, seconds.
    angular_accel_noise : float
        Without gyro: white angular acceleration driving the constant-rate model, rad/s^2/sqrt(Hz).
    rate_tau_s : float
        Without gyro: correlation time of the angular rate (a first-order Gauss-Markov rate, so a
        heading coasts to a stop while the field is rejected), seconds.
    gravity : float or None
        |a| at rest in the accelerometer's unit; None learns it from the samples (first sample,
        then the average at rest).
    accel_tolerance : float
        Use the (low-passed) accelerometer only while ``| |a| / gravity - 1 |`` is below this.
    field_tolerance : float
        Gate: largest accepted ``| |B| / reference - 1 |`` (VQF: 0.1).
    dip_tolerance_deg : float
        Gate: largest accepted dip error against the reference, degrees (VQF: 10).
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
    gyro_scale_error: float = 0.005
    accel_time_constant_s: float = 3.0
    motion_time_s: float = 1.0
    mag_heading_sigma_deg: float = 2.0
    field_reference_tau_s: float = 20.0
    angular_accel_noise: float = 0.1
    rate_tau_s: float = 1.0
    gravity: float | None = None
    accel_tolerance: float = 0.1
    field_tolerance: float = 0.1
    dip_tolerance_deg: float = 10.0
    heading_tolerance_deg: float = 10.0
    gate: bool = True
    gate_timeout_s: float = 20.0
    max_gap_s: float = 0.5

    def __post_init__(self):
        for name in ("field_norm", "mag_noise", "accel_noise", "gyro_noise", "gyro_bias_walk", "gyro_bias_sigma0",
                     "gyro_scale_error", "accel_time_constant_s", "motion_time_s", "mag_heading_sigma_deg",
                     "field_reference_tau_s", "angular_accel_noise", "rate_tau_s", "accel_tolerance",
                     "field_tolerance", "dip_tolerance_deg", "heading_tolerance_deg", "gate_timeout_s", "max_gap_s"):
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
    field_heading_sigma_deg : float
        Heading error of the accepted field itself, degrees: the larger of ``mag_heading_sigma_deg``
        and the one measured so far from the wander of its dip (module docstring); NaN for the
        two-vector filter.
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
    field_heading_sigma_deg: float
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
        self._tan_dip2 = float(np.tan(dip)) ** 2
        self._cos_dip2 = float(np.cos(dip)) ** 2
        self._env_floor = np.radians(config.mag_heading_sigma_deg) ** 2
        self._dip_noise_var = (config.mag_noise / config.field_norm) ** 2
        self._dip_excess_var = self._env_floor * self._cos_dip2  # the dip's wander beyond the sensor noise, rad^2
        self._yaw_var = self._dip_noise_var / self._cos_dip2  # the sensor noise in heading, rad^2
        self._kf = KalmanFilter(dim_x=6, dim_z=4)
        self._kf.P = np.diag(_P0_ATTITUDE + [config.gyro_bias_sigma0**2] * 3)
        # preallocated model matrices (filled in place each sample)
        self._f = np.eye(6)
        self._q = np.zeros((6, 6))
        self._h_mag = np.array([[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]])
        self._h_tilt = np.eye(6)[:2]
        self._h_acc = np.zeros((3, 6))
        self._h_bias = np.hstack([np.zeros((3, 3)), np.eye(3)])
        self._bias = np.zeros(3)
        self._rate = np.zeros(3)  # last gyro reading, held when a sample has none
        self._matrix: np.ndarray | None = None  # nominal R_world<-housing
        self._t: float | None = None
        self._gravity = config.gravity
        self._ref_norm = config.field_norm
        self._ref_dip = config.dip_deg
        self._rejected_since: float | None = None
        self._steps = 0
        # accelerometer low-pass in the inertial frame (kept in H, turned with the gyro)
        self._acc_lp: np.ndarray | None = None
        self._acc_lp_age = 0.0  # mean age of the low-pass's content, s: its sensitivity to a bias error
        self._residual_var = 0.0  # variance of what the low-pass leaves of the motion, (fraction of g)^2
        # rest detector
        self._rest_gyro: np.ndarray | None = None
        self._rest_acc: np.ndarray | None = None
        self._rest_s = 0.0
        # the last sample's diagnostics
        self._last = (1.0, 0.0, False, "absent", False)

    @property
    def initialised(self) -> bool:
        return self._matrix is not None

    @property
    def at_rest(self) -> bool:
        """The rest detector holds: the gyro reads its bias."""
        return self._rest_s >= _REST_MIN_S

    @property
    def field_heading_var(self) -> float:
        """Heading error variance of the accepted field itself, rad^2: the larger of the configured
        floor and the one measured from the wander of its dip (gyro filter; module docstring)."""
        return max(self._env_floor, self._dip_excess_var / self._cos_dip2)

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
        if not self._advance(t_s, accel, gyro, field_h):
            return None
        return self._estimate(t_s)

    # ------------------------------------------------------------------ internals

    def _advance(self, t_s, accel, gyro, field_h) -> bool:
        """The filter's work for one sample; False while it has no attitude yet."""
        field_h = np.asarray(field_h, dtype=float)
        b_norm = math.sqrt(field_h @ field_h)
        if gyro is not None:
            self._rate = np.asarray(gyro, dtype=float)
        a, a_norm = self._accel(accel)
        dt = 0.0 if self._t is None else max(t_s - self._t, 0.0)
        self._t = t_s
        if self._matrix is not None and dt > self.config.max_gap_s:
            self.events.append(f"filter restarted after a {dt:.2f} s gap in the samples")
            self._matrix = None
        if self._matrix is None:
            if a is None or b_norm == 0.0:
                return False
            self._start(a, a_norm, field_h)
            dt = 0.0
        if not self.gyro:
            self._predict_rate(dt)
            if a is not None and abs(a_norm / self._gravity - 1.0) <= self.config.accel_tolerance:
                self._two_vector_update(t_s, a / a_norm, field_h, b_norm)
                return True
            accel_ok = False
        else:
            self._propagate(dt)
            self._rest(dt, a)
            accel_ok = self._tilt_update(dt, a)
        matrix = self._matrix
        m_w = matrix @ field_h
        innovation = -math.atan2(m_w[1], m_w[0])
        gate, ratio, dip = self._gate(t_s, dt, field_h, b_norm, innovation)
        mag_ok = gate == "ok" and (self.gyro or accel_ok)
        if mag_ok:
            p = self._kf.P
            var = self._yaw_var + self._tan_dip2 * (p[0, 0] + p[1, 1]) / 2.0
            if dt > 0.0:
                var += self.field_heading_var * 2.0 * self.config.motion_time_s / dt
            self._kf.update_sequential(3, innovation, var, self._h_mag)
        self._inject()  # once per sample: the sequential updates share the error state
        self._last = (ratio, dip, mag_ok, gate, accel_ok)
        return True

    def _start(self, a, a_norm, field_h) -> None:
        """Attitude from the two-vector solution; attitude (and, without gyro, rate) covariance reset."""
        self._matrix = two_vector_rotation(a / a_norm, field_h, self._ref_dip, 0.0)[0].as_matrix()
        kf = self._kf
        keep = 3 if self.gyro else 0  # the gyro bias outlives a restart, the rate estimate does not
        p = np.diag(_P0_ATTITUDE + [_P0_RATE] * 3)
        if keep:
            p[3:, 3:] = kf.P[3:, 3:]
        kf.P = p
        kf.x[:] = 0.0
        self._acc_lp = a.copy()
        self._acc_lp_age = 0.0
        self._residual_var = 0.0
        self._rest_gyro, self._rest_acc, self._rest_s = self._rate.copy(), a.copy(), 0.0

    def _accel(self, accel) -> tuple[np.ndarray | None, float]:
        """The accelerometer reading and its norm (None, 0 if absent or zero); learns gravity."""
        if accel is None:
            return None, 0.0
        a = np.asarray(accel, dtype=float)
        norm = math.sqrt(a @ a)
        if not norm > 0:
            return None, 0.0
        if self._gravity is None:
            self._gravity = norm
        elif self.config.gravity is None and self.at_rest:
            self._gravity += (norm - self._gravity) * 1e-3  # at rest |a| is g
        return a, norm

    def _propagate(self, dt: float) -> None:
        """Gyro filter prediction: nominal attitude, inertial low-pass, covariance."""
        if dt == 0.0:
            return
        cfg = self.config
        w = self._rate - self._bias
        step = _exp(w * dt)
        self._matrix = self._matrix @ step
        self._steps += 1
        if self._steps % _ORTHONORMALISE_EVERY == 0:
            u, _, vt = np.linalg.svd(self._matrix)
            self._matrix = u @ vt
        if self._acc_lp is not None:
            self._acc_lp = step.T @ self._acc_lp  # a vector fixed in the inertial frame, seen from the turned housing
        f, q = self._f, self._q
        f[:3, 3:] = self._matrix * -dt
        rot_var = (cfg.gyro_noise**2 + cfg.gyro_scale_error**2 * float(w @ w) * _SCALE_CORRELATION_S) * dt
        bias_var = cfg.gyro_bias_walk**2 * dt
        q[0, 0] = q[1, 1] = q[2, 2] = rot_var
        q[3, 3] = q[4, 4] = q[5, 5] = bias_var
        self._kf.predict(F=f, Q=q)

    def _rest(self, dt: float, a) -> None:
        """VQF's rest detector; at rest the gyro reading measures its bias."""
        if a is None or dt == 0.0:
            return
        alpha = -math.expm1(-dt / _REST_TAU_S)
        self._rest_gyro += alpha * (self._rate - self._rest_gyro)
        self._rest_acc += alpha * (a - self._rest_acc)
        dg, da = self._rate - self._rest_gyro, a - self._rest_acc
        slow = self._rest_gyro @ self._rest_gyro < _REST_GYRO**2  # a slow steady turn is no rest (VQF's biasClip)
        steady = slow and dg @ dg < _REST_GYRO**2 and da @ da < (_REST_ACCEL * self._gravity) ** 2
        self._rest_s = self._rest_s + dt if steady else 0.0
        if not self.at_rest:
            return
        # the low-passed rate must also agree with the bias estimate (3 sigma): once the bias is known,
        # the onset of a slow turn is not taken for a bias change
        p = self._kf.P
        nu = self._rest_gyro - self._bias
        floor = self.config.gyro_noise**2 / (2.0 * _REST_TAU_S) + _REST_RATE_SIGMA**2
        if nu[0] ** 2 > 9.0 * (p[3, 3] + floor) or nu[1] ** 2 > 9.0 * (p[4, 4] + floor) \
                or nu[2] ** 2 > 9.0 * (p[5, 5] + floor):
            return
        var = self.config.gyro_noise**2 / dt + _REST_RATE_SIGMA**2
        self._kf.update_sequential(0, self._rate - self._bias, var, self._h_bias)

    def _tilt_update(self, dt: float, a) -> bool:
        """Tilt from the specific force low-passed in the inertial frame (module docstring)."""
        if a is None:
            return False
        cfg = self.config
        lp = self._acc_lp
        g = self._gravity
        if dt > 0.0:
            alpha = -math.expm1(-dt / cfg.accel_time_constant_s)
            lp += alpha * (a - lp)
            self._acc_lp_age = (1.0 - alpha) * (self._acc_lp_age + dt)
            tau_v = cfg.motion_time_s
            raw = a - lp
            attenuation = tau_v / (2.0 * math.pi * cfg.accel_time_constant_s)
            lp_norm = math.sqrt(lp @ lp)
            residual = (lp_norm / g - 1.0) ** 2 + float(raw @ raw) / g**2 * attenuation**2
            self._residual_var += -math.expm1(-dt / tau_v) * (residual - self._residual_var)
        else:
            lp_norm = math.sqrt(lp @ lp)
        if not lp_norm > 0 or abs(lp_norm / g - 1.0) > cfg.accel_tolerance:
            return False
        matrix = self._matrix
        var = cfg.accel_noise**2
        if dt > 0.0:
            var += self._residual_var * 2.0 * cfg.motion_time_s / dt
        up = matrix[2]  # R^T z
        self._h_acc[:, :3] = matrix.T @ _UP_CROSS
        # the content was turned into the housing with the estimated bias: a bias error db turns it by
        # age * db, so the low-passed direction reads up + age [up]x db
        x, y, z = (self._acc_lp_age * up).tolist()
        self._h_acc[:, 3:] = ((0.0, -z, y), (z, 0.0, -x), (-y, x, 0.0))
        self._kf.update_sequential(0, lp / lp_norm - up, var, self._h_acc)
        return True

    def _predict_rate(self, dt: float) -> None:
        """Two-vector filter prediction: the rate model moves the error, folded into the attitude."""
        if dt == 0.0:
            return
        cfg = self.config
        f = np.eye(6)
        decay = math.exp(-dt / cfg.rate_tau_s)
        f[:3, 3:] = np.eye(3) * cfg.rate_tau_s * (1.0 - decay)
        f[3:, 3:] = np.eye(3) * decay
        q = Q_continuous_white_noise(dim=2, dt=dt, spectral_density=cfg.angular_accel_noise**2,
                                     block_size=3, order_by_dim=False)
        self._kf.predict(F=f, Q=q)
        self._inject()

    def _inject(self) -> None:
        """Fold the error state into the nominal attitude (and bias), reset it to zero."""
        x = self._kf.x
        self._matrix = _exp(x[:3, 0]) @ self._matrix
        x[:3] = 0.0
        if self.gyro:
            db = x[3:, 0]
            self._bias = self._bias + db
            if self._acc_lp is not None:  # the part of the low-pass's turn error that db explains
                (vx, vy, vz), (bx, by, bz), age = self._acc_lp.tolist(), db.tolist(), self._acc_lp_age
                self._acc_lp -= (age * (vy * bz - vz * by), age * (vz * bx - vx * bz), age * (vx * by - vy * bx))
            x[3:] = 0.0

    def _gate(self, t_s, dt, field_h, b_norm, innovation) -> tuple[str, float, float]:
        """Gate reason, |B| ratio and measured dip (degrees) against the current up estimate."""
        cfg = self.config
        ratio = b_norm / self._ref_norm
        if b_norm == 0.0:
            return "absent", ratio, 0.0
        dip = math.degrees(math.asin(max(-1.0, min(1.0, -(self._matrix[2] @ field_h) / b_norm))))
        if not cfg.gate:
            return "ok", ratio, dip
        settled = self._kf.P[2, 2] < math.radians(cfg.heading_tolerance_deg / 3.0) ** 2
        if abs(ratio - 1.0) > cfg.field_tolerance:
            gate = "norm"
        elif abs(dip - self._ref_dip) > cfg.dip_tolerance_deg:
            gate = "dip"
        elif settled and abs(math.degrees(innovation)) > cfg.heading_tolerance_deg:
            gate = "innovation"
        else:
            self._rejected_since = None
            if dt > 0.0:  # the reference follows the accepted field slowly (VQF's magRefTau)
                alpha = -math.expm1(-dt / cfg.field_reference_tau_s)
                # the dip's wander beyond the white sensor noise (the filter's own tilt error stays in: it is
                # correlated like the environment's, and moves the heading as much, tan(dip) ~ 1 / cos(dip))
                excess = math.radians(dip - self._ref_dip) ** 2 - self._dip_noise_var
                self._dip_excess_var += alpha * (excess - self._dip_excess_var)
                self._ref_norm += alpha * (b_norm - self._ref_norm)
                self._ref_dip += alpha * (dip - self._ref_dip)
            return "ok", ratio, dip
        if self._rejected_since is None:
            self._rejected_since = t_s
        elif t_s - self._rejected_since > cfg.gate_timeout_s:
            self.events.append(f"field rejected for {cfg.gate_timeout_s:g} s: adopting |B| = {b_norm:.4g} and "
                               f"dip = {dip:.2f} deg as the new reference")
            self._ref_norm, self._ref_dip = b_norm, dip
            self._kf.P[2, 2] += math.radians(3.0 * cfg.heading_tolerance_deg) ** 2
            self._rejected_since = None
            return "ok", 1.0, dip
        return gate, ratio, dip

    def _two_vector_update(self, t_s, a_unit, field_h, b_norm) -> None:
        """Two-vector filter: tilt rows always, heading row when the gate lets the field in."""
        rotation = Rotation.from_matrix(self._matrix)
        solution = two_vector_rotation(a_unit, field_h, self._ref_dip, 0.0)[0]
        z = (solution * rotation.inv()).as_rotvec()
        gate, ratio, dip = self._gate(t_s, 0.0, field_h, b_norm, z[2])
        tilt_var = self.config.accel_noise**2
        self._kf.update_sequential(0, z[:2], tilt_var, self._h_tilt)
        if gate == "ok":
            self._kf.update_sequential(3, z[2], self._yaw_var + self._tan_dip2 * tilt_var, self._h_mag)
        self._inject()
        self._last = (ratio, dip, gate == "ok", gate, True)

    def _estimate(self, t_s) -> Estimate:
        rotation = Rotation.from_matrix(self._matrix)
        heading, pitch, roll = heading_pitch_roll(rotation)
        p = self._kf.P
        ratio, dip, mag_used, gate, accel_used = self._last
        return Estimate(t_s, rotation, float(heading[0]), float(pitch[0]), float(roll[0]),
                        math.degrees(math.sqrt(p[2, 2])), math.degrees(math.sqrt((p[0, 0] + p[1, 1]) / 2.0)),
                        math.degrees(math.sqrt(self.field_heading_var)) if self.gyro else math.nan, float(ratio),
                        float(dip), bool(mag_used), gate, bool(accel_used), self._bias.copy() if self.gyro else None)


@dataclass(frozen=True)
class FilterTrack:
    """:func:`run_filter`'s output, one row per sample (NaN before initialisation).

    Attributes
    ----------
    t_s : ndarray, shape (n,)
    quat : ndarray, shape (n, 4)
        ``R_world<-housing`` as scipy quaternions (x, y, z, w).
    heading_deg, pitch_deg, roll_deg : ndarray, shape (n,)
    heading_sigma_deg, tilt_sigma_deg, field_heading_sigma_deg, field_ratio, dip_deg : ndarray, shape (n,)
        As in :class:`Estimate`.
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
    field_heading_sigma_deg: np.ndarray
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
    matrices = np.full((n, 3, 3), np.nan)
    scalars = np.full((n, 5), np.nan)  # heading, tilt and field heading variance, field ratio, dip
    flags = np.zeros((n, 2), dtype=bool)
    gate = np.full(n, "absent", dtype=object)
    bias = None if gyro is None else np.full((n, 3), np.nan)
    accel_ok = np.all(np.isfinite(accel), axis=1)
    gyro_ok = None if gyro is None else np.all(np.isfinite(gyro), axis=1)
    rad2 = np.degrees(1.0) ** 2
    for i in range(n):  # the same work as AttitudeFilter.step, without building an Estimate per sample
        g = None if gyro is None or not gyro_ok[i] else gyro[i]
        if not filt._advance(float(t_s[i]), accel[i] if accel_ok[i] else None, g, field_h[i]):
            continue
        matrices[i] = filt._matrix
        p = filt._kf.P
        ratio, dip, mag_used, reason, accel_used = filt._last
        scalars[i] = (p[2, 2], (p[0, 0] + p[1, 1]) / 2.0, filt.field_heading_var if filt.gyro else np.nan,
                      ratio, dip)
        flags[i] = mag_used, accel_used
        gate[i] = reason
        if bias is not None:
            bias[i] = filt._bias
    ok = np.all(np.isfinite(matrices.reshape(n, 9)), axis=1)
    quat = np.full((n, 4), np.nan)
    angles = np.full((n, 3), np.nan)
    if ok.any():
        rotation = Rotation.from_matrix(matrices[ok])
        quat[ok] = rotation.as_quat()
        angles[ok] = np.column_stack(heading_pitch_roll(rotation))
    sigma = np.sqrt(scalars[:, :3] * rad2)
    return FilterTrack(t_s, quat, *angles.T, *sigma.T, scalars[:, 3], scalars[:, 4],
                       flags[:, 0], flags[:, 1], gate.astype(str), bias)


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
