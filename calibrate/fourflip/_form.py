"""Is the response curve the vocabulary's form?  A lack-of-fit test of a fit's response, curved or linear.

The vocabulary's ``nonlinear_response`` bends each channel by a few powers of its own field component
``x = a . B`` (a cubic, or powers 2 and 3, or 3 and 5).  A sensor whose curve has another shape (a knee:
linear up to ``0.7 |B|`` and compressing beyond) leaves, after the cubic, a residual that is still a function
of ``x`` alone.  On a four-flip bench that residual sits where the channel is vertical (its ``x`` near
``+-Z``, ``Z = |B| sin(dip)``, in two flips), where it reads as two per-flip offsets: what a field turning
with the turntable also adds, so the loop's next step took a platform field at delta-BIC 11 for a knee
(docs/benchmarks.md, "A response the cubic cannot follow").

The test: each channel's weighted residual against a general curve of its own ``x``, Legendre polynomials
of ``x / |B|`` of degrees 2..:data:`CURVE_DEGREE` times the channel's gain, their part the fit's parameters
can absorb projected off (the score test of :func:`calibrate.diagnosis.evidence.linear_score`).  Under
white noise at the floor each channel's chi-square drop follows chi-square with ``CURVE_DEGREE - 1``
degrees of freedom less the powers the fitted response has (those columns lie in the fit's own span, as do
degrees 0 and 1: the offset and the gain).  The channels' smallest p-value, times their number
(Bonferroni), is the test's.  A fit without a nonlinear response is tested as well: its columns include degree
3, the cubic itself, which the loop may have left unnamed (a cubic whose first harmonic at steep dip reads as a
gain; docs/benchmarks.md, "An unnamed cubic, asked the form test").  Spread over seven columns a channel the
cubic's chi-square is diluted, so a linear fit is also tested on the degree-3 columns alone, every judged
channel's jointly (one degree of freedom a channel: the vocabulary's odd cubic, whose BIC penalty of ``ln n`` a
channel can leave it unnamed where its chi-square is well beyond white noise); the smaller of the two p-values,
times two, is the test's (docs/benchmarks.md, "Four stacked, recording by recording").

Where the test rejects, :func:`response_misfit` sizes what the misfit did to the parameters: the same curves
fitted beside them, linearised at the fit, and the bias their determined components show propagated (the
unexplained fit's widening, beside the structure in time; docs/benchmarks.md, "A static misfit of the response
curve, covered").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.polynomial import legendre

from compass.sim.bench import channel_outputs, housing_field

from ..diagnosis.evidence import SINGULAR_RCOND, STRUCTURE_P, Check, Proposal, linear_score, unit_columns
from ..noise import chi2_sf
from ._jacobian import Partials
from ._mlfit import MLFit

__all__ = ["CURVE_DEGREE", "MAX_MOVE_SIGMAS", "RESPONSE", "ResponseForm", "ResponseMisfit", "curve_components",
           "response_form_check", "response_form_test", "response_misfit"]

CURVE_DEGREE = 8
"""Highest Legendre degree of the general curve (degrees 2..8: seven columns per channel)."""
RESPONSE = "nonlinear_response"
"""The effect whose form is tested."""
CUBIC_DEGREE = 3
"""The Legendre degree a linear response is also tested on alone (the vocabulary's odd cubic: ``x^3`` is
``P_3`` beside the gain's ``P_1``), every judged channel's column jointly."""


@dataclass(frozen=True)
class ResponseForm:
    """Outcome of :func:`response_form_test`.

    Attributes
    ----------
    delta_chi2 : ndarray, shape (c,)
        Each channel's first-order chi-square drop from a general curve of its field component.
    dof : int
        Degrees of freedom of each channel's drop under white noise.
    p_value : float
        The judged channels' smallest p-value times their number (at most 1; 1 when none is judged); for a linear
        response the smaller of that and the cubic's, times two.
    cubic_delta_chi2 : float or None
        A linear response's: the first-order chi-square drop of the degree-3 columns of every judged channel
        jointly; None for a fit with a curve.
    cubic_dof : int
        Degrees of freedom of ``cubic_delta_chi2`` under white noise: its columns, one a judged channel (0 without
        it).
    """

    delta_chi2: np.ndarray
    dof: int
    p_value: float
    cubic_delta_chi2: float | None = None
    cubic_dof: int = 0

    def p_value_over(self, mask: np.ndarray) -> float:
        """The test's p-value over the channels ``mask`` selects (1 when none is); a linear response's is the
        smaller of the general curves' and the cubic's (:data:`CUBIC_DEGREE`, ``cubic_delta_chi2`` on its own
        ``cubic_dof``, the channels its columns were taken from, whatever ``mask`` selects), times two."""
        p = [chi2_sf(d, self.dof) for d in self.delta_chi2[mask]]
        if not p:
            return 1.0
        curves = min(1.0, len(p) * min(p))
        if self.cubic_delta_chi2 is None:
            return curves
        return min(1.0, 2.0 * min(curves, chi2_sf(self.cubic_delta_chi2, self.cubic_dof)))

    def as_dict(self, channels) -> dict:
        """The diagnosis block's ``response_form_test``."""
        block = {"delta_chi2": {ch: float(v) for ch, v in zip(channels, self.delta_chi2)}, "dof": self.dof,
                 "p_value": self.p_value, "curve": f"Legendre degrees 2..{CURVE_DEGREE} of x / |B| per channel"}
        if self.cubic_delta_chi2 is not None:
            block |= {"cubic_delta_chi2": self.cubic_delta_chi2, "cubic_dof": self.cubic_dof}
        return block


def response_form_test(fit: MLFit, noise: np.ndarray, judged: np.ndarray | None = None) -> ResponseForm:
    """Test a fit's response (its ``nonlinear_response``, or linear without one) against a general curve of each
    channel's field component.

    Parameters
    ----------
    fit : MLFit
        The fit, with or without a ``nonlinear_response`` among its effects.
    noise : ndarray, shape (c,)
        Noise floor per channel, output units (the fit's weights).
    judged : ndarray of bool, shape (c,), optional
        The channels whose residual is judged (the p-value's); every channel by default.

    Returns
    -------
    ResponseForm
        Each channel's drop, with ``CURVE_DEGREE - 1`` degrees of freedom less the fitted response's powers.

    Notes
    -----
    Column ``k`` of channel ``c`` is ``K_c(t) P_k(x_c / |B|)``, the output's change when the channel's curve
    gains ``|B| P_k(x / |B|)`` (the weights as the fit's); :func:`calibrate.diagnosis.evidence.linear_score`
    projects the fit's Jacobian off it and returns ``r^T J~ (J~^T J~)^+ J~^T r``.
    """
    r0, j_b, blocks = _curve_columns(fit, noise)
    normal_b = j_b.T @ j_b
    c, q = blocks.shape[0], blocks.shape[-1]
    x = np.concatenate([fit.x, np.zeros(q)])
    drops = np.empty(c)
    for ch in range(c):
        drops[ch], _ = linear_score(None, x, fit.x.size, j_b, block_jacobian=blocks[ch], r0=r0, normal_b=normal_b)
    powers = _response_powers(fit)
    dof = q - sum(1 for k in powers if 2 <= k <= CURVE_DEGREE)
    chosen = np.ones(c, dtype=bool) if judged is None else np.asarray(judged, dtype=bool)
    cubic, cubic_dof = None, 0
    if not powers and chosen.any():  # the vocabulary's cubic, one column a judged channel, jointly
        columns = np.stack([blocks[ch][:, CUBIC_DEGREE - 2] for ch in np.flatnonzero(chosen)], axis=1)
        x3 = np.concatenate([fit.x, np.zeros(columns.shape[1])])
        cubic, _ = linear_score(None, x3, fit.x.size, j_b, block_jacobian=columns, r0=r0, normal_b=normal_b)
        cubic_dof = columns.shape[1]
    test = ResponseForm(drops, dof, 1.0, cubic, cubic_dof)
    return replace(test, p_value=test.p_value_over(chosen))


def _response_powers(fit: MLFit) -> tuple[int, ...]:
    """The powers of the fit's nonlinear response (none for a linear one)."""
    return next((tuple(e.powers) for e in fit.effects if e.name == RESPONSE), ())


MAX_MOVE_SIGMAS = 3.0
"""A curve component whose noise alone moves some parameter by more than this many of its sigmas is not determined
by the recording (:func:`response_misfit`): its bias is not estimated."""


@dataclass(frozen=True)
class ResponseMisfit:
    """The fit's parameters' bias from a static misfit of the response curve (:func:`response_misfit`).

    Attributes
    ----------
    bias_covariance : ndarray, shape (p, p)
        The squared bias the curve's determined components put in the parameters, each estimated without its
        noise's part, in the fit's parameters (as ``fit.covariance``).
    delta_chi2 : float
        The chi-square the judged channels' general curves take jointly, the fit's own columns projected off.
    taken : tuple of int
        How many of the curves' components put a bias in (determined, and ``z^2 > 1``), and how many are not
        degenerate (the fit's own columns leave them to the curves).
    """

    bias_covariance: np.ndarray
    delta_chi2: float
    taken: tuple[int, int]

    def cover(self, covariance: np.ndarray) -> np.ndarray:
        """The cover of the stated parameters' error for the fit's covariance ``C``: ``C`` plus the squared bias."""
        return covariance + self.bias_covariance


def response_misfit(fit: MLFit, noise: np.ndarray, judged: np.ndarray | None = None) -> ResponseMisfit:
    """What a static misfit of the response curve did to the fit's parameters.

    The judged channels' general curves (:func:`response_form_test`'s columns ``L``) enter beside the fit's
    Jacobian ``J`` as nuisance parameters, linearised at the fit.  With ``J^T W r = 0`` at the fit the augmented
    least squares moves the parameters by ``-A c``, ``A = (J^T W J)^-1 J^T W L`` (what ``J`` absorbs of each
    curve column) and ``c = -(L~^T W L~)^+ L~^T W r`` the curves' coefficients on the residual, ``L~ = L - J A``:
    the stated parameters, the fit's, are off by ``delta = A c`` (the bias) plus the augmented fit's error.

    In the eigenbasis of ``L~^T W L~`` (unit columns) each component ``k`` has a signed root chi-square ``z_k``
    (unit variance under white noise, independent of the fit's own noise as ``J^T W L~ = 0``) and moves the
    parameters by ``m_k`` per unit ``z``.  ``z_k^2 - 1`` is the unbiased estimate of its squared bias in
    ``z``'s units (``delta delta^T`` would count the noise ``m_k m_k^T`` once more), so the bias taken is
    ``sum_k max(z_k^2 - 1, 0) m_k m_k^T`` (the components taken as independent in sign: the expected squared bias,
    not a bound on it).  A component whose ``m_k`` is over :data:`MAX_MOVE_SIGMAS` of some parameter's sigma (at
    the noise floor, as ``z``'s: the covariance without its chi-square scale) is not determined (a channel that
    sees only the horizontal field has its degrees 2-8 on ``|x| < H``, where they mimic the offset, gain and
    cubic): its ``z`` is noise many times any bias it could show, and it is left out; a degenerate one (a degree
    the response's own powers hold) carries no information and is dropped as
    :func:`calibrate.diagnosis.evidence.linear_score` drops it.

    Parameters
    ----------
    fit : MLFit
        The fit, with or without a nonlinear response.
    noise : ndarray, shape (c,)
        Noise floor per channel, output units (the fit's weights).
    judged : ndarray of bool, shape (c,), optional
        The channels whose curve is taken (an undithered ADC's rounding is a curve of its field by itself);
        every channel by default.

    Returns
    -------
    ResponseMisfit
        The squared bias in the fit's parameters, the curves' chi-square, and the components counted.
    """
    z, moves, taken = curve_components(fit, noise, judged)
    weight = np.where(taken, np.maximum(z**2 - 1.0, 0.0), 0.0)
    return ResponseMisfit(bias_covariance=(moves * weight) @ moves.T, delta_chi2=float(z @ z),
                          taken=(int(np.count_nonzero(weight)), int(z.size)))


def curve_components(fit: MLFit, noise: np.ndarray,
                     judged: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The general curves' components beside the fit (:func:`response_misfit`'s model): each one's signed root
    chi-square, its move of the parameters per unit of it, and whether it is determined.

    Linearised at the fit, the least squares of ``[J L]`` on the residual moves the fit's parameters by
    ``-sum_k m_k z_k`` and has the parameters' covariance ``(J^T W J)^-1 + sum_k m_k m_k^T``
    at the noise floor (tests/calibrate/fourflip/test_form.py holds both to the augmented fit).

    Parameters
    ----------
    fit, noise, judged
        As :func:`response_misfit`.

    Returns
    -------
    z : ndarray, shape (k,)
        Each non-degenerate component's signed root chi-square (unit variance under white noise).
    moves : ndarray, shape (p, k)
        ``m_k``, the parameters' move per unit ``z_k``, in the fit's parameters.
    taken : ndarray of bool, shape (k,)
        The components within :data:`MAX_MOVE_SIGMAS` of every parameter's noise-floor sigma per unit ``z``.
    """
    r0, j_b, blocks = _curve_columns(fit, noise)
    chosen = np.ones(blocks.shape[0], dtype=bool) if judged is None else np.asarray(judged, dtype=bool)
    curve = np.concatenate([blocks[ch] for ch in np.flatnonzero(chosen)], axis=1)
    scale = np.linalg.norm(np.nan_to_num(fit.jac), axis=0)
    scale[scale == 0] = 1.0
    absorbed, *_ = np.linalg.lstsq(j_b.T @ j_b, j_b.T @ curve, rcond=SINGULAR_RCOND**2)  # A, J's unit columns
    norm = np.linalg.norm(curve, axis=0)  # the columns' own norm: one J absorbs whole is left near zero and dropped
    norm[norm == 0] = 1.0
    tilde = (curve - j_b @ absorbed) / norm
    w, v = np.linalg.eigh(tilde.T @ tilde)
    determined = w > SINGULAR_RCOND**2 * max(w.max(), 1e-300)
    w, v = w[determined], v[:, determined]
    z = (v.T @ (tilde.T @ r0)) / np.sqrt(w)  # each component's signed root chi-square
    moves = (absorbed / norm) @ v / np.sqrt(w) / scale[:, None]  # (p, k): the parameters' move per unit z
    sigma = np.sqrt(np.diag(fit.covariance) / (fit.chi2 / max(fit.dof, 1)))  # the noise floor's, as z's
    finite = np.isfinite(sigma) & (sigma > 0)
    return z, moves, np.all(np.abs(moves[finite]) <= MAX_MOVE_SIGMAS * sigma[finite, None], axis=0)


def _curve_columns(fit: MLFit, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fit's weighted residual, its Jacobian with unit columns and each channel's general-curve columns.

    Returns
    -------
    r0 : ndarray, shape (n,)
        The weighted residual (data - model over the noise floor, each bin's count in), ``n`` bins times channels.
    j_b : ndarray, shape (n, p)
        ``fit.jac`` with every non-zero column scaled to unit norm (undetermined entries 0).
    blocks : ndarray, shape (c, n, CURVE_DEGREE - 1)
        Channel ``ch``'s columns ``-K_ch(t) P_k(x_ch / |B|)`` times the weights on its own rows (zero elsewhere):
        the residual's derivative by the coefficient of ``|B| P_k(x / |B|)`` added to its curve.
    """
    bins, phys = fit.bins, fit.physics
    weights = np.broadcast_to(bins.root_n / noise, bins.outputs.shape)
    b_h = housing_field(phys, bins.samples)
    r0 = ((bins.outputs - channel_outputs(phys, bins.samples, b_h @ phys.directions.T)) * weights).ravel()
    parts = Partials(phys, bins.samples, b_h)
    curve = legendre.legvander(parts.x / phys.field_norm, CURVE_DEGREE)[..., 2:]  # (g, c, CURVE_DEGREE - 1)
    c, q = phys.gains.size, curve.shape[-1]
    blocks = np.zeros((c,) + bins.outputs.shape + (q,))
    for ch in range(c):
        blocks[ch, :, ch, :] = -(parts.gain_t[:, ch, None] * curve[:, ch, :]) * weights[:, ch, None]
    return r0, unit_columns(np.nan_to_num(fit.jac)), blocks.reshape(c, r0.size, q)


def response_form_check(noise: np.ndarray, judged: np.ndarray | None = None) -> Check:
    """A veto (:data:`calibrate.diagnosis.evidence.Check`) of an effect proposed after a response the test rejects.

    Where the model already has a nonlinear response, :func:`response_form_test` rejects its form
    (p below :data:`calibrate.diagnosis.evidence.STRUCTURE_P`), and the proposed effect buys less chi-square
    than the general curve would (the sum of the channels' drops), the effect may be taking the curve's
    misfit (a knee's read as per-flip offsets by a platform field): it is not claimed, and the loop stops
    with the response as it is, whose verdict the same test makes unexplained.

    Parameters
    ----------
    noise : ndarray, shape (c,)
        Noise floor per channel, output units.
    judged : ndarray of bool, shape (c,), optional
        The channels whose residual is judged (:func:`response_form_test`).
    """

    def check(p: Proposal):
        if not _response_powers(p.current):  # a linear response's misfit is what the proposed cubic may take
            return None, {}
        form = response_form_test(p.current, noise, judged)
        if form.p_value >= STRUCTURE_P:
            return None, {}
        drop, curve = p.current.chi2 - p.trial.chi2, float(np.sum(form.delta_chi2))
        if drop >= curve:
            return None, {}
        return (f"the fitted response's curve is not the vocabulary's form (a general curve of each channel's field "
                f"would take chi2 {curve:.0f}, response form test p = {form.p_value:.2g}) and this effect takes less "
                f"(chi2 {drop:.0f}): it may be taking the curve's misfit"), {}

    return check
