"""What the four-flip bench cannot see of a field fixed to the turntable, stated as a prior.

A field ``b_p`` fixed to the turntable (:class:`calibrate.fourflip.effects.PlatformField`) is seen by
channel ``a`` in flip ``kappa`` as ``(Rx(kappa) a) . b_p``.  Its y part turns with the flips and is
fitted.  Its x part (along the flip axis) adds ``a_x b_x`` in every flip and angle, exactly as the
channel's zero-field offset does: the offsets absorb it, and at runtime, with the platform gone, each
offset (field units) is wrong by ``a_x b_x``, a heading error.  Its z part adds to the Earth's vertical
field at every angle and flip: the dip and a common scale of the gains absorb it.  Reading the two as
zero with no sigma states the offsets, gains and dip too precisely.

The prior: a magnetised part's field has no preferred direction, so each of ``b_x`` and ``b_z`` is taken
as zero-mean with the variance ``p_y^2 + s_y^2`` (the fitted y part ``p_y``, its sigma ``s_y``: the
expected square of ``b_y``).  That is one draw's estimate of the per-axis variance (a chi-square of one
degree of freedom: half the time it is below 0.45 times the truth, so a single recording's stated sigma
can under-cover by 1.5x or more, and over-cover as often); ``s_y^2`` is its floor when ``p_y`` is near
zero by chance, since a field whose y part the bench cannot tell from zero could have x and z parts
as large.  No larger floor: the effect is in the fit because the y part was decisive.

The parameters' move per unit ``b_x`` and ``b_z`` is the weighted least-squares projection of the
outputs' change onto the fit's Jacobian (what a refit with the component set would move, to first
order): for ``b_x`` it is ``a_x`` on each offset and nothing else (the reference relation).  Its outer
product times the prior variance is added to the fit's covariance.
"""

from __future__ import annotations

import numpy as np

from ._jacobian import Partials
from ._mlfit import MLFit, with_covariance
from .effects import PlatformField

__all__ = ["platform_prior", "unseen_platform_sensitivity"]


def unseen_platform_sensitivity(fit: MLFit, noise: np.ndarray) -> np.ndarray:
    """The fit's parameters' move per unit of the platform field's x and z parts (turntable frame, in the
    y parameter's units: field units over ``field_norm``), shape (n_params, 2).

    The outputs' change at the fit's bins, weighted as the fit is, projected on the fit's Jacobian by
    least squares (``fit.jac``: the weighted residual's, hence the sign).
    """
    bins = fit.bins
    parts = Partials(fit.physics, bins.samples)
    unit = fit.physics.field_norm * np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    d_b_h = np.stack([parts.turntable_to_housing(v) for v in unit], axis=-1)  # (n, 3, 2)
    d_out = parts.through_field(d_b_h)  # (n, c, 2)
    weights = np.broadcast_to(bins.root_n / noise, d_out.shape[:2])
    d_res = (-d_out * weights[..., None]).reshape(-1, 2)
    return np.linalg.lstsq(fit.jac, d_res, rcond=None)[0]


def platform_prior(fit: MLFit, noise: np.ndarray) -> tuple[MLFit, dict | None]:
    """The fit with the platform field's unseen x and z parts carried into its covariance, and what they are.

    Returns the fit unchanged and None when the platform field is not among its effects.  When the fitted y
    part's variance ``p_y^2 + s_y^2`` is not finite (the fit could not determine the y part) no prior can be
    stated: the fit comes back unchanged with ``prior_sigma_fieldunit`` None, for the caller to say so (the
    file's sigmas then leave the unseen parts out).

    Returns
    -------
    fit : MLFit
        Its covariance plus ``G diag(var, var) G^T`` (:func:`unseen_platform_sensitivity`).
    unseen : dict or None
        ``prior_sigma_fieldunit`` (each of x and z; None: not stated), ``fitted_y_fieldunit`` (None when not
        finite) and the added covariance (``added_covariance``, fit units; absent when not stated) for the
        caller to state the cost.
    """
    effect = next((e for e in fit.effects if isinstance(e, PlatformField)), None)
    if effect is None:
        return fit, None
    i = fit.block_start(effect)
    var = float(fit.x[i] ** 2 + fit.covariance[i, i])  # fit units (field_norm)
    scale = float(effect.report_scale(fit.physics))
    if not np.isfinite(var):
        y = float(fit.x[i] * scale)
        return fit, {"fitted_y_fieldunit": y if np.isfinite(y) else None, "prior_sigma_fieldunit": None}
    g = unseen_platform_sensitivity(fit, noise)
    added = var * (g @ g.T)
    return with_covariance(fit, fit.covariance + added), {
        "fitted_y_fieldunit": float(fit.x[i] * scale),
        "prior_sigma_fieldunit": float(np.sqrt(var) * scale),
        "added_covariance": added,
    }
