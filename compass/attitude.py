"""Heading, pitch and roll from the field in H and gravity, with per-row quality (SPEC section 1).

One field vector fixes only two of the three angles: the seed's runtime system (three equations,
one per field component, for heading, pitch and roll) has rank 2, since turning the housing about
the field's own direction changes no output.  So :func:`solve_attitude` needs one of

- an accelerometer (``accel``): the optimal two-vector (Wahba) solution, weights from both
  sensors' noise, full heading/pitch/roll with propagated 1-sigma uncertainties;
- known pitch and roll (``pitch_deg``, ``roll_deg``): heading only;
- ``level=True``: pitch = roll = 0 assumed, heading with the worst-case error that a tilt up to
  ``max_tilt_deg`` would cause, and the tilt the field itself shows (a lower bound);

and refuses otherwise, naming the missing information.

The field's reference direction is the site's (:mod:`compass.site`), never the bench session's: a
:class:`~compass.site.ReferenceField` from the WMM at a given site, or estimated from the recording's
own quiet rows.  Its dip uncertainty, and each row's own dip discrepancy beyond its noise, enter the
two-vector weight (gravity primary: the field then fixes heading, and neither an uncertain dip nor
a disturbed row can pull the tilt), and ``disturbed`` is judged against it.

World frame NWU (magnetic north), housing FLU, ``R_world<-housing = Rz(-heading) Ry(-pitch)
Rx(roll)``; an accelerometer at rest reads +1 g along the housing's up direction.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from .frames import heading_pitch_roll, r_world_from_housing, world_field
from .model import SensorModel
from .sample_check import FIELD_RATIO_LIMIT, skip_codes
from .site import ReferenceField, reference_from_recording

__all__ = ["Attitude", "UnusableCalibration", "ScaleMismatch", "solve_attitude",
           "two_vector_rotation", "level_heading_bound_deg"]

_UP = np.array([0.0, 0.0, 1.0])
DIP_NOISE_SIGMAS = 2.0
"""A row's dip discrepancy within this many of its sigmas is noise; beyond, it lowers the field's weight."""


class UnusableCalibration(ValueError):
    """The calibration, not the recording, makes every row unusable (the command names the calibration file)."""


class ScaleMismatch(ValueError):
    """The recording's readings are beyond anything the calibration's responses give: one of them is in
    another unit or scale than the other (the command names both files)."""


@dataclass(frozen=True)
class Attitude:
    """Attitude per sample and its quality.

    Attributes
    ----------
    mode : {"accelerometer", "known_tilt", "level"}
    heading_deg, pitch_deg, roll_deg : ndarray, shape (n,)
        SPEC section 1: heading in [0, 360) clockwise from magnetic north, pitch in [-90, 90]
        (+X up positive), roll in (-180, 180] (right side down positive).
    heading_sigma_deg : ndarray, shape (n,)
        Propagated 1-sigma heading error: sensor noise, and the calibration's direction, offset
        and gain uncertainty where the file gives it (in ``level`` mode without the tilt error,
        which ``heading_bound_deg`` bounds).  Grows without limit as pitch nears +-90 degrees,
        where heading is undefined.
    pitch_sigma_deg, roll_sigma_deg : ndarray, shape (n,), or None
        ``accelerometer`` mode only.
    field_ratio : ndarray, shape (n,)
        Measured |B| over the calibrated |B|.
    dip_deg : ndarray, shape (n,)
        Measured angle of the field below the horizontal (from the field-gravity angle); in
        ``level`` mode below the housing's XY plane.
    in_range : ndarray of bool, shape (n,)
        Every channel inside its calibrated range.
    disturbed : ndarray of bool, shape (n,)
        |B| or dip differ from the calibration by more than noise and tolerance allow: a magnetic
        disturbance, an acceleration besides gravity, or (``level``) more tilt than assumed.
    heading_bound_deg : ndarray, shape (n,), or None
        ``level`` mode: the largest heading error a tilt up to ``max_tilt_deg`` causes.
    tilt_min_deg : ndarray, shape (n,), or None
        ``level`` mode: the tilt the field proves, a lower bound at 95 % or more: a tilt moves the
        apparent dip by at most itself, so ``max(0, |apparent dip - dip| - 2 sigma)``; 0 on a level
        housing but for 4.6 % of rows (``|z| > 2``).
    reference : ReferenceField or None
        The reference field the rows were solved and judged against, and where it came from.
    heading_true_deg, heading_true_sigma_deg : ndarray, shape (n,), or None
        With a site (the reference knows the declination): ``heading + declination`` in [0, 360)
        and its 1-sigma, the WMM's declination uncertainty included.
    skipped : ndarray of int, shape (n,), or None
        Rows never solved, by reason (:data:`compass.sample_check.SKIP_REASONS`: a non-finite or
        absurd field or accelerometer reading); their angles and sigmas are NaN and they count
        as ``disturbed``.  None: every row was solved.
    """

    mode: str
    heading_deg: np.ndarray
    pitch_deg: np.ndarray
    roll_deg: np.ndarray
    heading_sigma_deg: np.ndarray
    field_ratio: np.ndarray
    dip_deg: np.ndarray
    in_range: np.ndarray
    disturbed: np.ndarray
    pitch_sigma_deg: np.ndarray | None = None
    roll_sigma_deg: np.ndarray | None = None
    heading_bound_deg: np.ndarray | None = None
    tilt_min_deg: np.ndarray | None = None
    reference: ReferenceField | None = None
    heading_true_deg: np.ndarray | None = None
    heading_true_sigma_deg: np.ndarray | None = None
    skipped: np.ndarray | None = None

    def columns(self) -> dict[str, np.ndarray]:
        """Output columns in file order (SPEC section 2's attitude output); absent ones left out."""
        names = ("heading_deg", "pitch_deg", "roll_deg", "heading_sigma_deg", "pitch_sigma_deg",
                 "roll_sigma_deg", "heading_true_deg", "heading_true_sigma_deg", "heading_bound_deg", "tilt_min_deg", "field_ratio", "dip_deg",
                 "in_range", "disturbed")
        skipped = np.zeros(len(self.heading_deg), dtype=int) if self.skipped is None else self.skipped
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None} | {"skipped": skipped}


