"""Seed 001: the 3-D platform method, a joint fit of magnetometer, tilt sensor and local field.

A non-magnetic platform turns the housing about three axes through known angles
(:mod:`compass.io.platform3d`), so the housing's attitude in the bench frame W, ``R_i = R_W<-H``,
is known for every sample.  The magnetometer and the tilt sensor then see known rotations of two
fixed vectors, the field ``b_W`` and the up direction ``u_W``:

.. math::

    m_i = M R_i^T b_W + o_m, \\qquad t_i = A R_i^T u_W + o_t

(:func:`compass.sim.platform3d.predict`).  One ``scipy.optimize.least_squares`` fit estimates

- ``M`` (3x3) and ``o_m``: row ``c`` of ``M`` is the channel's gain times its unit sensing
  direction in H, so ``M`` holds the three scales, the three non-orthogonality angles and the
  rotation of the magnetometer's axes relative to the housing (9 numbers);
- ``A`` (2x3 or 3x3) and ``o_t``: the same for the tilt sensor (two-axis: 2 scales, 1
  non-orthogonality angle, a 3-D rotation);
- the field direction in W: elevation and azimuth ``delta`` from the platform's zero;
- the base's level error: ``u_W = Rot([tx, ty, 0]) z``.

Reported from these, each with its standard error (Jacobian, scaled by the residual): scales,
angles between axes minus 90 degrees (non-orthogonality), the rotation of each sensor's
orthonormalised frame relative to H (the polar factor of its unit-axis matrix, no axis
privileged), the rotation taking magnetometer-frame vectors into the tilt sensor's frame, the dip
about the true vertical, and |B|.

Identifiability (gauge freedoms), and how each is fixed:

- |B| versus the magnetometer gains: only their product is seen.  ``|b_W|`` is fixed to the known
  ``field_ut`` (gains per uT) or to 1 (gains per |B|); ``field_norm_recording_units`` reports
  |B| in output units for a sensor whose gains are 1 (e.g. one that already reads uT).
- ``(M, b_W)`` versus ``(-M, -b_W)``: the same data.  The field is taken pointing down (northern
  hemisphere) unless the metadata's ``site_lat_deg`` is negative, as for the four-flip bench.
- Field azimuth versus the platform's yaw zero: the platform's ``z`` zero is arbitrary; ``delta``
  is the field's azimuth from it, a nuisance parameter.  Heading at runtime is from magnetic north.
- The housing frame is the platform's inner frame (the seed presses the housing's edges on the
  platform's axes); a housing seated askew turns both sensors' rotations alike and leaves
  ``mag_to_tilt`` unchanged.  Gravity only fixes two of its three angles, so without the platform
  angles a housing rotation could not be told from sensor misalignment: the platform provides it.
- The base level error is separable from the tilt sensor's axes only when the platform turns about
  the vertical too (``platform_z_deg`` varies).
- The poses must turn both vectors through three dimensions of H: a platform that only turns about
  the vertical leaves each sensor's vertical response inseparable from its offset.  The fit checks
  the scaled Jacobian's singular values and refuses (:class:`~calibrate.contract.CannotCalibrate`) naming the
  parameters the poses leave undetermined.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from compass.calibration_file import channel_entry, header
from compass.io.platform3d import Platform3DRecording
from compass.sim.platform3d import predict, up_in_bench

from .contract import (Calibration, Calibrator, CannotCalibrate, metadata_field_ut, require_response,
                       require_sane_cells)
from .diagnosis.offsets import (OffsetDiagnosis, Problem, diagnose_offsets,
                              pooled_repeat_noise)

__all__ = ["Platform3DCalibrator", "Platform3DResult", "calibrate_platform3d", "axis_geometry"]

MAG_CHANNELS = ("mx", "my", "mz")
_AXES = "xyz"
_MIN_RELATIVE_SINGULAR = 1e-6
"""Smallest singular value of the column-scaled Jacobian, relative to the largest, accepted."""


def axis_geometry(matrix: np.ndarray) -> np.ndarray:
    """Scales, non-orthogonality and rotation of a sensor's axes, flattened.

    Parameters
    ----------
    matrix : ndarray, shape (c, 3)
        Rows: scale times unit sensing direction in H (c = 2 or 3).

    Returns
    -------
    ndarray
        ``c`` scales (row norms); the angles between axis pairs minus 90 degrees (3 for three
        axes, 1 for two: (x, y), (x, z), (y, z)); the rotation vector (degrees) of the rotation
        ``Q`` nearest the unit axes (``v_sensor = Q v_H``; the third axis of a two-axis sensor is
        the normal of the first two).
    """
    k = np.linalg.norm(matrix, axis=1)
    u = matrix / k[:, None]
    pairs = [(0, 1), (0, 2), (1, 2)] if len(u) == 3 else [(0, 1)]
    nonorth = [np.degrees(np.arccos(np.clip(u[i] @ u[j], -1, 1))) - 90.0 for i, j in pairs]
    full = u if len(u) == 3 else np.vstack([u, np.cross(u[0], u[1]) / np.linalg.norm(np.cross(u[0], u[1]))])
    w, _, vt = np.linalg.svd(full)
    q = w @ vt
    if np.linalg.det(q) < 0:
        q = w @ np.diag([1.0, 1.0, -1.0]) @ vt
    return np.concatenate([k, nonorth, Rotation.from_matrix(q).as_rotvec(degrees=True)])


def _geometry_names(prefix: str, columns) -> list[str]:
    pairs = [(0, 1), (0, 2), (1, 2)] if len(columns) == 3 else [(0, 1)]
    return ([f"{prefix}_scale_{c}" for c in columns]
            + [f"{prefix}_nonorthogonality_{columns[i]}_{columns[j]}_deg" for i, j in pairs]
            + [f"{prefix}_rotvec_{a}_deg" for a in _AXES])


@dataclass(frozen=True)
class Platform3DResult(Calibration):
    """A 3-D platform calibration (seed 001) with its statistics.

    Attributes
    ----------
    names : tuple of str
        Fitted parameters: ``M[c,j]``, ``o_m[c]``, ``field_elevation_rad``, ``field_azimuth_rad``,
        ``A[c,j]``, ``o_t[c]``, ``base_tilt_x_rad``, ``base_tilt_y_rad``.
    values : ndarray, shape (p,)
    covariance : ndarray, shape (p, p)
        Scaled by the residual (reduced chi-square of the noise-weighted fit).
    mag_matrix : ndarray, shape (3, 3)
        ``M``: output units per field unit (uT when ``field_ut`` is known, else per |B|), H frame.
    mag_offset : ndarray, shape (3,)
    tilt_matrix : ndarray, shape (c, 3)
        ``A``: output units per g, H frame.
    tilt_offset : ndarray, shape (c,)
    tilt_columns : tuple of str
    field_w : ndarray, shape (3,)
        The field in W, field units.
    up_w : ndarray, shape (3,)
        The true up direction in W.
    derived : dict
        Name -> (value, sigma): scales, non-orthogonality and rotation of both sensors,
        ``mag_to_tilt_rotvec_*_deg``, ``dip_deg``, ``field_azimuth_deg``, ``base_tilt_*_deg``,
        ``field_norm_recording_units``.
    mag_direction_covariance : ndarray, shape (3, 3, 3)
        Covariance of each magnetometer sensing direction (rad^2).
    mag_response_sigma : ndarray, shape (3, 2)
        Standard errors of each magnetometer channel's (offset, gain).
    residuals_mag : ndarray, shape (n, 3)
    residuals_tilt : ndarray, shape (n, c)
        Measured minus predicted, output units.
    noise_mag, noise_tilt : ndarray or None
        White noise from the spread of repeated samples at one pose; None without repeats.
    field_ut : float or None
    chi2 : float
        Of the noise-weighted residuals.
    dof : int
    bic : float
    success : bool
    message : str
    warnings : tuple of str
    diagnosis : OffsetDiagnosis or None
        The residual diagnosis of the magnetometer (:mod:`calibrate.diagnosis.offsets`); None when
        not run.  With claimed effects, ``values`` end with their parameters, ``mag_offset`` is
        the offset at their reference (the first sample's ``t_s``, the mean ``temp_c``) and the
        residuals are those of the model with them.
    """

    names: tuple
    values: np.ndarray
    covariance: np.ndarray
    mag_matrix: np.ndarray
    mag_offset: np.ndarray
    tilt_matrix: np.ndarray
    tilt_offset: np.ndarray
    tilt_columns: tuple
    field_w: np.ndarray
    up_w: np.ndarray
    derived: dict
    mag_direction_covariance: np.ndarray
    mag_response_sigma: np.ndarray
    residuals_mag: np.ndarray
    residuals_tilt: np.ndarray
    noise_mag: np.ndarray | None
    noise_tilt: np.ndarray | None
    field_ut: float | None
    chi2: float
    dof: int
    bic: float
    success: bool
    message: str
    warnings: tuple = field(default_factory=tuple)
    diagnosis: OffsetDiagnosis | None = None

    calibration_kind = "platform3d"

    @property
    def parameters(self) -> dict:
        """The derived parameters (scales, non-orthogonality, rotations, dip, ...): name -> (value, sigma)."""
        return dict(self.derived)

    @property
    def sigma(self) -> np.ndarray:
        """Standard errors of :attr:`values`."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def dip_deg(self) -> float:
        return self.derived["dip_deg"][0]

    def to_json(self) -> dict:
        """The calibration file (SPEC section 2, channel form for the magnetometer), JSON-ready.

        Extra keys: ``tilt_sensor`` (read by :class:`compass.io.platform3d.TiltSensor`),
        ``misalignment`` and ``platform3d`` (every parameter with its sigma).
        """
        field_range = np.linalg.norm(self.field_w)
        channels = {}
        for c, name in enumerate(MAG_CHANNELS):
            gain = float(np.linalg.norm(self.mag_matrix[c]))
            response = {"model": "linear", "offset": float(self.mag_offset[c]), "gain": gain,
                        "range": [-float(field_range), float(field_range)]}
            channels[name] = channel_entry(self.mag_matrix[c] / gain, response,
                                           covariance=self.mag_direction_covariance[c],
                                           response_sigma=self.mag_response_sigma[c])
        noise = self.noise_mag if self.noise_mag is not None else np.sqrt(np.mean(self.residuals_mag**2, axis=0))
        rms = float(np.sqrt(np.mean(self.residuals_mag**2)))
        if self.diagnosis is not None:
            effects, diagnosis = list(self.diagnosis.effects), self.diagnosis.block
        else:
            effects = []
            diagnosis = {"noise_floor": float(np.mean(noise)), "steps": [{"model": "base", "residual_rms": rms}],
                         "effects": [], "residual_rms_before": rms, "residual_rms_after": rms,
                         "unexplained": None if self.noise_mag is None else bool(rms > 1.5 * np.mean(noise)),
                         "not_applicable": {"diagnosis": "not run (calibrate_platform3d(..., diagnose=False))"}}
        d = self.derived
        return header("platform3d") | {
            "channels": channels,
            "dip_deg": d["dip_deg"][0],
            "dip_sigma_deg": d["dip_deg"][1],
            "field_ut": self.field_ut,
            "noise_floor": [float(v) for v in noise],
            "effects": effects,
            "diagnosis": diagnosis,
            "method": "platform3d",
            "field_azimuth_deg": d["field_azimuth_deg"][0],
            "tilt_sensor": {
                "columns": list(self.tilt_columns),
                "matrix": self.tilt_matrix.tolist(),
                "offset": self.tilt_offset.tolist(),
                "unit": "output units per g (specific force, +1 g up at rest), housing frame H",
                "noise_floor": None if self.noise_tilt is None else self.noise_tilt.tolist(),
            },
            "misalignment": {k: list(d[f"{k}_{a}_deg"] for a in _AXES) for k in
                             ("mag_rotvec", "tilt_rotvec", "mag_to_tilt_rotvec")},
            "platform3d": {"parameters": {k: {"value": v, "sigma": s} for k, (v, s) in d.items()},
                           "fit": {"chi2": self.chi2, "dof": self.dof, "bic": self.bic, "success": self.success,
                                   "message": self.message}},
            "warnings": list(self.warnings),
        }

    def report(self) -> str:
        """A fit report for a person: values +- sigma, strong correlations, warnings in words."""
        unit = "uT" if self.field_ut else "|B|"
        d = self.derived
        lines = [f"3-D platform calibration (seed 001): {len(self.residuals_mag)} samples, "
                 f"tilt sensor {', '.join(self.tilt_columns)}; magnetometer gains per {unit}, tilt per g"]

        def row(label, keys, fmt=".4f"):
            parts = []
            for key in keys:
                short = key.rsplit("_", 2)[-2] if key.endswith("_deg") and len(keys) > 1 else key.split("_")[-1]
                parts.append((f"{short} " if len(keys) > 1 else "") + f"{d[key][0]:{fmt}} +- {d[key][1]:.2g}")
            lines.append(f"  {label}: " + ", ".join(parts))

        for prefix, cols in (("mag", MAG_CHANNELS), ("tilt", self.tilt_columns)):
            keys = _geometry_names(prefix, cols)
            n_pair = 3 if len(cols) == 3 else 1
            row(f"{prefix} scales", keys[:len(cols)], ".6g")
            pairs = keys[len(cols):len(cols) + n_pair]
            lines.append(f"  {prefix} non-orthogonality (angle between axes - 90 deg): " + ", ".join(
                f"{'/'.join(k.split('_')[2:4])} {d[k][0]:+.4f} +- {d[k][1]:.2g}" for k in pairs))
            row(f"{prefix} rotation vector from H (deg)", keys[-3:])
        row("mag-to-tilt rotation vector (deg)", [f"mag_to_tilt_rotvec_{a}_deg" for a in _AXES])
        lines.append("  magnetometer offsets " + ", ".join(f"{v:.6g}" for v in self.mag_offset)
                     + "; tilt offsets " + ", ".join(f"{v:.6g}" for v in self.tilt_offset))
        row("dip (deg)", ["dip_deg"])
        row("field azimuth from the platform zero (deg)", ["field_azimuth_deg"])
        row("base level error (deg)", ["base_tilt_x_deg", "base_tilt_y_deg"])
        row("|B| in output units at unit gain", ["field_norm_recording_units"], ".6g")
        for label, res, noise in (("magnetometer", self.residuals_mag, self.noise_mag),
                                  ("tilt sensor", self.residuals_tilt, self.noise_tilt)):
            rms = np.sqrt(np.mean(res**2, axis=0))
            lines.append(f"  {label} residual rms " + ", ".join(f"{v:.3g}" for v in rms)
                         + ("" if noise is None else " (noise from repeats " + ", ".join(f"{v:.3g}" for v in noise) + ")"))
        lines.append(f"  chi2/dof {self.chi2 / max(self.dof, 1):.3f} ({self.dof} dof)")
        sig = self.sigma
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = self.covariance / np.outer(sig, sig)
        strong = [(self.names[i], self.names[j], corr[i, j]) for i in range(len(sig)) for j in range(i)
                  if abs(corr[i, j]) > 0.9]
        if strong:
            lines.append("  correlations above 0.9: " + "; ".join(f"{a}/{b} {c:+.2f}" for a, b, c in strong))
        if self.diagnosis is not None:
            lines.append(self.diagnosis.format("magnetometer output units"))
        for w in self.warnings:
            lines.append(f"  warning: {w}")
        return "\n".join(lines)


def _names(tilt_columns) -> list[str]:
    names = [f"M[{c},{a}]" for c in MAG_CHANNELS for a in _AXES] + [f"o_m[{c}]" for c in MAG_CHANNELS]
    names += ["field_elevation_rad", "field_azimuth_rad"]
    names += [f"A[{c},{a}]" for c in tilt_columns for a in _AXES] + [f"o_t[{c}]" for c in tilt_columns]
    return names + ["base_tilt_x_rad", "base_tilt_y_rad"]


def _unpack(p: np.ndarray, n_tilt: int, field_magnitude: float):
    m, o_m = p[:9].reshape(3, 3), p[9:12]
    el, az = p[12], p[13]
    b_w = field_magnitude * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)])
    k = 14 + 3 * n_tilt
    a, o_t = p[14:k].reshape(n_tilt, 3), p[k:k + n_tilt]
    u_w = up_in_bench(np.degrees(p[k + n_tilt:k + n_tilt + 2]))
    return m, o_m, b_w, a, o_t, u_w


