"""The filter's records, as VQF lays out its own: what a user tunes (:class:`FilterConfig`, VQF's
``Params``), what is derived from it once (:class:`FilterCoefficients`), what one sample reports
(:class:`Diagnostics`, :class:`Estimate`) and what bad input it skipped (:class:`SkipCounts`).
The per-sample state records live beside their filters (``GyroState``, ``TwoVectorState``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["DEFAULT_GYRO_SCALE_ERROR", "FilterConfig", "FilterCoefficients", "fitted_scale_error", "Diagnostics", "SkipCounts", "Estimate", "SKIP_REASONS"]

_SCALE_CORRELATION_S = 1.0  # a scale-factor error persists while the housing keeps turning
DEFAULT_GYRO_SCALE_ERROR = 0.005
"""The gyro scale error the filter allows for when nothing is known of the board's (a good MEMS gyro after its
factory trim; BROAD's boards), and the floor under a fitted one (fraction of the rate)."""
_REST_TAU_S = 0.5  # low-pass of VQF's rest detector, s
_REST_RATE_SIGMA = 1e-3  # residual true rate "at rest" (tremor, Earth's rotation), rad/s


FIELD_UPDATES = ("kalman", "no-tilt", "heading", "heading-tilt")
"""``FilterConfig.field_update``'s values."""


