"""A calibration's own uncertainty, propagated to the field in the housing frame and to the heading.

A tumble file's (:class:`TumbleUncertainty`, below) and a channel form's (:class:`ChannelUncertainty`: a
four-flip's or an installation's direction covariances and offset and gain sigmas); either is
``SensorModel.calibration_uncertainty``, carried by ``FilterConfig.from_model`` and added to the filter's
heading sigma by :func:`with_calibration_sigma` (``compass live``, its replay and ``run_filter``).  A part the
file leaves undetermined (:attr:`TumbleUncertainty.undetermined`) is never read as zero: it takes a stated
prior (:data:`HARD_IRON_PRIOR`, :data:`SOFT_IRON_PRIOR`, :data:`ROTATION_PRIOR_DEG`), and
:func:`undetermined_words` says which part and what it adds to the heading sigma.

A tumble file writes ``B_H = C S (x - h)`` (``x`` the raw reading, recording units; ``h`` the hard
iron; ``S`` the soft iron, file units; ``C`` = ``mag_to_accel``) and, under ``tumble``, the standard
errors of ``h`` (``hard_iron_sigma``), of each entry of ``S`` (``soft_iron_sigma``; ``S`` is symmetric,
so ``S_ij`` and ``S_ji`` are one number) and of ``C``'s rotation vector (``misalignment_rotvec_sigma_deg``),
widened by the residual diagnosis when structure remained (``unexplained``).  To first order

.. math::

    \\delta B_H = -C S\\,\\delta h + C\\,\\delta S\\,(x - h) + \\delta\\theta \\times B_H ,
    \\qquad x - h = S^{-1} C^T B_H ,

with ``Exp(dtheta) C`` the perturbed rotation (for the few-degree rotations of a mounting, the
rotation vector's errors are ``dtheta``'s to within a few per cent).  The file gives sigmas, not the
correlations, so the parameters are taken as independent:

.. math::

    \\Sigma_B = (CS)\\,\\mathrm{diag}(\\sigma_h^2)\\,(CS)^T
      + \\sum_{i \\le j} \\sigma_{S,ij}^2\\, v_{ij} v_{ij}^T
      + [B_H]_\\times \\mathrm{diag}(\\sigma_\\theta^2) [B_H]_\\times^T ,
    \\qquad v_{ij} = C (e_i (x-h)_j + e_j (x-h)_i)\\ (i \\ne j), \\quad v_{ii} = C e_i (x-h)_i .

The first term is the four-flip's offset sigma (it is there at zero field), the other two its
direction and gain sigmas (they grow with the field); a rotation about the vertical turns the heading
whole, which a per-channel direction covariance would spread over three independent channels, so the
term is kept as one 3x3 covariance (:meth:`compass.model.SensorModel.field_covariance` adds it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["TumbleUncertainty", "ChannelUncertainty", "channel_priors", "joint_problem", "joint_weights",
           "CURVE_POWERS", "CURVE_FIELDS", "independent_joint", "with_calibration_sigma", "with_calibration_sigma_many",
           "undetermined_words",
           "HARD_IRON_PRIOR", "SOFT_IRON_PRIOR", "ROTATION_PRIOR_DEG",
           "ROTATION_PRIOR_AXIS_DEG"]

CURVE_POWERS = (2, 3, 5)
"""The powers of a response curve's coefficients, in the order :func:`joint_weights` takes them."""
CURVE_FIELDS = ("quadratic", "cubic", "quintic")
"""The name of each power of :data:`CURVE_POWERS`, in its order: the field of
:class:`~compass.response.CubicResponse` and of :class:`~compass.sim.bench.BenchPhysics` that holds it."""

