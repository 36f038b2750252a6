"""The calibration file (SPEC section 2): its format string, kind key, writer and validated reader.

Every calibration kind writes through :func:`header`, :func:`channel_entry` and :func:`write`;
everything at runtime reads through :func:`load` (or :func:`from_dict`), which validates the whole
file once, for every command, and returns what the runtime needs (:class:`CalibrationFile`).
Nobody else parses the JSON.

The kind of calibration sits under ``"model"`` (:data:`KIND_KEY`): ``fourflip``, ``platform3d``
and ``reference`` are the channel form (a sensing direction and a response per channel),
``tumble`` the ellipsoid form (``hard_iron``, ``soft_iron``, ``field_norm``, ``mag_to_accel``).
Older files that have no ``"model"`` (the four-flip's) or name the kind under ``"method"``
(``platform3d``, ``reference``) still load.

Adding a kind or a block to the file (the installation of issue 11, for example):

- a kind with its own runtime form: ``MODEL_READERS["installed"] = reader`` where
  ``reader(d: dict) -> SensorModel`` (it may call :func:`from_dict` on a nested base calibration);
- a block the runtime needs beside the sensor model: ``SECTION_READERS["installation"] = reader``
  where ``reader(d: dict) -> object`` reads ``d["installation"]``; it is called only when the key
  is present and its result is in :attr:`CalibrationFile.sections` (``"site"`` is read so, into a
  :class:`compass.site.Site`).

Readers raise ``ValueError`` (or :class:`CalibrationFileError` with the key) for anything they
refuse; :func:`load` names the file.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .io.names import RESERVED_NAMES
from .io.units import MAX_ABS_VALUE
from .limits import FIELD_UT, Range

_OUTPUT = Range(-MAX_ABS_VALUE, MAX_ABS_VALUE)
"""An output (offset) in output units: within the recordings' limit (:data:`compass.io.units.MAX_ABS_VALUE`)."""
_GAIN = Range(1 / MAX_ABS_VALUE, MAX_ABS_VALUE)
"""A gain, output units per field unit: positive, within 1e-12..1e12 (the recordings' limit either way)."""

__all__ = ["FORMAT", "KIND_KEY", "CalibrationFile", "CalibrationFileError", "MODEL_READERS", "NoFieldVector",
           "SECTION_READERS",
           "channel_entry", "dumps", "from_dict", "header", "kind_of", "load", "write"]

FORMAT = "compass-calibration/1"
KIND_KEY = "model"
CHANNEL_KINDS = ("fourflip", "platform3d", "reference", "channels")
"""Kinds written in the channel form (SPEC section 2); ``channels``: a sensor model written as such
(:meth:`compass.model.SensorModel.to_json`), whatever fit it came from."""
TUMBLE_CHANNELS = ("mx", "my", "mz")
_UNIT_TOLERANCE = 1e-6  # |direction| - 1 accepted
_ROTATION_TOLERANCE = 1e-6  # R R^T - I accepted, element-wise
_SYMMETRY_TOLERANCE = 1e-6  # relative asymmetry of soft_iron accepted


class CalibrationFileError(ValueError):
    """A calibration file (or document) the runtime cannot use: the message names the file and the key.

    Attributes
    ----------
    path : str or None
        The file, when read from one.
    key : str or None
        Dotted path of the offending key (``channels.mx.response.gain``); given as a tuple
        ``("channels", name, "response.gain")`` for a channel's key (names may hold dots).
    reason : str
        What is wrong, in words.
    """

    def __init__(self, reason: str, *, key: str | tuple | None = None, path=None):
        self.reason, self.path, self._key = reason, None if path is None else str(path), key
        self.key = ".".join(key) if isinstance(key, tuple) else key
        if isinstance(key, tuple):  # ("channels", name, sub): "channel 'mx': 'response.gain' must be ..."
            where = f"channel '{key[1]}': '{key[2]}' " if len(key) > 2 else f"channel '{key[1]}' "
        else:
            where = f"'{key}' " if key else ""
        super().__init__((f"{self.path}: " if self.path else "") + where + reason)

    def in_file(self, path) -> "CalibrationFileError":
        """The same error naming ``path``."""
        return type(self)(self.reason, key=self._key, path=path)


class NoFieldVector(CalibrationFileError):
    """A valid calibration of channels that cannot give a field vector (fewer than three, or
    coplanar: :class:`compass.model.NotAFieldVector`): written by the calibration, refused on
    reading by everything that solves the field."""


