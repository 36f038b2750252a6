"""compass: the runtime of the compass toolkit.

Load a calibration, turn raw channel outputs into the field in the housing frame, solve
heading, pitch and roll, filter them live.  Frames and angles follow SPEC section 1 (housing
FLU, world magnetic North-West-Up).

>>> from compass import load_calibration, solve_attitude      # doctest: +SKIP
>>> cal = load_calibration("cal.json")                        # doctest: +SKIP
>>> att = solve_attitude(cal.model, raw, accel=cal.imu.apply(accel))  # doctest: +SKIP

Names are imported on first use, so the command line starts without loading the filter stack.
"""

from importlib import import_module

_HOMES = {
    "Attitude": "attitude",
    "level_heading_bound_deg": "attitude",
    "solve_attitude": "attitude",
    "two_vector_rotation": "attitude",
    "Calibration": "calibration",
    "load_calibration": "calibration",
    "save_calibration": "calibration",
    "AttitudeFilter": "filter",
    "FilterConfig": "filter",
    "run_filter": "filter",
    "heading_pitch_roll": "frames",
    "r_world_from_housing": "frames",
    "seed_angles": "frames",
    "SensorModel": "model",
    "CubicResponse": "response",
    "LinearResponse": "response",
    "Response": "response",
    "TableResponse": "response",
    "response_from_json": "response",
}
__all__ = sorted(_HOMES)


_RENAMED = {"load_calibration": "load", "save_calibration": "save"}  # their names inside compass.calibration


def __getattr__(name):
    if name not in _HOMES:
        raise AttributeError(f"module 'compass' has no attribute {name!r}")
    return getattr(import_module(f".{_HOMES[name]}", __name__), _RENAMED.get(name, name))


def __dir__():
    return sorted(set(globals()) | set(_HOMES))