def _start(rot: Rotation, mag, tilt, field_magnitude: float, sign: float) -> np.ndarray:
    """Linear least squares for the sensors on a grid of field directions; best grid point."""
    ones = np.ones((len(mag), 1))
    design_t = np.hstack([rot.apply([0.0, 0.0, 1.0], inverse=True), ones])
    sol_t, *_ = np.linalg.lstsq(design_t, tilt, rcond=None)
    best = None
    for el in np.radians(np.arange(5.0, 86.0, 20.0)) * sign:
        for az in np.radians(np.arange(0.0, 360.0, 30.0)):
            b = field_magnitude * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)])
            design = np.hstack([rot.apply(b, inverse=True), ones])
            sol, *_ = np.linalg.lstsq(design, mag, rcond=None)
            rss = float(np.sum((design @ sol - mag) ** 2))
            if best is None or rss < best[0]:
                best = (rss, sol, el, az)
    _, sol, el, az = best
    return np.concatenate([sol[:3].T.ravel(), sol[3], [el, az], sol_t[:3].T.ravel(), sol_t[3], [0.0, 0.0]])


def _pose_hint(rot: Rotation) -> str:
    """Why the poses may fail, in words (empty when they look rich enough)."""
    up_h = rot.apply([0.0, 0.0, 1.0], inverse=True)
    span = np.linalg.svd(np.hstack([up_h, np.ones((len(up_h), 1))]), compute_uv=False)
    if span[-1] < 1e-6 * span[0]:
        return ("the platform never tilted the housing out of one plane (the vertical in H stays on a cone or a "
                "circle), so each sensor's response along the missing direction cannot be told from its offset: "
                "record poses with platform_y_deg and platform_x_deg varied")
    return ""