HARD_IRON_PRIOR = 0.1
"""1-sigma of a hard-iron component the fit left undetermined, as a fraction of |B|: a product's iron moves the
offset by a fraction of the Earth's field (a few uT to tens); a stated prior, not a measurement."""
SOFT_IRON_PRIOR = 0.05
"""1-sigma of a soft-iron entry the fit left undetermined, as a fraction of the soft iron's scale
(``det(S)^(1/3)``): a few per cent of distortion, as the tumble fits here find on boards; a stated prior."""
ROTATION_PRIOR_DEG = 2.0
"""1-sigma of the magnetometer-to-accelerometer rotation when it was not determined (or not fitted), as the total
angle between the two frames (RMS), degrees: two sensors' axes on one board or in one package agree to a degree
or two in all (data sheets give their own alignment to +-1 deg, a board's assembly as much again), and that is a
statement about the angle between the frames, not about each component; a stated prior.  Each component of the
rotation vector takes :data:`ROTATION_PRIOR_AXIS_DEG`.  The mounting rotation alone: a fit without accelerometer
recovers the soft iron itself (a symmetric iron to thousandths of a degree of rotation), so nothing is added for
it (tools/bench_undetermined_prior.py)."""
ROTATION_PRIOR_AXIS_DEG = ROTATION_PRIOR_DEG / math.sqrt(3.0)
"""1-sigma of each component of the undetermined rotation vector, degrees (``ROTATION_PRIOR_DEG / sqrt(3)``:
three independent components of this sigma give a total angle of RMS :data:`ROTATION_PRIOR_DEG`)."""
JOINT_TOLERANCE = 1e-6
"""Relative disagreement accepted between a joint covariance's marginals and the sigmas beside it, and its
asymmetry and most negative eigenvalue (each parameter scaled by its own sigma; the direction's three by the
RMS direction sigma)."""


_COST_HEADINGS_DEG = np.arange(0.0, 360.0, 30.0)  # level headings the cost of a prior is averaged over


