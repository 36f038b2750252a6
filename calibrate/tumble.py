"""Free-motion (tumble) calibration: hard and soft iron by ellipsoid fitting, coverage, misalignment.

The magnetometer, turned through many orientations in a constant field, reads points on an
ellipsoid.  The calibration maps them back onto a sphere,

.. math:: m_i = S (x_i - h), \\qquad |m_i| = F,

with ``h`` the hard-iron offset (recording units), ``S`` a symmetric positive-definite soft-iron
correction and ``F`` the field norm (SPEC section 2, ``"model": "tumble"``).  Three kinds of ``S``:

``offset``
    ``S = I`` (a sphere: hard iron only), 4 parameters.
``diagonal``
    ``S`` diagonal (per-axis gains), 6 parameters.
``full``
    ``S`` symmetric (gains and cross-axis coupling), 9 parameters.

``S`` is parameterised through the Cholesky factor ``L`` of ``S^2 / F^2 = L L^T`` with a
logarithmic diagonal, so every fit is a real ellipsoid (positive-definite ``S``, positive
determinant); ``S`` is the symmetric square root.  Without a known field, ``det S = 1`` and ``F``
is the geometric-mean radius in recording units.  The loss is the geometric residual
``r_i = F (|L^T (x_i - h)| - 1)`` (recording units), minimised by ``scipy.optimize.least_squares``
with a robust ``soft_l1`` loss; samples beyond ``OUTLIER_SIGMAS`` robust sigmas are then dropped and
the fit repeated with a plain quadratic loss, which gives the standard errors, the chi-square and
the BIC (``n ln(RSS/n) + k ln n`` on a common set of samples) that choose the kind.

A kind is *determined* when its standard errors are below ``MAX_RELATIVE_SIGMA`` of the field and,
for ``diagonal`` and ``full``, when the field was seen along each of the magnetometer's six
half-axes (otherwise the ellipsoid is extrapolated from one side).  The automatic choice takes the
determined kind with the lowest BIC and says in words which orientations are missing.

With an accelerometer, the rotation between magnetometer and accelerometer frames follows from the
constancy of the dip: on quasi-static samples (``||a| / g - 1| < STATIC_TOLERANCE``) the angle
between gravity and the field is ``90 deg + dip``.  The rotation ``C`` (``mag_to_accel``) and the dip
minimise the robust sum of squared angle residuals,

.. math:: e_i = \\arccos(\\hat a_i \\cdot C \\hat m_i) - (90^\\circ + \\delta),

and are kept when the BIC prefers them to the dip alone.  The rotation about the mean field-gravity
plane is weakly determined when the device turned little; its sigma says so.

References: seed 003 (ellipsoid fitting for scale factors); the dip-constancy alignment follows
e.g. Vasconcelos et al., "Geometric approach to strapdown magnetometer calibration in sensor
frame", IEEE TAES 47(2), 2011, and Li et al. (magnetometer-accelerometer alignment).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import sqrtm
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from compass.calibration_file import header
from compass.io.tumble import TumbleRecording

from .contract import Calibration, Calibrator, CannotCalibrate, metadata_field_ut
from .noise import robust_sigma

if TYPE_CHECKING:
    from .tumble_diagnose import TumbleDiagnosis

__all__ = ["KINDS", "Coverage", "KindFit", "Misalignment", "TumbleCalibrator", "TumbleResult", "sphere_coverage", "fit_ellipsoid",
           "fit_misalignment", "refine_jointly", "calibrate_tumble", "field_gravity_angles", "static_mask"]

KINDS = ("offset", "diagonal", "full")
_N_PARAMS = {"offset": 4, "diagonal": 6, "full": 9}
OUTLIER_SIGMAS = 4.0
"""Samples farther than this many robust sigmas from the fitted ellipsoid are dropped."""
MAX_RELATIVE_SIGMA = 0.01
"""A kind is determined when every standard error (offset / field, soft-iron element) is below this."""
MAX_RADIUS_RATIO = 3.0
"""A fit whose field norm exceeds this many times the samples' extent (95th percentile of their
distance from their median) is degenerate: a huge sphere through a nearly flat patch of samples,
as when the field changed partway (a magnet attached to the device)."""
FACE_COVERAGE_DEG = 45.0
"""A half-axis counts as seen when some sample's field direction lies within this angle of it."""
STATIC_TOLERANCE = 0.02
"""Quasi-static samples: | |a| / g - 1 | below this (g = median |a|)."""
MAX_ANGLE_WIDENING = 0.05
"""A correction that widens the field-gravity angle spread by more than this fraction is not used."""
_N_CELLS = 200
_MAX_NFEV = 400
_FACES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")


@dataclass(frozen=True)
class Coverage:
    """How much of the sphere of field directions the samples cover (magnetometer frame).

    Attributes
    ----------
    fraction : float
        Fraction of ``_N_CELLS`` equal-area cells (nearest Fibonacci-sphere centre) holding a sample.
    faces_seen : dict of str to bool
        Whether the field came within ``FACE_COVERAGE_DEG`` of each half-axis ``+X .. -Z``.
    """

    fraction: float
    faces_seen: dict

    @property
    def missing(self) -> list[str]:
        return [f for f, seen in self.faces_seen.items() if not seen]

    def words(self) -> str:
        """What is missing, for a person holding the device."""
        if not self.missing:
            return f"the field was seen from every side ({100 * self.fraction:.0f} % of the sphere covered)"
        axes = ", ".join(self.missing)
        return (f"the field never pointed along the magnetometer's {axes} "
                f"{'axes' if len(self.missing) > 1 else 'axis'} (only {100 * self.fraction:.0f} % of the sphere covered): "
                f"turn the device so that each of these axes points along the field in turn (north and, "
                f"in the northern hemisphere, steeply down) - usually by turning it over")


