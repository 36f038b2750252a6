"""The live pipeline: bytes from a port -> stream lines -> field in H -> filter -> outputs.

:class:`LiveSession` is what ``compass live`` runs, without the terminal: feed it the items of
:meth:`compass.serial_reader.SerialReader.items` and it decodes, solves, filters and writes the
attitude CSV and the Rerun recording, counting everything it had to skip.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from .calibration import ImuCorrection
from .filter import AttitudeFilter, Estimate, FilterConfig, FilterStart
from .io.clock import SampleClock
from .io.sample_log import SampleLog
from .io.streams import (HELD_JUDGE_SAMPLES, JUDGE_SAMPLES, MIN_TURNED_PAIRS, TURNED_DEG,
                         StreamDecoder, StreamOptions, field_scale_check, fixed_field_words, gravity_pairs,
                         held_field_words, time_steps_verdict, world_fixed_turn)
from .io.units import MAX_ABS_VALUE
from .iron_uncertainty import undetermined_words, with_calibration_sigma
from .sample_check import GyroRail
from .serial_reader import Chunk, LinkEvent
from .site import ReferenceField, upside_down

__all__ = ["LiveSession", "Reading", "GATE_CODES", "CSV_COLUMNS", "QUATERNION_COLUMNS"]

_CLOCK_WORDS_AFTER_S = 2.0
"""A stream without t_s is said once its dates span this, s (its rate read over them)."""
HINT_MIN_SAMPLES = 50
"""Fewest estimates a closing hint judges."""
HINT_REJECTED_SHARE = 0.8
"""Share of estimates with the field rejected above which the session ends with a hint."""
GATE_CODES = {"ok": 0, "norm": 1, "dip": 2, "innovation": 3, "absent": 4, "rail": 5, "magnet": 6}
CSV_COLUMNS = ("t_s", "heading_deg", "pitch_deg", "roll_deg", "heading_sigma_deg", "tilt_sigma_deg", "field_ratio",
               "dip_deg", "mag_used", "gate", "accel_used", "in_range", "latency_ms")
_CSV_ROW = "%.4f,%.3f,%.3f,%.3f,%.3f,%.3f,%.4f,%.2f,%d,%d,%d,%d,%.3f"
_TRUE_COLUMNS = ("heading_true_deg", "heading_true_sigma_deg")  # with a site: heading + declination
QUATERNION_COLUMNS = ("qw", "qx", "qy", "qz")
"""The attitude quaternion (scalar first, ``R_world<-housing``) a replay's CSV adds (``quaternion=True``)."""
_LATENCY_WINDOW = 100_000  # samples kept for the latency percentiles
UPSIDE_DOWN_SAMPLES = 100
"""Estimates whose median dip is judged against a given reference (compass.site.upside_down)."""
AXES_ROWS = 2000
"""Rows (every :data:`AXES_EVERY`-th estimate) the axis check (:func:`compass.axes.check_axes`) judges, once."""
AXES_EVERY = 5
GYRO_AXES_ROWS = 6000
"""Rows (every one, the gyro's turn between them integrated) the gyro's axis check (:func:`compass.axes.axes_from_gyro`)
judges, once: a minute at 100 Hz.  Rows that did not turn the housing enough (:func:`compass.axes.turned_enough`: a
module left at rest) are not judged: the older half goes and the check waits for more."""
GYRO_UNIT_WINDOW_S = 10.0
"""Seconds of rows over which the gyro's turn is judged against the calibrated field's
(:func:`compass.io.units.gyro_field_ratio`), window after window through the session until one says it: a deg/s gyro
read as rad/s is said within seconds of the first turns, not at the axis check's :data:`GYRO_AXES_ROWS`; a window
whose field turned without the housing (a magnet moved by hand) tells nothing, so no window clears it."""
FIELD_TURN_ROWS = 6000
"""Rows the field's turn check (:meth:`LiveSession._judge_field_turn`) keeps while it waits for the housing to turn;
the older half goes when they are too few turned pairs."""
FIELD_TURN_EVERY = 100
"""Rows between two tries of the field's turn check (a second at 100 Hz)."""
FIELD_TURN_SPAN_S = 10.0
"""Longest time between two rows the gyro confirms the housing's turn between, s: a still housing's gyro bias (0.01
rad/s) turns it by 6 deg meanwhile, under half of :data:`compass.io.streams.TURNED_DEG`."""


def invalid_words(stats) -> str:
    """``"3 invalid (a number no module sends, not finite or beyond 1e+12: gx = nan first)"``: a
    :class:`compass.io.lines.LineStats`'s invalid lines in words, naming the first one's cell when the decoder knows
    it (``"0 invalid"`` without one)."""
    first = "" if stats.invalid_cell is None else f": {stats.invalid_cell} first"
    return f"{stats.invalid} invalid" + (f" (a number no module sends, not finite or beyond {MAX_ABS_VALUE:g}{first})"
                                         if stats.invalid else "")