@dataclass(frozen=True, eq=False)
class TumbleUncertainty:
    """The standard errors of a tumble file's hard iron, soft iron and rotation (independent).

    Attributes
    ----------
    soft_iron : ndarray, shape (3, 3)
        ``S``, file units (field units per recording unit).
    mag_to_accel : ndarray, shape (3, 3)
        ``C`` (the identity when the file has none).
    hard_iron_sigma : ndarray, shape (3,)
        Recording units.
    soft_iron_sigma : ndarray, shape (3, 3)
        Of each entry of ``S`` (the upper triangle is used), file units.
    rotation_sigma_rad : ndarray, shape (3,)
        Of ``C``'s rotation vector, rad.
    undetermined : tuple of str
        The parts whose sigma the file does not give (a null or infinite entry: the fit could not determine
        them; no rotation fitted), in words with the prior each takes; their entries above hold that prior.
    prior : TumbleUncertainty or None
        The priors' part alone (the undetermined entries' priors, zeros elsewhere): what they add
        (:meth:`cost_deg`); None when nothing is undetermined.
    """

    soft_iron: np.ndarray
    mag_to_accel: np.ndarray
    hard_iron_sigma: np.ndarray
    soft_iron_sigma: np.ndarray
    rotation_sigma_rad: np.ndarray
    undetermined: tuple = ()
    prior: "TumbleUncertainty | None" = None

    def __post_init__(self):
        object.__setattr__(self, "undetermined", tuple(self.undetermined))
        for name, shape in (("soft_iron", (3, 3)), ("mag_to_accel", (3, 3)), ("hard_iron_sigma", (3,)),
                            ("soft_iron_sigma", (3, 3)), ("rotation_sigma_rad", (3,))):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise ValueError(f"{name} must be finite with shape {shape}, got {value.shape}")
            if name.endswith("sigma") or name.endswith("sigma_rad"):
                if np.any(value < 0):
                    raise ValueError(f"{name} must not be negative")
            object.__setattr__(self, name, value)

    @cached_property
    def _to_raw(self) -> np.ndarray:
        """``S^-1 C^T``: ``x - h`` from ``B_H``."""
        return np.linalg.solve(self.soft_iron, self.mag_to_accel.T)

    @cached_property
    def _hard_iron_term(self) -> np.ndarray:
        cs = self.mag_to_accel @ self.soft_iron
        return (cs * self.hard_iron_sigma**2) @ cs.T

    def covariance(self, field_h) -> np.ndarray:
        """Covariance of ``B_H`` from the calibration's parameters at the field ``field_h``.

        Parameters
        ----------
        field_h : array_like, shape (..., 3)
            Field in H, field units.

        Returns
        -------
        ndarray, shape (..., 3, 3)
            Field units squared (module docstring); an undetermined part's is its prior's.
        """
        b = np.asarray(field_h, dtype=float)
        x = np.einsum("ij,...j->...i", self._to_raw, b)  # x - h, recording units
        cov = np.broadcast_to(self._hard_iron_term, b.shape[:-1] + (3, 3)).copy()
        c = self.mag_to_accel
        for i in range(3):
            for j in range(i, 3):
                sigma = self.soft_iron_sigma[i, j]
                if sigma == 0.0:
                    continue
                v = c[:, i] * x[..., j, None] + (c[:, j] * x[..., i, None] if i != j else 0.0)
                cov += sigma**2 * v[..., :, None] * v[..., None, :]
        s2 = self.rotation_sigma_rad**2
        if np.any(s2 > 0):
            bx = _skew(b)
            cov += np.einsum("...ik,k,...jk->...ij", bx, s2, bx)
        return cov


    @cached_property
    def _scalars(self) -> tuple:
        """The heading sigma's constants as Python floats: ``(CS)^T``, ``C^T`` and ``S^-1 C^T`` row by row, the
        hard iron's and the rotation's variances, and ``(i, j, sigma_S,ij^2)`` on and above the diagonal."""
        rows = lambda m: tuple(tuple(float(v) for v in row) for row in m)  # noqa: E731
        soft = tuple((i, j, float(self.soft_iron_sigma[i, j]) ** 2) for i in range(3) for j in range(i, 3)
                     if self.soft_iron_sigma[i, j] > 0.0)
        return (rows((self.mag_to_accel @ self.soft_iron).T), rows(self.mag_to_accel.T), rows(self._to_raw),
                tuple(float(v) ** 2 for v in self.hard_iron_sigma), tuple(float(v) ** 2 for v in self.rotation_sigma_rad),
                soft)

    def heading_sigma_deg(self, matrix, field_h) -> float:
        """The heading's 1-sigma from the calibration alone at one attitude, the tilt taken as known, degrees.

        A field error ``dB`` turns the field's horizontal part ``B_h`` by ``dB . n / |B_h|``, ``n`` the unit
        horizontal direction across it (``up x B / |B_h|`` in H, ``up`` the third row of ``R_world<-H``): the
        variance is ``n^T Sigma_B n / |B_h|^2``, as :func:`compass.attitude.solve_attitude` with a known tilt,
        wherever the reference field points (the live filter's North may have moved with a new place).
        The module docstring's three terms as scalar quadratic forms in ``n``, on Python floats (it runs on
        every live sample).

        Parameters
        ----------
        matrix : sequence of 9 floats, or array_like of shape (3, 3)
            ``R_world<-housing`` (NWU world), e.g. the live filter's.
        field_h : sequence of 3 floats
            The calibrated field in H (what the filter takes), field units.

        Returns
        -------
        float
            Degrees; ``inf`` when the field is vertical.
        """
        cs_t, c_t, to_raw, hard_var, rot_var, soft = self._scalars
        r = np.ravel(matrix) if not isinstance(matrix, (list, tuple)) or len(matrix) != 9 else matrix
        ux, uy, uz = float(r[6]), float(r[7]), float(r[8])
        bx, by, bz = (float(v) for v in field_h)
        n = (uy * bz - uz * by, uz * bx - ux * bz, ux * by - uy * bx)  # up x B: |n| = |B_h|
        horizontal2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2]
        if not horizontal2 > 0.0:
            return float("inf")
        dot = lambda row, v: row[0] * v[0] + row[1] * v[1] + row[2] * v[2]  # noqa: E731
        var = sum(h * dot(row, n) ** 2 for h, row in zip(hard_var, cs_t))
        u = [dot(row, n) for row in c_t]  # C^T n
        x = [dot(row, (bx, by, bz)) for row in to_raw]  # x - h
        for i, j, v in soft:  # n . v_ij: u_i x_j + u_j x_i, u_i x_i on the diagonal
            var += v * (u[i] * x[j] + u[j] * x[i] if i != j else u[i] * x[i]) ** 2
        turned = (by * n[2] - bz * n[1], bz * n[0] - bx * n[2], bx * n[1] - by * n[0])  # B x n
        var += sum(w * t * t for w, t in zip(rot_var, turned))
        return math.degrees(math.sqrt(var) / horizontal2)

    def cost_deg(self, field_norm: float, dip_deg: float) -> float:
        """What the undetermined parts' priors (:attr:`prior`) add to the heading sigma of a level housing, RMS
        over headings, degrees (0 when nothing is undetermined).

        Parameters
        ----------
        field_norm : float
            |B|, field units.
        dip_deg : float
            The field's dip, degrees.
        """
        return _cost_deg(self.prior, field_norm, dip_deg)


