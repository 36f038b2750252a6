"""The one validated reader of calibration files (SPEC section 2): document -> :class:`Calibration`.

The kind sits under ``"model"`` (:data:`KIND_KEY`): ``fourflip``, ``platform3d``, ``reference`` and
``channels`` are the channel form (a sensing direction and a response per channel), ``tumble`` the
ellipsoid form (``hard_iron``, ``soft_iron``, ``field_norm``, ``mag_to_accel``), ``installed`` a bench
calibration under ``base`` with the product's iron under ``installation``.  Older files that have no
``"model"`` (the four-flip's) or name the kind under ``"method"`` (``platform3d``, ``reference``) still load.

Every refusal is a :class:`CalibrationFileError` naming the key (and the file, from :func:`load`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..io.names import RESERVED_NAMES
from ..io.units import MAX_ABS_VALUE
from ..limits import FIELD_UT
from . import _checks as check
from ._errors import CalibrationFileError, NoFieldVector
from ._format import CHANNEL_KINDS, FORMAT, KIND_KEY, TUMBLE_CHANNELS
from ._imu import ImuCorrection
from ._value import Calibration, Installation, Provenance, TumbleForm

__all__ = ["KINDS", "MAX_GYRO_MATRIX_ERROR", "from_dict", "gyro_matrix_mismatch", "gyro_matrix_seen", "gyro_scale_error", "kind_of", "latency_seen", "load", "loads", "model_from_dict"]

KINDS = ("fourflip", "platform3d", "reference", "channels", "tumble", "installed")
"""Every kind the reader knows (the file's ``"model"``)."""
SIGMA_LIMIT = MAX_ABS_VALUE
"""Largest standard error a tumble file's sigmas may hold (recording units, file units, degrees)."""
MAX_MAG_LATENCY_S = 0.25
"""Largest magnetometer latency a file may hold, s: the filter's first-order turn ``m + tau (m x w)`` is off by
``(tau w)^2 / 2``, 3 % at 1 rad/s; the gyro-aided fit's prior (50 ms) keeps its own far inside."""
LATENCY_SIGMA_SEEN_S = 0.01
"""A fitted latency counts as seen only with a standard error below this, s: a fifth of the gyro-aided fit's
prior (``calibrate.tumble.gyro.LATENCY_PRIOR_S``), so the prior did not make it."""
MAX_GYRO_MATRIX_ERROR = 0.2
"""Largest ``|G - I|`` entry a file's gyro matrix may hold: 20 %, seven times the MPU-9250's scale tolerance (3 %);
beyond it the gyro's unit or an axis is wrong, not its scale."""
GYRO_MATRIX_SIGMA_SEEN = 0.005
"""An entry of the fitted gyro matrix counts as seen only with a standard error below this (0.5 %, the gyro scale
error the filter's noise allows for, ``FilterConfig.gyro_scale_error``; well under the fit's prior of 2-3 %, so the
prior did not make it) and beyond 3 of its sigmas from the identity's (:func:`gyro_matrix_seen`)."""
GYRO_MATRIX_MISMATCH = np.where(np.eye(3, dtype=bool), 0.09, 0.06)
"""An entry of ``G - I`` beyond this is a model mismatch, never applied: 3 of the gyro-aided fit's prior sigmas
(``calibrate.tumble.gyro.GYRO_MATRIX_PRIOR``, the datasheet's 3 % scale and 2 % cross-axis tolerances); the fit
took up there what its model leaves out, not the gyro's error."""


def load(path) -> Calibration:
    """Read and validate a calibration file.

    Raises
    ------
    CalibrationFileError
        Unreadable, not JSON, nested too deeply, unknown ``format`` or kind, or any key the
        runtime needs missing or invalid; the message names the file and the key.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except IsADirectoryError:
        raise CalibrationFileError("is a folder, expected a calibration file (JSON)", path=path) from None
    except OSError as exc:
        raise CalibrationFileError(f"cannot read calibration file ({exc.strerror})", path=path) from None
    except UnicodeDecodeError as exc:
        raise CalibrationFileError(f"not a JSON calibration file (not UTF-8 text: {exc.reason})", path=path) from None
    return loads(text, name=path)


def loads(text: str, *, name) -> Calibration:
    """Validate a calibration file's text (one kept elsewhere: a calibration store's row).

    Parameters
    ----------
    text : str
        The file's JSON.
    name : str or path-like
        What to call it in errors and in :attr:`Calibration.path` (``module M7 in calibrations.sqlite``).

    Raises
    ------
    CalibrationFileError
        As :func:`load`, naming ``name``.
    """
    try:
        d = json.loads(text, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise CalibrationFileError(f"not a JSON calibration file ({exc})", path=name) from None
    except RecursionError:
        raise CalibrationFileError("not a calibration file: its JSON is nested too deeply", path=name) from None
    try:
        return from_dict(d, path=name)
    except CalibrationFileError as exc:
        raise exc.in_file(name) from None


def model_from_dict(d):
    """The sensor model of a calibration document: ``from_dict(d).model``."""
    return from_dict(d).model


def kind_of(d: dict) -> str:
    """The calibration's kind: ``"model"``, else an older file's ``"method"``, else the four-flip's channels."""
    kind = d.get(KIND_KEY)
    if kind is None:
        method = d.get("method")
        kind = method if method in CHANNEL_KINDS else "fourflip"
    if not isinstance(kind, str) or kind not in KINDS:
        raise CalibrationFileError(f"unknown calibration model {kind!r} under '{KIND_KEY}' (known: {', '.join(KINDS)})")
    return kind


