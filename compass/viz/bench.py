"""The bench station's session in Rerun (``compass bench --rerun FILE.rrd|spawn``).

The cube turns on the table as each kept flip's rows say, each flip's coverage fills in on a ring
of its own around the table as its turn goes, the module's outputs and the degrees covered are
plotted against the module's time, and the station's instructions and warnings are listed.  A flip
is drawn when the station keeps it (its rows at their own times: the replay shows the turn as it
was made); the degrees covered and the words are logged as they come, so a spawned viewer follows
the turn in progress.

Entities (timeline ``t``: the module's time, seconds):

=================================== ================================================================
entity                              content
=================================== ================================================================
``bench/turntable``                 ``Transform3D`` Rz(platform_deg); a ring with its zero mark
``bench/turntable/cube``            ``Transform3D`` Rx(flip_deg); the housing (FLU) with its axes
``bench/coverage/flip_KKK``         the flip's ring of 5-degree cells: grey, then the flip's colour
                                    once visited (filling in as the turn goes)
``bench/coverage/labels``           the rings' names, at their zero (static)
``coverage/flip_KKK``               degrees of the circle covered in the flip, as the station saw it
``outputs/<channel>``               the kept rows' outputs, the module's units
``events``                          ``TextLog``: instructions, redos, warnings, flips kept
=================================== ================================================================
"""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy.spatial.transform import Rotation

from ..io.fourflip import NOMINAL_FLIPS_DEG
from . import _layout
from ._drawing import log_housing

__all__ = ["BenchRecording", "bench_views"]

CELL_DEG = 5.0
_RING_RADIUS = 1.6  # the first flip's ring; the next ones 0.25 further out (the table's ring is at 1.4)
_RING_STEP = 0.25
_FLOOR = -0.35
_FLIP_COLORS = np.array([[230, 120, 40], [40, 170, 90], [30, 120, 220], [170, 70, 200]], dtype=np.uint8)
_GREY = np.array([110, 110, 110], dtype=np.uint8)
_FRAMES = 90  # cube poses and ring states drawn per flip
_CELLS = np.arange(0.0, 360.0, CELL_DEG)


def bench_views(channels) -> rrb.Container:
    """The layout: the bench in 3-D beside the degrees covered and the outputs; the words across the bottom (an
    instruction is a long line)."""
    return rrb.Vertical(
        rrb.Horizontal(
            _layout.spatial(origin="/bench", name="the cube on the turntable; rings: each flip's coverage "
                                                  "(inner: flip 0; grey: not yet visited)", eye=(3.9, 3.1, 2.9),
                            target=(0.0, 0.0, -0.3)),
            rrb.Vertical(
                _layout.series(origin="/coverage", name="degrees of the circle covered, per flip"),
                _layout.series(origin="/outputs", name=f"outputs of the flips kept ({', '.join(channels)}; "
                                                       f"module units)"),
                row_shares=[1, 2]),
            column_shares=[1, 1]),
        _layout.text_log(origin="/events", name="what the station said"),
        row_shares=[3, 1], name="bench session")


