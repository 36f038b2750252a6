"""Four-flip calibration of single-axis magnetic channels (seed 000).

Three estimators, one result type:

- ``patent``: the seed as written.  Output minima are the lowest samples; theta, gamma,
  elevation, psi by claims 3-4; the dip from the first midpoint crossing after the flip-0
  minimum (claim 5); the response as the tabulated ``f(beta)`` (claims 6-7).  Two corrections
  of the text: the seed's ``beta`` drops a sign (its ``cos(beta)`` is ``-B.a/|B|``), and the
  midpoint value it assumes known is estimated from the 0/180 flip means.  For a channel whose
  flip-0 curve is flat (near Z) the table is taken from the flip with the largest swing.
- ``harmonic``: the same formulas with each minimum and crossing located by a least-squares
  first-harmonic fit of the whole turn.
- ``ml`` (default): the joint maximum-likelihood fit of :mod:`calibrate.fourflip._mlfit`, started from
  the singularity-free vector combination of the harmonics, with standard errors.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import isotonic_regression
from scipy.spatial.transform import Rotation

from compass.frames import seed_angles
from compass.io.fourflip import FourFlipRecording
from compass.iron_uncertainty import CURVE_FIELDS
from compass.model import MIN_SINGULAR_VALUE
from compass.response import CubicResponse, LinearResponse, TableResponse
from compass.sim.bench import BenchPhysics, BenchSamples, bench_outputs, housing_field

from . import _harmonic as hm
from .accelerometer import with_accelerometer
from ._mlfit import MLFit, fit_ml
from ._phases import flip_azimuths, zero_off_words
from ..contract import Calibrator, CannotCalibrate, FitStatistics
from ..health import AXIS_TOLERANCE_DEG, ChannelHealth, check_channels
from ..health import to_json as health_json
from .diagnosis import (FEW_CHANNELS_WARNING, UNEXPLAINED_WARNING, WANDER_WARNING, diagnose_fourflip, examine_residual,
                        platform_unseen_warning, unexplained_warning)
from ..noise import SPIKE_SIGMAS, find_spikes, lattice_step, noise_floor, quantisation_note
from .result import FourFlipResult, ChannelCalibration
from ..site_field import compare_with_site

__all__ = ["METHODS", "FourFlipCalibrator", "calibrate_fourflip", "channel_health", "physics_from_harmonics",
           "relabelling_warning", "result_from_ml"]

METHODS = ("ml", "harmonic", "patent")
_TABLE_BINS = 36
_POORLY_DETERMINED_DEG = 1.0
_VERTICAL_SIGMAS = 5.0
"""Below this, the flip means do not show the vertical field well enough for the hemisphere to fix the
directions' common sign (a one-sided 5-sigma test: chance 3e-7 of a wrong sign when it passes)."""


