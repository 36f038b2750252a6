"""Residual diagnosis of a tumble calibration: find what the ellipsoid lacks, add it, report before and after.

The loop of :mod:`calibrate.fourflip.diagnosis` (SPEC section 4; steps 3 and 4 and the last part of 5 are
:func:`calibrate.diagnosis.evidence.select_effects`), on the radial residual of the ellipsoid,

.. math:: r_i = F \\left( |L^T c(y_i - p_h)| - 1 \\right) \\approx |S\\, c(x_i - h)| - F,

in recording units (``y = (x - centre) / radius`` the normalised raw reading, ``p_h`` the hard iron
in those units, ``L`` the ellipsoid's shape, ``S`` the soft iron with ``det S = 1``), where ``c`` is
the chain of corrections of the effects in the model (the identity for the plain ellipsoid):

1. Noise floor from second differences in time of the chosen ellipsoid's radial residual.  Turning
   the device leaves ``|m|`` unchanged, so the residual carries no motion; whatever the model lacks
   (a drift, a temperature change, a misfit that depends on the direction) changes slowly from one
   sample to the next and cancels, while white noise of sigma gives ``6 sigma^2``.
2. The base fit is the chosen ellipsoid kind, on its inliers, weighted by the floor.
3. For each candidate form the recording can show, a score (Lagrange-multiplier) test linearises
   the form's parameters at zero and gives the chi-square drop they could buy after projecting out
   what the current parameters absorb; the most promising forms (one per effect) are refitted.
4. The refit with the largest decisive evidence (delta-BIC above
   :data:`~calibrate.diagnosis.evidence.DECISIVE_BIC`) is added when it explains a real share
   (:data:`~calibrate.diagnosis.evidence.MIN_SHARE`) of the structured residual, its parameters are
   determined (finite covariance) and, with an accelerometer, it does not widen the spread of the
   field-gravity angle (the dip deviation, a residual the effect was not fitted to); repeat.
5. ``unexplained`` is true when the residual still carries structure (:func:`residual_structure`)
   or its rms exceeds the floor by more than :data:`~calibrate.diagnosis.evidence.FLOOR_MARGIN`.  If structure
   remains, the added effects may have absorbed part of something the toolkit does not model (a
   hard iron that stepped partway is partly a drift): nothing is claimed and the base fit is kept.
   When unexplained, the covariance is widened to cover the structure (the CR2 sandwich over blocks
   of consecutive samples, :mod:`calibrate.diagnosis.blocks`: a tumble has no flips, what it lacks
   changes with time; a hard iron walking between the blocks is propagated as a process in the
   parameters, the ellipsoid centre's columns, and CR2 takes the rest) and ``unexplained_cost``
   gives the hard-iron sigmas and, once the dip is known (:meth:`TumbleDiagnosis.with_alignment`),
   a level housing's heading sigma, naive and widened.

Effects, as corrections of ``z = y - p_h`` (normalised units, raw magnetometer frame); every one is
zero at the reference time ``t_ref`` (the first sample) and temperature ``T_ref`` (the mean of
``temp_c``), so the file's ``hard_iron`` is the one at ``t_ref`` and ``T_ref``:

``offset_drift`` (linear)
    ``z - v (t - t_ref) / T`` (``T`` the session length): a hard iron wandering steadily.
``offset_drift`` (warm-up)
    ``z - A (1 - exp(-(t - t_ref) / tau))``, one time constant for the three axes (one thermal path).
``temperature`` (offset; offset and scale)
    ``(z - k d) / (1 + g d)`` with ``d = (T - T_ref) / span(T)``: hard iron, and per-axis scale, linear
    in ``temp_c``.
``nonlinear_response`` (odd cubic)
    ``z + c z^3`` per axis: a response bending toward the extremes of the range.
``gain_drift`` (linear; quadratic)
    ``z / (1 + sum_k g_k tau^k)`` per axis, ``tau = (t - t_ref) / T``: each axis's gain (about the
    hard iron) changing slowly with time, as a room warming with no ``temp_c`` column does.

What ``gain_drift`` can and cannot tell.  The tumble's only constraint is a constant ``|B|``.  Write
the drifted gains as a common part ``c(t)`` and per-axis parts ``e_a(t)`` (sum zero).  The per-axis
parts change the ellipsoid's *shape* with time: with the field seen along every half-axis again and
again through the session they are identifiable from the shape alone.  The common part changes
only the sphere's *size*: ``|m|`` grows by ``c(t) |B|``, which is exactly what a field whose
magnitude changed during the recording does (a slow wander of the local field along itself): it is
identifiable only under the assumption that ``|B|`` stayed constant, and a ``gain_drift`` claimed on
a recording where the field itself changed is that change, named as a gain.  With a half-axis never
seen (``missing``) a gain change about the hard iron bends a cap of the sphere the way a hard iron
moving along that axis does (``z_a (1 + g tau) ~ z_a + g tau`` where ``z_a ~ 1``): the two trade off
and the form is not applicable (said in ``not_applicable``).  Without a ``t_s`` that changes it is
not applicable either.

The magnetometer-accelerometer rotation (:func:`calibrate.tumble.alignment.fit_misalignment`) is fitted after
the diagnosis, on the corrected readings, and reported as a step of the same form: the field-gravity
angle's rms about the dip before and after, with its delta-BIC.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from itertools import combinations_with_replacement

import numpy as np
from scipy.optimize import approx_fprime

from compass.frames import row_norms

from ..contract import FitStatistics
from ..diagnosis.evidence import (FitRecord, Proposal, determined, gather_forms, is_unexplained, linearised_score,
                                  refit_from_better_start, select_effects, unit_columns)
from ..diagnosis.blocks import TIME_BLOCKS, level_heading_sigma_deg, time_blocks, widened_in_time
from ..diagnosis.robust import extra_sigma
from ..diagnosis.forms import json_float, rms
from ..effects import (Basis, EffectForm, OddCubic, Recorded, TemperatureForm, TimePolynomial, WarmUpForm, settled,
                       time_powers, warm_up_tau_s)
from ..diagnosis.report import Diagnosis
from ..noise import chi2_sf, second_difference_sigma, second_differences
from .alignment import MAX_ANGLE_WIDENING, Misalignment, field_gravity_angles, static_mask
from .ellipsoid import EllipsoidFit, fit_covariance, plain_fit, propagate, radial_jacobian, shape_matrix, sym_sqrt

__all__ = ["TumbleEffect", "TUMBLE_FORMS", "TumbleDiagnosis", "NOT_CONVERGED_WARNING", "UNEXPLAINED_WARNING",
           "diagnose_tumble", "unexplained_cost",
           "ellipsoid_parameter_names", "radial_noise_floor", "residual_structure"]

_AXES = ("mx", "my", "mz")
_N_AXES = len(_AXES)
STRUCTURE_BLOCKS = TIME_BLOCKS
"""Blocks of consecutive samples (and temperature bands) in the structure test: the unexplained
widening's blocks (:data:`calibrate.diagnosis.blocks.TIME_BLOCKS`), one blocking for both."""
MIN_BLOCK_SAMPLES = 50
_STRUCTURE_CHUNK_ROWS = 8192
"""Rows per chunk of the structure regression (a chunk's design takes 8192 x ~90 x 8 bytes, 6 MB)."""
_JACOBIAN_CHUNK_ROWS = 32768
"""Rows per chunk of the fits' residual and Jacobian (their temporaries then stay in the CPU's cache)."""
UNEXPLAINED_WARNING = ("structure remains in |m| - F above the noise floor that no modelled effect accounts for "
                       "(a field that changed during the recording, a disturbance, an effect the toolkit does not "
                       "model): see the diagnosis; the uncertainties are then optimistic")