def calibrate_platform3d(rec: Platform3DRecording, *, field_ut: float | None = None, diagnose: bool = True,
                         candidates=None) -> Platform3DResult:
    """Joint fit of magnetometer, tilt sensor, field and base level from a 3-D platform recording.

    Parameters
    ----------
    rec : Platform3DRecording
    field_ut : float, optional
        Known |B| (gains then per uT); default: the metadata's ``field_ut``, else gains per |B|.
    diagnose : bool
        Run the residual diagnosis of the magnetometer (SPEC section 4,
        :func:`calibrate.diagnosis.offsets.diagnose_offsets`) and keep the effects it claims.
    candidates : sequence of str, optional
        Effects the diagnosis considers (default ``offset_drift``, ``temperature``,
        ``nonlinear_response``); ``offset_drift`` needs a ``t_s`` column, ``temperature`` a ``temp_c`` one.

    Returns
    -------
    Platform3DResult

    Raises
    ------
    CannotCalibrate
        The poses leave parameters undetermined (the message names them and says which poses
        are missing), a channel does not follow the field (constant, or a cell far off; the
        message names the column), or the ``field_ut`` metadata is not a positive number.
    ValueError
        ``field_ut`` not positive.

    Notes
    -----
    Residuals are weighted per sensor channel by the noise: the spread of repeated samples at
    one pose when the recording has repeats, else the residual rms of a first fit.  The
    covariance is ``(J^T J)^-1 chi2 / dof`` of the weighted fit; derived quantities get theirs by
    propagation through a numerical Jacobian.  The BIC is ``chi2 + p ln(N)`` on the weighted
    residuals.

    The diagnosis works on the magnetometer: its noise floor is the pose-to-pose repeat scatter
    (without repeats, the first fit's residual, and ``unexplained`` is then null); the platform
    sets each channel's linear response, so an odd cubic response is identifiable beside the
    gains.  Claimed effects join the joint fit (their parameters follow the base ones in
    ``values``) and the reported offsets hold at their reference time and temperature.
    """
    if field_ut is None:
        field_ut = metadata_field_ut(rec.path, rec.metadata)
    if field_ut is not None and not field_ut > 0:
        raise ValueError(f"field_ut must be positive, got {field_ut}")
    magnitude = field_ut or 1.0
    require_sane_cells(rec.path, MAG_CHANNELS + tuple(rec.tilt_columns), np.hstack([rec.mag, rec.tilt]), rec.rows)
    lat = rec.metadata.get("site_lat_deg")
    sign = -1.0 if lat is not None and float(lat) < 0 else 1.0
    rot = rec.rotation
    n_tilt = rec.tilt.shape[1]
    names = _names(rec.tilt_columns)
    p0 = _start(rot, rec.mag, rec.tilt, magnitude, sign)
    noise_mag, noise_tilt = pooled_repeat_noise(rec.mag, rec.pose), pooled_repeat_noise(rec.tilt, rec.pose)

    def residuals(p, w_m, w_t):
        m, o_m, b_w, a, o_t, u_w = _unpack(p, n_tilt, magnitude)
        pm, pt = predict(rot, m, o_m, b_w, a, o_t, u_w)
        return np.concatenate([((pm - rec.mag) / w_m).ravel(), ((pt - rec.tilt) / w_t).ravel()])

    w_m = noise_mag if noise_mag is not None else np.full(3, np.std(rec.mag) * 1e-3)
    w_t = noise_tilt if noise_tilt is not None else np.full(n_tilt, np.std(rec.tilt) * 1e-3)
    fit = least_squares(residuals, p0, args=(w_m, w_t), x_scale="jac", method="lm")
    if noise_mag is None or noise_tilt is None:  # weights from the first fit's residual rms
        m, o_m, b_w, a, o_t, u_w = _unpack(fit.x, n_tilt, magnitude)
        pm, pt = predict(rot, m, o_m, b_w, a, o_t, u_w)
        w_m = noise_mag if noise_mag is not None else np.sqrt(np.mean((pm - rec.mag) ** 2, axis=0))
        w_t = noise_tilt if noise_tilt is not None else np.sqrt(np.mean((pt - rec.tilt) ** 2, axis=0))
        fit = least_squares(residuals, fit.x, args=(w_m, w_t), x_scale="jac", method="lm")

    jac = fit.jac
    col = np.linalg.norm(jac, axis=0)
    col[col == 0] = 1.0
    scaled = jac / col
    eig, vec = np.linalg.eigh(scaled.T @ scaled)  # singular values squared, ascending
    if eig[0] < _MIN_RELATIVE_SINGULAR**2 * eig[-1]:
        null = vec[:, 0]
        involved = [names[j] for j in np.argsort(-np.abs(null)) if abs(null[j]) > 0.2]
        hint = _pose_hint(rot)
        raise CannotCalibrate(f"{rec.path}: the platform poses do not determine {', '.join(involved)}"
                              + (f": {hint}" if hint else " (they trade off against each other)"))
    pm, pt = predict(rot, *_unpack(fit.x, n_tilt, magnitude))
    require_response(rec.path, MAG_CHANNELS + tuple(rec.tilt_columns), np.hstack([rec.mag, rec.tilt]),
                     np.hstack([rec.mag - pm, rec.tilt - pt]), rec.rows)
    x, delta, diagnosis = fit.x, np.zeros_like(rec.mag), None
    chi2 = float(np.sum(fit.fun**2))
    if diagnose:
        diagnosis = _diagnose(rec, fit.x, n_tilt, magnitude, w_m, w_t, noise_mag is not None,
                              ("offset_drift", "temperature", "nonlinear_response") if candidates is None else candidates)
        if diagnosis.effects:
            x, jac, delta = diagnosis.x, diagnosis.jac, diagnosis.delta
            names = names + diagnosis.names
            m, o_m, b_w, a, o_t, u_w = _unpack(x, n_tilt, magnitude)
            pm, pt = predict(rot, m, o_m, b_w, a, o_t, u_w)
            chi2 = float(np.sum(((rec.mag - pm - delta) / w_m) ** 2) + np.sum(((pt - rec.tilt) / w_t) ** 2))
    n_obs, k = len(fit.fun), len(x)
    dof = n_obs - k
    cov = np.linalg.inv(jac.T @ jac) * chi2 / max(dof, 1)

    m, o_m, b_w, a, o_t, u_w = _unpack(x, n_tilt, magnitude)
    pm, pt = predict(rot, m, o_m, b_w, a, o_t, u_w)
    pm = pm + delta
    i_base_tilt = 14 + 4 * n_tilt
    geo_names = _geometry_names("mag", MAG_CHANNELS) + _geometry_names("tilt", rec.tilt_columns)
    derived_names = geo_names + [f"mag_to_tilt_rotvec_{x}_deg" for x in _AXES] + [
        "dip_deg", "field_azimuth_deg", "base_tilt_x_deg", "base_tilt_y_deg", "field_norm_recording_units"]

    def derived(p):
        mm, _, bw, aa, _, uw = _unpack(p, n_tilt, magnitude)
        gm, gt = axis_geometry(mm), axis_geometry(aa)
        q = Rotation.from_rotvec(gt[-3:], degrees=True) * Rotation.from_rotvec(gm[-3:], degrees=True).inv()
        bhat = bw / np.linalg.norm(bw)
        dip = np.degrees(np.arcsin(np.clip(-bhat @ uw, -1.0, 1.0)))
        extra = [dip, np.degrees(p[13]), np.degrees(p[i_base_tilt]), np.degrees(p[i_base_tilt + 1]),
                 np.mean(np.linalg.norm(mm, axis=1)) * magnitude]
        return np.concatenate([gm, gt, q.as_rotvec(degrees=True), extra])

    values, dcov = _propagate(derived, x, cov)
    dsig = np.sqrt(np.clip(np.diag(dcov), 0.0, None))
    derived_table = {name: (float(v), float(s_)) for name, v, s_ in zip(derived_names, values, dsig)}
    derived_table["field_azimuth_deg"] = (float(np.mod(values[derived_names.index("field_azimuth_deg")], 360.0)),
                                          derived_table["field_azimuth_deg"][1])

    dir_cov, resp_sig = [], []
    for c in range(3):
        def channel(p, c=c):
            row = p[3 * c:3 * c + 3]
            return np.concatenate([row / np.linalg.norm(row), [p[9 + c], np.linalg.norm(row)]])

        _, ccov = _propagate(channel, x, cov)
        dir_cov.append(ccov[:3, :3])
        resp_sig.append(np.sqrt(np.clip(np.diag(ccov)[3:], 0.0, None)))

    warnings = []
    if not fit.success:
        warnings.append(f"the least-squares fit did not converge: {fit.message}")
    if noise_mag is None:
        warnings.append("no pose was recorded twice: the noise is taken from the residual, so a model error would "
                        "go unnoticed (record several samples per pose)")
    if chi2 / max(dof, 1) > 2.0 and noise_mag is not None:
        warnings.append(f"residuals are {np.sqrt(chi2 / max(dof, 1)):.1f} times the noise seen in repeated samples: "
                        "the linear model misses something (nonlinear response, a magnetised platform part, "
                        "platform angle errors); uncertainties are scaled up accordingly")
    return Platform3DResult(
        names=tuple(names), values=x, covariance=cov, mag_matrix=m, mag_offset=o_m, tilt_matrix=a,
        tilt_offset=o_t, tilt_columns=rec.tilt_columns, field_w=b_w, up_w=u_w, derived=derived_table,
        mag_direction_covariance=np.array(dir_cov), mag_response_sigma=np.array(resp_sig),
        residuals_mag=rec.mag - pm, residuals_tilt=rec.tilt - pt, noise_mag=noise_mag, noise_tilt=noise_tilt,
        field_ut=field_ut, chi2=chi2, dof=dof, bic=chi2 + k * np.log(n_obs), success=bool(fit.success),
        message=str(fit.message), warnings=tuple(warnings), diagnosis=diagnosis)


