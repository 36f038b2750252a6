"""The installation's least squares: the product's hard and soft iron in H on top of a bench model.

The bench model gives the field the module sees in its housing frame, ``b = field(raw)``.  Inside
the product (SPEC section 2) that is ``b = S B_H + h``, with ``S = I + D`` (``D`` symmetric: the
induced magnetisation of soft iron; six entries) and ``h`` the hard iron.  Every row of a rotation
of the product keeps the Earth's field fixed, so with ``B_H = S^{-1} (b - h)`` and ``u`` the
accelerometer's up direction

.. math::

    r_{1,i} = \\frac{|B_{H,i}| - F}{\\sigma_b}, \\qquad
    r_{2,i} = \\frac{u_i \\cdot B_{H,i} / |B_{H,i}| + \\sin\\delta}
                   {\\sqrt{(\\sigma_b^2/|B|^2 + \\sigma_u^2)(1 - \\mu_i^2)}}

(the constancy of |B| and of the field-gravity angle; ``F``, ``delta`` the site's |B| and dip,
fitted; ``sigma_b`` is the bench's white noise and ``|B|`` in the angle's noise the median measured
one, both held fixed: a noise model that changed with ``S`` or ``F`` would let the fit buy
chi-square by flattening or shrinking the field), and with ``heading_ref_deg`` a third residual,
the product's heading from the two-vector solution (gravity first) against the reference, which
also fixes the yaw of the housing in the product (ArduPilot's large-vehicle calibration uses a
known yaw the same way).  Weak priors close the problem: ``h ~ N(0, 20 uT)`` (in the bench
model's field units, :func:`prior_hard_iron`: 0.4 |B| when they are |B|), each entry of ``D ~ N(0, 0.05)`` (a product's
soft iron is a few %), and with a site the WMM's |B| and dip with their uncertainties.

What the rotations do not determine stays at its prior: a parameter the rows pin no better than
:data:`UNDETERMINED_NOISE` noise floors is *undetermined* (held at the prior's mean), and the report
says so in words.  A level swing, for instance, keeps the vertical field constant: the vertical
hard iron and the vertical soft iron ``S_zz`` then only shift and scale a constant (the points lie
on a circle, which many ellipsoids contain, down to a flat disk); they are held at zero
(:func:`undetermined_mask`), while ``S_xz``, ``S_yz`` (symmetric ``D``) show in the vertical
channel's once-a-turn swing; the overall scale of ``S`` trades with ``F``: without a site's |B| it
is fixed by ``trace(S) = 3``, exactly: one diagonal entry of ``D`` is minus the sum of the other two
(:func:`coordinates`), so the fit moves only trace-free soft iron.  ``scipy.optimize.least_squares``
fits all parameters together; the covariance is ``(J^T J)^{-1}`` times the reduced chi-square when
above 1, and a held parameter's prior uncertainty is carried into the fitted ones through their
sensitivity to it.

A swing within a few degrees of level has a weak direction: the vertical hard iron ``h_z``, ``S_zz`` and
the dip only shift and scale a nearly constant vertical field, told apart by the tilts alone (``h_z``'s
sigma is 6x the horizontal's at +-10 deg, 12x at +-5). Along it the fit is biased by the magnetometer's
noise, and the bias does not fall as the sigma does with more rows: it is that of least squares with
noisy regressors (errors in variables). Two O(1)-per-row terms of the normal equations do not vanish in
expectation: the angle residual's Jacobian in ``h`` and ``D`` holds the noisy ``B^ = B_H / |B_H|`` (its
correlation with the residual's own noise, ``sigma_dir^2 [B^ (1 - mu^2) + mu (u - mu B^)] / |B|``, is
twice what a shift of the dip absorbs), and its weight ``1 / (1 - mu^2)`` moves with the parameters (the
fit lowers chi-square by turning ``mu``), which pulls the other way. What is left moves ``h_z``,
``S_zz`` and the dip together: on the benchmark's clean swings (+-10 deg, 2000 rows, 0.15 uT per
channel; seeds 0-11) ``h_z`` is 0.107 +- 0.015 uT high for a sigma of 0.05-0.08 (``S_zz`` 0.0018 high,
the dip 0.02 deg), 0.42 uT at +-5 deg, 0.027 at +-20, 0.108 at 8000 rows (seeds 20-31: 0.100, and 0.056
at 8000 rows); its spread over seeds is honest (SD of err/sig 0.7-1.0), so the err/sig of 1.84 is the
bias's (``tools/bench_swing_sigma.py``). With no noise the fit is exact
(``tests/calibrate/installation/test_swing_estimand.py``): the estimand is the fit's. The fit takes it
out to second order (:func:`debiased`, applied to the final fit by ``calibrate.installation.fit``):
0.107 -> 0.004 +- 0.014 uT at +-10 deg, 0.42 -> 0.005 at +-5, err/sig of ``h_z`` 1.84 -> 0.79 (seeds
0-11). Residual forms were tried first and not kept: the angle's residual as ``u . B_H + sin(dip)
|B_H|`` over a constant |B| cut the bias only because the scale of ``S`` then buys chi-square and pulls
against it (a tumble's |B| went 1 % off its site prior); over the fitted ``F`` or the median ``|B_H|``
the bias was back. docs/benchmarks.md, "Why the clean swing's sigma under-covers".

Parameters, in order: ``h`` (3, field units), the entries of ``D``
(:data:`compass.installed.SOFT_IRON_ENTRIES`), ``F`` (field units), the dip (deg), the yaw (deg,
with ``heading_ref_deg``), then three per effect in the model (the hard iron's change per unit of
the effect's regressor).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from compass.attitude import two_vector_rotation
from compass.frames import heading_pitch_roll
from compass.installed import SOFT_IRON_ENTRIES, soft_iron_basis

from ..diagnosis.evidence import FitRecord

__all__ = ["PRIOR_HARD_IRON_UT", "TYPICAL_FIELD_UT", "prior_hard_iron", "PRIOR_SOFT_IRON", "UNDETERMINED_NOISE",
           "LEVEL_DEG", "N_CORE", "Rows", "InstallationFit", "coordinates", "fit_installation", "residuals", "field_h",
           "split", "is_level", "product_heading", "effect_slice", "parameter_names", "debiased"]

PRIOR_HARD_IRON_UT = 20.0
"""Prior sigma of each hard-iron component, uT."""
TYPICAL_FIELD_UT = 50.0
"""The Earth's |B| (uT) that turns :data:`PRIOR_HARD_IRON_UT` into units of |B| when the bench model
knows no |B| in uT (its field unit is then its own |B|, 22-67 uT on Earth)."""
PRIOR_SOFT_IRON = 0.05
"""Prior sigma of each entry of ``S - I``."""
UNDETERMINED_NOISE = 5.0
"""A parameter pinned no better than this many noise floors is held at its prior."""
LEVEL_DEG = 2.0
"""A swing whose up direction stays this close (RMS) to its mean is level."""
N_CORE = 11
"""Hard iron (3), soft-iron entries (6), |B| and dip: the parameters every fit has."""
_DIAGONAL = (5, 4, 3)  # the entries d_zz, d_yy, d_xx of x, in the order one is chosen to carry trace(D) = 0
_MAX_MOVE_SIGMA = 2.0
"""The unexplained excess's correction (:func:`debiased`) moving a parameter by more than this many of its
stated sigmas is left out: under a field wander it moved one by at most 1.3 (seeds 0-19 of
``tools/bench_swing_sigma.py``, which 1.0 cut on 3 of 20), a failed fit's residuals by 2.5 and more."""
_EXPANSION_TOLERANCE = 0.1
"""The largest neglected fourth-order term of :func:`debiased`'s expansion, as a fraction of the kept second-order
one (``s^2 / 4`` for an angular noise ``s``), at which the unexplained excess's correction is still made."""