@dataclass(frozen=True)
class KindFit:
    """One ellipsoid kind fitted to the samples.

    Attributes
    ----------
    kind : str
    hard_iron, hard_iron_sigma : ndarray, shape (3,)
        Offset ``h`` and its standard error, recording units.
    soft_iron, soft_iron_sigma : ndarray, shape (3, 3)
        ``S`` normalised to ``det S = 1`` and its element-wise standard error.
    field_norm, field_norm_sigma : float
        Geometric-mean radius ``F``, recording units.
    residuals : ndarray, shape (n,)
        ``|S (x - h)| - F`` of every sample (outliers included), recording units.
    inliers : ndarray of bool, shape (n,)
    rss : float
        Sum of squared residuals over ``inliers``.
    bic : float
        On the common sample set of the comparison (NaN if not compared).
    determined : bool
    reason : str
        Why the kind is not determined (empty if it is).
    success : bool
    message : str
    params : ndarray
        Fit parameters in normalised units: ``(h - centre) / radius``, then the shape of ``L``.
    centre, radius : ndarray (3,), float
        The normalisation (algebraic sphere fit), recording units.
    degenerate : bool
        The field norm exceeds ``MAX_RADIUS_RATIO`` times the samples' extent (see ``reason``).
    """

    kind: str
    hard_iron: np.ndarray
    hard_iron_sigma: np.ndarray
    soft_iron: np.ndarray
    soft_iron_sigma: np.ndarray
    field_norm: float
    field_norm_sigma: float
    residuals: np.ndarray
    inliers: np.ndarray
    rss: float
    bic: float
    determined: bool
    reason: str
    success: bool
    message: str
    params: np.ndarray
    centre: np.ndarray
    radius: float
    degenerate: bool = False

    @property
    def n_params(self) -> int:
        return _N_PARAMS[self.kind]

    def calibrated(self, mag: np.ndarray) -> np.ndarray:
        """``S (x - h)``, shape (n, 3), recording units (det S = 1)."""
        return (np.asarray(mag, dtype=float) - self.hard_iron) @ self.soft_iron.T


@dataclass(frozen=True)
class Misalignment:
    """Rotation between magnetometer and accelerometer frames from the constancy of the dip.

    Attributes
    ----------
    rotation : Rotation or None
        ``C``, taking calibrated magnetometer vectors into the accelerometer frame; None when the
        data do not support one (BIC) - the frames are then taken as aligned.
    rotvec_deg, rotvec_sigma_deg : ndarray, shape (3,)
        Rotation vector of ``C`` and its standard error, degrees (NaN when not fitted).
    dip_deg, dip_sigma_deg : float
        Dip from the field-gravity angle, degrees (> 0: field points down).
    n_static : int
        Quasi-static samples used.
    spread_before_deg, spread_after_deg : float
        Standard deviation of the field-gravity angle over those samples before and after ``C``.
    delta_bic : float
        BIC with the rotation minus BIC without (negative: the rotation is supported).
    """

    rotation: Rotation | None
    rotvec_deg: np.ndarray
    rotvec_sigma_deg: np.ndarray
    dip_deg: float
    dip_sigma_deg: float
    n_static: int
    spread_before_deg: float
    spread_after_deg: float
    delta_bic: float