def from_dict(d, *, path=None) -> Calibration:
    """Validate a calibration document (a parsed file) into its :class:`Calibration`.

    Raises
    ------
    CalibrationFileError
        The message names the key.
    NoFieldVector
        Valid channels that cannot give a field vector (fewer than three, or coplanar).
    """
    if not isinstance(d, dict):
        raise CalibrationFileError(f"expected a JSON object, got {check.json_type(d)}")
    fmt = d.get("format")
    if fmt != FORMAT:
        raise CalibrationFileError(f"unknown calibration format {fmt!r}: this reader knows only {FORMAT!r}")
    kind = kind_of(d)
    try:
        return _calibration(d, kind, None if path is None else str(path))
    except RecursionError:
        raise CalibrationFileError("nested too deeply") from None
    except CalibrationFileError:
        raise
    except ValueError as exc:  # the model's own checks (SensorModel), a singular solve: named as the file's
        raise CalibrationFileError(f"describes no usable sensor ({exc})") from None


def _calibration(d: dict, kind: str, path) -> Calibration:
    installation = tumble = None
    if kind == "installed":
        _common(d)  # the site's field and dip beside the bench's: checked as every kind's
        installation = _installation(d)
        model = _installed_model(installation)
        base = installation.base
        imu = ImuCorrection(base.imu.mag_to_accel, installation.alignment, base.imu.offset, base.imu.scale,
                            base.imu.one_g)
        hemisphere = base.provenance.hemisphere_assumed
    elif kind == "tumble":
        model, tumble = _tumble(d)
        imu, hemisphere = ImuCorrection(), False
    else:
        model = _channel_model(d)
        rotation = None if d.get("mag_to_accel") is None else check.rotation(d["mag_to_accel"], "mag_to_accel")
        imu = ImuCorrection(rotation, None, *_bench_accelerometer(d.get("accelerometer")))
        hemisphere = kind == "fourflip" and _hemisphere_assumed(d.get("hemisphere"))
    tilt = None if d.get("tilt_sensor") is None else _block(_tilt_sensor, d, "tilt_sensor")
    site = None if d.get("site") is None else _block(_site, d, "site")
    method = d.get("method")
    dip_sigma = d.get("dip_sigma_deg")
    warnings = _warnings(d)
    if installation is not None:
        warnings += tuple(f"base calibration: {w}" for w in installation.base.provenance.warnings)
    provenance = Provenance(method if isinstance(method, str) else None, hemisphere,
                            float(dip_sigma) if _is_number(dip_sigma) else None, warnings, _unexplained(d))
    return Calibration(kind, model, imu, tilt, site, provenance, installation, tumble, path, d)


def _warnings(d: dict) -> tuple[str, ...]:
    """The file's ``warnings``: a list of words (absent: none)."""
    words = d.get("warnings")
    if words is None:
        return ()
    if not isinstance(words, list) or not all(isinstance(w, str) for w in words):
        raise CalibrationFileError(f"must be a list of words, got {check.show(words)}", key="warnings")
    return tuple(words)


def _unexplained(d: dict) -> bool | None:
    """The diagnosis's ``unexplained`` (an installed file's under ``installation``), a reported flag: None when it
    is not a bool."""
    inst = d.get("installation")
    block = inst.get("diagnosis") if isinstance(inst, dict) and isinstance(inst.get("diagnosis"), dict) else \
        d.get("diagnosis")
    flag = block.get("unexplained") if isinstance(block, dict) else None
    return flag if isinstance(flag, bool) else None


def _parse_int(text: str) -> int | float:
    """A JSON integer; one beyond any float is infinite (then refused as not finite), never an OverflowError."""
    return int(text) if len(text.lstrip("-")) <= 308 else math.inf


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _block(reader, d: dict, key: str):
    """A block read by its own type's reader; its refusal named under ``key``."""
    try:
        return reader(d)
    except CalibrationFileError:
        raise
    except (ValueError, TypeError, KeyError, AttributeError, IndexError) as exc:
        raise CalibrationFileError(check.words(exc), key=key) from None


def _hemisphere_assumed(hemisphere) -> bool:
    return not isinstance(hemisphere, dict) or bool(hemisphere.get("default", True))


def _bench_accelerometer(block) -> tuple:
    """``(offset, scale, one_g)`` of a four-flip's ``accelerometer`` block, all None when absent or unusable.

    A reported block: one the runtime cannot use (missing keys, wrong shapes, non-positive scales) is left
    out, as the runtime did before it applied the block.
    """
    try:
        offset, scale_yz, one_g = (np.asarray(block[k], dtype=float) for k in ("offset", "scale_yz", "one_g"))
    except (KeyError, TypeError, ValueError):
        return None, None, None
    scale = np.concatenate([[1.0], scale_yz]) if scale_yz.shape == (2,) else None
    if offset.shape != (3,) or scale is None or not (np.all(np.isfinite(offset)) and np.all(scale > 0)
                                                     and float(one_g) > 0):
        return None, None, None
    return offset, scale, float(one_g)


def _common(d: dict) -> tuple:
    """The top-level ``field_ut`` and ``dip_deg`` (None when absent), in :mod:`compass.limits`' ranges."""
    field_ut = check.number(d.get("field_ut"), "field_ut", allow_none=True, bounds=FIELD_UT)
    dip_deg = check.number(d.get("dip_deg"), "dip_deg", low=-90.0, high=90.0, allow_none=True)
    effects = d.get("effects")
    if effects is not None and not isinstance(effects, list):
        raise CalibrationFileError(f"must be a list of effects, got {check.show(effects)}", key="effects")
    return field_ut, dip_deg