def prior_hard_iron(field_ut: float | None) -> float:
    """Prior sigma of each hard-iron component in the bench model's field units.

    Parameters
    ----------
    field_ut : float or None
        The bench model's |B| in uT (its field unit is then uT), None when it knows none (its
        field unit is its |B|).
    """
    return PRIOR_HARD_IRON_UT if field_ut is not None else PRIOR_HARD_IRON_UT / TYPICAL_FIELD_UT


@dataclass(frozen=True)
class Rows:
    """The rows a fit uses and how they are weighted.

    Attributes
    ----------
    b : ndarray, shape (n, 3)
        The bench model's field in H, field units.
    u : ndarray, shape (n, 3)
        Unit up direction (the accelerometer's), H.
    sigma_b : float
        White noise of each field component, field units.
    sigma_dir : float
        The same over the median |b|: the field direction's noise, rad.
    sigma_u : float
        The up direction's noise, rad.
    heading_ref : ndarray, shape (n,), or None
        The product's known magnetic heading, deg.
    regressors : dict
        Effect name -> (n,) regressor: the hard iron changes by the effect's parameters times it.
    prior_hard_iron : float
        Prior sigma of each hard-iron component, field units.
    heading_sigma_deg : float
        The reference's noise (re-estimated from the first fit's residual).
    """

    b: np.ndarray
    u: np.ndarray
    sigma_b: float
    sigma_dir: float
    sigma_u: float
    heading_ref: np.ndarray | None
    regressors: dict
    prior_hard_iron: float = PRIOR_HARD_IRON_UT
    heading_sigma_deg: float = 0.5

    @property
    def n_fixed_params(self) -> int:
        """Parameters before the effects' (:data:`N_CORE`, and the yaw with a heading reference)."""
        return N_CORE + (self.heading_ref is not None)


