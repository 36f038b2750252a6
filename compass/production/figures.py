"""The figures a production line judges a calibrated module by, from its sensor model and diagnosis.

Every figure is one number per module (the worst channel's where channels differ), named with its
unit, or None when the calibration kind does not give it (a tumble gives no direction covariance).
:data:`FIGURES` lists them; :mod:`compass.production.spec` holds the limits.

The heading budget propagates the calibration's parameter covariance (directions, offsets, gains)
to the heading of a level module at a site, over every heading:

.. math::

    \\hat b = P\\,\\hat c,\\quad \\hat c_i = (x_i - o_i)/g_i,\\qquad
    \\delta h = u^\\top \\delta b,\\quad u = (-b_y, b_x, 0) / (b_x^2 + b_y^2)

with :math:`P` the model's solver (``B_H = P c``).  A direction error :math:`\\delta a_i` moves the
field by :math:`-P_{:,i}\\,(\\delta a_i \\cdot b)`; an offset error by :math:`-P_{:,i}\\,\\delta o_i/g_i`;
a gain error by :math:`-P_{:,i}\\,c_i\\,\\delta g_i/g_i`.  The variance of :math:`\\delta h` summed over
channels is the parameters' share of the heading error; its RMS over headings is the figure.
Sensor noise is not in it (a runtime filter averages it; its share is the SNR figure's).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

__all__ = ["FIGURES", "WARNING_CLASSES", "Figure", "classify_warning", "heading_error_deg", "module_figures"]


@dataclass(frozen=True)
class Figure:
    """One judged figure: its unit and what it says, for the spec's docs and the report."""

    name: str
    unit: str
    meaning: str


FIGURES = {f.name: f for f in (
    Figure("direction_sigma_deg", "deg", "largest sensing-direction uncertainty of the module's channels"),
    Figure("non_orthogonality_deg", "deg", "largest departure from 90 deg between two channels' directions"),
    Figure("axis_misalignment_deg", "deg", "largest angle of a channel from its nearest housing axis"),
    Figure("gain_spread", "fraction", "(largest - smallest) / median of the channels' gains"),
    Figure("offset_ut", "uT", "largest zero-field output of a channel, in field units (uT when |B| is known)"),
    Figure("fit_error_pct", "%", "residual RMS after the diagnosis over the field's response (median gain x |B|)"),
    Figure("residual_over_floor", "ratio", "residual RMS after the diagnosis over the noise floor"),
    Figure("snr_min", "ratio", "smallest channel signal-to-noise: gain x |B| over the channel's noise floor"),
    Figure("snr_ratio_min", "ratio", "smallest channel SNR over the module's median channel SNR"),
    Figure("heading_error_deg", "deg", "RMS over headings of the heading error the calibration's parameter "
                                       "sigmas give a level module at the spec's site"),
    Figure("bench_dip_deg", "deg", "the dip the bench measured (one bench, one field: a drift is the bench's)"),
)}
"""Name -> :class:`Figure`, in report order."""

WARNING_CLASSES = {
    "channel": r"^channel \S+: |dead|signal-to-noise|\bSNR\b|housing axis",
    "not_converged": r"did not converge",
    "undetermined": r"singular covariance|poorly determined|not determined|cannot separate|no uncertainty",
    "coverage": r"coverage|part of the sphere|never (horizontal|vertical)",
    "saturation": r"saturat|beyond .*range|extrapolat",
    "outliers": r"rejected as|spike",
    "coplanar": r"coplanar",
    "no_repeats": r"recorded twice|no repeated",
    "unexplained": r"unexplained|structure (remains|above)",
    "accelerometer": r"accelerometer",
}
"""Warning class -> regular expression on the warning's words (first match wins; else ``other``).

Calibrations warn in words; a production spec names classes (``[warnings] fail_on``).  ``channel``
takes the per-channel warnings of :mod:`calibrate.health` (issue 27: a drowned channel, a direction
short of the accuracy asked, one far off its housing axis), which all start ``channel NAME:``."""

_PATTERNS = [(name, re.compile(rx, re.IGNORECASE)) for name, rx in WARNING_CLASSES.items()]


def classify_warning(text: str) -> str:
    """The class of a calibration warning (:data:`WARNING_CLASSES`), ``other`` when none matches."""
    return next((name for name, rx in _PATTERNS if rx.search(text)), "other")


def _non_orthogonality_deg(directions: np.ndarray) -> float:
    cosines = np.clip(directions @ directions.T, -1.0, 1.0)
    i, j = np.triu_indices(len(directions), 1)
    return float(np.max(np.abs(90.0 - np.degrees(np.arccos(cosines[i, j])))))


def _axis_misalignment_deg(directions: np.ndarray) -> float:
    nearest = np.max(np.abs(directions), axis=1)  # cosine to the nearest of +-X, +-Y, +-Z
    return float(np.max(np.degrees(np.arccos(np.clip(nearest, -1.0, 1.0)))))