def _temperature(d: dict, channels, gains):
    from ..temperature import TemperatureCompensation

    try:
        return TemperatureCompensation.from_effects(d.get("effects"), channels, gains)
    except (ValueError, TypeError, KeyError, AttributeError) as exc:
        raise CalibrationFileError(check.words(exc), key="effects") from None


# ------------------------------------------------------------------------------------- channel form


def _response(v, key: tuple):
    from ..response import CubicResponse, LinearResponse, TableResponse

    r = check.obj(v, key)
    model = r.get("model")
    offset = check.number(r.get("offset"), check.sub(key, "offset"), bounds=check.OUTPUT)
    gain = check.number(r.get("gain"), check.sub(key, "gain"), bounds=check.GAIN)
    x_range = (-np.inf, np.inf)
    if r.get("range") is not None:
        lo, hi = check.array(r["range"], (2,), check.sub(key, "range"))
        if not lo < hi:
            raise CalibrationFileError(f"must be [low, high] with low < high, got [{lo:g}, {hi:g}]",
                                       key=check.sub(key, "range"))
        x_range = (float(lo), float(hi))
    if model == "linear":
        return LinearResponse(offset, gain, x_range)
    if model not in ("cubic", "table"):
        raise CalibrationFileError(f"unknown response model {check.show(model)} (known: linear, cubic, table)",
                                   key=check.sub(key, "model"))
    if not np.all(np.isfinite(x_range)):
        raise CalibrationFileError(f"must be given for a {model} response (its calibrated range [low, high])",
                                   key=check.sub(key, "range"))
    if model == "cubic":
        coef = {k: check.number(r.get(k, 0.0), check.sub(key, k)) for k in ("cubic", "quintic", "quadratic")}
        response = CubicResponse(offset, gain, x_range, **coef)
    else:
        x = r.get("x")
        n = len(x) if isinstance(x, list) else 0
        xs = check.array(x, (n,), check.sub(key, "x"))
        vs = check.array(r.get("v"), (n,), check.sub(key, "v"))
        if n < 2:
            raise CalibrationFileError(f"must hold at least 2 points, got {n}", key=check.sub(key, "x"))
        if np.any(np.diff(xs) <= 0):
            raise CalibrationFileError("must increase (a table's field components)", key=check.sub(key, "x"))
        if np.any(np.diff(vs) <= 0):
            raise CalibrationFileError("must increase with the field (a monotone response)", key=check.sub(key, "v"))
        response = TableResponse(offset, gain, x_range, x_table=tuple(xs), v_table=tuple(vs))
    grid = np.linspace(x_range[0], x_range[1], 257)
    if not np.all(np.diff(response.shape(grid)) > 0):
        raise CalibrationFileError(f"is not monotone over its calibrated range "
                                   f"[{x_range[0]:.4g}, {x_range[1]:.4g}]", key=key)
    return response


def _channel_model(d: dict):
    from ..model import NotAFieldVector, SensorModel

    field_ut, dip_deg = _common(d)
    channels = d.get("channels")
    if not isinstance(channels, dict) or not channels:
        raise CalibrationFileError("expected 'channels': an object of channel name -> direction and response")
    names, directions, responses, covariances, sigmas, joints = [], [], [], [], [], []
    for name, ch in channels.items():
        key = ("channels", name)
        if name in RESERVED_NAMES or not name.strip():
            raise CalibrationFileError("is not a channel name: " + ("empty" if not name.strip() else
                                       f"{name} is the recordings' and the line protocol's own column"), key=key)
        check.obj(ch, key)
        direction = check.array(ch.get("direction"), (3,), check.sub(key, "direction"))
        norm = math.hypot(*direction)  # no overflow at 1e308 entries, as a sum of squares would
        if not abs(norm - 1.0) < check.UNIT_TOLERANCE:
            raise CalibrationFileError(f"must be a unit vector, its norm is {norm:.6g}",
                                       key=check.sub(key, "direction"))
        names.append(name)
        directions.append(direction)
        responses.append(_response(ch.get("response"), check.sub(key, "response")))
        cov = ch.get("direction_covariance")
        if cov is not None:
            cov = check.array(cov, (3, 3), check.sub(key, "direction_covariance"))
            if not np.allclose(cov, cov.T, atol=1e-12 + 1e-6 * np.abs(cov).max()) or np.any(np.diag(cov) < 0):
                raise CalibrationFileError("must be a symmetric covariance (non-negative diagonal)",
                                           key=check.sub(key, "direction_covariance"))
        covariances.append(cov)
        rs = ch.get("response_sigma")
        if rs is not None:
            check.obj(rs, check.sub(key, "response_sigma"))
            rs = tuple(check.number(rs.get(k), f"{key}.response_sigma.{k}", nonnegative=True, allow_none=True)
                       for k in ("offset", "gain"))
            gain, gain_sigma = responses[-1].gain, rs[1]
            if gain_sigma is not None and gain < check.DEAD_RESPONSE_SIGMAS * gain_sigma:
                raise CalibrationFileError(f"does not respond to the field: its gain {gain:.3g} +- {gain_sigma:.2g} is "
                                           f"{gain / gain_sigma:.1f} sigma from zero (a dead or disconnected sensor); "
                                           "recalibrate the module after repair", key=key)
        sigmas.append(rs)
        joints.append(_channel_joint(ch, cov, rs, responses[-1], key))
    gains = np.array([r.gain for r in responses])
    covariance, sigma, priors = _channel_sigmas(names, np.array(directions), gains, field_ut or 1.0, covariances,
                                                sigmas)
    try:
        return SensorModel(
            channels=tuple(names),
            directions=np.array(directions),
            responses=tuple(responses),
            field_norm=field_ut or 1.0,
            field_ut=field_ut,
            dip_deg=dip_deg,
            noise=check.noise(d.get("noise_floor"), len(names)),
            direction_covariance=covariance,
            response_sigma=sigma,
            temperature=_temperature(d, names, gains),
            sigma_priors=priors,
            joint_covariance=None if all(j is None for j in joints) else tuple(joints),
        )
    except CalibrationFileError:
        raise
    except NotAFieldVector as exc:
        raise NoFieldVector(f"cannot give a field vector: {exc}", key="channels") from None
    except ValueError as exc:
        raise CalibrationFileError(f"are unusable: {exc}", key="channels") from None