@dataclass(frozen=True)
class InstallationFit(FitRecord):
    """One fit (the diagnosis loop's :class:`calibrate.diagnosis.evidence.FitRecord`).

    ``effects`` are the effect forms in the model, ``residuals`` the |B| residual ``|B_H| - F``
    (field units), ``chi2`` that of the rows' weighted residuals (priors excluded) and ``jac`` the
    Jacobian of the weighted residuals in the coordinates the fit moved (:func:`coordinates`).

    Attributes
    ----------
    chi2_mag : float
        Chi-square of the |B| residual alone.
    heading_rms_deg : float or None
        RMS of the heading residual, with a heading reference.
    fixed : ndarray of bool
        Parameters held at the prior's mean (undetermined).
    """

    chi2_mag: float
    heading_rms_deg: float | None
    fixed: np.ndarray

    @property
    def n_rows(self) -> int:
        return self.residuals.size

    @property
    def residual_rms(self) -> float:
        """RMS of ``|B_H| - F``, field units."""
        return float(np.sqrt(np.mean(self.residuals**2)))

    @property
    def n_free(self) -> int:
        """The coordinates the fit moved."""
        return self.jac.shape[1]

    @property
    def dof(self) -> int:
        return self.n_obs - self.n_free

    def bic(self) -> float:
        """chi2 + k ln n over the parameters the fit moved."""
        return self.chi2 + self.n_free * np.log(self.n_obs)


def split(x: np.ndarray, rows: Rows, effects: tuple):
    """``(h, D entries, F, dip, yaw or None, {effect name: its 3 parameters})``."""
    h, d, f, dip = x[:3], x[3:9], x[9], x[10]
    yaw = x[N_CORE] if rows.heading_ref is not None else None
    k = rows.n_fixed_params
    extra = {e.name: x[k + 3 * i:k + 3 * i + 3] for i, e in enumerate(effects)}
    return h, d, f, dip, yaw, extra


def parameter_names(rows: Rows, effects: tuple) -> tuple[str, ...]:
    """Names of ``x`` in order (module docstring): ``h``, ``D``'s entries, ``F``, the dip, the yaw, each effect's."""
    core = (("hard_iron_x", "hard_iron_y", "hard_iron_z") + tuple(f"D_{e}" for e in SOFT_IRON_ENTRIES)
            + ("field_norm", "dip_deg") + (("yaw_deg",) if rows.heading_ref is not None else ()))
    return core + tuple(f"{e.name}.{axis}" for e in effects for axis in "xyz")