NOT_CONVERGED_WARNING = "the fit did not converge"
"""How the warning for a final fit stopped short of its minimum starts (:func:`calibrate.tumble.fit.calibrate_tumble`;
the production class ``not_converged``, which ``compass export`` refuses)."""
_FD_STEP = 1e-6


@dataclass(frozen=True)
class _Rows:
    """Samples the corrections act on: normalised readings and their time and temperature."""

    y: np.ndarray
    t_s: np.ndarray | None
    temp_c: np.ndarray | None

    def take(self, mask: np.ndarray) -> "_Rows":
        return _Rows(self.y[mask], None if self.t_s is None else self.t_s[mask],
                     None if self.temp_c is None else self.temp_c[mask])


@dataclass(frozen=True)
class _Context:
    """Constants of a recording the effects are written against (recording units, s, degC)."""

    radius: float
    basis: Basis


class TumbleEffect(EffectForm):
    """One extension of the ellipsoid model (:class:`calibrate.effects.Effect`): its correction.

    Its channels are the three axes (``n_params(3)``).  Parameters are in normalised units (of order
    one or smaller); :meth:`report` turns them into physical ones.  :meth:`applicable` also reads
    the recording's ``missing`` half-axes (the field never came near them, e.g. ``("+Z",)``).
    """

    def correct(self, z: np.ndarray, q: np.ndarray, rows: _Rows, ctx: _Context) -> np.ndarray:
        """The reading minus hard iron, shape (n, 3), normalised units, with the effect removed."""
        raise NotImplementedError

    def pulled(self, g: np.ndarray, z: np.ndarray, q: np.ndarray, rows: _Rows, ctx: _Context) -> np.ndarray | None:
        """``g . d correct / d q`` of each row, shape (n, n_params): the residual's derivatives by ``q`` when
        ``g`` is its gradient by the corrected reading; None (the default) leaves them to finite differences."""
        return None

    def passed_back(self, g: np.ndarray, z: np.ndarray, q: np.ndarray, rows: _Rows, ctx: _Context) -> np.ndarray | None:
        """``g . d correct / d z`` of each row, shape (n, 3): the gradient by the effect's input reading from
        ``g``, the one by its output; None (the default) leaves the fits' Jacobian to finite differences."""
        return None

    def reference(self, ctx: _Context) -> dict:
        """Where the effect is zero (the file's hard iron holds there)."""
        return {}

    def report(self, q: np.ndarray, sigma: np.ndarray, ctx: _Context) -> dict:
        """``{name: {"value", "sigma"}}`` in physical units (named in each key)."""
        raise NotImplementedError


def _per_axis(label: str, values, sigmas) -> dict:
    return {f"{ax}.{label}": {"value": float(v), "sigma": float(s)} for ax, v, s in zip(_AXES, values, sigmas)}


class _AtFirstSample(TumbleEffect):
    def reference(self, ctx):
        return {"t_s": ctx.basis.t_ref_s}


class LinearDrift(TimePolynomial, _AtFirstSample):
    """Hard iron changing at a constant rate (degree 1): parameters are the change over the session."""

    def correct(self, z, q, rows, ctx):
        return z - np.outer(ctx.basis.tau(rows.t_s), q)

    def pulled(self, g, z, q, rows, ctx):
        return -ctx.basis.tau(rows.t_s)[:, None] * g

    def passed_back(self, g, z, q, rows, ctx):
        return g

    def report(self, q, sigma, ctx):
        scale = ctx.radius / ctx.basis.session_s
        return _per_axis("hard_iron_rate_per_s", q * scale, sigma * scale)


class WarmUp(WarmUpForm, _AtFirstSample):
    """Hard iron settling after switch-on: per-axis change ``A`` and ``log(tau / session)``."""

    def correct(self, z, q, rows, ctx):
        tau = warm_up_tau_s(ctx.basis.session_s, q[3])
        return z - np.outer(settled(rows.t_s, ctx.basis.t_ref_s, tau), q[:3])

    def pulled(self, g, z, q, rows, ctx):
        tau = warm_up_tau_s(ctx.basis.session_s, q[3])
        if tau == ctx.basis.session_s * np.exp(q[3]):  # log(tau / session) inside the clip
            elapsed = (rows.t_s - ctx.basis.t_ref_s) / tau
            d_log_tau = -np.exp(-elapsed) * elapsed  # d settled / d log(tau)
        else:
            d_log_tau = np.zeros(len(rows.t_s))
        return np.column_stack([-settled(rows.t_s, ctx.basis.t_ref_s, tau)[:, None] * g, -(g @ q[:3]) * d_log_tau])

    def passed_back(self, g, z, q, rows, ctx):
        return g

    def report(self, q, sigma, ctx):
        tau = warm_up_tau_s(ctx.basis.session_s, q[3])
        out = _per_axis("hard_iron_settled_change", q[:3] * ctx.radius, sigma[:3] * ctx.radius)
        out["tau_s"] = {"value": float(tau), "sigma": float(tau * sigma[3])}
        return out


