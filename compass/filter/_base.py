"""What the gyro and the two-vector filter share: records, input screening, the gate, the output."""

from __future__ import annotations

import copy
import math

import numpy as np

from ._gate import MagneticGate
from ._records import Diagnostics, Estimate, FilterCoefficients, FilterConfig, SkipCounts

__all__ = ["AttitudeFilter"]

_P0_ATTITUDE = (0.05**2, 0.05**2, 0.2**2)  # initial error variance of tilt and heading, rad^2
_RELEARN_S = 1.0  # accelerometer out of range this long, gravity not configured: re-learn gravity


def exp_matrix(x: float, y: float, z: float) -> tuple:
    """Rotation matrix (row-major 9-tuple) of the rotation vector ``(x, y, z)`` (rad), Rodrigues' formula."""
    th2 = x * x + y * y + z * z
    if th2 < 1e-10:
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    c = 1.0 - b * th2
    return (c + b * x * x, b * x * y - a * z, b * x * z + a * y,
            b * x * y + a * z, c + b * y * y, b * y * z - a * x,
            b * x * z - a * y, b * y * z + a * x, c + b * z * z)


def mat_mul(m: tuple, n: tuple) -> tuple:
    """Product of two row-major 3x3 matrices given as 9-tuples."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = m
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = n
    return (a0 * b0 + a1 * b3 + a2 * b6, a0 * b1 + a1 * b4 + a2 * b7, a0 * b2 + a1 * b5 + a2 * b8,
            a3 * b0 + a4 * b3 + a5 * b6, a3 * b1 + a4 * b4 + a5 * b7, a3 * b2 + a4 * b5 + a5 * b8,
            a6 * b0 + a7 * b3 + a8 * b6, a6 * b1 + a7 * b4 + a8 * b7, a6 * b2 + a7 * b5 + a8 * b8)


def heading_pitch_roll_deg(m: tuple) -> tuple[float, float, float]:
    """SPEC section 1 heading [0, 360), pitch, roll (-180, 180] from ``R_world<-housing`` (row-major 9-tuple).

    The closed form of :func:`compass.frames.heading_pitch_roll` (scipy's ``as_euler("ZYX")``) for
    one rotation, away from pitch = +-90 degrees, without building a Rotation.
    """
    heading = math.degrees(-math.atan2(m[3], m[0])) % 360.0
    if heading >= 360.0:
        heading = 0.0
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, m[6]))))
    roll = math.degrees(math.atan2(m[7], m[8]))
    return heading, pitch, (roll + 360.0 if roll <= -180.0 else roll)


class AttitudeFilter:
    """Causal attitude filter, one sample at a time (see :mod:`compass.filter`).

    ``AttitudeFilter(config, gyro=True)`` makes a :class:`~compass.filter.GyroFilter`, ``gyro=False``
    a :class:`~compass.filter.TwoVectorFilter` (as ``pathlib.Path`` makes a ``PosixPath``).

    Three records, as VQF keeps them: :attr:`config` (what a user tunes), :attr:`coefficients`
    (derived once), :attr:`state` (what changes each sample: a copy when read, copied in when set,
    :meth:`reset` restores the initial one).  :meth:`update` is the lean per-sample step (VQF's
    ``update``); :meth:`estimate` reads the output; :meth:`step` does both; :func:`run_filter`
    runs :meth:`update` over arrays.

    Bad input is screened before anything is fused: a non-finite time, or one that goes back, skips
    the sample; a non-finite or out-of-range (``FilterConfig.*_range``) gyro, accelerometer or field reading is
    skipped as if absent (the gyro's last good rate is held), counted by reason in
    :attr:`skipped` and named in :attr:`diagnostics`; the next good reading is used as usual.

    Attributes
    ----------
    config : FilterConfig
    coefficients : FilterCoefficients
    gate : MagneticGate
    events : list of str
        Notes on restarts and reference changes since the last :meth:`drain_events`.

    Examples
    --------
    >>> f = AttitudeFilter(FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1), gyro=True)
    >>> up, b = np.array([0, 0, 9.81]), np.array([25.0, 0.0, -43.3])   # level, facing north
    >>> est = f.step(0.0, up, np.zeros(3), b)
    >>> round(est.heading_deg, 3) % 360, est.mag_used
    (0.0, True)
    >>> f.step(0.01, up, [1e300, 0.0, 0.0], b).skipped, f.skipped.gyro_out_of_range
    ('gyro out of range', 1)
    """

    gyro: bool
    _kinds: dict[bool, type] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        AttitudeFilter._kinds[cls.gyro] = cls

    def __new__(cls, config: FilterConfig, *, gyro: bool | None = None):
        if cls is AttitudeFilter:
            if gyro is None:
                raise TypeError("AttitudeFilter(config, gyro=...) needs gyro=True or False")
            cls = AttitudeFilter._kinds[bool(gyro)]
        return super().__new__(cls)

    def __init__(self, config: FilterConfig, *, gyro: bool | None = None):
        if gyro is not None and bool(gyro) != self.gyro:
            raise ValueError(f"{type(self).__name__} is the gyro={self.gyro} filter, got gyro={gyro}")
        self.config = config
        self.coefficients = FilterCoefficients.from_config(config)
        self.gate = MagneticGate(config, self.coefficients)
        self.events: list[str] = []
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the initial state (no attitude, the configured reference field, zero bias)."""
        self._s = self._initial_state()
        self._prime = None
        self._bind()

    def prime(self, gravity: float | None, up_h, field_h) -> None:
        """Start values from a window of samples (:class:`~compass.filter.FilterStart`), not the first row.

        Parameters
        ----------
        gravity : float or None
            |a| that 1 g reads, accelerometer units (ignored when ``config.gravity`` is set; None:
            learnt from the first sample as without a window).
        up_h : array_like, shape (3,), or None
            Unit up direction in H at the next sample.
        field_h : array_like, shape (3,), or None
            Field in H at the next sample, field units.  With ``up_h`` it gives the first attitude
            (and the gyro filter's inertial low-pass its start); a later restart after a gap starts
            from its own row.
        """
        if gravity is not None and self.config.gravity is None:
            if not (math.isfinite(gravity) and gravity > 0):
                raise ValueError(f"gravity must be a positive number, got {gravity!r}")
            self._s.gravity = float(gravity)
        if up_h is None or field_h is None:
            self._prime = None
            return
        up, field = tuple(float(v) for v in up_h), tuple(float(v) for v in field_h)
        if not (all(map(math.isfinite, up + field)) and any(up) and any(field)):
            raise ValueError(f"the start's up and field directions must be finite and non-zero, got {up} and {field}")
        self._prime = (up, field)

    @property
    def state(self):
        """A copy of the filter's state record (``GyroState`` or ``TwoVectorState``)."""
        return copy.deepcopy(self._s)

    @state.setter
    def state(self, value) -> None:
        expected = type(self._initial_state())
        if type(value) is not expected:
            raise TypeError(f"expected a {expected.__name__}, got {type(value).__name__}")
        value = copy.deepcopy(value)
        if np.shape(value.covariance) != (21,) or not np.all(np.isfinite(value.covariance)):
            raise ValueError("state.covariance must be 21 finite floats (the packed upper triangle)")
        value.covariance = tuple(float(v) for v in value.covariance)
        self._s = value
        self._bind()

    def _bind(self) -> None:
        """Views of the state's covariance used in place on the per-sample path."""

    @property
    def initialised(self) -> bool:
        return self._s.matrix is not None

    @property
    def diagnostics(self) -> Diagnostics:
        """What the latest sample did (updated in place: copy it to keep it)."""
        return self._s.diagnostics

    @property
    def skipped(self) -> SkipCounts:
        """Bad-input skips so far, by reason."""
        return self._s.skipped

    @property
    def matrix(self) -> tuple | None:
        """``R_world<-housing`` as a row-major 9-tuple (None before the first attitude)."""
        return self._s.matrix

    @property
    def heading_var(self) -> float:
        """Variance of the world-frame attitude error about the vertical, rad^2."""
        return self._s.covariance[11]

    @property
    def tilt_var(self) -> float:
        """Mean variance of the world-frame attitude error about the two horizontal axes, rad^2."""
        p = self._s.covariance
        return (p[0] + p[6]) / 2.0

    @property
    def field_heading_var(self) -> float:
        """Heading error variance of the accepted field itself, rad^2 (NaN without a gyro)."""
        return math.nan

    @property
    def gyro_bias(self) -> tuple | None:
        """Estimated gyro bias in H, rad/s (None without a gyro)."""
        return None

    def drain_events(self) -> list[str]:
        """Return and clear the pending event notes."""
        events, self.events = self.events, []
        return events

    # ------------------------------------------------------------------ per sample
    def step(self, t_s: float, accel, gyro, field_h) -> Estimate | None:
        """Process one sample and return the estimate.

        Parameters
        ----------
        t_s : float
            Sample time, seconds (non-decreasing: a sample whose time goes back, or in the running gyro filter jumps
            over ``max_gap_s`` ahead, is skipped, and the next one tells a corrupted time from a restarted clock or
            a real gap: :meth:`_time_step`).
        accel : array_like, shape (3,), or None
            Accelerometer in H, any unit (specific force, +up at rest).
        gyro : array_like, shape (3,), or None
            Angular rate of H in H, rad/s; None holds the last rate (gyro filter) and is ignored
            by the two-vector filter.
        field_h : array_like, shape (3,), or None
            Field in H, field units (e.g. :meth:`compass.model.SensorModel.field`).

        Returns
        -------
        Estimate or None
            None until the first sample with an accelerometer and a field reading initialises the
            attitude, and for a sample with a non-finite time or one kept aside (gone back, jumped ahead).
        """
        if not self.update(t_s, accel, gyro, field_h):
            return None
        return self.estimate()

    def update(self, t_s: float, accel, gyro, field_h) -> bool:
        """:meth:`step` without building the :class:`Estimate`; False while there is no attitude."""
        raise NotImplementedError

    def estimate(self) -> Estimate:
        """The :class:`Estimate` after the latest sample (the filter must be initialised)."""
        s = self._s
        m, d = s.matrix, s.diagnostics
        heading, pitch, roll = heading_pitch_roll_deg(m)
        return Estimate(s.t_s, m, heading, pitch, roll, math.degrees(math.sqrt(self.heading_var)),
                        math.degrees(math.sqrt(self.tilt_var)), math.degrees(math.sqrt(self.field_heading_var)),
                        d.field_ratio, d.dip_deg, d.mag_used, d.gate, d.accel_used, self.gyro_bias, d.skipped)

    def _begin(self, t_s, accel, gyro, field_h):
        """What every :meth:`update` starts with: the time step, the screened readings, a (re)start.

        Returns
        -------
        (t_s, dt, a, b) or None
            ``t_s`` as a Python float, ``dt`` the step (0 on a (re)start; the filter restarts after a
            gap longer than ``max_gap_s``), ``a``/``b`` the screened accelerometer and field readings
            (``(x, y, z, |v|^2)`` or None); None when the time is not finite or the filter cannot
            start yet (no gravity or no field).
        """
        s = self._s
        s.diagnostics.skipped = ""
        t_s = float(t_s)  # a numpy scalar would make every later operation a slow numpy one
        if not math.isfinite(t_s):
            self._skip("t_s not finite")
            return None
        dt = 0.0 if s.t_s is None else self._time_step(t_s)
        if s.t_back_s is not None:  # kept aside, the sample skipped: the next time tells a corrupted one from a restart
            self._skip("t_s went back" if s.t_back_s < s.t_s else "t_s jumped ahead")
            return None
        self._reading = None
        if gyro is not None and self.gyro:
            w = self._vector(gyro, "gyro", 0.0, self._gyro_range2)
            self._reading = w  # as sent: where it reads a rail (GyroFilter)
            if w is not None:
                s.rate_rad_s = self.config.housing_rate(w)  # the gyro's scale and axes, before anything reads the rate
        if accel is not None and self.config.accel_correction is not None:
            accel = self.config.housing_accel(accel)  # the accelerometer's own calibration, before anything reads it
        a, b = self._screen(t_s, accel, field_h, dt)
        s.t_s = t_s
        if s.matrix is not None and dt > self.config.max_gap_s:
            self.events.append(f"filter restarted after a {dt:.2f} s gap in the samples")
            s.matrix = None
        if s.matrix is None:
            if a is None or b is None or b[3] == 0.0:
                return None
            if self._prime is not None:  # the window's up and field, not this one row's
                (ux, uy, uz), (fx, fy, fz) = self._prime
                self._prime, g = None, s.gravity
                self._start((g * ux, g * uy, g * uz, g * g), (fx, fy, fz, fx * fx + fy * fy + fz * fz))
            else:
                self._start(a, b)
            dt = 0.0
        return t_s, dt, a, b

    def _time_step(self, t_s: float) -> float:
        """The step to ``t_s`` from the last time, s.  A time that goes back is kept aside (``t_back_s``; its
        sample is skipped): if the next one goes on from the old clock, it was a corrupted value and the step
        is taken from the old clock (one bad time never turns the gyro through a made-up interval); if it goes
        on from the new one, the module restarted its clock, which is adopted.  So is a time over ``max_gap_s``
        ahead while the gyro filter runs (not at the step right after a (re)start: a stream whose every step is a
        gap restarts at each sample, none skipped): a corrupted value costs its sample, not a restart; a real gap
        restarts the filter at the sample after it (the two-vector filter solves each sample alone: none kept
        aside)."""
        s = self._s
        back, s.t_back_s = s.t_back_s, None
        if t_s >= s.t_s:
            if back is None and self.gyro and s.matrix is not None and s.since_start_s > 0.0 \
                    and t_s - s.t_s > self.config.max_gap_s:
                s.t_back_s = t_s  # a jump ahead: the next time tells a corrupted one from a gap
                return 0.0
            return t_s - s.t_s
        if back is not None and t_s >= back:  # the second time on the new clock: a restart
            s.t_s = back
            return t_s - back
        s.t_back_s = t_s
        return 0.0

    # ------------------------------------------------------------------ input screening
    def _skip(self, reason: str) -> None:
        self._s.skipped.count(reason)
        d = self._s.diagnostics
        d.skipped = f"{d.skipped}, {reason}" if d.skipped else reason

    def _vector(self, v, sensor: str, lo2: float, hi2: float):
        """``(x, y, z, |v|^2)`` of a reading, or None (counted) when not finite or ``|v|^2`` not in [lo2, hi2]."""
        if type(v) is np.ndarray:
            v = v.tolist()
        x, y, z = v
        n2 = x * x + y * y + z * z
        if lo2 <= n2 <= hi2:  # False for NaN
            return x, y, z, n2
        finite = math.isfinite(x) and math.isfinite(y) and math.isfinite(z)
        self._skip(f"{sensor} {'out of range' if finite else 'not finite'}")
        return None

    def _screen(self, t_s, accel, field_h, dt: float):
        """Screened accelerometer and field readings (None where absent or skipped); learns gravity."""
        s, cfg = self._s, self.config
        a = None
        if accel is not None:
            g = s.gravity
            if g is None:
                a = self._vector(accel, "accel", 1e-300, 1e300)
                if a is not None:
                    s.gravity = math.sqrt(a[3])
            else:
                a = self._vector(accel, "accel", 1e-300, (g * cfg.accel_range) ** 2)
                if a is not None and a[3] >= (g / cfg.accel_range) ** 2:
                    s.accel_bad_s = 0.0
                    if cfg.gravity is None and s.rest_s >= self._REST_MIN_S:
                        s.gravity = g + (math.sqrt(a[3]) - g) * 1e-3  # at rest |a| is g
                else:  # beyond the range (skipped), or below its inverse (free fall, briefly: still used)
                    s.accel_bad_s += dt
                    if cfg.gravity is None and s.accel_bad_s >= _RELEARN_S:
                        # a unit change (or an absurd first sample): the readings' own scale becomes gravity
                        x, y, z = accel.tolist() if type(accel) is np.ndarray else accel
                        n2 = x * x + y * y + z * z
                        if 0.0 < n2 < math.inf:
                            self.events.append(f"accelerometer beyond {cfg.accel_range:g} times gravity or below "
                                               f"its inverse for {_RELEARN_S:g} s: gravity re-learnt as "
                                               f"{math.sqrt(n2):.4g}")
                            s.gravity, s.accel_bad_s, a = math.sqrt(n2), 0.0, (x, y, z, n2)
                            self._restart_accel(a)
        b = None if field_h is None else self._vector(field_h, "field", 0.0,
                                                      (cfg.field_range * s.gate.ref_norm) ** 2)
        return a, b

    def _restart_accel(self, a) -> None:
        """Forget what was learnt from the accelerometer's old scale (gravity was re-learnt)."""

    def _reference_moved(self) -> None:
        """The gate adopted another reference field (its timeout)."""

    def _gate_field(self, t_s: float, dt: float, b, innovation: float) -> str:
        """Gate one screened field reading ``(x, y, z, |b|^2)``; fills the diagnostics, returns the reason."""
        s, c, d = self._s, self.coefficients, self._s.diagnostics
        bx, by, bz, b2 = b
        b_norm = math.sqrt(b2)
        m = s.matrix
        ratio = b_norm / s.gate.ref_norm
        dip = 0.0
        if b_norm > 0.0:
            dip = math.degrees(math.asin(max(-1.0, min(1.0, -(m[6] * bx + m[7] * by + m[8] * bz) / b_norm))))
        p = s.covariance
        reason = self.gate.check(s.gate, t_s, dt, b_norm, dip, innovation, p[11] < c.settled_var)
        if reason == MagneticGate.ADOPTED:
            self.events.append(f"field rejected for {self.config.gate_timeout_s:g} s: adopting |B| = {b_norm:.4g} "
                               f"and dip = {dip:.2f} deg as the new reference")
            s.covariance = p[:11] + (p[11] + c.adopt_var,) + p[12:]
            reason, ratio = "ok", 1.0
            self._reference_moved()
        d.field_ratio, d.dip_deg, d.gate = ratio, dip, reason
        return reason

    _REST_MIN_S = 1.5