def effect_slice(rows: Rows, effects: tuple, name: str) -> slice:
    """Where the parameters of the effect ``name`` sit in ``x``."""
    k = rows.n_fixed_params + 3 * [e.name for e in effects].index(name)
    return slice(k, k + 3)


def field_h(x: np.ndarray, rows: Rows, effects: tuple) -> np.ndarray:
    """``B_H = S^{-1} (b / (1 + sum_gains g_e c_e) - h - sum_offsets g_e c_e)``, shape (n, 3), field units.

    An effect whose ``scales`` is true changes the gain of each axis of H (it scales the hard iron
    with the field: the sensor's gain drifted); the others move the hard iron.
    """
    h, d, *_, extra = split(x, rows, effects)
    soft = np.eye(3) + np.einsum("k,kij->ij", d, soft_iron_basis())
    scales = {e.name for e in effects if getattr(e, "scales", False)}
    gain = 1.0 + sum(rows.regressors[name][:, None] * g[None, :] for name, g in extra.items() if name in scales)
    offset = h + sum(rows.regressors[name][:, None] * g[None, :] for name, g in extra.items() if name not in scales)
    return np.linalg.solve(soft, (rows.b / gain - offset).T).T


def residuals(x: np.ndarray, rows: Rows, effects: tuple, priors: dict) -> np.ndarray:
    """Whitened residuals: |B| and field-gravity angle per row, the heading reference per row when
    recorded, then the priors (module docstring)."""
    h, d, f, dip, yaw, _ = split(x, rows, effects)
    bh = field_h(x, rows, effects)
    nb = np.linalg.norm(bh, axis=1)
    # the noise is held at the bench's (S is near I): a noise model that changed with S or |B| would let the
    # fit buy chi-square by flattening or shrinking the field
    mu = np.einsum("ij,ij->i", bh, rows.u) / nb
    parts = [(nb - f) / rows.sigma_b,
             (mu + np.sin(np.radians(dip))) / np.sqrt((rows.sigma_dir**2 + rows.sigma_u**2)
                                                     * np.maximum(1.0 - mu**2, 1e-6))]
    if yaw is not None:
        heading = product_heading(rows.u, bh, dip, yaw)
        parts.append((np.mod(heading - rows.heading_ref + 180.0, 360.0) - 180.0) / rows.heading_sigma_deg)
    parts.append(h / rows.prior_hard_iron)
    parts.append(d / PRIOR_SOFT_IRON)
    if "field" in priors:  # without it the scale of S, which trades with |B|, is fixed by trace(S) = 3 (coordinates)
        parts.append(np.atleast_1d((f - priors["field"][0]) / priors["field"][1]))
    if "dip" in priors:
        parts.append(np.atleast_1d((dip - priors["dip"][0]) / priors["dip"][1]))
    return np.concatenate(parts)


def product_heading(u, bh, dip, yaw) -> np.ndarray:
    """Heading of the product's forward axis: two-vector (gravity first) in H, turned by the yaw."""
    housing = two_vector_rotation(u, bh, dip, 0.0)
    return heading_pitch_roll(housing * Rotation.from_euler("z", -yaw, degrees=True))[0]


