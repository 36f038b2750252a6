"""Seed 003: the K matrix, offsets and axis angles of each sensor of an array, from known fields.

For every sensor the seed writes the known field ``B`` (array frame) as a linear function of the
outputs ``V``, its formula (1):

.. math:: B = K (V - V_0), \\qquad B_0 = K V_0,

with ``B_0`` the zero-point offsets in field units.  Its formula (2) ties ``K`` to the axis
angles: row ``c`` of ``K^{-1}`` is the axis' scale factor (``a, b, c``) times its direction
cosines in the array frame, ``(cos alpha_1, cos alpha_2, cos alpha_3)`` for the first axis,
beta for the second, gamma for the third, under the constraint (3) that the cosines of each axis
have unit norm.  So ``scale_c = |row_c(K^-1)|`` and ``alpha_j = arccos(row_1j / scale_1)``.

The fit regresses the outputs on the known fields, ``V = G B + V_0`` with ``G = K^{-1}``
(``scipy.linalg.lstsq`` per channel on the design ``[B, 1]``): the noise is in the outputs, not
in the reference fields, so this is the least-squares estimate the noise calls for; ``K = G^{-1}``.
The standard errors are ``s^2 (X^T X)^{-1}`` per channel with ``s^2`` the residual variance on
``n - 4`` degrees of freedom, propagated to ``K``, the offsets, the scales and the angles
through numerical Jacobians.  With exactly 4 fields nothing is left to estimate ``s``.

The design ``[B, 1]`` has rank 4 only when the fields are not coplanar (no plane, through zero
or not, holds all of them); otherwise the offsets and ``K`` cannot be separated and the fit
refuses (:class:`~calibrate.contract.CannotCalibrate`).

The reference fields are given in the array's frame, so every sensor's calibrated field
``K_s (V_s - V_0s)`` is in that common frame; each sensor's axes are also reported as scales,
angles between axes minus 90 degrees, and the rotation of its orthonormalised frame relative to
the array frame (:func:`calibrate.platform3d.axis_geometry`).
"""

from .fit import MAX_CONDITION, WARN_CONDITION, ReferenceCalibrator, calibrate_reference, fit_k
from .result import ReferenceResult, SensorK

__all__ = ["MAX_CONDITION", "WARN_CONDITION", "ReferenceCalibrator", "ReferenceResult", "SensorK", "calibrate_reference",
           "fit_k"]
