"""The sensor model: channels, sensing matrix and inverse responses, giving the field in H.

A calibration file (SPEC section 2) describes each single-axis channel ``c`` by a unit sensing
direction ``a_c`` in the housing frame H and a monotone response ``v_c = f_c(x_c)`` of the field
component ``x_c = B_H . a_c``.  At runtime the responses are inverted channel by channel and the
field vector is solved from the stacked components:

.. math::

    x = A B_H, \\qquad A = \\begin{pmatrix} a_1^T \\ \\vdots \\ a_c^T \\end{pmatrix}, \\qquad
    \\hat B_H = (A^T W A)^{-1} A^T W x, \\quad W = \\mathrm{diag}(\\sigma_{x,c}^{-2})

``A`` (the sensing matrix) is never assumed orthogonal: with three channels this is ``A^{-1} x``,
with more it is the noise-weighted least-squares solution.  The seed's runtime step writes the
field as ``sum_c a_c cos(beta_c)``, which is only right for orthonormal axes.

A tumble calibration (``"model": "tumble"``: ``m = soft_iron @ (raw - hard_iron)``, then
``mag_to_accel @ m`` in the accelerometer frame) is the same model with three linear channels:
``raw = hard_iron + G B_H`` with ``G = soft_iron^-1 mag_to_accel^T``, so row ``c`` of ``G`` is
``gain_c a_c``.  Its housing frame is the accelerometer's (or the magnetometer's when
``mag_to_accel`` is null).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
import numpy as np

from .limits import reads_one_g
from .iron_uncertainty import (CURVE_FIELDS, ChannelUncertainty, TumbleUncertainty, independent_joint,
                              joint_problem)
from .response import CubicResponse, LinearResponse, Response
from .temperature import TemperatureCompensation

__all__ = ["NotAFieldVector", "SensorModel"]

MIN_SINGULAR_VALUE = 1e-3
"""Smallest singular value of the sensing matrix (unit rows) that gives a field vector: the axes span 3-D."""
_SLOPE_STEP = 1e-4  # relative step of the numerical response slope (nonlinear channels only)


class NotAFieldVector(ValueError):
    """The channels are calibrated but cannot give a field vector: fewer than three, or coplanar.

    A calibration file of such channels is valid (SPEC: a one-channel recording is a single-axis
    calibration) and is written; everything that solves the field vector refuses it.
    """


@dataclass(frozen=True, eq=False)
class SensorModel:
    """A calibrated magnetic sensor: the runtime half of a calibration file.

    Read it from a calibration file with :func:`compass.calibration.load` (``.model``); write it with
    :func:`compass.calibration.model_to_dict` and :func:`compass.calibration.save`.

    Attributes
    ----------
    channels : tuple of str
        Channel (column) names, in the order of the rows of ``directions``.
    directions : ndarray, shape (c, 3)
        Unit sensing directions in the housing frame H.
    responses : tuple of Response
        Each channel's output as a function of its field component (field units).
    field_norm : float
        Calibrated |B| in field units (uT when ``field_ut`` is known, else 1: units of |B|).
    field_ut : float or None
        |B| in microtesla if the calibration knew it.
    dip_deg : float or None
        Calibrated dip (> 0: field points down), degrees; None if the calibration has none.
    noise : ndarray, shape (c,), or None
        White noise of each channel's output (output units); None when unknown.
    direction_covariance : ndarray, shape (c, 3, 3), or None
        Covariance of each sensing direction (rad^2, tangent to the unit sphere); None when the
        calibration gives none (``patent``, ``harmonic``, tumble).
    response_sigma : ndarray, shape (c, 2), or None
        Standard errors of each channel's (offset, gain), output units and output units per
        field unit; None when unknown.
    form : {"channels", "tumble", "installed"}
        How the calibration file wrote it: channels, a tumble's ellipsoid, or a bench model inside
        its product.
    temperature : TemperatureCompensation or None
        The file's ``temperature`` effect: applied when readings come with ``temp_c``.
    iron_uncertainty : TumbleUncertainty or None
        A tumble file's standard errors of its hard iron, soft iron and rotation
        (:mod:`compass.iron_uncertainty`): :meth:`field_covariance` adds them; None for the channel
        form (whose ``direction_covariance`` and ``response_sigma`` hold its own) and for a tumble file
        without them.
    sigma_priors : tuple or None
        The stated priors a channel form's null sigmas took (beside others the file gives): ``(direction
        covariance (c, 3, 3), response sigma (c, 2), words)`` from
        :func:`compass.iron_uncertainty.channel_priors`, already in :attr:`direction_covariance` and
        :attr:`response_sigma`; None when nothing took one.
    joint_covariance : tuple of (ndarray of shape (5, 5) or (8, 8), or None), or None
        Each channel's joint covariance of its direction (rad^2), offset and gain (the units of
        :attr:`response_sigma`), whose marginals are :attr:`direction_covariance` and :attr:`response_sigma`
        (checked): a four-flip's, whose direction, offset and gain errors are correlated within a channel (a
        warm-up during the first flip).  8 x 8 for a channel with a cubic response: then its curve's quadratic,
        cubic and quintic coefficients (1 / field unit^(k - 1), as the response holds them), which trade against
        the gain.  The runtime's calibration sigma then keeps the correlations, through the curve's levers at the
        channel's field (:class:`compass.iron_uncertainty.ChannelUncertainty`); a channel's None takes the three
        as independent; None when no channel has one.
    mag_latency_s : float
        How late the magnetometer reads against the gyro, s: a tumble's gyro-aided fit's
        ``tumble.gyro.mag_latency_s`` when it saw one (positive, beyond 3 sigma), else 0.
        :meth:`compass.filter.FilterConfig.from_model` passes it to the filter when asked (``mag_latency=True``).
    gyro_matrix : ndarray, shape (3, 3), or None
        The gyro's scale and axes against the housing: the housing-frame rate is ``gyro_matrix @ w``, ``w`` the
        gyro's reading; a tumble's gyro-aided fit's ``tumble.gyro.gyro_matrix``, the entries it did not see at
        the identity's (:func:`compass.calibration.gyro_matrix_seen`); None when it saw none.
    gyro_scale_error : tuple of 2 floats, or None
        What the gyro-aided fit saw of the gyro's scale and axis error, as the RMS over rate directions of
        ``|E w| / |w|`` (dimensionless; :func:`compass.calibration.gyro_scale_error`):
        ``(with gyro_matrix applied, the gyro as read)``; None when the file has no usable fit.  Both are
        rotation-invariant (an installation keeps them).  :meth:`compass.filter.FilterConfig.from_model` sets the
        filter's ``gyro_scale_error`` from it.
    accel_correction : (ndarray (3, 3), ndarray (3,), float) or None
        The accelerometer's own calibration ``(A, b, one_g)``: the corrected reading is ``A (a - b)`` (a tumble
        file's ``accelerometer`` block, :mod:`calibrate.tumble.accelerometer`; the recording's unit, in which 1 g
        reads ``one_g``); None when the file has none.  :meth:`compass.filter.FilterConfig.from_model` passes it to the
        filter, which applies it to every accelerometer row.
    """

    channels: tuple[str, ...]
    directions: np.ndarray
    responses: tuple[Response, ...]
    field_norm: float
    field_ut: float | None = None
    dip_deg: float | None = None
    noise: np.ndarray | None = None
    direction_covariance: np.ndarray | None = None
    response_sigma: np.ndarray | None = None
    form: str = "channels"
    temperature: TemperatureCompensation | None = None
    iron_uncertainty: TumbleUncertainty | None = None
    mag_latency_s: float = 0.0
    gyro_matrix: np.ndarray | None = None
    gyro_scale_error: tuple[float, float] | None = None
    accel_correction: tuple | None = None
    sigma_priors: tuple | None = None
    joint_covariance: tuple | None = None

    def __post_init__(self):
        c = len(self.channels)
        if np.shape(self.directions) != (c, 3) or len(self.responses) != c:
            raise ValueError(f"expected {c} directions of shape (3,) and {c} responses, got "
                             f"{np.shape(self.directions)} and {len(self.responses)}")
        if self.joint_covariance is not None:
            self._check_joint()
        if not np.all(np.isfinite(self.directions)):
            raise ValueError("sensing directions must be finite")
        if not self.field_norm > 0:
            raise ValueError(f"calibrated |B| must be positive, got {self.field_norm}")
        if not (np.isfinite(self.mag_latency_s) and self.mag_latency_s >= 0.0):
            raise ValueError(f"mag_latency_s must be a non-negative number, got {self.mag_latency_s!r}")
        if self.gyro_matrix is not None and not (np.shape(self.gyro_matrix) == (3, 3)
                                                 and np.all(np.isfinite(self.gyro_matrix))
                                                 and np.linalg.det(self.gyro_matrix) > 0):
            raise ValueError(f"gyro_matrix must be a finite 3 x 3 matrix of positive determinant, got {self.gyro_matrix!r}")
        if self.gyro_scale_error is not None and not (np.shape(self.gyro_scale_error) == (2,)
                                                      and np.all(np.isfinite(self.gyro_scale_error))
                                                      and np.all(np.asarray(self.gyro_scale_error) >= 0.0)):
            raise ValueError(f"gyro_scale_error must be 2 non-negative numbers, got {self.gyro_scale_error!r}")
        if c < 3:
            raise NotAFieldVector(f"the calibration has {c} channel{'s' if c > 1 else ''} ({', '.join(self.channels)}): "
                                  "a calibration of single-axis channels, valid as such, but the field vector (and "
                                  "heading, pitch, roll) needs at least 3 channels calibrated together")
        smallest = np.linalg.svd(self.unit_directions, compute_uv=False)[-1]
        if smallest < MIN_SINGULAR_VALUE:
            raise NotAFieldVector(f"the sensing directions of {', '.join(self.channels)} do not span three "
                                  f"dimensions (smallest singular value {smallest:.2g}): the field cannot be solved")

    def _check_joint(self) -> None:
        """:attr:`joint_covariance` one entry a channel, each None or a covariance whose marginals are the
        channel's sigmas (:func:`compass.iron_uncertainty.joint_problem`), else ValueError."""
        joint = tuple(self.joint_covariance)
        if len(joint) != len(self.channels):
            raise ValueError(f"joint_covariance must hold one entry per channel ({len(self.channels)}), got {len(joint)}")
        for c, s in enumerate(joint):
            if s is None:
                continue
            cov = None if self.direction_covariance is None else self.direction_covariance[c]
            sigma = None if self.response_sigma is None else self.response_sigma[c]
            problem = joint_problem(s, cov, sigma, isinstance(self.responses[c], CubicResponse))
            if problem is not None:
                raise ValueError(f"channel {self.channels[c]}'s joint_covariance {problem}")
        object.__setattr__(self, "joint_covariance", tuple(None if s is None else np.asarray(s, dtype=float)
                                                           for s in joint))

    # ------------------------------------------------------------------ derived

    @cached_property
    def unit_directions(self) -> np.ndarray:
        """Directions normalised to unit length, shape (c, 3)."""
        a = np.asarray(self.directions, dtype=float)
        return a / np.linalg.norm(a, axis=1, keepdims=True)

    @cached_property
    def gains(self) -> np.ndarray:
        """Zero-field gain of each channel, output units per field unit, shape (c,)."""
        return np.array([r.gain for r in self.responses])

    @cached_property
    def zero_outputs(self) -> np.ndarray:
        """Each channel's output at zero field, output units, shape (c,)."""
        return np.array([float(r.output(0.0)) for r in self.responses])

    @cached_property
    def component_noise(self) -> np.ndarray | None:
        """Noise of each field component at zero field, field units, shape (c,); None if unknown."""
        return None if self.noise is None else np.asarray(self.noise, float) / self.gains

    @cached_property
    def solver(self) -> np.ndarray:
        """The matrix P (3, c) with ``B_H = P x``: ``A^-1`` for three channels, weighted least squares above.

        The weights are the inverse component noise variances; equal when a channel's noise is unknown or
        reads zero (a file's floor of 0 is a rounding, not an exact channel).
        """
        a = self.unit_directions
        noise = self.component_noise
        known = noise is not None and bool(np.all(noise > 0))
        w = 1.0 / noise**2 if known else np.ones(len(a))
        return np.linalg.solve(a.T @ (w[:, None] * a), a.T * w[None, :])

    def _joint_and_curves(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """:attr:`joint_covariance` stacked for :class:`compass.iron_uncertainty.ChannelUncertainty`: a channel
        without one holds its sigmas (priors included) as independent; all 8 x 8 when any channel carries its
        curve (the others with zero curve rows), with each channel's curve coefficients (zeros for a channel whose
        joint covariance is 5 x 5: its levers are the linear ones, as before curves), else curves None."""
        if self.joint_covariance is None:
            return None, None
        joints = [independent_joint(None if self.direction_covariance is None else self.direction_covariance[c],
                                    None if self.response_sigma is None else self.response_sigma[c])
                  if s is None else s for c, s in enumerate(self.joint_covariance)]
        curved = [len(s) == 8 for s in joints]
        if not any(curved):
            return np.stack(joints), None
        out = np.zeros((len(joints), 8, 8))
        for c, s in enumerate(joints):
            out[c, :len(s), :len(s)] = s
        curves = np.array([[getattr(r, k) for k in CURVE_FIELDS] if is_curved else [0.0] * len(CURVE_FIELDS)
                           for r, is_curved in zip(self.responses, curved)], dtype=float)
        return out, curves

    @cached_property
    def _channel_uncertainty(self) -> ChannelUncertainty:
        joint, curves = self._joint_and_curves()
        if self.sigma_priors is None:
            return ChannelUncertainty(self.unit_directions, self.solver, self.gains, self.direction_covariance,
                                      self.response_sigma, joint_covariance=joint, curves=curves)
        cov, sigma, words = self.sigma_priors
        prior = ChannelUncertainty(self.unit_directions, self.solver, self.gains, cov, sigma)
        return ChannelUncertainty(self.unit_directions, self.solver, self.gains, self.direction_covariance,
                                  self.response_sigma, words, prior, joint, curves)

    @cached_property
    def calibration_uncertainty(self) -> TumbleUncertainty | ChannelUncertainty | None:
        """The calibration's own uncertainty, a constant error (not noise): a tumble file's
        :attr:`iron_uncertainty`, else the channels' direction covariances and offset and gain sigmas (a
        four-flip's, an installation's; :class:`compass.iron_uncertainty.ChannelUncertainty`); None when the
        file gives none.  What ``compass live``, its replay and :func:`compass.filter.run_filter` add to the
        filter's heading sigma (:func:`compass.iron_uncertainty.with_calibration_sigma`)."""
        if self.iron_uncertainty is not None:
            return self.iron_uncertainty
        if self.direction_covariance is None and self.response_sigma is None:
            return None
        return self._channel_uncertainty

    # ------------------------------------------------------------------ runtime

    def components(self, raw, temp_c=None) -> tuple[np.ndarray, np.ndarray]:
        """Invert every channel's response.

        Parameters
        ----------
        raw : array_like, shape (..., c)
            Channel outputs (output units), channels in the order of :attr:`channels`.
        temp_c : float or array_like, shape (...), optional
            Sensor temperature of each reading, degC: with a :attr:`temperature` effect the
            readings are first taken back to its reference temperature; ignored without one.

        Raises
        ------
        ValueError
            ``temp_c`` given and the temperature effect names no reference temperature.

        Returns
        -------
        x : ndarray, shape (..., c)
            Field component along each sensing direction, field units.
        in_range : ndarray of bool, shape (..., c)
            False where the component lies outside the channel's calibrated range.
        """
        raw = np.asarray(raw, dtype=float)
        if raw.shape[-1:] != (len(self.channels),):
            raise ValueError(f"expected raw outputs of shape (..., {len(self.channels)}) for channels "
                             f"{', '.join(self.channels)}, got {raw.shape}")
        valid = True
        if self.temperature is not None and temp_c is not None:
            raw, valid = self.temperature.to_reference(raw, temp_c, self.zero_outputs)
        pairs = [r.field_component(raw[..., c]) for c, r in enumerate(self.responses)]
        return np.stack([p[0] for p in pairs], axis=-1), np.stack([p[1] for p in pairs], axis=-1) & valid

    def corrected_accel(self, accel) -> np.ndarray | None:
        """Accelerometer readings (n, 3) through :attr:`accel_correction` (``A (a - b)``, as
        :meth:`compass.filter.FilterConfig.housing_accel` corrects each sample).

        As given (and a :class:`compass.io.units.RecordingWarning`) when the corrected rows do not read 1 g as the
        calibration's recording did (``one_g``: :func:`compass.limits.reads_one_g`, the rule
        :meth:`compass.calibration.ImuCorrection.fits` uses): another unit.  As given without a correction.
        """
        if accel is None or self.accel_correction is None:
            return accel
        matrix, offset, one_g = self.accel_correction
        corrected = (np.asarray(accel, dtype=float) - offset) @ np.asarray(matrix).T
        if reads_one_g(corrected, one_g):
            return corrected
        import warnings

        from .io.units import RecordingWarning

        warnings.warn(RecordingWarning(f"the accelerometer does not read 1 g as in the calibration's recording "
                                       f"({one_g:.4g}): another unit? Its correction is not applied"))
        return accel

    def field(self, raw, temp_c=None) -> tuple[np.ndarray, np.ndarray]:
        """Field vector in the housing frame H from channel outputs.

        Parameters
        ----------
        raw : array_like, shape (..., c)
            Channel outputs (output units).
        temp_c : float or array_like, shape (...), optional
            Sensor temperature of each reading, degC (see :meth:`components`).

        Returns
        -------
        field : ndarray, shape (..., 3)
            ``B_H`` in field units (uT when :attr:`field_ut` is known, else units of |B|).
        in_range : ndarray of bool, shape (...)
            True where every channel is inside its calibrated range.

        Examples
        --------
        >>> from compass.response import LinearResponse
        >>> m = SensorModel(("x", "y", "z"), np.eye(3), (LinearResponse(1.0, 2.0),) * 3, 1.0)
        >>> m.field([[3.0, 1.0, 1.0]])[0]
        array([[1., 0., 0.]])
        """
        x, ok = self.components(raw, temp_c)
        return _times(x, self.solver.T), np.all(ok, axis=-1)

    def component_variance(self, field) -> np.ndarray:
        """Variance of each field component ``x_c`` as estimated from one sample, field units squared.

        Sums the channel's white noise (through the response's slope at that field) and, when the
        calibration gives them, the uncertainty of its sensing direction, offset and gain.  The
        covariance of the field vector is then ``P diag(var) P^T`` with ``P`` = :attr:`solver`:

        .. math::

            \\mathrm{var}_c = \\frac{\\sigma_{v,c}^2}{f_c'(x_c)^2} + B^T \\Sigma_{a_c} B
                + \\frac{\\sigma_{V0,c}^2 + x_c^2 \\sigma_{K,c}^2}{K_c^2}

        (with a channel's :attr:`joint_covariance` the last two terms are its quadratic form ``w^T S_c w``,
        the correlations kept, through its curve's levers when it is 8 x 8:
        :class:`compass.iron_uncertainty.ChannelUncertainty`)

        Parameters
        ----------
        field : array_like, shape (..., 3)
            Field in H (field units), e.g. from :meth:`field`.

        Returns
        -------
        ndarray, shape (..., c)
            Zero where nothing is known (no ``noise_floor``, no covariances).
        """
        b = np.asarray(field, dtype=float)
        var = self.noise_variance(b)
        if self.direction_covariance is not None or self.response_sigma is not None:
            var += self._channel_uncertainty.component_variance(b)
        return var

    def noise_variance(self, field) -> np.ndarray:
        """The white noise's part of :meth:`component_variance` alone (``sigma_v^2 / f'(x)^2``), field units
        squared, shape (..., c): what changes from sample to sample, none of the calibration's own constant
        error (what a filter fuses: :meth:`compass.filter.FilterConfig.from_model`).  Zero without ``noise_floor``."""
        x = _times(np.asarray(field, dtype=float), self.unit_directions.T)
        if self.component_noise is None:
            return np.zeros_like(x)
        return (self.component_noise / self._relative_slope(x)) ** 2 * np.ones_like(x)

    def field_covariance(self, field) -> np.ndarray:
        """Covariance of the estimated field vector in H, ``P diag(var) P^T``, shape (..., 3, 3).

        See :meth:`component_variance`; a tumble file's :attr:`iron_uncertainty` adds
        its own (:meth:`compass.iron_uncertainty.TumbleUncertainty.covariance`); field units squared.
        """
        p = self.solver
        cov = np.einsum("ic,...c,jc->...ij", p, self.component_variance(field), p)
        if self.iron_uncertainty is None:
            return cov
        return cov + self.iron_uncertainty.covariance(field)

    def _relative_slope(self, x: np.ndarray) -> np.ndarray | float:
        """``f'(x) / K`` per channel: 1 for linear channels, a central difference otherwise."""
        if all(isinstance(r, LinearResponse) for r in self.responses):
            return 1.0
        h = _SLOPE_STEP * self.field_norm
        slopes = [np.ones_like(x[..., c]) if isinstance(r, LinearResponse) else
                  (r.output(x[..., c] + h) - r.output(x[..., c] - h)) / (2 * h * r.gain)
                  for c, r in enumerate(self.responses)]
        return np.stack(slopes, axis=-1)


def _times(rows: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``rows @ matrix`` for many rows (einsum: ``@`` goes through a multithreaded BLAS that
    slows down many-fold on a busy machine for such thin products)."""
    return np.einsum("...i,ij->...j", rows, matrix)