@dataclass(frozen=True, eq=False)
class CalibrationFile:
    """A validated calibration file: everything the runtime needs.

    Attributes
    ----------
    kind : str
        ``fourflip``, ``platform3d``, ``reference``, ``tumble`` or a registered kind.
    model : SensorModel
        The magnetic sensor (field in the housing frame H from the channel outputs).
    tilt_sensor : TiltSensor or None
        A 3-D platform calibration's tilt sensor (``"tilt_sensor"``), else None.
    sections : dict
        Blocks read by :data:`SECTION_READERS` (key -> object), for those present.
    data : dict
        The document as read (for reports and exports; do not parse it again).
    path : str or None
    """

    kind: str
    model: Any
    tilt_sensor: Any = None
    sections: dict = field(default_factory=dict)
    data: dict = field(default_factory=dict)
    path: str | None = None


# ---------------------------------------------------------------------------------------------- writing


def header(kind: str) -> dict:
    """The first keys of every calibration file: ``{"format": FORMAT, "model": kind}``."""
    return {"format": FORMAT, KIND_KEY: kind}


def channel_entry(direction, response: dict, *, covariance=None, response_sigma=None, angles: bool = True) -> dict:
    """One channel of the channel form (SPEC section 2).

    Parameters
    ----------
    direction : array_like, shape (3,)
        Unit sensing direction in the housing frame H.
    response : dict
        The response's JSON (:meth:`compass.response.Response.to_json`).
    covariance : array_like, shape (3, 3), optional
        Covariance of the direction (rad^2), written with ``direction_sigma_deg`` (null without it).
    response_sigma : (float, float), optional
        Standard errors of (offset, gain), output units and output units per field unit.
    angles : bool
        Add seed 000's angles ``theta_deg, gamma_deg, elevation_deg, psi_deg``.

    Returns
    -------
    dict
    """
    from .frames import direction_sigma_deg, seed_angles

    direction = np.asarray(direction, dtype=float)
    entry: dict = {"direction": direction.tolist(), "direction_sigma_deg": None if covariance is None else
                   float(direction_sigma_deg(np.asarray(covariance, dtype=float)))}
    if angles:
        entry.update({k: float(v) for k, v in seed_angles(direction).items()})
    entry["response"] = response
    if covariance is not None:
        entry["direction_covariance"] = np.asarray(covariance, dtype=float).tolist()
    if response_sigma is not None:
        entry["response_sigma"] = {"offset": _plain(response_sigma[0]), "gain": _plain(response_sigma[1])}
    return entry


def dumps(doc: dict) -> str:
    """The file's text: validated as :func:`from_dict` reads it, no NaN or Infinity anywhere.

    Numbers the runtime reads must be finite (else :class:`CalibrationFileError` naming the key);
    a non-finite number in a reported-only key (an undefined sigma, a BIC) is written as null,
    JSON's "not available".

    Raises
    ------
    CalibrationFileError
    """
    try:
        from_dict(doc)
    except NoFieldVector:
        pass  # single-axis channels (or coplanar ones): a valid calibration the vector runtime refuses on reading
    return json.dumps(_finite_or_null(doc), indent=2, allow_nan=False) + "\n"


def write(path, doc: dict, *, force: bool = False) -> Path:
    """Validate ``doc`` and write it atomically to ``path`` (refused without ``force`` if it exists).

    Raises
    ------
    CalibrationFileError, FileExistsError, OutputError
    """
    from .io.atomic import atomic_write_text, check_writable

    text = dumps(doc)
    out = check_writable(path, force)
    atomic_write_text(out, text)
    return out


