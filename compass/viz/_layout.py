"""The views every layout is built from, set so that a recording reads at a glance when it opens.

Rerun's defaults suit a live stream, not a finished recording: a time series opens on a window
about the time cursor (half a trial blank, or nothing when the cursor sits at the end), a text log
shows time, entity path and level before the message (cut to three letters in a narrow panel), a
3-D view picks its own camera, and the side panels take 40 % of the width. The helpers here set
those once: whole timelines, the message alone, a camera looking at the scene from the front-left
above, panels collapsed.
"""

from __future__ import annotations

import rerun.blueprint as rrb
from rerun.blueprint.encodings import TextLogColumn, TimelineColumn

__all__ = ["series", "text_log", "spatial", "blueprint", "APPLICATION_IDS"]

# one application id per kind of recording: Rerun keeps one blueprint per application id, so two
# kinds sharing one would open each other's layout (the tumble in the four-flip's panels, all empty)
APPLICATION_IDS = {"fourflip": "compass_calibrate_fourflip", "tumble": "compass_calibrate_tumble",
                   "platform3d": "compass_calibrate_platform3d", "reference": "compass_calibrate_reference",
                   "installed": "compass_calibrate_installed", "attitude": "compass_attitude",
                   "evaluate": "compass_evaluate", "live": "compass_live", "live_tumble": "compass_live_tumble",
                   "demo": "compass_demo", "bench": "compass_bench"}

TIMELINES = ("t", "sample", "turntable_deg")
"""Every timeline the recordings use."""

_WHOLE = rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())


def series(*, name: str, origin: str = "/", contents=None, legend: str | None = "RightTop") -> rrb.TimeSeriesView:
    """A time series over the whole recording (not a window about the time cursor).

    Parameters
    ----------
    name : str
        Title; says the unit.
    origin, contents
        As :class:`rerun.blueprint.TimeSeriesView` (contents default to the origin's subtree).
    legend : str or None
        Corner of the legend (``"RightTop"``, ``"LeftBottom"`` ...); None hides it (one series,
        named in the title).
    """
    legend_bp = rrb.PlotLegend(visible=False) if legend is None else rrb.PlotLegend(corner=legend, visible=True)
    return rrb.TimeSeriesView(origin=origin, contents="$origin/**" if contents is None else contents, name=name,
                              axis_x=rrb.TimeAxis(view_range=_WHOLE, link="Independent"), plot_legend=legend_bp)


def text_log(*, origin: str, name: str) -> rrb.TextLogView:
    """A text log showing the message only (no time, entity path or level columns)."""
    columns = rrb.TextLogColumns(  # an empty list of timeline columns shows the active one: hide each by name
        timeline_columns=[TimelineColumn(name, visible=False) for name in TIMELINES],
        text_log_columns=[TextLogColumn("Body", visible=True), TextLogColumn("EntityPath", visible=False),
                          TextLogColumn("LogLevel", visible=False)])
    return rrb.TextLogView(origin=origin, name=name, columns=columns)


def spatial(*, origin: str, name: str, eye=(2.6, 2.2, 1.6), target=(0.0, 0.0, 0.0), contents=None) -> rrb.Spatial3DView:
    """A 3-D view with its camera set: at ``eye`` looking at ``target`` (the view's frame), Z up.

    The default eye, front-left and above (+X, +Y, +Z), sees a housing's nose, left side and top.
    """
    return rrb.Spatial3DView(origin=origin, name=name, contents="$origin/**" if contents is None else contents,
                             eye_controls=rrb.EyeControls3D(kind="Orbital", position=list(eye),
                                                            look_target=list(target), eye_up=[0.0, 0.0, 1.0]))


def blueprint(root, timeline: str) -> rrb.Blueprint:
    """The recording's default layout: ``root`` across the window, side panels collapsed, the time
    panel on ``timeline`` (collapsed to its scrubber)."""
    return rrb.Blueprint(root, rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(timeline=timeline, state="collapsed"))