@dataclass(frozen=True)
class Temperature(TemperatureForm, TumbleEffect):
    """Hard iron (and, with ``scale``, per-axis scale) linear in ``temp_c``."""

    scale: bool = False

    def n_params(self, n_channels):
        return 2 * n_channels if self.scale else n_channels

    def correct(self, z, q, rows, ctx):
        d = ctx.basis.d(rows.temp_c)[:, None]
        z = z - d * q[:3]
        return z / (1.0 + d * q[3:]) if self.scale else z

    def pulled(self, g, z, q, rows, ctx):
        d = ctx.basis.d(rows.temp_c)[:, None]
        if not self.scale:
            return -d * g
        gain = 1.0 + d * q[3:]
        return np.column_stack([-d * g / gain, -d * g * (z - d * q[:3]) / gain**2])

    def passed_back(self, g, z, q, rows, ctx):
        return g / (1.0 + ctx.basis.d(rows.temp_c)[:, None] * q[3:]) if self.scale else g

    def reference(self, ctx):
        return {"temp_c": ctx.basis.temp_ref_c}

    def report(self, q, sigma, ctx):
        span = ctx.basis.temp_span_c
        scale = ctx.radius / span
        out = _per_axis("hard_iron_per_degc", q[:3] * scale, sigma[:3] * scale)
        if self.scale:
            out.update(_per_axis("scale_rel_per_degc", q[3:] / span, sigma[3:] / span))
        return out


class OddCubicReading(OddCubic, TumbleEffect):
    """Odd cubic per axis about the hard iron: ``z + c z^3`` (``c``: correction at ``|z| = 1``, ~ |B|).

    Only with the field seen along every half-axis: from one side a cubic bends the surface the
    way a far-away hard iron does, and the two trade off without bound.
    """

    def applicable(self, columns):
        if columns.missing:
            return (f"the field was never along {', '.join(columns.missing)}: a cubic response trades off against "
                    "the hard iron")
        return None

    def correct(self, z, q, rows, ctx):
        return z + q * (z * z * z)  # a product: numpy takes z**3 through pow(), 20x slower

    def pulled(self, g, z, q, rows, ctx):
        return g * (z * z * z)

    def passed_back(self, g, z, q, rows, ctx):
        return g * (1.0 + 3.0 * q * (z * z))

    def report(self, q, sigma, ctx):
        return _per_axis("cubic_correction_at_field", q, sigma)


class GainDrift(TimePolynomial, _AtFirstSample):
    """Per-axis gain changing with time (module docstring): ``z / (1 + sum_k g_ak tau^k)``.

    Parameters are per axis, then per power (``q.reshape(3, degree)``): the relative gain change
    at the end of the session from each power.  Only with the field seen along every half-axis (a
    cap of the sphere's gain change is a moving hard iron).
    """

    def applicable(self, columns):
        why = super().applicable(columns)
        if why is None and columns.missing:
            why = (f"the field was never along {', '.join(columns.missing)}: a gain change there trades off "
                   "against a moving hard iron")
        return why

    def _gain(self, q, rows, ctx):
        """``tau^k`` (shape (n, degree)) and each axis's gain ``1 + sum_k g_ak tau^k`` (shape (n, 3))."""
        powers = time_powers(ctx.basis.tau(rows.t_s), self.degree)
        return powers, 1.0 + powers @ q.reshape(_N_AXES, self.degree).T

    def correct(self, z, q, rows, ctx):
        return z / self._gain(q, rows, ctx)[1]

    def pulled(self, g, z, q, rows, ctx):
        # d (z_a / gain_a) / d g_ak = -z_a tau^k / gain_a^2, in the order of q (per axis, then per power)
        powers, gain = self._gain(q, rows, ctx)
        return (-(g * z / (gain * gain))[:, :, None] * powers[:, None, :]).reshape(len(z), -1)

    def passed_back(self, g, z, q, rows, ctx):
        return g / self._gain(q, rows, ctx)[1]

    def report(self, q, sigma, ctx):
        out = {}
        q, sigma = q.reshape(_N_AXES, self.degree), sigma.reshape(_N_AXES, self.degree)
        for k in range(self.degree):
            per = ctx.basis.session_s ** (k + 1)
            label = "gain_rate_rel_per_s" if k == 0 else f"gain_rel_per_s{k + 1}"
            out.update(_per_axis(label, q[:, k] / per, sigma[:, k] / per))
        return out


_DRIFT = "a hard iron changing with t_s"
TUMBLE_FORMS: dict[str, tuple[TumbleEffect, ...]] = {
    "offset_drift": (LinearDrift("offset_drift", "linear", _DRIFT + ", at a constant rate"),
                     WarmUp("offset_drift", "warm-up", _DRIFT + ", settling exponentially (one time constant)")),
    "temperature": (Temperature("temperature", "offset", "a hard iron linear in temp_c"),
                    Temperature("temperature", "offset and scale", "a hard iron and per-axis scale linear in temp_c",
                                scale=True)),
    "nonlinear_response": (OddCubicReading("nonlinear_response", "odd cubic",
                                         "|m| bending with the direction beyond any ellipsoid: an odd cubic response per axis"),),
    "gain_drift": (GainDrift("gain_drift", "linear", "each axis's gain changing with t_s, at a constant rate", 1),
                   GainDrift("gain_drift", "quadratic", "each axis's gain changing with t_s, quadratic in time", 2)),
}
"""Each effect's forms for the tumble, simplest first; the evidence (BIC) chooses among them."""


class _Fit(FitRecord):
    """A tumble fit: the shared record, and where an effect's parameters sit in ``x``."""

    def block(self, effect: TumbleEffect, k: int) -> slice:
        start = k
        for e in self.effects:
            if e is effect:
                return slice(start, start + e.n_params(_N_AXES))
            start += e.n_params(_N_AXES)
        raise KeyError(effect.label)


