"""The magnetometer-accelerometer rotation and the dip from the constancy of the field-gravity angle.

See :mod:`calibrate.tumble` for the model.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..noise import robust_sigma
from .ellipsoid import MAX_NFEV, OUTLIER_SIGMAS, KindFit, fit_covariance, propagate, radial_residual, sym_sqrt

STATIC_TOLERANCE = 0.02
"""Quasi-static samples: | |a| / g - 1 | below this (g = median |a|)."""


MAX_ANGLE_WIDENING = 0.05
"""A correction that widens the field-gravity angle spread by more than this fraction is not used."""


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
    sigma_r = max(robust_sigma(radial_residual(fit.params, kind, y[inl])), 1e-9)

    def angles(q):
        mm = (ys - q[:3]) @ sym_sqrt(kind, q[3:k])
        if with_rot:
            mm = Rotation.from_rotvec(q[k:k + 3]).apply(mm)
        cos = np.sum(mm * a_unit, axis=1) / np.linalg.norm(mm, axis=1)
        return np.arccos(np.clip(cos, -1.0, 1.0)) - q[-1]

    q0 = np.concatenate([fit.params, np.radians(first.rotvec_deg) if with_rot else [], [np.radians(90.0 + first.dip_deg)]])
    sigma_a = max(robust_sigma(angles(q0)), 1e-9)
    use_r, use_a = np.ones(len(y[inl]), bool), np.ones(len(ys), bool)

    def resid(q):
        return np.concatenate([radial_residual(q[:k], kind, y[inl][use_r]) / sigma_r, angles(q)[use_a] / sigma_a])

    robust = least_squares(resid, q0, loss="soft_l1", f_scale=2.0, tr_solver="lsmr", max_nfev=MAX_NFEV)
    use_r = np.abs(radial_residual(robust.x[:k], kind, y[inl])) < OUTLIER_SIGMAS * sigma_r
    use_a = np.abs(angles(robust.x)) < OUTLIER_SIGMAS * sigma_a
    final = least_squares(resid, robust.x, method="lm", max_nfev=MAX_NFEV)
    cov = fit_covariance(final, len(final.fun))
    h, sig_h, s_mat, sig_s, f_norm, sig_f = propagate(kind, final.x[:k], cov, fit.centre, fit.radius)
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
