"""Seed 001: the 3-D platform method, a joint fit of magnetometer, tilt sensor and local field.

A non-magnetic platform turns the housing about three axes through known angles
(:mod:`compass.io.platform3d`), so the housing's attitude in the bench frame W, ``R_i = R_W<-H``,
is known for every sample.  The magnetometer and the tilt sensor then see known rotations of two
fixed vectors, the field ``b_W`` and the up direction ``u_W``:

.. math::

    m_i = M R_i^T b_W + o_m, \\qquad t_i = A R_i^T u_W + o_t

(:func:`compass.sim.platform3d.predict`).  One ``scipy.optimize.least_squares`` fit estimates

- ``M`` (3x3) and ``o_m``: row ``c`` of ``M`` is the channel's gain times its unit sensing
  direction in H, so ``M`` holds the three scales, the three non-orthogonality angles and the
  rotation of the magnetometer's axes relative to the housing (9 numbers);
- ``A`` (2x3 or 3x3) and ``o_t``: the same for the tilt sensor (two-axis: 2 scales, 1
  non-orthogonality angle, a 3-D rotation);
- the field direction in W: elevation and azimuth ``delta`` from the platform's zero;
- the base's level error: ``u_W = Rot([tx, ty, 0]) z``.

Reported from these, each with its standard error (Jacobian, scaled by the residual): scales,
angles between axes minus 90 degrees (non-orthogonality), the rotation of each sensor's
orthonormalised frame relative to H (the polar factor of its unit-axis matrix, no axis
privileged), the rotation taking magnetometer-frame vectors into the tilt sensor's frame, the dip
about the true vertical, and |B|.

Identifiability (gauge freedoms), and how each is fixed:

- |B| versus the magnetometer gains: only their product is seen.  ``|b_W|`` is fixed to the known
  ``field_ut`` (gains per uT) or to 1 (gains per |B|); ``field_norm_recording_units`` reports
  |B| in output units for a sensor whose gains are 1 (e.g. one that already reads uT).
- ``(M, b_W)`` versus ``(-M, -b_W)``: the same data.  The field is taken pointing down (northern
  hemisphere) unless the metadata's ``site_lat_deg`` is negative, as for the four-flip bench.
- Field azimuth versus the platform's yaw zero: the platform's ``z`` zero is arbitrary; ``delta``
  is the field's azimuth from it, a nuisance parameter.  Heading at runtime is from magnetic north.
- The housing frame is the platform's inner frame (the seed presses the housing's edges on the
  platform's axes); a housing seated askew turns both sensors' rotations alike and leaves
  ``mag_to_tilt`` unchanged.  Gravity only fixes two of its three angles, so without the platform
  angles a housing rotation could not be told from sensor misalignment: the platform provides it.
- The base level error is separable from the tilt sensor's axes only when the platform turns about
  the vertical too (``platform_z_deg`` varies).
- The poses must turn both vectors through three dimensions of H: a platform that only turns about
  the vertical leaves each sensor's vertical response inseparable from its offset.  The fit checks
  the scaled Jacobian's singular values and refuses (:class:`~calibrate.contract.CannotCalibrate`) naming the
  parameters the poses leave undetermined.
"""

from .fit import Platform3DCalibrator, calibrate_platform3d
from .result import MAG_CHANNELS, Platform3DResult, axis_geometry

__all__ = ["MAG_CHANNELS", "Platform3DCalibrator", "Platform3DResult", "axis_geometry", "calibrate_platform3d"]
