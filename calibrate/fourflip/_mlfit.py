"""Joint maximum-likelihood fit of a four-flip recording (all channels, all flips).

Parameters, per channel: a unit sensing direction as a 2-D step in the tangent plane of a
starting direction (no singularity anywhere on the sphere), the zero-field output and the log
gain (gains stay positive); shared: dip and field azimuth; then each active effect's block.
The loss is the chi-square of the outputs weighted by each channel's noise floor,

.. math:: \\chi^2 = \\sum_{i,c} \\left( (v_{ic} - \\hat v_{ic}(p)) / \\sigma_c \\right)^2,

minimised by Levenberg-Marquardt (``scipy.optimize.least_squares``).  Standard errors come from
the Jacobian at the solution, scaled by the reduced chi-square.

A long recording is fitted on bin means: consecutive samples of one flip whose turntable
readings fall in one :data:`BIN_DEG` bin and their times in one bin of the session
(:func:`calibrate.diagnosis.forms.session_bin`) are replaced by their mean (inputs and outputs),
weighted by the square root of their count (:class:`Bins`).  The model is smooth in the angle, so the
prediction at a bin's mean angle differs from the bin's mean prediction by ``f'' var(phi) / 2``,
for the first harmonic at most ``K |B| w^2 / 24`` over a bin ``w`` (in rad): 3e-8 ``K |B|`` at
0.05 deg, 1.6e-6 uT in a 50 uT field, far below the noise of any bin mean.  The chi-square, its
degrees of freedom and the residuals stay those of every sample; a recording whose bins hold one
sample each is fitted as it is.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from compass.frames import direction_sigma_deg as _direction_sigma_deg
from compass.iron_uncertainty import CURVE_FIELDS, CURVE_POWERS
from compass.sim.bench import BenchPhysics, BenchSamples, bench_outputs, channel_outputs, housing_field

from ..diagnosis.evidence import SINGULAR_RCOND, linear_score, unit_columns
from ..diagnosis.forms import session_bin
from ._jacobian import Partials
from .effects import FourFlipEffect, NonlinearResponse

__all__ = ["BIN_DEG", "Bins", "MLFit", "block_p_values", "cramer_rao", "curve_coefficients", "fit_ml", "offset_step",
           "score_effect", "structured_covariance", "step_size_output", "tangent_basis", "walk_covariance",
           "walk_p_value", "with_covariance"]

_BASE_PER_CHANNEL = 4  # u, v, offset, log gain
_MAX_ITERATIONS = 100  # residual evaluations of one Levenberg-Marquardt fit (the Jacobian is analytic)
RATE_STEP_DEG = 0.01
"""Turn-angle step of the signal's rate by a forward difference (a lag's shape: a relative error ~1e-4), degrees."""
BIN_DEG = 0.05
"""Width of the turntable-angle bins whose consecutive samples the fit takes as one mean, degrees."""
@dataclass(frozen=True)
class Bins:
    """A recording's bin means: where the fit runs (see the module docstring).

    Attributes
    ----------
    samples : BenchSamples
        Each bin's mean turntable reading, flip angle, time and temperature, and its flip.
    outputs : ndarray, shape (g, c)
        Each bin's mean outputs.
    root_n : ndarray, shape (g, 1)
        Square root of each bin's sample count (the weight of its mean).
    """

    samples: BenchSamples
    outputs: np.ndarray
    root_n: np.ndarray | float

    @classmethod
    def of(cls, samples: BenchSamples, outputs: np.ndarray) -> "Bins":
        """The bins of a recording (the samples themselves when no bin holds two)."""
        new = np.zeros(samples.platform_deg.size, dtype=bool)  # where a bin starts
        new[0] = True
        for cell in (np.floor(samples.platform_deg / BIN_DEG), samples.flip_index, session_bin(samples.t_s)):
            if cell is not None:
                new[1:] |= cell[1:] != cell[:-1]
        if new.all():
            return cls(samples, outputs, 1.0)
        index = np.cumsum(new) - 1
        counts = np.bincount(index)

        def mean(v):
            return None if v is None else np.bincount(index, weights=v) / counts

        binned = BenchSamples(mean(samples.platform_deg), mean(samples.flip_deg), samples.flip_index[new],
                              mean(samples.t_s), mean(samples.temp_c))
        return cls(binned, np.column_stack([mean(v) for v in outputs.T]), np.sqrt(counts)[:, None])


def tangent_basis(directions: np.ndarray) -> np.ndarray:
    """Two orthonormal vectors perpendicular to each direction, shape (c, 2, 3)."""
    basis = np.empty((len(directions), 2, 3))
    for i, a in enumerate(directions):
        helper = np.eye(3)[np.argmin(np.abs(a))]
        e1 = np.cross(a, helper)
        e1 /= np.linalg.norm(e1)
        basis[i] = e1, np.cross(a, e1)
    return basis


@dataclass(frozen=True)
class MLFit:
    """Outcome of one joint fit.

    Attributes
    ----------
    physics : BenchPhysics
        Fitted parameters.
    effects : tuple of FourFlipEffect
    names : list of str
        Fit parameter names (in the fit's scaled units).
    x : ndarray
        Fit parameters.
    covariance : ndarray
        Scaled covariance of ``x`` (NaN where not determined).
    direction_covariance : ndarray, shape (c, 3, 3)
        Covariance of each unit direction.
    residuals : ndarray, shape (n, c)
        Measured minus predicted, output units.
    chi2, dof : float, int
        Weighted chi-square and degrees of freedom (of every sample).
    singular : list of str
        Parameter combinations the data cannot determine, in words.
    success : bool
    message : str
    """

    physics: BenchPhysics
    effects: tuple
    names: list
    x: np.ndarray
    covariance: np.ndarray
    direction_covariance: np.ndarray
    residuals: np.ndarray
    chi2: float
    dof: int
    singular: list
    success: bool
    message: str
    jac: np.ndarray = field(repr=False, default=None)
    layout: "_Layout" = field(repr=False, default=None)
    bins: Bins = field(repr=False, default=None)

    @property
    def n_params(self) -> int:
        return len(self.x)

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / max(self.dof, 1)

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    def bic(self) -> float:
        """Bayesian information criterion with the noise floor known: chi2 + k ln(n)."""
        return self.chi2 + self.n_params * np.log(self.residuals.size)

    def direction_sigma_deg(self) -> np.ndarray:
        """RMS angular uncertainty of each direction, degrees, shape (c,)."""
        return _direction_sigma_deg(self.direction_covariance)

    def channel_covariance(self) -> np.ndarray:
        """Each channel's joint covariance of its unit direction (3), offset (output units) and gain (output units
        per field unit), shape (c, 5, 5): the (u, v, offset, log gain) block taken through the layout's map.

        A parameter the fit could not determine (its covariance row NaN) makes NaN only the rows and columns
        that depend on it: the others keep their terms, as the per-parameter sigmas do.
        """
        return self._joint_covariance(())

    def curve_covariance(self) -> np.ndarray | None:
        """Each channel's joint covariance of its direction, offset and gain (:meth:`channel_covariance`'s five)
        and its response curve's coefficients (quadratic, cubic, quintic: 1 / field unit^(k - 1), as
        :class:`compass.response.CubicResponse` holds them), shape (c, 8, 8); a power the fit does not carry
        has zero rows.  None when the fit has no curve (a linear response).

        A curve and a gain trade against each other over the range a channel sees (their errors are correlated
        near -1), so the two together move a heading less than the gain's variance alone says.  NaN as in
        :meth:`channel_covariance` where a parameter is undetermined.
        """
        curves = tuple(e for e in self.effects if isinstance(e, NonlinearResponse))
        return self._joint_covariance(curves) if curves else None

    def _joint_covariance(self, curves: tuple) -> np.ndarray:
        """:meth:`channel_covariance` (no ``curves``) or :meth:`curve_covariance` (the fit's curve effects)."""
        c, size = self.layout.c, 5 + (len(CURVE_POWERS) if curves else 0)
        gains, norm = self.physics.gains, self.physics.field_norm
        out = np.empty((c, size, size))
        for ch in range(c):
            columns = list(range(_BASE_PER_CHANNEL * ch, _BASE_PER_CHANNEL * (ch + 1)))
            rows = []
            for e in curves:  # each power's parameter: the relative output change at |B|, coefficient p / |B|^(k-1)
                at = self.block_start(e) + len(e.powers) * ch
                columns += [at + i for i in range(len(e.powers))]
                rows += [(5 + CURVE_POWERS.index(k), norm ** (1 - k)) for k in e.powers]
            m = np.zeros((size, len(columns)))
            m[:3, :2] = _direction_map(self.layout, self.x, ch)
            m[3, 2], m[4, 3] = self.layout.start.gains[ch], gains[ch]  # offset = V0 + p K0, gain = K0 exp(q)
            for j, (row, scale) in enumerate(rows):
                m[row, _BASE_PER_CHANNEL + j] = scale
            cov = self.covariance[np.ix_(columns, columns)]
            out[ch] = m @ np.nan_to_num(cov, nan=0.0) @ m.T
            unknown = np.any(m[:, ~np.isfinite(np.diag(cov))] != 0.0, axis=1)
            out[ch][unknown, :] = np.nan
            out[ch][:, unknown] = np.nan
        return out

    def effect_parameters(self, effect: FourFlipEffect) -> tuple[list, np.ndarray, np.ndarray]:
        """(names, values, sigmas) of one effect's block in reporting units."""
        start = self.block_start(effect)
        n = effect.n_params(len(self.physics.gains))
        scale = effect.report_scale(self.physics)
        block = slice(start, start + n)
        return self.names[block], self.x[block] * scale, self.sigma[block] * np.abs(scale)

    def effect_start(self) -> dict:
        """Fitted effect blocks by name, in fit units (to start a larger fit from this one)."""
        c = len(self.physics.gains)
        out = {}
        for e in self.effects:
            start = self.block_start(e)
            out[e.name] = self.x[start:start + e.n_params(c)]
        return out

    def block_start(self, effect: FourFlipEffect) -> int:
        c = len(self.physics.gains)
        start = _BASE_PER_CHANNEL * c + 2
        for e in self.effects:
            if e is effect:
                return start
            start += e.n_params(c)
        raise KeyError(effect.name)


class _Predictor:
    """Predicted outputs, reusing the field in H while only channel parameters change.

    A finite-difference Jacobian perturbs one parameter at a time; most belong to one channel
    (direction, offset, gain, response, drift) and leave the field in the housing frame as it was.
    """

    def __init__(self, samples: BenchSamples):
        self.samples, self._key, self._b_h = samples, None, None

    def __call__(self, physics: BenchPhysics) -> np.ndarray:
        return channel_outputs(physics, self.samples, self.field(physics) @ physics.directions.T)

    def field(self, physics: BenchPhysics) -> np.ndarray:
        """The field in H at the samples, shape (n, 3) (recomputed only when the geometry changed)."""
        key = _geometry_key(physics)
        if key != self._key:
            self._key, self._b_h = key, housing_field(physics, self.samples)
        return self._b_h


def _geometry_key(physics: BenchPhysics) -> tuple:
    """Everything :func:`housing_field` depends on, hashable."""
    arrays = (physics.encoder_fourier, physics.turntable_zero_deg, physics.flip_rotvec_deg, physics.platform_field)
    return (physics.dip_deg, physics.azimuth_deg, physics.field_norm,
            *(None if a is None else np.asarray(a).tobytes() for a in arrays))


class _Layout:
    """Packs and unpacks the parameter vector around a starting point."""

    def __init__(self, start: BenchPhysics, effects, samples: BenchSamples, channels):
        self.start, self.effects, self.samples, self.channels = start, tuple(effects), samples, tuple(channels)
        self.c = len(start.gains)
        self.basis = tangent_basis(start.directions)
        self.names = []
        for ch in channels:
            self.names += [f"{ch}.dir_u", f"{ch}.dir_v", f"{ch}.offset_fieldunit", f"{ch}.log_gain"]
        self.names += ["dip_rad", "azimuth_rad"]
        for e in self.effects:
            self.names += e.param_names(channels)

    def x0(self, effect_start: dict | None = None) -> np.ndarray:
        x = np.zeros(len(self.names))
        x[_BASE_PER_CHANNEL * self.c] = np.radians(self.start.dip_deg)
        x[_BASE_PER_CHANNEL * self.c + 1] = np.radians(self.start.azimuth_deg)
        if effect_start:
            i = _BASE_PER_CHANNEL * self.c + 2
            for e in self.effects:
                n = e.n_params(self.c)
                if e.name in effect_start:
                    x[i:i + n] = effect_start[e.name]
                i += n
        return x

    def directions(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions and the un-normalised vectors, shape (c, 3)."""
        per = x[: _BASE_PER_CHANNEL * self.c].reshape(self.c, _BASE_PER_CHANNEL)
        n = self.start.directions + np.einsum("ck,ckj->cj", per[:, :2], self.basis)
        return n / np.linalg.norm(n, axis=1, keepdims=True), n

    def physics(self, x) -> BenchPhysics:
        per = x[: _BASE_PER_CHANNEL * self.c].reshape(self.c, _BASE_PER_CHANNEL)
        directions, _ = self.directions(x)
        start = self.start
        with np.errstate(over="ignore"):  # a trial step the optimiser takes too far: inf, its residual refused
            gains = start.gains * np.exp(per[:, 3])
        physics = BenchPhysics(
            directions=directions,
            offsets=start.offsets + per[:, 2] * start.gains,
            gains=gains,
            dip_deg=float(np.degrees(x[_BASE_PER_CHANNEL * self.c])),
            azimuth_deg=float(np.degrees(x[_BASE_PER_CHANNEL * self.c + 1])),
            field_norm=start.field_norm,
        )
        i = _BASE_PER_CHANNEL * self.c + 2
        for e in self.effects:
            n = e.n_params(self.c)
            physics = e.apply(physics, x[i:i + n], self.samples)
            i += n
        return physics


def output_jacobian(layout: _Layout, x: np.ndarray, samples: BenchSamples, b_h: np.ndarray | None = None) -> np.ndarray:
    """d outputs / d x of the model at ``samples``, analytic (:mod:`calibrate.fourflip._jacobian`): (n, c, k).

    Base parameters: a direction's tangent step moves it by ``(I - a a^T) e / |n|``; the offset step
    adds the starting gain; the log gain scales everything the gain multiplies (the response and every
    drift, since their blocks are in field units times the gain): ``v - V0``; dip and azimuth turn
    the Earth field in the bench frame.
    """
    physics = layout.physics(x)
    parts = Partials(physics, samples, b_h)
    c = layout.c
    out = np.zeros((samples.platform_deg.size, c, x.size))
    directions, n = layout.directions(x)
    predicted = channel_outputs(physics, samples, parts.x)
    for ch in range(c):
        projector = (np.eye(3) - np.outer(directions[ch], directions[ch])) / np.linalg.norm(n[ch])
        col = _BASE_PER_CHANNEL * ch
        out[:, ch, col:col + 2] = parts.per_x[:, ch, None] * (parts.b_h @ (projector @ layout.basis[ch].T))
        out[:, ch, col + 2] = layout.start.gains[ch]
        out[:, ch, col + 3] = predicted[:, ch] - physics.offsets[ch]
    dip, azimuth = np.radians(physics.dip_deg), np.radians(physics.azimuth_deg)
    d_field = physics.field_norm * np.array([
        [-np.sin(dip) * np.cos(azimuth), -np.sin(dip) * np.sin(azimuth), -np.cos(dip)],
        [-np.cos(dip) * np.sin(azimuth), np.cos(dip) * np.cos(azimuth), 0.0]])
    d_b_h = np.stack([parts.bench_to_housing(v) for v in d_field], axis=-1)
    out[:, :, _BASE_PER_CHANNEL * c:_BASE_PER_CHANNEL * c + 2] = parts.through_field(d_b_h)
    i = _BASE_PER_CHANNEL * c + 2
    for e in layout.effects:
        k = e.n_params(c)
        out[:, :, i:i + k] = e.jacobian(physics, x[i:i + k], samples, parts)
        i += k
    return out


def fit_ml(
    samples: BenchSamples,
    outputs: np.ndarray,
    channels,
    start: BenchPhysics,
    noise: np.ndarray,
    effects=(),
    effect_start: dict | None = None,
    max_evaluations: int = _MAX_ITERATIONS,
) -> MLFit:
    """Fit the four-flip model with the given effects by weighted least squares.

    Parameters
    ----------
    samples : BenchSamples
    outputs : ndarray, shape (n, c)
    channels : sequence of str
    start : BenchPhysics
        Starting point (directions, offsets, gains, dip, azimuth, field magnitude).
    noise : ndarray, shape (c,)
        Per-channel noise sigma used as weights (output units).
    effects : sequence of FourFlipEffect
    effect_start : dict, optional
        Starting values of effect blocks by name (zero otherwise).
    max_evaluations : int
        Residual evaluations allowed; a fit cut short is the best point reached (Levenberg-Marquardt takes only
        steps that lower the chi-square, so its chi-square bounds the converged one's from above).
    """
    bins = Bins.of(samples, outputs)
    weights = bins.root_n / noise

    layout = _Layout(start, effects, samples, channels)  # the effects' constants from every sample
    predict = _Predictor(bins.samples)

    def residual(p):
        return ((bins.outputs - predict(layout.physics(p))) * weights).ravel()

    def jacobian(p):
        physics = layout.physics(p)
        predict(physics)  # the field in H, cached when the geometry has not changed
        d_out = output_jacobian(layout, p, bins.samples, predict.field(physics))
        return (-d_out * np.asarray(weights)[..., None]).reshape(-1, p.size)

    x0 = layout.x0(effect_start)
    if effect_start:
        # a first-order start can overshoot far outside the linear regime: keep it only if it helps
        plain = layout.x0()
        if np.sum(residual(plain) ** 2) < np.sum(residual(x0) ** 2):
            x0 = plain
    res = least_squares(residual, x0, jac=jacobian, method="lm", x_scale="jac", max_nfev=max_evaluations)
    x = res.x
    jac = res.jac
    physics = layout.physics(x)
    residuals = outputs - bench_outputs(physics, samples)
    dof = residuals.size - x.size
    chi2 = float(np.sum((residuals / noise) ** 2))
    cov, singular = _covariance(jac, layout.names)
    cov *= chi2 / max(dof, 1)
    dir_cov = _direction_covariance(layout, x, cov)
    return MLFit(physics, layout.effects, layout.names, x, cov, dir_cov, residuals, chi2, dof, singular,
                 bool(res.success), str(res.message), jac=jac, layout=layout, bins=bins)


def _covariance(jac: np.ndarray, names) -> tuple[np.ndarray, list]:
    """Inverse of the Fisher matrix J^T J (columns scaled to unit norm, eigen-decomposed).

    Directions of parameter space the data cannot determine (eigenvalues below
    ``SINGULAR_RCOND**2`` of the largest) are dropped; parameters involved in them get NaN rows
    and columns and are named in the returned list.  The small normal matrix keeps this fast and
    free of multi-threaded BLAS stalls on a busy machine.
    """
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    js = jac / scale
    w, v = np.linalg.eigh(js.T @ js)
    keep = w > SINGULAR_RCOND**2 * w.max()
    inv = (v[:, keep] / w[keep]) @ v[:, keep].T / np.outer(scale, scale)
    singular = []
    for vec in v[:, ~keep].T:
        involved = np.flatnonzero(np.abs(vec) > 0.2)
        singular.append(" + ".join(names[i] for i in involved) if involved.size else "a combination of parameters")
        inv[involved, :] = np.nan
        inv[:, involved] = np.nan
    return inv, singular


def curve_coefficients(physics: BenchPhysics) -> np.ndarray:
    """Each channel's response curve coefficients over :data:`~compass.iron_uncertainty.CURVE_POWERS` (quadratic,
    cubic, quintic; 1 / field unit^(k - 1)), zero for a power the physics does not carry, shape (c, 3)."""
    c = len(physics.gains)
    held = (getattr(physics, name) for name in CURVE_FIELDS)
    return np.column_stack([np.zeros(c) if v is None else np.asarray(v, dtype=float) for v in held])


def _direction_map(layout: _Layout, x, c: int) -> np.ndarray:
    """``d a / d (u, v)`` of channel ``c``'s unit direction, shape (3, 2)."""
    dirs, n = layout.directions(x)
    projector = (np.eye(3) - np.outer(dirs[c], dirs[c])) / np.linalg.norm(n[c])
    return projector @ layout.basis[c].T


def _direction_covariance(layout: _Layout, x, cov) -> np.ndarray:
    """Covariance of each unit direction from its (u, v) block."""
    out = np.empty((layout.c, 3, 3))
    for c in range(layout.c):
        g = _direction_map(layout, x, c)
        block = cov[_BASE_PER_CHANNEL * c:_BASE_PER_CHANNEL * c + 2, _BASE_PER_CHANNEL * c:_BASE_PER_CHANNEL * c + 2]
        out[c] = g @ block @ g.T
    return out


def structured_covariance(fit: MLFit, noise: np.ndarray, about_mean: bool = False):
    """Covariance of a fit's parameters under the structure its residual shows: one offset step, structure
    locked to the turn, or a process in time.

    :func:`calibrate.diagnosis.robust.structure_in_time` on the bins the fit ran on: where one step of
    one channel's offset explains the whole structure, its move of the parameters; where structure locked
    to the turn does (each turn's own gain of the turning part and lag in each channel, :func:`_gain_and_lag`,
    and its harmonics 2 and up of the turn angle), its move of the parameters; otherwise each
    channel's structure a stationary process over the whole recording (across flips: a slow wander
    or a room's temperature cycle carries over from one flip to the next), its spectrum estimated
    from what the fit left of it, read as the offsets' wander or, where decisively likelier, as each
    gain's (the process times the channel's signal, :func:`_signal`: robust.py, "A gain's wander: its
    carrier").  Per-flip clusters (CR2, :func:`calibrate.diagnosis.robust.cluster_covariance`)
    took flips as independent and left a random walk and an air-con cycle at 1.3-1.6 times the
    widened sigma (tools/bench_loop.py).

    ``about_mean``: the step's and the process's move taken about each channel's mean level over the session
    (the offsets then state the session's mean level: robust.py, "About the session's mean").

    Returns
    -------
    calibrate.diagnosis.robust.TimeStructure
        Its covariance in the fit's parameters (as ``fit.covariance``; NaN where that is), the step if
        it is one (its size in the weighted residual's units: :func:`step_size_output` converts), and
        whether the locked structure explained it.
    """
    from ..diagnosis.robust import TurnPhase, structure_in_time

    bins = fit.bins
    weighted, t_s, bread = _weighted_residual(fit, noise)
    locked = TurnPhase(np.radians(bins.samples.platform_deg), bins.samples.flip_index,
                       shapes=_gain_and_lag(fit, noise))
    return structure_in_time(fit.jac, weighted, t_s, bread, locked=locked, about_mean=about_mean,
                             carrier=_signal(fit, noise))


def walk_covariance(fit: MLFit, noise: np.ndarray):
    """Covariance of a fit's parameters with each channel's offset a random walk whose size the residual's block sums
    give (:func:`calibrate.diagnosis.walk.offset_walk`), on the bins the fit ran on.

    Returns
    -------
    calibrate.diagnosis.walk.OffsetWalk
        Its covariance in the fit's parameters (as ``fit.covariance``; NaN where that is), each channel's walk in
        noise sigmas of a sample per square root of a second, and the floor's own factor.
    """
    from ..diagnosis.walk import offset_walk

    weighted, t_s, bread = _weighted_residual(fit, noise)
    return offset_walk(fit.jac, weighted, t_s, bread, row_weight=fit.bins.root_n)


def offset_step(fit: MLFit, noise: np.ndarray, about_mean: bool = False):
    """The one step of one channel's offset that explains the whole structure of the fit's residual, with its
    covariance (:func:`calibrate.diagnosis.robust.offset_step`; its move taken about each channel's mean level over
    the session with ``about_mean``), or None; on the bins the fit ran on.

    Returns
    -------
    calibrate.diagnosis.robust.TimeStructure or None
    """
    from ..diagnosis.robust import offset_step as step_of

    weighted, t_s, bread = _weighted_residual(fit, noise)
    return step_of(fit.jac, weighted, t_s, bread, about_mean=about_mean)


def block_p_values(fit: MLFit, noise: np.ndarray, draws: int) -> np.ndarray:
    """Each band's p-value for structure in the fit's residual summed over time blocks
    (:func:`calibrate.diagnosis.robust.band_p_values`, ``draws`` of its null; white beyond the floor first), on the
    bins the fit ran on.

    Returns
    -------
    ndarray, shape (N_BANDS + 1,)
    """
    from ..diagnosis.robust import band_p_values

    weighted, t_s, bread = _weighted_residual(fit, noise)
    return band_p_values(fit.jac, weighted, t_s, bread, draws=draws)


def walk_p_value(fit: MLFit, noise: np.ndarray) -> float:
    """The p-value of "no channel's offset walks" in the fit's residual summed over time blocks
    (:func:`calibrate.diagnosis.walk.walk_p_value`), on the bins the fit ran on."""
    from ..diagnosis.walk import walk_p_value as p_value_of

    weighted, t_s, bread = _weighted_residual(fit, noise)
    return p_value_of(fit.jac, weighted, t_s, bread, row_weight=fit.bins.root_n)


def _weighted_residual(fit: MLFit, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fit's residual at its bins over the noise floor (white noise: unit variance), each bin's time, s, and
    the bread ``(J^T J)^-1`` (the covariance without its chi-square scale)."""
    bins = fit.bins
    weighted = (bins.outputs - _Predictor(bins.samples)(fit.physics)) * (bins.root_n / noise)
    # without a t_s column, the recording's order at one bin a second
    t_s = bins.samples.t_s if bins.samples.t_s is not None else np.arange(weighted.shape[0], dtype=float)
    return weighted, t_s, fit.covariance / (fit.chi2 / max(fit.dof, 1))


def _signal(fit: MLFit, noise: np.ndarray) -> np.ndarray:
    """Each channel's fitted signal less its offset at the fit's bins, in the weighted residual's units, shape
    (g, c): a gain's wander ``g(t)`` leaves ``signal * g`` in the weighted residual (its carrier)."""
    bins, phys = fit.bins, fit.physics
    return (_Predictor(bins.samples)(phys) - phys.offsets) * (bins.root_n / noise)


def _gain_and_lag(fit: MLFit, noise: np.ndarray) -> np.ndarray:
    """Each channel's signal less its mean over each turn (a gain of that turn's turning part) and the signal's
    rate in the turn angle (per radian: a lag of that turn) at the fit's bins, in the weighted residual's units,
    shape (g, c, 2).

    The gain's turning part alone: a gain's level over a turn is an offset level of the turn, which the
    mountings absorb as they absorb a wander's, and which the process model therefore keeps
    (:func:`calibrate.diagnosis.robust.structure_in_time`).
    """
    bins, phys = fit.bins, fit.physics
    weights = bins.root_n / noise
    predict = _Predictor(bins.samples)
    signal = _signal(fit, noise)
    turned = replace(bins.samples, platform_deg=bins.samples.platform_deg + RATE_STEP_DEG)
    rate = (_Predictor(turned)(phys) - predict(phys)) * weights / np.radians(RATE_STEP_DEG)
    flip = np.unique(bins.samples.flip_index, return_inverse=True)[1].ravel()
    counts = np.bincount(flip)[:, None]
    means = np.stack([np.bincount(flip, weights=column) for column in signal.T], axis=1) / counts
    return np.stack([signal - means[flip], rate], axis=2)


def step_size_output(fit: MLFit, noise: np.ndarray, channel: int, size: float) -> float:
    """A step's size in output units from the weighted residual's (``size`` noise sigmas of a bin of median count)."""
    return float(size * noise[channel] / np.median(np.broadcast_to(fit.bins.root_n, (fit.bins.outputs.shape[0], 1))))


def with_covariance(fit: MLFit, covariance: np.ndarray) -> MLFit:
    """The fit with another covariance of its parameters (and the directions' that follows from it)."""
    return replace(fit, covariance=covariance, direction_covariance=_direction_covariance(fit.layout, fit.x, covariance))


def score_effect(fit: MLFit, noise: np.ndarray, effect: FourFlipEffect) -> tuple[float, np.ndarray]:
    """Score (Lagrange multiplier) test for adding ``effect`` to a fitted model.

    Linearises the effect's parameters at zero size around the current solution, removes what
    the current parameters can already absorb, and returns the chi-square drop a refit would
    give to first order, with the Gauss-Newton start values of the effect's block.  An effect
    with a shape parameter (a time constant) is linearised at each of its
    :meth:`~calibrate.fourflip.effects.FourFlipEffect.score_points` and the best is kept.  The effect's
    columns are its analytic :meth:`~calibrate.fourflip.effects.FourFlipEffect.jacobian`.

    Returns
    -------
    expected_delta_chi2 : float
    start : ndarray
        First-order estimate of the effect's parameters (fit units).
    """
    layout, bins = fit.layout, fit.bins
    extended = _Layout(layout.start, layout.effects + (effect,), layout.samples, layout.channels)
    predict = _Predictor(bins.samples)
    weights = bins.root_n / noise

    def residual(p):
        return ((bins.outputs - predict(extended.physics(p))) * weights).ravel()

    def block_jacobian(x):
        physics = extended.physics(x)
        parts = Partials(physics, bins.samples, predict.field(physics))
        d_out = effect.jacobian(physics, x[fit.x.size:], bins.samples, parts)
        return (-d_out * np.asarray(weights)[..., None]).reshape(-1, d_out.shape[-1])

    j_b = unit_columns(np.nan_to_num(fit.jac))
    best = (-np.inf, None)
    for shape in effect.score_points(layout.c):
        x = np.concatenate([fit.x, shape])
        drop, delta = linear_score(residual, x, fit.x.size, j_b, block_jacobian=block_jacobian(x))
        if drop > best[0]:
            best = (drop, shape + delta)
    return best


def cramer_rao(physics: BenchPhysics, samples: BenchSamples, channels, noise: np.ndarray, effects=(),
               step: float = 1e-6) -> tuple[np.ndarray, float]:
    """Cramer-Rao bound of each channel's direction angle and of the dip, degrees.

    Fisher information of the model (base plus ``effects``, their parameters taken at zero) at
    ``physics`` with per-channel noise ``noise``, by central differences of the forward model in
    the fit's own parameterisation.  Combinations the data cannot determine at all are left out
    by a pseudo-inverse (the directions are never among them).

    Returns
    -------
    direction_deg : ndarray, shape (c,)
        RMS angular bound of each direction.
    dip_deg : float
    """
    layout = _Layout(physics, tuple(effects), samples, channels)
    x0 = layout.x0()
    weights = 1.0 / np.asarray(noise)
    jac = np.empty((samples.platform_deg.size * layout.c, x0.size))
    for j in range(x0.size):
        dx = np.zeros_like(x0)
        dx[j] = step
        plus = bench_outputs(layout.physics(x0 + dx), samples)
        minus = bench_outputs(layout.physics(x0 - dx), samples)
        jac[:, j] = ((plus - minus) * weights / (2 * step)).ravel()
    scale = np.where(np.any(jac, axis=0), np.linalg.norm(jac, axis=0), 1.0)
    cov = np.linalg.pinv((jac / scale).T @ (jac / scale), rcond=1e-12, hermitian=True) / np.outer(scale, scale)
    i = _BASE_PER_CHANNEL * np.arange(layout.c)
    dip = _BASE_PER_CHANNEL * layout.c
    return np.degrees(np.sqrt(cov[i, i] + cov[i + 1, i + 1])), float(np.degrees(np.sqrt(cov[dip, dip])))