class BenchRecording:
    """A bench session recorded (or streamed) as it goes.

    Parameters
    ----------
    target : str or path
        ``spawn`` or an ``.rrd`` file (checked with :func:`compass.viz.check_rerun_target`).
    channels : sequence of str
        The module's magnetic channels.
    """

    def __init__(self, target, channels):
        from ._stream import Recording

        self.channels = tuple(channels)
        self.recording = Recording(target, application_id=_layout.APPLICATION_IDS["bench"],
                                   blueprint=_layout.blueprint(bench_views(self.channels), "t"))
        self.rec = self.recording.rec
        self._t_s = 0.0
        self._static()

    def _static(self) -> None:
        rec = self.rec
        rec.set_time("t", duration=0.0)
        phi = np.linspace(0.0, 2.0 * np.pi, 73)
        ring = np.column_stack([1.4 * np.cos(phi), 1.4 * np.sin(phi), np.full(phi.shape, -0.3)])
        rec.log("bench/turntable/ring", rr.LineStrips3D([ring, [[0.0, 0.0, -0.3], [1.4, 0.0, -0.3]]],
                                                        colors=[[120, 120, 120]]), static=True)
        log_housing(rec, "bench/turntable/cube", color=(200, 200, 200), label="cube (housing)", scale=0.8)
        # each ring named at its own angle, fanned out at the viewer's side, so that no two names stack on screen
        at = np.radians(-20.0 - 28.0 * np.arange(len(NOMINAL_FLIPS_DEG)))
        radii = _RING_RADIUS + _RING_STEP * np.arange(len(NOMINAL_FLIPS_DEG))
        rec.log("bench/coverage/labels", rr.Points3D(
            np.column_stack([radii * np.cos(at), radii * np.sin(at), np.full(len(at), _FLOOR)]), radii=[0.01],
            colors=_FLIP_COLORS, labels=[f"flip {f:g}" for f in NOMINAL_FLIPS_DEG], show_labels=True), static=True)
        for k, flip in enumerate(NOMINAL_FLIPS_DEG):
            self._ring(k, np.zeros(len(_CELLS), bool))
            rec.log(f"coverage/{_name(flip)}", rr.SeriesLines(names=[f"flip {flip:g}"], colors=[_FLIP_COLORS[k]]),
                    static=True)
        for j, name in enumerate(self.channels):
            rec.log(f"outputs/{name}", rr.SeriesPoints(names=[name], marker_sizes=[1.0]), static=True)

    def _ring(self, k: int, covered: np.ndarray) -> None:
        r = _RING_RADIUS + _RING_STEP * k
        a = np.radians(_CELLS + CELL_DEG / 2)
        colors = np.where(covered[:, None], _FLIP_COLORS[k], _GREY)
        self.rec.log(f"bench/coverage/{_name(NOMINAL_FLIPS_DEG[k])}", rr.Points3D(
            np.column_stack([r * np.cos(a), r * np.sin(a), np.full(a.shape, _FLOOR)]), colors=colors,
            radii=np.where(covered, 0.035, 0.02)))

    def event(self, t_s: float | None, level: str, text: str) -> None:
        """A line the station said (at module time ``t_s``, or the last one seen)."""
        self._at(t_s)
        self.rec.log("events", rr.TextLog(text, level=rr.TextLogLevel.WARN if level == "warn" else
                                          rr.TextLogLevel.INFO))

    def progress(self, t_s: float, flip_deg: float | None, covered_deg: float) -> None:
        """The degrees covered so far in the flip being recorded."""
        if flip_deg is None:
            return
        self._at(t_s)
        self.rec.log(f"coverage/{_name(flip_deg)}", rr.Scalars(float(covered_deg)))

    def flip(self, rows) -> None:
        """A kept flip (:class:`compass.station.store.FlipRows`): the cube turning through its rows and its ring
        filling in, at the rows' times; its outputs."""
        columns = list(rows.columns)
        table = np.asarray(rows.table, dtype=float)
        t, phi = table[:, columns.index("t_s")], table[:, columns.index("platform_deg")]
        k = NOMINAL_FLIPS_DEG.index(rows.flip_deg)
        index = [rr.TimeColumn("t", duration=t)]
        for name in self.channels:
            self.rec.send_columns(f"outputs/{name}", indexes=index,
                                  columns=rr.Scalars.columns(scalars=table[:, columns.index(name)]))
        keep = np.unique(np.linspace(0, len(t) - 1, min(_FRAMES, len(t))).astype(int))
        turn = Rotation.from_euler("z", phi[keep][:, None], degrees=True).as_quat()
        flip = Rotation.from_euler("x", np.full((len(keep), 1), rows.flip_deg), degrees=True).as_quat()
        frames = [rr.TimeColumn("t", duration=t[keep])]
        self.rec.send_columns("bench/turntable", indexes=frames, columns=rr.Transform3D.columns(quaternion=turn))
        self.rec.send_columns("bench/turntable/cube", indexes=frames, columns=rr.Transform3D.columns(quaternion=flip))
        cell = (np.mod(phi, 360.0) // CELL_DEG).astype(int)
        covered = np.zeros(len(_CELLS), bool)
        start = 0
        for stop in keep:
            covered[cell[start:stop + 1]] = True
            start = stop + 1
            self.rec.set_time("t", duration=float(t[stop]))
            self._ring(k, covered)
        self._t_s = max(self._t_s, float(t[-1]))

    def _at(self, t_s: float | None) -> None:
        if t_s is not None and np.isfinite(t_s):
            self._t_s = float(t_s)
        self.rec.set_time("t", duration=self._t_s)

    def close(self) -> None:
        """Write the file (or end the stream)."""
        self.recording.close()

    def discard(self) -> None:
        self.recording.discard()


def _name(flip_deg: float) -> str:
    return f"flip_{int(flip_deg):03d}"