def _cost_deg(prior, field_norm: float, dip_deg: float) -> float:
    """RMS over level headings of ``prior.heading_sigma_deg``, degrees; 0 for no prior."""
    if prior is None:
        return 0.0
    from .frames import r_world_from_housing, world_field

    rot = r_world_from_housing(_COST_HEADINGS_DEG, 0.0, 0.0)
    fields = rot.apply(world_field(dip_deg, field_norm), inverse=True)
    var = [prior.heading_sigma_deg(m, b) ** 2 for m, b in zip(rot.as_matrix(), fields)]
    return float(np.sqrt(np.mean(var)))


@dataclass(frozen=True, eq=False)
class ChannelUncertainty:
    """A channel-form calibration's own uncertainty (a four-flip's, widened when structure remained; an
    installation's): each channel's sensing-direction covariance and offset and gain sigmas, the field's
    covariance through the solver ``P`` (``B_H = P x``).

    Per channel ``c`` (:meth:`compass.model.SensorModel.component_variance`, whose calibration part this is):

    .. math::

        \\mathrm{var}_c = B^T \\Sigma_{a_c} B + \\frac{\\sigma_{V0,c}^2 + x_c^2 \\sigma_{K,c}^2}{K_c^2},
        \\qquad \\Sigma_B = P\\,\\mathrm{diag}(\\mathrm{var})\\,P^T ,

    ``x_c = a_c . B`` the field along the channel's unit direction ``a_c``.  Within a channel the direction,
    offset and gain errors need not be independent (a four-flip's warm-up during the first flip ties a channel's
    offset to its direction): with the channel's joint covariance ``S_c`` of ``(a_c, V0_c, K_c)`` (the file's
    ``joint_covariance``, whose marginals are its sigmas) the component's variance is

    .. math::

        \\mathrm{var}_c = w^T S_c w, \\qquad w = (B, 1 / K_c, x_c / K_c),

    every error moving the solved component the same way (``-(B . da + dV0 / K + x dK / K)``); with ``S_c``
    block-diagonal this is the line above.  A channel read through a response curve ``g(x) = x + sum_k c_k x^k``
    whose ``S_c`` carries the curve's coefficients too (8 x 8, ``curves``) takes :func:`joint_weights`' curve
    levers ``w = (B, 1 / (K g'), g / (K g'), x^k / g')`` at its ``x``.  This is the one formula
    :func:`calibrate.diagnosis.robust.heading_sigma_deg` (the four-flip's own) uses too.  The channels' errors are
    taken as independent (the file gives no correlations between channels).

    Attributes
    ----------
    unit_directions : ndarray, shape (c, 3)
    solver : ndarray, shape (3, c)
    gains : ndarray, shape (c,)
        Output units per field unit.
    direction_covariance : ndarray, shape (c, 3, 3), or None
        rad^2 (None: the file gives none).
    response_sigma : ndarray, shape (c, 2), or None
        Offset (output units) and gain (output units per field unit) sigmas (None: the file gives none).
    undetermined : tuple of str
        As :attr:`TumbleUncertainty.undetermined`: the channels' sigmas the file left null beside others it
        gives, in words with the prior each takes (:func:`channel_priors`); their entries above hold it.
    prior : ChannelUncertainty or None
        The priors' part alone (zeros elsewhere): what they add (:meth:`cost_deg`); None when nothing is
        undetermined.
    joint_covariance : ndarray, shape (c, 5, 5) or (c, 8, 8), or None
        Each channel's joint covariance of its direction (rad^2), offset and gain (the units of
        ``response_sigma``); when given it is used in place of ``direction_covariance`` and ``response_sigma``
        (a channel the file gives none for holds its independent form: :func:`independent_joint`).  None: the
        three taken as independent.  (c, 8, 8) with ``curves``: the curve's coefficients after the gain
        (quadratic, cubic, quintic; zero rows for a channel without them).
    curves : ndarray, shape (c, 3), or None
        Each channel's curve coefficients (quadratic, cubic, quintic; 1 / field unit^(k - 1), as
        :class:`compass.response.CubicResponse` holds them), zeros for a channel without an 8 x 8 joint covariance;
        None: linear levers.
    """

    unit_directions: np.ndarray
    solver: np.ndarray
    gains: np.ndarray
    direction_covariance: np.ndarray | None = None
    response_sigma: np.ndarray | None = None
    undetermined: tuple = ()
    prior: "ChannelUncertainty | None" = None
    joint_covariance: np.ndarray | None = None
    curves: np.ndarray | None = None

    def __post_init__(self):
        size = 5 if self.curves is None else 8
        if self.joint_covariance is not None and np.shape(self.joint_covariance)[1:] != (size, size):
            raise ValueError(f"joint_covariance must be (c, {size}, {size}) "
                             f"{'with' if size == 8 else 'without'} curves, got {np.shape(self.joint_covariance)}")

    def cost_deg(self, field_norm: float, dip_deg: float) -> float:
        """As :meth:`TumbleUncertainty.cost_deg`."""
        return _cost_deg(self.prior, field_norm, dip_deg)

    def component_variance(self, field_h) -> np.ndarray:
        """``var_c`` (class docstring) at ``field_h`` (shape (..., 3), field units): shape (..., c), field units
        squared."""
        b = np.asarray(field_h, dtype=float)
        if self.joint_covariance is not None:
            w = joint_weights(b, self.unit_directions, self.gains, self.curves)
            return np.einsum("...ci,cij,...cj->...c", w, self.joint_covariance, w)
        x = np.einsum("...i,ci->...c", b, self.unit_directions)
        var = np.zeros_like(x)
        if self.direction_covariance is not None:
            var += np.einsum("...i,cij,...j->...c", b, self.direction_covariance, b)
        if self.response_sigma is not None:
            var += (self.response_sigma[:, 0] ** 2 + x**2 * self.response_sigma[:, 1] ** 2) / self.gains**2
        return var

    def covariance(self, field_h) -> np.ndarray:
        """``Sigma_B`` at ``field_h`` (shape (..., 3)): shape (..., 3, 3), field units squared."""
        p = self.solver
        return np.einsum("ic,...c,jc->...ij", p, self.component_variance(field_h), p)

    @cached_property
    def _scalars(self) -> tuple:
        """Per channel, as Python floats: ``a_c``, ``P``'s column, ``Sigma_a`` row by row (or None), the offset
        and gain variances over ``K^2`` (0 when not given), ``1 / K`` with the joint covariance row by row
        (None without one; it then replaces the three before), and the curve's coefficients (quadratic, cubic,
        quintic; zeros without ``curves``)."""
        rows = lambda m: tuple(tuple(float(v) for v in row) for row in m)  # noqa: E731
        out = []
        for c in range(len(self.gains)):
            cov = None if self.direction_covariance is None else rows(self.direction_covariance[c])
            k2 = float(self.gains[c]) ** 2
            off, gain = (0.0, 0.0) if self.response_sigma is None else \
                (float(self.response_sigma[c, 0]) ** 2 / k2, float(self.response_sigma[c, 1]) ** 2 / k2)
            joint = None if self.joint_covariance is None else rows(self.joint_covariance[c])
            curve = (0.0, 0.0, 0.0) if self.curves is None else tuple(float(v) for v in self.curves[c])
            out.append((tuple(float(v) for v in self.unit_directions[c]), tuple(float(v) for v in self.solver[:, c]),
                        cov, off, gain, 1.0 / float(self.gains[c]), joint, curve))
        return tuple(out)

    def heading_sigma_deg(self, matrix, field_h) -> float:
        """The heading's 1-sigma from the calibration alone at one attitude, the tilt taken as known, degrees:
        ``sqrt(n^T Sigma_B n) / |B_h|^2`` with ``n = up x B`` (as :meth:`TumbleUncertainty.heading_sigma_deg`),
        ``n^T Sigma_B n = sum_c var_c (P_c . n)^2``, on Python floats (it runs on every live sample).
        Parameters as :meth:`TumbleUncertainty.heading_sigma_deg`."""
        r = np.ravel(matrix) if not isinstance(matrix, (list, tuple)) or len(matrix) != 9 else matrix
        ux, uy, uz = float(r[6]), float(r[7]), float(r[8])
        b = tuple(float(v) for v in field_h)
        bx, by, bz = b
        n = (uy * bz - uz * by, uz * bx - ux * bz, ux * by - uy * bx)
        horizontal2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2]
        if not horizontal2 > 0.0:
            return math.inf
        var = 0.0
        for a, p, cov, off, gain, inverse_gain, joint, curve in self._scalars:
            x = a[0] * bx + a[1] * by + a[2] * bz
            if joint is not None:  # w^T S w, w = (B, 1 / (K g'), g / (K g'), x^k / g'): joint_weights'
                q, c3, c5 = curve
                slope = 1.0 + 2.0 * q * x + 3.0 * c3 * x * x + 5.0 * c5 * x**4
                w = (bx, by, bz, inverse_gain / slope, (x + q * x * x + c3 * x**3 + c5 * x**5) * inverse_gain / slope,
                     x * x / slope, x**3 / slope, x**5 / slope)[:len(joint)]
                v = sum(w[i] * sum(joint[i][j] * w[j] for j in range(len(w))) for i in range(len(w)))
            else:
                v = off + x * x * gain
                if cov is not None:
                    v += sum(b[i] * (cov[i][0] * bx + cov[i][1] * by + cov[i][2] * bz) for i in range(3))
            pn = p[0] * n[0] + p[1] * n[1] + p[2] * n[2]
            var += v * pn * pn
        return math.degrees(math.sqrt(var) / horizontal2)


