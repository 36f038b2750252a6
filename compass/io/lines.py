"""The ASCII line protocol of a compass module on a serial line (docs/runtime.md, "Line protocol").

A module sends text lines; ``\\n``, ``\\r\\n`` and a lone ``\\r`` all end a line, and spaces
around cells are ignored.

- A **header line** names the columns, comma separated, as in SPEC section 2's attitude
  recording: the calibration's channel columns (required), optional ``t_s`` (module clock,
  seconds), ``ax,ay,az`` (accelerometer in the housing frame H, any unit), ``gx,gy,gz`` (gyro in
  H, rad/s), ``temp_c``, and ``seq`` (an integer the module increments by one every sample, so
  the receiver can count samples lost on the line).  Unknown columns are ignored.  A line is a
  header when its first cell is not a number.  Modules should repeat the header about once a
  second: a receiver that opens the port mid-stream needs one before it can read samples.
- A **sample line** has one number a column, in the header's order.  An empty cell in an
  optional column (``t_s``, ``seq``, ``temp_c``, or any of a group ``ax,ay,az`` / ``gx,gy,gz``)
  means "not measured this time"; the channel cells are required.
- Lines starting with ``#`` are comments.
- Optional NMEA-style checksum: a line may end with ``*hh``, the XOR of every byte before the
  ``*`` as two hex digits.  When the header carries one, every sample line must carry one.

Everything else is counted and skipped, never raised: garbage (bytes that are not ASCII, a
header-less or overlong line, a cell that is not a number, a checksum mismatch, too many
cells), invalid samples (a well-formed line with a number that is not finite or beyond
:data:`~compass.io.units.MAX_ABS_VALUE` in magnitude, the recordings' limit, or a ``seq`` that is
not a non-negative integer), partial lines (fewer cells than the header: a truncated line),
samples before any usable header, repeated ``seq`` values, and samples lost in transit: the gap
between two ``seq`` values, or without ``seq`` the gap in ``t_s`` against the module's own sample
interval (also across a reconnect), less the lines already counted as bad in between.  A gap of
more than :data:`MAX_GAP_SAMPLES` is not believed: the counter or the clock jumped (a corrupted
value, a module restarted mid-count); it is said as an event and not counted as lost.  An
overlong line counts once however long it is.
"""

from __future__ import annotations

import statistics
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from .units import MAX_ABS_VALUE

__all__ = ["Header", "LineDecoder", "LineStats", "Sample", "MAX_GAP_SAMPLES", "checksum", "format_line", "line_text"]

MAX_LINE_BYTES = 8192  # a 150-column header is about 1.2 KiB
_GROUPS = {"accel": ("ax", "ay", "az"), "gyro": ("gx", "gy", "gz")}
_SCALARS = ("t_s", "seq", "temp_c")
_DT_WINDOW = 32  # t_s steps kept to estimate the module's sample interval
_DT_MIN_STEPS = 8  # steps needed before a t_s gap is counted
MAX_GAP_SAMPLES = 1_000_000
"""Largest gap counted as samples lost in transit: 17 minutes at 1 kHz, nearly 3 hours at 100 Hz.
A larger jump of ``seq`` or ``t_s`` is a counter or clock that jumped, not a link that lost a
million lines: said once as an event and not counted."""


def checksum(payload: bytes) -> int:
    """XOR of all bytes of ``payload`` (the NMEA checksum), 0..255."""
    value = 0
    for byte in payload:
        value ^= byte
    return value


def format_line(cells, *, with_checksum: bool = True) -> bytes:
    """One protocol line from cells (strings or numbers), ``\\r\\n`` terminated.

    Examples
    --------
    >>> format_line(["t_s", "mx"])
    b't_s,mx*61\\r\\n'
    """
    payload = ",".join(str(c) for c in cells).encode("ascii")
    if with_checksum:
        payload += b"*%02X" % checksum(payload)
    return payload + b"\r\n"