def coordinates(fixed: np.ndarray, traceless: bool) -> tuple[np.ndarray, int | None]:
    """The parameters as ``x = T y``, with ``trace(D) = 0`` exact when ``traceless``.

    ``T`` is the identity but for one free diagonal entry of ``D`` (``d_zz``, else ``d_yy``, else
    ``d_xx``), which is minus the sum of the other two, held ones included (a held ``S_zz``'s prior
    uncertainty then moves the other two together).  Its coordinate in ``y`` is unused.

    Parameters
    ----------
    fixed : ndarray of bool
        The parameters held at their prior's mean.
    traceless : bool
        Impose ``trace(D) = 0`` (no site's |B| ties the scale of ``S``).

    Returns
    -------
    T : ndarray, shape (n, n)
    dependent : int or None
        The index of the entry that carries the trace (None: no constraint, or every diagonal
        entry held at zero, which meets it).
    """
    t = np.eye(len(fixed))
    dependent = next((k for k in _DIAGONAL if not fixed[k]), None) if traceless else None
    if dependent is not None:
        t[dependent] = 0.0
        t[dependent, [k for k in _DIAGONAL if k != dependent]] = -1.0
    return t, dependent


def fit_installation(rows: Rows, effects: tuple, priors: dict, start: np.ndarray | None = None,
                     fixed: np.ndarray | None = None) -> InstallationFit:
    """Least-squares fit; parameters in ``fixed`` (a mask, default: those the rows cannot determine,
    :func:`undetermined_mask`) stay at their start (the prior's mean, zero).

    Parameters
    ----------
    rows : Rows
    effects : tuple of InstallationEffect
        The hard iron's changes in the model (each named in ``rows.regressors``).
    priors : dict
        ``"field"`` and ``"dip"``: ``(mean, sigma)`` of the site's |B| (field units) and dip (deg).
        Without ``"field"``, ``trace(S) = 3`` (:func:`coordinates`).
    start : ndarray, optional
        Where to start (default: no iron, the median |b| and dip, the mean yaw).
    fixed : ndarray of bool, optional
    """
    nb = np.linalg.norm(rows.b, axis=1)
    if start is None:
        dip0 = float(np.degrees(np.arcsin(np.clip(-np.median(np.einsum("ij,ij->i", rows.b, rows.u) / nb), -1, 1))))
        start = np.concatenate([np.zeros(9), [np.median(nb), dip0]])
        if rows.heading_ref is not None:
            bench = product_heading(rows.u, rows.b, dip0, 0.0)
            diff = np.radians(rows.heading_ref - bench)
            start = np.append(start, np.degrees(np.arctan2(np.mean(np.sin(diff)), np.mean(np.cos(diff)))))
        start = np.concatenate([start, np.zeros(3 * len(effects))])
    if fixed is None:
        fixed = undetermined_mask(rows, effects, priors, start)
    t, dependent = coordinates(fixed, "field" not in priors)
    moved = ~fixed
    if dependent is not None:
        moved[dependent] = False
    y0 = start.copy()

    def moved_residuals(y_moved):
        y = y0.copy()
        y[moved] = y_moved
        return residuals(t @ y, rows, effects, priors)

    bound = 25.0 * rows.prior_hard_iron
    lower = np.concatenate([[-bound] * 3, [-0.5] * 6, [1e-6, -90.0], [-np.inf] * (len(start) - N_CORE)])
    upper = np.concatenate([[bound] * 3, [0.5] * 6, [np.inf, 90.0], [np.inf] * (len(start) - N_CORE)])
    result = least_squares(moved_residuals, y0[moved], x_scale="jac", method="trf",
                           bounds=(lower[moved], upper[moved]))
    y = y0.copy()
    y[moved] = result.x
    x = t @ y
    n = len(rows.b)
    data_rows = result.fun[: (3 if rows.heading_ref is not None else 2) * n]
    chi2 = float(data_rows @ data_rows)
    n_obs = len(data_rows)
    # every parameter's uncertainty, the held ones at their prior's, which the fitted ones inherit
    # through their sensitivity to them (a level swing's horizontal hard iron carries S_xz times the
    # unknown vertical field): cov_y = C_m + K P_h K^T, K = -(J_m^T J_m)^-1 J_m^T J_h, cov = T cov_y T^T
    jac = _jacobian(x, rows, effects, priors) @ t
    scale = max(1.0, chi2 / max(n_obs - int(moved.sum()), 1))
    c_moved = np.linalg.pinv(jac[:, moved].T @ jac[:, moved])
    k = np.zeros((len(x), int(fixed.sum())))
    k[moved] = -c_moved @ jac[:, moved].T @ jac[:, fixed]
    k[fixed] = np.eye(int(fixed.sum()))
    held = (np.array([rows.prior_hard_iron] * 3 + [PRIOR_SOFT_IRON] * 6 + [0.0] * (len(x) - 9)) ** 2)[fixed]
    cov_y = k @ np.diag(held) @ k.T
    cov_y[np.ix_(moved, moved)] += c_moved * scale
    cov = t @ cov_y @ t.T
    mag = np.linalg.norm(field_h(x, rows, effects), axis=1) - x[9]
    heading_rms = None
    if rows.heading_ref is not None:
        heading_rms = float(np.sqrt(np.mean((result.fun[2 * n:3 * n] * rows.heading_sigma_deg) ** 2)))
    return InstallationFit(tuple(effects), x, jac[:, moved], cov, mag, chi2, n_obs, bool(result.success),
                           str(result.message), float(np.sum((mag / rows.sigma_b) ** 2)), heading_rms, fixed)