@dataclass(frozen=True)
class _Scoring:
    """What the score tests against one fit share (:meth:`_Model.score`).

    Attributes
    ----------
    fit : _Fit
    z : ndarray, shape (rows, 3)
        Its corrected reading (:meth:`_Model.corrected`), normalised units.
    g : ndarray, shape (rows, 3)
        :meth:`_Model.gradient` at ``z``.
    j_b : ndarray, shape (rows, k)
        :func:`~calibrate.diagnosis.evidence.unit_columns` of its Jacobian; ``normal_b`` is ``j_b^T j_b``.
    r0 : ndarray, shape (rows,)
        Its weighted residual.
    """

    fit: _Fit
    z: np.ndarray
    g: np.ndarray
    j_b: np.ndarray
    normal_b: np.ndarray
    r0: np.ndarray


class _Model:
    """The ellipsoid with a chain of corrections, on fixed rows, weighted by the floor."""

    def __init__(self, fit: EllipsoidFit, rows: _Rows, ctx: _Context, floor: float):
        self.ellipsoid, self.k, self.field_norm = fit.ellipsoid, fit.n_params, fit.field_norm
        self.rows, self.ctx, self.floor = rows, ctx, floor
        self._scored_against: _Scoring | None = None  # the fit last scored against

    def corrected(self, x, effects, rows: _Rows) -> np.ndarray:
        """``c(y - p_h)``, shape (n, 3), normalised units."""
        z, i = rows.y - x[:3], self.k
        for e in effects:
            z = e.correct(z, x[i:i + e.n_params(_N_AXES)], rows, self.ctx)
            i += e.n_params(_N_AXES)
        return z

    def radial(self, x, effects, rows: _Rows) -> np.ndarray:
        """Radial residual, recording units; a chunk of rows at a time (each row's depends on its sample only,
        and a chunk's temporaries stay in the CPU's cache: 1.5x faster on a 700000-sample tumble)."""
        low = shape_matrix(self.ellipsoid, x[3:self.k])
        norm = np.empty(len(rows.y))
        for start in range(0, len(rows.y), _JACOBIAN_CHUNK_ROWS):
            part = slice(start, start + _JACOBIAN_CHUNK_ROWS)
            z = self.corrected(x, effects, rows.take(part)) @ low
            norm[part] = np.sqrt(np.einsum("ij,ij->i", z, z))
        return self.field_norm * (norm - 1.0)

    def weighted(self, x, effects) -> np.ndarray:
        return self.radial(x, effects, self.rows) / self.floor

    def analytic_jacobian(self, x, effects, rows: _Rows, out: np.ndarray | None = None) -> np.ndarray | None:
        """d radial / d x of ``rows``, shape (rows, x.size), back through the chain of corrections; None when an
        effect lacks its derivatives (:meth:`TumbleEffect.pulled`, :meth:`TumbleEffect.passed_back`).

        With ``w = c L`` the residual is ``F (|w| - 1)``: the shape's columns are
        :func:`~calibrate.tumble.ellipsoid.radial_jacobian`'s with ``c`` for ``y - h``; the gradient by
        ``c``, ``F L u`` (``u = w / |w|``), is passed back through the effects from the last, each taking
        its own columns from it; by the raw reading it is minus the hard iron's.  ``out`` (that shape) receives it
        instead of a new array (written in part when None is returned).
        """
        k = self.k
        inputs, z, i = [], rows.y - x[:3], k
        for e in effects:
            inputs.append((e, z, slice(i, i + e.n_params(_N_AXES))))
            z = e.correct(z, x[inputs[-1][2]], rows, self.ctx)
            i = inputs[-1][2].stop
        jac = np.empty((len(rows.y), x.size)) if out is None else out
        radial_jacobian(np.concatenate([np.zeros(3), x[3:k]]), self.ellipsoid, z, out=jac[:, :k])
        g = -jac[:, :3]  # L u, the gradient by the corrected reading (over F)
        for e, z_in, block in reversed(inputs):
            columns = e.pulled(g, z_in, x[block], rows, self.ctx)
            g = e.passed_back(g, z_in, x[block], rows, self.ctx)
            if columns is None or g is None:
                return None
            jac[:, block] = columns
        jac[:, :3] = -g
        jac *= self.field_norm
        return jac

    def jacobian(self, x, effects) -> np.ndarray:
        """d weighted / d x, shape (rows, x.size), a chunk of rows at a time.

        Analytic (:meth:`analytic_jacobian`) when every effect has its derivatives.  Else the shape's
        columns still are (the shape acts after the corrections), and the hard iron's and the effects'
        are forward differences with ``least_squares``' own steps for ``jac="2-point"``
        (``sqrt(eps) max(1, |x|)``, signed as ``x``).  A row's residual depends on its own sample only, so
        the chunks give the same Jacobian while the temporaries take a chunk's memory, not the recording's.
        """
        k = self.k
        step = np.sqrt(np.finfo(float).eps) * np.where(x >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x))
        differenced = np.r_[0:3, k:x.size]
        shape_only = np.concatenate([np.zeros(3), x[3:k]])  # radial_jacobian's d = y - 0: the corrected reading

        def radial_of(part, rows):
            full = x.copy()
            full[differenced] = part
            return self.radial(full, effects, rows)

        n = len(self.rows.y)
        jac = np.empty((n, x.size))
        for start in range(0, n, _JACOBIAN_CHUNK_ROWS):
            rows = slice(start, start + _JACOBIAN_CHUNK_ROWS)
            chunk, block = self.rows.take(rows), jac[rows]
            if self.analytic_jacobian(x, effects, chunk, out=block) is None:
                block[:, 3:k] = self.field_norm * radial_jacobian(shape_only, self.ellipsoid,
                                                                  self.corrected(x, effects, chunk))[:, 3:]
                block[:, differenced] = approx_fprime(x[differenced], radial_of, step[differenced], chunk)
            block /= self.floor
        return jac

    def fit(self, effects, x0) -> _Fit:
        res = plain_fit(self.weighted, x0, self.jacobian, args=(effects,), max_nfev=100 * (x0.size + 1))
        cov = fit_covariance(res, res.fun.size)
        return _Fit(tuple(effects), res.x, res.jac, cov, res.fun * self.floor, float(res.fun @ res.fun),
                    res.fun.size, bool(res.success), str(res.message))

    def held(self, x, success: bool, message: str) -> _Fit:
        """The ellipsoid at ``x`` as another fit made it, not refitted: its residual and Jacobian here; no covariance
        (inf: ``|m|`` alone is not what determined ``x``, so its ``J^T J`` does not give ``x``'s)."""
        r = self.weighted(x, ())
        return _Fit((), np.array(x, dtype=float), self.jacobian(x, ()), np.full((x.size, x.size), np.inf),
                    r * self.floor, float(r @ r), r.size, bool(success), str(message))

    def gradient(self, fit: _Fit, c: np.ndarray) -> np.ndarray:
        """``L u`` (``u = w / |w|``, ``w = c L``) of each row, shape (rows, 3): the radial residual's gradient by the
        corrected reading ``c`` (normalised units) over ``F``, with ``fit``'s shape ``L``."""
        low = shape_matrix(self.ellipsoid, fit.x[3:self.k])
        w = c @ low
        return (w / row_norms(w)[:, None]) @ low.T

    def pulled(self, fit: _Fit, effect: TumbleEffect, q: np.ndarray, z: np.ndarray,
               g: np.ndarray | None = None) -> np.ndarray | None:
        """d weighted / d q of ``effect`` added last to ``fit`` with parameters ``q``, shape (rows, q.size), or None.

        ``z`` is ``fit``'s corrected reading (:meth:`corrected`), which the effect corrects further.
        With ``w = c L`` the residual is ``F (|w| - 1)``, whose gradient by the corrected reading ``c``
        is ``F L u`` (``u = w / |w|``, :meth:`gradient`); the effect's :meth:`TumbleEffect.pulled` takes it on
        to ``q``.  ``g``: :meth:`gradient` at ``c``, when the caller has it (at a score point, where the
        effect is switched off, ``c`` is ``z``).
        """
        g = self.gradient(fit, effect.correct(z, q, self.rows, self.ctx)) if g is None else g
        block = effect.pulled(g, z, q, self.rows, self.ctx)
        return None if block is None else block * (self.field_norm / self.floor)

    def score(self, fit: _Fit, effect: TumbleEffect) -> tuple[float, np.ndarray]:
        """Score test for adding ``effect``: (expected chi-square drop, start of its block).

        The effect's Jacobian at each of its score points is projected off the current fit's
        Jacobian (what the current parameters absorb); directions it cannot tell from them are
        dropped.  The drop is ``r^T J (J^T J)^{-1} J^T r`` with the projected ``J``; the start is the
        Gauss-Newton step from the score point.  The effect's columns are analytic where it has them
        (:meth:`pulled`), else forward differences.

        A round scores every form against one fit: what the scores share is computed once per fit
        (:class:`_Scoring`).  The score points are blocks of zero size, where every form's correction
        returns its input as it is (``tests/calibrate/tumble/test_score_reuse.py``): the residual there is
        the fit's own, and so is the gradient by the corrected reading.
        """
        if self._scored_against is None or self._scored_against.fit is not fit:
            z = self.corrected(fit.x, fit.effects, self.rows)
            j_b = unit_columns(fit.jac)
            self._scored_against = _Scoring(fit, z, self.gradient(fit, z), j_b, j_b.T @ j_b,
                                            self.weighted(fit.x, fit.effects))
        at = self._scored_against
        return linearised_score(self.weighted, fit, effect, effect.score_points(_N_AXES), _FD_STEP,
                                block_jacobian=lambda q: self.pulled(fit, effect, q, at.z, at.g), j_b=at.j_b,
                                r0=at.r0, normal_b=at.normal_b)

    def refit(self, fit: _Fit, effect: TumbleEffect, start: np.ndarray) -> _Fit:
        """The fit with ``effect`` added, from ``start`` or the effect switched off, whichever fits better."""
        self._scored_against = None  # a round's scores come before its refits: free its (rows, k) Jacobian for them
        return refit_from_better_start(self.fit, self.weighted, fit, effect, effect.score_points(_N_AXES)[0], start)


