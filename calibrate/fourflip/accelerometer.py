"""The bench accelerometer: its alignment with the housing, and the turntable's tilt, from the four flips.

A recording's ``ax, ay, az`` (SPEC section 2) come from an accelerometer riding in the housing.  At
rest it reads the specific force, +g up.  With the pose ``a_W = Rz(phi) Rx(kappa) a_H`` of SPEC
section 1 and the turntable level, gravity seen in the housing frame H is

.. math::

    f_H = R_x(\\kappa)^T R_z(\\phi)^T (0, 0, g)^T = g\\,(0, \\sin\\kappa, \\cos\\kappa)^T,

independent of the turntable angle: flips 0, 90, 180, 270 put it along +Z, +Y, -Z, -Y of H.  The
accelerometer reads ``a = S C f_H + b`` with ``C = R_accel<-H`` (the calibration file's
``mag_to_accel``: the magnetic channels' directions are in H), per-axis scales ``S`` and offsets ``b``.

What the flips identify (turn means ``m_k`` of flip k):

- ``T_z = (m_0 - m_2) / 2 = S C e_z g`` and ``T_y = (m_1 - m_3) / 2 = S C e_y g``: two directions
  that fix the rotation ``C`` fully (Wahba: :meth:`scipy.spatial.transform.Rotation.align_vectors`),
  free of the offsets; their lengths are the Y and Z scales (undone before the directions are
  compared); the angle between them minus 90 deg is one more check: an accelerometer whose axes
  are not orthogonal, or cube faces that are not square, which the accelerometer alone cannot tell
  apart (the magnetic fit's ``flip_error`` effect can: when the diagnosis claimed it, its fitted
  flip errors turn ``f_H`` and their sigmas widen ``C``'s);
- offsets: every axis sees a +/- pair, ``b = (m_0 + m_2) / 2 = (m_1 + m_3) / 2`` (each flip's mean
  less its predicted gravity, in general); the difference of the two is a closure check (offset
  drift between flips, flip errors not modelled);
- the X axis never sees gravity: its scale is not identifiable (it scales only the small
  misalignment it reads, a second-order effect).

A turntable whose axis is tilted from the vertical: in the turntable-axis frame W' true up is
``u = (t_x, t_y, ~1)``; in the frame turning with the turntable it is ``Rz(phi)^T u``, so gravity in
H moves with the first harmonic of the turntable angle and its mean over a turn is the axis.  The
means (``C``) and the harmonic (the tilt) are therefore fitted apart; a misalignment, offset or
scale is constant in H and cannot masquerade as the tilt.  Rotated back into the turning frame,

.. math::

    g_x = t_x \\cos\\phi + t_y \\sin\\phi + c_{x,k}, \\qquad g_y = -t_x \\sin\\phi + t_y \\cos\\phi + c_{y,k}.

What the tilt means for the dip: the magnetic fit has no gravity, it measures the field against the
turntable axis.  With the fitted dip' and field azimuth delta' (both in W'),
``sin(dip) = sin(dip') u_z - cos(dip') (t_x cos delta' + t_y sin delta')``: to first order the dip
against gravity is ``dip' - (t_x cos delta' + t_y sin delta')``.

Not identifiable from the flips: a tilt of the platform top fixed to the turntable (it turns with
it, so it is constant in H): its part about X is one with the rotation about X, its part about Y
with the X offset.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..noise import robust_sigma

__all__ = ["AccelerometerAlignment", "describe_accelerometer", "fit_accelerometer", "with_accelerometer"]

_OFFSET_WARN = 0.005  # |b| / g above which the runtime's tilt error (offsets are not removed) is worth a word
_SCALE_WARN = 0.01  # |s_y / s_z - 1|
_ORTHOGONALITY_SIGMAS = 5.0  # non-orthogonality / closure beyond this many noise sigmas: inconsistent
_ORTHOGONALITY_FLOOR_DEG = 0.05  # ... and beyond this angle (slow drift is not in the noise sigma)
_NOMINAL_WARN_DEG = 5.0  # a flip's gravity this far from nominal (before the fit): wiring or axis names
_MAGNITUDE_WARN = 0.02  # |a| spread within a turn, relative: not at rest or not a clean accelerometer
_TILT_DIP_SIGMAS = 2.0  # the tilt's dip shift beyond this many dip sigmas gets a warning
_GLITCH_SIGMAS = 8.0  # an accelerometer sample this many robust sigmas off its turn's fit is dropped


@dataclass(frozen=True)
class AccelerometerAlignment:
    """What a four-flip recording's accelerometer says (see the module's notes for the model).

    Attributes
    ----------
    mag_to_accel : ndarray, shape (3, 3)
        ``R_accel<-H``: takes a vector in the housing frame H (the magnetic channels' frame) into
        the accelerometer's frame.
    rotvec_deg : ndarray, shape (3,)
        Its rotation vector, degrees (small: rotations about the accelerometer's x, y, z).
    rotvec_covariance_deg2 : ndarray, shape (3, 3)
        Covariance of the rotation vector's error (in the accelerometer frame), deg^2: from the
        noise of the turn means, inflated by the fit's own misfit (non-orthogonality) when larger,
        plus the flip errors' uncertainty when they were given.
    offset : ndarray, shape (3,)
        Accelerometer zero offsets ``b``, recording units.
    g : float
        The accelerometer's reading of 1 g (mean of the Y and Z half differences), recording units.
    scale_yz : ndarray, shape (2,)
        Y and Z axis scales relative to ``g`` (X: not identifiable).
    orthogonality_deg : float
        Angle between the measured Y and Z gravity directions minus 90 deg (0 for orthogonal axes
        and square cube faces), with ``orthogonality_sigma_deg`` from the noise.
    closure : ndarray, shape (3,)
        ``(m_0 + m_2)/2 - (m_1 + m_3)/2``, recording units (0 when the offsets are stable and the
        flips square); ``closure_sigma`` its noise sigma per axis.
    residual_deg : ndarray, shape (4,)
        Angle between each flip's measured gravity (offset removed, rotated into H) and the
        gravity the pose predicts, degrees.
    tilt_xy : ndarray, shape (2,)
        True up in the turntable-axis frame (``t_x, t_y``, radians: the turntable's tilt from level;
        azimuth from the turntable zero, counterclockwise), with ``tilt_covariance`` (rad^2).
    magnitude_spread : float
        Standard deviation of ``|a|`` within the turns over its mean.
    dip_axis_deg, dip_gravity_deg, dip_gravity_sigma_deg : float or None
        The magnetic fit's dip (against the turntable axis) and the dip against gravity with the
        measured tilt (None when no dip was given); :func:`with_accelerometer` reports the latter.
    flip_errors_deg : ndarray, shape (4,)
        Flip-angle errors used for the gravity in H (the magnetic fit's ``flip_error`` effect, else 0).
    glitches_dropped : int
        Accelerometer samples left out as glitches (off their turn's fit by more than 8 robust sigmas).
    warnings : tuple of str
    """

    mag_to_accel: np.ndarray
    rotvec_deg: np.ndarray
    rotvec_covariance_deg2: np.ndarray
    offset: np.ndarray
    g: float
    scale_yz: np.ndarray
    orthogonality_deg: float
    orthogonality_sigma_deg: float
    closure: np.ndarray
    closure_sigma: np.ndarray
    residual_deg: np.ndarray
    tilt_xy: np.ndarray
    tilt_covariance: np.ndarray
    magnitude_spread: float
    flip_errors_deg: np.ndarray
    glitches_dropped: int = 0
    dip_axis_deg: float | None = None
    dip_gravity_deg: float | None = None
    dip_gravity_sigma_deg: float | None = None
    warnings: tuple = field(default=())

    @property
    def rotvec_sigma_deg(self) -> np.ndarray:
        return np.sqrt(np.diag(self.rotvec_covariance_deg2))

    @property
    def angle_deg(self) -> float:
        """Total misalignment angle, degrees."""
        return float(np.linalg.norm(self.rotvec_deg))

    @property
    def tilt_deg(self) -> float:
        """Turntable axis tilt from the vertical, degrees."""
        return float(np.degrees(np.arcsin(min(1.0, np.linalg.norm(self.tilt_xy)))))

    @property
    def tilt_sigma_deg(self) -> float:
        """Sigma of :attr:`tilt_deg` (radial), degrees."""
        t = self.tilt_xy
        r = np.linalg.norm(t)
        u = t / r if r > 0 else np.array([1.0, 0.0])
        return float(np.degrees(np.sqrt(u @ self.tilt_covariance @ u)))

    @property
    def tilt_azimuth_deg(self) -> float:
        """Azimuth (from the turntable zero, counterclockwise) toward which true up leans from the axis."""
        return float(np.mod(np.degrees(np.arctan2(self.tilt_xy[1], self.tilt_xy[0])), 360.0))

    def to_json(self) -> dict:
        """The ``"accelerometer"`` block of the calibration file."""
        out = {
            "mag_to_accel_rotvec_deg": self.rotvec_deg.tolist(),
            "mag_to_accel_rotvec_sigma_deg": self.rotvec_sigma_deg.tolist(),
            "mag_to_accel_rotvec_covariance_deg2": self.rotvec_covariance_deg2.tolist(),
            "misalignment_deg": self.angle_deg,
            "offset": self.offset.tolist(),
            "one_g": self.g,
            "scale_yz": self.scale_yz.tolist(),
            "orthogonality_deg": self.orthogonality_deg,
            "orthogonality_sigma_deg": self.orthogonality_sigma_deg,
            "closure": self.closure.tolist(),
            "closure_sigma": self.closure_sigma.tolist(),
            "flip_residual_deg": self.residual_deg.tolist(),
            "flip_errors_used_deg": self.flip_errors_deg.tolist(),
            "magnitude_spread": self.magnitude_spread,
            "glitches_dropped": self.glitches_dropped,
            "turntable_tilt_deg": self.tilt_deg,
            "turntable_tilt_sigma_deg": self.tilt_sigma_deg,
            "turntable_tilt_azimuth_deg": self.tilt_azimuth_deg,
            "turntable_up_xy": self.tilt_xy.tolist(),
            "turntable_up_xy_covariance": self.tilt_covariance.tolist(),
            "not_identified": "the X axis scale (X never sees gravity); a tilt of the platform top that turns "
                              "with the turntable (one with the rotation about X and the X offset)",
        }
        if self.dip_gravity_deg is not None:
            out |= {"dip_turntable_axis_deg": self.dip_axis_deg, "dip_gravity_deg": self.dip_gravity_deg,
                    "dip_gravity_sigma_deg": self.dip_gravity_sigma_deg}
        return out


def fit_accelerometer(accel, platform_deg, flip_deg, flip_index, *, flip_errors_deg=None, flip_errors_sigma_deg=None,
                      dip_deg=None, dip_sigma_deg=None, azimuth_deg=None) -> AccelerometerAlignment:
    """Estimate the accelerometer's alignment with H and the turntable's tilt from a four-flip recording.

    Parameters
    ----------
    accel : array_like, shape (n, 3)
        ``ax, ay, az`` in any unit (g, m/s^2, counts).
    platform_deg, flip_deg : array_like, shape (n,)
        Turntable reading phi and recorded flip kappa, degrees.
    flip_index : array_like of int, shape (n,)
        0..3 for the nominal flips 0, 90, 180, 270.
    flip_errors_deg, flip_errors_sigma_deg : array_like, shape (4,), optional
        Flip-angle errors and their sigmas (the magnetic fit's ``flip_error`` effect; flip 0 defines
        H, so its is 0): gravity in H is turned by them, and their sigmas widen the rotation's.
    dip_deg, dip_sigma_deg, azimuth_deg : float, optional
        The magnetic fit's dip and field azimuth (against the turntable axis): give them to get the
        dip against gravity.

    Returns
    -------
    AccelerometerAlignment

    Raises
    ------
    ValueError
        Non-finite readings, or a flip whose Y/Z pair reads no gravity (an accelerometer that is
        not one, or columns that are not ``ax, ay, az``).
    """
    a = np.asarray(accel, dtype=float)
    phi = np.radians(np.asarray(platform_deg, dtype=float))
    flip = np.asarray(flip_deg, dtype=float)
    index = np.asarray(flip_index)
    errors = np.zeros(4) if flip_errors_deg is None else np.asarray(flip_errors_deg, dtype=float)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"accelerometer reading not finite at sample {int(np.argmax(~np.all(np.isfinite(a), axis=1)))}")
    keep = _not_glitches(a, phi, index)
    a, phi, flip, index = a[keep], phi[keep], flip[keep], index[keep]
    means, mean_var, spread = _turn_means(a, phi, index)
    w = _wahba(means, mean_var, _gravity_in_housing(flip, errors, index))
    covariance = w.covariance
    if flip_errors_sigma_deg is not None:  # the flip errors' own uncertainty, propagated (rad^2)
        step_deg = 1e-3
        jac = np.column_stack([
            (_wahba(means, mean_var, _gravity_in_housing(flip, errors + step_deg * np.eye(4)[k], index)).rotation
             * w.rotation.inv()).as_rotvec() / np.radians(step_deg) for k in range(4)])
        covariance = covariance + jac @ np.diag(np.radians(flip_errors_sigma_deg) ** 2) @ jac.T

    f_h = _gravity_in_housing(flip, errors, index)[1]
    predicted = w.g * w.scale * w.rotation.apply(f_h)  # gravity part of each flip's mean
    offset = np.mean(means - predicted, axis=0)
    closure = (means[0] + means[2] - predicted[0] - predicted[2]) / 2 - (means[1] + means[3] - predicted[1] - predicted[3]) / 2
    closure_sigma = np.sqrt(mean_var.sum(axis=0)) / 2
    in_housing = w.rotation.apply((means - offset) / w.scale, inverse=True)
    residual = np.degrees(np.arccos(np.clip(np.sum(in_housing * f_h, axis=1)
                                            / np.linalg.norm(in_housing, axis=1) / np.linalg.norm(f_h, axis=1), -1, 1)))
    kappa = np.radians(flip + errors[index])
    tilt_xy, tilt_cov = _turntable_tilt((a - offset) / (w.scale * w.g), phi, kappa, index, w.rotation)

    result = AccelerometerAlignment(
        mag_to_accel=w.rotation.as_matrix(), rotvec_deg=np.degrees(w.rotation.as_rotvec()),
        rotvec_covariance_deg2=np.degrees(np.degrees(covariance)), offset=offset, g=w.g, scale_yz=w.scale[1:],
        orthogonality_deg=w.orthogonality_deg, orthogonality_sigma_deg=w.orthogonality_sigma_deg,
        closure=closure, closure_sigma=closure_sigma, residual_deg=residual, tilt_xy=tilt_xy,
        tilt_covariance=tilt_cov, magnitude_spread=spread, flip_errors_deg=errors,
        glitches_dropped=int(np.sum(~keep)))
    if dip_deg is not None and azimuth_deg is not None:
        dip_g, dip_g_sigma = _dip_against_gravity(dip_deg, dip_sigma_deg, azimuth_deg, tilt_xy, tilt_cov)
        result = replace(result, dip_axis_deg=float(dip_deg), dip_gravity_deg=dip_g, dip_gravity_sigma_deg=dip_g_sigma)
    return replace(result, warnings=_warnings(result, w.nominal_angle_deg, dip_sigma_deg))


def _gravity_in_housing(flip_deg, errors_deg, index):
    """Per sample ``f_H / g = (0, sin kappa, cos kappa)`` at the flip angle plus its error, and per flip its mean."""
    kappa = np.radians(flip_deg + errors_deg[index])
    per_sample = np.column_stack([np.zeros_like(kappa), np.sin(kappa), np.cos(kappa)])
    return per_sample, np.array([per_sample[index == k].mean(axis=0) for k in range(4)])


@dataclass(frozen=True)
class _Wahba:
    rotation: Rotation
    covariance: np.ndarray  # rad^2
    g: float
    scale: np.ndarray
    orthogonality_deg: float
    orthogonality_sigma_deg: float
    nominal_angle_deg: np.ndarray


def _wahba(means, mean_var, gravity) -> _Wahba:
    """``C = R_accel<-H`` from the flips' half differences (offset-free) against gravity in H."""
    f_h = gravity[1]
    t_y, t_z = (means[1] - means[3]) / 2, (means[0] - means[2]) / 2
    var_y, var_z = (mean_var[1] + mean_var[3]) / 4, (mean_var[0] + mean_var[2]) / 4
    g = 0.5 * (np.linalg.norm(t_y) + np.linalg.norm(t_z))
    if not g > 0 or min(np.linalg.norm(t_y), np.linalg.norm(t_z)) < 0.1 * g:
        raise ValueError("the accelerometer does not see gravity turn with the flips (a flip pair reads the same): "
                         "are ax, ay, az an accelerometer riding in the housing?")
    # per-axis scales undone before the directions are compared (a Y/Z scale difference would tilt
    # them by ~ (s_z - s_y) x misalignment); the X axis never sees gravity: its scale is taken as 1 g
    scale = np.array([1.0, np.linalg.norm(t_y) / g, np.linalg.norm(t_z) / g])
    measured = np.array([t_y / scale, t_z / scale])
    measured /= np.linalg.norm(measured, axis=1, keepdims=True)
    housing = np.array([f_h[1] - f_h[3], f_h[0] - f_h[2]])
    housing /= np.linalg.norm(housing, axis=1, keepdims=True)
    # noise of a direction, radians: the mean per-component variance over the squared length
    direction_var = np.array([var_y.mean() / np.sum(t_y**2), var_z.mean() / np.sum(t_z**2)])
    rotation, _, sensitivity = Rotation.align_vectors(measured, housing, weights=1.0 / direction_var,
                                                      return_sensitivity=True)
    covariance = sensitivity * len(direction_var) / np.sum(1.0 / direction_var)  # rad^2 (scipy's Notes)
    nominal_cos, cos_yz = float(housing[0] @ housing[1]), float(measured[0] @ measured[1])
    orthogonality = float(np.degrees(np.arcsin(np.clip(nominal_cos, -1, 1)) - np.arcsin(np.clip(cos_yz, -1, 1))))
    orthogonality_sigma = float(np.degrees(np.sqrt(direction_var.sum())))
    misfit = (orthogonality / orthogonality_sigma) ** 2  # one degree of freedom left after the rotation
    return _Wahba(rotation, covariance * max(1.0, misfit), float(g), scale, orthogonality, orthogonality_sigma,
                  np.degrees(np.arccos(np.clip(np.sum(measured * housing, axis=1), -1, 1))))


def _harmonic_design(phi):
    return np.column_stack([np.ones_like(phi), np.cos(phi), np.sin(phi)])


def _not_glitches(a, phi, index) -> np.ndarray:
    """Samples within :data:`_GLITCH_SIGMAS` robust sigmas (MAD) of their flip's first-harmonic fit on every axis:
    a knock or a line glitch would otherwise pull a turn mean (one 5 g sample in 360 moves it 0.8 deg)."""
    keep = np.ones(len(a), dtype=bool)
    for k in range(4):
        mask = index == k
        design = _harmonic_design(phi[mask])
        coef, *_ = np.linalg.lstsq(design, a[mask], rcond=None)
        resid = a[mask] - design @ coef
        sigma = robust_sigma(resid, axis=0)
        keep[mask] = np.all(np.abs(resid) <= _GLITCH_SIGMAS * np.maximum(sigma, 1e-12 * np.abs(coef[0]).max()), axis=1)
    return keep


def _turn_means(a, phi, index):
    """Per flip, the mean of each axis over the turn (constant of a first-harmonic fit, so an uneven
    turn does not leak the tilt's harmonic into it), its variance, and the relative |a| spread."""
    means, variances, spreads = np.empty((4, 3)), np.empty((4, 3)), []
    for k in range(4):
        mask = index == k
        design = _harmonic_design(phi[mask])
        coef, *_ = np.linalg.lstsq(design, a[mask], rcond=None)
        resid = a[mask] - design @ coef
        dof = max(mask.sum() - 3, 1)
        noise_var = np.sum(resid**2, axis=0) / dof
        means[k] = coef[0]
        variances[k] = noise_var * np.linalg.inv(design.T @ design)[0, 0]
        norm = np.linalg.norm(a[mask], axis=1)
        spreads.append(np.std(norm) / np.mean(norm))
    return means, variances, float(np.max(spreads))


def _turntable_tilt(a_g, phi, kappa, index, rotation):
    """True up in the turntable-axis frame (t_x, t_y) and its covariance, from the first harmonic of
    gravity seen in the frame turning with the turntable (per-flip constants absorb what is fixed in H)."""
    in_housing = rotation.apply(a_g, inverse=True)
    turning = Rotation.from_euler("x", kappa[:, None]).apply(in_housing)  # Rx(kappa) f_H: gravity in the turning frame
    n = len(phi)
    c, s = np.cos(phi), np.sin(phi)
    design = np.zeros((2 * n, 2 + 8))
    design[:n, 0], design[:n, 1] = c, s
    design[n:, 0], design[n:, 1] = -s, c
    design[np.arange(n), 2 + index] = 1.0
    design[n + np.arange(n), 6 + index] = 1.0
    y = np.concatenate([turning[:, 0], turning[:, 1]])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    resid = y - design @ coef
    noise_var = np.sum(resid**2) / max(len(y) - design.shape[1], 1)
    covariance = noise_var * np.linalg.inv(design.T @ design)[:2, :2]
    return coef[:2], covariance


def _dip_against_gravity(dip_deg, dip_sigma_deg, azimuth_deg, tilt_xy, tilt_cov):
    """Dip against true up from the dip against the turntable axis and the turntable's tilt, degrees."""

    def dip_g(x):
        dip, az, tx, ty = x
        up = np.array([tx, ty, np.sqrt(max(0.0, 1 - tx**2 - ty**2))])
        b = np.array([np.cos(dip) * np.cos(az), np.cos(dip) * np.sin(az), -np.sin(dip)])
        return np.arcsin(np.clip(-b @ up, -1.0, 1.0))

    x = np.array([np.radians(dip_deg), np.radians(azimuth_deg), *tilt_xy])
    value = dip_g(x)
    step = 1e-7
    jac = np.array([(dip_g(x + step * np.eye(4)[j]) - value) / step for j in range(4)])
    cov = np.zeros((4, 4))
    cov[0, 0] = np.radians(dip_sigma_deg) ** 2 if dip_sigma_deg is not None else 0.0
    cov[2:, 2:] = tilt_cov
    return float(np.degrees(value)), float(np.degrees(np.sqrt(jac @ cov @ jac)))


def _warnings(r: AccelerometerAlignment, nominal_angle_deg, dip_sigma_deg) -> tuple:
    out = []
    half_turn_about_x = r.angle_deg > 150.0 and abs(r.rotvec_deg[0]) > 0.95 * r.angle_deg
    if half_turn_about_x:
        out.append(f"the accelerometer reads -1 g along Z in flip 0 (mag_to_accel is a half turn about X, "
                   f"{r.angle_deg:.1f} deg): it reads gravity rather than specific force (then recalibrate with "
                   "--accel-sign -1, and use it at runtime too) or it is mounted upside down about X, or every flip "
                   "is labelled 180 deg off (the cube started with its +Z face down); the flips cannot tell these "
                   "apart, since X never sees gravity")
    elif np.max(nominal_angle_deg) > _NOMINAL_WARN_DEG:
        out.append(f"the accelerometer's gravity is {np.max(nominal_angle_deg):.1f} deg from where the flips put it "
                   "in the housing frame: its axes are not the housing's (names, signs, mounting), which the fitted "
                   "mag_to_accel takes into account, or the flips are mislabelled (flips 90 and 270 exchanged, the "
                   "cube turned the other way about X, is the same data as a chip turned half round about Z), which "
                   "turns every direction and heading: check the flips' labels, then the wiring")
    if r.glitches_dropped:
        out.append(f"{r.glitches_dropped} accelerometer sample(s) left out as glitches (more than {_GLITCH_SIGMAS:g} "
                   "robust sigmas off their turn): knocks or line errors")
    if r.magnitude_spread > _MAGNITUDE_WARN:
        out.append(f"|a| varies by {100 * r.magnitude_spread:.1f} % within a turn: the housing was not at rest "
                   "(vibration, the turntable accelerating) or the accelerometer is noisy; its alignment is less sure")
    worst = float(np.max(np.abs(r.closure) / np.maximum(r.closure_sigma, 1e-300)))
    if worst > _ORTHOGONALITY_SIGMAS and np.max(np.abs(r.closure)) / r.g > np.radians(_ORTHOGONALITY_FLOOR_DEG):
        out.append(f"the accelerometer's offsets differ between the 0/180 and the 90/270 flip pairs by "
                   f"{np.max(np.abs(r.closure)) / r.g:.2g} g ({worst:.0f} noise sigmas): offset drift between flips, "
                   "or flips far from square")
    if (abs(r.orthogonality_deg) > _ORTHOGONALITY_SIGMAS * r.orthogonality_sigma_deg
            and abs(r.orthogonality_deg) > _ORTHOGONALITY_FLOOR_DEG):
        out.append(f"gravity in the 90/270 flips is {r.orthogonality_deg:+.2f} deg off square with the 0/180 flips "
                   f"(+- {r.orthogonality_sigma_deg:.2f} from noise): the accelerometer's axes are not orthogonal or "
                   "the cube's faces are not square (the magnetic diagnosis's flip_error tells which); "
                   "mag_to_accel splits the difference and its sigma is widened to match")
    offset_g = np.linalg.norm(r.offset) / r.g
    if offset_g > _OFFSET_WARN:
        out.append(f"the accelerometer's offsets are {offset_g:.3f} g ({np.degrees(np.arcsin(min(offset_g, 1))):.2f} "
                   "deg of tilt): the runtime does not remove them, so pitch and roll err by up to that much")
    if abs(r.scale_yz[0] / r.scale_yz[1] - 1) > _SCALE_WARN:
        out.append(f"the accelerometer's Y and Z scales differ by {100 * (r.scale_yz[0] / r.scale_yz[1] - 1):+.1f} %: "
                   "uncorrected at runtime, a tilt error of up to about half that in radians")
    if r.dip_gravity_deg is not None:
        shift = r.dip_gravity_deg - r.dip_axis_deg
        if dip_sigma_deg is None or abs(shift) > _TILT_DIP_SIGMAS * max(dip_sigma_deg, 1e-12):
            out.append(f"the turntable is tilted {r.tilt_deg:.3f} +- {r.tilt_sigma_deg:.3f} deg from level (the "
                       f"accelerometer's gravity turns with it): the magnetic fit's dip {r.dip_axis_deg:.3f} deg is "
                       f"against the turntable axis; against gravity it is {r.dip_gravity_deg:.3f} +- "
                       f"{r.dip_gravity_sigma_deg:.3f} deg, the dip this calibration reports")
    return tuple(out)


def describe_accelerometer(block: dict) -> str:
    """Report lines of a calibration file's ``"accelerometer"`` block."""
    rv, sig = block["mag_to_accel_rotvec_deg"], block["mag_to_accel_rotvec_sigma_deg"]
    lines = ["  accelerometer (ax, ay, az) against the housing, from the four flips:",
             "    mag_to_accel rotation vector (" + ", ".join(f"{v:+.3f} +- {s:.3f}" for v, s in zip(rv, sig))
             + f") deg, {block['misalignment_deg']:.3f} deg in all (applied at runtime: pitch and roll of the housing)",
             f"    offsets ({', '.join(f'{v:+.4g}' for v in block['offset'])}), 1 g reads {block['one_g']:.5g}, "
             f"Y/Z scales {block['scale_yz'][0]:.4f}/{block['scale_yz'][1]:.4f}; Y-Z off square "
             f"{block['orthogonality_deg']:+.3f} +- {block['orthogonality_sigma_deg']:.3f} deg",
             f"    turntable tilt from level {block['turntable_tilt_deg']:.3f} +- {block['turntable_tilt_sigma_deg']:.3f} "
             f"deg (up leans toward {block['turntable_tilt_azimuth_deg']:.0f} deg from the turntable zero)"]
    if "dip_gravity_deg" in block:
        lines.append(f"    dip against gravity {block['dip_gravity_deg']:.3f} +- {block['dip_gravity_sigma_deg']:.3f} deg "
                     f"(reported above); the magnetic fit's, against the turntable axis, "
                     f"{block['dip_turntable_axis_deg']:.3f} deg")
    lines.append(f"    not identified: {block['not_identified']}")
    return "\n".join(lines)


def with_accelerometer(result, rec):
    """``result`` with the recording's accelerometer examined: ``mag_to_accel``, the ``accelerometer`` block
    and its warnings, and the dip referred to gravity (SPEC's dip; the magnetic fit's, against the
    turntable axis, stays in the block); unchanged when the recording has no ``ax, ay, az``.

    Parameters
    ----------
    result : FourFlipResult
        The magnetic calibration of ``rec`` (its flip errors, dip and field azimuth are used).
    rec : FourFlipRecording
        The recording as the fit saw it (spikes dropped).
    """
    if rec.accel is None:
        return result
    errors, sigmas = np.zeros(4), np.zeros(4)
    for effect in result.effects:
        if effect["name"] == "flip_error":
            p = [effect["parameters"][f"flip{k}.error_deg"] for k in (90, 180, 270)]
            errors[1:], sigmas[1:] = [e["value"] for e in p], [e["sigma"] for e in p]
    try:
        fit = fit_accelerometer(rec.accel, rec.platform_deg, rec.flip_deg, rec.flip_index, flip_errors_deg=errors,
                                flip_errors_sigma_deg=sigmas,
                                dip_deg=result.dip_deg, dip_sigma_deg=result.dip_sigma_deg,
                                azimuth_deg=result.azimuth_deg)
    except ValueError as exc:
        return replace(result, warnings=result.warnings + (f"accelerometer not used: {exc}",))
    extra = dict(result.extra) | {"mag_to_accel": fit.mag_to_accel.tolist(), "accelerometer": fit.to_json()}
    # SPEC's dip is against gravity (W: Z up against gravity); the magnetic fit's is against the turntable axis
    dip = {} if fit.dip_gravity_deg is None else {
        "dip_deg": fit.dip_gravity_deg,
        "dip_sigma_deg": None if result.dip_sigma_deg is None else fit.dip_gravity_sigma_deg}
    return replace(result, extra=extra, warnings=result.warnings + tuple(f"accelerometer: {w}" for w in fit.warnings),
                   **dip)