def _channel_joint(ch: dict, direction_covariance, response_sigma, response, key: tuple):
    """A channel's joint covariance for the model: its ``curve_joint_covariance`` (8 x 8) when there, whose
    top-left 5 x 5 must be its ``joint_covariance``, else its ``joint_covariance`` (5 x 5), else None."""
    from ..iron_uncertainty import JOINT_TOLERANCE

    joint = _joint_covariance(ch.get("joint_covariance"), direction_covariance, response_sigma, response, 5,
                              check.sub(key, "joint_covariance"))
    curve_key = check.sub(key, "curve_joint_covariance")
    curved = _joint_covariance(ch.get("curve_joint_covariance"), direction_covariance, response_sigma, response, 8,
                               curve_key)
    if curved is None:
        return joint
    if joint is None:
        raise CalibrationFileError("comes without the channel's joint_covariance (its top-left 5x5)", key=curve_key)
    scale = np.sqrt(np.diag(joint))
    scale[scale == 0.0] = 1.0
    if np.max(np.abs(curved[:5, :5] - joint) / np.outer(scale, scale)) > JOINT_TOLERANCE:
        raise CalibrationFileError("must have the channel's joint_covariance as its top-left 5x5", key=curve_key)
    return curved


def _joint_covariance(value, direction_covariance, response_sigma, response, size: int, key):
    """A channel's ``joint_covariance`` (``size`` 5: its direction's, offset's and gain's covariance, whose marginals
    are the channel's ``direction_covariance`` and ``response_sigma``) or ``curve_joint_covariance`` (``size`` 8,
    only for a cubic ``response``: then its quadratic, cubic and quintic coefficients' too), or None when absent or
    null."""
    from ..iron_uncertainty import joint_problem
    from ..response import CubicResponse

    if value is None:
        return None
    joint = check.array(value, (size, size), key)
    problem = joint_problem(joint, direction_covariance, response_sigma, isinstance(response, CubicResponse))
    if problem is not None:
        raise CalibrationFileError(problem, key=key)
    return joint


def _channel_sigmas(names, directions, gains, field_norm, covariances, sigmas) -> tuple:
    """The channels' direction covariances (c, 3, 3) and response sigmas (c, 2), each None when no channel gives
    one (nothing claimed), and the priors a null one took beside others given (never read as zero:
    :func:`compass.iron_uncertainty.channel_priors`), as ``SensorModel.sigma_priors`` (None when none)."""
    from ..iron_uncertainty import channel_priors

    c = len(names)
    dir_gone = np.array([cov is None for cov in covariances])
    rs = [(None, None) if s is None else s for s in sigmas]
    off_gone, gain_gone = (np.array([r[i] is None for r in rs]) for i in (0, 1))
    has_dir, has_rs = not dir_gone.all(), not (off_gone.all() and gain_gone.all())
    dir_gone &= has_dir
    off_gone &= has_rs
    gain_gone &= has_rs
    covariance = np.array([np.zeros((3, 3)) if cov is None else cov for cov in covariances]) if has_dir else None
    sigma = np.array([[0.0 if v is None else v for v in r] for r in rs], dtype=float).reshape(c, 2) if has_rs else None
    if not (dir_gone.any() or off_gone.any() or gain_gone.any()):
        return covariance, sigma, None
    prior_cov, prior_sigma, words = channel_priors(directions, gains, field_norm, names, dir_gone, off_gone, gain_gone)
    if covariance is not None:
        covariance = covariance + prior_cov
    if sigma is not None:
        sigma = np.hypot(sigma, prior_sigma)
    return covariance, sigma, (prior_cov, prior_sigma, words)


# -------------------------------------------------------------------------------------- tumble form