@dataclass(frozen=True)
class FilterConfig:
    """Noise model, gate, input ranges and reference field of the attitude filter (VQF's ``Params``).

    Nothing here is fitted to a data set: the defaults are generic MEMS figures and VQF's published
    time constants and thresholds; pass your sensors' data-sheet values where you know them.

    Attributes
    ----------
    field_norm : float
        Reference |B|, field units (the unit of ``field_h``).  Under :class:`FilterStart`
        (:func:`run_filter`, ``compass live``) it only screens absurd fields until the reference is
        seeded from the stream, unless the reference is given.
    dip_deg : float
        Reference dip, degrees (> 0: field points down); as ``field_norm``.
    mag_noise : float
        White noise of each field component, field units, per sample.
    accel_noise : float
        White noise of each component of the unit accelerometer vector (fraction of g), per sample.
    gyro_noise : float
        Gyro rate noise density, rad/s/sqrt(Hz) (per-sample sigma = density * sqrt(rate)).
    gyro_bias_walk : float
        Gyro bias random walk, rad/s^2/sqrt(Hz).
    gyro_bias_sigma0 : float
        Initial 1-sigma of each bias component, rad/s.
    gyro_scale_error : float
        Relative scale-factor and cross-axis error of the gyro (fraction of the rate).
    accel_time_constant_s : float
        Low-pass of the specific force in the inertial frame, seconds.  VQF's ``tauAcc`` is 3 s for
        a filter that sets the tilt to the low-passed direction outright; this filter's own tilt
        correction adds about a second of smoothing on top (its Kalman time constant in motion), and
        the low-pass carries the gyro's scale error over the angle turned within its memory, so 2 s
        (issue 13's leave-one-out protocol chose 2 s over 3 s on 13 of 14 BROAD folds).
    accel_lowpass_order : int
        Order of the inertial low-pass, both with mean age ``accel_time_constant_s``: 1 (first order)
        leaves of hand-held motion ``(v - LP v) / tau``, its velocity; 2 (a Butterworth, VQF's kind)
        leaves ``omega_c^2`` times its displacement.  2 gains in fast turns and loses in translation and
        heading on BROAD and on simulated boards (issue 22, docs/benchmarks.md): 1 is the default.
    motion_time_s : float
        Time scale on which the housing's velocity varies (hand-held motion), seconds: the
        correlation time of what the low-pass leaves of the motion acceleration.  A constant: read from the
        data (the leak's ``sqrt(<q^2> / <q'^2>)``, 0.03-0.31 s on BROAD) it made the attached-magnet
        inclination worse, 0.72 -> 0.78 deg (docs/benchmarks.md, issue 22).
    field_error_time_s : float
        Correlation time of the field's own heading error (calibration residue, inhomogeneity) as the
        housing moves and turns, seconds: how often the field brings independent heading information.
    mag_heading_sigma_deg : float
        Heading error of the undisturbed field itself (inhomogeneity across the working volume,
        calibration residue), degrees: the floor; the gyro filter uses the larger of it and the
        error it measures from the wander of the field's dip (module docstring).  1 degree (issue
        13's leave-one-out protocol chose it over 2 degrees on 13 of 14 BROAD folds).
    field_reference_tau_s : float
        Time constant with which the gate's reference |B| and dip follow the accepted field, seconds.
    angular_accel_noise : float
        Without gyro: white angular acceleration driving the constant-rate model, rad/s^2/sqrt(Hz).
    rate_tau_s : float
        Without gyro: correlation time of the angular rate (a first-order Gauss-Markov rate, so a
        heading coasts to a stop while the field is rejected), seconds.
    gravity : float or None
        |a| at rest in the accelerometer's unit (``--gravity``: what 1 g reads); None learns it from
        the samples (the start window's median |a| under :class:`FilterStart`, as :func:`run_filter`
        and ``compass live`` start; a bare :class:`AttitudeFilter` the first sample's; then the
        average at rest).
    accel_tolerance : float
        Use the (low-passed) accelerometer only while ``| |a| / gravity - 1 |`` is below this.
    field_tolerance : float
        Gate: largest accepted ``| |B| / reference - 1 |`` (VQF: 0.1).
    dip_tolerance_deg : float
        Gate: largest accepted dip error against the reference, degrees (VQF: 10).
    heading_tolerance_deg : float
        Gate: largest accepted heading innovation, degrees, checked once the heading 1-sigma is
        below a third of it.
    gate : bool
        Gate the field at all (False: every field sample updates the heading; for comparisons).
    gate_timeout_s : float
        A continuous rejection this long adopts the current field as the reference, seconds.
    max_gap_s : float
        A time step longer than this restarts the attitude from the next two-vector solution
        (the gyro bias is kept), seconds; the gyro filter, once running, first keeps such a sample aside (skipped:
        a corrupted time, if the next one goes on from the old clock) and restarts at the sample after it.
    gyro_range_rad_s : float
        A gyro sample whose |omega| exceeds this is absurd (beyond any MEMS gyro's range, 4000 deg/s
        by default): skipped, the last good rate is held, rad/s.
    accel_range : float
        An accelerometer sample with ``|a| / gravity`` above this (64: four times the common 16 g
        full scale) or exactly zero is absurd: skipped.  (Near-zero specific force is real: free fall.)
    field_range : float
        A field sample with ``|B| / reference`` above this is absurd (a magnetometer saturates long
        before): skipped.
    mag_latency_s : float
        The magnetometer's reading is this late against the gyro and accelerometer, s (gyro filter:
        the field is turned forward by the gyro's rotation over it, to first order; 0 = none).
    gyro_matrix : tuple of 3 tuples of 3 floats, or None
        ``G``: each gyro reading ``w`` is taken as the housing-frame rate ``G w`` before anything else uses it
        (its scale and axis errors against the housing; a tumble's gyro-aided fit,
        ``tumble.gyro.gyro_matrix``); None = the identity.
    accel_correction : (3 tuples of 3 floats, 3 floats, float), or None
        ``(A, b, one_g)``: each accelerometer reading ``a`` is taken as ``A (a - b)`` before anything else uses it
        (the accelerometer's own offsets, scales and cross-axis sensitivity; a tumble file's ``accelerometer``
        block, :mod:`calibrate.tumble.accelerometer`, in that recording's unit, in which 1 g reads ``one_g``: a
        stream in another unit is refused at the start, :attr:`FilterStart.gravity_words`); None = as read.
    rest_bias_estimation : bool
        At rest the gyro reading measures its bias (VQF's ``restBiasEstEnabled``).
    rest_confirm_s : float
        The gyro filter takes a reading at rest for its bias only once the rest has held this much longer,
        seconds (rest confirmed on both sides; 0: at once, as before issue 22).  The onset of a slow turn stays
        below the rest detector's thresholds until its low-pass (0.5 s) catches up: taken for the bias, a turn
        of a few tenths of a deg/s becomes a bias error the field and the accelerometer must then undo
        (simulated tapping: 0.1 deg/s, 2 deg of heading; docs/benchmarks.md).  The default, 1 s, is two of the
        detector's time constants (86 % of a step).
    motion_adaptive_accel : bool
        The tilt measurement's noise grows with the motion the accelerometer sees (False: the white
        ``accel_noise`` only).
    field_error_from_dip : bool
        The field's heading error is measured from the wander of its dip (False: the floor
        ``mag_heading_sigma_deg`` only).
    start_rest_bias : bool
        The rest the gyro filter starts in (the rest detector holding since the attitude began) measures the bias
        from its first reading, each once the rest has held ``rest_confirm_s`` beyond it and the detector its 1.5 s
        (issue 22).  Other rests count from the detector's 1.5 s on: a reading before may be the tail of the motion
        before the rest; at the start no motion precedes.  A restart after a gap longer than ``max_gap_s`` is a start too: what
        came before the gap is not known, and the kept bias's sigma gates a reading that disagrees.  False: every rest alike.
    start_field_bias_hold : bool
        The gyro filter's field (heading) update does not move the bias (a Schmidt update) at the start: while
        the tilt holds it (``start_bias_hold``, ``accel_time_constant_s``), and on while the rest the attitude
        started in holds until one of its readings measures the bias (issue 22): the heading row's gain on the
        vertical bias through ``P(eps_z, b) = -sigma_b0^2 t`` turns the start's heading and tilt errors into up
        to 1 deg/s of bias.  Measured and not the default: it gains on the simulated boards (BROAD-like seeds
        4-7, 0.31 -> 0.26 deg heading) but costs BROAD trial 32 0.04 deg (docs/benchmarks.md).
    follow_place : bool
        The gyro filter's reference field follows the place: a field the gate rejects that stays
        constant in the world frame over ``place_window_s`` while the housing turns (and is not a
        constant field in the housing frame: a magnet on it) becomes the reference, its |B|, dip and
        azimuth (:mod:`compass.filter._place`); said as an event.
    place_window_s : float
        The window over which a new place's field is told from a magnet on the housing, seconds.
    residual_in_band : bool
        The motion-adaptive tilt noise counts only the part of the raw motion ``f - LP f`` that varies on the
        motion's time scale (low-passed with time constant ``motion_time_s / 2 pi`` before it is attenuated
        and squared; issue 22): a 25 Hz vibration or a 2 ms tap, which the inertial low-pass removes almost
        entirely, no longer makes the filter distrust the accelerometer for ``motion_time_s`` (False: the raw
        motion, as before).
    lever_arm : bool
        The gyro filter's tilt measurement takes out what the first-order inertial low-pass leaves of a hand-held
        turn about a centre away from the IMU, ``(v - LP v) / tau`` with ``v = w x r``, the lever arm ``r``
        fitted as it runs (:mod:`compass.filter._lever`; issue 22), and its acceleration ``M r`` out of the motion
        the tilt's noise follows (``motion_adaptive_accel``).  Only with ``accel_lowpass_order`` 1.
    calibration_uncertainty : compass.iron_uncertainty.TumbleUncertainty or ChannelUncertainty or None
        The calibration's own uncertainty (``SensorModel.calibration_uncertainty``; :meth:`from_model` sets
        it): never fused (a constant error, not noise), only added to the reported heading sigma at each
        estimate's attitude (:func:`compass.iron_uncertainty.with_calibration_sigma`: ``compass live``,
        its replay and :func:`run_filter` alike).
    field_update : str
        What the gyro filter's field (heading) update may move (issue 22): ``"kalman"`` every state its
        gain reaches through the covariance's cross terms (the tilt and the whole gyro bias: the
        optimal update when the field is what the model says); ``"no-tilt"`` the heading and the bias,
        never the tilt; ``"heading"`` the heading and the bias along the world vertical only, as VQF's
        magnetometer never touches the inclination (both Schmidt updates: :func:`compass.filter._kalman.update_heading`);
        ``"heading-tilt"`` as ``"heading"``, with the tilt's share of the measured azimuth (``tan(dip)``
        times the tilt about the field's horizontal direction) in the measurement model instead of
        white noise: the heading it teaches keeps its correlation with the tilt's error, and a later
        tilt correction carries the heading along.
    start_bias_hold : bool
        The gyro filter holds its bias (does not estimate it from the tilt: a Schmidt update) for
        ``accel_time_constant_s`` after the start, while the inertial low-pass still carries its start
        (False: from the first sample, as before issue 22).  Holding it until the tilt sigma fell below
        a degree was tried and rejected: in motion that never happens, and the bias was never learnt
        (tools/bench_replay.py, simulated slow rotation from the first sample: 4.2 deg inclination).
    """

    field_norm: float
    dip_deg: float
    mag_noise: float
    accel_noise: float = 0.005
    gyro_noise: float = 3e-4
    gyro_bias_walk: float = 1e-4
    gyro_bias_sigma0: float = 0.05
    gyro_scale_error: float = DEFAULT_GYRO_SCALE_ERROR
    accel_time_constant_s: float = 2.0
    accel_lowpass_order: int = 1
    motion_time_s: float = 0.5
    field_error_time_s: float = 4.0
    mag_heading_sigma_deg: float = 1.0
    field_reference_tau_s: float = 20.0
    angular_accel_noise: float = 0.1
    rate_tau_s: float = 1.0
    gravity: float | None = None
    accel_tolerance: float = 0.1
    field_tolerance: float = 0.1
    dip_tolerance_deg: float = 10.0
    heading_tolerance_deg: float = 10.0
    gate: bool = True
    gate_timeout_s: float = 20.0
    max_gap_s: float = 0.5
    gyro_range_rad_s: float = math.radians(4000.0)
    accel_range: float = 64.0
    field_range: float = 10.0
    mag_latency_s: float = 0.0
    gyro_matrix: tuple | None = None
    accel_correction: tuple | None = None
    rest_bias_estimation: bool = True
    rest_confirm_s: float = 1.0
    motion_adaptive_accel: bool = True
    field_error_from_dip: bool = True
    start_bias_hold: bool = True
    start_rest_bias: bool = True
    start_field_bias_hold: bool = False
    follow_place: bool = True
    place_window_s: float = 4.0
    residual_in_band: bool = False
    field_update: str = "kalman"
    lever_arm: bool = False
    calibration_uncertainty: object = None

    def __post_init__(self):
        for f in fields(self):
            if (f.name in ("dip_deg", "gravity", "mag_latency_s", "rest_confirm_s", "gyro_matrix",
                           "accel_correction", "calibration_uncertainty")
                    or f.type in ("bool", "str")):
                continue
            value = getattr(self, f.name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"FilterConfig.{f.name} must be a positive number, got {value!r}")
        for name in ("accel_range", "field_range"):
            if not getattr(self, name) > 1.0:
                raise ValueError(f"FilterConfig.{name} must be above 1, got {getattr(self, name)!r}")
        if not (np.isfinite(self.mag_latency_s) and self.mag_latency_s >= 0.0):
            raise ValueError(f"FilterConfig.mag_latency_s must be a non-negative number, got {self.mag_latency_s!r}")
        if not (np.isfinite(self.rest_confirm_s) and self.rest_confirm_s >= 0.0):
            raise ValueError(f"FilterConfig.rest_confirm_s must be a non-negative number, got {self.rest_confirm_s!r}")
        if self.field_update not in FIELD_UPDATES:
            raise ValueError(f"FilterConfig.field_update must be one of {', '.join(FIELD_UPDATES)}, "
                             f"got {self.field_update!r}")
        if self.accel_lowpass_order not in (1, 2):
            raise ValueError(f"FilterConfig.accel_lowpass_order must be 1 or 2, got {self.accel_lowpass_order!r}")
        if self.lever_arm and self.accel_lowpass_order != 1:
            raise ValueError("FilterConfig.lever_arm needs accel_lowpass_order 1 (the first-order low-pass's leftover)")
        if not -90.0 < self.dip_deg < 90.0:
            raise ValueError(f"FilterConfig.dip_deg must be in (-90, 90), got {self.dip_deg!r}")
        if self.gravity is not None and not (np.isfinite(self.gravity) and self.gravity > 0):
            raise ValueError(f"FilterConfig.gravity must be positive or None, got {self.gravity!r}")
        if self.gyro_matrix is not None:
            g = np.asarray(self.gyro_matrix, dtype=float) if np.shape(self.gyro_matrix) == (3, 3) else None
            if g is None or not np.all(np.isfinite(g)) or not np.linalg.det(g) > 0:
                raise ValueError("FilterConfig.gyro_matrix must be a finite 3 x 3 matrix (tuple of 3 tuples) of positive "
                                 f"determinant, got {self.gyro_matrix!r}")
            object.__setattr__(self, "gyro_matrix", tuple(tuple(float(v) for v in row) for row in g))
        if self.accel_correction is not None:
            object.__setattr__(self, "accel_correction", _accel_correction(self.accel_correction))

    def housing_rate(self, w) -> tuple:
        """The housing-frame rate ``G w`` of a gyro reading ``w`` (rad/s, 3 floats), ``G`` :attr:`gyro_matrix`
        (None: ``w`` as read): the one place a gyro sample is corrected, for the filter and its start alike."""
        g = self.gyro_matrix
        if g is None:  # the per-sample path: the reading's own tuple, no copy
            return w[:3]
        return tuple(r[0] * w[0] + r[1] * w[1] + r[2] * w[2] for r in g)

    def housing_accel(self, a) -> tuple:
        """The corrected reading ``A (a - b)`` of an accelerometer reading ``a`` (3 floats), ``(A, b)``
        :attr:`accel_correction` (None: ``a`` as read): the one place an accelerometer sample is corrected, for the
        filter and its start alike."""
        c = self.accel_correction
        if c is None:
            return a
        m, (bx, by, bz), _ = c
        x, y, z = a[0] - bx, a[1] - by, a[2] - bz
        return tuple(r[0] * x + r[1] * y + r[2] * z for r in m)

    @classmethod
    def from_model(cls, model, *, mag_latency: bool = False, gravity: float | None = None,
                   gyro_matrix: bool = False, gyro_scale_error: float | None = None) -> "FilterConfig":
        """Reference field and magnetometer noise from a :class:`compass.model.SensorModel`.

        The noise is the field's white noise at zero field alone (``model.noise_variance``), for every form:
        none of the calibration's own uncertainty (a tumble file's iron sigmas, a four-flip's or an
        installation's offset, gain and direction sigmas: a constant error, not noise from sample to sample;
        it is carried as :attr:`calibration_uncertainty`, which ``compass live``, its replay and
        :func:`run_filter` add to the reported heading sigma instead, so it is counted once and never fused).
        ``gravity``: what 1 g reads (``--gravity``), else learnt from the start window.

        With ``mag_latency`` also the magnetometer's latency the calibration found
        (``model.mag_latency_s``: a tumble's gyro-aided fit's, 0 when the file has none; ``compass live``
        and ``compass attitude --filter`` ``--mag-latency``).  Off by default: on BROAD the latency fitted
        on another trial cost the undisturbed trials' heading (docs/benchmarks.md, "The magnetometer's
        latency from the calibration file").

        With ``gyro_matrix`` also the gyro's scale and axes the calibration found (``model.gyro_matrix``: a tumble's
        gyro-aided fit's, the entries it saw; nothing when the file has none): each gyro sample is corrected by it
        first (``compass live`` and ``compass attitude --filter`` ``--gyro-matrix``).  Off by default: on simulated
        boards it took most of what the gyro's scale error cost in rotation, but on BROAD the matrix fitted on
        another trial doubled every group's heading and inclination error (docs/benchmarks.md, "The gyro's scale
        and axes from the calibration file").

        The gyro's scale error (:attr:`gyro_scale_error`) is what the calibration's gyro-aided fit says remains
        (``model.gyro_scale_error``, the entries it saw: with ``gyro_matrix`` their sigma, without it ``|G - I|`` and
        the sigma; :func:`compass.calibration.gyro_scale_error`) in quadrature with the default 0.005
        (:func:`fitted_scale_error`); the default when the file has no fit.  ``gyro_scale_error`` given (``--gyro-scale-error``) overrides it.

        The accelerometer's own calibration (``model.accel_correction``: a tumble file's ``accelerometer`` block) is
        always carried: every accelerometer row is corrected by it (:meth:`housing_accel`), in the tumble recording's
        unit (a stream in another unit must not get it).

        Change other fields with ``dataclasses.replace``.

        Raises
        ------
        ValueError
            The calibration has no dip, or no noise floor above zero.
        """
        if model.dip_deg is None:
            raise ValueError("the calibration has no dip_deg: the filter needs the field's reference direction")
        if model.noise is None or not np.all(np.asarray(model.noise) > 0):
            raise ValueError("the calibration has no noise_floor above zero: the filter cannot weight the magnetometer")
        p = model.solver
        noise = float(np.sqrt(np.trace((p * model.noise_variance(np.zeros(3))) @ p.T) / 3.0))
        if gyro_scale_error is None:
            gyro_scale_error = fitted_scale_error(model, gyro_matrix)
        return cls(field_norm=model.field_norm, dip_deg=model.dip_deg, mag_noise=noise,
                   gyro_scale_error=gyro_scale_error,
                   mag_latency_s=model.mag_latency_s if mag_latency else 0.0, gravity=gravity,
                   gyro_matrix=model.gyro_matrix if gyro_matrix else None,
                   accel_correction=model.accel_correction,
                   calibration_uncertainty=model.calibration_uncertainty)


