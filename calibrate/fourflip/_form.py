"""Is the response curve the vocabulary's form?  A lack-of-fit test of a fitted nonlinear response.

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
(Bonferroni), is the test's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.polynomial import legendre

from compass.sim.bench import channel_outputs, housing_field

from ..diagnosis.evidence import STRUCTURE_P, Check, Proposal, linear_score, unit_columns
from ..noise import chi2_sf
from ._jacobian import Partials
from ._mlfit import MLFit

__all__ = ["CURVE_DEGREE", "RESPONSE", "ResponseForm", "response_form_check", "response_form_test"]

CURVE_DEGREE = 8
"""Highest Legendre degree of the general curve (degrees 2..8: seven columns per channel)."""
RESPONSE = "nonlinear_response"
"""The effect whose form is tested."""


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
        The judged channels' smallest p-value times their number (at most 1; 1 when none is judged).
    """

    delta_chi2: np.ndarray
    dof: int
    p_value: float

    def p_value_over(self, mask: np.ndarray) -> float:
        """The test's p-value over the channels ``mask`` selects (1 when none is)."""
        p = [chi2_sf(d, self.dof) for d in self.delta_chi2[mask]]
        return min(1.0, len(p) * min(p)) if p else 1.0

    def as_dict(self, channels) -> dict:
        """The diagnosis block's ``response_form_test``."""
        return {"delta_chi2": {ch: float(v) for ch, v in zip(channels, self.delta_chi2)}, "dof": self.dof,
                "p_value": self.p_value, "curve": f"Legendre degrees 2..{CURVE_DEGREE} of x / |B| per channel"}


def response_form_test(fit: MLFit, noise: np.ndarray, judged: np.ndarray | None = None) -> ResponseForm | None:
    """Test a fit's nonlinear response against a general curve of each channel's field component.

    Parameters
    ----------
    fit : MLFit
        A fit with a ``nonlinear_response`` among its effects.
    noise : ndarray, shape (c,)
        Noise floor per channel, output units (the fit's weights).
    judged : ndarray of bool, shape (c,), optional
        The channels whose residual is judged (the p-value's); every channel by default.

    Returns
    -------
    ResponseForm or None
        None when the fit has no nonlinear response (nothing to test).

    Notes
    -----
    Column ``k`` of channel ``c`` is ``K_c(t) P_k(x_c / |B|)``, the output's change when the channel's curve
    gains ``|B| P_k(x / |B|)`` (the weights as the fit's); :func:`calibrate.diagnosis.evidence.linear_score`
    projects the fit's Jacobian off it and returns ``r^T J~ (J~^T J~)^+ J~^T r``.
    """
    response = next((e for e in fit.effects if e.name == RESPONSE), None)
    if response is None:
        return None
    bins, phys = fit.bins, fit.physics
    weights = np.broadcast_to(bins.root_n / noise, bins.outputs.shape)
    b_h = housing_field(phys, bins.samples)
    r0 = ((bins.outputs - channel_outputs(phys, bins.samples, b_h @ phys.directions.T)) * weights).ravel()
    parts = Partials(phys, bins.samples, b_h)
    curve = legendre.legvander(parts.x / phys.field_norm, CURVE_DEGREE)[..., 2:]  # (g, c, CURVE_DEGREE - 1)
    j_b = unit_columns(np.nan_to_num(fit.jac))
    normal_b = j_b.T @ j_b
    c, q = phys.gains.size, curve.shape[-1]
    x = np.concatenate([fit.x, np.zeros(q)])
    drops = np.empty(c)
    for ch in range(c):
        block = np.zeros(bins.outputs.shape + (q,))
        block[:, ch, :] = -(parts.gain_t[:, ch, None] * curve[:, ch, :]) * weights[:, ch, None]
        drops[ch], _ = linear_score(None, x, fit.x.size, j_b, block_jacobian=block.reshape(-1, q), r0=r0,
                                    normal_b=normal_b)
    dof = q - sum(1 for k in response.powers if 2 <= k <= CURVE_DEGREE)
    test = ResponseForm(drops, dof, 1.0)
    return replace(test, p_value=test.p_value_over(np.ones(c, dtype=bool) if judged is None else judged))


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
        form = response_form_test(p.current, noise, judged)
        if form is None or form.p_value >= STRUCTURE_P:
            return None, {}
        drop, curve = p.current.chi2 - p.trial.chi2, float(np.sum(form.delta_chi2))
        if drop >= curve:
            return None, {}
        return (f"the fitted response's curve is not the vocabulary's form (a general curve of each channel's field "
                f"would take chi2 {curve:.0f}, response form test p = {form.p_value:.2g}) and this effect takes less "
                f"(chi2 {drop:.0f}): it may be taking the curve's misfit"), {}

    return check