def _tumble(d: dict) -> tuple:
    """The channel form of a tumble calibration (see :mod:`compass.model`) and the file's matrices."""
    from ..model import SensorModel
    from ..response import LinearResponse

    field_ut, dip_deg = _common(d)
    soft = check.soft_iron(d.get("soft_iron"), "soft_iron")
    field_norm = check.number(d.get("field_norm"), "field_norm", positive=True, high=MAX_ABS_VALUE)
    hard = check.hard_iron(d.get("hard_iron"), field_norm, "hard_iron")
    mag_to_accel = None if d.get("mag_to_accel") is None else check.rotation(d["mag_to_accel"], "mag_to_accel")
    rot = np.eye(3) if mag_to_accel is None else mag_to_accel
    g = np.linalg.solve(soft, rot.T)  # raw - hard_iron = g @ B_H
    gains = np.linalg.norm(g, axis=1)
    span = (-field_norm, field_norm)
    # per-axis noise in recording units: a list, or calibrate.tumble's scalar under 'diagnosis'
    diagnosis = d.get("diagnosis")
    noise_key = "noise_floor" if d.get("noise_floor") is not None else "diagnosis.noise_floor"
    noise = d.get("noise_floor", diagnosis.get("noise_floor") if isinstance(diagnosis, dict) else None)
    block = d.get("tumble") if isinstance(d.get("tumble"), dict) else {}
    model = SensorModel(
        channels=TUMBLE_CHANNELS,
        directions=g / gains[:, None],
        responses=tuple(LinearResponse(float(o), float(k), span) for o, k in zip(hard, gains)),
        field_norm=field_norm,
        field_ut=field_ut,
        dip_deg=dip_deg,
        noise=check.noise(noise, 3, noise_key),
        form="tumble",
        temperature=_temperature(d, TUMBLE_CHANNELS, gains),
        iron_uncertainty=_tumble_uncertainty(block, soft, rot, mag_to_accel is not None, field_norm),
        mag_latency_s=_mag_latency_s(block.get("gyro")),
        gyro_matrix=_gyro_matrix(block.get("gyro")),
        gyro_scale_error=_gyro_scale_error(block.get("gyro")),
        accel_correction=_accel_correction(d.get("accelerometer")),
    )
    norm = block.get("field_norm_recording_units")
    if norm is None and field_ut is None:
        norm = field_norm  # no |B| given: the file's field norm is in the recording's unit
    ellipsoid = block.get("kind")  # the file's spelling of the fitted ellipsoid
    return model, TumbleForm(hard, soft, mag_to_accel, field_norm, float(norm) if _is_number(norm) else None,
                             ellipsoid if isinstance(ellipsoid, str) else None)


def _tumble_uncertainty(block: dict, soft: np.ndarray, rotation: np.ndarray, rotation_fitted: bool,
                        field_norm: float):
    """The ``tumble`` block's sigmas of the hard iron, soft iron and rotation as a
    :class:`~compass.iron_uncertainty.TumbleUncertainty`; None when the file gives no hard-iron or soft-iron
    sigmas at all (a file written by hand: no calibration term, nothing claimed).  An entry the fit wrote
    null or infinite (it could not determine it), a null ``misalignment_rotvec_sigma_deg`` or no rotation
    fitted (``mag_to_accel`` null: the accelerometer's frame taken as the magnetometer's) is never read as
    zero: it takes the stated prior (:data:`compass.iron_uncertainty.HARD_IRON_PRIOR` of |B|,
    :data:`~compass.iron_uncertainty.SOFT_IRON_PRIOR` of the soft iron's scale,
    :data:`~compass.iron_uncertainty.ROTATION_PRIOR_AXIS_DEG` per axis) and is named in its ``undetermined``.  An absent
    rotation sigma beside a fitted rotation: zeros, as the file says nothing of it.  Anything else that is
    not a list of numbers of the key's shape is refused."""
    from ..iron_uncertainty import (HARD_IRON_PRIOR, ROTATION_PRIOR_AXIS_DEG, ROTATION_PRIOR_DEG, SOFT_IRON_PRIOR,
                                   TumbleUncertainty)

    if block.get("hard_iron_sigma") is None or block.get("soft_iron_sigma") is None:
        return None
    scale = abs(float(np.linalg.det(soft))) ** (1.0 / 3.0)  # field units per recording unit
    undetermined = []
    hard, hard_gone = _sigma(block.get("hard_iron_sigma"), (3,), "tumble.hard_iron_sigma")
    if hard_gone.any():
        undetermined.append(f"the hard iron along {', '.join(np.array(TUMBLE_CHANNELS)[hard_gone])} "
                            f"(taken as {100 * HARD_IRON_PRIOR:.0f} % of |B|)")
    soft_sigma, soft_gone = _sigma(block.get("soft_iron_sigma"), (3, 3), "tumble.soft_iron_sigma")
    soft_gone = soft_gone | soft_gone.T  # S_ij and S_ji one number
    if soft_gone.any():
        undetermined.append("the soft iron's " + ", ".join(f"S_{'xyz'[i]}{'xyz'[j]}" for i, j in
                                                           zip(*np.nonzero(np.triu(soft_gone))))
                            + f" (taken as {100 * SOFT_IRON_PRIOR:.0f} %)")
    key = "misalignment_rotvec_sigma_deg"
    rot, rot_gone = np.zeros(3), np.zeros(3, dtype=bool)
    rot_prior = np.radians(ROTATION_PRIOR_AXIS_DEG)
    if not rotation_fitted:
        rot_gone[:] = True
        undetermined.append(f"the rotation from the magnetometer to the accelerometer (not fitted, taken as none; "
                            f"its sigma as {ROTATION_PRIOR_DEG:g} deg in all, {ROTATION_PRIOR_AXIS_DEG:.2g} deg per "
                            "axis: a mounting's)")
    elif key in block:
        rot, rot_gone = _sigma(block.get(key), (3,), f"tumble.{key}")
        if rot_gone.any():
            undetermined.append(f"the rotation to the accelerometer about {', '.join(np.array(list('xyz'))[rot_gone])} "
                                f"(taken as {ROTATION_PRIOR_AXIS_DEG:.2g} deg per axis)")
        rot = np.radians(rot)
    for name, value in (("hard_iron_sigma", hard), ("soft_iron_sigma", soft_sigma), (key, rot)):
        if np.any(value < 0):
            raise CalibrationFileError("must not be negative (standard errors)", key=f"tumble.{name}")
    if not undetermined:
        return TumbleUncertainty(soft, rotation, hard, soft_sigma, rot)
    priors = (np.where(hard_gone, HARD_IRON_PRIOR * field_norm / scale, 0.0),
              np.where(soft_gone, SOFT_IRON_PRIOR * scale, 0.0), np.where(rot_gone, rot_prior, 0.0))
    prior = TumbleUncertainty(soft, rotation, *priors)
    # in quadrature: an undetermined entry holds 0 (its prior alone); S_ij beside a null S_ji keeps its own sigma too
    return TumbleUncertainty(soft, rotation, np.hypot(hard, priors[0]), np.hypot(soft_sigma, priors[1]),
                             np.hypot(rot, priors[2]),
                             tuple(undetermined), prior)