def _accel_correction(value) -> tuple:
    """:attr:`FilterConfig.accel_correction` as ``(3 tuples of 3 floats, 3 floats, float)``, checked (finite, the
    matrix of positive determinant, what 1 g reads above zero)."""
    try:
        m, b, one_g = value
        m, b, one_g = np.asarray(m, dtype=float), np.asarray(b, dtype=float), float(one_g)
    except (TypeError, ValueError):
        m = b = one_g = None
    if (m is None or m.shape != (3, 3) or b.shape != (3,) or not np.all(np.isfinite(m)) or not np.all(np.isfinite(b))
            or not np.linalg.det(m) > 0 or not 0.0 < one_g < math.inf):
        raise ValueError("FilterConfig.accel_correction must be (a finite 3 x 3 matrix of positive determinant, "
                         f"3 finite offsets, what 1 g reads), got {value!r}")
    return tuple(tuple(float(v) for v in row) for row in m), tuple(float(v) for v in b), one_g


def fitted_scale_error(model, gyro_matrix: bool) -> float:
    """The gyro scale error a calibration's gyro-aided fit leaves (``model.gyro_scale_error``: with ``gyro_matrix``
    applied, or the gyro as read), added in quadrature to :data:`DEFAULT_GYRO_SCALE_ERROR` (what the filter allows
    for what the fit did not see); that default when the file has no fit.

    Parameters
    ----------
    model : compass.model.SensorModel
    gyro_matrix : bool
        The fitted ``model.gyro_matrix`` corrects each gyro sample (``--gyro-matrix``).

    Returns
    -------
    float
        Fraction of the rate.
    """
    fitted = model.gyro_scale_error
    if fitted is None:
        return DEFAULT_GYRO_SCALE_ERROR
    with_matrix, as_read = fitted
    return math.hypot(DEFAULT_GYRO_SCALE_ERROR, with_matrix if gyro_matrix and model.gyro_matrix is not None else as_read)


