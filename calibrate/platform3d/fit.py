"""The 3-D platform fit (seed 001): :func:`calibrate_platform3d` and :class:`Platform3DCalibrator`."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from compass.io.platform3d import Platform3DRecording
from compass.sim.platform3d import predict, up_in_bench

from ..contract import (Calibrator, CannotCalibrate, FitStatistics, metadata_field_ut, require_response,
                        require_sane_cells)
from ..health import AXIS_TOLERANCE_DEG, ChannelHealth, check_channels
from ..health import to_json as health_json
from ..diagnosis.offsets import (Grouped, OffsetDiagnosis, Problem, SampleGroups, diagnose_offsets,
                                pooled_repeat_noise, same_inputs)
from .result import AXES, MAG_CHANNELS, Platform3DResult, axis_geometry, geometry_names

_MIN_RELATIVE_SINGULAR = 1e-6
"""Smallest singular value of the column-scaled Jacobian, relative to the largest, accepted."""


def _names(tilt_columns) -> list[str]:
    names = [f"M[{c},{a}]" for c in MAG_CHANNELS for a in AXES] + [f"o_m[{c}]" for c in MAG_CHANNELS]
    names += ["field_elevation_rad", "field_azimuth_rad"]
    names += [f"A[{c},{a}]" for c in tilt_columns for a in AXES] + [f"o_t[{c}]" for c in tilt_columns]
    return names + ["base_tilt_x_rad", "base_tilt_y_rad"]


def _unpack(p: np.ndarray, n_tilt: int, field_norm: float):
    m, o_m = p[:9].reshape(3, 3), p[9:12]
    el, az = p[12], p[13]
    b_w = field_norm * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)])
    k = 14 + 3 * n_tilt
    a, o_t = p[14:k].reshape(n_tilt, 3), p[k:k + n_tilt]
    u_w = up_in_bench(np.degrees(p[k + n_tilt:k + n_tilt + 2]))
    return m, o_m, b_w, a, o_t, u_w


def _start(rot: Rotation, mag, tilt, counts, field_norm: float, sign: float) -> np.ndarray:
    """Linear least squares for the sensors on a grid of field directions; best grid point.

    ``rot``, ``mag`` and ``tilt`` are per pose (the means of its ``counts`` samples, weighted by
    ``sqrt(counts)``: the same solutions as every sample's).
    """
    root_n = np.sqrt(counts)[:, None]
    design_t = np.hstack([rot.apply([0.0, 0.0, 1.0], inverse=True) * root_n, root_n])
    sol_t, *_ = np.linalg.lstsq(design_t, tilt * root_n, rcond=None)
    best = None
    for el in np.radians(np.arange(5.0, 86.0, 20.0)) * sign:
        for az in np.radians(np.arange(0.0, 360.0, 30.0)):
            b = field_norm * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)])
            design = np.hstack([rot.apply(b, inverse=True) * root_n, root_n])
            sol, *_ = np.linalg.lstsq(design, mag * root_n, rcond=None)
            rss = float(np.sum((design @ sol - mag * root_n) ** 2))
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

    The model depends on the pose alone, so the fit runs on each pose's mean output weighted by
    the square root of its sample count: the same minimum and ``J^T J`` as every sample's, the
    within-pose scatter a constant of the chi-square (which is that of every sample).  Time and
    memory then grow with the recording only through reading it and its residuals.

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
    # the base model depends on the pose alone: it is fitted to each pose's mean (exact, see Grouped)
    poses = SampleGroups.of(rec.pose)
    rot_g, root_n = rot[poses.first], np.sqrt(poses.counts)[:, None]
    mag_g, tilt_g = poses.mean(rec.mag), poses.mean(rec.tilt)
    p0 = _start(rot_g, mag_g, tilt_g, poses.counts, magnitude, sign)
    noise_mag, noise_tilt = pooled_repeat_noise(rec.mag, rec.pose), pooled_repeat_noise(rec.tilt, rec.pose)

    def residuals(p, w_m, w_t):
        pm, pt = predict(rot_g, *_unpack(p, n_tilt, magnitude))
        return np.concatenate([((pm - mag_g) * root_n / w_m).ravel(), ((pt - tilt_g) * root_n / w_t).ravel()])

    def every_sample(p):
        """Residuals of every sample, output units: magnetometer (n, 3), tilt sensor (n, c)."""
        pm, pt = predict(rot, *_unpack(p, n_tilt, magnitude))
        return rec.mag - pm, rec.tilt - pt

    w_m = noise_mag if noise_mag is not None else np.full(3, np.std(rec.mag) * 1e-3)
    w_t = noise_tilt if noise_tilt is not None else np.full(n_tilt, np.std(rec.tilt) * 1e-3)
    fit = least_squares(residuals, p0, args=(w_m, w_t), x_scale="jac", method="lm")
    if noise_mag is None or noise_tilt is None:  # weights from the first fit's residual rms
        r_m, r_t = every_sample(fit.x)
        w_m = noise_mag if noise_mag is not None else np.sqrt(np.mean(r_m**2, axis=0))
        w_t = noise_tilt if noise_tilt is not None else np.sqrt(np.mean(r_t**2, axis=0))
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
    r_m, r_t = every_sample(fit.x)
    require_response(rec.path, MAG_CHANNELS + tuple(rec.tilt_columns), np.hstack([rec.mag, rec.tilt]),
                     np.hstack([r_m, r_t]), rec.rows)
    x, delta, diagnosis = fit.x, np.zeros_like(rec.mag), None
    chi2 = float(np.sum((r_m / w_m) ** 2) + np.sum((r_t / w_t) ** 2))
    if diagnose:
        diagnosis = _diagnose(rec, rot, fit.x, n_tilt, magnitude, w_m, w_t, noise_mag is not None,
                              ("offset_drift", "temperature", "gain_drift", "nonlinear_response") if candidates is None
                              else candidates)
        if diagnosis.effects:
            x, jac, delta = diagnosis.x, diagnosis.jac, diagnosis.delta
            names = names + diagnosis.names
            m, o_m, b_w, a, o_t, u_w = _unpack(x, n_tilt, magnitude)
            pm, pt = predict(rot, m, o_m, b_w, a, o_t, u_w)
            chi2 = float(np.sum(((rec.mag - pm - delta) / w_m) ** 2) + np.sum(((pt - rec.tilt) / w_t) ** 2))
    n_obs, k = rec.mag.size + rec.tilt.size, len(x)
    dof = n_obs - k
    cov = np.linalg.inv(jac.T @ jac) * chi2 / max(dof, 1)

    m, o_m, b_w, a, o_t, u_w = _unpack(x, n_tilt, magnitude)
    pm, pt = predict(rot, m, o_m, b_w, a, o_t, u_w)
    pm = pm + delta
    i_base_tilt = 14 + 4 * n_tilt
    geo_names = geometry_names("mag", MAG_CHANNELS) + geometry_names("tilt", rec.tilt_columns)
    derived_names = geo_names + [f"mag_to_tilt_rotvec_{x}_deg" for x in AXES] + [
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
    statistics = FitStatistics(tuple(names), x, cov, chi2, dof, chi2 + k * np.log(n_obs), bool(fit.success),
                               str(fit.message))
    return Platform3DResult(
        statistics=statistics, mag_matrix=m, mag_offset=o_m, tilt_matrix=a,
        tilt_offset=o_t, tilt_columns=rec.tilt_columns, field_w=b_w, up_w=u_w, derived=derived_table,
        mag_direction_covariance=np.array(dir_cov), mag_response_sigma=np.array(resp_sig),
        residuals_mag=rec.mag - pm, residuals_tilt=rec.tilt - pt, noise_mag=noise_mag, noise_tilt=noise_tilt,
        field_ut=field_ut, warnings=tuple(warnings), diagnosis=diagnosis)


def _diagnose(rec: Platform3DRecording, rot: Rotation, p: np.ndarray, n_tilt: int, magnitude: float, w_m, w_t,
              from_repeats: bool, candidates) -> OffsetDiagnosis:
    """The residual diagnosis of the magnetometer channels, the tilt sensor kept in the joint fit.

    Its fits run on the means of samples with the same pose and ``temp_c`` at (nearly) the same
    ``t_s`` when there are such repeats (:class:`calibrate.diagnosis.offsets.Grouped`).
    """

    def model(rotation, mag, tilt, root_n=1.0):
        def linear(x):
            return predict(rotation, *_unpack(x, n_tilt, magnitude))[0] - x[9:12]

        def residuals(x, delta):
            pm, pt = predict(rotation, *_unpack(x, n_tilt, magnitude))
            return mag - pm - delta, ((pt - tilt) * root_n / w_t).ravel()

        return linear, residuals

    same = same_inputs(rec.pose, rec.t_s, rec.temp_c)
    grouped = None
    if len(same.counts) < len(rec.pose):
        grouped = Grouped(*model(rot[same.first], same.mean(rec.mag), same.mean(rec.tilt),
                                 np.sqrt(same.counts)[:, None]), same.counts, same.mean(rec.t_s), same.mean(rec.temp_c))
    problem = Problem(MAG_CHANNELS, p, *model(rot, rec.mag, rec.tilt), np.asarray(w_m, float), from_repeats,
                      rec.pose, k_channels=14, offset_index=np.arange(9, 12), grouped=grouped)
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
    plot_files = ("platform_residuals.png",)

    def __init__(self, *, field_ut: float | None = None, diagnose: bool = True,
                 axis_tolerance_deg: float | None = AXIS_TOLERANCE_DEG, direction_accuracy_deg: float | None = None):
        self.field_ut, self.diagnose = field_ut, diagnose
        self.axis_tolerance_deg, self.direction_accuracy_deg = axis_tolerance_deg, direction_accuracy_deg

    def fit(self, recording: Platform3DRecording) -> Platform3DResult:
        result = calibrate_platform3d(recording, field_ut=self.field_ut, diagnose=self.diagnose)
        health = channel_health(result)
        warnings = check_channels(recording.path, health, axis_tolerance_deg=self.axis_tolerance_deg,
                                  direction_accuracy_deg=self.direction_accuracy_deg)
        return replace(result, warnings=result.warnings + warnings, health=health_json(health))


def channel_health(result: Platform3DResult) -> list[ChannelHealth]:
    """Each magnetometer channel's response to the whole field (the row of ``M`` times |B|), its noise
    (repeated samples' spread, else the residual's) and its sensing direction in H (:mod:`calibrate.health`)."""
    from compass.frames import direction_sigma_deg

    field = float(np.linalg.norm(result.field_w))
    noise = result.noise_mag if result.noise_mag is not None else np.sqrt(np.mean(result.residuals_mag**2, axis=0))
    out = []
    for c, name in enumerate(MAG_CHANNELS):
        gain = float(np.linalg.norm(result.mag_matrix[c]))
        out.append(ChannelHealth(name, gain * field, float(result.mag_response_sigma[c][1]) * field, float(noise[c]),
                                 result.mag_matrix[c] / gain,
                                 float(direction_sigma_deg(result.mag_direction_covariance[c]))))
    return out
