"""The live attitude filter with a magnetic-disturbance gate.

Two causal filters share one error convention, the gate and the output:

- **with a gyro**: a multiplicative (error-state) extended Kalman filter.  The nominal attitude
  ``R = R_world<-housing`` (NWU world, FLU housing, SPEC section 1) is propagated with the
  bias-corrected gyro by the exact exponential of each step's rotation; the error state
  ``x = (eps, db)`` (closed-form Kalman updates, module ``_gyro``): ``eps`` the small rotation in the
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

A gyro axis held at its rail (saturated) hides the turn beyond it: after ``T`` s at the rail ``r`` the attitude is
off by an unknown excess of one sign, and ``Q_epsilon`` gains ``(k r T)^2`` on each world axis over the run (``k``
= 1; the inertial low-pass restarts, and the field waits while the tilt it widened would move its azimuth:
:mod:`._rail`).  Readings that never reach a rail change nothing.

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
correction slows to many seconds and the gyro carries the tilt.  ``accel_lowpass_order=2`` makes the
low-pass a Butterworth with the same mean age (VQF's kind), which leaves ``omega_c^2`` times the
displacement instead of the velocity over tau: better in fast turns, worse in translation and in
heading on BROAD, so not the default (docs/benchmarks.md, inclination in turns).  ``lever_arm=True`` takes out of
the first-order low-pass the velocity of a hand-held turn about a centre away from the IMU, ``(v - LP v) / tau`` with
``v = w x r`` and the arm ``r`` fitted as it runs (:mod:`._lever`), and its acceleration ``M r`` out of the motion
the tilt's noise follows: the low-pass's direction improves on every BROAD trial, the output's inclination in the
disturbed group alone, while the undisturbed inclination and the heading get worse, so not the default either.
Reading each low-pass's leak at every period (``H (1 - H) f``) instead of at ``tau_v`` alone, and blending the two
low-passes by least variance, were measured and not kept (docs/benchmarks.md, the leak each low-pass leaves); so was
reading ``tau_v`` (and the leak's size) from the data: the leak's own time scale is shorter than 0.5 s on every BROAD
trial, and trusting the accelerometer more costs the hand-turned trials and tapping (docs/benchmarks.md, the leak's
correlation time read from the data).  Shaping the gain instead (docs/benchmarks.md, the leak's shape on paper): a leak
shaped in the state passes more hand motion, not less; the scale error as a 1 s Gauss-Markov rate-error state keeps
the mean age and cuts the 2 s leak by a fifth on paper, and on BROAD moves no group's inclination and costs heading.

Magnetometer: its measurement row is the heading (as VQF's and x-io Fusion's): ``psi_meas = eps_z +
n_psi``, ``psi_meas`` minus the azimuth (toward West) of the field rotated into the world by the
estimate, with the sensor noise, the tilt error seen through ``tan(dip)`` and the environment's
heading error (field inhomogeneity, calibration residue, latency; correlated over
``field_error_time_s``) in ``var n_psi``.  Its Kalman gain still reaches the tilt and the gyro bias
through the covariance's cross terms (built by propagation: the bias error turns the attitude by
``-R db dt``, and the tilt and heading updates learn different world components of the bias), so a
disturbed field the gate lets in could tilt the estimate a little; ``FilterConfig.field_update``
"heading" makes it a Schmidt (consider) update that moves only the heading and the bias along the
vertical, as VQF's magnetometer never touches the inclination, and "heading-tilt" also puts the
tilt's ``tan(dip)`` share of the azimuth into the row instead of the noise (issue 22: neither moves
BROAD's inclination; docs/benchmarks.md, the field's update and the tilt).  The gyro filter measures that heading error
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
A reading counts only once the rest has held ``rest_confirm_s`` (1 s) beyond it: the onset of a slow
turn stays under the detector's thresholds until its 0.5 s low-pass catches up, and is not a bias.
The rest the attitude starts in counts from its first reading (``start_rest_bias``: no motion
precedes it).

The **gate** (VQF's and Fusion's magnetic rejection): the field is used only while its magnitude
and its dip against the filter's own up direction match a reference within tolerances, and (once
the heading is settled) its heading innovation is small.  The reference starts from the
calibration's |B| and dip and follows the accepted field slowly (``field_reference_tau_s``), so a
field that changes across a room is followed while a fast change (a magnet) is rejected.  A
rejection longer than ``gate_timeout_s`` means the environment changed: the current |B| and dip
become the reference and the heading is re-learnt from the field (VQF's ``magNewTime``).

**Layout** (as VQF's): :class:`FilterConfig` (what a user tunes), :class:`FilterCoefficients`
(derived once), a state record per filter (:class:`GyroState`, :class:`TwoVectorState`: read, set,
:meth:`~AttitudeFilter.reset`); :class:`GyroFilter` and :class:`TwoVectorFilter` share the
:class:`MagneticGate` (its state :class:`GateState`); :meth:`AttitudeFilter.update` is the lean public
per-sample step, :meth:`~AttitudeFilter.step` returns an :class:`Estimate`, :func:`run_filter` runs
``update`` over arrays; what a sample did is a :class:`Diagnostics` record, what bad input was
skipped a :class:`SkipCounts` record.

**Bad input**: a non-finite time skips the sample; a non-finite reading, or one beyond the
sensor's range (``gyro_range_rad_s``, ``accel_range``, ``field_range``), is skipped as absent and
counted by reason; it is never fused and never disables a sensor (an accelerometer out of range for
1 s with gravity not configured re-learns gravity: a unit change or an absurd first sample).

References: D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation estimation with bias
estimation and magnetic disturbance rejection", Information Fusion 91 (2023); x-io Fusion
(``FusionAhrs``); F. L. Markley, "Attitude error representations for Kalman filtering", JGCA 26 (2003).
"""

from ._base import AttitudeFilter
from ._gate import GateState, MagneticGate
from ._gyro import GyroFilter, GyroState
from ._place import PLACE_EVENT
from ._records import (DEFAULT_GYRO_SCALE_ERROR, SKIP_REASONS, Diagnostics, Estimate, FilterCoefficients, FilterConfig,
                       SkipCounts, fitted_scale_error)
from ._run import FilterTrack, reference_field, run_filter
from ._start import FilterStart, StartValues, through_start
from ._two_vector import TwoVectorFilter, TwoVectorState

__all__ = ["DEFAULT_GYRO_SCALE_ERROR", "fitted_scale_error", "FilterConfig", "FilterCoefficients", "Estimate", "Diagnostics", "SkipCounts", "SKIP_REASONS",
           "AttitudeFilter", "GyroFilter", "GyroState", "TwoVectorFilter", "TwoVectorState", "MagneticGate",
           "GateState", "FilterTrack", "run_filter", "reference_field", "FilterStart", "StartValues", "through_start",
           "PLACE_EVENT"]
