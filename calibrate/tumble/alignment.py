"""The magnetometer-accelerometer rotation and the dip from the constancy of the field-gravity angle.

See :mod:`calibrate.tumble` for the model.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import solve_sylvester
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from compass.frames import row_norms

from ..noise import robust_sigma
from .ellipsoid import (MAX_NFEV, OUTLIER_SIGMAS, EllipsoidFit, Normal, fit_covariance, propagate, radial_jacobian,
                        plain_fit, radial_normal, radial_residual, robust_rows, shape_matrix, sym_sqrt)

STATIC_TOLERANCE = 0.02
"""Quasi-static samples: | |a| / g - 1 | below this (g = median |a|)."""


MAX_ANGLE_WIDENING = 0.05
"""A correction that widens the field-gravity angle spread by more than this fraction is not used."""


_JACOBIAN_CHUNK_ROWS = 65536
"""Radial rows of the joint Jacobian computed at once (their temporaries take ~65536 x 3 x 8 bytes, 1.6 MB, each)."""


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
    withheld : str or None
        Why a rotation the data support was not applied (``rotation`` then None), in words.
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
    withheld: str | None = None

    def words(self) -> str:
        """Whether the rotation was applied and why, with the evidence as the diagnosis gives it
        (delta-BIC positive: in the rotation's favour)."""
        evidence = f"delta-BIC {-self.delta_bic:+.0f}"
        if self.rotation is not None:
            return f"rotation applied ({evidence})"
        if self.withheld:
            return f"rotation supported by the data ({evidence}) but not applied: {self.withheld}; frames taken as aligned"
        return f"rotation not supported by the data ({evidence}); frames taken as aligned"


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
    cos = np.sum(m * accel, axis=1) / (row_norms(m) * row_norms(accel))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def static_mask(accel: np.ndarray, tolerance: float = STATIC_TOLERANCE) -> np.ndarray:
    """Quasi-static samples: ``| |a| / median|a| - 1 | < tolerance``."""
    norm = row_norms(accel)
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
    ``OUTLIER_SIGMAS`` robust sigmas (:func:`~calibrate.tumble.ellipsoid.plain_fit`, on the analytic
    :func:`_turned_angles_jacobian`).  The BIC compares the fit with the rotation (4 parameters)
    to the dip alone (1 parameter) on the same samples.
    """
    static = static_mask(accel)
    if np.count_nonzero(static) < 20:
        return None
    m = mag_cal[static] / row_norms(mag_cal[static])[:, None]
    a = accel[static] / row_norms(accel[static])[:, None]
    angle0 = np.arccos(np.clip(np.sum(m * a, axis=1), -1.0, 1.0))
    spread0 = float(np.degrees(np.std(angle0)))

    resid = _turned_angles
    sigma = max(robust_sigma(angle0), 1e-6)
    p0 = np.array([0.0, 0.0, 0.0, np.median(angle0)])
    thin = robust_rows(len(m))  # the robust fit gives the start and the outlier test only
    robust = least_squares(resid, p0, args=(m[thin], a[thin]), loss="soft_l1", f_scale=2.0 * sigma, tr_solver="lsmr")
    r = resid(robust.x, m, a)
    sigma = max(robust_sigma(r), 1e-9)
    keep = np.abs(r - np.median(r)) < OUTLIER_SIGMAS * sigma
    m, a = m[keep], a[keep]
    final = plain_fit(resid, robust.x, _turned_angles_jacobian, args=(m, a))
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
        spread1 = float(np.degrees(np.std(resid(np.concatenate([final.x[:3], [0.0]]), m, a))))
    else:
        rot, dip = None, np.degrees(ang.mean()) - 90.0
        rotvec, rotvec_sig = np.full(3, np.nan), np.full(3, np.nan)
        dip_sig = float(np.degrees(np.std(ang) / np.sqrt(n)))
        spread1 = float(np.degrees(np.std(ang)))
    return Misalignment(rot, rotvec, rotvec_sig, float(dip), float(dip_sig), int(np.count_nonzero(static)),
                        spread0, spread1, float(delta_bic))


def _turned_angles(p: np.ndarray, m: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Angle between ``a`` and ``m`` turned by the rotation vector ``p[:3]``, minus ``p[3]``, rad, per row
    (unit ``m`` and ``a``, shape (n, 3)): :func:`fit_misalignment`'s residual."""
    mm = Rotation.from_rotvec(p[:3]).apply(m)
    return np.arccos(np.clip(np.sum(mm * a, axis=1), -1.0, 1.0)) - p[3]


def _turned_angles_jacobian(p: np.ndarray, m: np.ndarray, a: np.ndarray) -> np.ndarray:
    """d :func:`_turned_angles` / d p, shape (n, 4): ``-(a . (dR/dv_i) m) / sin(angle)`` for the rotation vector
    (:func:`_rotation_derivatives`; zero where the cosine is clipped), -1 for the angle."""
    cos = np.sum(Rotation.from_rotvec(p[:3]).apply(m) * a, axis=1)
    scale = -1.0 / np.where(np.abs(cos) < 1.0, np.sqrt(np.clip(1.0 - cos * cos, 0.0, None)), np.inf)
    jac = np.empty((len(m), 4))
    for i, d_rot in enumerate(_rotation_derivatives(p[:3])):
        jac[:, i] = scale * np.einsum("ij,ij->i", m @ d_rot.T, a)
    jac[:, 3] = -1.0
    return jac


def _skew(v: np.ndarray) -> np.ndarray:
    """``[v]x``, the matrix of the cross product ``v x .``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _rotation_derivatives(rotvec: np.ndarray) -> np.ndarray:
    r"""``dR/dv_i`` of ``R = exp([v]x)``, shape (3, 3, 3) (first index ``i``).

    .. math:: \frac{\partial R}{\partial v_i} = \frac{v_i [v]_\times + [v \times (I - R) e_i]_\times}{|v|^2} R

    (Gallego and Yezzi 2015, J. Math. Imaging Vis. 51, eq. 9), ``[e_i]x`` at ``v = 0``.
    """
    rot = Rotation.from_rotvec(rotvec).as_matrix()
    norm2 = float(rotvec @ rotvec)
    if norm2 < 1e-24:
        return np.array([_skew(e) for e in np.eye(3)])
    i_minus_r = np.eye(3) - rot
    return np.array([(rotvec[i] * _skew(rotvec) + _skew(np.cross(rotvec, i_minus_r[:, i]))) @ rot / norm2
                     for i in range(3)])


@dataclass(frozen=True)
class _JointResidual:
    r"""The weighted residual of :func:`refine_jointly` and its analytic Jacobian.

    Parameters ``q``: the ellipsoid's ``k`` (hard iron ``p_h``, then the shape of ``L``), the rotation
    vector of ``C`` (when ``with_rot``), the angle ``theta`` (rad).  The residual stacks the radial
    rows ``(|(y - p_h) L| - 1) / sigma_r`` and the angle rows

    .. math:: \left(\arccos\frac{\hat a \cdot m}{|m|} - \theta\right) / \sigma_a, \qquad m = M (y - p_h),
              \quad M = C A, \quad A = (L L^T)^{1/2}.

    With ``u = m / |m|`` and ``c = u . a``, ``g = d angle / d m = -(a - c u) / (|m| sqrt(1 - c^2))``
    (zero where the angle is clipped); an angle row is then ``-M^T g`` for ``p_h``,
    ``g . (dM/dp) (y - p_h)`` for the shape and rotation parameters (``dM = C dA`` and ``dC A``) and
    ``-1`` for ``theta``.  ``dA`` of a shape parameter solves the Sylvester equation
    ``A dA + dA A = dL L^T + L dL^T``; ``dC`` is :func:`_rotation_derivatives`.
    """

    ellipsoid: str
    k: int
    with_rot: bool
    y_radial: np.ndarray
    y_static: np.ndarray
    a_unit: np.ndarray
    sigma_r: float
    sigma_a: float

    def angles(self, q: np.ndarray) -> np.ndarray:
        """Field-gravity angle of each static row minus ``theta``, rad (unweighted)."""
        k = self.k
        mm = (self.y_static - q[:3]) @ sym_sqrt(self.ellipsoid, q[3:k])
        if self.with_rot:
            mm = Rotation.from_rotvec(q[k:k + 3]).apply(mm)
        cos = np.sum(mm * self.a_unit, axis=1) / row_norms(mm)
        return np.arccos(np.clip(cos, -1.0, 1.0)) - q[-1]

    def residual(self, q: np.ndarray) -> np.ndarray:
        return np.concatenate([radial_residual(q[:self.k], self.ellipsoid, self.y_radial) / self.sigma_r,
                               self.angles(q) / self.sigma_a])

    def _matrix_derivatives(self, q: np.ndarray) -> tuple[np.ndarray, list]:
        """``M`` and ``dM/dq_j`` of the shape and rotation parameters (in that order)."""
        k = self.k
        low = shape_matrix(self.ellipsoid, q[3:k])
        a_mat = sym_sqrt(self.ellipsoid, q[3:k])
        rot = Rotation.from_rotvec(q[k:k + 3]).as_matrix() if self.with_rot else np.eye(3)
        unit = np.eye(3)
        d_lows = [low] if self.ellipsoid == "offset" else [low[j, j] * np.outer(unit[j], unit[j]) for j in range(3)]
        if self.ellipsoid == "full":
            d_lows += [np.outer(unit[a], unit[b]) for a, b in ((1, 0), (2, 0), (2, 1))]
        d_m = [rot @ solve_sylvester(a_mat, a_mat, d_low @ low.T + low @ d_low.T) for d_low in d_lows]
        if self.with_rot:
            d_m += [d_rot @ a_mat for d_rot in _rotation_derivatives(q[k:k + 3])]
        return rot @ a_mat, d_m

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """d residual / d q, shape (radial rows + static rows, q.size)."""
        k, n_r = self.k, len(self.y_radial)
        jac = np.zeros((n_r + len(self.y_static), q.size))
        for start in range(0, n_r, _JACOBIAN_CHUNK_ROWS):  # its temporaries a chunk at a time
            rows = slice(start, min(start + _JACOBIAN_CHUNK_ROWS, n_r))
            radial_jacobian(q[:k], self.ellipsoid, self.y_radial[rows], out=jac[rows, :k])
        jac[:n_r] /= self.sigma_r
        jac[n_r:] = self._angle_jacobian_t(q).T
        return jac

    def normal(self, q: np.ndarray) -> Normal:
        """The normal equations of :meth:`residual` and :meth:`jacobian` (:func:`~calibrate.tumble.ellipsoid.plain_fit`'s
        ``normal``): the radial rows' summed a chunk at a time (:func:`~calibrate.tumble.ellipsoid.radial_normal`), the
        angle rows' from their Jacobian."""
        k = self.k
        radial = radial_normal(q[:k], self.ellipsoid, self.y_radial)
        r_a, j_a = self.angles(q) / self.sigma_a, self._angle_jacobian_t(q)
        jtj, jtr = j_a @ j_a.T, j_a @ r_a
        jtj[:k, :k] += radial.jtj / self.sigma_r**2
        jtr[:k] += radial.jtr / self.sigma_r**2
        return Normal(radial.chi2 / self.sigma_r**2 + float(r_a @ r_a), jtj, jtr, radial.rows + len(r_a))

    def _angle_jacobian_t(self, q: np.ndarray) -> np.ndarray:
        """d (angle rows of :meth:`residual`) / d q, transposed: shape (q.size, static rows), each parameter's
        derivatives a contiguous row (as :func:`~calibrate.tumble.ellipsoid.radial_jacobian`'s columns)."""
        m_mat, d_m = self._matrix_derivatives(q)
        d = np.ascontiguousarray((self.y_static - q[:3]).T)
        a = np.ascontiguousarray(self.a_unit.T)
        mm = m_mat @ d
        norm = np.sqrt(np.einsum("ij,ij->j", mm, mm))
        u = mm / norm
        cos = np.einsum("ij,ij->j", u, a)
        sin = np.sqrt(np.clip(1.0 - cos * cos, 0.0, None))
        g = -(a - cos * u) / np.where(np.abs(cos) < 1.0, norm * sin, np.inf)
        rows = np.empty((q.size, d.shape[1]))
        rows[:3] = -(m_mat.T @ g)
        # g . (dM d) = sum_il dM_il g_i d_l: every matrix's at once, against the products g_i d_l of each row
        rows[3:-1] = np.reshape(d_m, (len(d_m), 9)) @ (g[:, None, :] * d[None, :, :]).reshape(9, -1)
        rows[-1] = -1.0
        rows /= self.sigma_a
        return rows


def refine_jointly(fit: EllipsoidFit, mag: np.ndarray, accel: np.ndarray, first: Misalignment) -> tuple[EllipsoidFit, Misalignment]:
    r"""Refit the ellipsoid, the rotation and the dip together.

    Parameters
    ----------
    fit : EllipsoidFit
        The ellipsoid alone (start values, inliers, kind).
    mag, accel : ndarray, shape (n, 3)
        All samples (the ones ``fit`` was made from), recording units.
    first : Misalignment
        The sequential estimate: start values, and whether a rotation is fitted at all.

    Returns
    -------
    EllipsoidFit, Misalignment

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
    ellipsoid, k = fit.ellipsoid, fit.n_params
    mag = np.asarray(mag, float)
    inl = fit.inliers
    static = inl & static_mask(accel)
    a_unit = accel[static] / row_norms(accel[static])[:, None]
    with_rot = first.rotation is not None
    y_inl, y_static = ((mag[rows] - fit.centre) / fit.radius for rows in (inl, static))
    sigma_r = max(robust_sigma(radial_residual(fit.params, ellipsoid, y_inl)), 1e-9)
    q0 = np.concatenate([fit.params, np.radians(first.rotvec_deg) if with_rot else [], [np.radians(90.0 + first.dip_deg)]])
    every = _JointResidual(ellipsoid, k, with_rot, y_inl, y_static, a_unit, sigma_r, 1.0)
    sigma_a = max(robust_sigma(every.angles(q0)), 1e-9)
    every = replace(every, sigma_a=sigma_a)
    # the robust fit gives the start and the outlier tests only, on rows thinned alike (ellipsoid.ROBUST_ROWS)
    thin = robust_rows(len(y_inl) + len(y_static))
    robust_on = replace(every, y_radial=y_inl[thin], y_static=y_static[thin], a_unit=a_unit[thin])
    robust_x = least_squares(robust_on.residual, q0, jac=robust_on.jacobian, loss="soft_l1", f_scale=2.0,
                             tr_solver="lsmr", max_nfev=MAX_NFEV).x
    use_r = np.abs(radial_residual(robust_x[:k], ellipsoid, y_inl)) < OUTLIER_SIGMAS * sigma_r
    use_a = np.abs(every.angles(robust_x)) < OUTLIER_SIGMAS * sigma_a
    kept = replace(every, y_radial=y_inl[use_r], y_static=y_static[use_a], a_unit=a_unit[use_a])
    del every, robust_on, y_inl, y_static, a_unit  # the kept rows only, beside the final fit's Jacobian
    final = plain_fit(kept.residual, robust_x, kept.jacobian, normal=kept.normal)
    cov = fit_covariance(final, len(kept.y_radial) + len(kept.y_static))
    h, sig_h, s_mat, sig_s, f_norm, sig_f = propagate(ellipsoid, final.x[:k], cov, fit.centre, fit.radius)
    resid_all = row_norms((mag - h) @ s_mat.T) - f_norm
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