@dataclass(frozen=True)
class Header:
    """Where each known column sits in a sample line.

    Attributes
    ----------
    names : tuple of str
        The header's cells, stripped.
    channels : ndarray of int, shape (c,)
        Cell index of each calibration channel, in the calibration's order.
    accel, gyro : ndarray of int, shape (3,), or None
        Cell indices of ``ax,ay,az`` and ``gx,gy,gz``; None when the group is absent or incomplete.
    t_s, seq, temp_c : int or None
        Cell index of the optional scalar columns.
    checksummed : bool
        The header carried a checksum: sample lines must too.
    ignored : tuple of str
        Columns the receiver does not use (unknown, or an incomplete group).
    """

    names: tuple[str, ...]
    channels: np.ndarray
    accel: np.ndarray | None
    gyro: np.ndarray | None
    t_s: int | None
    seq: int | None
    temp_c: int | None
    checksummed: bool
    ignored: tuple[str, ...]

    def describe(self) -> str:
        """One line for the event log."""
        parts = [f"header: {','.join(self.names)}"]
        if self.ignored:
            parts.append(f"ignoring {','.join(self.ignored)}")
        if self.accel is None:
            parts.append("no accelerometer")
        if self.gyro is None:
            parts.append("no gyro")
        return "; ".join(parts)


@dataclass(frozen=True)
class Sample:
    """One decoded sample line.

    Attributes
    ----------
    raw : ndarray, shape (c,)
        Channel outputs in the calibration's channel order (output units).
    accel : ndarray, shape (3,), or None
        Accelerometer in H, any unit (specific force: +up at rest).
    gyro : ndarray, shape (3,), or None
        Angular rate of H in H, rad/s.
    t_s : float or None
        Module clock, seconds.
    seq : int or None
        Module sample counter.
    temp_c : float or None
        Sensor temperature, degrees Celsius.
    header : Header or None
        The header the line was decoded under (a chunk is decoded whole, so the decoder's current
        header may already be a later one).
    t_rx : float or None
        When its bytes arrived (s, the reader's clock), for a sample a decoder held back before handing it
        out (:class:`compass.io.streams.StreamDecoder`); None: it arrived with the chunk it comes out of.
    lost_before : int
        Samples the decoder knows were lost between the sample before and this one (0 for the first sample): the
        ``seq`` gap when both carry ``seq``, else the sample lines between them it could not use (garbage, invalid,
        partial, header-less).  A stream without ``t_s`` is dated with them in their place
        (:class:`compass.io.clock.SampleClock`).
    """

    raw: np.ndarray
    accel: np.ndarray | None = None
    gyro: np.ndarray | None = None
    t_s: float | None = None
    seq: int | None = None
    temp_c: float | None = None
    header: Header | None = None
    t_rx: float | None = None
    lost_before: int = 0


@dataclass
class LineStats:
    """Counts of what the decoder saw (mutable, updated in place).

    Attributes
    ----------
    samples : int
        Sample lines decoded.
    headers, comments : int
        Header and comment lines.
    rejected_headers : int
        Header lines the receiver cannot use (a calibration channel missing, a repeated column).
    garbage : int
        Lines that are not the protocol (see the module docstring); an overlong line counts once.
    invalid : int
        Well-formed sample lines with a number no module sends: not finite (nan, inf), beyond
        :data:`~compass.io.units.MAX_ABS_VALUE` in magnitude, or a negative ``seq``: never used.
    partial : int
        Lines with fewer cells than the header, and fragments cut by a (re)connect.
    unheaded : int
        Sample lines before any usable header (or after one that lacks a calibration channel).
    repeated : int
        Samples whose ``seq`` repeats the previous one (skipped: never used twice).
    lost : int
        Samples never received: missing ``seq`` values, or without ``seq`` the gap in ``t_s``
        against the module's sample interval, less the bad lines received in between.
    invalid_cell : str or None
        The first invalid line's first number no module sends, ``"gx = nan"`` (None: none yet, or a decoder
        that does not name it).
    """

    samples: int = 0
    headers: int = 0
    comments: int = 0
    rejected_headers: int = 0
    garbage: int = 0
    invalid: int = 0
    partial: int = 0
    unheaded: int = 0
    repeated: int = 0
    lost: int = 0
    invalid_cell: str | None = None

    @property
    def bad_lines(self) -> int:
        """Sample lines received but not used: garbage, invalid, partial, header-less, repeated."""
        return self.garbage + self.invalid + self.partial + self.unheaded + self.repeated

    @property
    def dropped(self) -> int:
        """Samples the receiver did not use: bad lines and samples lost in transit."""
        return self.bad_lines + self.lost