def _sigma(v, shape: tuple, key: str) -> tuple[np.ndarray, np.ndarray]:
    """A standard error of ``shape`` under ``key`` and where the fit could not give one (a null or infinite
    entry; the whole key null: every entry), shape ``shape`` of bool; those entries hold 0.  Anything else not
    finite numbers of that shape is refused.  Bounded by :data:`SIGMA_LIMIT` (a sigma beyond it is no calibration)."""
    if v is None:
        return np.zeros(shape), np.ones(shape, dtype=bool)
    if _undetermined(v):  # numbers and nulls only
        try:
            value = np.array(v, dtype=object)
            value = np.array([math.nan if e is None else e for e in value.flat], dtype=float).reshape(shape)
        except (TypeError, ValueError):  # ragged, or another shape
            value = None
        if value is not None:
            gone = ~np.isfinite(value)
            return check.array(np.where(gone, 0.0, value).tolist(), shape, key, limit=SIGMA_LIMIT), gone
        check.array(v, shape, key)  # refused: the shape named
    return check.array(v, shape, key, limit=SIGMA_LIMIT), np.zeros(shape, dtype=bool)


def _undetermined(v) -> bool:
    """Nested lists of numbers or nulls, at least one of them null or infinite."""
    def entries(x):
        return [e for item in x for e in entries(item)] if isinstance(x, list) else [x]
    values = entries(v) if isinstance(v, list) else [v]
    if not all(e is None or (isinstance(e, (int, float)) and not isinstance(e, bool)) for e in values):
        return False
    return any(e is None or not math.isfinite(e) for e in values)


def _mag_latency_s(gyro) -> float:
    """``tumble.gyro.mag_latency_s`` when the gyro-aided fit saw a latency (:func:`latency_seen`) the filter
    can compensate: the magnetometer late (positive); else 0 (an early magnetometer, the gyro the late one,
    cannot be compensated by turning the field forward: the fit's words say so).  Refused beyond
    +-:data:`MAX_MAG_LATENCY_S`, where the first-order turn the filter applies no longer holds.  0 when the
    calibration did not use the gyro-aided fit (``used`` not true): its numbers are not the calibration's."""
    if gyro is None:
        return 0.0
    gyro = check.obj(gyro, "tumble.gyro")
    if gyro.get("used") is not True:
        return 0.0
    tau, sigma = gyro.get("mag_latency_s"), gyro.get("mag_latency_sigma_s")
    if tau is None:
        return 0.0
    tau = check.number(tau, "tumble.gyro.mag_latency_s", low=-MAX_MAG_LATENCY_S, high=MAX_MAG_LATENCY_S)
    sigma = check.number(sigma, "tumble.gyro.mag_latency_sigma_s", nonnegative=True, allow_none=True)
    return tau if sigma is not None and tau > 0.0 and latency_seen(tau, sigma) else 0.0


def _gyro_matrix(gyro) -> np.ndarray | None:
    """``tumble.gyro.gyro_matrix`` (``G``: the housing-frame rate is ``G w``, ``w`` the gyro's reading) with each entry
    the data did not see or that are a model mismatch (:func:`gyro_matrix_seen` of it and ``gyro_matrix_sigma``; no
    sigma: none seen) at the identity's;
    None when no entry was seen.  Refused: not 3 x 3 numbers, an entry of ``G - I`` beyond
    +-:data:`MAX_GYRO_MATRIX_ERROR`, a negative sigma.  None when the calibration did not use the gyro-aided fit
    (``used`` not true: a fit it refused)."""
    if gyro is None:
        return None
    gyro = check.obj(gyro, "tumble.gyro")
    if gyro.get("used") is not True:
        return None
    if gyro.get("gyro_matrix") is None:
        _gyro_matrix_sigma(gyro.get("gyro_matrix_sigma"))  # refused when garbage, though there is no matrix
        return None
    g = _nested_3x3(gyro["gyro_matrix"], "tumble.gyro.gyro_matrix")
    error = g - np.eye(3)
    if np.any(np.abs(error) > MAX_GYRO_MATRIX_ERROR):
        i, j = np.unravel_index(np.argmax(np.abs(error)), (3, 3))
        raise CalibrationFileError(f"must be within {100 * MAX_GYRO_MATRIX_ERROR:g} % of the identity (a gyro scale or "
                                   f"axis error; beyond, its unit or an axis is wrong), got {g[i, j]:g} at row {i}, "
                                   f"column {j}", key="tumble.gyro.gyro_matrix")
    sigma = _gyro_matrix_sigma(gyro.get("gyro_matrix_sigma"))
    if sigma is None:
        return None
    seen = gyro_matrix_seen(g, sigma)
    return np.where(seen, g, np.eye(3)) if seen.any() else None


MAX_ACCEL_MATRIX_ERROR = 0.5
"""An entry of the accelerometer's matrix ``A - I`` beyond this is refused (a unit or an axis wrong, not a scale)."""


