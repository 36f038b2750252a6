"""Free-motion (tumble) calibration: hard and soft iron by ellipsoid fitting, coverage, misalignment.

The magnetometer, turned through many orientations in a constant field, reads points on an
ellipsoid.  The calibration maps them back onto a sphere,

.. math:: m_i = S (x_i - h), \\qquad |m_i| = F,

with ``h`` the hard-iron offset (recording units), ``S`` a symmetric positive-definite soft-iron
correction and ``F`` the field norm (SPEC section 2, ``"model": "tumble"``).  Three kinds of ``S``:

``offset``
    ``S = I`` (a sphere: hard iron only), 4 parameters.
``diagonal``
    ``S`` diagonal (per-axis gains), 6 parameters.
``full``
    ``S`` symmetric (gains and cross-axis coupling), 9 parameters.

``S`` is parameterised through the Cholesky factor ``L`` of ``S^2 / F^2 = L L^T`` with a
logarithmic diagonal, so every fit is a real ellipsoid (positive-definite ``S``, positive
determinant); ``S`` is the symmetric square root.  Without a known field, ``det S = 1`` and ``F``
is the geometric-mean radius in recording units.  The loss is the geometric residual
``r_i = F (|L^T (x_i - h)| - 1)`` (recording units), minimised by ``scipy.optimize.least_squares``
with a robust ``soft_l1`` loss; samples beyond ``OUTLIER_SIGMAS`` robust sigmas are then dropped and
the fit repeated with a plain quadratic loss, which gives the standard errors, the chi-square and
the BIC (``n ln(RSS/n) + k ln n`` on a common set of samples) that choose the kind.

A kind is *determined* when its standard errors are below ``MAX_RELATIVE_SIGMA`` of the field and,
for ``diagonal`` and ``full``, when the field was seen along each of the magnetometer's six
half-axes (otherwise the ellipsoid is extrapolated from one side).  The automatic choice takes the
determined kind with the lowest BIC and says in words which orientations are missing.

With an accelerometer, the rotation between magnetometer and accelerometer frames follows from the
constancy of the dip: on quasi-static samples (``||a| / g - 1| < STATIC_TOLERANCE``) the angle
between gravity and the field is ``90 deg + dip``.  The rotation ``C`` (``mag_to_accel``) and the dip
minimise the robust sum of squared angle residuals,

.. math:: e_i = \\arccos(\\hat a_i \\cdot C \\hat m_i) - (90^\\circ + \\delta),

and are kept when the BIC prefers them to the dip alone.  The rotation about the mean field-gravity
plane is weakly determined when the device turned little; its sigma says so.

References: seed 003 (ellipsoid fitting for scale factors); the dip-constancy alignment follows
e.g. Vasconcelos et al., "Geometric approach to strapdown magnetometer calibration in sensor
frame", IEEE TAES 47(2), 2011, and Li et al. (magnetometer-accelerometer alignment).

The package, one module per concern: :mod:`~calibrate.tumble.ellipsoid` (the three kinds and
their choice), :mod:`~calibrate.tumble.coverage`, :mod:`~calibrate.tumble.alignment` (rotation and
dip), :mod:`~calibrate.tumble.diagnosis` (the residual diagnosis), :mod:`~calibrate.tumble.result`
and :mod:`~calibrate.tumble.fit` (:func:`calibrate_tumble`, :class:`TumbleCalibrator`);
:mod:`~calibrate.tumble.collector` gathers a live tumble (``compass live --calibrate tumble``).
"""

from .alignment import MAX_ANGLE_WIDENING, STATIC_TOLERANCE, Misalignment, field_gravity_angles, fit_misalignment, refine_jointly, static_mask
from .coverage import Coverage, sphere_coverage
from .diagnosis import (TUMBLE_FORMS, UNEXPLAINED_WARNING, TumbleDiagnosis, TumbleEffect, diagnose_tumble,
                        radial_noise_floor, residual_structure)
from .ellipsoid import ELLIPSOIDS, MAX_RADIUS_RATIO, MAX_RELATIVE_SIGMA, OUTLIER_SIGMAS, EllipsoidFit, fit_ellipsoid
from .fit import TumbleCalibrator, calibrate_tumble
from .result import TumbleResult

__all__ = ["ELLIPSOIDS", "MAX_ANGLE_WIDENING", "MAX_RADIUS_RATIO", "MAX_RELATIVE_SIGMA", "OUTLIER_SIGMAS", "STATIC_TOLERANCE",
           "TUMBLE_FORMS", "UNEXPLAINED_WARNING", "Coverage", "EllipsoidFit", "Misalignment", "TumbleCalibrator",
           "TumbleCollector", "TumbleDiagnosis", "TumbleEffect", "TumbleResult", "calibrate_tumble", "diagnose_tumble",
           "field_gravity_angles", "fit_ellipsoid", "fit_misalignment", "radial_noise_floor", "refine_jointly",
           "residual_structure", "sphere_coverage", "static_mask"]


def __getattr__(name: str):
    """:class:`~calibrate.tumble.collector.TumbleCollector` on first use: the live collector's stream decoding
    (:mod:`compass.io.streams`) is not imported by every tumble calibration."""
    if name == "TumbleCollector":
        from .collector import TumbleCollector

        return TumbleCollector
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