@dataclass(frozen=True)
class FilterCoefficients:
    """What the filter derives once from its :class:`FilterConfig` (VQF's ``Coefficients``).

    Variances in rad^2 unless said; the per-step factors that depend on the sample interval are
    computed per sample (the interval is the samples' own, not fixed).

    Attributes
    ----------
    tan_dip2, cos_dip2 : float
        ``tan^2`` and ``cos^2`` of the reference dip.
    env_floor_var : float
        ``mag_heading_sigma_deg`` squared, rad^2: the floor of the field's own heading error.
    dip_noise_var : float
        The sensor noise in the field's direction, ``(mag_noise / field_norm)^2``, rad^2.
    yaw_var : float
        The sensor noise in heading, ``dip_noise_var / cos^2(dip)``, rad^2.
    rest_floor_var : float
        Variance of the rest detector's low-passed rate about the true bias, (rad/s)^2.
    rest_rate_var_density : float
        ``gyro_noise^2``: the rest measurement's variance times dt, (rad/s)^2 s.
    gyro_var, bias_walk_var : float
        ``gyro_noise^2``, (rad/s)^2 / Hz, and
        ``gyro_bias_walk^2``, (rad/s)^2 / s.
    accel_var : float
        ``accel_noise^2``, (fraction of g)^2.
    settled_var : float
        Heading variance below which the innovation gate applies, rad^2.
    adopt_var : float
        Heading variance added when the gate adopts a new reference, rad^2.
    scale_var : float
        ``gyro_scale_error^2`` times its correlation time, s.
    attenuation2 : float
        The inertial low-pass's attenuation of motion at the motion time scale, squared.
    """

    tan_dip2: float
    cos_dip2: float
    env_floor_var: float
    dip_noise_var: float
    yaw_var: float
    rest_floor_var: float
    rest_rate_var_density: float
    gyro_var: float
    bias_walk_var: float
    accel_var: float
    settled_var: float
    adopt_var: float
    scale_var: float
    attenuation2: float

    @classmethod
    def from_config(cls, config: FilterConfig) -> "FilterCoefficients":
        dip = math.radians(config.dip_deg)
        cos_dip2 = math.cos(dip) ** 2
        dip_noise_var = (config.mag_noise / config.field_norm) ** 2
        return cls(
            tan_dip2=math.tan(dip) ** 2, cos_dip2=cos_dip2,
            env_floor_var=math.radians(config.mag_heading_sigma_deg) ** 2,
            dip_noise_var=dip_noise_var, yaw_var=dip_noise_var / cos_dip2,
            rest_floor_var=config.gyro_noise**2 / (2.0 * _REST_TAU_S) + _REST_RATE_SIGMA**2,
            rest_rate_var_density=config.gyro_noise**2,
            gyro_var=config.gyro_noise**2, bias_walk_var=config.gyro_bias_walk**2, accel_var=config.accel_noise**2,
            settled_var=math.radians(config.heading_tolerance_deg / 3.0) ** 2,
            adopt_var=math.radians(3.0 * config.heading_tolerance_deg) ** 2,
            scale_var=config.gyro_scale_error**2 * _SCALE_CORRELATION_S,
            attenuation2=_attenuation(config.motion_time_s / (2.0 * math.pi * config.accel_time_constant_s),
                                      config.accel_lowpass_order) ** 2)