def _finite_or_null(value):
    if isinstance(value, dict):
        return {k: _finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_null(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite_or_null(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _plain(v):
    return None if v is None else float(v)


# ---------------------------------------------------------------------------------------------- reading


def load(path) -> CalibrationFile:
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
    try:
        d = json.loads(text, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise CalibrationFileError(f"not a JSON calibration file ({exc})", path=path) from None
    except RecursionError:
        raise CalibrationFileError("not a calibration file: its JSON is nested too deeply", path=path) from None
    try:
        cal = from_dict(d)
    except CalibrationFileError as exc:
        raise exc.in_file(path) from None
    return CalibrationFile(cal.kind, cal.model, cal.tilt_sensor, cal.sections, cal.data, str(path))


def _parse_int(text: str) -> int | float:
    """A JSON integer; one beyond any float is infinite (then refused as not finite), never an OverflowError."""
    return int(text) if len(text.lstrip("-")) <= 308 else math.inf


def kind_of(d: dict) -> str:
    """The calibration's kind: ``"model"``, else an older file's ``"method"``, else the four-flip's channels."""
    kind = d.get(KIND_KEY)
    if kind is None:
        method = d.get("method")
        kind = method if method in CHANNEL_KINDS else "fourflip"
    if not isinstance(kind, str) or kind not in MODEL_READERS:
        raise CalibrationFileError(f"unknown calibration model {kind!r} under '{KIND_KEY}' "
                                   f"(known: {', '.join(MODEL_READERS)})")
    return kind


def hemisphere_assumed(d: dict) -> bool:
    """The calibration (or an installed file's base) is a four-flip bench whose hemisphere was assumed, not
    given: its data cannot tell ``(a, B)`` from ``(-a, -B)``, so a field read turned over points there."""
    base = d.get("base") if kind_of(d) == "installed" else d
    if not isinstance(base, dict) or kind_of(base) != "fourflip":
        return False
    hemisphere = base.get("hemisphere")
    return not isinstance(hemisphere, dict) or bool(hemisphere.get("default", True))


def from_dict(d) -> CalibrationFile:
    """Validate a calibration document (a parsed file) and build what the runtime needs.

    Raises
    ------
    CalibrationFileError
        The message names the key.
    """
    if not isinstance(d, dict):
        raise CalibrationFileError(f"expected a JSON object, got {_json_type(d)}")
    fmt = d.get("format")
    if fmt != FORMAT:
        raise CalibrationFileError(f"unknown calibration format {fmt!r}: this reader knows only {FORMAT!r}")
    kind = kind_of(d)
    try:
        model = MODEL_READERS[kind](d)
        sections = {key: _section(reader, d, key) for key, reader in SECTION_READERS.items() if d.get(key) is not None}
    except RecursionError:
        raise CalibrationFileError("nested too deeply") from None
    except CalibrationFileError:
        raise
    except ValueError as exc:  # the model's own checks (SensorModel), a singular solve: named as the file's
        raise CalibrationFileError(f"describes no usable sensor ({exc})") from None
    tilt = sections.pop("tilt_sensor", None)
    return CalibrationFile(kind, model, tilt, sections, d)


def _section(reader, d: dict, key: str):
    try:
        return reader(d)
    except CalibrationFileError:
        raise
    except (ValueError, TypeError, KeyError, AttributeError, IndexError) as exc:
        raise CalibrationFileError(_words(exc), key=key) from None


def _words(exc: Exception) -> str:
    text = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
    return f"is malformed ({text})"


def _json_type(v) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "true/false", type(None): "null"}.get(
        type(v), "a number")


# ------------------------------------------------------------------------------------- value checks


def _number(v, key: str, *, positive=False, nonnegative=False, allow_none=False, low=None, high=None, bounds=None):
    """``v`` as a float: a finite number (and positive, not negative, within [low, high] or ``bounds``, a
    :class:`compass.limits.Range`, when asked); CalibrationFileError naming ``key`` else."""
    if v is None and allow_none:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise CalibrationFileError(f"must be a number{' or null' if allow_none else ''}, got {_show(v)}", key=key)
    v = float(v)
    if not math.isfinite(v):
        raise CalibrationFileError(f"must be finite, got {v}", key=key)
    if positive and not v > 0:
        raise CalibrationFileError(f"must be positive, got {v:g}", key=key)
    if nonnegative and v < 0:
        raise CalibrationFileError(f"must not be negative, got {v:g}", key=key)
    if bounds is not None and v not in bounds:
        raise CalibrationFileError(f"must be {bounds.describe()}, got {v:g}", key=key)
    if (low is not None and v < low) or (high is not None and v > high):
        raise CalibrationFileError(f"must be within [{'-inf' if low is None else f'{low:g}'}, "
                                   f"{'inf' if high is None else f'{high:g}'}], got {v:g}", key=key)
    return v


def _array(v, shape: tuple, key: str, limit: float = np.inf) -> np.ndarray:
    """``v`` as a finite float array of ``shape``, every value within +-``limit``."""
    what = "a list of 3 numbers" if shape == (3,) else f"{'x'.join(map(str, shape))} nested lists of numbers"
    try:
        ok = _all_numbers(v)
        out = np.asarray(v, dtype=float) if ok else None
    except (TypeError, ValueError):
        out = None
    if out is None or out.shape != shape:
        raise CalibrationFileError(f"must be {what}, got {_show(v)}", key=key)
    if not np.all(np.isfinite(out)):
        raise CalibrationFileError(f"must be finite, got {_show(v)}", key=key)
    if np.any(np.abs(out) > limit):
        raise CalibrationFileError(f"must be within +-{limit:g} (no sensor output reaches beyond), got "
                                   f"{out.flat[np.argmax(np.abs(out))]:g}", key=key)
    return out


def _all_numbers(v) -> bool:
    if isinstance(v, list):
        return all(_all_numbers(x) for x in v)
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _show(v) -> str:
    text = json.dumps(v) if isinstance(v, (int, float, str, type(None), bool)) else _json_type(v)
    return text if len(text) < 60 else text[:57] + "..."


def _sub(key, sub: str):
    """The key of ``sub`` inside ``key`` (a dotted string, or a channel's tuple)."""
    if isinstance(key, tuple):
        return key[:2] + (f"{key[2]}.{sub}" if len(key) > 2 else sub,)
    return f"{key}.{sub}"


def _object(v, key) -> dict:
    if not isinstance(v, dict):
        raise CalibrationFileError(f"must be an object, got {_show(v)}", key=key)
    return v


def _rotation(v, key: str) -> np.ndarray:
    r = _array(v, (3, 3), key)
    if not np.allclose(r @ r.T, np.eye(3), atol=_ROTATION_TOLERANCE) or np.linalg.det(r) < 0:
        raise CalibrationFileError(f"must be a proper rotation matrix (orthonormal, determinant +1), got "
                                   f"determinant {np.linalg.det(r):.6g}", key=key)
    return r


def _common(d: dict) -> tuple:
    """The top-level ``field_ut`` and ``dip_deg`` (None when absent), in :mod:`compass.limits`' ranges."""
    field_ut = _number(d.get("field_ut"), "field_ut", allow_none=True, bounds=FIELD_UT)
    dip_deg = _number(d.get("dip_deg"), "dip_deg", low=-90.0, high=90.0, allow_none=True)
    effects = d.get("effects")
    if effects is not None and not isinstance(effects, list):
        raise CalibrationFileError(f"must be a list of effects, got {_show(effects)}", key="effects")
    return field_ut, dip_deg


def _noise(value, n: int, key: str = "noise_floor") -> np.ndarray | None:
    if value is None:
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * n
    out = _array(value, (n,), key, limit=MAX_ABS_VALUE)
    if np.any(out < 0):
        raise CalibrationFileError(f"must not be negative, got {_show(value)}", key=key)
    return out


def _temperature(d: dict, channels, gains):
    from .temperature import TemperatureCompensation

    try:
        return TemperatureCompensation.from_effects(d.get("effects"), channels, gains)
    except (ValueError, TypeError, KeyError, AttributeError) as exc:
        raise CalibrationFileError(_words(exc), key="effects") from None


# ------------------------------------------------------------------------------------- channel form


def _response(v, key: tuple):
    from .response import CubicResponse, LinearResponse, TableResponse

    r = _object(v, key)
    model = r.get("model")
    offset = _number(r.get("offset"), _sub(key, "offset"), bounds=_OUTPUT)
    gain = _number(r.get("gain"), _sub(key, "gain"), bounds=_GAIN)
    x_range = (-np.inf, np.inf)
    if r.get("range") is not None:
        lo, hi = _array(r["range"], (2,), _sub(key, "range"))
        if not lo < hi:
            raise CalibrationFileError(f"must be [low, high] with low < high, got [{lo:g}, {hi:g}]", key=_sub(key, "range"))
        x_range = (float(lo), float(hi))
    if model == "linear":
        return LinearResponse(offset, gain, x_range)
    if model not in ("cubic", "table"):
        raise CalibrationFileError(f"unknown response model {_show(model)} (known: linear, cubic, table)",
                                   key=_sub(key, "model"))
    if not np.all(np.isfinite(x_range)):
        raise CalibrationFileError(f"must be given for a {model} response (its calibrated range [low, high])", key=_sub(key, "range"))
    if model == "cubic":
        coef = {k: _number(r.get(k, 0.0), _sub(key, k)) for k in ("cubic", "quintic", "quadratic")}
        response = CubicResponse(offset, gain, x_range, **coef)
    else:
        x = r.get("x")
        n = len(x) if isinstance(x, list) else 0
        xs = _array(x, (n,), _sub(key, "x"))
        vs = _array(r.get("v"), (n,), _sub(key, "v"))
        if n < 2:
            raise CalibrationFileError(f"must hold at least 2 points, got {n}", key=_sub(key, "x"))
        if np.any(np.diff(xs) <= 0):
            raise CalibrationFileError("must increase (a table's field components)", key=_sub(key, "x"))
        if np.any(np.diff(vs) <= 0):
            raise CalibrationFileError("must increase with the field (a monotone response)",
                                       key=_sub(key, "v"))
        response = TableResponse(offset, gain, x_range, x_table=tuple(xs), v_table=tuple(vs))
    grid = np.linspace(x_range[0], x_range[1], 257)
    if not np.all(np.diff(response.shape(grid)) > 0):
        raise CalibrationFileError(f"is not monotone over its calibrated range "
                                   f"[{x_range[0]:.4g}, {x_range[1]:.4g}]", key=key)
    return response


def _channel_model(d: dict):
    from .model import NotAFieldVector, SensorModel

    field_ut, dip_deg = _common(d)
    channels = d.get("channels")
    if not isinstance(channels, dict) or not channels:
        raise CalibrationFileError("expected 'channels': an object of channel name -> direction and response")
    names, directions, responses, covariances, sigmas = [], [], [], [], []
    for name, ch in channels.items():
        key = ("channels", name)
        if name in RESERVED_NAMES or not name.strip():
            raise CalibrationFileError("is not a channel name: " + ("empty" if not name.strip() else
                                       f"{name} is the recordings' and the line protocol's own column"), key=key)
        _object(ch, key)
        direction = _array(ch.get("direction"), (3,), _sub(key, "direction"))
        if not abs(np.linalg.norm(direction) - 1.0) < _UNIT_TOLERANCE:
            raise CalibrationFileError(f"must be a unit vector, its norm is {np.linalg.norm(direction):.6g}",
                                       key=_sub(key, "direction"))
        names.append(name)
        directions.append(direction)
        responses.append(_response(ch.get("response"), _sub(key, "response")))
        cov = ch.get("direction_covariance")
        if cov is not None:
            cov = _array(cov, (3, 3), _sub(key, "direction_covariance"))
            if not np.allclose(cov, cov.T, atol=1e-12 + 1e-6 * np.abs(cov).max()) or np.any(np.diag(cov) < 0):
                raise CalibrationFileError("must be a symmetric covariance (non-negative diagonal)",
                                           key=_sub(key, "direction_covariance"))
        covariances.append(cov)
        rs = ch.get("response_sigma")
        if rs is not None:
            _object(rs, _sub(key, "response_sigma"))
            rs = tuple(_number(rs.get(k), f"{key}.response_sigma.{k}", nonnegative=True, allow_none=True)
                       for k in ("offset", "gain"))
        sigmas.append(rs)
    gains = np.array([r.gain for r in responses])
    try:
        return SensorModel(
            channels=tuple(names),
            directions=np.array(directions),
            responses=tuple(responses),
            field_magnitude=field_ut or 1.0,
            field_ut=field_ut,
            dip_deg=dip_deg,
            noise=_noise(d.get("noise_floor"), len(names)),
            direction_covariance=None if any(c is None for c in covariances) else np.array(covariances),
            response_sigma=(None if any(s is None or None in s for s in sigmas) else np.array(sigmas, dtype=float)),
            temperature=_temperature(d, names, gains),
        )
    except CalibrationFileError:
        raise
    except NotAFieldVector as exc:
        raise NoFieldVector(f"cannot give a field vector: {exc}", key="channels") from None
    except ValueError as exc:
        raise CalibrationFileError(f"are unusable: {exc}", key="channels") from None


# -------------------------------------------------------------------------------------- tumble form


def _tumble_model(d: dict):
    """The channel form of a tumble calibration (see :mod:`compass.model`)."""
    from .model import SensorModel
    from .response import LinearResponse

    field_ut, dip_deg = _common(d)
    soft = _array(d.get("soft_iron"), (3, 3), "soft_iron", limit=_GAIN.hi)
    hard = _array(d.get("hard_iron"), (3,), "hard_iron", limit=MAX_ABS_VALUE)
    field_norm = _number(d.get("field_norm"), "field_norm", positive=True, high=MAX_ABS_VALUE)
    check_hard_iron(hard, field_norm, "hard_iron")
    scale = np.abs(soft).max()
    if not np.allclose(soft, soft.T, rtol=0.0, atol=_SYMMETRY_TOLERANCE * scale):
        raise CalibrationFileError("must be symmetric (a soft-iron matrix is)", key="soft_iron")
    eig = np.linalg.eigvalsh(soft)
    if not eig[0] > 1e-9 * scale:
        raise CalibrationFileError(f"must be positive definite, its eigenvalues are {np.round(eig, 6).tolist()}",
                                   key="soft_iron")
    if not (eig[0] >= _GAIN.lo and eig[-1] <= _GAIN.hi):  # the inverse of a gain: field units per output unit
        raise CalibrationFileError(f"must have eigenvalues in [{_GAIN.lo:g}, {_GAIN.hi:g}], got {eig[0]:.4g} to "
                                   f"{eig[-1]:.4g}", key="soft_iron")
    rot = np.eye(3) if d.get("mag_to_accel") is None else _rotation(d["mag_to_accel"], "mag_to_accel")
    g = np.linalg.solve(soft, rot.T)  # raw - hard_iron = g @ B_H
    gains = np.linalg.norm(g, axis=1)
    span = (-field_norm, field_norm)
    # per-axis noise in recording units: a list, or calibrate.tumble's scalar under 'diagnosis'
    diagnosis = d.get("diagnosis")
    noise_key = "noise_floor" if d.get("noise_floor") is not None else "diagnosis.noise_floor"
    noise = d.get("noise_floor", diagnosis.get("noise_floor") if isinstance(diagnosis, dict) else None)
    return SensorModel(
        channels=TUMBLE_CHANNELS,
        directions=g / gains[:, None],
        responses=tuple(LinearResponse(float(o), float(k), span) for o, k in zip(hard, gains)),
        field_magnitude=field_norm,
        field_ut=field_ut,
        dip_deg=dip_deg,
        noise=_noise(noise, 3, noise_key),
        kind="tumble",
        temperature=_temperature(d, TUMBLE_CHANNELS, gains),
    )


def check_hard_iron(hard, field_magnitude: float, key: str) -> None:
    """CalibrationFileError unless ``|hard| <= FIELD_RATIO_LIMIT * field_magnitude``: a sensor offset by a
    hundred times the field it measures reads beyond the range the filters screen (a magnet on it)."""
    from .sample_check import FIELD_RATIO_LIMIT

    size = math.hypot(*hard)  # np.linalg.norm overflows for 1e308
    if not size <= FIELD_RATIO_LIMIT * field_magnitude:
        raise CalibrationFileError(f"must be within {FIELD_RATIO_LIMIT:g} times the field's {field_magnitude:.4g} "
                                   f"in size (a magnet on the sensor saturates it), got {size:.4g}", key=key)


def _tilt_sensor(d: dict):
    from .io.platform3d import TiltSensor

    t = _object(d["tilt_sensor"], "tilt_sensor")
    _array(t.get("offset"), (len(t["offset"]) if isinstance(t.get("offset"), list) else 3,), "tilt_sensor.offset")
    return TiltSensor.from_json(d)


def _installed_model(d: dict):
    from .installed import from_installed_json  # the bench model inside its product (issue 11)

    _common(d)  # the site's field and dip beside the bench's: checked as every kind's
    return from_installed_json(d)


MODEL_READERS: dict[str, Callable[[dict], Any]] = {
    "fourflip": _channel_model,
    "platform3d": _channel_model,
    "reference": _channel_model,
    "channels": _channel_model,
    "tumble": _tumble_model,
    "installed": _installed_model,
}
"""Kind -> reader of its sensor model (``reader(d) -> SensorModel``)."""

def _site(d: dict):
    from .site import Site

    return Site.from_json(d["site"])


def _mag_to_accel(d: dict):
    from .accel_alignment import read_mag_to_accel

    return read_mag_to_accel(d)


SECTION_READERS: dict[str, Callable[[dict], Any]] = {
    "tilt_sensor": _tilt_sensor,
    "site": _site,
    "mag_to_accel": _mag_to_accel,
}
"""Key -> reader of a block the runtime needs beside the sensor model, called when the key is present."""