def debiased(fit: InstallationFit, rows: Rows, priors: dict, unexplained: bool = False) -> InstallationFit:
    r"""The fit with its errors-in-variables bias taken out (module docstring), to second order in the noise.

    The least-squares estimate solves ``sum_i J_i^T r_i = 0`` with ``J_i`` and ``r_i`` of the noisy
    rows; at the true parameters that sum's expectation is not zero but, for white noise of
    variance ``s_k^2`` in each coordinate ``d_k`` of a row (the field's three in H, ``sigma_b``; the up
    direction's three, ``sigma_u``),

    .. math::

        E = \sum_i \sum_k s_k^2 \left( \frac{\partial J_i^T}{\partial d_k} \frac{\partial r_i}{\partial d_k}
            + \tfrac12 J_i^T \frac{\partial^2 r_i}{\partial d_k^2} \right)

    (central differences over the rows' coordinates, the rows' own values standing in for the true
    ones), so the estimate is off by ``-(J^T J)^{-1} E``, which is added back in the coordinates
    the fit moved.  The covariance is kept (the correction is second order in the noise); the
    residuals and chi-squares are those at the corrected parameters.

    With ``unexplained`` (the diagnosis found structure above the floor) part of that excess may be
    noise in the regressors too: a field wandering in the world frame, or a hard iron walking, moves
    each row's field by ``dB_i``, which enters the row's Jacobian and its residual alike.  It is
    counted as two more per-row directions of noise in the expectation above, along the Earth
    field's estimate (:func:`field_h`, the product's hard iron taken out) and across it in the plane
    of the field and up, each of the variance the |B| rows show above their floor (:func:`_excess`).  This is an
    approximation: a slow excess is correlated between rows, and the cross-row terms of the
    expansion are left out; it is shown to work empirically (a swing's vertical hard iron under a
    0.4 uT field wander was 0.52-0.59 uT high, 3-6 standard errors, on seeds 0-19, 20-29 and 30-49,
    and is 0.14-0.22 with it, the across part bounded by the along one, :func:`_excess`:
    ``tools/bench_swing_sigma.py``, docs/benchmarks.md).  The excess's
    correction is left out, and the fit's message says why, when its move of any parameter exceeds
    :data:`_MAX_MOVE_SIGMA` of that parameter's stated sigmas (the structure is then not small noise:
    a failed fit's residuals are not), or when the excess is outside the expansion's validity: the angle rows' residual
    goes as ``cos(theta + delta)`` with ``E[cos] = cos(theta) (1 - s^2/2 + s^4/8 - ...)`` for an
    angular noise ``s`` (the |B| rows' likewise in ``s = sigma / |B|``), so the neglected term is
    ``s^2 / 4`` of the kept one, and the correction is skipped when that exceeds
    :data:`_EXPANSION_TOLERANCE` (a tenth: ``s > 0.63 rad``).
    """
    x, effects = fit.x, fit.effects
    jac = _jacobian(x, rows, effects, priors)
    base = residuals(x, rows, effects, priors)
    t, dependent = coordinates(fit.fixed, "field" not in priors)
    moved = ~fit.fixed
    if dependent is not None:
        moved[dependent] = False
    j_moved = (jac @ t)[:, moved]

    def step(directions) -> np.ndarray:
        """The bias ``(J^T J)^{-1} E`` of noise along ``directions``, in ``x``."""
        expectation = np.zeros(len(x))
        for name, sigma, k in directions:
            def shifted(step, name=name, k=k):
                values = getattr(rows, name).copy()
                if isinstance(k, int):
                    values[:, k] += step
                else:  # a direction per row
                    values += step * k
                if name == "u":  # the up direction stays a unit vector: its noise is across it
                    values /= np.linalg.norm(values, axis=1, keepdims=True)
                return replace(rows, **{name: values})
            up, down = shifted(sigma), shifted(-sigma)
            r_up, r_down = residuals(x, up, effects, priors), residuals(x, down, effects, priors)
            dr = (r_up - r_down) / (2.0 * sigma)
            d2r = (r_up - 2.0 * base + r_down) / sigma**2
            djac = (_jacobian(x, up, effects, priors) - _jacobian(x, down, effects, priors)) / (2.0 * sigma)
            expectation += sigma**2 * (djac.T @ dr + 0.5 * jac.T @ d2r)
        return t[:, moved] @ np.linalg.solve(j_moved.T @ j_moved, (t.T @ expectation)[moved])

    floor = [(name, sigma, k) for name, sigma in (("b", rows.sigma_b), ("u", rows.sigma_u)) for k in range(3)]
    new_x = x + step(floor)
    message = fit.message
    if unexplained:
        along, across = _excess(fit, rows, effects, priors)
        bh = field_h(x, rows, effects)
        field = np.linalg.norm(bh, axis=1)
        bh /= field[:, None]  # the Earth field's direction (S is near I: a step along it in b is one in H)
        normal = rows.u - np.einsum("ij,ij->i", rows.u, bh)[:, None] * bh
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        angular = np.sqrt(along) / float(np.median(field))
        extra = [("b", np.sqrt(v), d) for v, d in ((along, bh), (across, normal)) if v > 0]
        if angular**2 / 4.0 > _EXPANSION_TOLERANCE:
            message += (f"; the unexplained excess's errors-in-variables correction left out: the excess, "
                        f"{np.degrees(angular):.1f} deg RMS, is beyond a second-order expansion")
        elif extra:
            move = step(extra)
            sigma = np.sqrt(np.maximum(np.diag(fit.covariance), 0.0))
            ratio = np.where(sigma > 0, np.abs(move) / np.where(sigma > 0, sigma, 1.0), 0.0)
            worst = int(np.argmax(ratio))
            if ratio[worst] > _MAX_MOVE_SIGMA:
                message += (f"; the unexplained excess's errors-in-variables correction left out: it would move "
                            f"{parameter_names(rows, effects)[worst]} by {move[worst]:+.3g}, "
                            f"{ratio[worst]:.1f} times its sigma")
            else:
                new_x = new_x + move
    x = new_x
    n_data = fit.n_obs
    data_rows = residuals(x, rows, effects, priors)[:n_data]
    mag = np.linalg.norm(field_h(x, rows, effects), axis=1) - x[9]
    n = len(rows.b)
    heading_rms = None if rows.heading_ref is None else float(
        np.sqrt(np.mean((data_rows[2 * n:3 * n] * rows.heading_sigma_deg) ** 2)))
    return replace(fit, x=x, residuals=mag, chi2=float(data_rows @ data_rows), message=message,
                   chi2_mag=float(np.sum((mag / rows.sigma_b) ** 2)), heading_rms_deg=heading_rms)


