"""Reading a four-flip truth file back (``compass simulate runtime|installation --truth``), validated.

The file is what :func:`compass.sim.fourflip.write_fourflip` wrote beside its recording; a user
may hand any JSON.  Every value the runtime and installation simulators read is checked here, so
a wrong type, shape, a NaN or a value beyond its physical range is one ``ValueError`` naming the
file and the key, never a NaN in the simulated recording or an error from deep inside numpy.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .. import limits

__all__ = ["read_bench_truth", "NEEDED"]

NEEDED = ("directions", "offsets", "gains_per_ut", "dip_deg", "field_ut", "channels", "noise_ut")
"""Keys the simulators read (``noise`` and ``effects`` are read when present)."""
_OUTPUT = limits.Range(-1e12, 1e12)  # an offset, in output units: the recordings' MAX_ABS_VALUE
_GAIN = limits.Range(-1e9, 1e9)  # output units per uT: a 32-bit ADC's counts over 4 uT
_UNIT_TOLERANCE = 1e-3


def read_bench_truth(path) -> dict:
    """The truth dictionary of ``path``, every value the simulators use checked.

    Raises
    ------
    ValueError
        ``"<path>: ..."``: not JSON, not a four-flip truth file, or a key whose value has the wrong
        type, shape, is not finite or out of its range (:mod:`compass.limits`).
    """
    path = Path(path)
    try:
        truth = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ValueError(f"{path}: cannot read a four-flip truth file ({exc})") from None
    if not isinstance(truth, dict) or any(k not in truth for k in NEEDED):
        raise ValueError(f"{path}: not a four-flip truth file (needs {', '.join(NEEDED)}; "
                         "compass simulate fourflip writes one beside its recording)")
    channels = truth["channels"]
    if (not isinstance(channels, list) or not 1 <= len(channels) <= limits.CHANNELS.hi
            or not all(isinstance(c, str) and c for c in channels) or len(set(channels)) != len(channels)):
        raise ValueError(f"{path}: key 'channels' must be a list of 1 to {limits.CHANNELS.hi} distinct names, "
                         f"got {_short(channels)}")
    n = len(channels)
    directions = _array(path, truth, "directions", (n, 3), limits.Range(-1.0, 1.0))
    norms = np.linalg.norm(directions, axis=1)
    if np.any(np.abs(norms - 1.0) > _UNIT_TOLERANCE):
        raise ValueError(f"{path}: key 'directions' must hold unit vectors, got a norm of "
                         f"{norms[np.argmax(np.abs(norms - 1.0))]:.4g}")
    _array(path, truth, "offsets", (n,), _OUTPUT)
    gains = _array(path, truth, "gains_per_ut", (n,), _GAIN)
    if np.any(gains == 0):
        raise ValueError(f"{path}: key 'gains_per_ut' must not hold a zero gain (a channel that does not sense)")
    if "noise" in truth:
        _array(path, truth, "noise", (n,), _OUTPUT)
    for key, bounds in (("dip_deg", limits.DIP_DEG), ("field_ut", limits.FIELD_UT), ("noise_ut", limits.NOISE_UT)):
        _number(path, truth, key, bounds)
    _effects(path, truth.get("effects", []), n)
    return truth


def _number(path: Path, truth: dict, key: str, bounds: limits.Range) -> float:
    try:
        return bounds.check(truth[key], f"key {key!r}")
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _array(path: Path, node: dict, key: str, shape: tuple, bounds: limits.Range, where: str = "") -> np.ndarray:
    """``node[key]`` as a float array of ``shape`` whose every value is within ``bounds``."""
    name = f"{where}{key!r}"
    value = node.get(key)
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        a = None
    if a is None or a.shape != shape or _has_other_types(value):
        raise ValueError(f"{path}: key {name} must be {'a list' if len(shape) == 1 else 'a list of lists'} of "
                         f"numbers of shape {shape}, got {_short(value)}")
    outside = ~((a >= bounds.lo) & (a <= bounds.hi))  # True for NaN
    if outside.any():
        raise ValueError(f"{path}: key {name} must hold numbers in [{bounds.lo:g}, {bounds.hi:g}], got "
                         f"{a[np.unravel_index(np.argmax(outside), a.shape)]:g}")
    return a


def _has_other_types(value) -> bool:
    """True when a (nested) list holds anything but ints and floats (a string '1' converts silently)."""
    if isinstance(value, list):
        return any(_has_other_types(v) for v in value)
    return isinstance(value, bool) or not isinstance(value, (int, float))


def _effects(path: Path, effects, n: int) -> None:
    """The effects the simulators apply again: a nonlinear response's saturation, the accelerometer's."""
    if not isinstance(effects, list) or not all(isinstance(e, dict) and isinstance(e.get("name"), str)
                                                and isinstance(e.get("parameters"), dict) for e in effects):
        raise ValueError(f"{path}: key 'effects' must be a list of {{\"name\": ..., \"parameters\": {{...}}}}, "
                         f"got {_short(effects)}")
    for effect in effects:
        p, where = effect["parameters"], f"effects: {effect['name']}: "
        if effect["name"] == "nonlinear_response":
            _array(path, p, "tanh_saturation_ut", (n,), limits.Range(1e-3, 1e5), where)
        elif effect["name"] == "accelerometer":
            _array(path, p, "scale", (3,), limits.Range(0.5, 2.0), where)
            rotation = _array(path, p, "mag_to_accel", (3, 3), limits.Range(-1.0, 1.0), where)
            if not np.allclose(rotation @ rotation.T, np.eye(3), atol=_UNIT_TOLERANCE) or np.linalg.det(rotation) < 0:
                raise ValueError(f"{path}: key {where}'mag_to_accel' must be a rotation matrix")
            _array(path, p, "offset_g", (3,), limits.Range(-1.0, 1.0), where)


def _short(value) -> str:
    text = json.dumps(value, allow_nan=True) if not isinstance(value, float) or math.isfinite(value) else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