@dataclass(frozen=True)
class TumbleDiagnosis(Diagnosis):
    """Outcome of the residual diagnosis of a tumble fit.

    Attributes
    ----------
    fit : EllipsoidFit
        The ellipsoid at the reference condition (hard iron at ``t_ref`` and ``T_ref``), fitted
        with the claimed effects; the base fit itself when none is claimed.
    raw_at_reference : ndarray, shape (n, 3)
        Every raw reading with the claimed effects removed (what the sensor would have read at the
        reference condition), recording units, magnetometer frame; ``fit.calibrated`` maps it onto
        the sphere.
    effects : tuple of dict
        ``{"name", "form", "reference", "parameters"}`` of each claimed effect: the file's ``effects``.
    block : dict
        The SPEC section 4 ``diagnosis`` block.
    statistics : FitStatistics
        The final fit's: the ellipsoid's normalised parameters (:func:`ellipsoid_parameter_names`),
        then the claimed effects', against the radial noise floor.
    """

    fit: EllipsoidFit
    raw_at_reference: np.ndarray
    effects: tuple
    block: dict
    statistics: FitStatistics

    def with_alignment(self, mis: Misalignment, fit: EllipsoidFit) -> "TumbleDiagnosis":
        """Add the magnetometer-accelerometer rotation as a step, and the final fit's residual.

        Parameters
        ----------
        mis : Misalignment
            The rotation's fit (``rotation`` None when it was not applied).
        fit : EllipsoidFit
            The ellipsoid after the rotation was fitted with it (its residuals on
            ``raw_at_reference``).

        Notes
        -----
        That refit holds the effects fixed, so its standard errors leave out how the ellipsoid
        trades off against them; with claimed effects each one is kept at least as large as the
        diagnosis's, which includes that.
        """
        if self.effects or "unexplained_cost" in self.block:  # the diagnosis's sigmas held the effects or the widening
            fit = replace(fit, hard_iron_sigma=np.fmax(fit.hard_iron_sigma, self.fit.hard_iron_sigma),
                          soft_iron_sigma=np.fmax(fit.soft_iron_sigma, self.fit.soft_iron_sigma),
                          field_norm_sigma=float(np.fmax(fit.field_norm_sigma, self.fit.field_norm_sigma)))
        rms = float(np.sqrt(np.mean(fit.residuals[fit.inliers] ** 2)))
        applied = mis.rotation is not None
        evidence = (f"field-gravity angle rms about the dip {mis.spread_before_deg:.3f} -> {mis.spread_after_deg:.3f} deg "
                    f"over {mis.n_static} quasi-static samples; " + mis.words())
        # not an effect of the residual (SPEC section 4's steps add those): the frames' alignment, beside them
        alignment = {"name": "mag_to_accel", "residual_rms": rms, "applied": applied,
                     "angle_rms_deg_before": mis.spread_before_deg, "angle_rms_deg_after": mis.spread_after_deg,
                     "evidence": evidence, "delta_bic": -mis.delta_bic}
        block = dict(self.block, alignment=alignment, residual_rms_after=rms)
        if "unexplained_cost" in block and np.isfinite(mis.dip_deg):  # the runtime's heading, now the dip is known
            block["unexplained_cost"] = _with_heading(block["unexplained_cost"], fit.field_norm, mis.dip_deg)
        block["unexplained"] = is_unexplained(block["structure_test"]["p_value"], rms, block["noise_floor"])
        return replace(self, fit=fit, block=block)