def _excess(fit: InstallationFit, rows: Rows, effects: tuple, priors: dict) -> tuple[float, float]:
    """The field's variance beyond the floor's along the field and across it (field units squared).

    From the fit's residuals (:func:`debiased`): along, the |B| rows' mean square less ``sigma_b^2``;
    across, the angle rows' whitened mean square less one, times their floor in field units,
    ``sigma_b^2 + |B|^2 sigma_u^2`` (``|B|`` the median measured: ``sigma_dir = sigma_b / |B|``), but at
    most the along one.  The angle rows' excess is the field's across and the accelerometer's
    together, and the accelerometer's own rows cannot part them (``|a| - g`` sees only a disturbance
    along gravity, which leaves the up direction as it is; a slow one is inside any low-pass); the
    |B| rows, which the accelerometer does not touch, bound the field's (a wander in the world frame,
    a hard iron walking, has no preferred direction with respect to the field).  Each at least zero.
    """
    n = fit.n_rows
    weighted = residuals(fit.x, rows, effects, priors)
    along = max(float(np.mean((weighted[:n] * rows.sigma_b) ** 2) - rows.sigma_b**2), 0.0)
    field = rows.sigma_b / rows.sigma_dir
    across = float((np.mean(weighted[n:2 * n] ** 2) - 1.0) * (rows.sigma_b**2 + (field * rows.sigma_u) ** 2))
    return along, min(max(across, 0.0), along)