def _attenuation(ratio: float, order: int) -> float:
    """The inertial low-pass's gain at the motion's time scale, ``ratio = tau_v / (2 pi tau)`` (well below 1):
    ``ratio`` for the first-order one, ``2 ratio^2`` for the Butterworth (cut-off ``sqrt 2 / tau``)."""
    return ratio if order == 1 else 2.0 * ratio * ratio


SKIP_REASONS = ("t_s not finite", "t_s went back", "t_s jumped ahead",
                "gyro not finite", "gyro out of range", "accel not finite", "accel out of range",
                "field not finite", "field out of range")
"""Why a sample (or one sensor's part of it) was skipped, never fused."""


@dataclass(slots=True)
class SkipCounts:
    """Samples (or one sensor's part of them) skipped as bad input, by reason (:data:`SKIP_REASONS`).

    A non-finite value or one beyond the sensor's range is never fused and never disables the
    sensor: the next good sample is used as usual.
    """

    t_s_not_finite: int = 0
    t_s_went_back: int = 0
    t_s_jumped_ahead: int = 0
    gyro_not_finite: int = 0
    gyro_out_of_range: int = 0
    accel_not_finite: int = 0
    accel_out_of_range: int = 0
    field_not_finite: int = 0
    field_out_of_range: int = 0

    def count(self, reason: str) -> None:
        """Count one skip for ``reason`` (one of :data:`SKIP_REASONS`)."""
        name = reason.replace(" ", "_")
        setattr(self, name, getattr(self, name) + 1)

    @property
    def total(self) -> int:
        return sum(getattr(self, f.name) for f in fields(self))

    def as_dict(self) -> dict[str, int]:
        """``{reason: count}`` for the reasons that occurred."""
        return {r: getattr(self, r.replace(" ", "_")) for r in SKIP_REASONS if getattr(self, r.replace(" ", "_"))}


