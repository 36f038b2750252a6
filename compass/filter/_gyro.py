"""The gyro filter: a multiplicative (error-state) Kalman filter with gyro-bias states.

The per-sample path is closed-form arithmetic on Python floats (:mod:`._kalman` for the
covariance): no generic filterpy call, no numpy array and no Rotation object per sample.  The model is in :mod:`compass.filter`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.special import chdtri  # chi2.ppf(q, k) == chdtri(k, 1 - q), without importing scipy.stats (a second of start-up)

from ._base import _P0_ATTITUDE, AttitudeFilter, exp_matrix, mat_mul
from ._kalman import PackedCovariance, pack, predict_gyro, update_axis, update_heading, update_tilt
from ._gate import GateState
from ._lever import LeverState, acceleration, add_sample, leftover, restart, restart_block
from ._place import MAGNET, MAGNET_EVENT, PLACE_EVENT, REFERENCE, PlaceDetector, PlaceState
from ._rail import RAIL_MIN2, RAIL_WAIT_S, RailState, rail_variances
from ._records import _REST_RATE_SIGMA, _REST_TAU_S, Diagnostics, SkipCounts

__all__ = ["FIELD_HOLD_S", "GyroFilter", "GyroState"]

_REST_GYRO = math.radians(2.0)  # VQF's rest detector: rate deviation, rad/s
_REST_GYRO2 = _REST_GYRO**2
_REST_ACCEL = 0.05  # and specific-force deviation, fraction of g
_TURN_BOUND = float(chdtri(1, 0.001))  # a new place's North turned beyond its heading error: chi-square bound
_NORTH = {(True, True): " (North moves with it)", (False, True): " (within the heading error: North kept)",
          (False, False): " (North re-learnt from it: the last one was adopted on a timeout)"}
_ORTHONORMALISE_EVERY = 1000  # samples between re-orthonormalisations of the nominal matrix
_ANGLE_VAR_MAX = math.pi**2  # rad^2: an attitude error is an angle; the gyro's rail adds no more (compass.filter._rail)
FIELD_HOLD_S = 1.0
"""Longest a field reading repeated row after row is taken as the magnetometer's last conversion held, s: a 1 Hz
magnetometer's period.  Parts streamed for attitude convert at 8-100 Hz (AK8963's 8 Hz mode, QMC5883L's and
LIS3MDL's 10 Hz, HMC5883L's 15 Hz, BNO055's 20 Hz), and a limit within their period would fuse a held reading again
just before its successor, stale and with the field's weight.  Beyond it the field itself is taken to be constant: a
reading fused again after ``T`` s carries ``T`` s of the correlated error's weight, so a still constant field loses
nothing to the long limit."""


def heading_innovation(m: tuple, bx: float, by: float, bz: float, azimuth_rad: float = 0.0) -> float:
    """The field's heading innovation, rad: the azimuth (toward West) of the field ``(bx, by, bz)`` (in H) put
    into the world by ``m`` (``R_world<-housing``, row-major), less the reference's ``azimuth_rad``, negated
    (the heading error ``eps_z`` it measures), in (-pi, pi].

    To first order in the attitude error ``eps`` (``R_true = Exp(eps) R``) it is
    ``eps_z + tan(dip) (cos(a) eps_x + sin(a) eps_y)`` (``a = azimuth_rad``): a tilt about the field's
    horizontal direction turns its vertical part into the horizontal (``FilterConfig.field_update``).
    """
    innovation = -math.atan2(m[3] * bx + m[4] * by + m[5] * bz, m[0] * bx + m[1] * by + m[2] * bz)
    if azimuth_rad:
        innovation = (innovation + azimuth_rad + math.pi) % (2.0 * math.pi) - math.pi
    return innovation


@dataclass(slots=True)
class GyroState(PackedCovariance):
    """Everything the gyro filter carries from one sample to the next (readable, settable, resettable).

    Attributes
    ----------
    t_s : float or None
        Time of the last sample, s.
    matrix : tuple of 9 floats, or None
        Nominal ``R_world<-housing``, row-major; None before the first attitude.
    covariance : tuple of 21 floats
        Covariance of the error state ``(eps, db)`` (world-frame rotation, rad; housing-frame gyro
        bias error, rad/s), its upper triangle row by row (:attr:`covariance_matrix` for the 6x6 array).
    bias_rad_s : tuple of 3 floats
        Gyro bias in H, rad/s.
    rate_rad_s : tuple of 3 floats
        Last good gyro reading in H, rad/s (held when a sample has none).
    gravity : float or None
        |a| at rest, accelerometer units.
    acc_lp : tuple of 3 floats, or None
        The specific force low-passed in the inertial frame, seen in H.
    acc_lp_age_s : float
        Mean age of the low-pass's content, s (its sensitivity to a bias error).
    acc_lp_rate : tuple of 3 floats
        The second-order low-pass's other state: its output's rate of change in the inertial frame, seen
        in H, accelerometer units per second (zero for the first-order one).
    acc_residual : tuple of 3 floats
        The motion the low-pass leaves (specific force less the low-pass) low-passed at the motion's time scale
        (``FilterConfig.residual_in_band``), accelerometer units.
    age_lp : tuple of 2 floats
        The same low-pass run on the time since the start (its output and rate): the content's mean age is
        the time since the start less its output.
    residual_var : float
        Variance of what the low-pass leaves of the motion acceleration, (fraction of g)^2.
    rest_gyro, rest_acc : tuple of 3 floats, or None
        The rest detector's low-passed gyro and accelerometer.
    rest_s : float
        How long the rest detector has held, s.
    rest_pending : deque of tuples
        The gyro readings at rest not yet confirmed (``(gx, gy, gz, dt, rest_s)``, rad/s and s, the rest's
        duration when each was read, oldest first): each measures the bias once the rest has held
        ``FilterConfig.rest_confirm_s`` beyond it; dropped when the rest ends.
    start_rest : bool
        The rest detector has held since the attitude (re)started and none of its readings has measured the bias
        yet (``FilterConfig.start_rest_bias``, ``start_field_bias_hold``).
    accel_bad_s : float
        How long the accelerometer has been out of range, s.
    steps : int
        Propagation steps (for the periodic re-orthonormalisation).
    gate : GateState
    skipped : SkipCounts
    diagnostics : Diagnostics
        The latest sample's.
    since_start_s : float
        Time since the attitude (re)started, s: the bias is held for ``accel_time_constant_s``.
    t_back_s : float or None
        A time the last sample gave that left the clock: earlier than ``t_s`` (a corrupted clock, or the module
        restarting its clock), or over ``max_gap_s`` after it in the gyro filter (a corrupted clock, or a real gap);
        the next sample tells which.  Else None.
    place : PlaceState
        The place detector's window (``FilterConfig.follow_place``).
    lever : LeverState
        The lever arm's fit and the low-pass of its velocity (``FilterConfig.lever_arm``).
    rail : RailState
        The watch for a gyro axis held at its rail (:mod:`compass.filter._rail`).
    acc_lp_span_s : float
        Time since a run on the gyro's rail last restarted the inertial low-pass, s (inf: none since the start):
        until it reaches ``accel_time_constant_s`` the first-order low-pass is the mean of the samples since (the
        second-order one restarts and does not read it).
    field_sent : tuple of 3 floats, or None
        The last field reading as sent (None: none yet): one equal to it in all three components is that reading
        held, not a new one (:meth:`GyroFilter._fresh_field`).
    field_step_s : float
        Time since the last new field reading, s (the field's own step: its correlated error and the place
        window count time between new readings).
    """

    t_s: float | None
    matrix: tuple | None
    covariance: tuple
    bias_rad_s: tuple
    rate_rad_s: tuple
    gravity: float | None
    acc_lp: tuple | None
    acc_lp_age_s: float
    residual_var: float
    rest_gyro: tuple | None
    rest_acc: tuple | None
    rest_s: float
    accel_bad_s: float
    steps: int
    gate: GateState
    skipped: SkipCounts = field(default_factory=SkipCounts)
    diagnostics: Diagnostics = field(default_factory=Diagnostics)
    since_start_s: float = 0.0
    t_back_s: float | None = None
    place: PlaceState = field(default_factory=PlaceState)
    acc_lp_rate: tuple = (0.0, 0.0, 0.0)
    age_lp: tuple = (0.0, 0.0)
    acc_residual: tuple = (0.0, 0.0, 0.0)
    rest_pending: deque = field(default_factory=deque)
    start_rest: bool = True
    lever: LeverState = field(default_factory=LeverState)
    rail: RailState = field(default_factory=RailState)
    acc_lp_span_s: float = math.inf
    field_sent: tuple | None = None
    field_step_s: float = 0.0


class GyroFilter(AttitudeFilter):
    """The gyro filter (see :mod:`compass.filter`); ``AttitudeFilter(config, gyro=True)`` makes one."""

    gyro = True

    def _initial_state(self) -> GyroState:
        cfg = self.config
        p = pack(np.diag(_P0_ATTITUDE + (cfg.gyro_bias_sigma0**2,) * 3))
        return GyroState(None, None, p, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), cfg.gravity, None, 0.0, 0.0, None, None,
                         0.0, 0.0, 0, GateState.initial(cfg, self.coefficients))

    def _bind(self) -> None:
        self._gyro_range2 = self.config.gyro_range_rad_s**2
        self._x = [0.0] * 6  # the error state (eps, db), folded into the nominal state after each sample
        self._second_order = self.config.accel_lowpass_order == 2
        self._lever = self.config.lever_arm
        self._lp2_dt, self._lp2 = None, None  # the second-order low-pass's step and its coefficients
        self._place = PlaceDetector(self.config) if self.config.follow_place and self.config.gate else None
        # a decoupled field update injects its heading apart: one exponential of (eps_x, eps_y, eps_z) would
        # tilt by a second-order term eps_z * eps_tilt / 2
        self._split_injection = self.config.field_update != "kalman"

    @property
    def at_rest(self) -> bool:
        """The rest detector holds: the gyro reads its bias."""
        return self._s.rest_s >= self._REST_MIN_S

    @property
    def field_heading_var(self) -> float:
        return self.gate.field_heading_var(self._s.gate)

    @property
    def gyro_bias(self) -> tuple:
        return self._s.bias_rad_s

    @property
    def low_pass(self) -> tuple | None:
        """The specific force low-passed in the inertial frame, seen in H, accelerometer units (None before the start);
        with ``FilterConfig.lever_arm`` less what it leaves of the lever arm's acceleration: the tilt's measurement."""
        s = self._s
        if not self._lever or s.acc_lp is None or s.lever.low_pass is None:
            return s.acc_lp
        lx, ly, lz = s.acc_lp
        kx, ky, kz = leftover(s.lever, 0.0, self.config.accel_time_constant_s, self._rate())  # no step
        return lx - kx, ly - ky, lz - kz

    def update(self, t_s: float, accel, gyro, field_h) -> bool:
        begun = self._begin(t_s, accel, gyro, field_h)
        if begun is None:
            return False
        t_s, dt, a, b = begun
        d = self._s.diagnostics
        if dt > 0.0:
            self._propagate(dt)
            self._s.since_start_s += dt
            w = self._reading
            if w is not None and (w[3] >= RAIL_MIN2 or self._s.rail.last is not None) and self._rail(dt, w) \
                    and a is not None:
                self._restart_low_pass(a)
        if a is not None:
            if dt > 0.0:
                self._rest(dt, a)
            d.accel_used = self._tilt(dt, a)
        else:
            d.accel_used = False
            if self._lever:
                restart_block(self._s.lever)
        rail = self._s.rail
        if rail.tilt_open:
            rail.unmeasured_s = 0.0 if d.accel_used else rail.unmeasured_s + dt
        fresh, field_dt = self._fresh_field(dt, b)
        if fresh is not None or b is None:  # a held reading keeps the verdict it had when new
            self._heading(t_s, field_dt, fresh)
        self._inject()
        return True

    def _fresh_field(self, dt: float, b) -> tuple:
        """The field reading if it is a new one, and the time since the last new one, s.

        A magnetometer slower than the stream repeats its last reading until its next conversion (x-io's
        NGIMU log in ``../shared/data``: 80 % of rows; BROAD: 29 %).  A repeat is no new measurement: fused again,
        its noise would count as independent once per row, the heading would lean on the field as if it came at
        the stream's rate, and its age would grow unseen.  A reading equal to the last one in all three components
        is taken as that one held (``(None, dt)``; the row keeps that reading's verdict); a new one comes with the
        time since the last new one (absent readings count in it as held ones do).  A working sensor's noise makes
        three equal components by chance rare (a 0.15 uT count under 0.5 uT of noise: about 1e-3 per row at rest),
        and a chance repeat only drops a reading equal to one already used.  A reading held for
        :data:`FIELD_HOLD_S` is fused again, as a new one: held that long, the field itself is taken to be that
        constant (a still sensor whose noise is below its count, a noise-free simulation, a stuck sensor for the
        gate to judge).  The test is on the field as given: a correction that changes between the rows of one
        reading (a temperature compensation at each row's temperature, a hard-iron step) makes it look new, so
        ``compass live`` compensates a held reading at its own row's temperature.
        """
        s = self._s
        s.field_step_s += dt
        if b is None or (b[:3] == s.field_sent and s.field_step_s < FIELD_HOLD_S):
            return None, dt
        s.field_sent, step = b[:3], s.field_step_s
        s.field_step_s = 0.0
        return b, step

    # ------------------------------------------------------------------ the steps of one sample
    def _start(self, a, b) -> None:
        """Attitude from the two-vector solution (gravity first); attitude covariance reset, bias kept."""
        from ..attitude import two_vector_rotation

        s = self._s
        norm = math.sqrt(a[3])
        m = two_vector_rotation(np.array(a[:3]) / norm, np.array(b[:3]), s.gate.ref_dip_deg, 0.0)[0].as_matrix()
        if s.gate.ref_azimuth_rad:  # the reference's field lies at this azimuth, not along North
            m = Rotation.from_rotvec([0.0, 0.0, s.gate.ref_azimuth_rad]).as_matrix() @ m
        s.matrix = tuple(m.ravel().tolist())
        s.place.clear()
        s.gate.magnet_on_housing = False  # told against the attitude before: the place rule judges the new one again
        p0, p1, p2 = _P0_ATTITUDE
        s.covariance = (p0, 0.0, 0.0, 0.0, 0.0, 0.0, p1, 0.0, 0.0, 0.0, 0.0, p2, 0.0, 0.0, 0.0) + s.covariance[15:]
        self._x[:] = [0.0] * 6
        s.acc_lp, s.acc_lp_rate, s.age_lp = a[:3], (0.0, 0.0, 0.0), (0.0, 0.0)
        s.acc_lp_age_s, s.acc_lp_span_s = 0.0, math.inf
        restart(s.lever)
        s.rail.restart()
        s.residual_var, s.acc_residual = 0.0, (0.0, 0.0, 0.0)
        s.rest_gyro, s.rest_acc, s.rest_s = s.rate_rad_s, a[:3], 0.0
        s.rest_pending.clear()
        s.start_rest = True
        s.since_start_s = s.field_step_s = 0.0
        s.field_sent = None  # the start's field is a new reading whatever came before the restart

    def _restart_accel(self, a) -> None:
        s = self._s
        if s.acc_lp is not None:
            s.acc_lp, s.acc_lp_age_s, s.residual_var, s.acc_residual = a[:3], 0.0, 0.0, (0.0, 0.0, 0.0)
            s.acc_lp_rate, s.age_lp = (0.0, 0.0, 0.0), (s.since_start_s, 0.0)  # the low-pass content is new: age 0
            restart(s.lever)
        s.rest_acc, s.rest_s = a[:3], 0.0
        s.rest_pending.clear()
        s.start_rest = False

    def _propagate(self, dt: float) -> None:
        """Nominal attitude by the exact exponential of the bias-corrected rate; inertial low-pass; covariance."""
        s = self._s
        (gx, gy, gz), (bx, by, bz) = s.rate_rad_s, s.bias_rad_s
        wx, wy, wz = gx - bx, gy - by, gz - bz
        e = exp_matrix(wx * dt, wy * dt, wz * dt)
        m = mat_mul(s.matrix, e)
        s.steps += 1
        if s.steps % _ORTHONORMALISE_EVERY == 0:
            u, _, vt = np.linalg.svd(np.reshape(m, (3, 3)))
            m = tuple((u @ vt).ravel().tolist())
        s.matrix = m
        if s.acc_lp is not None:  # a vector fixed in the inertial frame, seen from the turned housing: e^T v
            vx, vy, vz = s.acc_lp
            s.acc_lp = (e[0] * vx + e[3] * vy + e[6] * vz, e[1] * vx + e[4] * vy + e[7] * vz,
                        e[2] * vx + e[5] * vy + e[8] * vz)
            if self._second_order:  # so is the low-pass's rate
                vx, vy, vz = s.acc_lp_rate
                s.acc_lp_rate = (e[0] * vx + e[3] * vy + e[6] * vz, e[1] * vx + e[4] * vy + e[7] * vz,
                                 e[2] * vx + e[5] * vy + e[8] * vz)
            elif self._lever and s.lever.low_pass is not None:  # and the lever arm's velocity's
                vx, vy, vz = s.lever.low_pass
                s.lever.low_pass = (e[0] * vx + e[3] * vy + e[6] * vz, e[1] * vx + e[4] * vy + e[7] * vz,
                                    e[2] * vx + e[5] * vy + e[8] * vz)
        # P <- F P F^T + Q, F = [[I, -R dt], [0, I]]
        c = self.coefficients
        q_att = (c.gyro_var + c.scale_var * (wx * wx + wy * wy + wz * wz)) * dt
        s.covariance = predict_gyro(s.covariance, m, dt, q_att, c.bias_walk_var * dt)

    def _rail(self, dt: float, w: tuple) -> bool:
        """The turn a gyro axis held at its rail hid, as attitude noise (:mod:`compass.filter._rail`): its variance
        on each world axis, uncorrelated; ``w`` the reading as sent, ``(x, y, z, |w|^2)``, rad/s.  True when an axis
        is on its rail."""
        s, g = self._s, self.config.gyro_matrix
        added = rail_variances(s.rail, w, dt)
        if added and not s.rail.tilt_open:
            s.rail.tilt_open, s.rail.unmeasured_s = True, 0.0
        for i, var in added:
            if g is not None:  # about the housing axis G e_i, of length |G e_i|
                var *= g[0][i] ** 2 + g[1][i] ** 2 + g[2][i] ** 2
            p = s.covariance
            # each diagonal entry stops at pi^2 (an angle); a non-negative diagonal added keeps P positive
            d0, d1, d2 = (min(var, max(0.0, _ANGLE_VAR_MAX - p[k])) for k in (0, 6, 11))
            s.covariance = (p[0] + d0,) + p[1:6] + (p[6] + d1,) + p[7:11] + (p[11] + d2,) + p[12:]
        return bool(added)

    def _rail_tilt_open(self) -> bool:
        """Whether the tilt a run on the gyro's rail left uncertain still moves the field's azimuth by more than the
        heading's settled sigma (``tan(dip)`` times it).  That error is the tilt state's, the same in every sample, not
        noise: field samples taken through it would settle the heading on it, so the heading waits for the
        accelerometer, while one measures the tilt (:data:`~compass.filter._rail.RAIL_WAIT_S`; :mod:`._rail`)."""
        c, rail = self.coefficients, self._s.rail
        rail.tilt_open = c.tan_dip2 * self.tilt_var > c.settled_var and rail.unmeasured_s < RAIL_WAIT_S
        return rail.tilt_open

    def _restart_low_pass(self, a) -> None:
        """The inertial low-pass from this sample on: its content was turned by the clipped gyro, so it carries the
        turn the rail hid and the tilt measurement is blind to it.  The first-order one is then the mean of the
        samples since (``acc_lp_span_s``) until ``accel_time_constant_s`` has passed (one sample's motion does not
        stay in it for a time constant); the motion's measured residual is kept."""
        s = self._s
        s.acc_lp, s.acc_lp_rate, s.age_lp = a[:3], (0.0, 0.0, 0.0), (s.since_start_s, 0.0)
        s.acc_lp_age_s, s.acc_lp_span_s = 0.0, 0.0
        restart(s.lever)

    def _rest(self, dt: float, a) -> None:
        """VQF's rest detector; at rest the gyro reading measures its bias, once the rest has held
        ``FilterConfig.rest_confirm_s`` beyond it (rest confirmed on both sides: the onset of a slow turn, below
        the detector's thresholds until its low-pass catches up, is not taken for the bias).  The rest the attitude
        starts in counts from its first reading (``FilterConfig.start_rest_bias``): no motion precedes it."""
        s = self._s
        alpha = -math.expm1(-dt / _REST_TAU_S)
        (gx, gy, gz), (rx, ry, rz) = s.rate_rad_s, s.rest_gyro
        rx, ry, rz = rx + alpha * (gx - rx), ry + alpha * (gy - ry), rz + alpha * (gz - rz)
        s.rest_gyro = (rx, ry, rz)
        ax, ay, az, _ = a
        cx, cy, cz = s.rest_acc
        cx, cy, cz = cx + alpha * (ax - cx), cy + alpha * (ay - cy), cz + alpha * (az - cz)
        s.rest_acc = (cx, cy, cz)
        limit2 = _REST_GYRO2
        steady = (rx * rx + ry * ry + rz * rz < limit2  # a slow steady turn is no rest (VQF's biasClip)
                  and (gx - rx) ** 2 + (gy - ry) ** 2 + (gz - rz) ** 2 < limit2
                  and (ax - cx) ** 2 + (ay - cy) ** 2 + (az - cz) ** 2 < (_REST_ACCEL * s.gravity) ** 2)
        if not steady:
            s.rest_s = 0.0
            s.rest_pending.clear()
            s.start_rest = False
            return
        s.rest_s += dt
        cfg = self.config
        if not cfg.rest_bias_estimation:
            return
        pending = s.rest_pending
        if s.rest_s >= self._REST_MIN_S or (s.start_rest and cfg.start_rest_bias):
            pending.append((gx, gy, gz, dt, s.rest_s))
        if s.rest_s < self._REST_MIN_S:
            return
        while pending and s.rest_s - pending[0][4] >= self.config.rest_confirm_s:  # by time: the rate may change
            self._rest_reading(*pending.popleft()[:4])

    def _rest_reading(self, gx: float, gy: float, gz: float, dt: float) -> None:
        """One confirmed gyro reading at rest (rad/s, over ``dt`` s) as a measurement of the bias."""
        s = self._s
        rx, ry, rz = s.rest_gyro
        # the low-passed rate must also agree with the bias estimate (3 sigma): once the bias is known,
        # the onset of a slow turn is not taken for a bias change
        p, (bx, by, bz), x = s.covariance, s.bias_rad_s, self._x
        bx, by, bz = bx + x[3], by + x[4], bz + x[5]  # with what this sample's earlier readings taught (a start's burst)
        floor = self.coefficients.rest_floor_var
        if (rx - bx) ** 2 > 9.0 * (p[15] + floor) or (ry - by) ** 2 > 9.0 * (p[18] + floor) \
                or (rz - bz) ** 2 > 9.0 * (p[20] + floor):
            return
        var = self.coefficients.rest_rate_var_density / dt + _REST_RATE_SIGMA**2
        s.start_rest = False
        b0, b1, b2 = s.bias_rad_s  # update_axis takes the innovation against the nominal bias
        p = update_axis(p, x, 3, gx - b0, var)
        p = update_axis(p, x, 4, gy - b1, var)
        s.covariance = update_axis(p, x, 5, gz - b2, var)

    def _tilt(self, dt: float, a) -> bool:
        """Tilt from the specific force low-passed in the inertial frame (:mod:`compass.filter`).

        The measurement ``R u - z`` (``u`` the low-passed direction) is taken in the world frame, where
        its model ``[z]x eps + age [z]x R db`` has two rows; its third, along the vertical, carries no
        information (the same posterior as the three housing-frame rows with isotropic noise).
        """
        s, cfg, c = self._s, self.config, self.coefficients
        g = s.gravity
        ax, ay, az, _ = a
        lx, ly, lz = s.acc_lp
        if dt > 0.0:
            if self._second_order:
                lx, ly, lz = self._low_pass2(dt, ax, ay, az)
            else:
                alpha = -math.expm1(-dt / cfg.accel_time_constant_s)
                if s.acc_lp_span_s < cfg.accel_time_constant_s:  # restarted by the gyro's rail: the mean since
                    s.acc_lp_span_s += dt
                    alpha = max(alpha, dt / s.acc_lp_span_s)
                lx, ly, lz = lx + alpha * (ax - lx), ly + alpha * (ay - ly), lz + alpha * (az - lz)
                s.acc_lp = (lx, ly, lz)
                s.acc_lp_age_s = (1.0 - alpha) * (s.acc_lp_age_s + dt)
                if self._lever:  # the arm's leftover out of the measurement, its acceleration out of the motion
                    lx, ly, lz = self._lever_step(dt, alpha, a, lx, ly, lz)
                    px, py, pz = acceleration(s.lever, dt, self._rate())
                    ax, ay, az = ax - px, ay - py, az - pz
            lp_norm = math.sqrt(lx * lx + ly * ly + lz * lz)
            if cfg.residual_in_band:  # only what varies on the motion's time scale: a vibration or a tap is not left
                beta = -math.expm1(-dt * 2.0 * math.pi / cfg.motion_time_s)
                rx, ry, rz = s.acc_residual
                rx, ry, rz = rx + beta * (ax - lx - rx), ry + beta * (ay - ly - ry), rz + beta * (az - lz - rz)
                s.acc_residual = (rx, ry, rz)
                raw2 = rx * rx + ry * ry + rz * rz
            else:
                raw2 = (ax - lx) ** 2 + (ay - ly) ** 2 + (az - lz) ** 2
            residual = (lp_norm / g - 1.0) ** 2 + raw2 / (g * g) * c.attenuation2
            s.residual_var += -math.expm1(-dt / cfg.motion_time_s) * (residual - s.residual_var)
        else:
            if self._lever:  # no step: the lever arm's leftover as it stands
                lx, ly, lz = self._lever_step(0.0, 0.0, a, lx, ly, lz)
            lp_norm = math.sqrt(lx * lx + ly * ly + lz * lz)
        if not lp_norm > 0 or abs(lp_norm / g - 1.0) > cfg.accel_tolerance:
            return False
        var = c.accel_var
        if dt > 0.0 and cfg.motion_adaptive_accel:
            var += s.residual_var * 2.0 * cfg.motion_time_s / dt
        m = s.matrix
        ux, uy, uz = lx / lp_norm, ly / lp_norm, lz / lp_norm
        d0 = m[0] * ux + m[1] * uy + m[2] * uz  # R u - z, x and y
        d1 = m[3] * ux + m[4] * uy + m[5] * uz
        age = s.acc_lp_age_s
        # the bias is held (not estimated from the tilt) while the low-pass still carries its start: a start
        # error leaving it would otherwise pass for a turn the gyro did not read, i.e. for a bias
        hold = cfg.start_bias_hold and s.since_start_s < cfg.accel_time_constant_s
        s.covariance = update_tilt(s.covariance, self._x, (-age * m[3], -age * m[4], -age * m[5]), d0,
                                   (age * m[0], age * m[1], age * m[2]), d1, var, hold)
        return True

    def _lever_step(self, dt: float, alpha: float, a, lx: float, ly: float, lz: float) -> tuple:
        """The lever arm's fit takes this sample, held ``dt`` s; the low-pass ``(lx, ly, lz)`` (stepped with gain
        ``alpha``; 0 and 0: no step) less what it leaves of the lever arm's acceleration
        (:mod:`compass.filter._lever`)."""
        s = self._s
        m, g, w = s.matrix, s.gravity, self._rate()
        add_sample(s.lever, dt, w, (a[0] - g * m[6], a[1] - g * m[7], a[2] - g * m[8]))
        kx, ky, kz = leftover(s.lever, alpha, self.config.accel_time_constant_s, w)
        return lx - kx, ly - ky, lz - kz

    def _rate(self) -> tuple:
        """The bias-corrected rate, rad/s (H)."""
        (gx, gy, gz), (bx, by, bz) = self._s.rate_rad_s, self._s.bias_rad_s
        return gx - bx, gy - by, gz - bz

    def _low_pass2(self, dt: float, ax: float, ay: float, az: float) -> tuple:
        """One step of the second-order (Butterworth) inertial low-pass; its output, also kept in the state.

        ``y'' + 2 s y' + 2 s^2 y = 2 s^2 x`` with ``s = 1 / accel_time_constant_s`` (poles ``-s +- i s``:
        Butterworth, DC group delay ``tau``, the first-order one's mean age), discretised exactly with the
        sample held over the step: ``(y, y') <- Phi (y, y') + (I - Phi) (x, 0)``.  The same filter run on
        the time since the start gives the content's mean age (the ramp's lag).
        """
        s = self._s
        if dt != self._lp2_dt:
            sig = 1.0 / self.config.accel_time_constant_s
            decay, c, sn = math.exp(-sig * dt), math.cos(sig * dt), math.sin(sig * dt)
            self._lp2_dt = dt
            self._lp2 = (decay * (c + sn), decay * sn / sig, -2.0 * sig * decay * sn, decay * (c - sn))
        f00, f01, f10, f11 = self._lp2
        g0 = 1.0 - f00
        (lx, ly, lz), (vx, vy, vz) = s.acc_lp, s.acc_lp_rate
        dx, dy, dz = ax - lx, ay - ly, az - lz
        s.acc_lp_rate = (f11 * vx - f10 * dx, f11 * vy - f10 * dy, f11 * vz - f10 * dz)
        lx, ly, lz = lx + g0 * dx + f01 * vx, ly + g0 * dy + f01 * vy, lz + g0 * dz + f01 * vz
        s.acc_lp = (lx, ly, lz)
        (ty, tv), since = s.age_lp, s.since_start_s
        d = since - ty
        s.age_lp = (ty + g0 * d + f01 * tv, f11 * tv - f10 * d)
        s.acc_lp_age_s = since - s.age_lp[0]
        return lx, ly, lz

    def _heading(self, t_s: float, dt: float, b) -> None:
        """Gate the field; when accepted, correct the heading (only) with its azimuth.  ``dt`` is the time since the
        last new field reading, s (:meth:`_fresh_field`)."""
        s, c, d = self._s, self.coefficients, self._s.diagnostics
        if b is None:
            d.field_ratio, d.dip_deg, d.mag_used, d.gate = math.nan, math.nan, False, "absent"
            return
        m = s.matrix
        bx, by, bz, b2 = b
        tau = self.config.mag_latency_s
        if tau > 0.0:  # the field read tau late: a world-fixed vector turns in H as dh/dt = h x omega
            (gx, gy, gz), (cx, cy, cz) = s.rate_rad_s, s.bias_rad_s
            wx, wy, wz = gx - cx, gy - cy, gz - cz
            bx, by, bz = bx + tau * (by * wz - bz * wy), by + tau * (bz * wx - bx * wz), bz + tau * (bx * wy - by * wx)
            b = (bx, by, bz, b2)
        if self._place is not None and dt > 0.0:
            self._follow_place(dt, b)
        innovation = heading_innovation(m, bx, by, bz, s.gate.ref_azimuth_rad)
        d.mag_used = self._gate_field(t_s, dt, b, innovation) == "ok"
        if d.mag_used and s.rail.tilt_open and self._rail_tilt_open():
            d.mag_used, d.gate = False, "rail"
        if d.mag_used:
            p = s.covariance
            mode = self.config.field_update
            # the tilt's share of the measured azimuth: white noise in var, or (heading-tilt) in the model
            tilt_in_model = mode == "heading-tilt"
            var = c.yaw_var if tilt_in_model else c.yaw_var + c.tan_dip2 * (p[0] + p[6]) / 2.0
            if dt > 0.0:  # correlated over T: 2 T / dt readings make one independent one (one at most)
                span = 2.0 * self.config.field_error_time_s
                var += self.gate.field_heading_var(s.gate) * span / min(dt, span)
            # the start's bias is held (FilterConfig.start_field_bias_hold): the field's heading error would pass for it
            hold = self.config.start_field_bias_hold and self._start_holds_bias()
            if mode == "kalman":
                s.covariance = update_axis(p, self._x, 2, innovation, var, hold)
                return
            tilt = (0.0, 0.0)
            if tilt_in_model:  # the azimuth moves by tan(dip) times the tilt about the field's horizontal direction
                t, azimuth = math.tan(math.radians(s.gate.ref_dip_deg)), s.gate.ref_azimuth_rad
                tilt = (t * math.cos(azimuth), t * math.sin(azimuth))
            s.covariance = update_heading(p, self._x, innovation, var, None if mode == "no-tilt" else (m[6], m[7], m[8]),
                                          tilt, hold)

    def _start_holds_bias(self) -> bool:
        """The field's heading row does not move the bias: the tilt's hold (``accel_time_constant_s``) is not over, or
        the rest the attitude started in holds and has not measured the bias yet (``FilterConfig.start_field_bias_hold``)."""
        s = self._s
        return (self.config.start_bias_hold and s.since_start_s < self.config.accel_time_constant_s) or (
            s.start_rest and s.rest_s > 0.0 and self.config.rest_bias_estimation)

    def _follow_place(self, dt: float, b) -> None:
        """The place detector's window; a new place's field becomes the reference (:mod:`compass.filter._place`)."""
        s = self._s
        g = s.gate
        (gx, gy, gz), (cx, cy, cz) = s.rate_rad_s, s.bias_rad_s
        rate2 = (gx - cx) ** 2 + (gy - cy) ** 2 + (gz - cz) ** 2
        if not self._place.add(s.place, dt, s.matrix, b, g.world_field(), rate2):
            return
        c, p = self.coefficients, s.covariance
        direction_var = max(c.env_floor_var * c.cos_dip2, g.dip_excess_var)
        move = self._place.judge(s.place, g.ref_norm, g.ref_dip_deg, direction_var, self.tilt_var, self.heading_var,
                                 (c.gyro_var, c.scale_var, max(p[15], p[18], p[20])))
        if move is None or (move.kind == REFERENCE and not g.magnet_on_housing):
            return
        if move.kind == REFERENCE:
            g.magnet_on_housing = False
            self.events.append(f"the field is the reference's again (|B| {move.field_norm:.4g}, dip {move.dip_deg:.1f} "
                               f"deg, steady in the world frame over {self.config.place_window_s:g} s): used again")
            return
        if move.kind == MAGNET:
            if not g.magnet_on_housing:
                g.magnet_on_housing = True
                self.events.append(
                    f"{MAGNET_EVENT} (steady in the housing frame over {self.config.place_window_s:g} s while it "
                    f"turned: {move.magnet_rms:.3g} rms within {move.magnet_bound_rms:.3g}; a new place would leave "
                    f"{move.place_rms:.3g}, beyond {move.place_bound_rms:.3g}): a magnet or iron on the housing, "
                    f"|B| {move.field_norm:.4g} against {g.ref_norm:.4g}: never adopted, and a sample used only where "
                    f"it agrees with the gyro's heading, until the reference's field is back or a new place is seen "
                    f"(the product's own iron: calibrate the installation, compass calibrate --base)")
            return
        # North moves with the field only where the turn is beyond what the heading's own error and the field's
        # explain (chi-square, one degree of freedom): otherwise it is that error, which the field then corrects
        turn = (move.azimuth_rad - g.ref_azimuth_rad + math.pi) % (2.0 * math.pi) - math.pi
        turned = g.north_from_gyro and turn * turn > _TURN_BOUND * (self.heading_var + self.gate.field_heading_var(g))
        east = -math.degrees(turn)  # azimuths count toward West
        self.events.append(
            f"{PLACE_EVENT}: |B| {g.ref_norm:.4g} -> {move.field_norm:.4g}, dip {g.ref_dip_deg:.1f} -> "
            f"{move.dip_deg:.1f} deg, its North {east:+.1f} deg east of the last one's by the gyro's heading"
            f"{_NORTH[turned, g.north_from_gyro]}: a new "
            f"place (steady in the world frame over {self.config.place_window_s:g} s while the housing turned: "
            f"{move.place_rms:.3g} rms within {move.place_bound_rms:.3g}; a magnet on the housing would leave "
            f"{move.magnet_rms:.3g}, beyond {move.magnet_bound_rms:.3g}), the new reference")
        g.ref_norm, g.ref_dip_deg, g.magnet_on_housing = move.field_norm, move.dip_deg, False
        if turned:
            g.ref_azimuth_rad = move.azimuth_rad
        elif not g.north_from_gyro:  # the heading came from an unverified field: the new one re-teaches it at once
            g.ref_azimuth_rad = 0.0
            s.covariance = p[:11] + (p[11] + c.adopt_var,) + p[12:]
        g.rejected_since_s = None
        s.place.clear()

    def _reference_moved(self) -> None:
        self._s.place.clear()

    def _inject(self) -> None:
        """Fold the error state into the nominal attitude and bias, reset it to zero."""
        s, x = self._s, self._x
        e0, e1, e2, d0, d1, d2 = x
        if self._split_injection:  # the tilt's turn, then the heading's about the world vertical (which keeps the tilt)
            if e0 or e1:
                s.matrix = mat_mul(exp_matrix(e0, e1, 0.0), s.matrix)
            if e2:
                s.matrix = mat_mul(exp_matrix(0.0, 0.0, e2), s.matrix)
        elif e0 or e1 or e2:
            s.matrix = mat_mul(exp_matrix(e0, e1, e2), s.matrix)
        if d0 or d1 or d2:
            bx, by, bz = s.bias_rad_s
            s.bias_rad_s = (bx + d0, by + d1, bz + d2)
            if s.acc_lp is not None:  # the part of the low-pass's turn error that db explains
                (vx, vy, vz), age = s.acc_lp, s.acc_lp_age_s
                s.acc_lp = (vx - age * (vy * d2 - vz * d1), vy - age * (vz * d0 - vx * d2),
                            vz - age * (vx * d1 - vy * d0))
        x[:] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