def channel_priors(unit_directions, gains, field_norm: float, names, direction_gone, offset_gone,
                   gain_gone) -> tuple[np.ndarray, np.ndarray, tuple]:
    """The stated priors of a channel form's sigmas the file left null beside others it gives.

    A channel's direction takes the mounting's rotation prior (:data:`ROTATION_PRIOR_AXIS_DEG` about each axis:
    ``sigma^2 (I - a a^T)``, rad^2), its offset :data:`HARD_IRON_PRIOR` of |B| and its gain
    :data:`SOFT_IRON_PRIOR` of itself (the same sizes as a tumble's hard and soft iron).

    Parameters
    ----------
    unit_directions : array_like, shape (c, 3)
    gains : array_like, shape (c,)
        Output units per field unit.
    field_norm : float
        |B|, field units.
    names : sequence of str
        The channels' names, for the words.
    direction_gone, offset_gone, gain_gone : array_like of bool, shape (c,)
        Which channel's direction covariance, offset sigma and gain sigma the file left null.

    Returns
    -------
    direction_covariance : ndarray, shape (c, 3, 3)
        The prior where gone, zeros elsewhere, rad^2.
    response_sigma : ndarray, shape (c, 2)
        The priors where gone, zeros elsewhere: output units, output units per field unit.
    words : tuple of str
        One phrase per undetermined part (empty when none).
    """
    a = np.asarray(unit_directions, dtype=float)
    k = np.abs(np.asarray(gains, dtype=float))
    gone = [np.asarray(g, dtype=bool) for g in (direction_gone, offset_gone, gain_gone)]
    across = np.eye(3)[None] - a[:, :, None] * a[:, None, :]
    cov = np.where(gone[0][:, None, None], math.radians(ROTATION_PRIOR_AXIS_DEG) ** 2 * across, 0.0)
    sigma = np.column_stack([np.where(gone[1], HARD_IRON_PRIOR * field_norm * k, 0.0),
                             np.where(gone[2], SOFT_IRON_PRIOR * k, 0.0)])
    names = np.asarray(names)
    words = tuple(f"{what} of {', '.join(names[g])} (taken as {prior})" for what, g, prior in (
        ("the direction", gone[0], f"{ROTATION_PRIOR_AXIS_DEG:.2g} deg per axis: a mounting's"),
        ("the offset", gone[1], f"{100 * HARD_IRON_PRIOR:.0f} % of |B|"),
        ("the gain", gone[2], f"{100 * SOFT_IRON_PRIOR:.0f} %")) if g.any())
    return cov, sigma, words