@dataclass(frozen=True)
class TumbleResult(Calibration):
    """A tumble calibration (SPEC section 2, ``"model": "tumble"``).

    Attributes
    ----------
    fit : KindFit
        The chosen ellipsoid.
    candidates : tuple of KindFit
        Every kind tried, for the report and the BIC comparison.
    coverage : Coverage
    misalignment : Misalignment or None
        None without an accelerometer (or too few quasi-static samples).
    field_ut : float or None
        When known, ``soft_iron`` is scaled so that the calibrated field is in microtesla.
    noise : float
        White-noise sigma per axis from second differences of consecutive samples, recording units.
    n_samples, n_repeats : int
        Samples fitted; rows dropped as repeated magnetometer values.
    warnings : tuple of str
    refused : str
        Why no kind gives a usable calibration (every kind degenerate, or the field changed during
        the recording: see :func:`calibrate_tumble`), in words; empty when the result is usable.
        A refused result must not be written as a calibration file.
    diagnosis : TumbleDiagnosis or None
        The residual diagnosis (:mod:`calibrate.tumble_diagnose`); None when every kind is degenerate.  With claimed
        effects, ``fit`` is the ellipsoid at their reference time and temperature.
    """

    fit: KindFit
    candidates: tuple
    coverage: Coverage
    misalignment: Misalignment | None
    field_ut: float | None
    noise: float
    n_samples: int
    n_repeats: int
    warnings: tuple = field(default_factory=tuple)
    refused: str = ""
    diagnosis: TumbleDiagnosis | None = None

    calibration_kind = "tumble"

    @property
    def kind(self) -> str:
        """The chosen ellipsoid kind (``offset``, ``diagonal``, ``full``)."""
        return self.fit.kind

    @property
    def parameters(self) -> dict:
        """``hard_iron[i]`` (recording units), ``soft_iron[i,j]`` (file units), ``field_norm``: value and sigma."""
        fit = self.fit
        out = {f"hard_iron[{i}]": (float(v), float(e)) for i, (v, e) in enumerate(zip(fit.hard_iron, fit.hard_iron_sigma))}
        for (i, j), v in np.ndenumerate(self.soft_iron):
            out[f"soft_iron[{i},{j}]"] = (float(v), float(fit.soft_iron_sigma[i, j] * self.scale))
        out["field_norm"] = (self.field_norm, None if self.field_ut else float(fit.field_norm_sigma))
        return out

    def plots(self, recording, folder) -> list:
        """``tumble.png``: |B| before and after, per sample (:func:`calibrate.plots.plot_tumble`)."""
        from pathlib import Path

        from .plots import plot_tumble

        return [plot_tumble(recording.mag, self, Path(folder) / "tumble.png")]

    @property
    def hard_iron(self) -> np.ndarray:
        return self.fit.hard_iron

    @property
    def scale(self) -> float:
        """Factor from det-1 units to the file's units (``field_ut / F`` when |B| is known, else 1)."""
        return self.field_ut / self.fit.field_norm if self.field_ut else 1.0

    @property
    def soft_iron(self) -> np.ndarray:
        """``S`` as written to the file: det 1, or scaled to microtesla when |B| is known."""
        return self.fit.soft_iron * self.scale

    @property
    def field_norm(self) -> float:
        return float(self.field_ut) if self.field_ut else self.fit.field_norm

    @property
    def mag_to_accel(self) -> np.ndarray | None:
        m = self.misalignment
        return None if m is None or m.rotation is None else m.rotation.as_matrix()

    def calibrated(self, mag: np.ndarray) -> np.ndarray:
        """``m = soft_iron @ (raw - hard_iron)``, shape (n, 3), magnetometer frame, file units."""
        return (np.asarray(mag, dtype=float) - self.hard_iron) @ self.soft_iron.T

    def to_json(self) -> dict:
        """The calibration file (SPEC section 2, tumble kind), JSON-ready.

        ``hard_iron`` is the one at the claimed effects' reference (first sample's ``t_s``, mean
        ``temp_c``); the effects' parameters are under ``effects``; ``noise_floor`` is the per-axis
        noise of the raw readings, the diagnosis's that of the radial residual.

        Raises
        ------
        ValueError
            The result is refused (no usable calibration).
        """
        if self.refused:
            raise ValueError(f"a refused tumble calibration has no calibration file: {self.refused}")
        fit, mis = self.fit, self.misalignment
        return header("tumble") | {
            "hard_iron": fit.hard_iron.tolist(),
            "soft_iron": self.soft_iron.tolist(),
            "field_norm": self.field_norm,
            "mag_to_accel": None if self.mag_to_accel is None else self.mag_to_accel.tolist(),
            "field_ut": self.field_ut,
            "dip_deg": None if mis is None else mis.dip_deg,
            "dip_sigma_deg": None if mis is None else _json_float(mis.dip_sigma_deg),
            "channel_columns": ["mx", "my", "mz"],
            "noise_floor": [self.noise] * 3,
            "effects": list(self.diagnosis.effects),
            "diagnosis": self.diagnosis.block,
            "tumble": {
                "kind": fit.kind,
                "kinds": [{"kind": c.kind, "residual_rms": float(np.sqrt(np.mean(c.residuals[fit.inliers] ** 2))),
                           "bic": _json_float(c.bic), "determined": c.determined} for c in self.candidates],
                "hard_iron_sigma": fit.hard_iron_sigma.tolist(),
                "soft_iron_sigma": (fit.soft_iron_sigma * self.scale).tolist(),
                "field_norm_recording_units": fit.field_norm,
                "field_norm_sigma_recording_units": fit.field_norm_sigma,
                "coverage_fraction": self.coverage.fraction,
                "coverage_missing": self.coverage.missing,
                "n_samples": self.n_samples,
                "n_repeats_dropped": self.n_repeats,
                "n_outliers": int(np.count_nonzero(~fit.inliers)),
                "misalignment_rotvec_deg": None if mis is None else [_json_float(v) for v in mis.rotvec_deg],
                "misalignment_rotvec_sigma_deg": None if mis is None else [_json_float(v) for v in mis.rotvec_sigma_deg],
                "field_gravity_angle_spread_deg": None if mis is None else
                {"before": mis.spread_before_deg, "after": mis.spread_after_deg, "n_static": mis.n_static},
            },
            "warnings": list(self.warnings),
        }

    def report(self) -> str:
        """A fit report for a person: values +- sigma, the kinds compared, coverage and warnings in words."""
        fit = self.fit
        lines = [f"Tumble calibration: {fit.kind} ellipsoid from {self.n_samples} samples "
                 f"({self.n_repeats} repeated rows dropped, {np.count_nonzero(~fit.inliers)} outliers)"]
        lines.append("  hard iron " + ", ".join(f"{v:.5g} +- {s:.2g}" for v, s in zip(fit.hard_iron, fit.hard_iron_sigma))
                     + " (recording units)")
        unit = "uT" if self.field_ut else "recording units"
        lines.append(f"  field norm {self.field_norm:.5g} {unit}; soft iron (det 1 shape):")
        for row, srow in zip(fit.soft_iron, fit.soft_iron_sigma):
            lines.append("    " + "  ".join(f"{v:+.5f} +- {s:.1g}" for v, s in zip(row, srow)))
        lines.append("  kinds: " + "; ".join(
            f"{c.kind} BIC {c.bic:.1f} rms {np.sqrt(np.mean(c.residuals[fit.inliers] ** 2)):.3g}"
            + ("" if c.determined else f" (not determined: {c.reason})") for c in self.candidates))
        lines.append(f"  noise floor {self.noise:.3g} per axis; coverage: {self.coverage.words()}")
        mis = self.misalignment
        if mis is not None:
            lines.append(f"  dip {mis.dip_deg:.3f} +- {mis.dip_sigma_deg:.3f} deg from {mis.n_static} quasi-static samples")
            if mis.rotation is None:
                lines.append(f"  mag-to-accel rotation not supported by the data (delta BIC {mis.delta_bic:+.1f}); frames taken as aligned")
            else:
                lines.append("  mag-to-accel rotation vector " + ", ".join(
                    f"{v:+.3f} +- {s:.3f}" for v, s in zip(mis.rotvec_deg, mis.rotvec_sigma_deg)) + " deg")
            lines.append(f"  field-gravity angle spread {mis.spread_before_deg:.3f} -> {mis.spread_after_deg:.3f} deg")
        if self.diagnosis is not None:
            from .tumble_diagnose import format_tumble_diagnosis  # it builds on this module

            lines.append(format_tumble_diagnosis(self.diagnosis.block))
        for w in self.warnings:
            lines.append(f"  warning: {w}")
        return "\n".join(lines)