def _accel_correction(block) -> tuple | None:
    """``(matrix, offset, one_g)`` of a tumble file's ``accelerometer`` block (``f = matrix @ (a - offset)``, the
    recording's unit, in which 1 g reads ``one_g``; :mod:`calibrate.tumble.accelerometer`), None when absent or not
    fitted (null values).
    Refused: not numbers of the shapes, a matrix not symmetric or an entry of ``A - I`` beyond
    +-:data:`MAX_ACCEL_MATRIX_ERROR`."""
    if block is None:
        return None
    block = check.obj(block, "accelerometer")
    if block.get("matrix") is None and block.get("offset") is None:
        return None
    matrix = _nested_3x3(block.get("matrix"), "accelerometer.matrix")
    offset = check.array(block.get("offset"), (3,), "accelerometer.offset")
    one_g = check.number(block.get("one_g"), "accelerometer.one_g", positive=True)
    if (not np.allclose(matrix, matrix.T) or np.any(np.abs(matrix - np.eye(3)) > MAX_ACCEL_MATRIX_ERROR)
            or not np.linalg.det(matrix) > 0.0):
        raise CalibrationFileError(f"must be symmetric, of positive determinant and within {MAX_ACCEL_MATRIX_ERROR:g} "
                                   f"of the identity, got {matrix.tolist()}", key="accelerometer.matrix")
    return matrix, offset, one_g


def _gyro_scale_error(gyro) -> tuple[float, float] | None:
    """:func:`gyro_scale_error` of the file's fitted ``tumble.gyro.gyro_matrix`` and its sigma; None when the
    calibration did not use the fit or the file holds no matrix or sigma.  Refused as :func:`_gyro_matrix` refuses."""
    if gyro is None:
        return None
    gyro = check.obj(gyro, "tumble.gyro")
    if gyro.get("used") is not True or gyro.get("gyro_matrix") is None:
        return None
    sigma = _gyro_matrix_sigma(gyro.get("gyro_matrix_sigma"))
    if sigma is None:
        return None
    return gyro_scale_error(_nested_3x3(gyro["gyro_matrix"], "tumble.gyro.gyro_matrix"), sigma)


def gyro_scale_error(matrix, sigma) -> tuple[float, float]:
    """The gyro scale and axis error a fitted gyro matrix says remains, with its seen entries applied and without.

    The rate error of a gyro read through ``G`` is ``E w``, ``E = G - I`` (a coherent error: it turns the attitude by
    ``E`` times the angle turned).  Averaged over the directions of ``w``, ``|E w|^2 = |w|^2 ||E||_F^2 / 3``, so the one
    number the filter takes (its ``gyro_scale_error``, a fraction of the rate on every axis, ``s`` for ``E = s I``) is
    ``sqrt(sum e_ij^2 / 3)``: the same in any frame the gyro is turned to (an installation keeps it).  It under-allows
    an error concentrated on one axis in turns about that axis (a yaw axis alone 5 % high: 2.9 %), where the bound
    over every direction (the largest singular value of ``E`` and, for the fit's error, the worst column
    ``sqrt(max_j sum_i sigma_ij^2)``, a sound bound of ``E|D w|^2 / |w|^2`` for independent entries) would not; the
    bound was measured and not kept (docs/benchmarks.md, "The gyro's scale error in the noise model"): the filter adds
    ``s^2 |w|^2`` about every axis alike, so the bound over-allows on the axes the motion does not turn about, and it
    lost on BROAD (geometric mean heading 1.45 -> 1.63 deg) and on simulated boards whose z axis alone is 5 % off
    (0.98 -> 1.03 deg over the seven motions), winning only on turns about the one axis in error.

    Only the entries the fit saw (:func:`gyro_matrix_seen`, the one rule for the words and the runtime) count, each
    with what is left of it in expectation: applied, its variance ``sigma_ij^2``; not applied, ``(G - I)_ij^2 +
    sigma_ij^2``.  An entry it did not see counts nothing beyond what the filter allows for every board
    (:data:`compass.filter.DEFAULT_GYRO_SCALE_ERROR`, which :meth:`compass.filter.FilterConfig.from_model` adds in
    quadrature): that default is the prior spread of a board's error, and a fit that read the entry within 3 sigma of
    the identity's only narrows it (the posterior variance ``sigma_p^2 sigma^2 / (sigma_p^2 + sigma^2)`` is below both;
    averaged over what the fit could have read, the true error's expected square is the prior's, and an unseen
    reading selects the smaller ones), so its ``sigma_ij^2`` on top of the default would count the same uncertainty
    twice.  Measured on BROAD: counting the precise unseen entries' ``sigma_ij^2`` (with the bound above) made trial
    02's file (nothing seen) say 0.85 % and cost trial 01 0.84 -> 1.55 deg of heading.  An entry with no usable sigma
    (null, a sigma its prior made) or a model mismatch (:func:`gyro_matrix_mismatch`) is never seen.

    Parameters
    ----------
    matrix : array_like, shape (3, 3)
        The fitted ``G`` (dimensionless).
    sigma : array_like, shape (3, 3)
        Its entries' standard errors (dimensionless; inf or NaN where none).

    Returns
    -------
    tuple of 2 floats
        ``(with the seen entries applied, the gyro as read)``, fractions of the rate; 0 where nothing was seen.
    """
    g = np.asarray(matrix, dtype=float)
    seen = gyro_matrix_seen(g, sigma)
    var = np.where(seen, np.asarray(sigma, dtype=float), 0.0) ** 2
    error2 = np.where(seen, g - np.eye(3), 0.0) ** 2
    return float(np.sqrt(var.sum() / 3.0)), float(np.sqrt((error2 + var).sum() / 3.0))