def matrix_quaternion(matrix_rows) -> tuple[float, float, float, float]:
    """``(w, x, y, z)`` of a rotation given as a row-major 9-tuple, scalar first, ``w >= 0``."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.reshape(matrix_rows, (3, 3))).as_quat(canonical=True).tolist()
    return w, x, y, z


class Reading(NamedTuple):
    """One decoded sample on its way to the filter (held in the start window).

    Attributes
    ----------
    sample : compass.io.lines.Sample
        As decoded (its header, ``t_s``, raw outputs).
    accel : ndarray, shape (3,), or None
        The accelerometer in the model's frame (``Calibration.imu`` applied), the module's unit.
    gyro : ndarray, shape (3,), or None
        The gyro in the model's frame, rad/s.
    field_h : ndarray, shape (3,)
        The field in the model's frame, field units.
    field_row : list of float
        ``field_h`` as a list (what the filter's per-sample step takes).
    in_range : bool
        Every channel inside its calibrated range.
    t_rx : float
        When its chunk was read from the port, ``time.perf_counter()`` seconds.
    """

    sample: object
    accel: np.ndarray | None
    gyro: np.ndarray | None
    field_h: np.ndarray
    field_row: list
    in_range: bool
    t_rx: float


@dataclass
class LiveSession:
    """Decode, solve and filter a live stream; write the CSV and Rerun outputs.

    Parameters
    ----------
    model : compass.model.SensorModel
        ``Calibration.model``.
    config : FilterConfig, optional
        Default :meth:`FilterConfig.from_model`.  Its ``calibration_uncertainty`` (the calibration's own, which
        ``from_model`` carries) is added to the reported heading sigma at each estimate's attitude
        (:func:`compass.iron_uncertainty.with_calibration_sigma`; a part the calibration left undetermined
        counts with a stated prior, said in a warning event).  A ``FilterConfig(...)`` built by hand has
        none (its ``calibration_uncertainty`` defaults to None): the reported sigma is then the filter's
        noise alone; build it with ``dataclasses.replace(FilterConfig.from_model(model), ...)`` to keep it.
    out : text file, optional
        Receives the attitude CSV (:data:`CSV_COLUMNS`; ``gate`` coded as :data:`GATE_CODES`).
    sink : compass.viz.RerunSink, optional
    on_event : callable, optional
        ``on_event(level, text)`` for every event (link, header, garbage, gate, filter).
    reference : compass.site.ReferenceField, optional
        The site's field (``--site``): the filter's reference |B| and dip, and with its declination
        the true heading (``heading_true_deg`` in the readout and the CSV).  Without it the
        reference is seeded from the stream's first quiet second, never the calibration bench's.
        Either way the samples of that second are held and then solved: the filter starts from the
        window (:class:`compass.filter.FilterStart`, the start :func:`compass.filter.run_filter` uses
        too), never from one row.
    imu : compass.calibration.ImuCorrection, optional
        The calibration's inertial correction (``Calibration.imu``): the module's accelerometer and
        gyro are turned into the model's frame by it (the bench's ``mag_to_accel``, an installed file's
        alignment), and the bench accelerometer's offsets and scales are undone when the stream's first
        accelerometer readings read 1 g as the bench's did (else said once and not applied).
    sign_from_bench : bool
        The calibration is a four-flip bench's, whose data cannot tell the hemisphere: an upside-down
        verdict then names that cause (:func:`compass.site.upside_down`).
    stream : compass.io.streams.StreamOptions, optional
        The stream's format and units (default: found from the first lines, the protocol's units).
    quaternion : bool
        The CSV also carries the attitude quaternion ``qw,qx,qy,qz`` (scalar first,
        ``R_world<-housing``, SPEC section 1; the replay's output).
    record : compass.io.sample_log.SampleLog, optional
        Receives every decoded sample, dated, as a recording the replay reproduces the session from
        (``compass live --record``).

    Attributes
    ----------
    decoder : compass.io.streams.StreamDecoder
        Its ``stats`` count samples and dropped lines; its ``fatal`` says why the stream cannot be used
        (channels missing, a field in another unit than the calibration's).
    estimate : Estimate or None
        The latest output.
    in_range : bool
        Every channel of the latest sample inside its calibrated range.
    latencies_s : deque of float
        Chunk read from the port -> estimate available, seconds, for the latest samples (time
        the bytes waited in the kernel while the session was busy is not included, nor the
        samples held for the first quiet second).
    output_latencies_s : deque of float
        Chunk read -> CSV row written and Rerun row buffered (or sent), seconds.
    samples : int
        Estimates produced.
    unsolved : int
        Decoded samples that gave no attitude row: no accelerometer yet, or a field reading the
        filter's screen skipped (not finite, or beyond its range: counted in ``skipped`` too), whose
        row would have no field ratio nor dip to write.
    turned_over : str or None
        Set once the first :data:`UPSIDE_DOWN_SAMPLES` estimates show the field turned over against a
        given reference (``--site``), or mirrored against the dip the calibration measured: why, in words (the
        command stops on it); None otherwise.
    rejected : dict of str to (int, float, float)
        Estimates whose field the gate rejected, by gate: count, sum of ``field_ratio``, sum of
        ``dip_deg`` (for :meth:`closing_hint`).
    wrong_gravity : str or None
        Set when the start window is complete and the given gravity (``FilterConfig.gravity``, ``--gravity``), or
        the unit of the calibration's accelerometer correction, is not what 1 g reads
        (:attr:`compass.filter.FilterStart.gravity_words`): why, in words; the session then solves
        nothing more (the commands stop on it, as on :attr:`turned_over`); None otherwise.
    wrong_time : str or None
        Set when the module's first :data:`~compass.io.streams.JUDGE_SAMPLES` times do not tell the filter the time
        between samples (:func:`~compass.io.streams.time_steps_verdict`: ``t_s`` in milliseconds restarts the gyro
        filter at every sample, one that never changes turns nothing): why, in words; the commands stop on it, as
        the replay refuses such a recording; None otherwise, and for a stream without a gyro (the two-vector filter
        solves each row alone: said only).
    gyro_unit : str or None
        Set when the decoder finds the gyro would be fused wrong against the accelerometer's tilt
        (:func:`compass.io.units.gyro_fault_words`, the replay's refusal), or when it turns more than
        :data:`compass.io.units.FIELD_UNIT_RATIO` times the calibrated field over a :data:`GYRO_UNIT_WINDOW_S` window (a deg/s gyro read as rad/s turns the attitude 57 times too fast; a field
        read in a unit too small stays put): why, in words; the commands stop on it, as on :attr:`wrong_field`;
        None otherwise.
    wrong_field : str or None
        Set once the housing turned (gravity by :data:`~compass.io.streams.TURNED_DEG` between
        :data:`~compass.io.streams.MIN_TURNED_PAIRS` pairs of quasi-static rows, the gyro confirming the turn) while
        the calibrated field stayed put in it (:func:`~compass.io.streams.fixed_field_words`: gauss read as uT with a
        hard iron near |B| passes the decoder's norm check): why, and the unit that makes it turn, in words; the
        session then solves nothing more and the commands stop on it (exit 2); None otherwise.
    axes : str or None
        Set when the field-gravity angle of the first :data:`AXES_ROWS` sampled estimates (or of the whole
        stream, on close) wanders in a way one sign pattern of the field's axes removes: what to
        negate, in words (said as a warning event); or when the field's turns over the first
        :data:`GYRO_AXES_ROWS` rows match the gyro's only with other axes (:func:`compass.axes.axes_from_gyro`): what
        they are; None otherwise.
    skipped : dict of str to int
        Readings never fused, by reason (:data:`compass.filter.SKIP_REASONS`): the filter's screen (a
        non-finite or out-of-range sensor part is skipped, the rest of the sample used) and, in the
        start window, :func:`compass.sample_check.skip_codes` (the whole sample).
    """

    model: object
    config: FilterConfig | None = None
    out: object = None
    sink: object = None
    on_event: object = None
    reference: object = None
    imu: ImuCorrection = field(default_factory=ImuCorrection)
    sign_from_bench: bool = True
    stream: StreamOptions | None = None
    quaternion: bool = False
    record: SampleLog | None = None
    decoder: StreamDecoder = field(init=False)
    turned_over: str | None = None
    wrong_gravity: str | None = None
    wrong_time: str | None = None
    gyro_unit: str | None = None
    wrong_field: str | None = None
    axes: str | None = None
    estimate: Estimate | None = None
    in_range: bool = True
    latencies_s: deque = field(default_factory=lambda: deque(maxlen=_LATENCY_WINDOW))
    output_latencies_s: deque = field(default_factory=lambda: deque(maxlen=_LATENCY_WINDOW))
    samples: int = 0
    unsolved: int = 0
    skipped: dict = field(default_factory=dict)
    rejected: dict = field(default_factory=dict)
    _filter: AttitudeFilter | None = None
    _t0: float | None = None
    _bad_reported: int = 0
    _bad_reported_at: float = 0.0
    _gate: str = "ok"
    _temp_c: float | None = None
    _raw: tuple | None = None  # the last magnetometer reading as sent: a repeat is that reading held
    _header_seen: object = None
    _start: FilterStart | None = None
    _axes_rows: list | None = field(default_factory=list)  # (accel, field) pairs for the axis check; None once judged
    _gyro_axes_rows: list | None = field(default_factory=list)  # (t_s, gyro, field, accel) for the gyro's axis check
    _unit_rows: list = field(default_factory=list)  # (t_s, gyro, field) of the gyro unit's window
    _turn_rows: list | None = field(default_factory=list)  # (t_s, accel, gyro, raw) for the field's turn check
    _dips: list | None = None  # measured dips of the first estimates, against a given reference
    _dip_reference: ReferenceField | None = None  # the reference they are judged against: the given, or the
    # calibration's own dip
    _bench_accel: bool | None = None  # the bench's offsets apply to this stream's unit; None: not judged yet
    _times: list | None = field(default_factory=list)  # the first samples' t_s for the step check; None once judged
    _held: list | None = field(default_factory=list)  # the first (t_s, raw) for the held-reading words; None once said
    _rail: GyroRail = field(default_factory=GyroRail)  # a gyro axis held at its range: said once
    _last_rx: float = 0.0
    _clock: SampleClock = field(default_factory=SampleClock)  # dates the samples of a stream without t_s
    _clock_said: bool = False

    def __post_init__(self):
        self.decoder = StreamDecoder(self.model.channels, self.stream, field_check=field_scale_check(self.model))
        if self.config is None:
            self.config = FilterConfig.from_model(self.model)
        # the user's reference, else the dip the calibration measured: check the stream's field is not turned over
        self._dip_reference = self.reference if self.reference is not None else self._calibration_dip()
        if self._dip_reference is not None:
            self._dips = []
        # the site's reference (also one whose |B| is unknown in a calibration's unit that is not the uT: the
        # start completes it) or, without a site, the stream's own
        self._start = FilterStart(self.config, self.reference)
        if self.reference is not None and np.isfinite(self.reference.field_norm):
            self._use_reference(self.reference)
        words = undetermined_words(self.config.calibration_uncertainty, self.config.field_norm, self.config.dip_deg)
        if words is not None:
            self._event("warn", words)
        if self.out is not None:
            self.out.write(f"# gate: {', '.join(f'{v} {k}' for k, v in GATE_CODES.items())}\n"
                           + ",".join(CSV_COLUMNS + (_TRUE_COLUMNS if self._declination is not None else ())
                                      + (QUATERNION_COLUMNS if self.quaternion else ())) + "\n")

    @property
    def _declination(self):
        return None if self.reference is None else self.reference.declination_deg

    @property
    def stopped(self) -> bool:
        """Whether the session found a reason its attitudes are wrong (:attr:`turned_over`, :attr:`wrong_gravity`,
        :attr:`wrong_time`, :attr:`wrong_field`, :attr:`gyro_unit`): it solves nothing more, keeps no output but
        ``--record``, and the commands stop on it in its words."""
        return any(words is not None for words in (self.turned_over, self.wrong_gravity, self.wrong_time,
                                                   self.wrong_field, self.gyro_unit))

    def _calibration_dip(self) -> ReferenceField | None:
        """The dip the calibration measured against its own accelerometer as a reference to judge the stream's field
        turned over by (:func:`~compass.site.upside_down`: an accelerometer that reads gravity turns the dip's
        sign); None where the calibration's dip sign is an assumption (a four-flip bench without its latitude) or
        it has none."""
        dip = self.model.dip_deg
        if self.sign_from_bench or dip is None or not np.isfinite(dip):
            return None
        return ReferenceField(float(dip), 0.0, float(self.model.field_norm), 0.0, "calibration",
                              f"the calibration's dip {dip:+.1f} deg")

    def _use_reference(self, reference) -> None:
        self.reference = reference
        self.config = replace(self.config, field_norm=reference.field_norm, dip_deg=reference.dip_deg)
        self._filter = None  # one made before (samples of a header without accelerometer) had the bench's field
        self._event("info", f"reference field: {reference.description}")
        if self.sink is not None:
            self.sink.set_reference(reference.dip_deg, reference.description)

    def feed(self, item: Chunk | LinkEvent) -> None:
        """Process one item of :meth:`SerialReader.items`."""
        if isinstance(item, LinkEvent):
            if item.kind == "connected":
                self.decoder.resync()
                self._clock.restart()
            self._event("warn" if item.kind == "disconnected" else "info", item.message)
            return
        if self._t0 is None:
            self._t0 = item.t_rx
        self._last_rx = item.t_rx
        samples = self.decoder.feed(item.data, item.t_rx)
        if samples:
            self._chunk(samples, item.t_rx)
        if self.decoder.fatal is not None:
            self._record_withheld(item.t_rx)
        if self.decoder.events:
            for level, text in self.decoder.drain_events():
                self._event(level, text)
        stats = self.decoder.stats
        bad = stats.garbage + stats.partial + stats.invalid
        if bad != self._bad_reported and item.t_rx - self._bad_reported_at >= 1.0:
            self._event("warn", f"line noise: {stats.garbage} garbage, {stats.partial} partial and "
                                f"{invalid_words(stats)} lines so far")
            self._bad_reported, self._bad_reported_at = bad, item.t_rx

    def feed_samples(self, samples: list, t_rx: float) -> None:
        """Process samples decoded elsewhere (a recording's rows: :func:`compass.replay.replay`), in order;
        each carries its :class:`~compass.io.lines.Header`, and ``t_rx`` stands for their arrival time."""
        if self._t0 is None:
            self._t0 = t_rx
        self.decoder.stats.samples += len(samples)
        if samples:
            self._chunk(samples, t_rx)

    def _chunk(self, samples: list, t_rx: float) -> None:
        """A chunk's samples: what is not sequential once for all of them (the calibration's field, the
        reference seeding's screen), then each sample through the seeding or the filter."""
        self._judge_steps(samples)  # the module's own t_s
        samples = self._dated(samples, t_rx)
        if self.record is not None:
            stopped = self.record.write(samples, self.decoder.options.accel_known(self.decoder.format))
            if stopped is not None:
                self._event("warn", stopped)
        if self.gyro_unit is None and self.decoder.gyro_fault is not None:  # against the accelerometer's tilt, as
            self.gyro_unit = self.decoder.gyro_fault  # the replay refuses it
            self._event("warn", self.gyro_unit)
        self._judge_rail(samples)
        self._judge_held(samples)
        fields, in_range = self._fields(samples)
        field_rows, in_range = fields.tolist(), in_range.tolist()
        imu = self.imu
        bench = self._judge_accel(samples)
        readings = []
        for k, sample in enumerate(samples):
            accel, gyro = sample.accel, sample.gyro
            accel = None if accel is None else imu.apply(accel, bench=bench)
            gyro = None if gyro is None else imu.rotate(gyro)
            readings.append(Reading(sample, accel, gyro, fields[k], field_rows[k], in_range[k],
                                    t_rx if sample.t_rx is None else sample.t_rx))  # its arrival, if the decoder held it
        for reading in readings:
            if self.stopped:
                return
            if self._start is not None and reading.sample.header.accel is not None:
                # without an accelerometer there is no attitude, and nothing to seed the reference from: the
                # filter is made at once and says so (holding the samples would grow without end)
                self._starting(reading)
            else:
                self._sample(reading)

    def _record_withheld(self, t_rx: float) -> None:
        """Write the samples the decoder withheld for its unit check under ``--record`` (the session stops on its
        words: what the module sent is kept, as before any other stop)."""
        withheld = self.decoder.take_withheld()
        if withheld and self.record is not None:
            self.record.write(self._dated(withheld, t_rx), self.decoder.options.accel_known(self.decoder.format))

    def _dated(self, samples: list, t_rx: float) -> list:
        """The samples, those without ``t_s`` dated by :class:`~compass.io.clock.SampleClock` from their arrival
        (their chunk's, or the decoder's when it held them), seconds since the session's first chunk; the samples
        the decoder knows lost counted in their place."""
        if all(s.t_s is not None for s in samples):
            return samples
        dated = self._clock.dated(samples, t_rx, self._t0)
        period = self._clock.period_s
        if not self._clock_said and period is not None and dated[-1].t_s >= _CLOCK_WORDS_AFTER_S:
            self._clock_said = True
            self._event("info", f"the module sends no t_s: its samples are dated from when they arrive, one period "
                                f"apart ({1.0 / period:.1f} Hz), not in the port's bursts")
        return dated

    def _judge_steps(self, samples: list) -> None:
        """Say once when the module's ``t_s`` does not tell the filter the time between samples
        (:func:`~compass.io.streams.time_steps_verdict`, which the replay refuses), judged on its first
        :data:`~compass.io.streams.JUDGE_SAMPLES` samples: a clock not running, a counter not sent, a firmware's
        milliseconds sent as t_s."""
        if self._times is None:
            return
        self._times += [s.t_s for s in samples if s.t_s is not None]
        if len(self._times) < JUDGE_SAMPLES:
            return
        verdict, self._times = time_steps_verdict(self._times[:JUDGE_SAMPLES], self.config.max_gap_s), None
        if verdict is None:
            return
        if samples[-1].header is not None and samples[-1].header.gyro is None:  # each row solved alone: said only
            self._event("warn", f"the module's {verdict}")
            return
        # the gyro filter restarts at every step, or integrates no turn: the commands stop on it
        self.wrong_time = (f"the module's {verdict}; send t_s in seconds, or leave it out (the samples are then "
                           "dated by their arrival)")
        self._event("warn", self.wrong_time)

    def _judge_held(self, samples: list) -> None:
        """Say once (info) when the magnetometer repeats its last reading on many of the first
        :data:`~compass.io.streams.HELD_JUDGE_SAMPLES` rows (:func:`~compass.io.streams.held_field_words`): the
        filter fuses each reading once (``compass.filter._gyro``), and the person learns the magnetometer's rate."""
        if self._held is None:
            return
        self._held += [(s.t_s, s.raw) for s in samples]
        if len(self._held) < HELD_JUDGE_SAMPLES:
            return
        rows, self._held = self._held[:HELD_JUDGE_SAMPLES], None
        words = held_field_words([r for _, r in rows], [t for t, _ in rows])
        if words is not None:
            self._event("info", words)

    def _judge_rail(self, samples: list) -> None:
        """Say once when a gyro axis holds its range (:class:`compass.sample_check.GyroRail`), on the gyro as sent."""
        if self._rail.said:
            return
        sent = [s for s in samples if s.gyro is not None]
        if sent:
            words = self._rail.feed([s.gyro for s in sent], [s.t_s for s in sent])
            if words is not None:
                self._event("warn", words)

    def _judge_accel(self, samples: list) -> bool:
        """Whether the bench's accelerometer offsets and scales apply: judged once, on the first chunk with
        accelerometer readings (:meth:`compass.calibration.ImuCorrection.fits`)."""
        if not self.imu.has_bench_correction:
            return False
        if self._bench_accel is None:
            accel = [s.accel for s in samples if s.accel is not None]
            if not accel:
                return False
            self._bench_accel = self.imu.fits(np.array(accel))
            if not self._bench_accel:
                self._event("warn", self.imu.not_fitting)
        return self._bench_accel

    def _fields(self, samples: list) -> tuple[np.ndarray, np.ndarray]:
        """The samples' field in H (temperature-compensated when the calibration can), shape (n, 3), and
        their in-range flags, shape (n,); an empty ``temp_c`` cell keeps the last temperature, and so does a
        magnetometer reading repeated from the row before (its last conversion held, compensated at its own
        temperature: the filter knows a held reading by its field, which must repeat too)."""
        raw = np.array([s.raw for s in samples], dtype=float)
        effect = self.model.temperature
        if effect is None or effect.reference_c is None:
            return self.model.field(raw)
        temps = []
        for s, reading in zip(samples, map(tuple, raw.tolist())):
            if s.temp_c is not None and reading != self._raw:
                self._temp_c = s.temp_c
            self._raw = reading
            temps.append(self._temp_c)
        known = np.array([t is not None for t in temps])
        if known.all():
            return self.model.field(raw, np.array(temps, dtype=float))
        fields, in_range = self.model.field(raw)  # no temperature yet: taken as at the reference
        if known.any():
            fields[known], in_range[known] = self.model.field(raw[known], np.array(temps, dtype=float)[known])
        return fields, in_range

    def _starting(self, reading: Reading) -> None:
        """Hold a sample in the start window (:class:`compass.filter.FilterStart`); start when it is complete."""
        reason = self._start.add(reading, reading.sample.t_s, reading.accel, reading.gyro, reading.field_h)
        if reason is not None:
            self._count_skip(reason)
        elif self._start.done:
            self._started()

    def _started(self) -> None:
        """The start window is complete: its reference, the filter it starts, the held samples solved."""
        start, self._start = self._start, None
        self.wrong_gravity = start.gravity_words
        if self.wrong_gravity is not None:  # the commands stop on it: nothing is solved
            return
        if start.values.reference is not self.reference:  # not the site's, already in use
            self._use_reference(start.values.reference)
        held = start.take_held()
        header = held[0].sample.header
        self._filter = start.make_filter(header.gyro is not None, self.config)
        self._filter_event(self._filter, header)
        for held_reading in held:
            self._sample(held_reading, held=True)

    def _sample(self, reading: Reading, held: bool = False) -> None:
        """One sample through the filter and into the outputs."""
        sample, accel, gyro, field_h, field_row, in_range, t_rx = reading
        header = sample.header  # its own: a header later in the same chunk may have replaced the decoder's
        if self._filter is None or self._filter.gyro != (header.gyro is not None):
            self._filter = AttitudeFilter(self.config, gyro=header.gyro is not None)
            self._filter_event(self._filter, header)
        effect = self.model.temperature
        if effect is not None and header is not self._header_seen:
            self._header_seen = header
            if effect.reference_c is None:
                self._event("warn", "the calibration's temperature effect names no reference temperature: "
                                    "not applied (recalibrate)")
            elif header.temp_c is None:
                self._event("warn", "the calibration has a temperature effect but the module sends no temp_c: "
                                    f"readings are taken as at {effect.reference_c:.1f} degC")
        t_s = sample.t_s
        filt = self._filter
        est = filt.step(t_s, accel, gyro, field_row)
        unit_rows = self._unit_rows  # rows in time: a clock that goes back (a restart) starts the window again
        if (self.gyro_unit is None and not self.decoder.gyro_unit_said and not self.decoder.gyro_unit_right
                and gyro is not None and field_row is not None and math.isfinite(t_s)):
            if unit_rows and t_s < unit_rows[-1][0]:
                unit_rows.clear()
            unit_rows.append((t_s, *gyro, *field_row))
            if t_s - unit_rows[0][0] >= GYRO_UNIT_WINDOW_S:
                self._judge_gyro_unit_window()
        axes_rows = self._gyro_axes_rows  # rows in time: a clock that goes back (a restart) ends them
        if axes_rows is not None and gyro is not None and math.isfinite(t_s) and (not axes_rows or t_s >= axes_rows[-1][0]):
            absent = (math.nan,) * 3
            axes_rows.append((t_s, *gyro, *(absent if field_row is None else field_row),
                              *(absent if accel is None else accel)))
            if len(axes_rows) >= GYRO_AXES_ROWS:
                self._judge_gyro_axes()
        turn_rows = self._turn_rows  # with a gyro only: without one a turn cannot be told from a brake's tilt
        if turn_rows is not None and accel is not None and gyro is not None and math.isfinite(t_s):
            if turn_rows and t_s < turn_rows[-1][0]:  # the module's clock restarted: the turns start again
                turn_rows.clear()
            turn_rows.append((t_s, *accel, *gyro, *sample.raw))
            if len(turn_rows) % FIELD_TURN_EVERY == 0:
                self._judge_field_turn()
        if filt.events:
            for text in filt.drain_events():
                self._event("warn", text)
        if filt.diagnostics.skipped:  # a non-finite or out-of-range reading: never fused (the filter's screen)
            for reason in filt.diagnostics.skipped.split(","):
                self._count_skip(reason.strip())
        if est is None or est.gate == "absent":  # no attitude, or no field to write a row of
            self.unsolved += 1
            return
        own = self.config.calibration_uncertainty
        if own is not None:  # the calibration's own uncertainty at this attitude (the filter's is the noise's)
            est = replace(est, heading_sigma_deg=with_calibration_sigma(est.heading_sigma_deg, own, est.matrix_rows,
                                                                        field_row))
        self.estimate, self.in_range = est, in_range
        self.samples += 1
        if self._axes_rows is not None and accel is not None and self.samples % AXES_EVERY == 0:
            self._axes_rows.append((*accel, *field_row))
            if len(self._axes_rows) >= AXES_ROWS:
                self._judge_axes()
        if self._dips is not None and accel is not None:
            self._dips.append(est.dip_deg)
            if len(self._dips) >= UPSIDE_DOWN_SAMPLES:
                self._judge_turn()
        if not est.mag_used:
            n, ratio, dip = self.rejected.get(est.gate, (0, 0.0, 0.0))
            self.rejected[est.gate] = (n + 1, ratio + est.field_ratio, dip + est.dip_deg)
        if est.gate != self._gate:
            reading = f"|B| ratio {est.field_ratio:.3f}, dip {est.dip_deg:.1f} deg"
            self._event("info" if est.mag_used else "warn",
                        "field used again" if est.mag_used else
                        f"field waits for the accelerometer's tilt after a gyro axis held its range (rail): {reading}"
                        if est.gate == "rail" else f"field rejected ({est.gate}): {reading}")
            self._gate = est.gate
        latency = time.perf_counter() - t_rx
        held = held or sample.t_rx is not None  # held back by the decoder (its unit check)
        if not held:  # samples held for the reference waited for it: out of the percentiles
            self.latencies_s.append(latency)
        true = None if self._declination is None else self.true_heading()
        if self.out is not None:
            row = _CSV_ROW % (t_s, est.heading_deg, est.pitch_deg, est.roll_deg, est.heading_sigma_deg,
                              est.tilt_sigma_deg, est.field_ratio, est.dip_deg, est.mag_used,
                              GATE_CODES[est.gate], est.accel_used, in_range, 1e3 * latency)
            if true is not None:
                row += ",%.3f,%.3f" % true
            if self.quaternion:
                row += ",%.9f,%.9f,%.9f,%.9f" % matrix_quaternion(est.matrix_rows)
            self.out.write(row + "\n")
        if self.sink is not None:
            self.sink.log(t_s, self.samples, est, field_h / self.config.field_norm, accel, raw=sample.raw,
                          gyro=gyro, gate_code=GATE_CODES[est.gate], in_range=in_range,
                          latency_ms=1e3 * latency, **({} if true is None else {"true_heading": true}))
        if not held:
            self.output_latencies_s.append(time.perf_counter() - t_rx)

    def _filter_event(self, filt: AttitudeFilter, header) -> None:
        kind = "gyro (error-state EKF with bias)" if filt.gyro else "two-vector"
        if header.accel is not None:
            self._event("info", f"filter: {kind}")
        else:
            self._event("warn", f"filter: {kind}; no accelerometer: no attitude")

    def _judge_axes(self) -> None:
        """The sampled estimates' field-gravity angle against the sign patterns of the field's axes (once)."""
        from .axes import check_axes

        rows, self._axes_rows = np.array(self._axes_rows, dtype=float), None
        if len(rows) == 0:
            return
        channels = tuple(self.model.channels)
        names = channels if len(channels) == 3 else ("the field's x", "the field's y", "the field's z")
        verdict = check_axes(rows[:, :3], rows[:, 3:], names=names)
        if verdict is not None:
            self.axes = verdict.text
            self._event("warn", verdict.text)

    def _judge_gyro_axes(self, last: bool = False) -> None:
        """The field's turns against the gyro's over the first rows that turned the housing (once): a stream whose
        magnetometer columns are not those the calibration was made with (a ``--columns`` remap not given again)
        reads turned axes.  Rows that did not turn enough wait for more, unless they are the ``last``."""
        from .axes import accel_axes_from_gyro, axes_from_gyro, turned_enough
        from .io.tumble import gyro_turns
        from .sample_check import new_readings

        rows = np.array(self._gyro_axes_rows, dtype=float)
        t, gyro = rows[:, 0], rows[:, 1:4]
        finite_gyro = np.where(np.isfinite(gyro), gyro, 0.0)
        turns = gyro_turns(t, finite_gyro, np.ones(len(t), dtype=bool))
        if not last and not turned_enough(turns, t):
            del self._gyro_axes_rows[:len(rows) // 2]  # at rest: the newer half may be where the turns begin
            return
        self._gyro_axes_rows = None
        if len(rows) < 2:
            return
        field_h, accel = rows[:, 4:7], rows[:, 7:10]
        if not self.decoder.gyro_unit_said and self.gyro_unit is None:
            self._judge_gyro_unit(t, gyro, field_h)
        if self.decoder.gyro_unit_said or self.gyro_unit is not None:
            return  # the axes cannot be judged against a gyro read in another unit
        accel_words = accel_axes_from_gyro(accel, turns, t)
        if accel_words is not None:  # the field's axes are then judged against a gyro that is itself in question
            self._event("warn", accel_words)
            return
        keep = new_readings(field_h)
        channels = tuple(self.model.channels)
        known = self.reference is not None and self.reference.source == "site"  # a recording's dip is this field's own
        site_dip = self.reference.dip_deg if known else None
        verdict = axes_from_gyro(field_h[keep], gyro_turns(t, finite_gyro, keep), t[keep],
                                 up=accel[keep], site_dip_deg=site_dip,
                                 names=channels if len(channels) == 3 else ("mx", "my", "mz"))
        if verdict is not None:
            self.axes, self._axes_rows = verdict.finding, None  # the accelerometer's sign patterns are then moot
            self._event("warn", f"{verdict.finding}: is the stream read with the remap its calibration was made with? "
                                f"Else recalibrate reading it in the gyro's axes: {verdict.remap}")

    def _judge_gyro_unit_window(self) -> None:
        """The gyro's unit against the calibrated field's turn over the :data:`GYRO_UNIT_WINDOW_S` window just
        complete; the next window starts."""
        rows = np.array(self._unit_rows, dtype=float)
        self._unit_rows.clear()
        self._judge_gyro_unit(rows[:, 0], rows[:, 1:4], rows[:, 4:7])

    def _judge_field_turn(self) -> None:
        """Whether the calibrated field stays put in the housing while the housing turns (:attr:`wrong_field`), once
        :data:`~compass.io.streams.MIN_TURNED_PAIRS` pairs of rows show the turn: gravity turned by
        :data:`~compass.io.streams.TURNED_DEG`, the gyro by half that within :data:`FIELD_TURN_SPAN_S`, and a field
        fixed in the world would have turned by half that too (the gyro's turn applied to it: a tilt about the field's
        own direction turns it by nothing, as it does at low dip when the housing rolls facing North, which against
        gravity's turn would read as a field that stays put).  Fewer: the older half of :data:`FIELD_TURN_ROWS` goes,
        and the check waits for more."""
        from .axes import orientations

        rows = np.array(self._turn_rows, dtype=float)
        t, accel, gyro, raw = rows[:, 0], rows[:, 1:4], rows[:, 4:7], rows[:, 7:]
        i, j, alpha = gravity_pairs(accel, min_deg=TURNED_DEG)
        turn = None
        if len(i):
            attitude = orientations(np.where(np.isfinite(gyro), gyro, 0.0) * np.diff(t, prepend=t[0])[:, None])
            turn = attitude[i].inv() * attitude[j]  # R_j = R_i D
            expected = world_fixed_turn(self.model.field(raw)[0], i, turn)
            keep = ((t[j] - t[i] <= FIELD_TURN_SPAN_S) & (turn.magnitude() >= alpha / 2.0)
                    & (expected >= np.radians(TURNED_DEG) / 2.0))
            i, j, alpha, turn = i[keep], j[keep], alpha[keep], turn[keep] if keep.any() else None
        if len(i) < MIN_TURNED_PAIRS:
            if len(rows) >= FIELD_TURN_ROWS:
                del self._turn_rows[:len(rows) // 2]
            return
        self._turn_rows = None
        self.wrong_field = fixed_field_words(self.model, raw, i, j, alpha, turn)
        if self.wrong_field is not None:
            self._event("warn", self.wrong_field)

    def _judge_gyro_unit(self, t, gyro, field_h) -> bool:
        """Whether the gyro turns tens of times more than the calibrated field does (said once, kept in
        :attr:`gyro_unit`): a unit taken for another.  The stream's check reads the accelerometer's tilt, which a
        housing turned about the vertical, or slowly, never gives it; the field turns then too (``|dip| < 90``)."""
        from .io.units import FIELD_UNIT_RATIO, gyro_field_ratio, stuck_gyro_words

        ratio = gyro_field_ratio(t, gyro, field_h)
        if ratio is None or not ratio > FIELD_UNIT_RATIO or self.decoder.gyro_unit_right:
            # less: the field turns without the gyro by itself (a magnet passing by), no unit's mark; a gyro that
            # turned as the accelerometer saw the housing tilt is right, and the field is what does not turn
            # (_judge_field_turn's case)
            return False
        unit = self.decoder.options.gyro_unit or "rad/s"
        self.gyro_unit = (f"the gyro read in {unit} turns {ratio:.0f} times more than the calibrated field turns with "
                          f"the housing (a deg/s gyro read as rad/s gives 57-100; so does a field read in a unit too "
                          f"small, which stays put: --mag-unit): is --gyro-unit right?"
                          f"{stuck_gyro_words(gyro[np.all(np.isfinite(gyro), axis=1)])}")
        self.decoder.gyro_unit_said = True  # the stream's own check (the accelerometer's tilt) says it no more
        self._event("warn", self.gyro_unit)
        return True

    def _judge_turn(self) -> None:
        """The measured dips so far against the given reference, or the calibration's own dip: :attr:`turned_over`
        (once)."""
        self.turned_over = upside_down(np.array(self._dips), self._dip_reference,
                                       bench_sign_ambiguous=self.sign_from_bench)
        self._dips = None

    def _count_skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1
        if self.skipped[reason] == 1:
            self._event("warn", f"sample skipped, never fused: {reason} (counted in the summary)")

    def true_heading(self) -> tuple[float, float]:
        """Heading from true north and its 1-sigma (declination's included), degrees; needs a site."""
        est, ref = self.estimate, self.reference
        return ((est.heading_deg + ref.declination_deg) % 360.0, math.hypot(est.heading_sigma_deg,
                                                                          ref.declination_sigma_deg))

    def _event(self, level: str, text: str) -> None:
        if self.on_event is not None:
            self.on_event(level, text)
        if self.sink is not None:
            t_s = self.estimate.t_s if self.estimate is not None else 0.0
            self.sink.event(t_s, self.samples, text, level)

    def readout(self, rate_hz: float) -> str:
        """The one-line live readout."""
        stats = self.decoder.stats
        tail = f"{rate_hz:6.1f} Hz  dropped {stats.dropped}  [{self.decoder.describe()}]"
        est = self.estimate
        if est is None:
            what = "the first quiet second (the start)" if self._start is not None and self._start.held else "samples"
            return f"waiting for {what} ({stats.samples} decoded, {stats.unheaded} before a header)  {tail}"
        flags = [name for name, on in (("MAG-REJECTED:" + est.gate, not est.mag_used),
                                       ("ACCEL-SKIPPED", not est.accel_used), ("OUT-OF-RANGE", not self.in_range)) if on]
        true = "" if self._declination is None else f"true {self.true_heading()[0]:6.1f}  "
        return (f"heading {est.heading_deg:6.1f}  {true}pitch {est.pitch_deg:+6.1f}  roll {est.roll_deg:+7.1f} deg  "
                f"+-{est.heading_sigma_deg:.2f}  |B| {est.field_ratio:.3f}  dip {est.dip_deg:5.1f}  "
                f"{' '.join(flags) or 'ok':<22} {tail}")

    def latency_ms(self, outputs: bool = False) -> tuple[float, float]:
        """p50 and p99 of the latency to the estimate (``outputs``: to the outputs), ms; NaN without samples."""
        values = self.output_latencies_s if outputs else self.latencies_s
        if not values:
            return float("nan"), float("nan")
        p50, p99 = np.percentile(np.fromiter(values, float), [50, 99])
        return 1e3 * float(p50), 1e3 * float(p99)

    def summary(self) -> str:
        """One line: samples, dropped lines by cause, samples not fused by reason, latency."""
        s = self.decoder.stats
        p50, p99 = self.latency_ms()
        skipped = "".join(f", {reason} {n}" for reason, n in self.skipped.items())
        return (f"{self.samples} attitudes from {s.samples} samples; dropped lines {s.dropped} (garbage {s.garbage}, "
                f"invalid {s.invalid}, partial {s.partial}, before a header {s.unheaded}, repeated seq {s.repeated}, "
                f"lost in transit {s.lost}); not fused {sum(self.skipped.values())}{skipped}; "
                f"latency p50 {p50:.2f} ms, p99 {p99:.2f} ms")

    def closing_hint(self) -> str | None:
        """Why the field was rejected through most of the session and what to check, in words; None
        when it was mostly used (or too few estimates to tell).

        A session with the wrong sensor's calibration showed MAG-REJECTED:dip throughout and ended
        without a word; so did a ``--site`` whose |B| or dip the module does not read.  None after a stop: its words
        say why.
        """
        if self.stopped:
            return None  # the session stopped on it, in words
        total = sum(n for n, _, _ in self.rejected.values())
        if self.samples < HINT_MIN_SAMPLES or total < HINT_REJECTED_SHARE * self.samples:
            return None
        gate, (n, ratio_sum, dip_sum) = max(self.rejected.items(), key=lambda item: item[1][0])
        ref = self.reference
        ref_dip = ref.dip_deg if ref is not None else self.config.dip_deg
        measured = {"dip": f"its dip read {dip_sum / n:.1f} deg on average against the reference's {ref_dip:.1f} deg",
                    "norm": f"its |B| read {ratio_sum / n:.3f} of the reference's on average (the gate allows "
                            f"1 +- {self.config.field_tolerance:g})",
                    "innovation": "the heading it gave disagreed with the gyro's (a gyro unit? --gyro-unit)",
                    "absent": "no field reading came",
                    "magnet": "it turned with the housing (a magnet or iron on it)",
                    "rail": "it waited for the accelerometer to bring back the tilt a gyro axis held at its range left "
                            "open (a gyro stuck at a rail? a turn beyond the gyro's range?)"}.get(gate, gate)
        site = (f"; the reference is {ref.description}: a site far from the module, or a date long past, does "
                f"the same" if ref is not None and ref.source == "site" else "")
        return (f"the field was rejected in {100 * total / self.samples:.0f} % of the estimates, mostly for its "
                f"{'|B|' if gate == 'norm' else gate}: {measured}. Is --cal the calibration of this "
                f"module's sensor (and this installation)? Iron near the module does the same{site}. The headings "
                f"followed the gyro alone")

    def close(self) -> None:
        """Flush the outputs (the CSV file stays open: its owner closes it).

        The Rerun recording is finished only if it holds a sample and the field was not found turned
        over; otherwise it is discarded, so a session that never started leaves no empty ``.rrd`` behind
        and an existing file stays as it was.
        A stream that ended before its first quiet second has its held samples solved against the
        reference their rows give (:meth:`compass.filter.FilterStart.finish`), if ten of them do.
        """
        samples = self.decoder.flush()  # held for the unit check: judged on what came
        if samples:
            self._chunk(samples, self._last_rx)
        if self.decoder.fatal is not None:
            self._record_withheld(self._last_rx)
        for level, text in self.decoder.drain_events():
            self._event(level, text)
        if self._start is not None and self._start.held and self._start.finish():
            self._started()
        if self._dips:  # a stream shorter than the check: judged on what it gave
            self._judge_turn()
        if self._turn_rows and self.wrong_field is None:
            self._judge_field_turn()
        if self._gyro_axes_rows and self.wrong_field is None:
            self._judge_gyro_axes(last=True)
        if self._axes_rows:
            self._judge_axes()
        if self.sink is not None:  # a field turned over, or an accelerometer never used, gives wrong attitudes
            keep = self.samples > 0 and not self.stopped
            self.sink.close() if keep else self.sink.discard()
        if self.out is not None:
            self.out.flush()