@dataclass(slots=True)
class Diagnostics:
    """What the filter did with the latest sample (updated in place each sample: copy to keep).

    Attributes
    ----------
    field_ratio : float
        Measured |B| over the gate's reference |B|.
    dip_deg : float
        Measured dip against the filter's up direction, degrees.
    mag_used : bool
        The gate let the field in and the heading update was applied.
    gate : str
        ``"ok"``, or why the field was not used: ``"norm"``, ``"dip"``, ``"innovation"``, ``"absent"``,
        ``"rail"`` (waits for the tilt a gyro axis held at its rail left open: :mod:`compass.filter._rail`),
        ``"magnet"`` (a magnet told on the housing, the sample not agreeing with the gyro's heading:
        :mod:`compass.filter._place`).
    accel_used : bool
        The accelerometer (tilt) update was applied.
    skipped : str
        ``""``, or the reasons (:data:`SKIP_REASONS`, comma-separated) this sample's parts were skipped.
    """

    field_ratio: float = 1.0
    dip_deg: float = 0.0
    mag_used: bool = False
    gate: str = "absent"
    accel_used: bool = False
    skipped: str = ""


@dataclass(frozen=True, slots=True)
class Estimate:
    """The filter's output after one sample.

    Built once a sample (``compass live``): it keeps the filter's tuples and makes the arrays
    (:attr:`matrix`, :attr:`rotation`, :attr:`gyro_bias`) only when they are read.

    Attributes
    ----------
    t_s : float
        Sample time, seconds.
    matrix_rows : tuple of 9 floats
        ``R_world<-housing`` (NWU world, FLU housing), row-major; :attr:`matrix` is the array,
        :attr:`rotation` the same as a Rotation.
    heading_deg, pitch_deg, roll_deg : float
        SPEC section 1 angles.
    heading_sigma_deg, tilt_sigma_deg : float
        1-sigma of the world-frame error about the vertical and (rms) about a horizontal axis,
        degrees, from the filter covariance.
    field_heading_sigma_deg : float
        Heading error of the accepted field itself, degrees: the larger of ``mag_heading_sigma_deg``
        and the one measured so far from the wander of its dip (module docstring); NaN for the
        two-vector filter.
    field_ratio, dip_deg, mag_used, gate, accel_used, skipped
        As in :class:`Diagnostics`.
    gyro_bias_rad_s : tuple of 3 floats, or None
        Estimated gyro bias in H, rad/s (gyro filter only); :attr:`gyro_bias` is the array.
    """

    t_s: float
    matrix_rows: tuple
    heading_deg: float
    pitch_deg: float
    roll_deg: float
    heading_sigma_deg: float
    tilt_sigma_deg: float
    field_heading_sigma_deg: float
    field_ratio: float
    dip_deg: float
    mag_used: bool
    gate: str
    accel_used: bool
    gyro_bias_rad_s: tuple | None
    skipped: str = ""

    @property
    def matrix(self) -> np.ndarray:
        """``R_world<-housing``, shape (3, 3)."""
        return np.array(self.matrix_rows).reshape(3, 3)

    @property
    def rotation(self) -> Rotation:
        """``R_world<-housing`` as a scipy Rotation."""
        return Rotation.from_matrix(self.matrix)

    @property
    def gyro_bias(self) -> np.ndarray | None:
        """Estimated gyro bias in H, rad/s, shape (3,) (None without a gyro)."""
        return None if self.gyro_bias_rad_s is None else np.array(self.gyro_bias_rad_s)