def two_vector_rotation(up_h, field_h, dip_deg: float, field_weight: float) -> Rotation:
    """Optimal rotation for the two-vector Wahba problem, closed form, vectorised.

    Minimises ``w_g |z - R u|^2 + w_B |b_W - R m|^2`` over rotations ``R = R_world<-housing``,
    with ``u``, ``m`` the unit measured up and field directions in H and ``z``, ``b_W`` their
    NWU references (``b_W`` from the dip).  ``B = sum w r b^T`` has rank 2, so the optimum maps
    the measured plane's normal ``u x m`` onto the references' normal ``z x b_W``; inside that
    plane it turns by

    .. math:: \\theta = \\arg\\big( (1 - f) + f e^{i(\\rho - \\beta)} \\big),
              \\qquad f = \\frac{w_B}{w_g + w_B}

    from the solution that puts ``u`` on ``z`` exactly (TRIAD with gravity first), with
    ``beta``, ``rho`` the measured and reference angles between the two vectors.  Equal to
    ``Rotation.align_vectors([z, b_W], [u, m], weights=[w_g, w_B])`` (checked in the tests).

    Parameters
    ----------
    up_h, field_h : array_like, shape (n, 3)
        Measured up (accelerometer) and field directions in H; any length, not parallel.
    dip_deg : float
        Reference dip.
    field_weight : float
        ``f`` in [0, 1]; 0 aligns ``up_h`` exactly (tilt known or assumed).

    Returns
    -------
    Rotation
        ``R_world<-housing``, n rotations.
    """
    up = np.atleast_2d(np.asarray(up_h, dtype=float)).T
    field = np.atleast_2d(np.asarray(field_h, dtype=float)).T
    rows = _two_vector_rows(up / np.sqrt(_dot(up, up)), field, dip_deg, field_weight)
    return Rotation.from_matrix(_matrix(rows), assume_valid=True)