def joint_weights(field_h, unit_directions, gains, curves=None) -> np.ndarray:
    """``w = (B, 1 / K_c, x_c / K_c)`` at ``field_h``: how each error of a channel's joint covariance (its direction,
    rad; offset; gain) moves the solved component, so its variance is ``w^T S_c w`` (:class:`ChannelUncertainty`).

    With a response curve ``g(x) = x + sum_k c_k x^k`` (``curves``, over :data:`CURVE_POWERS`) the solved
    component's error is ``-B . da - (dV0 + g dK + K sum_k x^k dc_k) / (K g')``, so
    ``w = (B, 1 / (K g'), g / (K g'), x^2 / g', x^3 / g', x^5 / g')``: the joint covariance then carries the
    curve's coefficients after the gain (:meth:`calibrate.fourflip._mlfit.MLFit.curve_covariance`).

    Parameters
    ----------
    field_h : array_like, shape (..., 3)
        The field in H, field units.
    unit_directions : ndarray, shape (c, 3)
    gains : ndarray, shape (c,)
        Output units per field unit.
    curves : ndarray, shape (c, 3), optional
        Each channel's curve coefficients (quadratic, cubic, quintic; 1 / field unit^(k - 1)).  None: linear.

    Returns
    -------
    ndarray, shape (..., c, 5), or (..., c, 8) with ``curves``
    """
    b = np.asarray(field_h, dtype=float)
    x = np.einsum("...i,ci->...c", b, unit_directions)
    if curves is None:
        return np.concatenate([np.broadcast_to(b[..., None, :], x.shape + (3,)),
                               np.broadcast_to(1.0 / gains, x.shape)[..., None], (x / gains)[..., None]], axis=-1)
    curves = np.asarray(curves, dtype=float)
    powers = np.array(CURVE_POWERS)
    terms = x[..., None] ** powers  # (..., c, 3)
    g = x + np.sum(curves * terms, axis=-1)
    slope = 1.0 + np.sum(powers * curves * x[..., None] ** (powers - 1), axis=-1)  # g'(x)
    return np.concatenate([np.broadcast_to(b[..., None, :], x.shape + (3,)), (1.0 / (gains * slope))[..., None],
                           (g / (gains * slope))[..., None], terms / slope[..., None]], axis=-1)


