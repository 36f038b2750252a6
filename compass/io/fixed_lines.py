"""Decoders for streams whose columns are fixed in advance, not named by a header line.

- :class:`CsvDecoder`: bare numbers, comma, semicolon or space separated, one sample a line, whose
  columns the user names (``--columns t_s,ax,ay,az,gx,gy,gz,mx,my,mz``; ``-mz``: the cell is minus
  ``mz``, a board whose Z axis points down; ``t_ms`` and ``t_us`` are times in ms and us; a name the
  toolkit does not know is a column to skip).
- :class:`MotionCalDecoder`: MotionCal's ``Raw:`` integer counts and ``Uni:`` floats
  (:mod:`compass.io.motioncal`); ``Cal1:``/``Cal2:`` echoes are kept (:attr:`MotionCalDecoder.echo`).
  A sketch that prints both (Adafruit's: a ``Raw:`` line, then the same sample's ``Uni:`` line) is read
  from its ``Uni:`` lines, the finer ones, from the first one on (its ``Raw:`` twins skipped); the
  samples before it come from ``Raw:`` lines.  Nothing is held back: no latency is added.

Both split bytes into lines, count and skip what is not a sample, and hand out
:class:`compass.io.lines.Sample` values exactly as :class:`compass.io.lines.LineDecoder` does (they are
its subclasses: same splitting, statistics, events and ``resync``), so a consumer cannot tell them apart.
Values come out in the toolkit's units where the format fixes them (MotionCal: field in uT, accelerometer
in g, gyro in rad/s); a CSV's are as sent (:mod:`compass.io.streams` scales them by the units named).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from . import motioncal as mc
from .lines import _GROUPS, _SCALARS, Header, LineDecoder, Sample, _plausible
from .units import STANDARD_GRAVITY

__all__ = ["Layout", "CsvDecoder", "MotionCalDecoder", "parse_columns", "MOTIONCAL_COLUMNS"]

MOTIONCAL_COLUMNS = ("ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")
_TIME_SCALES = {"t_s": 1.0, "t_ms": 1e-3, "t_us": 1e-6}
_TAGS = ("Raw:", "Uni:", "Cal1:", "Cal2:")
_SPLIT = re.compile(r"\s*[,;]\s*|\s+")
_RAW_SCALES = (mc.G_PER_COUNT,) * 3 + (math.radians(mc.DEG_S_PER_COUNT),) * 3 + (mc.UT_PER_COUNT,) * 3
_UNI_SCALES = (1.0 / STANDARD_GRAVITY,) * 3 + (1.0,) * 3 + (1.0,) * 3


@dataclass(frozen=True)
class Layout:
    """Where each quantity sits in a fixed line and the factor that takes its cell to the toolkit's unit.

    Attributes
    ----------
    header : compass.io.lines.Header
        Cell indices of the calibration channels, accelerometer, gyro, ``t_s``, ``seq``, ``temp_c``
        (``names`` are the toolkit's names, ``t_ms`` and ``t_us`` as ``t_s``).
    scales : tuple of float, one a cell
        Multiplies each cell (a sign, a time unit, a count's size).
    missing : tuple of str
        Calibration channels no cell holds.
    """

    header: Header
    scales: tuple[float, ...]
    missing: tuple[str, ...]

    @classmethod
    def from_names(cls, names, channels, scales=None) -> "Layout":
        """The layout of cells named ``names`` (a leading ``-`` negates), for the calibration's ``channels``."""
        clean, signs = [], []
        for n in names:
            n = n.strip()
            signs.append(-1.0 if n.startswith("-") else 1.0)
            n = n.lstrip("-").strip()
            clean.append("t_s" if n in _TIME_SCALES else n)
            signs[-1] *= _TIME_SCALES.get(n, 1.0)
        if len(set(clean)) != len(clean):
            dup = sorted({n for n in clean if clean.count(n) > 1})
            raise ValueError(f"column(s) {', '.join(dup)} named twice (t_s, t_ms and t_us are one time)")
        scale = tuple((np.array(signs) * (1.0 if scales is None else np.asarray(scales, dtype=float))).tolist())
        known = set(channels) | set(_SCALARS) | {n for g in _GROUPS.values() for n in g}
        groups = {k: (np.array([clean.index(n) for n in g]) if all(n in clean for n in g) else None)
                  for k, g in _GROUPS.items()}
        ignored = tuple(n for n in clean if n not in known
                        or any(n in g and groups[k] is None for k, g in _GROUPS.items()))
        missing = tuple(c for c in channels if c not in clean)
        index = np.array([clean.index(c) for c in channels if c in clean])
        header = Header(tuple(clean), index, groups["accel"], groups["gyro"],
                        *(clean.index(s) if s in clean else None for s in _SCALARS), False, ignored)
        return cls(header, scale, missing)

    def sample(self, values: list[float]) -> Sample:
        """The sample of one line's scaled values (ValueError for a partly empty group, as in the protocol)."""
        h = self.header
        seq = None if h.seq is None else int(values[h.seq])
        return Sample(np.array([values[i] for i in h.channels]),
                      None if h.accel is None else np.array([values[i] for i in h.accel]),
                      None if h.gyro is None else np.array([values[i] for i in h.gyro]),
                      None if h.t_s is None else values[h.t_s], seq,
                      None if h.temp_c is None else values[h.temp_c], h)


def parse_columns(text: str) -> tuple[str, ...]:
    """``"t_s,ax,ay,az,mx,my,-mz"`` -> the names in order (ValueError for an empty name or a repeat).

    Examples
    --------
    >>> parse_columns("t_ms, mx,my,-mz")
    ('t_ms', 'mx', 'my', '-mz')
    """
    names = tuple(n.strip() for n in text.split(","))
    if not names or any(n in ("", "-") for n in names):
        raise ValueError(f"--columns: expected names separated by commas (t_s,mx,my,-mz), got {text!r}")
    Layout.from_names(names, ())  # repeats
    return names


@dataclass
class _FixedDecoder(LineDecoder):
    """A :class:`LineDecoder` whose lines have fixed cells: subclasses say what a line holds (:meth:`_cells`)."""

    layout: Layout | None = None

    def _start(self) -> None:
        """Adopt :attr:`layout`: its header, or the mismatch of the channels it lacks."""
        if self.layout.missing:
            self.mismatch = (self.layout.header.names, self.layout.missing)
        else:
            self.header = self.layout.header
            self.events.append(("info", self.layout.header.describe().replace("header:", "columns:", 1)))

    def parse_line(self, line: bytes) -> Sample | None:
        text, untrusted = self._content(line)
        if text is None:
            return None
        if untrusted and not self._whole(text):
            self.stats.partial += 1  # the first line after a (re)connect may be the tail of one
            return None
        cells = self._cells(text)
        if cells is None:
            return None
        if self.header is None:
            self.stats.unheaded += 1
            return None
        layout = self.layout
        if len(cells) != len(layout.scales):
            if len(cells) < len(layout.scales):
                self.stats.partial += 1  # a line cut short
            else:
                self.stats.garbage += 1
            return None
        try:
            values = [float(c) * k for c, k in zip(cells, layout.scales)]
        except ValueError:
            self.stats.garbage += 1
            return None
        if not all(map(_plausible, values)):  # not finite, or beyond what any sensor, time or angle reads
            self.stats.invalid += 1
            return None
        return self._accepted(layout.sample(values))

    def _cells(self, text: str) -> list[str] | None:
        """The sample cells of a line, or None when it is not a sample (counted by the subclass)."""
        raise NotImplementedError

    def _whole(self, text: str) -> bool:
        """Whether a line is known to start where its line started (after a (re)connect, others are not)."""
        raise NotImplementedError


@dataclass
class CsvDecoder(_FixedDecoder):
    """Bare numbers without a header, named by ``columns`` (module docstring).

    Parameters
    ----------
    channels : sequence of str
        The calibration's channel names.
    columns : sequence of str
        One name a cell (:func:`parse_columns`).

    Examples
    --------
    >>> d = CsvDecoder(("mx", "my", "mz"), columns=("t_ms", "mx", "my", "-mz"))
    >>> s = d.feed(b"1000 1.5 2 3\\r\\n")[0]
    >>> s.t_s, s.raw.tolist()
    (1.0, [1.5, 2.0, -3.0])
    """

    columns: tuple = ()
    relayout: Callable[[str], tuple | None] | None = None
    """Asked of a line of text where numbers should be: the columns it names when it is a log's header (a module
    that sends its header again, in another order after a firmware change or restart), else None; without it such
    a line is garbage (a header the user named away with ``--columns``)."""

    def __post_init__(self):
        super().__post_init__()
        self.layout = Layout.from_names(self.columns, self.channels)
        self._start()

    def _whole(self, text: str) -> bool:
        return False  # bare numbers: a cut first number looks like a number

    def _cells(self, text: str) -> list[str] | None:
        cells = _SPLIT.split(text)
        try:
            float(cells[0])
        except ValueError:
            columns = None if self.relayout is None else self.relayout(text)
            if columns is None:
                self.stats.garbage += 1  # text where numbers should be (a banner, a header the user named away)
            else:
                self.stats.headers += 1
                if tuple(columns) != tuple(self.columns):  # the lines after it are read in its order
                    self.columns, self.header, self.mismatch = tuple(columns), None, None
                    self.layout = Layout.from_names(self.columns, self.channels)
                    self._start()
                elif self.header is not None:  # the same columns, maybe other units: the samples after it carry
                    self.layout = Layout.from_names(self.columns, self.channels)  # a header of their own
                    self.header = self.layout.header
            return None
        return cells


@dataclass
class MotionCalDecoder(_FixedDecoder):
    """MotionCal's ``Raw:`` and ``Uni:`` lines (module docstring); field in uT, accelerometer in g, gyro in rad/s.

    Attributes
    ----------
    source : {"Raw", "Uni"} or None
        Which lines samples are read from (None before the first sample line).
    echo : dict
        The latest ``"Cal1"`` (10 numbers) and ``"Cal2"`` (9) a sketch echoed (its stored calibration).

    Examples
    --------
    >>> d = MotionCalDecoder(("mx", "my", "mz"))
    >>> d.feed(b"Raw:0,0,8192,0,0,16,200,0,-400\\r\\n")[0].raw.tolist()
    [20.0, 0.0, -40.0]
    """

    source: str | None = None
    echo: dict = field(default_factory=dict)

    def __post_init__(self):
        super().__post_init__()
        self.layout = Layout.from_names(MOTIONCAL_COLUMNS, self.channels)
        self._start()

    def parse_line(self, line: bytes) -> Sample | None:
        tag = line[:4]
        if tag == b"Uni:" and self.source != "Uni":
            twin = self.source == "Raw"  # this sample was read from its Raw: line already
            self._use("Uni", twin)
            if twin:
                self.stats.comments += 1
                return None
        elif tag == b"Raw:" and self.source is None:
            self._use("Raw", False)
        return super().parse_line(line)

    def _use(self, source: str, switched: bool) -> None:
        self.source = source
        self.layout = Layout(self.layout.header, _RAW_SCALES if source == "Raw" else _UNI_SCALES, self.layout.missing)
        self.events.append(("info", f"MotionCal {source}: lines, " + (
            "counts of 1/8192 g, 1/16 deg/s and 0.1 uT" if source == "Raw" else
            "m/s^2, rad/s and uT" + (" (the finer of the two the sketch prints: its Raw: lines skipped from now)"
                                     if switched else ""))))

    def _whole(self, text: str) -> bool:
        return text.startswith(_TAGS)  # a line's tag is its start

    def _cells(self, text: str) -> list[str] | None:
        tag, _, rest = text.partition(":")
        if tag in ("Raw", "Uni"):
            if tag != self.source:
                self.stats.comments += 1  # the twin of a sample read from the other kind of line
                return None
            cells = rest.split(",")
            if tag == "Raw" and len(cells) == len(MOTIONCAL_COLUMNS) and mc.int16_counts(cells) is None:
                self.stats.garbage += 1  # MotionCal takes only int16 counts
                return None
            return cells
        echo = mc.parse_cal_line(text)
        if echo is not None:
            self.stats.comments += 1
            self.echo[echo[0]] = echo[1]
            return None
        self.stats.garbage += 1  # a banner, a message, a line MotionCal would not read either
        return None
