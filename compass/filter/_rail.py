"""A gyro axis held at its rail (saturated): the attitude error the clipped turn leaves, as process noise.

**Model.**  While axis ``i`` of the gyro reads its rail ``r`` (rad/s), the true rate is at least ``r`` and the
excess ``e(t) >= 0`` is unknown and of one sign over the run (a flick rises past the rail and comes back).  The
filter turns the housing by ``r`` only, so after ``T`` s on the rail the attitude is off by ``integral e dt`` about
the sensor's axis, in the world frame about ``u = R G e_i`` (``G`` the gyro's matrix,
``FilterConfig.gyro_matrix``).  The excess is correlated over the whole run, not white: its error grows like
``T``, not like ``sqrt(T)``; a sample that lengthens the run from ``T_0`` to ``T`` adds

.. math::

    \\Delta P_{\\epsilon\\epsilon} = (k\\, r)^2\\, (T^2 - T_0^2)\\, |G e_i|^2\\, I_3 ,

so the run's total is ``(k r T)^2`` on each world axis.  ``k`` is :data:`RAIL_EXCESS`: a flick whose rate is a half
sine of peak ``rho r`` loses ``k(rho) r T`` with ``k`` = 0.13, 0.33, 0.65, 0.98, 1.30, 3.2 at ``rho`` = 1.2, 1.5, 2,
2.5, 3, 6 (a triangular profile about 3/4 of that): ``k = 1`` is one sigma for the flicks of 2.5-3 times the rail a
hand gives a 250 deg/s part (a 565 deg/s flick: 2.3 times, 35 deg lost over 0.18 s), three sigma for a 6 times one.
The error of one run is capped at pi (an angle). The direction is known, but the rank-one ``u u^T`` correlates the
heading with the tilt, so the accelerometer's tilt then sets the heading (by ``u_z / u_h``), and reads an unseen clip of
another axis (one not yet learnt) or the low-pass's motion along ``u``. The isotropic bound (each component of the error
is at most ``|u| k r T``) has no such path: measured before the field's wait below (``tools/bench_gyro_rail.py``,
development seeds, no lever arm, 500 deg/s rail), the rank-one left 11.8 deg of heading RMS, the isotropic 0.7; with a
0.1 m lever arm the rank-one 7.9 / 7.9 deg (heading / inclination), the heading and tilt shares without their
correlation 8.9 / 5.9, the isotropic 8.2 / 5.3 (docs/benchmarks.md). The mean excess is not added to the rate: its size
is unknown, and the noise alone lets the field and the accelerometer take the attitude back at once. The heading's gate
tests the innovation only while the heading variance is below ``settled_var``, ``(heading_tolerance_deg / 3)^2``: an
inflated heading is not settled, so the field's 35 deg innovation is accepted, weighted by that variance (its |B| and
dip tests stay). But while the tilt the run widened moves the field's azimuth by more than the settled heading sigma
(``tan(dip)`` times the tilt sigma), the field waits, its gate said as ``"rail"``: that azimuth error is the tilt
state's, the same in every sample, not noise, and field samples taken through it settle the heading on it (without this
wait two held-out seeds kept 30-45 deg of heading after a roll flick, then locked out by the innovation test). It waits
for an accelerometer that measures the tilt: one absent or refused for :data:`RAIL_WAIT_S` ends the wait (a stream
without one would wait for ever). The added variance stops at ``pi^2`` on each axis, over every run (an angle). The
inertial low-pass was turned by the clipped rate too, so its content carries the same error and the tilt measurement is
blind to it: each sample on the rail restarts it, and the first-order one is then the mean of the samples since until
``accel_time_constant_s`` has passed (``GyroFilter._restart_low_pass``).

**Which samples are on the rail** (per axis, causally, on the reading as sent): a rail is learnt from
:data:`~compass.sample_check.RAIL_SAMPLES` identical readings in a row of at least
:data:`~compass.sample_check.RAIL_MIN_RAD_S` (as :class:`compass.sample_check.GyroRail` says it); that run is
counted whole when it is learnt (the ``T`` of its first samples goes in at its tenth), and from then on every
reading within :data:`RAIL_TOLERANCE` of the learnt ``|r|`` is on it from its first sample (a 16-bit part's two
rails differ by one count, 3e-5 of the range).  A turning gyro repeats a reading by chance: a 16-bit count at
2000 deg/s full scale is 0.061 deg/s, and with 0.1 deg/s of noise per sample two readings agree with probability
about ``count / (sqrt(4 pi) sigma)`` = 0.17; ten in a row, 1e-7 per sample and axis (one false rail in about three
days of turning faster than 2 rad/s at 100 Hz), and a false rail then inflates only readings within 0.1 % of it,
each by about ``(r dt)^2`` (1 deg at 2 rad/s, 100 Hz), which the field takes back.  Readings that never reach a rail
change nothing (the state stays idle while ``|w|`` is below 2 rad/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..sample_check import RAIL_MIN_RAD_S, RAIL_SAMPLES

__all__ = ["RAIL_EXCESS", "RAIL_MIN2", "RAIL_TOLERANCE", "RAIL_WAIT_S", "RailState", "rail_variances"]

RAIL_EXCESS = 1.0
"""``k``: the unknown excess rate over a run on the rail, as a fraction of the rail (one sigma; see the module)."""
RAIL_TOLERANCE = 1e-3
"""Relative distance from a learnt rail within which a reading is on it."""
RAIL_MIN2 = RAIL_MIN_RAD_S**2
"""Its square, (rad/s)^2: no reading whose ``|w|`` is below it is on a rail."""
RAIL_WAIT_S = 2.0
"""Longest the field waits for an accelerometer that does not measure the tilt after a run on the rail, s (the
inertial low-pass's time constant)."""


@dataclass(slots=True)
class RailState:
    """The rail watch's state (part of ``GyroState``), per sensor axis.

    Attributes
    ----------
    last : tuple of 3 floats, or None
        The last reading as sent, rad/s, while its ``|w|`` is at least ``RAIL_MIN_RAD_S`` (None: idle).
    repeats : list of 3 ints
        Readings in a row equal to the one before (at least ``RAIL_MIN_RAD_S``), ending at the last one.
    run_s : list of 3 floats
        Duration of the run of identical readings ending at the last one, its first sample's step included, s.
    added_s : list of 3 floats
        The part of the present run on the rail already in the covariance, s.
    rail_rad_s : list of 3 floats
        The learnt rail ``|r|``, rad/s (NaN: none yet).
    tilt_open : bool
        A run on the rail has widened the tilt, and the field's heading waits until it is back
        (``GyroFilter._rail_tilt_open``).
    unmeasured_s : float
        While ``tilt_open``: time since the accelerometer last measured the tilt, s.  The field waits for it at most
        :data:`RAIL_WAIT_S`: an accelerometer absent or refused that long is not coming, and the field is then used
        as it would be without the rail.
    """

    last: tuple | None = None
    repeats: list = field(default_factory=lambda: [0, 0, 0])
    run_s: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    added_s: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    rail_rad_s: list = field(default_factory=lambda: [math.nan] * 3)
    tilt_open: bool = False
    unmeasured_s: float = 0.0

    def end_runs(self) -> None:
        """Every run ends (idle); the learnt rails stay (they are the part's)."""
        self.last = None
        self.repeats[:], self.run_s[:], self.added_s[:] = [0, 0, 0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]

    def restart(self) -> None:
        """The attitude restarted (its covariance reset): every run ends and the field does not wait."""
        self.end_runs()
        self.tilt_open, self.unmeasured_s = False, 0.0


def rail_variances(state: RailState, w: tuple, dt: float) -> list:
    """One reading's step: the variance each axis's run on its rail adds, ``[(axis, rad^2), ...]`` (empty
    off the rail); ``state`` updated in place.

    Parameters
    ----------
    state : RailState
    w : tuple
        The reading as sent, ``(x, y, z, |w|^2)``, rad/s (before ``FilterConfig.gyro_matrix``).
    dt : float
        The step this reading propagates, s.
    """
    if w[3] < RAIL_MIN2:  # no axis at RAIL_MIN_RAD_S: every run ends
        if state.last is not None:
            state.end_runs()
        return []
    last, out = state.last, []
    for i in range(3):
        v = w[i]
        a = abs(v)
        if a >= RAIL_MIN_RAD_S and last is not None and v == last[i]:
            state.repeats[i] += 1
            state.run_s[i] += dt
        else:
            state.repeats[i], state.run_s[i], state.added_s[i] = 0, dt, 0.0
        if state.repeats[i] + 1 >= RAIL_SAMPLES and a != state.rail_rad_s[i]:
            state.rail_rad_s[i] = a  # learnt (or a new range)
        r = state.rail_rad_s[i]
        if a >= RAIL_MIN_RAD_S and abs(a - r) <= RAIL_TOLERANCE * r:
            k_r = RAIL_EXCESS * r
            run_s = min(state.run_s[i], math.pi / k_r)  # the error about an axis is an angle
            added = state.added_s[i]
            if run_s > added:
                out.append((i, k_r * k_r * (run_s * run_s - added * added)))
                state.added_s[i] = run_s
    state.last = w[:3]
    return out