def independent_joint(direction_covariance, response_sigma) -> np.ndarray:
    """The joint covariance (5, 5) of a channel's direction, offset and gain taken as independent: ``Sigma_a`` and
    the offset and gain variances on the diagonal (zeros for a None part)."""
    out = np.zeros((5, 5))
    if direction_covariance is not None:
        out[:3, :3] = direction_covariance
    if response_sigma is not None:
        out[3, 3], out[4, 4] = np.square(np.asarray(response_sigma, dtype=float))
    return out


def joint_problem(joint, direction_covariance, response_sigma, curve: bool = False) -> str | None:
    """Why ``joint`` is not a channel's joint covariance whose marginals are the sigmas beside it; None when it is.

    Parameters
    ----------
    joint : array_like, shape (5, 5) or (8, 8)
        Of the direction (rad), offset and gain (output units, output units per field unit); 8 x 8: then the
        response curve's quadratic, cubic and quintic coefficients (1 / field unit^(k - 1)).
    direction_covariance : array_like, shape (3, 3), or None
        rad^2.
    response_sigma : sequence of 2 (float or None), or None
        The offset's and the gain's sigmas.
    curve : bool
        Whether the channel's response has a curve's coefficients (a cubic response): an 8 x 8 needs one.

    Returns
    -------
    str or None
        The reason in words (a message's tail, after the key's name).
    """
    joint = np.asarray(joint, dtype=float)
    if joint.shape not in ((5, 5), (8, 8)):
        return (f"must be 5 x 5 (the direction's 3, the offset, the gain) or 8 x 8 (then the response curve's "
                f"quadratic, cubic, quintic), got shape {joint.shape}")
    if joint.shape == (8, 8) and not curve:
        return "is 8 x 8 (a response curve's coefficients) but the channel's response has no curve (not cubic)"
    if not np.all(np.isfinite(joint)):
        return "must be finite"
    if direction_covariance is None or response_sigma is None or any(v is None for v in response_sigma):
        return ("comes without the channel's direction_covariance and both response_sigma entries: its marginals "
                "must be those")
    sigma = np.array(response_sigma, dtype=float)
    scale = np.concatenate([np.full(3, np.sqrt(max(np.trace(direction_covariance), 0.0))), sigma,
                            np.sqrt(np.maximum(np.diag(joint)[5:], 0.0))])
    scale[scale == 0.0] = 1.0
    unit = joint / np.outer(scale, scale)
    if np.max(np.abs(unit - unit.T)) > JOINT_TOLERANCE:
        return "must be symmetric"
    if np.linalg.eigvalsh(0.5 * (unit + unit.T))[0] < -JOINT_TOLERANCE:
        return "must be a covariance (positive semi-definite)"
    if (np.max(np.abs(unit[:3, :3] - np.asarray(direction_covariance) / scale[0] ** 2)) > JOINT_TOLERANCE
            or np.any(np.abs(np.sqrt(np.maximum(np.diag(joint)[3:5], 0.0)) - sigma) > JOINT_TOLERANCE * scale[3:5])):
        return ("must have the channel's direction_covariance and response_sigma as its marginals (its direction "
                "block and the square roots of its last two diagonal entries)")
    return None