def _jacobian(x: np.ndarray, rows: Rows, effects: tuple, priors: dict) -> np.ndarray:
    """Forward-difference Jacobian of :func:`residuals` (priors included) in every parameter."""
    base = residuals(x, rows, effects, priors)
    step = np.concatenate([np.full(3, 1e-3), np.full(6, 1e-5), [1e-3, 1e-4], np.full(len(x) - N_CORE, 1e-4)])
    return np.column_stack([(residuals(x + h * e, rows, effects, priors) - base) / h
                            for h, e in zip(step, np.eye(len(x)))])


def undetermined_mask(rows: Rows, effects: tuple, priors: dict, x: np.ndarray) -> np.ndarray:
    """Hard and soft iron parameters the rows cannot determine, held at the prior's mean (zero).

    A swing that stays level within :data:`LEVEL_DEG` RMS never changes the vertical field: its
    vertical hard iron and ``S_zz`` are held (the classical swing's blind spot; the small rocking of
    a real swing would otherwise "determine" them from noise, pulled by whatever the other is held
    at).  Then, linearised at ``x``, the parameter the rows pin worst is held while some are pinned
    no better than :data:`UNDETERMINED_NOISE` noise floors (a hard-iron component to ``5 sigma_b``,
    a soft-iron entry to ``5 sigma_b / |B|``): a flat direction can span several parameters.
    """
    mask = np.zeros(len(x), dtype=bool)
    if is_level(rows):
        mask[[2, 5]] = True  # hard_iron_z, soft_iron_zz
    jac = _jacobian(x, rows, effects, priors)
    limit = UNDETERMINED_NOISE * rows.sigma_b * np.concatenate([[1.0] * 3, [1.0 / x[9]] * 6,
                                                                np.full(len(x) - 9, np.inf)])
    while True:
        t, dependent = coordinates(mask, "field" not in priors)
        moved = ~mask
        if dependent is not None:
            moved[dependent] = False
        j_moved = (jac @ t)[:, moved]
        spread = t[:, moved] @ np.linalg.pinv(j_moved.T @ j_moved) @ t[:, moved].T
        ratio = np.where(mask, 0.0, np.sqrt(np.diag(spread)) / limit)
        worst = int(np.argmax(ratio))
        if ratio[worst] <= 1.0:
            return mask
        mask[worst] = True


def is_level(rows: Rows) -> bool:
    """The up direction stays within :data:`LEVEL_DEG` (RMS) of its mean: a level swing."""
    mean_up = rows.u.mean(axis=0)
    mean_up /= np.linalg.norm(mean_up)
    return bool(np.sqrt(np.mean(np.arccos(np.clip(rows.u @ mean_up, -1.0, 1.0)) ** 2)) < np.radians(LEVEL_DEG))