def _json_float(v) -> float | None:
    return float(v) if np.isfinite(v) else None


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z**2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def sphere_coverage(directions: np.ndarray) -> Coverage:
    """Coverage of the sphere by field directions.

    Parameters
    ----------
    directions : ndarray, shape (n, 3)
        Field directions in the magnetometer frame (need not be unit).

    Returns
    -------
    Coverage
    """
    u = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    cells = _fibonacci_sphere(_N_CELLS)
    hit = np.unique(np.argmax(u @ cells.T, axis=1))
    best = np.max(u, axis=0), np.max(-u, axis=0)
    cos_lim = np.cos(np.radians(FACE_COVERAGE_DEG))
    seen = {}
    for k, axis in enumerate("XYZ"):
        seen[f"+{axis}"] = bool(best[0][k] >= cos_lim)
        seen[f"-{axis}"] = bool(best[1][k] >= cos_lim)
    return Coverage(len(hit) / _N_CELLS, {f: seen[f] for f in _FACES})


def _shape(kind: str, p: np.ndarray) -> np.ndarray:
    """Lower-triangular L (S^2 / F^2 = L L^T) from the shape parameters."""
    if kind == "offset":
        return np.exp(p[0]) * np.eye(3)
    if kind == "diagonal":
        return np.diag(np.exp(p[:3]))
    low = np.diag(np.exp(p[:3]))
    low[1, 0], low[2, 0], low[2, 1] = p[3:6]
    return low


def _shape_params(kind: str, m: np.ndarray) -> np.ndarray:
    """Start values for ``kind`` from a positive-definite ``S^2 / F^2`` matrix ``m``."""
    if kind == "offset":
        return np.array([0.5 * np.log(np.mean(np.diag(m)))])
    if kind == "diagonal":
        return 0.5 * np.log(np.diag(m))
    low = np.linalg.cholesky(m)
    return np.concatenate([np.log(np.diag(low)), [low[1, 0], low[2, 0], low[2, 1]]])


def _residual(p, kind, y):
    low = _shape(kind, p[3:])
    return np.linalg.norm((y - p[:3]) @ low, axis=1) - 1.0


def _unpack(kind, p, centre, radius):
    """(h, S det 1, F) in recording units from normalised parameters."""
    low = _shape(kind, p[3:])
    a = np.real(sqrtm(low @ low.T)) / radius  # S / F, maps raw units onto the unit sphere
    a = (a + a.T) / 2.0
    f_norm = np.linalg.det(a) ** (-1.0 / 3.0)
    return centre + radius * p[:3], a * f_norm, f_norm


def _fit_kind(kind, y, p0, inlier_mask=None):
    """Robust fit, trimming, then a plain refit on the inliers; normalised units."""
    start = p0
    if inlier_mask is None:
        first = least_squares(_residual, p0, args=(kind, y), loss="soft_l1", f_scale=0.02, method="trf", tr_solver="lsmr",
                              max_nfev=_MAX_NFEV)
        sigma = max(robust_sigma(_residual(first.x, kind, y)), 1e-9)
        robust = least_squares(_residual, first.x, args=(kind, y), loss="soft_l1", f_scale=2.0 * sigma,
                               method="trf", tr_solver="lsmr", max_nfev=_MAX_NFEV)
        r = _residual(robust.x, kind, y)
        sigma = max(robust_sigma(r), 1e-9)
        inlier_mask = np.abs(r - np.median(r)) < OUTLIER_SIGMAS * sigma
        start = robust.x
    final = least_squares(_residual, start, args=(kind, y[inlier_mask]), method="lm", max_nfev=_MAX_NFEV)
    return final, inlier_mask