def _nested_3x3(v, key: str) -> np.ndarray:
    """3 x 3 nested lists of finite numbers; a wrong entry is named (``key[i][j]``), a wrong shape the key."""
    if isinstance(v, list) and len(v) == 3 and all(isinstance(row, list) and len(row) == 3 for row in v):
        return np.array([[check.number(e, f"{key}[{i}][{j}]") for j, e in enumerate(row)] for i, row in enumerate(v)])
    return check.array(v, (3, 3), key)  # refused: the shape named


def _gyro_matrix_sigma(v) -> np.ndarray | None:
    """``tumble.gyro.gyro_matrix_sigma``: 3 x 3 non-negative numbers, null where the fit gave no sigma (inf);
    None when absent."""
    key = "tumble.gyro.gyro_matrix_sigma"
    if v is None:
        return None
    if not (isinstance(v, list) and len(v) == 3 and all(isinstance(row, list) and len(row) == 3 for row in v)):
        raise CalibrationFileError(f"must be 3x3 nested lists of numbers or nulls, got {check.show(v)}", key=key)
    return np.array([[np.inf if e is None else check.number(e, f"{key}[{i}][{j}]", nonnegative=True, high=SIGMA_LIMIT)
                      for j, e in enumerate(row)] for i, row in enumerate(v)])


def gyro_matrix_seen(matrix, sigma) -> np.ndarray:
    """Which entries of a fitted gyro matrix the data saw and the runtime may apply (the one rule for the
    calibration's words and the runtime): beyond 3 of its sigmas from the identity's, the sigma below
    :data:`GYRO_MATRIX_SIGMA_SEEN`, and not a model mismatch (:func:`gyro_matrix_mismatch`).

    Parameters
    ----------
    matrix : array_like, shape (3, 3)
        The fitted ``G`` (dimensionless).
    sigma : array_like, shape (3, 3)
        The entries' standard errors (dimensionless; inf or NaN where none).

    Returns
    -------
    ndarray of bool, shape (3, 3)
    """
    error = np.abs(np.asarray(matrix, dtype=float) - np.eye(3))
    sigma = np.asarray(sigma, dtype=float)
    precise = np.isfinite(sigma) & (sigma < GYRO_MATRIX_SIGMA_SEEN)
    return precise & (error > 3.0 * np.where(precise, sigma, 0.0)) & ~gyro_matrix_mismatch(matrix)


def gyro_matrix_mismatch(matrix) -> np.ndarray:
    """Which entries of a fitted gyro matrix are a model mismatch: ``|G - I|`` beyond :data:`GYRO_MATRIX_MISMATCH`
    (3 prior sigmas), never applied however precise.

    Parameters
    ----------
    matrix : array_like, shape (3, 3)
        The fitted ``G`` (dimensionless).

    Returns
    -------
    ndarray of bool, shape (3, 3)
    """
    return np.abs(np.asarray(matrix, dtype=float) - np.eye(3)) > GYRO_MATRIX_MISMATCH


def latency_seen(latency_s: float, sigma_s: float) -> bool:
    """Whether a fitted magnetometer latency was seen by the data: beyond 3 of its sigmas from zero and the
    sigma within :data:`LATENCY_SIGMA_SEEN_S` (the one rule for the calibration's words and the runtime).

    Parameters
    ----------
    latency_s, sigma_s : float
        The latency (positive: the magnetometer late) and its standard error, s.
    """
    return bool(abs(latency_s) > 3.0 * sigma_s and sigma_s < LATENCY_SIGMA_SEEN_S)


def _tilt_sensor(d: dict):
    from ..io.platform3d import TiltSensor

    t = check.obj(d["tilt_sensor"], "tilt_sensor")
    check.array(t.get("offset"), (len(t["offset"]) if isinstance(t.get("offset"), list) else 3,), "tilt_sensor.offset")
    return TiltSensor.from_json(d)


def _site(d: dict):
    from ..site import Site

    return Site.from_json(d["site"])


# ------------------------------------------------------------------------------------ installed form


def _installation(d: dict) -> Installation:
    """The bench calibration under ``base`` and the product's iron under ``installation``."""
    base_doc, inst = d.get("base"), d.get("installation")
    if not isinstance(base_doc, dict):
        raise CalibrationFileError("must be the bench calibration (an object)", key="base")
    if not isinstance(inst, dict):
        raise CalibrationFileError("must be an object with hard_iron_ut and soft_iron", key="installation")
    try:
        base = from_dict(base_doc)
    except CalibrationFileError as exc:
        raise exc.under("base") from None
    if base.kind == "installed":
        raise CalibrationFileError("must be a bench calibration, not another installed one", key="base")
    hard = check.hard_iron(inst.get("hard_iron_ut"), base.model.field_norm, "installation.hard_iron_ut")
    soft = check.soft_iron(inst.get("soft_iron"), "installation.soft_iron")
    cov = None if inst.get("covariance") is None else check.array(inst["covariance"], (9, 9), "installation.covariance")
    align = (None if inst.get("alignment") is None else check.rotation(inst["alignment"], "installation.alignment"))
    return Installation(base, hard, soft, cov, align)


def _installed_model(installation: Installation):
    from ..installed import installed_model

    return installed_model(installation.base.model, installation.hard_iron_ut, installation.soft_iron,
                           installation.covariance, installation.alignment)