def ellipsoid_parameter_names(ellipsoid: str) -> tuple[str, ...]:
    """Names of an ellipsoid kind's normalised parameters (:func:`calibrate.tumble.ellipsoid.shape_matrix`).

    ``h_*``: the hard iron's offset from the normalising centre over its radius; ``log_l*``: the log
    of the shape ``L``'s diagonal (one shared by the axes for ``offset``); ``l_*``: its lower entries.
    """
    shape = {"offset": ("log_l",), "diagonal": ("log_l_x", "log_l_y", "log_l_z"),
             "full": ("log_l_x", "log_l_y", "log_l_z", "l_yx", "l_zx", "l_zy")}[ellipsoid]
    return ("h_x", "h_y", "h_z") + shape


def radial_noise_floor(residuals: np.ndarray) -> float:
    """White-noise sigma of a radial residual from its second differences in time.

    Parameters
    ----------
    residuals : ndarray, shape (n,)
        Radial residual of every sample in recording order, recording units.

    Returns
    -------
    float
        ``MAD(r[i-1] - 2 r[i] + r[i+1]) / sqrt(6)`` (normalised MAD: robust to disturbances and
        steps; :func:`calibrate.noise.second_difference_sigma`), recording units.
    """
    return float(second_difference_sigma(second_differences(residuals)))


_MONOMIALS = tuple(idx for degree in (3, 4) for idx in combinations_with_replacement(range(3), degree))
"""The structure regression's cubic and quartic monomials of the field direction, as the axes they multiply."""


def _structure_design(directions: np.ndarray, blocks, n_blocks: int, extra: np.ndarray | None = None) -> np.ndarray:
    """Columns of :func:`residual_structure`'s regression for some rows: block-local terms, then monomials.

    The block-local columns come first: a block's are zero outside it, so a chunk of rows within a few
    blocks leaves the others' rows of the factorisation untouched (:func:`residual_structure`).  For each
    band, block ``b``'s columns are ``1, x, y, z`` on its rows; a monomial is the product of its axes in
    order (``((x_i x_j) x_k) x_l``, each from the one before it).  ``extra`` (one value a row), when given,
    is appended as the last column.
    """
    n_local = 4 * n_blocks * len(blocks)
    design = np.zeros((len(directions), n_local + len(_MONOMIALS) + (extra is not None)))
    rows = np.arange(len(directions))[:, None]
    local = np.column_stack([np.ones(len(directions)), directions])
    for band, block in enumerate(blocks):  # each row's four columns, by index: no mask per block
        design[rows, 4 * (band * n_blocks + np.asarray(block))[:, None] + np.arange(4)] = local
    axes = np.ascontiguousarray(directions.T)
    products = {(i,): axes[i] for i in range(3)}  # each monomial's, and its leading axes'
    for column, idx in enumerate(_MONOMIALS, start=n_local):
        for end in range(2, len(idx) + 1):
            if idx[:end] not in products:
                products[idx[:end]] = products[idx[:end - 1]] * axes[idx[end - 1]]
        design[:, column] = products[idx]
    if extra is not None:
        design[:, -1] = extra
    return design


