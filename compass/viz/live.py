"""Rerun output of ``compass live``: the filter's estimates in batches, the 3-D views at display rate.

Entities and their meaning: :mod:`compass.viz.attitude`; timelines ``t`` (sample time, a duration)
and ``sample`` (the running sample number, as the CSV's row order). Samples are buffered and sent
as columns (``send_columns``) every ``flush_s`` of sample time: one call per entity and batch instead
of one per sample. The 3-D views (housing, field and gravity arrows) get at most ``frame_rate_hz`` frames a
second of sample time, sent in the same batches: a viewer shows no more.
"""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy.spatial.transform import Rotation

from . import _layout
from ._stream import Recording, columns_index
from .attitude import attitude_views, log_attitude_statics, log_reference, send_attitude, send_frames, send_raw

__all__ = ["RerunSink", "ENTITIES", "live_blueprint"]

ENTITIES = ("world/housing", "world/housing/body", "world/housing/axes", "world/field", "world/reference_field",
            "housing/field", "housing/expected", "housing/expected/field_gate", "housing/gravity",
            "housing/expected/gravity_gate", "events",
            "raw/mag", "raw/accel", *(f"compass/{name}" for name in (
                "heading_deg", "pitch_deg", "roll_deg", "heading_deg/sigma_band", "pitch_deg/sigma_band",
                "roll_deg/sigma_band", "field_ratio", "field_ratio/gate_limits", "dip_deg", "dip_deg/gate_limits",
                "gate", "mag_used", "accel_used", "in_range", "latency_ms")))
VIEWER_FLUSH_S = 0.05
FILE_FLUSH_S = 5.0
_MAX_ROWS = 5000  # most samples buffered whatever their times
_FLOAT_COLUMNS = ("heading_deg", "pitch_deg", "roll_deg", "heading_sigma_deg", "tilt_sigma_deg", "field_ratio",
                  "dip_deg", "gate", "mag_used", "accel_used", "in_range", "latency_ms", "heading_true_deg",
                  "heading_true_sigma_deg")


def live_blueprint() -> rrb.Blueprint:
    """The layout of a live recording (:func:`compass.viz.attitude.attitude_views`)."""
    return _layout.blueprint(attitude_views(), "t")