def heading_error_deg(model, dip_deg: float, field: float, headings_deg=np.arange(0.0, 360.0, 10.0)) -> float | None:
    """RMS over headings of the heading sigma the calibration's parameter covariance gives, degrees.

    Parameters
    ----------
    model : compass.model.SensorModel
    dip_deg : float
        The site's dip (> 0 pointing down), degrees.
    field : float
        The site's |B| in the model's field units.
    headings_deg : array_like
        Headings of the level module to average over.

    Returns
    -------
    float or None
        None when the model carries no parameter uncertainty at all.
    """
    cov = model.direction_covariance
    resp = model.response_sigma
    if cov is None and resp is None:
        return None
    a, gains, solver = model.unit_directions, model.gains, model.solver
    psi = np.radians(np.asarray(headings_deg, float))
    dip = np.radians(dip_deg)
    # field in H of a level module (FLU) whose +X points at heading psi (clockwise from north)
    b = field * np.column_stack([np.cos(dip) * np.cos(psi), np.cos(dip) * np.sin(psi),
                                 np.full_like(psi, -np.sin(dip))])
    horizontal2 = b[:, 0] ** 2 + b[:, 1] ** 2
    u = np.column_stack([-b[:, 1], b[:, 0], np.zeros_like(psi)]) / horizontal2[:, None]  # dh/db, rad per field unit
    sens = u @ solver  # (headings, channels): dh / dc_i
    c = b @ a.T  # field components along each channel
    var = np.zeros(sens.shape)
    if cov is not None:
        var += sens**2 * np.einsum("hk,ckl,hl->hc", b, np.asarray(cov, float), b)
    if resp is not None:
        resp = np.asarray(resp, float)
        var += sens**2 * ((resp[:, 0] / gains) ** 2 + (c * resp[:, 1] / gains) ** 2)
    return float(np.degrees(np.sqrt(np.mean(var.sum(axis=1)))))


def module_figures(model, diagnosis: dict | None, warnings, *, site_dip_deg: float, site_field_ut: float,
                   bench_field_ut: float | None = None) -> dict:
    """Every figure of :data:`FIGURES` for one calibrated module.

    Parameters
    ----------
    model : compass.model.SensorModel
        The calibrated sensor (any kind, in its channel form).
    diagnosis : dict or None
        The calibration file's ``diagnosis`` block (SPEC section 4), None when not run.
    warnings : sequence of str
        The calibration's warnings, in words.
    site_dip_deg, site_field_ut : float
        Where the heading budget is predicted (the spec's ``[site]``).
    bench_field_ut : float or None
        The bench's |B| in uT when the model does not carry it (``model.field_ut`` None: its gains are
        per bench |B|): from the recording's site or the spec (:func:`calibrate.batch.bench_field_ut`).
        With neither, ``offset_ut`` cannot be put in uT and is left unjudged, said in ``unjudged``.

    Returns
    -------
    dict
        Figure name -> float or None; ``unexplained`` -> bool or None; ``warning_classes`` -> sorted
        list of the warnings' classes; ``unjudged`` -> figure name -> why it could not be computed
        for this module (a figure the kind never gives has no entry).
    """
    a = model.unit_directions
    gains = model.gains
    field = model.field_norm
    out: dict = dict.fromkeys(FIGURES)
    if model.direction_covariance is not None:
        from ..frames import direction_sigma_deg

        out["direction_sigma_deg"] = float(np.max(direction_sigma_deg(np.asarray(model.direction_covariance))))
    out["non_orthogonality_deg"] = _non_orthogonality_deg(a)
    out["axis_misalignment_deg"] = _axis_misalignment_deg(a)
    median_gain = float(np.median(np.abs(gains)))
    out["gain_spread"] = float((np.max(gains) - np.min(gains)) / median_gain) if median_gain > 0 else None
    field_ut = model.field_ut if model.field_ut is not None else bench_field_ut
    out["unjudged"] = {}
    if field_ut is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            zero_ut = np.abs(model.zero_outputs / gains) * (field_ut / field)  # offset in |B|, times |B| in uT
        out["offset_ut"] = float(np.max(zero_ut)) if np.all(np.isfinite(zero_ut)) else None
    else:
        out["unjudged"]["offset_ut"] = ("the bench's |B| in uT is unknown (the recording has no '# field_ut:' nor "
                                        "site keys, the spec no [site] bench_field_ut): the offset is "
                                        f"{float(np.max(np.abs(model.zero_outputs / gains)) / field):.3g} bench |B|")
    if model.noise is not None and np.all(np.asarray(model.noise) > 0):
        snr = np.abs(gains) * field / np.asarray(model.noise, float)
        out["snr_min"] = float(np.min(snr))
        out["snr_ratio_min"] = float(np.min(snr) / np.median(snr))
    if diagnosis is not None:
        floor, after = diagnosis.get("noise_floor"), diagnosis.get("residual_rms_after")
        if floor and after is not None:
            out["residual_over_floor"] = float(after / floor)
        if after is not None and median_gain > 0:
            out["fit_error_pct"] = float(100.0 * after / (median_gain * field))
    site_field = site_field_ut * field / field_ut if field_ut is not None else field
    out["heading_error_deg"] = heading_error_deg(model, site_dip_deg, site_field)
    out["bench_dip_deg"] = None if model.dip_deg is None else float(model.dip_deg)
    unexplained = None if diagnosis is None else diagnosis.get("unexplained")
    out["unexplained"] = None if unexplained is None else bool(unexplained)
    out["warning_classes"] = sorted({classify_warning(w) for w in warnings})
    return out