def _diagnose(rec: Platform3DRecording, p: np.ndarray, n_tilt: int, magnitude: float, w_m, w_t,
              from_repeats: bool, candidates) -> OffsetDiagnosis:
    """The residual diagnosis of the magnetometer channels, the tilt sensor kept in the joint fit."""
    rot = rec.rotation

    def predicted(x):
        return predict(rot, *_unpack(x, n_tilt, magnitude))

    def linear(x):
        return predicted(x)[0] - x[9:12]

    def residuals(x, delta):
        pm, pt = predicted(x)
        return rec.mag - pm - delta, ((pt - rec.tilt) / w_t).ravel()

    problem = Problem(MAG_CHANNELS, p, linear, residuals, np.asarray(w_m, float), from_repeats, rec.pose,
                      k_channels=14, offset_index=np.arange(9, 12))
    return diagnose_offsets(problem, t_s=rec.t_s, temp_c=rec.temp_c, candidates=candidates)


def _propagate(f, p: np.ndarray, cov: np.ndarray, step: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """``f(p)`` and its covariance ``D cov D^T`` (central differences, steps relative to sqrt(diag cov))."""
    base = f(p)
    scale = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    scale = np.where(scale > 0, scale, 1e-6)
    jac = np.empty((len(base), len(p)))
    for j in range(len(p)):
        h = np.zeros_like(p)
        h[j] = 1e-3 * scale[j] + step
        jac[:, j] = (f(p + h) - f(p - h)) / (2 * h[j])
    return base, jac @ cov @ jac.T


class Platform3DCalibrator(Calibrator):
    """Seed 001's 3-D platform calibration of magnetometer and tilt sensor (:func:`calibrate_platform3d`).

    Parameters
    ----------
    field_ut : float, optional
        Known |B| (gains then per uT); default the recording's ``# field_ut:`` metadata.
    diagnose : bool
        Run the residual diagnosis (SPEC section 4).
    """

    kind = "platform3d"

    def __init__(self, *, field_ut: float | None = None, diagnose: bool = True):
        self.field_ut, self.diagnose = field_ut, diagnose

    def fit(self, recording: Platform3DRecording) -> Platform3DResult:
        return calibrate_platform3d(recording, field_ut=self.field_ut, diagnose=self.diagnose)