def _algebraic_start(x: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the linear least-squares sphere ``|x|^2 = 2 c.x + k``."""
    design = np.column_stack([2.0 * x, np.ones(len(x))])
    sol, *_ = np.linalg.lstsq(design, np.sum(x**2, axis=1), rcond=None)
    centre = sol[:3]
    return centre, float(np.sqrt(max(sol[3] + centre @ centre, 1e-30)))


def _covariance(res, n_obs: int) -> np.ndarray:
    """Parameter covariance from the Jacobian, scaled by the reduced chi-square (inf if singular)."""
    k = len(res.x)
    jtj = res.jac.T @ res.jac
    if np.linalg.cond(jtj) > 1e12:
        return np.full((k, k), np.inf)
    return np.linalg.inv(jtj) * float(np.sum(res.fun**2)) / max(n_obs - k, 1)


def _propagate(kind, p, cov, centre, radius):
    """Standard errors of h, S (det 1) and F from the covariance of the normalised parameters."""
    k = _N_PARAMS[kind]
    h, s, f_norm = _unpack(kind, p, centre, radius)
    sig_h = radius * np.sqrt(np.clip(np.diag(cov)[:3], 0.0, None))
    grads_s, grads_f = np.empty((9, k)), np.empty(k)
    for j in range(k):
        step = np.zeros(k)
        step[j] = 1e-6
        _, s_j, f_j = _unpack(kind, p + step, centre, radius)
        grads_s[:, j] = (s_j - s).ravel() / 1e-6
        grads_f[j] = (f_j - f_norm) / 1e-6
    cov = cov[:k, :k]
    with np.errstate(invalid="ignore"):
        sig_s = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", grads_s, cov, grads_s), 0.0, None)).reshape(3, 3)
        sig_f = float(np.sqrt(max(grads_f @ cov @ grads_f, 0.0)))
    return h, sig_h, s, sig_s, f_norm, sig_f


def _kind_fit(kind, x, y, centre, radius, p0, inliers) -> KindFit:
    res, inliers = _fit_kind(kind, y, p0, inliers)
    h, sig_h, s, sig_s, f_norm, sig_f = _propagate(kind, res.x, _covariance(res, int(np.count_nonzero(inliers))),
                                                   centre, radius)
    resid_all = np.linalg.norm((x - h) @ s.T, axis=1) - f_norm
    return KindFit(kind, h, sig_h, s, sig_s, f_norm, sig_f, resid_all, inliers, float(np.sum(resid_all[inliers] ** 2)),
                   np.nan, True, "", bool(res.success), res.message, res.x, centre, radius)


def fit_ellipsoid(mag: np.ndarray, kind: str = "auto") -> tuple[KindFit, tuple, Coverage]:
    """Fit the ellipsoid kinds and choose one.

    Parameters
    ----------
    mag : ndarray, shape (n, 3)
        Raw magnetometer samples (repeats removed), recording units, magnetometer frame.
    kind : {"auto", "offset", "diagonal", "full"}
        ``auto`` takes the determined kind with the lowest BIC; a named kind is fitted as asked
        (the result warns through ``determined`` when the data do not support it).

    Returns
    -------
    chosen : KindFit
    candidates : tuple of KindFit
        The kinds fitted, simplest first, with BIC on a common sample set.
    coverage : Coverage
        Of the field directions about the offset-only centre.

    Raises
    ------
    ValueError
        ``kind`` unknown, or fewer samples than the full kind's parameters.
    """
    if kind not in ("auto",) + KINDS:
        raise ValueError(f"kind must be 'auto' or one of {KINDS}, got {kind!r}")
    x = np.asarray(mag, dtype=float)
    if len(x) < 12:
        raise ValueError(f"a tumble calibration needs at least 12 samples, got {len(x)}")
    centre, radius = _algebraic_start(x)
    y = (x - centre) / radius
    names = KINDS if kind == "auto" else KINDS[: KINDS.index(kind) + 1]

    # each kind starts from the previous one; the most flexible kind's trimming sets the common samples
    fits, params = [], []
    p = np.zeros(4)
    for name in names:
        if params:
            low = _shape(names[len(params) - 1], params[-1][3:])
            p = np.concatenate([params[-1][:3], _shape_params(name, low @ low.T)])
        fit = _kind_fit(name, x, y, centre, radius, p, None)
        fits.append(fit)
        params.append(fit.params)
    common = fits[-1].inliers
    coverage = sphere_coverage(x[common] - fits[0].hard_iron)
    n = int(np.count_nonzero(common))
    extent = float(np.percentile(np.linalg.norm(x[common] - np.median(x[common], axis=0), axis=1), 95))
    final = []
    for fit, p in zip(fits, params):
        if not np.array_equal(fit.inliers, common):
            fit = _kind_fit(fit.kind, x, y, centre, radius, p, common)
        bic = n * np.log(fit.rss / n) + fit.n_params * np.log(n)
        rel = max(np.max(fit.hard_iron_sigma) / fit.field_norm, np.max(fit.soft_iron_sigma),
                  fit.field_norm_sigma / fit.field_norm)
        reason = ""
        degenerate = not fit.field_norm <= MAX_RADIUS_RATIO * extent
        if degenerate:
            reason = (f"degenerate: a sphere of radius {fit.field_norm:.4g} ({fit.field_norm / max(extent, 1e-300):.3g} "
                      f"times the samples' extent {extent:.4g}) with hard iron {np.linalg.norm(fit.hard_iron):.4g}; "
                      "the samples lie on no ellipsoid around the device: the field changed during the recording "
                      "(a magnet or magnetised part attached or moved partway) or the device barely turned")
        elif not np.isfinite(rel) or rel > MAX_RELATIVE_SIGMA:
            reason = (f"standard errors up to {100 * rel:.2g} % of the field" if np.isfinite(rel)
                      else "singular covariance")
        elif fit.kind != "offset" and coverage.missing:
            reason = f"the field was never along {', '.join(coverage.missing)}"
        final.append(replace(fit, bic=float(bic), determined=not reason, reason=reason, degenerate=degenerate))
    if kind != "auto":
        return final[-1], tuple(final), coverage
    usable = [f for f in final if f.determined] or final[:1]
    return min(usable, key=lambda f: f.bic), tuple(final), coverage


def field_gravity_angles(mag_cal: np.ndarray, accel: np.ndarray, rotation: Rotation | None = None) -> np.ndarray:
    """Angle between gravity-up (the accelerometer) and the field, degrees, per sample.

    Parameters
    ----------
    mag_cal : ndarray, shape (n, 3)
        Calibrated field, magnetometer frame, any unit.
    accel : ndarray, shape (n, 3)
        Accelerometer, accelerometer frame, any unit.
    rotation : Rotation, optional
        ``mag_to_accel``; identity when None.
    """
    m = mag_cal if rotation is None else rotation.apply(mag_cal)
    cos = np.sum(m * accel, axis=1) / (np.linalg.norm(m, axis=1) * np.linalg.norm(accel, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def static_mask(accel: np.ndarray, tolerance: float = STATIC_TOLERANCE) -> np.ndarray:
    """Quasi-static samples: ``| |a| / median|a| - 1 | < tolerance``."""
    norm = np.linalg.norm(accel, axis=1)
    return np.abs(norm / np.median(norm) - 1.0) < tolerance


def fit_misalignment(mag_cal: np.ndarray, accel: np.ndarray) -> Misalignment | None:
    """Rotation from the calibrated magnetometer frame to the accelerometer frame, and the dip.

    Parameters
    ----------
    mag_cal : ndarray, shape (n, 3)
        Calibrated field (inliers only), magnetometer frame.
    accel : ndarray, shape (n, 3)
        Accelerometer at the same instants (specific force, +1 g up at rest), any unit.

    Returns
    -------
    Misalignment or None
        None when fewer than 20 quasi-static samples exist.

    Notes
    -----
    Residuals are angle errors in radians with a robust ``soft_l1`` loss scaled by the robust
    spread of the angles; standard errors come from a plain refit on the samples within
    ``OUTLIER_SIGMAS`` robust sigmas.  The BIC compares the fit with the rotation (4 parameters)
    to the dip alone (1 parameter) on the same samples.
    """
    static = static_mask(accel)
    if np.count_nonzero(static) < 20:
        return None
    m = mag_cal[static] / np.linalg.norm(mag_cal[static], axis=1, keepdims=True)
    a = accel[static] / np.linalg.norm(accel[static], axis=1, keepdims=True)
    angle0 = np.arccos(np.clip(np.sum(m * a, axis=1), -1.0, 1.0))
    spread0 = float(np.degrees(np.std(angle0)))

    def resid(p):
        mm = Rotation.from_rotvec(p[:3]).apply(m)
        return np.arccos(np.clip(np.sum(mm * a, axis=1), -1.0, 1.0)) - p[3]

    sigma = max(robust_sigma(angle0), 1e-6)
    p0 = np.array([0.0, 0.0, 0.0, np.median(angle0)])
    robust = least_squares(resid, p0, loss="soft_l1", f_scale=2.0 * sigma, tr_solver="lsmr")
    r = resid(robust.x)
    sigma = max(robust_sigma(r), 1e-9)
    keep = np.abs(r - np.median(r)) < OUTLIER_SIGMAS * sigma
    m, a = m[keep], a[keep]
    final = least_squares(resid, robust.x, method="lm")
    n = len(m)
    rss_rot = float(np.sum(final.fun**2))
    ang = np.arccos(np.clip(np.sum(m * a, axis=1), -1.0, 1.0))
    rss_dip = float(np.sum((ang - ang.mean()) ** 2))
    delta_bic = n * np.log(rss_rot / rss_dip) + 3 * np.log(n)
    cov = np.linalg.pinv(final.jac.T @ final.jac) * rss_rot / max(n - 4, 1)
    sig = np.degrees(np.sqrt(np.clip(np.diag(cov), 0.0, None)))
    if delta_bic < 0:
        rot, dip = Rotation.from_rotvec(final.x[:3]), np.degrees(final.x[3]) - 90.0
        rotvec, rotvec_sig, dip_sig = np.degrees(final.x[:3]), sig[:3], sig[3]
        spread1 = float(np.degrees(np.std(resid(np.concatenate([final.x[:3], [0.0]])))))
    else:
        rot, dip = None, np.degrees(ang.mean()) - 90.0
        rotvec, rotvec_sig = np.full(3, np.nan), np.full(3, np.nan)
        dip_sig = float(np.degrees(np.std(ang) / np.sqrt(n)))
        spread1 = float(np.degrees(np.std(ang)))
    return Misalignment(rot, rotvec, rotvec_sig, float(dip), float(dip_sig), int(np.count_nonzero(static)),
                        spread0, spread1, float(delta_bic))


def _sym_sqrt(kind, p_shape):
    """Symmetric positive-definite ``A`` with ``A^2 = L L^T`` (the calibration's shape, normalised units)."""
    low = _shape(kind, p_shape)
    w, v = np.linalg.eigh(low @ low.T)
    return (v * np.sqrt(w)) @ v.T


def refine_jointly(fit: KindFit, mag: np.ndarray, accel: np.ndarray, first: Misalignment) -> tuple[KindFit, Misalignment]:
    r"""Refit the ellipsoid, the rotation and the dip together.

    Parameters
    ----------
    fit : KindFit
        The ellipsoid alone (start values, inliers, kind).
    mag, accel : ndarray, shape (n, 3)
        All samples (the ones ``fit`` was made from), recording units.
    first : Misalignment
        The sequential estimate: start values, and whether a rotation is fitted at all.

    Returns
    -------
    KindFit, Misalignment

    Notes
    -----
    The loss adds the radial residuals of the inliers, in units of their robust sigma, to the
    field-gravity angle residuals of the quasi-static inliers, in units of theirs:

    .. math:: \sum_i \rho\left(\frac{|A(y_i - h)| - 1}{\sigma_r}\right)^2
              + \sum_{j \in static} \rho\left(\frac{\arccos(\hat a_j \cdot C \widehat{A(y_j - h)}) - \theta}{\sigma_a}\right)^2

    (``soft_l1`` loss ``rho``), so the dip constancy also pins the hard iron where the ellipsoid alone
    is weakly determined (poor coverage).  Standard errors come from a plain refit on the samples
    within ``OUTLIER_SIGMAS`` of both.
    """
    kind, k = fit.kind, fit.n_params
    y = (np.asarray(mag, float) - fit.centre) / fit.radius
    inl = fit.inliers
    static = inl & static_mask(accel)
    a_unit = accel[static] / np.linalg.norm(accel[static], axis=1, keepdims=True)
    ys = y[static]
    with_rot = first.rotation is not None
    sigma_r = max(robust_sigma(_residual(fit.params, kind, y[inl])), 1e-9)

    def angles(q):
        mm = (ys - q[:3]) @ _sym_sqrt(kind, q[3:k])
        if with_rot:
            mm = Rotation.from_rotvec(q[k:k + 3]).apply(mm)
        cos = np.sum(mm * a_unit, axis=1) / np.linalg.norm(mm, axis=1)
        return np.arccos(np.clip(cos, -1.0, 1.0)) - q[-1]

    q0 = np.concatenate([fit.params, np.radians(first.rotvec_deg) if with_rot else [], [np.radians(90.0 + first.dip_deg)]])
    sigma_a = max(robust_sigma(angles(q0)), 1e-9)
    use_r, use_a = np.ones(len(y[inl]), bool), np.ones(len(ys), bool)

    def resid(q):
        return np.concatenate([_residual(q[:k], kind, y[inl][use_r]) / sigma_r, angles(q)[use_a] / sigma_a])

    robust = least_squares(resid, q0, loss="soft_l1", f_scale=2.0, tr_solver="lsmr", max_nfev=_MAX_NFEV)
    use_r = np.abs(_residual(robust.x[:k], kind, y[inl])) < OUTLIER_SIGMAS * sigma_r
    use_a = np.abs(angles(robust.x)) < OUTLIER_SIGMAS * sigma_a
    final = least_squares(resid, robust.x, method="lm", max_nfev=_MAX_NFEV)
    cov = _covariance(final, len(final.fun))
    h, sig_h, s_mat, sig_s, f_norm, sig_f = _propagate(kind, final.x[:k], cov, fit.centre, fit.radius)
    resid_all = np.linalg.norm((mag - h) @ s_mat.T, axis=1) - f_norm
    new_fit = replace(fit, hard_iron=h, hard_iron_sigma=sig_h, soft_iron=s_mat, soft_iron_sigma=sig_s, field_norm=f_norm,
                      field_norm_sigma=sig_f, residuals=resid_all, rss=float(np.sum(resid_all[inl] ** 2)),
                      success=bool(final.success), message=final.message, params=final.x[:k])
    sig = np.degrees(np.sqrt(np.clip(np.diag(cov), 0.0, None)))
    rotation = Rotation.from_rotvec(final.x[k:k + 3]) if with_rot else None
    spread_after = float(np.std(field_gravity_angles(new_fit.calibrated(mag[static]), accel[static], rotation)))
    mis = replace(first, rotation=rotation,
                  rotvec_deg=np.degrees(final.x[k:k + 3]) if with_rot else first.rotvec_deg,
                  rotvec_sigma_deg=sig[k:k + 3] if with_rot else first.rotvec_sigma_deg,
                  dip_deg=float(np.degrees(final.x[-1]) - 90.0), dip_sigma_deg=float(sig[-1]),
                  spread_after_deg=spread_after)
    return new_fit, mis


def _noise_floor(x: np.ndarray) -> float:
    """Per-axis white-noise sigma from second differences of consecutive samples (median over axes)."""
    d = x[:-2] - 2.0 * x[1:-1] + x[2:]
    return float(np.median(robust_sigma(d)) / np.sqrt(6.0))


def calibrate_tumble(mag: np.ndarray, accel: np.ndarray | None = None, *, kind: str = "auto",
                     field_ut: float | None = None, n_repeats: int = 0, t_s: np.ndarray | None = None,
                     temp_c: np.ndarray | None = None) -> TumbleResult:
    """Calibrate hard and soft iron (and the magnetometer-accelerometer rotation) from a tumble.

    Parameters
    ----------
    mag : ndarray, shape (n, 3)
        Raw magnetometer, recording units, magnetometer frame; repeated values already removed
        (:func:`compass.io.tumble.read_tumble` does that).
    accel : ndarray, shape (n, 3), optional
        Accelerometer at the same rows (specific force), any unit.
    kind : {"auto", "offset", "diagonal", "full"}
    field_ut : float, optional
        Known |B|; the file's ``soft_iron`` then gives microtesla.
    n_repeats : int
        Rows dropped upstream as repeats (reported only).
    t_s, temp_c : ndarray, shape (n,), optional
        Time (s) and sensor temperature (degC) of each sample: the residual diagnosis then
        examines a drifting and a temperature-dependent hard iron too.

    Returns
    -------
    TumbleResult
        Refused (``refused`` says why) when every kind is degenerate, or when the residual
        diagnosis leaves structure in |m| unexplained and, with an accelerometer, the calibrated
        field agrees worse with gravity than the raw readings (:func:`_widening`).

    Examples
    --------
    >>> from compass.sim.tumble import simulate_tumble
    >>> sim = simulate_tumble(seed=1, n=1500)
    >>> res = calibrate_tumble(sim.mag, sim.accel)
    >>> res.kind, bool(abs(res.field_norm - 50) < 5)
    ('full', True)
    """
    if field_ut is not None and not field_ut > 0:
        raise ValueError(f"field_ut must be positive, got {field_ut}")
    mag = raw = np.asarray(mag, dtype=float)
    noise = _noise_floor(mag)
    chosen, candidates, coverage = fit_ellipsoid(mag, kind)
    warnings = []
    if coverage.missing:
        warnings.append("incomplete coverage: " + coverage.words())
    full = candidates[-1]
    if kind == "auto" and chosen.kind != "full":
        why = full.reason or "the BIC prefers the simpler kind"
        warnings.append(f"used the {chosen.kind} kind: the full ellipsoid is not determined ({why})"
                        if not full.determined else f"used the {chosen.kind} kind ({why})")
    if chosen.degenerate:
        refused = (f"no usable calibration: no ellipsoid kind is determined, and the simplest ({chosen.kind}) is "
                   f"{chosen.reason}")
        return TumbleResult(chosen, candidates, coverage, None, field_ut, noise, len(mag), n_repeats,
                            tuple(warnings + [refused]), refused)
    if not chosen.determined:
        warnings.append(f"the {chosen.kind} kind is poorly determined: {chosen.reason}")
    n_out = int(np.count_nonzero(~chosen.inliers))
    if n_out > 0.2 * len(mag):
        warnings.append(f"{n_out} of {len(mag)} samples ({100 * n_out / len(mag):.0f} %) were rejected as "
                        "disturbed: the field around the device was not constant")
    offset_rel = np.linalg.norm(chosen.hard_iron) / chosen.field_norm
    if offset_rel > 3.0:
        warnings.append(f"hard iron is {offset_rel:.1f} times the field: the magnetometer may be near saturation")
    from .tumble_diagnose import UNEXPLAINED_WARNING, diagnose_tumble  # it builds on this module

    # effects the ellipsoid lacks are claimed first; everything after works on the readings they correct
    diagnosis = diagnose_tumble(mag, chosen, t_s=t_s, temp_c=temp_c, accel=accel, missing=coverage.missing)
    chosen, mag = diagnosis.fit, diagnosis.raw_at_reference
    if diagnosis.block["unexplained"]:
        warnings.append(UNEXPLAINED_WARNING)
    misalignment = None
    if accel is not None:
        keep = chosen.inliers
        accel = np.asarray(accel, dtype=float)
        misalignment = fit_misalignment(chosen.calibrated(mag[keep]), accel[keep])
        if misalignment is not None and coverage.missing and misalignment.rotation is not None:
            warnings.append("no magnetometer-accelerometer rotation fitted: with part of the sphere missing it "
                            "trades off against the hard iron; frames taken as aligned")
            misalignment = replace(misalignment, rotation=None, rotvec_deg=np.full(3, np.nan),
                                   rotvec_sigma_deg=np.full(3, np.nan))
        if misalignment is not None:
            chosen, misalignment = refine_jointly(chosen, mag, accel, misalignment)
            diagnosis = diagnosis.with_alignment(misalignment, chosen)
            chosen = diagnosis.fit
        else:
            warnings.append("fewer than 20 quasi-static samples: no magnetometer-accelerometer alignment, no dip")
    # the field changed partway: structure in |m| that no effect explains, and gravity agrees less with the result
    changed = diagnosis.block["unexplained"] and misalignment is not None
    refused = _widening(raw, accel, chosen.calibrated(mag), misalignment.rotation) if changed else ""
    return TumbleResult(chosen, candidates, coverage, misalignment, field_ut, noise, len(mag), n_repeats,
                        tuple(warnings + ([refused] if refused else [])), refused, diagnosis)


def _widening(raw: np.ndarray, accel: np.ndarray, mag_cal: np.ndarray, rotation: Rotation | None) -> str:
    """Why the calibration must not be used when it widens the field-gravity angle spread, else "".

    The angle between the field and gravity is a constant of the site.  Called when the residual
    diagnosis left structure in |m| that no effect explains: if then, on the quasi-static samples,
    the calibrated field also agrees worse with gravity than the raw readings (beyond
    :data:`MAX_ANGLE_WIDENING`), the fit is a compromise between fields that differed during the
    recording, however well it lowers the |B| spread.  Either sign alone is not enough: an
    uncalibrated accelerometer can make a right calibration agree worse with gravity.
    """
    static = static_mask(accel)
    before = float(np.std(field_gravity_angles(raw[static], accel[static])))
    after = float(np.std(field_gravity_angles(mag_cal[static], accel[static], rotation)))
    if not after > (1.0 + MAX_ANGLE_WIDENING) * before:  # also when either is NaN (no quasi-static samples)
        return ""
    return (f"no usable calibration: it widens the spread of the field-gravity angle over the quasi-static samples "
            f"from {before:.3g} deg (raw) to {after:.3g} deg, so the raw readings agree better with gravity than the "
            "calibrated ones: the field changed during the recording (a magnet or magnetised part attached or moved "
            "partway), which no single ellipsoid describes")


class TumbleCalibrator(Calibrator):
    """Free-motion (tumble) calibration: ellipsoid, coverage, magnetometer-accelerometer rotation.

    Parameters
    ----------
    ellipsoid : {"auto", "offset", "diagonal", "full"}
        The ellipsoid kind (auto: the determined kind with the lowest BIC).
    field_ut : float, optional
        Known |B| (the file's ``soft_iron`` then gives uT); default the recording's
        ``# field_ut:`` metadata.

    Notes
    -----
    The residual diagnosis always runs (the refusal of a field that changed partway rests on it).
    """

    kind = "tumble"
    draws_plots = True

    def __init__(self, *, ellipsoid: str = "auto", field_ut: float | None = None):
        self.ellipsoid, self.field_ut = ellipsoid, field_ut

    def fit(self, recording: TumbleRecording) -> TumbleResult:
        field_ut = self.field_ut if self.field_ut is not None else metadata_field_ut(recording.path,
                                                                                      recording.metadata)
        result = calibrate_tumble(recording.mag, recording.accel, kind=self.ellipsoid, field_ut=field_ut,
                                  n_repeats=recording.n_repeats, t_s=recording.t_s, temp_c=recording.temp_c)
        if result.refused:
            raise CannotCalibrate(f"{recording.path}: {result.refused}")
        return result