def _two_vector_rows(u, m, dip_deg: float, field_weight: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows (north, west, up) of :func:`two_vector_rotation`'s matrix, each (3, n), from the unit
    up vectors ``u`` and field vectors ``m`` given component-major, shape (3, n)."""
    if not np.all((0.0 <= field_weight) & (field_weight <= 1.0)):
        raise ValueError(f"field_weight must be in [0, 1], got {field_weight}")
    mu = _dot(m, u)
    along = m - mu * u  # in the plane, perpendicular to u, toward m
    along_norm = np.sqrt(_dot(along, along))
    along /= along_norm
    normal = _cross(u, along)  # = u x m / |u x m|
    # reference triad: up, north, west = up x b_W / |.|; b_W at angle rho from up toward north
    rho = np.radians(90.0 + dip_deg)
    beta = np.arctan2(along_norm, mu)
    theta = np.angle((1.0 - field_weight) + field_weight * np.exp(1j * (rho - beta)))
    c, s = np.cos(theta), np.sin(theta)
    # R = (cos t up + sin t north) u^T + (-sin t up + cos t north) along^T + west normal^T
    return s * u + c * along, normal, c * u - s * along


def solve_attitude(
    model: SensorModel,
    raw,
    *,
    accel=None,
    pitch_deg=None,
    roll_deg=None,
    level: bool = False,
    reference: ReferenceField | None = None,
    accel_noise_g: float = 0.002,
    max_tilt_deg: float = 5.0,
    disturbance_sigma: float = 5.0,
    field_tolerance: float = 0.02,
    dip_tolerance_deg: float = 1.0,
    temp_c=None,
) -> Attitude:
    """Attitude of every sample from the channel outputs and gravity (or a known/assumed tilt).

    Parameters
    ----------
    model : SensorModel
        Needs ``noise`` (the calibration's ``noise_floor``).  Its ``dip_deg`` (the bench's) is not used.
    raw : array_like, shape (n, c)
        Channel outputs in the order of ``model.channels``.
    accel : array_like, shape (n, 3), optional
        Accelerometer in H, any unit (specific force: +up at rest).
    pitch_deg, roll_deg : array_like, shape (n,), optional
        Known pitch and roll (both or neither), degrees, taken as exact.
    level : bool
        Assume pitch = roll = 0.
    reference : ReferenceField, optional
        The site's field (:func:`compass.site.reference_from_site`); default: estimated from the
        recording's quiet rows (:func:`compass.site.reference_from_recording`).
    accel_noise_g : float
        Accelerometer white noise per axis as a fraction of 1 g (default 0.002).
    max_tilt_deg : float
        ``level`` mode: the largest tilt the assumption allows, for ``heading_bound_deg``.
    disturbance_sigma, field_tolerance, dip_tolerance_deg : float
        A row is ``disturbed`` when ``|field_ratio - 1|`` exceeds ``max(k sigma, field_tolerance)``
        or the dip error exceeds ``max(k sigma, dip_tolerance_deg)`` (``level``: the tilt it shows
        exceeds ``max_tilt_deg`` by more than that), ``k = disturbance_sigma``; sigma counts the
        row's noise and calibration uncertainty and the reference's.
    temp_c : array_like, shape (n,), optional
        Sensor temperature, degC: applies the calibration's ``temperature`` effect
        (:meth:`compass.model.SensorModel.field`).

    Returns
    -------
    Attitude

    Raises
    ------
    ValueError
        No gravity and no tilt (the field alone fixes two angles of three), more than one
        source of tilt, a calibration without noise, or no reference and too few quiet rows to
        estimate one.
    UnusableCalibration
        The calibration's noise is out of any sensible range.

    Notes
    -----
    With ``R`` the estimate and ``eps`` the world-frame rotation error, the Wahba solution's
    linearisation gives ``eps = H^-1 sum_i w_i [r_i]x^T dm_i`` with ``H = sum_i w_i (I - r_i r_i^T)``;
    the measurement errors ``dm_i`` of the unit vectors come from ``model.component_variance`` (and a
    tumble file's hard iron, soft iron and rotation sigmas, ``model.iron_uncertainty``) and
    ``accel_noise_g``.  The angles' sensitivities to ``eps`` are the inverse Euler-rate relations
    (``d heading = eps_z + tan(pitch) eps . x_horizontal``), so heading sigma grows as pitch nears
    +-90 degrees.

    **Reference dip uncertainty.**  The solution maps the measured plane's normal ``u x m`` onto
    the references' (West): that fixes heading and needs no dip.  The dip only sets the rotation
    ``theta`` inside the plane (about West), which gravity fixes at 0 and the field at
    ``rho - beta`` (reference minus measured field-gravity angle).  A reference dip error
    ``delta`` is an error of the field's vote, so the optimal weight of the field is

    .. math:: f = \\frac{\\sigma_g^2}{\\sigma_g^2 + \\sigma_B^2 + \\sigma_{dip}^2}

    (per-axis variances of the unit vectors, rad^2): with ``sigma_dip`` large the solution is
    gravity first (TRIAD) and the dip cannot pull the tilt.  What is left moves the solution by
    ``f delta`` about West (``H^-1`` leaves West alone), adding ``f^2 sigma_dip^2 g_W^2`` to the
    variance of an angle with ``g = H^-1 j``.

    **Each row's own evidence.**  A row whose measured dip differs from the reference by more than
    twice its noise shows a dip error the reference's sigma does not cover (a magnet nearby, iron in
    the product, a wrong site): ``sigma_dip^2`` of that row adds the excess
    ``max(0, (dip - dip_ref)^2 - (2 sigma_{dip,row})^2)`` (:data:`DIP_NOISE_SIGMAS`; within it a
    discrepancy is noise, and the weight stays the optimal one of a right reference).  The pull ``f delta`` then stays below about
    ``sigma_g^2 / (2 sqrt(sigma_g^2 + sigma_B^2))`` whatever ``delta`` is (a few hundredths of a
    degree), instead of growing with it; a row flagged ``disturbed`` gets ``f = 0`` (its field votes
    for heading only).
    """
    sources = [name for name, given in (("accel", accel is not None), ("pitch_deg/roll_deg", pitch_deg is not None
                                         or roll_deg is not None), ("level", level)) if given]
    if not sources:
        raise ValueError("the field alone fixes only two of heading, pitch and roll (the seed's three equations "
                         "have rank 2): give accelerometer columns ax,ay,az, known pitch_deg and roll_deg "
                         "columns, or assume a level housing (--level)")
    if len(sources) > 1:
        raise ValueError(f"give one source of tilt, got {' and '.join(sources)}")
    if model.noise is None:
        raise ValueError("the calibration has no noise_floor: the solution cannot be weighted nor its "
                         "uncertainty propagated")
    if not accel_noise_g > 0:
        raise ValueError(f"accel_noise_g must be positive, got {accel_noise_g}")

    field, in_range = model.field(raw, temp_c)
    skipped = _skipped_rows(field, accel, model.field_norm)
    options = dict(level=level, reference=reference, accel_noise_g=accel_noise_g, max_tilt_deg=max_tilt_deg,
                   disturbance_sigma=disturbance_sigma, field_tolerance=field_tolerance,
                   dip_tolerance_deg=dip_tolerance_deg)
    if skipped.any():  # solve the rows that may be used; the others are flagged, never solved nor averaged
        keep = skipped == 0
        if not keep.any():
            if np.all(np.isfinite(np.asarray(raw, dtype=float))):
                _check_scale(model, np.asarray(raw, dtype=float))  # the two do not fit, if the scale is not
                raise UnusableCalibration("the calibration turns every reading into a non-finite or absurd field (its "
                                          "offsets or gains are out of any sensible range)")
            raise ValueError("no row can be used: every reading is non-finite or absurd")

        def rows_of(x):
            return None if x is None or np.ndim(x) == 0 else np.asarray(x)[keep]

        solved = _solve(model, field[keep], in_range[keep], accel=rows_of(accel), pitch_deg=rows_of(pitch_deg),
                        roll_deg=rows_of(roll_deg), **options)
        return _with_skipped(solved, keep, skipped, in_range)
    return _solve(model, field, in_range, accel=accel, pitch_deg=pitch_deg, roll_deg=roll_deg, **options)


def _solve(model: SensorModel, field: np.ndarray, in_range: np.ndarray, *, accel, pitch_deg, roll_deg, level: bool,
           reference, accel_noise_g: float, max_tilt_deg: float, disturbance_sigma: float, field_tolerance: float,
           dip_tolerance_deg: float) -> Attitude:
    """:func:`solve_attitude` on rows whose field (in H, shape (n, 3)) is already solved and usable."""
    n = len(field)
    var = np.ascontiguousarray(model.component_variance(field).T)  # (c, n)
    b = np.ascontiguousarray(field.T)  # component-major (3, n): elementwise work on contiguous rows
    b_norm = np.sqrt(_dot(b, b))
    m = b / b_norm

    a_norm = None
    if accel is not None:
        a = np.asarray(accel, dtype=float)
        if a.shape != (n, 3):
            raise ValueError(f"expected accel of shape ({n}, 3), got {a.shape}")
        a = np.ascontiguousarray(a.T)
        a_norm = np.sqrt(_dot(a, a))
        if np.any(a_norm == 0):
            raise ValueError(f"accelerometer reads zero at sample {int(np.argmax(a_norm == 0))}")
        up, up_var, mode = a / a_norm, accel_noise_g**2, "accelerometer"
    elif level:
        if not 0 <= max_tilt_deg < 90:
            raise ValueError(f"max_tilt_deg must be in [0, 90), got {max_tilt_deg}")
        up, up_var, mode = np.repeat(_UP[:, None], n, axis=1), 0.0, "level"
    else:
        if pitch_deg is None or roll_deg is None:
            raise ValueError("known tilt needs both pitch_deg and roll_deg")
        up = r_world_from_housing(0.0, pitch_deg, roll_deg).apply(_UP, inverse=True)
        if up.shape != (n, 3):
            raise ValueError(f"expected {n} pitch_deg and roll_deg values, got {len(up)}")
        up, up_var, mode = np.ascontiguousarray(up.T), 0.0, "known_tilt"
    if reference is None or not np.isfinite(reference.field_norm):
        own = reference_from_recording(field, up.T, a_norm)
        reference = own if reference is None else reference.complete(own)
    ref_dip = reference.dip_deg
    ref_dip_var = np.radians(reference.dip_sigma_deg) ** 2
    field_ratio = b_norm / reference.field_norm

    solver = model.solver
    # a tumble file's own uncertainty (hard iron, soft iron, rotation), one 3x3 a row: compass.iron_uncertainty
    iron = None if model.iron_uncertainty is None else model.iron_uncertainty.covariance(field).transpose(1, 2, 0)

    def field_quad(v):  # v^T Sigma_B v per sample, field units squared; v in H, (3, n)
        quad = sum(var[c] * _dot(solver[:, c, None], v) ** 2 for c in range(len(var)))
        return quad if iron is None else quad + np.einsum("in,ijn,jn->n", v, iron, v)

    mu = _dot(m, up)
    dip = np.degrees(np.arcsin(np.clip(-mu, -1.0, 1.0)))
    # sigma of the dip: d(m.u) = (Q_m u) . dB / |B| + (Q_u m) . du; the reference's adds
    qm = m - mu * up
    dip_sigma = np.degrees(np.sqrt((field_quad(up - mu * m) / b_norm**2 + up_var * _dot(qm, qm))
                                   / np.maximum(1.0 - mu**2, 1e-24) + ref_dip_var))
    ratio_sigma = np.hypot(np.sqrt(field_quad(m)) / reference.field_norm,
                           reference.field_sigma / reference.field_norm)
    field_bad = np.abs(field_ratio - 1.0) > np.maximum(disturbance_sigma * ratio_sigma, field_tolerance)
    dip_limit = np.maximum(disturbance_sigma * dip_sigma, dip_tolerance_deg)
    dip_error = np.abs(dip - ref_dip)

    # Wahba weights from noise: per-axis variance of each unit vector (field: at zero field); on the
    # field's side the reference dip's variance and the row's own dip discrepancy beyond 2 sigma (Notes)
    field_var = np.sum(model.component_variance(np.zeros(3)) * model.solver**2) / 3.0 / reference.field_norm**2
    if not np.isfinite(field_var):
        raise UnusableCalibration(f"the calibration's noise_floor and gains give a field noise of {field_var:g} "
                                  "(rad^2): out of any sensible range")
    excess = np.radians(dip - ref_dip) ** 2 - (DIP_NOISE_SIGMAS * np.radians(dip_sigma)) ** 2
    dip_var = ref_dip_var + np.maximum(excess, 0.0)
    disturbed = field_bad | (dip_error > dip_limit)
    f = np.where(disturbed, 0.0, up_var / (up_var + field_var + dip_var)) if up_var > 0 else 0.0
    rows = _two_vector_rows(up, m, ref_dip, f)
    heading, pitch, roll = heading_pitch_roll(Rotation.from_matrix(_matrix(rows), assume_valid=True))

    if mode == "accelerometer":
        sig = _wahba_sigmas(rows, heading, pitch, field_quad, b_norm, up_var, f, ref_dip, dip_var)
        return _with_true_north(Attitude(mode, heading, pitch, roll, sig[0], field_ratio, dip, in_range,
                                         disturbed, pitch_sigma_deg=sig[1], roll_sigma_deg=sig[2],
                                         reference=reference))
    # tilt exact: only the rotation about the vertical is left, fixed by the field's west component
    heading_sigma = np.degrees(np.sqrt(field_quad(rows[1])) / (b_norm * np.sqrt(1.0 - mu**2)))
    if mode == "known_tilt":
        return _with_true_north(Attitude(mode, heading, pitch, roll, heading_sigma, field_ratio, dip, in_range,
                                         disturbed, reference=reference))
    bound = np.full(n, level_heading_bound_deg(ref_dip, max_tilt_deg))
    return _with_true_north(Attitude(mode, heading, np.zeros(n), np.zeros(n), heading_sigma, field_ratio, dip,
                                     in_range, field_bad | (dip_error > max_tilt_deg + dip_limit),
                                     heading_bound_deg=bound, tilt_min_deg=np.maximum(dip_error - 2.0 * dip_sigma, 0.0),
                                     reference=reference))


def _skipped_rows(field: np.ndarray, accel, field_norm) -> np.ndarray:
    """Per row, the reason code it must not be solved (0: fine): |B| against the calibration's (else the
    recording's typical |B|), |a| against the recording's typical |a|."""
    with np.errstate(over="ignore", invalid="ignore"):
        b = np.linalg.norm(field, axis=1)
        a = None if accel is None else np.linalg.norm(np.asarray(accel, dtype=float), axis=1)
        typical = [float(np.median(x[np.isfinite(x)])) if x is not None and np.isfinite(x).any() else np.nan
                   for x in (b, a)]
    known = field_norm is not None and np.isfinite(field_norm) and field_norm > 0
    return skip_codes(field, field_norm if known else typical[0], accel, typical[1])


def _check_scale(model: SensorModel, raw: np.ndarray) -> None:
    """:class:`ScaleMismatch` when a channel's median reading is beyond what the calibration's response gives
    for any field up to :data:`~compass.sample_check.FIELD_RATIO_LIMIT` times its |B|: the recording and the
    calibration are in different units or scales (which one is wrong, the numbers cannot tell)."""
    reach = FIELD_RATIO_LIMIT * model.field_norm
    for c, response in enumerate(model.responses):
        lo, hi = np.sort(response.output(np.array([-reach, reach])))
        typical = float(np.median(raw[:, c]))
        if not lo <= typical <= hi:
            raise ScaleMismatch(f"channel {model.channels[c]} reads {typical:.4g} (median), beyond the {lo:.4g} to "
                                f"{hi:.4g} the calibration's channel gives for any field up to "
                                f"{FIELD_RATIO_LIMIT:g} times its |B|: is one in another unit or scale than the other?")


def _with_skipped(att: Attitude, keep: np.ndarray, skipped: np.ndarray, in_range: np.ndarray) -> Attitude:
    """``att`` (solved on the rows ``keep``) spread over every row: the skipped ones NaN and disturbed."""
    def spread(name, value):
        if name == "in_range":
            return in_range
        full = np.ones(len(keep), dtype=bool) if name == "disturbed" else np.full(len(keep), np.nan)
        full[keep] = value
        return full
    arrays = {f.name: spread(f.name, getattr(att, f.name)) for f in fields(att)
              if isinstance(getattr(att, f.name), np.ndarray)}
    return replace(att, **arrays, skipped=skipped)


def _with_true_north(att: Attitude) -> Attitude:
    """Add the true heading when the reference knows the declination (SPEC: east-positive,
    ``heading_true = heading + declination``); its variance adds the declination's."""
    ref = att.reference
    if ref is None or ref.declination_deg is None:
        return att
    true = np.mod(att.heading_deg + ref.declination_deg, 360.0)
    true[true >= 360.0] = 0.0
    sigma = np.hypot(att.heading_sigma_deg, ref.declination_sigma_deg or 0.0)
    return replace(att, heading_true_deg=true, heading_true_sigma_deg=sigma)


@lru_cache(maxsize=64)
def level_heading_bound_deg(dip_deg: float, max_tilt_deg: float) -> float:
    """Largest heading error from assuming a level housing that is tilted by up to ``max_tilt_deg``.

    The level solution reads heading as the azimuth of the field in the housing's XY plane;
    a tilt ``tau`` moves it by about ``tan(dip) tau`` (first order) and by up to 180 degrees when
    ``tau`` approaches ``90 - dip``.  Evaluated exactly on a dense grid of headings and tilts of
    magnitude ``max_tilt_deg`` (the error grows with the tilt), degrees in [0, 180].
    """
    if max_tilt_deg == 0:
        return 0.0
    tau = np.radians(max_tilt_deg)
    heading = np.arange(0.0, 360.0, 0.5)
    pitch = np.degrees(tau * np.sin(np.linspace(-np.pi / 2, np.pi / 2, 361)))
    roll = np.degrees(np.arccos(np.clip(np.cos(tau) / np.cos(np.radians(pitch)), -1.0, 1.0)))
    pitch, roll = np.concatenate([pitch, pitch]), np.concatenate([roll, -roll])
    h, p = np.meshgrid(heading, pitch, indexing="ij")
    r = np.broadcast_to(roll, h.shape)
    b = r_world_from_housing(h.ravel(), p.ravel(), r.ravel()).apply(world_field(dip_deg), inverse=True)
    error = np.degrees(np.arctan2(b[:, 1], b[:, 0])) - h.ravel()
    return float(np.max(np.abs(np.mod(error + 180.0, 360.0) - 180.0)))


def _wahba_sigmas(rows, heading, pitch, field_quad, b_norm, up_var, f, dip_deg, dip_var=0.0) -> list[np.ndarray]:
    """1-sigma heading, pitch, roll (degrees); see :func:`solve_attitude` Notes.

    ``Cov(eps) = H^-1 (w_g^2 S_g + w_B^2 S_B) H^-1`` with ``S_i = [r_i]x^T Sigma_i [r_i]x``.  An
    angle with world-frame sensitivity ``j`` (``d angle = j . eps``) and ``g = H^-1 j`` has variance
    ``w_g^2 sigma_g^2 |g x z|^2 + w_B^2 v^T Sigma_B v / |B|^2`` with ``v = R^T (b_W x g)`` in H
    (``R^T`` of a world axis is a row of ``R``: ``rows``), plus ``f^2 sigma_dip^2 g_W^2`` from the
    dip variance ``dip_var`` of the field's vote (rad^2; :func:`solve_attitude` Notes).  ``f`` and
    ``dip_var`` may be one value a row.
    """
    # H = I - (1 - f) z z^T - f b b^T with b = (c, 0, s) in NWU: West is its own axis (H_WW = 1) and the
    # north-up block [[1 - f c^2, -f c s], [-f c s, f c^2]] has determinant f (1 - f) c^2, so H^-1 is closed
    # form, one value a row.  f -> 0 (TRIAD) is a limit: H^-1 grows as 1/f about up while the field's
    # share f shrinks, their product finite, so a row with f = 0 is evaluated just beside it
    c_b, _, s_b = world_field(dip_deg)
    f = np.clip(np.broadcast_to(np.asarray(f, dtype=float), np.shape(heading)), 1e-9, 1.0 - 1e-9)  # f -> 1 alike
    det = f * (1.0 - f) * c_b**2
    inv_nn, inv_nu, inv_uu = f * c_b**2 / det, f * c_b * s_b / det, (1.0 - f * c_b**2) / det
    psi, theta = np.radians(-heading), np.radians(-pitch)  # scipy's ZYX yaw and pitch
    cp, sp, ct, tt = np.cos(psi), np.sin(psi), np.cos(theta), np.tan(theta)
    # world-frame rotation error eps -> d yaw, d pitch, d roll (inverse Euler-rate relations)
    sensitivities = ((tt * cp, tt * sp, 1.0), (-sp, cp, 0.0), (cp / ct, sp / ct, 0.0))
    sigmas = []
    for j_north, j_west, j_up in sensitivities:
        g_north, g_west, g_up = inv_nn * j_north + inv_nu * j_up, j_west, inv_nu * j_north + inv_uu * j_up
        c = (-s_b * g_west, s_b * g_north - c_b * g_up, c_b * g_west)  # b_W x g, world
        v = c[0] * rows[0] + c[1] * rows[1] + c[2] * rows[2]  # R^T (b_W x g), in H
        var = ((1.0 - f) ** 2 * up_var * (g_north**2 + g_west**2) + f**2 * field_quad(v) / b_norm**2
               + f**2 * dip_var * g_west**2)
        sigmas.append(np.degrees(np.sqrt(var)))
    return sigmas


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of component-major vectors, shape (3, n) (or (3, 1) against (3, n))."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of component-major vectors, shape (3, n)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _matrix(rows) -> np.ndarray:
    """Stack three component-major rows into matrices, shape (n, 3, 3)."""
    return np.stack(rows, axis=0).transpose(2, 0, 1)