def with_calibration_sigma(sigma_deg: float, uncertainty, matrix, field_h) -> float:
    """A filter's heading sigma (the noise's) with the calibration's own at its attitude, in quadrature, degrees.

    The one combination ``compass live``, its replay and :func:`compass.filter.run_filter` report.

    Parameters
    ----------
    sigma_deg : float
        The filter's heading 1-sigma, degrees.
    uncertainty : TumbleUncertainty or ChannelUncertainty or None
        ``SensorModel.calibration_uncertainty`` (None: ``sigma_deg`` as it is).
    matrix, field_h
        As :meth:`TumbleUncertainty.heading_sigma_deg`.

    Returns
    -------
    float
        Degrees.
    """
    if uncertainty is None:
        return sigma_deg
    return math.hypot(sigma_deg, uncertainty.heading_sigma_deg(matrix, field_h))


def with_calibration_sigma_many(sigma_deg, uncertainty, matrices, field_h) -> np.ndarray:
    """:func:`with_calibration_sigma` for many samples at once (:func:`compass.filter.run_filter`), vectorised
    through the uncertainty's :meth:`covariance`: ``n^T Sigma_B n / |B_h|^2`` with ``n = up x B``, degrees.

    Parameters
    ----------
    sigma_deg : array_like, shape (m,)
        The filter's heading 1-sigmas, degrees.
    uncertainty : TumbleUncertainty or ChannelUncertainty or None
    matrices : array_like, shape (m, 3, 3)
        ``R_world<-housing`` (NWU world) of each sample.
    field_h : array_like, shape (m, 3)
        The calibrated field in H of each sample, field units.

    Returns
    -------
    ndarray, shape (m,)
        Degrees (inf where the field has no horizontal part, as the scalar path).
    """
    sigma_deg = np.asarray(sigma_deg, dtype=float)
    if uncertainty is None:
        return sigma_deg.copy()
    b = np.asarray(field_h, dtype=float)
    n = np.cross(np.asarray(matrices, dtype=float)[:, 2, :], b)  # up x B: |n| = |B_h|
    horizontal2 = np.einsum("ni,ni->n", n, n)
    var = np.einsum("ni,nij,nj->n", n, uncertainty.covariance(b), n)
    with np.errstate(divide="ignore", invalid="ignore"):
        own = np.where(horizontal2 > 0.0, np.degrees(np.sqrt(var) / horizontal2), np.inf)
    return np.hypot(sigma_deg, own)


def undetermined_words(uncertainty, field_norm: float, dip_deg: float | None = None) -> str | None:
    """The one-line warning for a calibration with an undetermined part (None when every part is determined):
    which part, the prior it takes, and what the priors add to the heading sigma of a level housing (RMS over
    headings, in quadrature with the rest).

    Parameters
    ----------
    uncertainty : TumbleUncertainty or ChannelUncertainty or None
    field_norm : float
        |B|, field units (the calibration's or the reference's).
    dip_deg : float, optional
        The field's dip, degrees (default 60 when the calibration has none), said in the words.
    """
    if uncertainty is None or not uncertainty.undetermined:
        return None
    dip = 60.0 if dip_deg is None else float(dip_deg)
    return (f"the calibration leaves {'; '.join(uncertainty.undetermined)} undetermined: these stated priors (not "
            f"measured) add {uncertainty.cost_deg(field_norm, dip):.2g} deg to a level housing's heading sigma at "
            f"{dip:.0f} deg dip; recalibrate with more motion (and an accelerometer) to measure them")


def _skew(b: np.ndarray) -> np.ndarray:
    """``[b]x`` of every vector, shape (..., 3, 3)."""
    out = np.zeros(b.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -b[..., 2], b[..., 1], -b[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = b[..., 2], -b[..., 1], b[..., 0]
    return out