class RerunSink:
    """Send the live filter's output to Rerun: a viewer (``"spawn"``) or an ``.rrd`` file.

    Parameters
    ----------
    target : str or path
        ``"spawn"`` or an .rrd file (written under a temporary name, renamed by :meth:`close`).
    channels : sequence of str
        The calibration's channel names (the raw magnetometer series).
    dip_deg : float
        The calibration's dip (the reference field drawn in the world; the dip gate's centre).
    field_tolerance, dip_tolerance_deg, accel_tolerance : float
        The gate's limits (:class:`compass.filter.FilterConfig`).
    application_id, recording_id : str
    flush_s : float, optional
        Longest time samples wait in the buffer, seconds. Default: 0.05 to a viewer (it shows them
        at once), :data:`FILE_FLUSH_S` to a file (read only once complete, so larger, fewer chunks:
        a 20 s session at 0.05 s was 6,200 chunks, minutes to load; ``tools/bench_live_rrd.py``).
    frame_rate_hz : float
        Most 3-D frames per second (sample time).

    Raises
    ------
    ImportError
        rerun-sdk is not installed.
    """

    def __init__(self, target, *, channels=("mx", "my", "mz"), dip_deg: float = 60.0, field_tolerance: float = 0.1,
                 dip_tolerance_deg: float = 10.0, accel_tolerance: float = 0.1, application_id: str = "compass_live",
                 flush_s: float | None = None, frame_rate_hz: float = 30.0, recording_id: str | None = None):
        self.recording = Recording(target, application_id=application_id, blueprint=live_blueprint(),
                                   recording_id=recording_id)
        self.rec = self.recording.rec
        if flush_s is None:
            flush_s = VIEWER_FLUSH_S if self.recording.path is None else FILE_FLUSH_S
        self.flush_s, self.frame_s = flush_s, 1.0 / frame_rate_hz
        self.dip_deg, self.field_tolerance = dip_deg, field_tolerance
        self.dip_tolerance_deg, self.accel_tolerance = dip_tolerance_deg, accel_tolerance
        self._rows: list[tuple] = []
        self._frames: list[tuple] = []
        self._raw: list = []
        self._accel: list = []
        self._gyro: list = []
        self._pending: list = []  # events before the first sample
        self._gravity = None
        self._buffer_t0 = None  # sample time of the first buffered sample
        self._last_frame_t = -np.inf  # sample time of the last 3-D frame
        self._started = False
        log_attitude_statics(self.rec, dip_deg=dip_deg, channels=channels, field_tolerance=field_tolerance,
                             dip_tolerance_deg=dip_tolerance_deg, accel_tolerance=accel_tolerance)

    @classmethod
    def for_model(cls, target, model, config, **options):
        """A sink with the channel names and gate limits of a calibration and its filter configuration."""
        return cls(target, channels=model.channels, dip_deg=config.dip_deg, field_tolerance=config.field_tolerance,
                   dip_tolerance_deg=config.dip_tolerance_deg, accel_tolerance=config.accel_tolerance, **options)

    def set_reference(self, dip_deg: float, description: str | None = None) -> None:
        """The filter's reference field changed (a site's, or the first quiet second's): redraw it.

        ``description`` (where the reference came from) is the caller's event line; the arrow's label
        stays short.
        """
        self.dip_deg = float(dip_deg)
        log_reference(self.rec, dip_deg=self.dip_deg, field_tolerance=self.field_tolerance,
                      dip_tolerance_deg=self.dip_tolerance_deg)

    def log(self, t_s: float, sample: int, estimate, field_h, accel, *, raw=None, gyro=None, gate_code: int = 0,
            in_range: bool = True, latency_ms: float = np.nan, true_heading=(np.nan, np.nan)) -> None:
        """Buffer one sample; sends the buffer when it is ``flush_s`` old.

        Parameters
        ----------
        t_s : float
            Sample time, seconds.
        sample : int
            Running sample number.
        estimate : compass.filter.Estimate
        field_h : ndarray, shape (3,)
            Measured field in H over the reference |B|.
        accel : ndarray, shape (3,), or None
            Accelerometer in H, any unit.
        raw : ndarray, shape (c,), optional
            The sample's magnetometer channels, recording units.
        gyro : ndarray, shape (3,), optional
            The sample's gyro, rad/s.
        gate_code : int
            The CSV's ``gate`` code of this estimate.
        in_range : bool
        latency_ms : float
            The CSV's ``latency_ms``: chunk read from the port to this estimate, ms.
        true_heading : (float, float)
            ``heading_true_deg`` and its sigma (with a site), degrees; NaN without.
        """
        e = estimate
        self._rows.append((t_s, sample, e.heading_deg, e.pitch_deg, e.roll_deg, e.heading_sigma_deg, e.tilt_sigma_deg,
                           e.field_ratio, e.dip_deg, gate_code, e.mag_used, e.accel_used, in_range, latency_ms,
                           *true_heading))
        self._raw.append(raw)
        self._accel.append(accel)
        self._gyro.append(gyro)
        if accel is not None and self._gravity is None:
            self._gravity = float(np.linalg.norm(accel)) or None
        if t_s - self._last_frame_t >= self.frame_s:
            self._last_frame_t = t_s
            down = np.full(3, np.nan) if accel is None or self._gravity is None else -np.asarray(accel) / self._gravity
            self._frames.append((t_s, sample, e.rotation.as_quat(), field_h, down))
        if self._buffer_t0 is None:
            self._buffer_t0 = t_s
        # by sample time (a file's chunks do not depend on how fast the machine was); a clock that
        # went back (the module restarted) or a full buffer flushes too
        if not 0.0 <= t_s - self._buffer_t0 < self.flush_s or len(self._rows) >= _MAX_ROWS:
            self.flush()

    def event(self, t_s: float, sample: int, text: str, level: str = "info") -> None:
        """Log a text event at once (flushing buffered samples first, to keep the order).

        Events before the first sample are stamped with the first sample's time when it comes
        (held until then), so the events timeline starts where the data do.
        """
        self.flush()
        if not self._started:
            self._pending.append((text, level))
            return
        self._log_event(t_s, sample, text, level)

    def _log_event(self, t_s, sample, text, level) -> None:
        levels = {"info": rr.TextLogLevel.INFO, "warn": rr.TextLogLevel.WARN}
        self.rec.set_time("t", duration=t_s)
        self.rec.set_time("sample", sequence=sample)
        self.rec.log("events", rr.TextLog(text, level=levels.get(level, rr.TextLogLevel.ERROR)))

    def flush(self) -> None:
        """Send the buffered samples as columns."""
        self._buffer_t0 = None
        if not self._rows:
            return
        rows, raw, accel, gyro = np.array(self._rows, dtype=float), self._raw, self._accel, self._gyro
        self._rows, self._raw, self._accel, self._gyro = [], [], [], []
        index = columns_index(rows[:, 0], rows[:, 1].astype(np.int64))
        columns = dict(zip(_FLOAT_COLUMNS, rows[:, 2:].T))
        if np.all(np.isnan(columns["heading_true_deg"])):
            del columns["heading_true_deg"], columns["heading_true_sigma_deg"]
        send_attitude(self.rec, index, columns,
                      field_limits=(1 - self.field_tolerance, 1 + self.field_tolerance),
                      dip_limits=(self.dip_deg - self.dip_tolerance_deg, self.dip_deg + self.dip_tolerance_deg))
        send_raw(self.rec, index, mag=None if raw[0] is None else _stack(raw, len(raw[0])),
                 accel=None if all(a is None for a in accel) else _stack(accel, 3),
                 gyro=None if all(g is None for g in gyro) else _stack(gyro, 3))
        if self._frames:
            t, seq, quat, field_h, down = (np.array(c) for c in zip(*self._frames))
            self._frames = []
            send_frames(self.rec, columns_index(t, seq), Rotation.from_quat(quat), field_h,
                        None if np.all(np.isnan(down)) else down)
        if not self._started:
            self._started = True
            for text, level in self._pending:
                self._log_event(rows[0, 0], int(rows[0, 1]), text, level)
            self._pending = []

    def close(self) -> None:
        """Send what is buffered, then finish the recording (footer written, file in place)."""
        self.flush()
        self.recording.close()

    def discard(self) -> None:
        """Stop without writing the file: nothing was recorded (an existing file stays as it was)."""
        self.recording.discard()


def _stack(values, width: int) -> np.ndarray:
    """Rows of a buffer as an (n, width) array, NaN where a row had none."""
    return np.array([np.full(width, np.nan) if v is None else v for v in values], dtype=float)
