"""Rerun output of every command (optional: needs ``pip install compass-toolkit[rerun]``).

Each command takes ``--rerun FILE.rrd|spawn`` (:func:`add_rerun_option`, checked before any work
by :func:`check_rerun_target`) and writes one recording with a blueprint that lays it out:

- :mod:`compass.viz.attitude`: the housing in the world, field and gravity in the housing against
  the gate's cones, the attitude CSV's columns with sigma bands and gate limits, raw channels,
  events (``compass live``, ``compass attitude``, ``compass evaluate``);
- :mod:`compass.viz.live`: :class:`RerunSink`, the live stream in batches;
- :mod:`compass.viz.calibration`: the four-flip session replayed, the tumble's point clouds on
  their ellipsoid and sphere with the coverage, the platform and reference fits, the live tumble.

Importing this package does not import rerun; the names below load their module on first use.
"""

from __future__ import annotations

import importlib

from ._target import add_rerun_option, check_rerun_target, spawn_problem

__all__ = ["add_rerun_option", "check_rerun_target", "spawn_problem", "Recording", "RerunSink", "ENTITIES",
           "attitude_views", "log_attitude", "log_evaluation", "evaluation_views", "log_calibration",
           "calibration_views", "LiveTumbleRecording"]

_LAZY = {"Recording": "_stream", "RerunSink": "live", "ENTITIES": "live", "attitude_views": "attitude",
         "log_attitude": "attitude", "log_evaluation": "attitude", "evaluation_views": "attitude",
         "log_calibration": "calibration", "calibration_views": "calibration", "LiveTumbleRecording": "calibration"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
