"""How every run of the filter starts: one code path for ``compass live``, :func:`run_filter` and the replay.

The filter never starts from one row.  :class:`FilterStart` holds the first samples (each screened
alone: :func:`compass.sample_check.skip_codes`) until its window is complete, the stream's first
quiet second (:class:`compass.site.QuietSeed`; a stream that never holds still: 10 s), then gives

- the **reference field** |B| and dip: the one given (a site, ``--site``), else the window's quiet
  rows (:func:`compass.site.reference_from_recording`), never the calibration bench's;
- **gravity's size**: ``FilterConfig.gravity`` when the user said what 1 g reads, else the median
  |a| over the window's rows (each corrected by ``FilterConfig.accel_correction`` as the filter corrects it);
- the **first attitude**: the up and field directions at the window's first row, each the
  component-wise median of the window's rows turned into that row's frame by the gyro (the rotation
  the gyro reads between samples, corrected by ``FilterConfig.gyro_matrix`` as the filter corrects
  it, its bias taken as zero over the window: 0.02 deg/s over 10 s is 0.2 deg).  At rest that is the
  median of a still housing's readings; in motion the median of the specific force in an inertial frame, where the motion's acceleration (bounded velocity) averages
  out and gravity stays.  A garbage first row, or one 4.5 degrees off, no longer sets the tilt, the
  inertial low-pass's start and, through them, the gyro bias.

The caller then makes the filter (:meth:`FilterStart.make_filter`) and runs the held samples
through it in order, as it runs every later one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..limits import ONE_G_RATIO
from ..sample_check import skip_codes
from ..site import QuietSeed
from ._base import AttitudeFilter, exp_matrix, mat_mul
from ._records import FilterConfig

__all__ = ["FilterStart", "StartValues"]

_TYPICAL_ROWS = 8  # accepted |a| before the screen judges an absurd accelerometer against their median
GRAVITY_FACTOR = 2.0
"""A given gravity (``--gravity``) more than this factor from the window's median |a| is not what 1 g reads: the
filter, which takes the tilt only within ``FilterConfig.accel_tolerance`` of it, would never use the accelerometer
(a unit's factor: 9.81 for m/s^2 against g, 1000 for mg; an uncalibrated accelerometer's 0.77-1.30 g stays inside)."""
_REST_RATE = math.radians(2.0)  # VQF's rest threshold, rad/s


@dataclass(frozen=True)
class StartValues:
    """What :class:`FilterStart` found in its window.

    Attributes
    ----------
    reference : compass.site.ReferenceField
        The reference field the filter uses (the given one, completed, or the window's).
    gravity : float or None
        |a| that 1 g reads, accelerometer units (None: the window had no accelerometer row).
    up_h : tuple of 3 floats, or None
        Unit up direction at the window's first row, housing frame.
    field_h : tuple of 3 floats, or None
        Field at the window's first row, housing frame, field units.
    rows : int
        Rows of the window the values come from.
    window_gravity : float or None
        The window's median |a|, accelerometer units (``gravity`` unless the user gave one).
    """

    reference: object
    gravity: float | None
    up_h: tuple | None
    field_h: tuple | None
    rows: int
    window_gravity: float | None = None


class FilterStart:
    """Hold the first samples until the start window gives the reference, gravity and the first attitude.

    Parameters
    ----------
    config : FilterConfig
        Its ``field_norm`` screens absurd fields while the reference is unknown; its ``gravity``
        (not None) is what 1 g reads.
    reference : compass.site.ReferenceField, optional
        The site's field; None seeds it from the window.
    seconds, max_seconds : float
        As :class:`compass.site.QuietSeed`.

    Attributes
    ----------
    held : list
        The payloads of the samples held so far, in order (the caller's: an index, a reading).
    values : StartValues or None
        Set once the window is complete.
    """

    def __init__(self, config: FilterConfig, reference=None, seconds: float = 1.0, max_seconds: float = 10.0):
        self.config = config
        self.given = reference
        self.held: list = []
        self.values: StartValues | None = None
        self._seed = QuietSeed(seconds, max_seconds)
        self._rows: list = []  # (t_s, accel, gyro, field) of the held samples, Python floats
        self._norms: list[float] = []

    @property
    def done(self) -> bool:
        return self.values is not None

    @property
    def gravity_words(self) -> str | None:
        """Once :attr:`done`: why the given gravity (``FilterConfig.gravity``: beyond :data:`GRAVITY_FACTOR` of the
        window's median |a|), or the unit of the accelerometer's own calibration (``FilterConfig.accel_correction``'s
        ``one_g``: the window's corrected median |a| over it outside :data:`compass.limits.ONE_G_RATIO`), cannot be
        what 1 g reads, in words; None when they can, or none was given."""
        v = self.values
        seen = None if v is None else v.window_gravity
        if seen is None or not seen > 0.0:
            return None
        given, correction = self.config.gravity, self.config.accel_correction
        if correction is not None and seen / correction[2] not in ONE_G_RATIO:
            return (f"the calibration's accelerometer correction was fitted where 1 g read {correction[2]:.4g}, but "
                    f"this stream's corrected |a| over the start's {v.rows} rows is {seen:.4g}: another unit; send "
                    "the accelerometer in the calibration recording's unit (without --accel-unit converting it)")
        if given is None or max(given / seen, seen / given) <= GRAVITY_FACTOR:
            return None
        return (f"--gravity {given:g} is not what 1 g reads: the accelerometer's median |a| over the start's {v.rows} "
                f"rows is {seen:.4g}, {seen / given:.3g} times it, and the filter takes the tilt only within "
                f"{100 * self.config.accel_tolerance:g} % of 1 g (never, here): give --gravity in the accelerometer's "
                "unit (in g when --accel-unit names one), or leave it out to take the start's median")

    def add(self, payload, t_s: float, accel, gyro, field_h) -> str | None:
        """Screen and hold one sample; the reason it is skipped (one of :data:`compass.filter.SKIP_REASONS`,
        never fused: the limits of :func:`compass.sample_check.skip_codes`) or None.  :attr:`done` tells when the window is complete."""
        scale = float(np.median(self._norms)) if len(self._norms) >= _TYPICAL_ROWS else None
        code = int(skip_codes([field_h], self.config.field_norm, None if accel is None else [accel], scale,
                              None if gyro is None else [gyro])[0])
        if not math.isfinite(t_s):
            return "t_s not finite"
        if code:
            sensor, values = ((None, None), ("field", field_h), ("field", field_h), ("accel", accel), ("gyro", gyro))[code]
            return f"{sensor} {'out of range' if np.all(np.isfinite(values)) else 'not finite'}"
        # the accelerometer, corrected as the filter corrects it (FilterConfig.housing_accel)
        a = None if accel is None or not np.all(np.isfinite(accel)) else self.config.housing_accel(
            tuple(float(v) for v in accel))
        if a is not None:
            self._norms.append(math.hypot(*a))
        # the housing's rate, corrected as the filter corrects it (FilterConfig.housing_rate)
        g = None if gyro is None or not np.all(np.isfinite(gyro)) else self.config.housing_rate(
            tuple(float(v) for v in gyro))
        self.held.append(payload)
        self._rows.append((float(t_s), a, g, tuple(float(v) for v in field_h)))
        reference = self._seed.add(t_s, a, field_h)  # rows without an accelerometer do not seed it
        if reference is not None:
            self._finish(reference)
        return None

    def finish(self) -> bool:
        """The stream ended inside the window: the values from what there is (True), or False with too
        few rows to seed the reference (fewer than ten)."""
        if self.done or not self.held:
            return self.done
        reference = self._seed.finish()
        if reference is None and (self.given is None or not np.isfinite(self.given.field_norm)):
            return False
        self._finish(reference)
        return True

    def take_held(self) -> list:
        """The held payloads, in order; the start forgets them."""
        held, self.held = self.held, []
        return held

    def make_filter(self, gyro: bool, config: FilterConfig | None = None) -> AttitudeFilter:
        """A filter with the start's reference field and gravity, whose first attitude is the window's.

        ``config`` (default the start's) is the caller's current one: its reference field is replaced.
        """
        v = self.values
        cfg = config if config is not None else self.config
        cfg = replace(cfg, field_norm=v.reference.field_norm, dip_deg=v.reference.dip_deg)
        filt = AttitudeFilter(cfg, gyro=gyro)
        filt.prime(v.gravity, v.up_h, v.field_h)
        return filt

    def _finish(self, seeded) -> None:
        given = self.given
        reference = seeded if given is None else (given.complete(seeded) if seeded is not None else given)
        seen, up, field = self._first_attitude()
        gravity = seen if self.config.gravity is None else self.config.gravity
        self.values = StartValues(reference, gravity, up, field, len(self._rows), seen)
        self._rows = []

    def _first_attitude(self):
        """Gravity's size and the up and field directions at the first held row (module docstring)."""
        ups, fields, norms = [], [], []
        m = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)  # R_first<-this row, row-major
        t_prev, max_gap = None, self.config.max_gap_s  # across a gap (or a garbage time) the turn is unknown
        rates = np.array([g for _, _, g, _ in self._rows if g is not None]).reshape(-1, 3)
        # a window at rest (every rate within VQF's 2 deg/s of their median) turns by nothing: its rate is the
        # gyro's bias, which integrated would turn the window's later rows by up to bias x window
        still = len(rates) > 0 and bool(np.all(np.linalg.norm(rates - np.median(rates, axis=0), axis=1) < _REST_RATE))
        offset = np.median(rates, axis=0) if still else np.zeros(3)
        for t, a, g, b in self._rows:
            if g is not None:
                g = (g[0] - offset[0], g[1] - offset[1], g[2] - offset[2])
            dt = 0.0 if t_prev is None else t - t_prev
            if g is not None and 0.0 < dt <= max_gap:  # the filter turns by this row's rate over the step before it
                m = mat_mul(m, exp_matrix(g[0] * dt, g[1] * dt, g[2] * dt))
            t_prev = t
            r = np.reshape(m, (3, 3))
            fields.append(r @ b)
            if a is not None:
                norm = math.hypot(*a)
                norms.append(norm)
                ups.append(r @ np.array(a) / norm)
        field = tuple(np.median(fields, axis=0).tolist())
        if not ups:
            return None, None, field
        up = np.median(ups, axis=0)
        up_norm = float(np.linalg.norm(up))
        up = tuple((up / up_norm).tolist()) if up_norm > 0 else None
        return float(np.median(norms)), up, field


def through_start(start: FilterStart, rows, gyro: bool = True):
    """Each row as the filter takes it: the start window's rows held until the window is complete, then each.

    ``rows`` yields ``(t_s, accel, gyro, field_h)``; yields ``(filter, i)``, ``i`` the row's index, for the caller
    to update or step the filter with row ``i`` (the start's rows first, in order, once its filter exists).
    """
    filt = None
    for i, row in enumerate(rows):
        if filt is None:
            start.add(i, *row)
            if not start.done:
                continue
            filt = start.make_filter(gyro)
            todo = start.take_held()
        else:
            todo = [i]
        for j in todo:
            yield filt, j