def residual_structure(weighted: np.ndarray, directions: np.ndarray, bands) -> tuple[float, int, float]:
    """Structure left in a radial residual, against white noise at the floor.

    The weighted residual is regressed on cubic and quartic monomials of the field direction (a
    response no ellipsoid bends to) and, within blocks of equal count along each band (time,
    temperature), on a constant and the direction (a hard iron or field that changed).  Under white
    noise the chi-square drop follows chi2(rank).

    Parameters
    ----------
    weighted : ndarray, shape (n,)
        Residual over the noise floor.
    directions : ndarray, shape (n, 3)
        Unit field direction of each sample, magnetometer frame.
    bands : sequence of ndarray, shape (n,)
        Orderings to block along (``t_s`` or the sample index; ``temp_c``).

    Returns
    -------
    delta_chi2 : float
    dof : int
    p_value : float
    """
    n = len(weighted)
    n_blocks = max(2, min(STRUCTURE_BLOCKS, n // MIN_BLOCK_SAMPLES))
    blocks = [np.argsort(np.argsort(key, kind="stable")) * n_blocks // n for key in bands]
    # R of the QR factorisation of [design | weighted], a chunk of rows at a time (memory flat in n):
    # R has the design's singular values and R^T R its normal equations, so the least squares below
    # is the one on the whole design, rank threshold included.  A chunk updates only the rows and
    # columns of R it reaches: its non-zero columns, and every later column that a row of R among them
    # already has an entry in.  The other columns are zero in the chunk, so the reflections leave them
    # and the other rows as they are (the blocks of other times and temperatures: a third of the work)
    r_aug = None
    for start in range(0, n, _STRUCTURE_CHUNK_ROWS):
        rows = slice(start, start + _STRUCTURE_CHUNK_ROWS)
        chunk = _structure_design(directions[rows], [block[rows] for block in blocks], n_blocks, weighted[rows])
        if r_aug is None:
            r_aug = np.zeros((chunk.shape[1], chunk.shape[1]))
        reached = np.any(chunk != 0, axis=0)
        entries = r_aug != 0  # upper triangular: a reached row reaches the later columns it has entries in
        while True:  # until no reached row reaches a column not yet reached (at most a few rounds)
            grown = reached | np.any(entries[reached], axis=0)
            if np.array_equal(grown, reached):
                break
            reached = grown
        at = np.ix_(reached, reached)
        r_aug[at] = np.linalg.qr(np.vstack([r_aug[at], chunk[:, reached]]), mode="r")
    k = r_aug.shape[1] - 1
    r_design = r_aug[:k, :k]
    coef, _, rank, _ = np.linalg.lstsq(r_design, r_aug[:k, k], rcond=np.finfo(float).eps * max(n, k))
    drop = float(np.sum((r_design @ coef) ** 2))
    return drop, int(rank), chi2_sf(drop, rank)


_COST_METHOD = (f"a hard-iron walk between {TIME_BLOCKS} blocks of consecutive samples propagated to the fit, "
                "the CR2 sandwich over them for the rest (calibrate.diagnosis.blocks)")


def unexplained_cost(naive_sigma: np.ndarray, wide_sigma: np.ndarray, method: str = _COST_METHOD) -> dict:
    """The diagnosis's ``unexplained_cost``: the hard iron's sigma per axis, naive and widened (recording units), and
    how it was widened (``method``, in words)."""
    return {"hard_iron": {ax: {"naive": float(a), "widened": float(b)}
                          for ax, a, b in zip(_AXES, naive_sigma, wide_sigma)},
            "method": method}


def _with_heading(cost: dict, field_norm: float, dip_deg: float) -> dict:
    """``cost`` with the heading sigma of a level housing from the hard iron, naive and widened.

    The magnetometer's x and y are taken as horizontal (its rotation to the housing is a few degrees).
    """
    naive, wide = (level_heading_sigma_deg(cost["hard_iron"]["mx"][k], cost["hard_iron"]["my"][k], field_norm, dip_deg)
                   for k in ("naive", "widened"))
    return dict(cost, heading_deg=float(extra_sigma(wide, naive)), heading_sigma_deg={"naive": naive, "widened": wide},
                method=cost["method"] + "; the heading sigma from the hard iron alone, a level housing, RMS over headings")


def diagnose_tumble(mag: np.ndarray, fit: EllipsoidFit, *, t_s: np.ndarray | None = None,
                    temp_c: np.ndarray | None = None, accel: np.ndarray | None = None, missing=(),
                    candidates=None, refit: bool = True) -> TumbleDiagnosis:
    """Run the diagnosis loop on a tumble's chosen ellipsoid.

    Parameters
    ----------
    mag : ndarray, shape (n, 3)
        The raw readings ``fit`` was made from, recording units, magnetometer frame, in time order.
    fit : EllipsoidFit
        The chosen ellipsoid (its kind, normalisation and inliers are kept).
    t_s, temp_c : ndarray, shape (n,), optional
        Time (s) and sensor temperature (degC) of each reading.
    accel : ndarray, shape (n, 3), optional
        Accelerometer at the same rows, any unit: an effect is claimed only if it does not widen
        the spread of the field-gravity angle over the quasi-static samples (the dip deviation)
        by more than :data:`MAX_ANGLE_WIDENING`.
    missing : sequence of str
        Half-axes the field never came near (:attr:`calibrate.tumble.Coverage.missing`).
    candidates : sequence of str, optional
        Effect names to consider (default: every name in :data:`TUMBLE_FORMS`).
    refit : bool
        Whether the base model is ``fit``'s kind refitted to ``|m|`` on its inliers (``fit`` is then that fit's
        optimum, as :func:`~calibrate.tumble.ellipsoid.fit_ellipsoid` makes it, and the refit only weighs it by the
        floor).  False: ``fit`` was made from more than ``|m|`` (the gyro-aided fit, :mod:`calibrate.tumble.gyro`)
        and is diagnosed as it is: its own ``|m| - F``, no effect tried (``candidates`` must be empty), no widening
        from ``|m|`` alone.  Refitted to ``|m|`` alone, such a fit moves to what ``|m|`` prefers: off the field's
        cap of directions, where ``|m|`` does not determine the full ellipsoid, a sphere growing without bound
        (a simulated 15 % tumble: ``F`` 50 -> 1300, stopped at the evaluation limit), whose residual, scaled by the
        held ``F``, read 0.003 against a noise floor of 0.3.

    Notes
    -----
    The residual is ``F (|w| - 1)`` with ``F`` the given fit's field norm (:meth:`_Model.radial`): the distance from
    the surface, in recording units, for a fit near ``fit``, which every fit of the loop is (it starts there).

    Returns
    -------
    TumbleDiagnosis

    Raises
    ------
    ValueError
        ``t_s`` or ``temp_c`` not of length n, or an unknown candidate name.
    """
    mag = np.asarray(mag, dtype=float)
    n = len(mag)
    t_s = None if t_s is None else np.asarray(t_s, dtype=float)
    temp_c = None if temp_c is None else np.asarray(temp_c, dtype=float)
    for label, v, shape in (("t_s", t_s, (n,)), ("temp_c", temp_c, (n,)), ("accel", accel, (n, 3))):
        if v is not None and np.shape(v) != shape:
            raise ValueError(f"{label} must have one value per magnetometer sample {shape}, got shape {np.shape(v)}")
    names = list(TUMBLE_FORMS) if candidates is None else list(candidates)
    if not refit and names:
        raise ValueError(f"a fit diagnosed as it is (refit=False) has no effects tried, got candidates {names}")
    unknown = [c for c in names if c not in TUMBLE_FORMS]
    if unknown:
        raise ValueError(f"unknown tumble effect(s) {unknown}; known: {', '.join(TUMBLE_FORMS)}")

    pool, skipped = gather_forms(names, TUMBLE_FORMS, lambda e: e.applicable(Recorded(t_s, temp_c, tuple(missing))))
    ctx = _Context(radius=fit.radius, basis=Basis.of(t_s, temp_c))
    floor = radial_noise_floor(fit.residuals)
    rows = _Rows((mag[fit.inliers] - fit.centre) / fit.radius, None if t_s is None else t_s[fit.inliers],
                 None if temp_c is None else temp_c[fit.inliers])
    model = _Model(fit, rows, ctx, floor)
    bands = [np.arange(n)[fit.inliers] if t_s is None else rows.t_s]
    if temp_c is not None and np.ptp(temp_c) > 0:
        bands.append(rows.temp_c)

    static = None if accel is None else static_mask(np.asarray(accel, dtype=float))[fit.inliers]
    accel_static = None if accel is None else np.asarray(accel, dtype=float)[np.flatnonzero(fit.inliers)[static]]

    def angle_spread(f: _Fit) -> float:
        """Std of the field-gravity angle over the quasi-static inliers, deg (NaN without them)."""
        if static is None or np.count_nonzero(static) < 20:
            return float("nan")
        m = model.corrected(f.x, f.effects, rows)[static] @ sym_sqrt(fit.ellipsoid, f.x[3:model.k])
        return float(np.std(field_gravity_angles(m, accel_static)))

    def keeps_the_angle(p: Proposal):
        spread = angle_spread(p.current), angle_spread(p.trial)
        measured = {"angle_rms_deg_before": json_float(spread[0]), "angle_rms_deg_after": json_float(spread[1])}
        if spread[1] > (1.0 + MAX_ANGLE_WIDENING) * spread[0]:
            return f"it widens the field-gravity angle spread from {spread[0]:.3f} to {spread[1]:.3f} deg", measured
        return None, measured

    def claim(p: Proposal, measured: dict) -> dict:
        block = p.trial.block(p.effect, model.k)
        return {
            "added": p.effect.name,
            "form": p.effect.form,
            "residual_rms": rms(p.trial.residuals),
            **p.evidence(p.effect.n_params(_N_AXES)),
            **measured,
            "parameters": p.effect.report(p.trial.x[block], np.sqrt(np.diag(p.trial.covariance))[block], ctx),
        }

    def verdict(f: _Fit):
        z = model.corrected(f.x, f.effects, rows)
        structure = residual_structure(f.residuals / floor, z / row_norms(z)[:, None], bands)
        return structure, is_unexplained(structure[2], rms(f.residuals), floor)

    base = model.fit((), fit.params) if refit else model.held(fit.params, fit.success, fit.message)
    chosen = select_effects(
        base, pool, score=model.score, refit=model.refit, n_params=lambda e: e.n_params(_N_AXES),
        log_n=np.log(base.residuals.size),
        base_step={"model": "base", "kind": fit.ellipsoid, "residual_rms": rms(base.residuals)}
        | ({} if refit else {"refitted": False}),
        write_step=claim, verdict=verdict, checks=(determined("the ellipsoid"), keeps_the_angle))
    current, steps = chosen.fit, chosen.steps
    (structure, dof, p_value), unexplained = chosen.structure, chosen.unexplained

    covariance, cost = current.covariance, None
    if unexplained and refit:  # the sigmas grow to cover the structure that remains (calibrate.diagnosis.blocks)
        covariance = widened_in_time(current.jac, current.residuals / floor, time_blocks(bands[0]),
                                     current.covariance, hard=np.arange(3))
    final_fit, raw_ref, effects = fit, mag, ()
    if unexplained and np.all(np.isfinite(np.diag(covariance)[:model.k])):
        _, sig_h, _, sig_s, _, sig_f = propagate(fit.ellipsoid, current.x[:model.k], covariance, fit.centre, fit.radius)
        final_fit = replace(fit, hard_iron_sigma=np.fmax(sig_h, fit.hard_iron_sigma),
                            soft_iron_sigma=np.fmax(sig_s, fit.soft_iron_sigma),
                            field_norm_sigma=float(np.fmax(sig_f, fit.field_norm_sigma)))
        cost = unexplained_cost(fit.hard_iron_sigma, final_fit.hard_iron_sigma)
    if current.effects:
        k = model.k
        h, sig_h, s_mat, sig_s, f_norm, sig_f = propagate(fit.ellipsoid, current.x[:k], covariance,
                                                           fit.centre, fit.radius)
        every_row = _Rows((mag - fit.centre) / fit.radius, t_s, temp_c)
        raw_ref = h + fit.radius * model.corrected(current.x, current.effects, every_row)
        resid_all = row_norms((raw_ref - h) @ s_mat.T) - f_norm
        final_fit = replace(fit, hard_iron=h, hard_iron_sigma=sig_h, soft_iron=s_mat, soft_iron_sigma=sig_s,
                            field_norm=f_norm, field_norm_sigma=sig_f, residuals=resid_all,
                            rss=float(np.sum(resid_all[fit.inliers] ** 2)), success=current.success,
                            message=current.message, params=current.x[:k])
        effects = tuple({"name": step["added"], "form": step["form"], "reference": e.reference(ctx),
                         "parameters": step["parameters"]} for step, e in zip(steps[1:], current.effects))
    block = {
        "subject": "|m| - F",
        "noise_floor": floor,
        "noise_floor_source": "from second differences of the residual in time",
        "steps": steps,
        "effects": [e.name for e in current.effects],
        "residual_rms_before": steps[0]["residual_rms"],
        "residual_rms_after": rms(current.residuals),
        "unexplained": unexplained,
        "structure_test": {"delta_chi2": structure, "dof": dof, "p_value": p_value},
        "not_claimed": chosen.not_claimed,
        "not_applicable": skipped,
        "hard_iron_change": {"value": (final_fit.hard_iron - fit.hard_iron).tolist(),
                             "sigma": final_fit.hard_iron_sigma.tolist()},
    }
    if cost is not None:
        block["unexplained_cost"] = cost
    names = ellipsoid_parameter_names(fit.ellipsoid) + tuple(
        f"{e.name}[{j}]" for e in current.effects for j in range(e.n_params(_N_AXES)))
    statistics = FitStatistics(names, current.x, covariance, current.chi2, current.dof, current.bic(),
                               current.success, current.message)
    return TumbleDiagnosis(final_fit, raw_ref, effects, block, statistics)