def calibrate_fourflip(
    rec: FourFlipRecording, *, method: str = "ml", field_ut: float | None = None, dip_sign: float | None = None,
    site=None, diagnose: bool = False, progress=None,
) -> FourFlipResult:
    """Calibrate every channel of a four-flip recording.

    Parameters
    ----------
    rec : FourFlipRecording
    method : {"ml", "harmonic", "patent"}
    field_ut : float, optional
        |B| in microtesla; defaults to the recording's ``field_ut`` metadata.  Without it gains
        are per |B|.
    dip_sign : {+1, -1}, optional
        The data cannot tell the field's sign from the channels' (``(a, B)`` and ``(-a, -B)``
        give the same outputs); +1 (field points down, northern hemisphere) unless the
        metadata's ``site_lat_deg`` is negative.  The result's ``extra["hemisphere"]`` says which
        was taken and why; the report says it in words.
    site : compass.site.Site, optional
        Where and when the bench session was recorded, instead of the metadata's ``site_lat_deg``,
        ``site_lon_deg``, ``site_alt_m`` and ``date``: sets the hemisphere and the WMM site check.
    diagnose : bool
        Run the residual diagnosis loop (:mod:`calibrate.fourflip.diagnosis`): with ``ml`` the final model
        includes every effect the evidence supports; with the seed's rules the residual is only
        examined (the loop needs the joint fit).
    progress : callable, optional
        Receives one line of text per diagnosis stage.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    field_ut = field_ut if field_ut is not None else rec.field_ut
    metadata = rec.metadata if site is None else rec.metadata | {
        "site_lat_deg": site.lat_deg, "site_lon_deg": site.lon_deg, "site_alt_m": site.alt_m,
        "date": site.date.isoformat()}
    dip_sign, hemisphere = _hemisphere(metadata, dip_sign, "--site" if site is not None else "the recording")
    step = lattice_step(rec.outputs)
    noise = noise_floor(rec.platform_deg, rec.flip_index, rec.outputs, step)
    noise = np.where(noise > 0, noise, np.std(rec.outputs, axis=0) * 1e-3)
    quantised = quantisation_note(step, noise, rec.channels)
    spikes = find_spikes(rec.platform_deg, rec.flip_index, rec.outputs, noise)
    if spikes.any():
        rec = rec.subset(~spikes)
    # three channels or more: with fewer a flip's azimuth trades against a direction the pair cannot fix
    azimuths = flip_azimuths(rec.platform_deg, rec.flip_index, rec.outputs) if len(rec.channels) >= 3 else None
    zero_off = None if azimuths is None else zero_off_words(rec.path, azimuths)
    if zero_off is not None:  # one field azimuth in every flip, or the fit spreads the difference everywhere
        raise CannotCalibrate(zero_off)
    result = _estimate(rec, BenchSamples.from_recording(rec), noise, method, field_ut, dip_sign, diagnose, progress)
    result = with_accelerometer(result, rec)  # ax, ay, az: the accelerometer's alignment and the turntable's tilt
    vertical = hm.vector_harmonic(hm.fit_harmonics(rec.platform_deg, rec.flip_index, rec.outputs), 1.0,
                                  dip_sign).vertical_sigmas
    extra = dict(result.extra) | {"hemisphere": hemisphere | {"vertical_field_sigmas": vertical}}
    warnings = result.warnings
    if len(rec.channels) < 3:
        warnings = warnings + (f"{len(rec.channels)} channel{'s' if len(rec.channels) > 1 else ''}: a single-axis "
                               "calibration, valid as such; heading, pitch and roll need at least 3 channels calibrated "
                               "together (compass attitude and live refuse this file)",)
    else:
        unit = np.array([ch.direction for ch in result.channels])
        smallest = np.linalg.svd(unit / np.linalg.norm(unit, axis=1, keepdims=True), compute_uv=False)[-1]
        if smallest < MIN_SINGULAR_VALUE:
            warnings = warnings + (f"the channels' sensing directions do not span three dimensions (smallest singular "
                                   f"value {smallest:.2g}): single-axis calibrations, valid as such, but no field vector "
                                   "(compass attitude and live refuse this file)",)
        if rec.accel is None:  # with one, the reader checked the labels against gravity (and the alignment's
            # words name them where a turned accelerometer and turned labels are the same data)
            relabelled = relabelling_warning(unit, rec.channels)
            warnings = warnings + ((relabelled,) if relabelled else ())
    if vertical < _VERTICAL_SIGMAS:
        warnings = warnings + (f"the flip means hardly show the vertical field ({vertical:.1f} sigma: dip near 0, or "
                               "every channel along housing X): the data cannot tell these directions from their "
                               "negatives, and the hemisphere cannot either; their common sign is a guess",)
    if quantised is not None:
        extra["quantisation"] = quantised
        warnings = warnings + (quantised["words"],)
    if spikes.any():
        extra["spikes_dropped"] = int(spikes.sum())
        warnings = warnings + (f"{int(spikes.sum())} sample(s) dropped as spikes (more than {SPIKE_SIGMAS:g} noise "
                               "sigmas off their neighbours): line or sensor glitches",)
    site_check = compare_with_site(result.dip_deg, result.dip_sigma_deg, metadata, rec.path)
    if site_check is not None:
        extra["site_check"] = site_check
    return replace(result, extra=extra, warnings=warnings, kept=~spikes if spikes.any() else None)


def _label_maps():
    """The relabellings ``recorded = s * true + 90 n`` (mod 360) and what each does to the fitted directions.

    Each is an exact symmetry of the magnetic model (:mod:`compass.io.fourflip`'s notes): with
    ``recorded = true + 90 n`` the fit returns ``Rx(-90 n) a``, with ``recorded = -true - 90 n`` it
    returns ``Rz(pi) Rx(-90 n) a`` (the field's azimuth absorbs the half turn about Z).
    """
    for s in (1, -1):
        for n in range(4):
            turn = Rotation.from_euler("x", -90.0 * n, degrees=True)
            if s == -1:
                turn = Rotation.from_euler("z", 180.0, degrees=True) * turn
            recorded = {k: int((k + 90 * n) % 360) if s == 1 else int((-k - 90 * n) % 360) for k in (0, 90, 180, 270)}
            if any(recorded[k] != k for k in recorded):
                yield recorded, turn


_EXCHANGE_90_270 = {0: 0, 90: 270, 180: 180, 270: 90}
"""flip_deg as recorded for each true flip when the cube was turned the other way about X."""


def relabelling_warning(directions, channels) -> str | None:
    """Words when the channels sit on the housing's axes, some reversed, and flips 90 and 270 exchanged would put
    every one on the positive side of its own axis: the recording's flips are likelier mislabelled than the
    module's channels.

    A magnetometer-only recording fits every relabelling of its flips equally well (each turns every
    direction by one rotation, :func:`_label_maps`), so only the channels' layout can tell; a module with
    channels reversed on purpose is told to ignore it.

    Parameters
    ----------
    directions : ndarray, shape (c, 3)
        Fitted unit sensing directions in H.
    channels : sequence of str
    """
    directions = np.asarray(directions, float)
    cos_tol = np.cos(np.radians(AXIS_TOLERANCE_DEG))

    def positive_axes(d):
        """Per channel its nearest signed axis (index, sign), None unless each is within the tolerance and
        the channels cover X, Y and Z."""
        i = np.argmax(np.abs(d), axis=1)
        near = np.abs(d[np.arange(len(d)), i])
        if np.any(near < cos_tol) or len(set(i.tolist())) < 3:
            return None
        return i, np.sign(d[np.arange(len(d)), i])

    now = positive_axes(directions)
    if len(directions) < 3 or now is None or np.all(now[1] > 0):
        return None
    # only the mistake a person makes (the cube turned the other way about X): the other relabellings would say it
    # of honest layouts (FRD's +X -Y -Z is a half turn about X)
    turn = next(turn for recorded, turn in _label_maps() if recorded == _EXCHANGE_90_270)
    then = positive_axes(turn.apply(directions, inverse=True))
    if then is None or not np.all(then[1] > 0):  # the half turn about Z keeps each channel on its own axis
        return None
    said = ", ".join(f"{c} {'+' if sg > 0 else '-'}{'XYZ'[i]}" for c, i, sg in zip(channels, *now))
    return (f"the channels come out along {said}; with flip_deg relabelled 90 -> 270, 270 -> 90 (flips 90 and 270 "
            "exchanged: the cube turned the other way about X) every one would be along a positive housing axis. "
            "Without an accelerometer the flips' labels cannot be checked (any relabelling fits as well, every "
            "direction turned): if the channels are along +X, +Y, +Z, relabel the flips or re-record them as SPEC "
            "turns the cube (right-hand about +X: flip 90 brings +Y up); if they are mounted reversed, ignore this")


class FourFlipCalibrator(Calibrator):
    """Seed 000's four-flip calibration of single-axis channels (:func:`calibrate_fourflip`).

    Parameters
    ----------
    method : {"ml", "harmonic", "patent"}
    field_ut : float, optional
        |B| in uT; default the recording's ``field_ut`` metadata.
    site : str, optional
        ``LAT,LON[,ALT_M]`` where the bench stood (``--site``): sets the hemisphere (the data cannot
        tell ``(a, B)`` from ``(-a, -B)``) and the WMM site check, over the recording's metadata.
    date : str, optional
        ``YYYY-MM-DD`` with ``site`` (default the metadata's ``date``, else today).
    diagnose : bool
        Run the residual diagnosis loop (SPEC section 4).
    progress : callable, optional
        Receives one line of text per diagnosis stage.
    """

    kind = "fourflip"
    plot_files = ("fit.png", "residuals.png")

    def __init__(self, *, method: str = "ml", field_ut: float | None = None, site: str | None = None,
                 date: str | None = None, diagnose: bool = True, progress=None,
                 axis_tolerance_deg: float | None = AXIS_TOLERANCE_DEG, direction_accuracy_deg: float | None = None):
        self.method, self.field_ut, self.diagnose, self.progress = method, field_ut, diagnose, progress
        self.site, self.date = site, date
        self.axis_tolerance_deg, self.direction_accuracy_deg = axis_tolerance_deg, direction_accuracy_deg

    def fit(self, recording: FourFlipRecording) -> FourFlipResult:
        result = calibrate_fourflip(recording, method=self.method, field_ut=self.field_ut,
                                    site=_bench_site(self.site, self.date, recording), diagnose=self.diagnose,
                                    progress=self.progress)
        health = channel_health(result, recording)
        warnings = check_channels(recording.path, health, axis_tolerance_deg=self.axis_tolerance_deg,
                                  direction_accuracy_deg=self.direction_accuracy_deg)
        return replace(result, warnings=result.warnings + warnings,
                       extra=result.extra | {"channel_health": health_json(health)})


def channel_health(result: FourFlipResult, rec: FourFlipRecording) -> list[ChannelHealth]:
    """Each channel's response to the whole field, its noise and direction (:mod:`calibrate.health`).

    The response is the gain times |B| (|B| = 1 when gains are per |B|) with the joint fit's sigma.
    The seed's rules give no sigma, and their gain from extreme samples is far from zero even on pure
    noise; their response's significance is then that of the strongest flip's first harmonic (each
    coefficient's sigma ``rms sqrt(2 / n_flip)``), fitted to the samples the fit used.
    """
    field = result.field_ut or 1.0
    used = result.used(rec)
    harmonics = hm.fit_harmonics(used.platform_deg, used.flip_index, used.outputs)
    counts = np.bincount(used.flip_index, minlength=4)[:, None]
    significance = np.max(np.hypot(harmonics.cos, harmonics.sin) / (harmonics.residual_rms * np.sqrt(2.0 / counts)), axis=0)
    out = []
    for c, (ch, noise) in enumerate(zip(result.channels, result.noise)):
        response = ch.response.gain * field
        sigma = ch.gain_sigma * field if ch.gain_sigma is not None else response / significance[c]
        out.append(ChannelHealth(ch.name, response, float(sigma), float(noise), ch.direction, ch.direction_sigma_deg))
    return out


def _bench_site(site, date, rec: FourFlipRecording):
    """``--site`` and ``--date`` as a Site (the date defaults to the recording's), None without a site."""
    from compass.site import Site

    if site is None:
        if date is not None:
            raise CannotCalibrate("--date needs --site LAT,LON[,ALT_M]: the date only chooses the field at a site")
        return None
    try:
        return Site.parse(site, date if date is not None else rec.metadata.get("date"))
    except ValueError as exc:
        raise CannotCalibrate(str(exc)) from None


def _estimate(rec, samples, noise, method, field_ut, dip_sign, diagnose, progress) -> FourFlipResult:
    if method in ("patent", "harmonic"):
        result = _seed_rule(rec, samples, noise, field_ut, dip_sign, from_samples=method == "patent")
        if not diagnose:
            return result
        diagnosis = examine_residual(samples, result.residuals, noise)
        warnings = result.warnings + ((_seed_rule_warning(rec, samples, noise, method, field_ut, dip_sign),)
                                      if diagnosis["unexplained"] else ())
        return replace(result, diagnosis=diagnosis, warnings=warnings)
    start = physics_from_harmonics(rec, field_ut, dip_sign)
    if not diagnose:
        fit = fit_ml(samples, rec.outputs, rec.channels, start, noise)
        looked = examine_residual(samples, fit.residuals, noise)  # the diagnosis's yardstick, without its loop
        warnings = ((f"the residual carries structure above the noise floor (chi2/dof {fit.reduced_chi2:.3g}, "
                     f"structure test p = {looked['structure_test']['p_value']:.2g}): the recording has an effect the "
                     "base model lacks, and these sigmas do not cover it; without --no-diagnose the diagnosis names "
                     "it or widens them"),) if looked["unexplained"] else ()
        return result_from_ml(fit, rec, noise, field_ut, samples=samples, extra_warnings=warnings)
    base, fit, diagnosis = diagnose_fourflip(rec, start, noise, progress=progress)
    effects = []
    for effect in fit.effects:
        names, values, sigmas = fit.effect_parameters(effect)
        entry = {"name": effect.name, "form": effect.formula, "parameters": {
            n: {"value": float(v), "sigma": float(e)} for n, v, e in zip(names, values, sigmas)}}
        reference = effect.reference(fit.physics)
        effects.append({**entry, "reference": reference} if reference else entry)
    warnings = (unexplained_warning(diagnosis),) if diagnosis["unexplained"] else ()
    if diagnosis["unexplained"] and len(rec.channels) < 3:
        warnings += (FEW_CHANNELS_WARNING,)
    if "wander_cost" in diagnosis:
        warnings += (WANDER_WARNING,)
    if "platform_field_unseen" in diagnosis:
        warnings += (platform_unseen_warning(diagnosis["platform_field_unseen"]),)
    result = result_from_ml(fit, rec, noise, field_ut, effects=effects, diagnosis=diagnosis, extra_warnings=warnings,
                            samples=samples)
    return replace(result, base_residuals=base.residuals) if fit.effects else result


def _seed_rule_warning(rec, samples, noise, method, field_ut, dip_sign) -> str:
    """Why a seed rule's residual is above the floor: the recording, or the rule's own estimate.

    The joint fit (``ml``) is run: when it leaves the residual at the noise floor, the structure
    is the rule's misestimate (a minimum picked on a flat curve, a dip from an ill-conditioned
    crossing), not an effect the recording has.
    """
    ml = fit_ml(samples, rec.outputs, rec.channels, physics_from_harmonics(rec, field_ut, dip_sign), noise)
    if examine_residual(samples, ml.residuals, noise)["unexplained"]:
        return UNEXPLAINED_WARNING
    return (f"the {method} estimate leaves structure in the residual above the noise floor, but the joint fit "
            "(--method ml) of the same recording is at the floor: the misfit is this method's estimate (a "
            "minimum picked on a flat curve, a dip from an ill-conditioned midpoint crossing), not an effect of the "
            "recording; use --method ml")


def _hemisphere(metadata: dict, dip_sign, where: str) -> tuple[float, dict]:
    """The field's sign (+1 pointing down) and where it came from, for the file and the report."""
    lat = _float_or_none(metadata.get("site_lat_deg"))
    if dip_sign is not None:
        source = "the caller (dip_sign)"
    elif lat is not None:
        dip_sign = -1.0 if lat < 0 else 1.0
        source = f"--site latitude {lat:g}" if where == "--site" else f"'# site_lat_deg: {lat:g}' in the recording"
    else:
        dip_sign, source = 1.0, "the default: no '# site_lat_deg:' in the recording"
    return float(np.sign(dip_sign)), {"assumed": "north" if dip_sign > 0 else "south", "from": source,
                                      "default": source.startswith("the default")}


def _float_or_none(s):
    try:
        return float(s)
    except (TypeError, ValueError):
        return None


def physics_from_harmonics(rec: FourFlipRecording, field_ut, dip_sign) -> BenchPhysics:
    """Starting point of the joint fit: the vector combination of the four flips' harmonics."""
    h = hm.fit_harmonics(rec.platform_deg, rec.flip_index, rec.outputs)
    v = hm.vector_harmonic(h, field_ut or 1.0, dip_sign)
    return BenchPhysics(v.directions, v.offsets, v.gains, v.dip_deg, v.azimuth_deg, field_ut or 1.0)


def result_from_ml(fit: MLFit, rec: FourFlipRecording, noise, field_ut, *, effects=(), diagnosis=None,
                   extra_warnings=(), samples: BenchSamples | None = None) -> FourFlipResult:
    """Package a joint fit as a FourFlipResult (directions, responses, sigmas, warnings).

    ``samples`` are the recording's (:meth:`BenchSamples.from_recording`, made when not given): they
    give each channel's calibrated range.
    """
    phys = fit.physics
    sigma = fit.sigma
    per = 4
    channels = []
    x_range = _seen_range(phys, samples if samples is not None else BenchSamples.from_recording(rec))
    joint = fit.channel_covariance()  # the file's offset and gain sigmas are its marginals (the runtime reads both)
    curved = fit.curve_covariance()
    for c, name in enumerate(rec.channels):
        off_sigma, gain_sigma = (float(np.sqrt(v)) if np.isfinite(v) else None for v in np.diag(joint[c])[3:])
        response = _response_from_physics(phys, c, x_range[c])
        channels.append(ChannelCalibration(name, phys.directions[c], fit.direction_covariance[c], response,
                                           off_sigma, gain_sigma, joint[c], None if curved is None else curved[c]))
    dip_index = per * len(rec.channels)
    dip_sigma = float(np.degrees(sigma[dip_index])) if np.isfinite(sigma[dip_index]) else None
    warnings = list(extra_warnings)
    for combo in fit.singular:
        warnings.append(f"singular covariance: the data cannot separate {combo}"
                        + (" (no channel ever left the horizontal plane: dip and gain are one number)"
                           if "dip_rad" in combo else ""))
    if dip_sigma is not None and dip_sigma > _POORLY_DETERMINED_DEG:
        warnings.append(f"the dip is poorly determined (+- {dip_sigma:.2g} deg): no channel has much component "
                        "along housing Y or Z, so dip and gain are nearly one number; calibrate a tilted channel "
                        "with it or give the gain")
    if not fit.success:
        warnings.append(f"the fit did not converge: {fit.message}")
    parameters = {n: (float(v), float(s)) for n, v, s in zip(fit.names, fit.x, sigma)}
    return FourFlipResult(
        method="ml",
        channels=tuple(channels),
        dip_deg=phys.dip_deg,
        dip_sigma_deg=dip_sigma,
        azimuth_deg=float(np.mod(phys.azimuth_deg, 360.0)),
        field_ut=field_ut,
        noise=noise,
        residuals=fit.residuals,
        parameters=parameters,
        effects=tuple(effects),
        warnings=tuple(warnings),
        diagnosis=diagnosis,
        statistics=FitStatistics(tuple(fit.names), fit.x, fit.covariance, fit.chi2, fit.dof, fit.bic(), fit.success,
                                 fit.message),
    )


def _seen_range(physics: BenchPhysics, samples: BenchSamples) -> np.ndarray:
    """Field component ``B . a`` each channel saw over the session, (c, 2) in field units: its
    calibrated range.

    Not ``[-|B|, |B|]``: flips about X never turn a channel's X component vertical, so a channel
    along X sees only ``|B| cos(dip)`` (plus what its tilt adds); a channel along Y or Z reaches
    ``|B| sin(dip)`` where the flip makes it vertical and ``|B| cos(dip)`` where horizontal.
    """
    x = housing_field(physics, samples) @ physics.directions.T
    return np.column_stack([x.min(axis=0), x.max(axis=0)])


def _response_from_physics(phys: BenchPhysics, c: int, x_range) -> LinearResponse | CubicResponse:
    held = {name: getattr(phys, name) for name in CURVE_FIELDS}
    terms = {name: float(v[c]) for name, v in held.items() if v is not None}
    if terms:
        return CubicResponse(float(phys.offsets[c]), float(phys.gains[c]), tuple(x_range), **terms)
    return LinearResponse(float(phys.offsets[c]), float(phys.gains[c]), tuple(x_range))


# ----------------------------------------------------------------------------- seed rule


def _seed_rule(rec, samples, noise, field_ut, dip_sign, *, from_samples: bool) -> FourFlipResult:
    """Seed 000's closed-form rule with minima from samples (patent) or harmonic fits."""
    b = field_ut or 1.0
    h = hm.fit_harmonics(rec.platform_deg, rec.flip_index, rec.outputs)
    if from_samples:
        minima = hm.sample_minima(rec.platform_deg, rec.flip_index, rec.outputs)
        means = np.array([rec.outputs[rec.flip_index == k].mean(axis=0) for k in range(4)])
    else:
        minima, means = h.minimum_deg, h.mean
    # the minima cannot tell a from -a: each channel's sign comes from the harmonics (hm.orient)
    directions = hm.orient(hm.seed_direction(minima)["direction"], hm.vector_harmonic(h, b, dip_sign))
    angles = seed_angles(directions)
    midpoint = 0.5 * (means[0] + means[2])  # zero-field output from the 0/180 pair
    if from_samples:
        crossing = np.array([_first_crossing(rec, c, minima[0, c], midpoint[c]) for c in range(len(rec.channels))])
    else:
        ratio = (h.mean[0] - midpoint) / np.maximum(h.amplitude[0], 1e-300)
        # |ratio| > 1: the flip-0 curve never reaches the midpoint (tan(dip) tan(elevation) > 1)
        crossing = np.degrees(np.arccos(np.where(np.abs(ratio) <= 1.0, ratio, np.nan)))
    dips = hm.seed_dip(angles["elevation_deg"], crossing)
    conditioning = np.abs(np.sin(2 * np.radians(angles["elevation_deg"])))
    warnings = [f"channel {name}: its flip-0 output never crosses the midpoint value, so the seed's dip rule "
                "cannot use it" for name, d in zip(rec.channels, dips) if not np.isfinite(d)]
    if not np.any(np.isfinite(dips)):
        raise ValueError("the seed's dip rule has no channel whose flip-0 output crosses its midpoint value; "
                         "use --method ml")
    best = int(np.argmax(np.where(np.isfinite(dips), conditioning, -1.0)))
    dip = float(dips[best])
    dip = dip if np.sign(dip) == np.sign(dip_sign) or dip == 0 else -dip
    if conditioning[best] < np.sin(np.radians(20.0)):
        warnings.append(
            f"the seed's dip formula is ill-conditioned: every channel is within 10 deg of horizontal or vertical "
            f"(best: {rec.channels[best]}, elevation {angles['elevation_deg'][best]:.1f} deg)"
        )
    channels = []
    for c, name in enumerate(rec.channels):
        if from_samples:
            response = _seed_table(rec, c, directions[c], minima[:, c], dip, b, midpoint[c])
        else:
            response = _harmonic_linear(h, c, directions[c], dip, b, midpoint[c])
        channels.append(ChannelCalibration(name, directions[c], None, response))
    physics = BenchPhysics(directions, np.array([ch.response.offset for ch in channels]),
                           np.array([ch.response.gain for ch in channels]), dip, _seed_azimuth(minima, angles), b)
    if not from_samples:  # a table's range is its own support (one flip); a line's is what the session saw
        seen = _seen_range(physics, samples)
        channels = [replace(ch, response=replace(ch.response, x_range=tuple(seen[c]))) for c, ch in enumerate(channels)]
    residuals = rec.outputs - bench_outputs(physics, samples)
    extra = {"seed_rule": {"minima_deg": minima.T.tolist(), "dip_per_channel_deg": dips.tolist(),
                           "dip_from_channel": rec.channels[best], "midpoint_value": midpoint.tolist()}}
    return FourFlipResult(
        method="patent" if from_samples else "harmonic",
        channels=tuple(channels),
        dip_deg=dip,
        dip_sigma_deg=None,
        azimuth_deg=physics.azimuth_deg,
        field_ut=field_ut,
        noise=noise,
        residuals=residuals,
        warnings=tuple(warnings),
        extra=extra,
    )


def _seed_azimuth(minima, angles) -> float:
    """Field azimuth implied by the flip-0 minimum of the best-resolved channel: there its horizontal
    projection, at azimuth ``platform + theta`` in W, points away from the field."""
    c = int(np.argmax(np.cos(np.radians(angles["elevation_deg"]))))
    return float(np.mod(minima[0, c] - 180.0 + angles["theta_deg"][c], 360.0))


def _first_crossing(rec, c, phi_min, midpoint) -> float:
    """Turntable angle past the flip-0 minimum (counterclockwise) where the output first
    reaches the midpoint value, from the samples with linear interpolation; degrees."""
    mask = rec.flip_index == 0
    rel = np.mod(rec.platform_deg[mask] - phi_min, 360.0)
    order = np.argsort(rel)
    rel, v = rel[order], rec.outputs[mask, c][order]
    above = np.flatnonzero(v >= midpoint)
    if above.size == 0 or above[0] == 0:
        return np.nan
    i = above[0]
    frac = (midpoint - v[i - 1]) / (v[i] - v[i - 1])
    return float(rel[i - 1] + frac * (rel[i] - rel[i - 1]))


def _flip_elevation(direction, k) -> float:
    """Elevation (radians) of the direction in flip k (cube turned by k x 90 deg about X)."""
    kappa = np.radians(90.0 * k)
    z = np.sin(kappa) * direction[1] + np.cos(kappa) * direction[2]
    return float(np.arcsin(np.clip(z, -1.0, 1.0)))


def _seed_table(rec, c, direction, minima, dip, b, midpoint) -> TableResponse:
    """Seed 000's tabulated f(beta) (claims 6-7, sign corrected), from the flip with the largest
    output swing (flip 0 in the seed), made monotone by isotonic regression."""
    swings = [np.ptp(rec.outputs[rec.flip_index == k, c]) for k in range(4)]
    k = int(np.argmax(swings)) if swings[0] < 0.5 * max(swings) else 0
    mask = rec.flip_index == k
    el = _flip_elevation(direction, k)
    alpha = np.radians(dip)
    cos_angle = np.cos(alpha) * np.cos(el) * np.cos(np.radians(rec.platform_deg[mask] - minima[k])) + np.sin(alpha) * np.sin(el)
    x = -b * cos_angle  # B . a: the seed's beta is measured from -B
    v = rec.outputs[mask, c]
    edges = np.linspace(x.min(), x.max(), _TABLE_BINS + 1)
    which = np.clip(np.digitize(x, edges) - 1, 0, _TABLE_BINS - 1)
    filled = [i for i in range(_TABLE_BINS) if np.any(which == i)]
    xt = np.array([x[which == i].mean() for i in filled])
    vt = np.array([v[which == i].mean() for i in filled])
    vt = isotonic_regression(vt).x
    vt = vt + np.linspace(0.0, 1e-9 * max(np.ptp(vt), 1e-12), len(vt))  # strictly increasing for the inverse
    slope, intercept = np.polyfit(xt, vt, 1)
    gain = slope if slope > 0 else np.ptp(vt) / max(np.ptp(xt), 1e-12)
    return TableResponse(float(midpoint), float(gain), (float(xt[0]), float(xt[-1])), x_table=tuple(xt), v_table=tuple(vt))


def _harmonic_linear(h, c, direction, dip, b, midpoint) -> LinearResponse:
    """Linear response from the four amplitudes: ``A_k = K |B| cos(dip) h_k``."""
    horizontal = np.array([np.cos(_flip_elevation(direction, k)) for k in range(4)])
    amp = h.amplitude[:, c]
    gain = np.sqrt(np.sum(amp**2) / np.sum(horizontal**2)) / (b * np.cos(np.radians(dip)))
    return LinearResponse(float(midpoint), float(gain))
