"""Rerun logging of the live attitude (optional: needs ``pip install compass-toolkit[rerun]``).

Entities (world frame NWU, housing FLU, SPEC section 1), on timelines ``t`` (sample time, a
duration in seconds) and ``sample`` (running sample number):

========================== ======================================================================
entity                     content
========================== ======================================================================
``world``                  view coordinates: right-handed, Z up (static)
``world/housing``          ``Transform3D`` quaternion ``R_world<-housing`` (x, y, z, w)
``world/housing/box``      the housing as a box, X forward (static)
``world/field``            ``Arrows3D``: the measured field rotated into the world, over |B_ref|
``world/gravity``          ``Arrows3D``: the measured gravity (down), rotated into the world, unit
``compass/heading_deg``    ``Scalars`` (also ``pitch_deg``, ``roll_deg``)
``compass/field_ratio``    ``Scalars``: |B| / |B_ref|
``compass/dip_deg``        ``Scalars``: measured dip
``compass/gate``           ``Scalars``: 1 field used, 0 rejected by the disturbance gate
``events``                 ``TextLog``: connects, disconnects, headers, garbage, gate changes
========================== ======================================================================

Samples are buffered and sent as columns (``send_columns``) every ``flush_s``: one call per
entity and batch instead of one per sample keeps 1 kHz streams cheap.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["RerunSink", "ENTITIES"]

_SCALARS = ("heading_deg", "pitch_deg", "roll_deg", "field_ratio", "dip_deg", "gate")
ENTITIES = ("world", "world/housing", "world/housing/box", "world/field", "world/gravity", "events",
            *(f"compass/{name}" for name in _SCALARS))
_HOUSING_HALF_SIZES = [0.5, 0.3, 0.1]


class RerunSink:
    """Send the filter's output to Rerun: a viewer (``"spawn"``) or an ``.rrd`` file.

    Parameters
    ----------
    target : str or path
        ``"spawn"`` starts a viewer (needs a desktop); anything else is an .rrd file to write.
    application_id : str
    flush_s : float
        Longest time samples wait in the buffer, seconds.
    recording_id : str, optional

    Raises
    ------
    ImportError
        rerun-sdk is not installed.
    """

    def __init__(self, target, *, application_id: str = "compass_live", flush_s: float = 0.05,
                 recording_id: str | None = None):
        import rerun as rr

        self._rr = rr
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        if str(target) == "spawn":
            self.rec.spawn()
        else:
            self.rec.save(str(target))
        self.flush_s = flush_s
        self._rows: list[tuple] = []
        self._last_flush = time.perf_counter()
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log("world/housing/box", rr.Boxes3D(half_sizes=[_HOUSING_HALF_SIZES], colors=[[90, 140, 220]],
                                                      labels=["housing (X forward)"]), static=True)
        for name, color in (("field", [220, 60, 60]), ("gravity", [60, 180, 60])):
            self.rec.log(f"world/{name}", rr.Arrows3D.from_fields(colors=[color]), static=True)
        self.rec.log("compass/gate", rr.SeriesPoints(names=["field used"]), static=True)

    def log(self, t_s: float, sample: int, estimate, field_h, accel) -> None:
        """Buffer one sample; sends the buffer when it is ``flush_s`` old.

        Parameters
        ----------
        t_s : float
            Sample time, seconds.
        sample : int
            Running sample number.
        estimate : compass.filter.Estimate
        field_h : ndarray, shape (3,)
            Measured field in H, in units of the reference |B| (|B| / |B_ref| long).
        accel : ndarray, shape (3,), or None
            Accelerometer in H, any unit.
        """
        matrix = estimate.rotation.as_matrix()
        down = np.full(3, np.nan) if accel is None else -(matrix @ (accel / np.linalg.norm(accel)))
        self._rows.append((t_s, sample, estimate.rotation.as_quat(), matrix @ field_h, down, estimate.heading_deg,
                           estimate.pitch_deg, estimate.roll_deg, estimate.field_ratio, estimate.dip_deg,
                           float(estimate.mag_used)))
        if time.perf_counter() - self._last_flush >= self.flush_s:
            self.flush()

    def event(self, t_s: float, sample: int, text: str, level: str = "info") -> None:
        """Log a text event at once (flushing buffered samples first, to keep the order)."""
        rr = self._rr
        self.flush()
        self.rec.set_time("t", duration=t_s)
        self.rec.set_time("sample", sequence=sample)
        level = {"info": rr.TextLogLevel.INFO, "warn": rr.TextLogLevel.WARN}.get(level, rr.TextLogLevel.ERROR)
        self.rec.log("events", rr.TextLog(text, level=level))

    def flush(self) -> None:
        """Send the buffered samples as columns."""
        self._last_flush = time.perf_counter()
        if not self._rows:
            return
        rr, rec = self._rr, self.rec
        t, seq, quat, field_w, down, *scalars = (np.array(c) for c in zip(*self._rows))
        self._rows = []
        index = [rr.TimeColumn("t", duration=t), rr.TimeColumn("sample", sequence=seq)]
        rec.send_columns("world/housing", indexes=index, columns=rr.Transform3D.columns(quaternion=quat))
        rec.send_columns("world/field", indexes=index, columns=rr.Arrows3D.columns(vectors=field_w))
        rec.send_columns("world/gravity", indexes=index, columns=rr.Arrows3D.columns(vectors=down))
        for name, values in zip(_SCALARS, scalars):
            rec.send_columns(f"compass/{name}", indexes=index, columns=rr.Scalars.columns(scalars=values))

    def close(self) -> None:
        """Send what is buffered, then flush and finish the recording (writes the file's footer)."""
        self.flush()
        self.rec.disconnect()
