"""The two-vector filter: a Kalman filter on the TRIAD (gravity first) solutions, without a gyro."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ._base import _P0_ATTITUDE, AttitudeFilter, exp_matrix, mat_mul
from ._kalman import PackedCovariance, pack, unpack, update_axis
from ._gate import GateState
from ._records import Diagnostics, SkipCounts

__all__ = ["TwoVectorFilter", "TwoVectorState"]

_P0_RATE = 0.5**2  # initial angular rate variance, (rad/s)^2


@dataclass(slots=True)
class TwoVectorState(PackedCovariance):
    """Everything the two-vector filter carries from one sample to the next.

    Attributes
    ----------
    t_s : float or None
    matrix : tuple of 9 floats, or None
        Nominal ``R_world<-housing``, row-major.
    covariance : tuple of 21 floats
        Covariance of ``(eps, omega)`` (world-frame rotation error, rad; world-frame rate, rad/s),
        its upper triangle row by row (:attr:`covariance_matrix` for the 6x6 array).
    rate_rad_s : list of 3 floats
        The world-frame angular rate estimate, rad/s.
    gravity : float or None
    accel_bad_s : float
    rest_s : float
        Always 0 (the two-vector filter has no rest detector).
    gate : GateState
    skipped : SkipCounts
    diagnostics : Diagnostics
    t_back_s : float or None
        A time the last sample gave that left the clock: earlier than ``t_s`` (a corrupted clock, or the module
        restarting its clock), or over ``max_gap_s`` after it in the gyro filter (a corrupted clock, or a real gap);
        the next sample tells which.  Else None.
    """

    t_s: float | None
    matrix: tuple | None
    covariance: tuple
    rate_rad_s: list
    gravity: float | None
    accel_bad_s: float
    rest_s: float
    gate: GateState
    skipped: SkipCounts = field(default_factory=SkipCounts)
    diagnostics: Diagnostics = field(default_factory=Diagnostics)
    t_back_s: float | None = None


class TwoVectorFilter(AttitudeFilter):
    """The two-vector filter (see :mod:`compass.filter`); ``AttitudeFilter(config, gyro=False)`` makes one.

    State ``(eps, omega)``, ``omega`` the world-frame angular rate (rad/s), a first-order
    Gauss-Markov process driven by white angular acceleration (filterpy's
    ``Q_continuous_white_noise``); the measurement is the rotation vector from the estimate to the
    two-vector solution, world frame.  While the gate rejects the field this filter has no heading
    information: the heading coasts to a stop (rate correlation time ``rate_tau_s``).
    """

    gyro = False

    def _initial_state(self) -> TwoVectorState:
        cfg = self.config
        p = pack(np.diag(_P0_ATTITUDE + (_P0_RATE,) * 3))
        return TwoVectorState(None, None, p, [0.0, 0.0, 0.0], cfg.gravity, 0.0, 0.0,
                              GateState.initial(cfg, self.coefficients))

    def _bind(self) -> None:
        self._f = np.eye(6)
        self._q = np.zeros((6, 6))
        self._dt = None

    def update(self, t_s: float, accel, gyro, field_h) -> bool:
        begun = self._begin(t_s, accel, gyro, field_h)  # the gyro is not used (gyro is False)
        if begun is None:
            return False
        t_s, dt, a, b = begun
        s, cfg = self._s, self.config
        d = s.diagnostics
        if dt > 0.0:
            self._predict(dt)
        x = s.rate_rad_s
        err = [0.0, 0.0, 0.0] + x
        if a is not None and b is not None and b[3] > 0.0 and abs(math.sqrt(a[3]) / s.gravity - 1.0) <= cfg.accel_tolerance:
            self._measure(t_s, a, b, err)
            d.accel_used = True
        else:
            self._field_only(t_s, dt, b)
            d.accel_used = False
        s.rate_rad_s = err[3:]
        if err[0] or err[1] or err[2]:
            s.matrix = mat_mul(exp_matrix(err[0], err[1], err[2]), s.matrix)
        return True

    def _start(self, a, b) -> None:
        from ..attitude import two_vector_rotation

        s = self._s
        m = two_vector_rotation(np.array(a[:3]) / math.sqrt(a[3]), np.array(b[:3]), s.gate.ref_dip_deg, 0.0)[0]
        s.matrix = tuple(m.as_matrix().ravel().tolist())
        s.covariance = pack(np.diag(_P0_ATTITUDE + (_P0_RATE,) * 3))
        s.rate_rad_s = [0.0, 0.0, 0.0]

    def _predict(self, dt: float) -> None:
        """The rate model moves the attitude error (folded into the nominal attitude); covariance."""
        s, cfg = self._s, self.config
        if dt != self._dt:
            decay = math.exp(-dt / cfg.rate_tau_s)
            self._f[:3, 3:] = np.eye(3) * cfg.rate_tau_s * (1.0 - decay)
            self._f[3:, 3:] = np.eye(3) * decay
            from filterpy.common import Q_continuous_white_noise  # 0.5 s to import: only when dt changes

            self._q = Q_continuous_white_noise(dim=2, dt=dt, spectral_density=cfg.angular_accel_noise**2,
                                               block_size=3, order_by_dim=False)
            self._dt, self._moved, self._decay = dt, cfg.rate_tau_s * (1.0 - decay), decay
        s.covariance = pack(self._f @ unpack(s.covariance) @ self._f.T + self._q)
        wx, wy, wz = s.rate_rad_s
        s.matrix = mat_mul(exp_matrix(self._moved * wx, self._moved * wy, self._moved * wz), s.matrix)
        s.rate_rad_s = [self._decay * wx, self._decay * wy, self._decay * wz]

    def _measure(self, t_s: float, a, b, err: list) -> None:
        """Tilt rows always, the heading row when the gate lets the field in."""
        from ..attitude import two_vector_rotation

        s, c, d = self._s, self.coefficients, self._s.diagnostics
        rotation = Rotation.from_matrix(np.reshape(s.matrix, (3, 3)))
        solution = two_vector_rotation(np.array(a[:3]) / math.sqrt(a[3]), np.array(b[:3]), s.gate.ref_dip_deg, 0.0)[0]
        z = (solution * rotation.inv()).as_rotvec().tolist()
        reason = self._gate_field(t_s, 0.0, b, z[2])
        p, tilt_var = s.covariance, self.config.accel_noise**2
        p = update_axis(p, err, 0, z[0], tilt_var)
        s.covariance = p = update_axis(p, err, 1, z[1], tilt_var)
        d.mag_used = reason == "ok"
        if d.mag_used:
            s.covariance = update_axis(p, err, 2, z[2], c.yaw_var + c.tan_dip2 * tilt_var)

    def _field_only(self, t_s: float, dt: float, b) -> None:
        """Without a usable accelerometer the field is only gated (for the diagnostics), never used."""
        d = self._s.diagnostics
        d.mag_used = False
        if b is None:
            d.field_ratio, d.dip_deg, d.gate = math.nan, math.nan, "absent"
            return
        m = self._s.matrix
        innovation = -math.atan2(m[3] * b[0] + m[4] * b[1] + m[5] * b[2], m[0] * b[0] + m[1] * b[1] + m[2] * b[2])
        self._gate_field(t_s, dt, b, innovation)