def line_text(line: bytes, stats) -> str | None:
    """A line's text without surrounding space; None for a line longer than :data:`MAX_LINE_BYTES` or not UTF-8
    (counted in ``stats.garbage``) and "" for an empty one.  UTF-8, not ASCII alone: a log's header names its
    units so (``Gyroscope X (°/s)``, ``Magnetometer X (µT)``); a sample line's text is a number's or garbage."""
    if len(line) > MAX_LINE_BYTES:
        stats.garbage += 1
        return None
    try:
        return line.decode("utf-8").strip()
    except UnicodeDecodeError:
        stats.garbage += 1
        return None


@dataclass
class LineDecoder:
    """Split a byte stream into protocol lines and decode them; never raises on input.

    Parameters
    ----------
    channels : sequence of str
        The calibration's channel names (:attr:`compass.model.SensorModel.channels`).

    Attributes
    ----------
    stats : LineStats
    header : Header or None
        The last valid header.
    mismatch : tuple of (tuple of str, tuple of str) or None
        ``(header names, missing channels)`` once the same header lacking calibration channels
        came twice in a row with no usable header between (a module that does not send the
        calibration's channels; a single mangled header does not count).
    events : list of (str, str)
        ``(level, text)`` notes for a log ("info", "warn"): headers, rejected headers, garbage
        seen; :meth:`drain_events` empties it.

    Examples
    --------
    >>> d = LineDecoder(("mx", "my", "mz"))
    >>> d.feed(b"mx,my,mz\\r\\n1, 2, 3\\r\\n4,5\\n")[0].raw
    array([1., 2., 3.])
    >>> d.stats.samples, d.stats.partial
    (1, 1)
    """

    channels: tuple[str, ...]
    stats: LineStats = field(default_factory=LineStats)
    header: Header | None = None
    events: list = field(default_factory=list)
    mismatch: tuple | None = None
    _buffer: bytes = b""
    _skipping: bool = False  # inside an overlong line (already counted): drop bytes until its end
    _untrusted: bool = False  # the next line may be a fragment (after resync)
    _last_seq: int | None = None
    _last_t_s: float | None = None
    _dt_s: deque = field(default_factory=lambda: deque(maxlen=_DT_WINDOW))
    _bad_at_sample: int = 0  # bad lines at the last good sample
    _seq_gap: int | None = None  # samples the last sample's seq says were lost before it (None: no seq to tell)
    _anchor: tuple = (None, None)  # (seq, t_s) of the sample before the last
    _last_lost: int = 0  # samples counted lost at the last sample
    _last_rejected: tuple | None = None

    def __post_init__(self):
        self.channels = tuple(self.channels)

    def resync(self) -> None:
        """Forget buffered bytes and distrust the next line (call after a (re)connect: opening a
        port drops whatever the module sent before, so the first line may be the tail of one).

        The next line counts as partial unless it is a header, a comment or carries a valid
        checksum: a line's tail can have the right number of cells and a cut first number.
        """
        if self._buffer:
            self.stats.partial += 1
        self._buffer = b""
        self._skipping = False
        self._untrusted = True
        # the seq and t_s of the last sample are kept: a gap across the reconnect is samples lost

    def feed(self, chunk: bytes) -> list[Sample]:
        """Decode the complete lines in ``chunk`` (plus what earlier chunks left unfinished)."""
        data = self._buffer + chunk
        if b"\r" in data:
            data = data.replace(b"\r", b"\n")
        lines = data.split(b"\n")
        self._buffer = lines.pop()
        if self._skipping and lines:
            lines.pop(0)  # the end of an overlong line, counted when it began
            self._skipping = False
        if len(self._buffer) > MAX_LINE_BYTES:
            if not self._skipping:
                self.stats.garbage += 1
            self._skipping = True
            self._buffer = b""
        out = []
        for line in lines:
            sample = self.parse_line(line)
            if sample is not None:
                out.append(sample)
        return out

    def drain_events(self) -> list:
        """Return and clear the pending ``(level, text)`` events."""
        events, self.events = self.events, []
        return events

    def _content(self, line: bytes) -> tuple[str | None, bool]:
        """The line's text and whether it may be a fragment (the first line after a resync);
        the text is None for an empty, overlong, non-ASCII or comment line (counted)."""
        text = line_text(line, self.stats)
        if not text:
            return None, False
        untrusted, self._untrusted = self._untrusted, False
        if text[0] == "#":
            self.stats.comments += 1
            return None, untrusted
        return text, untrusted

    def parse_line(self, line: bytes) -> Sample | None:
        """Decode one line without its terminator; None for headers, comments and bad lines."""
        text, untrusted = self._content(line)
        if text is None:
            return None
        star = text.rfind("*")
        has_sum = star >= 0
        if has_sum:
            try:
                ok = int(text[star + 1:], 16) == checksum(text[:star].encode("ascii"))
            except ValueError:
                ok = False
            if not ok:
                self.stats.garbage += 1
                return None
            text = text[:star]
        cells = [c.strip() for c in text.split(",")]
        if not _is_number(cells[0]) and cells[0] != "":
            self._read_header(cells, has_sum)
            return None
        header = self.header
        if header is None:
            self.stats.unheaded += 1
            return None
        if (header.checksummed or untrusted) and not has_sum:
            self.stats.partial += 1  # a line cut short, or possibly the tail of one
            return None
        if len(cells) != len(header.names):
            if len(cells) < len(header.names):
                self.stats.partial += 1
            else:
                self.stats.garbage += 1
            return None
        try:
            sample = self._decode(header, cells)
        except _NotFinite:
            self.stats.invalid += 1
            if self.stats.invalid_cell is None:
                self.stats.invalid_cell = next((f"{name} = {cell}" for name, cell in zip(header.names, cells)
                                                if _is_number(cell) and not _plausible(float(cell))), None)
            return None
        except ValueError:
            self.stats.garbage += 1
            return None
        return self._accepted(sample)

    def _accepted(self, sample: Sample) -> Sample | None:
        """A decoded sample counted, with the samples lost before it (:attr:`Sample.lost_before`); None when its
        ``seq`` repeats the last one's."""
        if not self._count_gap(sample):
            self.stats.repeated += 1
            return None
        stats = self.stats
        if not stats.samples:
            lost = 0
        elif self._seq_gap is not None:
            lost = self._seq_gap  # the module's counter tells: a broken line between two seqs is no sample of its own
        else:
            lost = stats.bad_lines - self._bad_at_sample  # a sample line that came and could not be used
        stats.samples += 1
        self._bad_at_sample = stats.bad_lines
        return replace(sample, lost_before=lost) if lost > 0 else sample

    def _decode(self, header: Header, cells: list[str]) -> Sample:
        """ValueError when a required cell is empty or a cell is not a number; _NotFinite for a number
        no module sends (not finite, beyond MAX_ABS_VALUE, a negative seq)."""
        values = [float(cells[i]) for i in header.channels]
        seq = int(cells[header.seq]) if header.seq is not None and cells[header.seq] else None
        sample = Sample(np.array(values), _group(cells, header.accel), _group(cells, header.gyro),
                        _scalar(cells, header.t_s), seq, _scalar(cells, header.temp_c), header)
        if not all(map(_plausible, values)) or (seq is not None and not 0 <= seq <= MAX_ABS_VALUE):
            raise _NotFinite("a channel or seq out of range")
        return sample

    def _count_gap(self, sample: Sample) -> bool:
        """Count samples lost before ``sample`` (``seq``, else ``t_s`` gaps); False if its ``seq`` repeats."""
        missing, self._seq_gap = 0, None
        if sample.seq is not None and sample.seq == self._last_seq:
            return False
        outlier = self._last_was_outlier(sample)
        if outlier:  # its jump counted nothing lost, and the count goes on from the sample before it
            self.stats.lost -= self._last_lost
            self._last_seq, self._last_t_s = self._anchor
        self._anchor = (self._last_seq, self._last_t_s)
        if sample.seq is not None:
            if self._last_seq is not None and sample.seq > self._last_seq:
                missing = self._believed(sample.seq - self._last_seq - 1, "seq", self._last_seq, sample.seq)
            self._last_seq = sample.seq  # a smaller seq: the module restarted its counter
        elif sample.t_s is not None and self._last_t_s is not None:
            dt_s = sample.t_s - self._last_t_s
            if len(self._dt_s) >= _DT_MIN_STEPS and dt_s > 0:
                step_s = statistics.median(self._dt_s)  # a plain median: np.median costs 9 us a sample
                if dt_s > 1.5 * step_s:
                    missing = self._believed(max(0, round(dt_s / step_s) - 1), "t_s", self._last_t_s, sample.t_s)
            if dt_s > 0 and not missing:
                self._dt_s.append(dt_s)
        if sample.t_s is not None:
            self._last_t_s = sample.t_s
        missing = max(0, missing - outlier)  # the outlier was the sample of one of the slots
        if sample.seq is not None and self._anchor[0] is not None:
            self._seq_gap = missing
        self._last_lost = 0
        if missing:
            already = self.stats.bad_lines - self._bad_at_sample  # bad lines since the last sample: counted
            self._last_lost = max(0, missing - already)
            self.stats.lost += self._last_lost
        return True

    def _last_was_outlier(self, sample: Sample) -> bool:
        """The last sample's ``seq`` (else ``t_s``) left the sequence its neighbours keep: the one before it
        and ``sample`` are in order while it is not between them (a corrupted counter or clock, not a
        restart: after a restart the sequence goes on from the new value)."""
        name = "seq" if sample.seq is not None else "t_s"
        before = self._anchor[0 if name == "seq" else 1]
        last = self._last_seq if name == "seq" else self._last_t_s
        now = getattr(sample, name)
        if before is None or last is None or now is None or not before < now or before < last < now:
            return False
        self.events.append(("warn", f"{name} {last:g} between {before:g} and {now:g}: taken as a corrupted value, "
                                    f"not as samples lost"))
        return True

    def _believed(self, missing: int, name: str, before, after) -> int:
        """``missing`` samples lost, or 0 (said as an event) beyond :data:`MAX_GAP_SAMPLES`."""
        if missing <= MAX_GAP_SAMPLES:
            return missing
        self.events.append(("warn", f"{name} jumped from {before:g} to {after:g}, a gap of over "
                                    f"{MAX_GAP_SAMPLES:,} samples: taken as the module's counter or clock "
                                    f"jumping, not counted as lost"))
        return 0

    def _read_header(self, cells: list[str], has_sum: bool) -> None:
        names = tuple(cells)
        missing = [c for c in self.channels if c not in names]
        known = set(self.channels) | set(_SCALARS) | {n for g in _GROUPS.values() for n in g}
        if missing:
            if not known & set(names):
                self.stats.garbage += 1  # not a header: text where a sample should be
                return
            self.events.append(("warn", f"header {','.join(names)} lacks channel(s) {','.join(missing)} of "
                                        f"the calibration: samples skipped until a complete header"))
            self.header = None
            self.stats.rejected_headers += 1
            if self._last_rejected == names:
                self.mismatch = (names, tuple(missing))
            self._last_rejected = names
            return
        if len(set(names)) != len(names):
            self.events.append(("warn", f"header {','.join(names)} repeats a column: ignored"))
            self.stats.rejected_headers += 1
            return
        self._last_rejected = None
        groups = {}
        ignored = [n for n in names if n not in known]
        for key, group in _GROUPS.items():
            present = [n for n in group if n in names]
            groups[key] = np.array([names.index(n) for n in group]) if len(present) == 3 else None
            if 0 < len(present) < 3:
                ignored += present
        header = Header(names, np.array([names.index(c) for c in self.channels]), groups["accel"], groups["gyro"],
                        *(names.index(s) if s in names else None for s in _SCALARS), has_sum, tuple(ignored))
        self.stats.headers += 1
        if self.header is None or header.names != self.header.names or has_sum != self.header.checksummed:
            self.events.append(("info", header.describe()))
        self.header = header


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


class _NotFinite(ValueError):
    """A well-formed number no module sends: nan, infinite, or beyond MAX_ABS_VALUE in magnitude."""


def _plausible(value: float) -> bool:
    """Finite and within MAX_ABS_VALUE (math on floats: numpy's isfinite costs a microsecond a call)."""
    return -MAX_ABS_VALUE <= value <= MAX_ABS_VALUE  # False for nan


def _scalar(cells: list[str], index: int | None) -> float | None:
    if index is None or not cells[index]:
        return None
    value = float(cells[index])
    if not _plausible(value):
        raise _NotFinite("value out of range")
    return value


def _group(cells: list[str], index: np.ndarray | None) -> np.ndarray | None:
    """Three cells as a vector; None if the group is absent or all its cells are empty."""
    if index is None:
        return None
    texts = [cells[i] for i in index]
    if not any(texts):
        return None
    values = [float(t) for t in texts]  # ValueError on a partly empty group
    if not all(map(_plausible, values)):
        raise _NotFinite("value out of range")
    return np.array(values)
