"""CSV tables of SPEC section 2: ``# key: value`` metadata, one header row, numeric rows.

Every problem is reported as a :class:`RecordingError` naming the file, the row (1-based line
number in the file) and the column, so the command line can print one line and exit 2.

Real logs are read as they come:

- the separator is the header's: comma, semicolon, tab (or blanks); with a semicolon or tab a
  decimal comma (``1,5``) is read as a decimal point, with a comma separator it is named in the
  message;
- names are matched without regard to case (``MX`` is ``mx``) and with quotes and blanks stripped;
- ``--columns mx=NAME,...`` (:class:`ReadOptions`) or a ``# columns: mx=NAME,...`` metadata line
  gives the toolkit's name of a column; headers in the style of x-io Fusion's logs
  (``Time (s)``, ``Gyroscope X (deg/s)``, ``Accelerometer X (g)``, ``Magnetometer X (uT)``) are
  mapped to ``t_s, gx.., ax.., mx..`` with the units they name;
- units named (:mod:`compass.io.units`) are converted to SPEC's: gyro to rad/s, ``*_deg`` columns
  from radians, magnetometer to uT, the accelerometer's sign;
- a cell is a number (Python's ``1_5`` is not), bare or inside one pair of double quotes (a
  spreadsheet's ``"12.5"``); every cell of a column SPEC names (:data:`VOCABULARY`) must be a finite
  number of magnitude at most :data:`~compass.io.units.MAX_ABS_VALUE`; another column may hold text
  (a logger's ``status``): its cells are skipped, and :meth:`Table.column` refuses it at its first
  cell that is not a number when a reader uses it (a four-flip's channel, a calibration's);
- ``t_s`` must not decrease; ``# field_ut:`` must be a positive number.

Memory: the body is parsed by ``np.loadtxt`` from a stream of lines, so reading takes about what
``np.loadtxt`` takes (``tools/bench_scale.py``); a text column costs one Python call a cell, and a
text cell the first row did not show one more reading of the file.
"""

from __future__ import annotations

import codecs
import itertools
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import units
from ..limits import FIELD_UT
from .units import note

__all__ = ["RecordingError", "Table", "ReadOptions", "read_table", "add_read_arguments", "format_table", "VOCABULARY",
           "ABSENT_KEY", "LIVE_RECORD", "log_column_name", "magnetometer_axis"]

VOCABULARY = ("t_s", "temp_c", "flip_deg", "platform_deg", "platform_z_deg", "platform_y_deg", "platform_x_deg",
              "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz", "bx_ref", "by_ref", "bz_ref", "pitch_deg",
              "roll_deg", "heading_ref_deg")
"""Column names SPEC gives a meaning (matched without regard to case)."""
_GYRO, _ACCEL, _MAG = ("gx", "gy", "gz"), ("ax", "ay", "az"), ("mx", "my", "mz")
LIVE_RECORD = "compass live --record"
"""How a ``compass live --record`` file's ``# source:`` line starts (:class:`compass.io.sample_log.SampleLog`)."""
ABSENT_KEY = "absent"
"""A ``# absent: ...`` line (``compass live --record`` writes it): ``nan`` in ``temp_c`` or in a whole accelerometer
or gyro group is that group not sent on that row (the line protocol's empty cells), not a bad cell, where the replay
reads it (:func:`read_table`'s ``live_record``)."""
_OPTIONAL_GROUPS = (("temp_c",), _ACCEL, _GYRO)
_LOG_SENSORS = {"gyroscope": "g", "gyro": "g", "gyr": "g", "accelerometer": "a", "accel": "a", "acc": "a",
                "magnetometer": "m", "mag": "m"}
_LOG_NAME = re.compile(r"^(?P<sensor>[a-z]+)[ _]?(?P<axis>[xyz])\s*(?:\((?P<unit>[^)]*)\))?$", re.IGNORECASE)
_TIME_COLUMNS = {"t_ms": "ms", "t_us": "us"}
"""``--columns`` names of a time in milliseconds, microseconds: read as ``t_s``, converted."""
_TIME_NAME = re.compile(r"^time\s*\((?P<unit>s|ms|us)\)$", re.IGNORECASE)
_NUMBER = re.compile(r"^\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*$|^\s*[+-]?(?:nan|inf|infinity)\s*$",
                     re.IGNORECASE)
_DECIMAL_COMMA = re.compile(r"^\s*[+-]?\d+,\d+(?:[eE][+-]?\d+)?\s*$")
_SNIFF_BYTES = 1 << 16


class RecordingError(ValueError):
    """Bad input in a recording, with its location.

    Parameters
    ----------
    path : str
        The file.
    message : str
        What was expected and what was found.
    row : int, optional
        1-based line number in the file.
    column : str, optional
        Column name.
    """

    def __init__(self, path, message: str, row: int | None = None, column: str | None = None):
        self.path, self.row, self.column, self.reason = str(path), row, column, message
        where = [self.path]
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        super().__init__(f"{', '.join(where)}: {message}")


@dataclass(frozen=True)
class ReadOptions:
    """What the user says about a recording's columns and units (command-line options).

    Attributes
    ----------
    columns : dict of str to str
        The toolkit's name -> the file's name (``--columns mx=MagX,my=MagY``); a ``-`` before the
        file's name negates the column (``az=-AccZ``: a Z-down board).  Overrides the file's
        ``# columns:`` line.
    gyro_unit : {"rad/s", "deg/s"} or None
        None: the header's unit if it names one, else SPEC's rad/s.
    accel_unit : {"g", "m/s2"} or None
        None: the header's unit, else the recording's (any unit, SPEC).
    mag_unit : {"uT", "nT", "G", "mG"} or None
        None: the header's unit, else free.  A named unit is converted to uT.
    angle_unit : {"deg", "rad"}
        Unit of the ``*_deg`` columns as recorded (converted to degrees).
    accel_sign : {1, -1}
        -1 negates ``ax, ay, az`` (an accelerometer that reads gravity instead of specific force).
    """

    columns: dict = field(default_factory=dict)
    gyro_unit: str | None = None
    accel_unit: str | None = None
    mag_unit: str | None = None
    angle_unit: str = "deg"
    accel_sign: int = 1

    @classmethod
    def from_args(cls, args) -> "ReadOptions":
        """The options :func:`add_read_arguments` registered, from parsed arguments."""
        return cls(columns=getattr(args, "columns", None) or {}, gyro_unit=getattr(args, "gyro_unit", None),
                   accel_unit=getattr(args, "accel_unit", None), mag_unit=getattr(args, "mag_unit", None),
                   angle_unit=getattr(args, "angle_unit", "deg"), accel_sign=getattr(args, "accel_sign", 1))


def parse_column_map(text: str, *, source: str = "--columns") -> dict:
    """``"mx=Mag X,my=Mag Y"`` -> ``{"mx": "Mag X", "my": "Mag Y"}``.

    Raises
    ------
    ValueError
        An item without ``=``, an empty name, or a toolkit name given twice.
    """
    mapping: dict[str, str] = {}
    for item in text.split(","):
        ours, sep, theirs = item.partition("=")
        ours, theirs = ours.strip(), theirs.strip().strip('"').strip()
        if not sep or not ours or not theirs:
            raise ValueError(f"{source}: expected NAME=COLUMN items separated by commas (mx=MagX,my=MagY), got {item!r}")
        if ours in mapping:
            raise ValueError(f"{source}: '{ours}' is mapped twice")
        mapping[ours] = theirs
    return mapping


def add_read_arguments(parser) -> None:
    """Register the reading options (:class:`ReadOptions`) on a command that reads recordings."""
    import argparse

    def column_map(text):
        try:
            return parse_column_map(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    g = parser.add_argument_group("reading the recording (columns and units)")
    g.add_argument("--columns", type=column_map, metavar="NAME=COLUMN,...",
                   help="which file column is which, e.g. mx='Mag X',my='Mag Y',mz='Mag Z',t_s=time (also a "
                        "'# columns: ...' line in the file; t_ms=, t_us=: a time in ms, us); names match without "
                        "regard to case; az=-AccZ "
                        "negates a column; mx=my,my=mx swaps two (each maps to the header as read)")
    g.add_argument("--gyro-unit", choices=tuple(units.GYRO_UNITS), default=None,
                   help="unit of gx,gy,gz (default: the header's, else rad/s as SPEC says)")
    g.add_argument("--accel-unit", choices=tuple(units.ACCEL_UNITS), default=None,
                   help="unit of ax,ay,az (default: the header's, else any unit); checked against |g|")
    g.add_argument("--accel-sign", type=int, choices=(1, -1), default=1,
                   help="-1: the accelerometer reads gravity (-1 g on Z when level) instead of specific force")
    g.add_argument("--mag-unit", choices=tuple(units.MAG_UNITS), default=None,
                   help="unit of mx,my,mz (default: the header's, else free); converted to uT and checked against "
                        "the Earth's 25-65 uT")
    g.add_argument("--angle-unit", choices=tuple(units.ANGLE_UNITS), default="deg",
                   help="unit of the *_deg columns as recorded (default deg)")


@dataclass(frozen=True)
class Table:
    """A parsed numeric CSV.

    Attributes
    ----------
    path : str
    columns : tuple of str
        Column names: the toolkit's names where mapped or recognised, else as in the header.
    data : ndarray, shape (n_rows, n_columns)
        Finite floats, in SPEC's units where a unit was named (see :attr:`units`).
    rows : ndarray of int, shape (n_rows,)
        1-based file line number of each data row (for error messages).
    metadata : dict of str to str
        ``# key: value`` comment lines.
    header_line : int
        1-based line of the header row.
    original : dict of str to str
        Each column's name as the header spells it.
    units : dict of str to str
        Units named for a column (``{"gx": "deg/s"}``), by the user or the header.
    gyro_turn_ratio : float or None
        How much more the gyro turns than the accelerometer sees the housing tilt
        (:func:`compass.io.units.gyro_turn_ratio`, judged once on reading, its note issued then); None
        without ``gx,gy,gz``, ``ax,ay,az`` and ``t_s``, or when the housing did not tilt enough to tell.
    text_cells : dict of str to (int, str)
        The columns holding a cell that is not a number (never one of :data:`VOCABULARY`): column ->
        (row, cell) of the first.  Their data are NaN and :meth:`column` refuses them at that cell.
    """

    path: str
    columns: tuple[str, ...]
    data: np.ndarray
    rows: np.ndarray
    metadata: dict
    header_line: int = 1
    original: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)
    gyro_turn_ratio: float | None = None
    text_cells: dict = field(default_factory=dict)

    def _index(self, name: str) -> int | None:
        if name in self.columns:
            return self.columns.index(name)
        folded = [i for i, c in enumerate(self.columns) if c.lower() == name.lower()]
        return folded[0] if len(folded) == 1 else None

    def has(self, name: str) -> bool:
        return self._index(name) is not None

    def column(self, name: str) -> np.ndarray:
        """One column's values (name matched without regard to case); RecordingError naming it if missing, or at
        its first cell that is not a number (:attr:`text_cells`)."""
        i = self._index(name)
        if i is None:
            raise RecordingError(self.path, f"missing required column '{name}' (header has: {', '.join(self.columns)})",
                                 row=self.header_row, column=name)
        if self.columns[i] in self.text_cells:
            raise _not_a_number(self.path, self.original.get(self.columns[i], self.columns[i]),
                                *self.text_cells[self.columns[i]])
        return self.data[:, i]

    def group(self, names) -> np.ndarray | None:
        """The columns ``names`` together, shape (n_rows, len(names)); None when all are absent.

        Raises
        ------
        RecordingError
            Some of them present and not all (naming the missing one).
        """
        present = [n for n in names if self.has(n)]
        if not present:
            return None
        for name in names:
            if not self.has(name):
                raise RecordingError(self.path, f"has {', '.join(present)} but not '{name}': give all of "
                                                f"{', '.join(names)}", row=self.header_row, column=name)
        return np.column_stack([self.column(n) for n in names])

    def time_s(self) -> np.ndarray | None:
        """The optional ``t_s`` column, None when absent (checked non-decreasing on reading, except a live record's
        read by the replay: :func:`read_table`'s ``live_record``)."""
        return self.column("t_s") if self.has("t_s") else None

    @property
    def header_row(self) -> int:
        return self.header_line

    def ignore_unknown(self, known, *, what: str) -> None:
        """Note (do not refuse) the columns not in ``known``: the live protocol ignores them too."""
        known = {k.lower() for k in known}
        extra = [c for c in self.columns if c.lower() not in known]
        if extra:
            note(f"{self.path}: ignored column{'s' * (len(extra) > 1)} {', '.join(extra)} (not used by {what})")

    def check_constant(self, names) -> None:
        """RecordingError naming the first of ``names`` whose value never changes (a dead channel), or
        changes by no more than :data:`~compass.io.units.MIN_SPAN` (no sensor's turn is that small)."""
        for name in names:
            if self.has(name):
                v = self.column(name)
                span = np.ptp(v) if len(v) > 1 else np.inf
                if span == 0.0:
                    raise RecordingError(self.path, f"is constant ({v[0]:g} in all {len(v)} rows): the channel never "
                                                    "changes, a dead or disconnected sensor?", column=name)
                if not span > units.MIN_SPAN:
                    raise RecordingError(self.path, f"spans {span:.3g} only: the channel never changes by more than "
                                                    f"{units.MIN_SPAN:g}, which no sensor's turn is in any unit",
                                         column=name)

    def check_clipped(self, names, keep=None) -> None:
        """RecordingError naming the first of ``names`` that sits on its own extreme value (its largest or its
        smallest, exactly) in at least :data:`CLIPPED_SHARE` of its samples and :data:`CLIPPED_MIN_SAMPLES`
        of them, while its other values rarely repeat (at most :data:`CLIPPED_REPEAT_SHARE`): a clipped
        (saturated) channel, whose true value went past the sensor's or the ADC's range.

        A channel resolved more finely than its noise (the honest case of a float log) repeats a value only
        by chance, its extreme value almost never; a clipped one reads its rail on every sample beyond it.  A
        channel quantised as coarsely as its noise (an integer ADC read with a noise of a few counts, or less)
        repeats values anywhere, and reads one code for a whole flip along its axis: its extremes prove
        nothing and it is not judged here.  ``keep`` (bool, one a row) leaves out rows that repeat the
        sensor's last reading (:func:`compass.sample_check.new_readings`)."""
        rows = self.rows if keep is None else self.rows[keep]
        for name in names:
            v = self.column(name)
            if keep is not None:
                v = v[keep]
            finite = np.isfinite(v)
            v, at_rows = v[finite], rows[finite]
            for extreme in (v.max(), v.min()) if len(v) else ():
                on = v == extreme
                count = int(on.sum())
                if count < max(CLIPPED_MIN_SAMPLES, CLIPPED_SHARE * len(v)):
                    continue
                rest = v[(v != v.max()) & (v != v.min())]
                repeats = 1.0 - len(np.unique(rest)) / len(rest) if len(rest) else 1.0
                if repeats > CLIPPED_REPEAT_SHARE:
                    continue
                first = int(at_rows[np.flatnonzero(on)[0]])
                raise RecordingError(self.path, f"reads its extreme {extreme:+g} on {count} of {len(v)} samples, "
                                                f"where its other values repeat on {100.0 * repeats:.1f} % of "
                                                "them: clipped (saturated), the field went past the sensor's "
                                                "or the ADC's range: lower the channel's gain (or its offset, "
                                                "or the field at the bench) and record again",
                                     row=first, column=name)

    def check_dead_axis(self, names) -> None:
        """RecordingError naming the first of a vector sensor's columns ``names`` (all present) that never changes
        while the others change by more than :data:`DEAD_AXIS_SHARE` of the vector's median length, and the
        vector's length (steady for a sensor of a steady field: gravity) spreads by more than twice that share: a
        dead or disconnected axis.  A still housing logged at a coarse resolution changes none of them; a live
        coarse axis a gentle tilt leaves on one code (near level the vertical axis moves by ``1 - cos``, the others
        by ``sin``) keeps the length; a dead one takes its part out of it."""
        v = np.column_stack([self.column(name) for name in names])
        v = v[np.all(np.isfinite(v), axis=1)]  # a live record's rows the sensor was not sent on
        if len(v) == 0:
            return
        span = np.ptp(v, axis=0)
        norm = np.linalg.norm(v, axis=1)
        scale = np.median(norm)
        moved = span > DEAD_AXIS_SHARE * scale
        low, high = np.percentile(norm, [5.0, 95.0])
        if not high - low > 2.0 * DEAD_AXIS_SHARE * scale:
            return
        for k, name in enumerate(names):
            if span[k] == 0.0 and np.any(np.delete(moved, k)):
                raise RecordingError(self.path, f"is constant ({v[0, k]:g} in all {len(v)} rows) while "
                                                f"{', '.join(n for n, m in zip(names, moved) if m)} change: a dead "
                                                "or disconnected axis?", column=name)


DEAD_AXIS_SHARE = 0.1
"""A vector sensor's axis that never changes while another changes by more than this share of the vector's median
length is dead (:meth:`Table.check_dead_axis`): a tilt of 6 degrees moves an accelerometer's axes that much."""

CLIPPED_SHARE = 0.02
"""A channel on its extreme value in this share of its samples (and :data:`CLIPPED_MIN_SAMPLES`) is clipped
(:meth:`Table.check_clipped`).  A rail 0.3 % below a turning channel's peak holds it for 2 % of each turn
(``arccos(0.997) / 180 deg``); one flip of a four-flip is a quarter of its samples."""

CLIPPED_MIN_SAMPLES = 8
"""Fewest samples on one exact extreme value that count as a rail: a channel resolved more finely than its
noise repeats its largest value by chance about as often as any other, twice at most in practice."""

CLIPPED_REPEAT_SHARE = 0.1
"""A channel whose values other than its extremes repeat on more than this share of its samples is quantised
as coarsely as its noise (an integer ADC): an exact repeat of its extreme proves no rail and it is not judged.
Values drawn at random over ``K`` codes repeat on about ``n / (2 K)`` of ``n`` samples: 360 samples of a
float log over 10^5 codes 0.2 %, an integer channel spanning 600 counts 30 %."""


def read_table(path, options: ReadOptions | None = None, *, live_record: bool = False) -> Table:
    """Read and validate a numeric CSV recording.

    Parameters
    ----------
    path : str or Path
    options : ReadOptions, optional
        Column mapping and units named by the user.
    live_record : bool
        Read a ``compass live --record`` file (its ``# source:`` line) as the replay hands it to the live pipeline:
        its ``t_s`` may go back, as the module sent it (a clock the module restarted, a corrupted time: the filter
        skips or adopts it as the live session did), and with its ``# absent:`` line a ``nan`` group is one the
        module sent empty on that row.  Any other file, or any other reader, refuses both.

    Raises
    ------
    RecordingError
        Unreadable, binary or UTF-16 file, a folder, no header, no data rows, duplicate column, a
        mapped column that is absent, wrong number of cells, a cell that is not a finite number or
        is beyond ``MAX_ABS_VALUE``, ``t_s`` decreasing, a ``field_ut`` that is not a positive number.
    """
    options = options or ReadOptions()
    path = Path(path)
    _sniff(path)
    try:
        stream = open(path, encoding="utf-8-sig", newline=None)  # noqa: SIM115 (closed below)
    except OSError as exc:
        raise RecordingError(path, f"cannot read file ({exc.strerror})") from None
    with stream:
        lines = _Lines(path, stream)
        metadata, meta_rows = {}, {}
        header_text, header_line = None, 0
        for number, stripped in lines.content(metadata, meta_rows):
            header_text, header_line = stripped, number
            break
        if header_text is None:
            raise RecordingError(path, "no header row: expected comma-separated column names" if lines.any_text
                                 else "empty file: expected a header row and data rows")
        if header_text[:1] in ("{", "["):
            raise RecordingError(path, "this is JSON (a calibration file?): expected a CSV recording", row=header_line)
        sep = _separator(header_text)
        header = [_unquote(c) for c in (header_text.split(sep) if sep else header_text.split())]
        _check_header(path, header, header_line)
        first = lines.peek_data()
        if first is None:
            raise RecordingError(path, "header only: no data rows", row=header_line)
        decimal_comma = sep not in (",", None) and any(_DECIMAL_COMMA.match(_unquoted(c)) for c in first[1].split(sep))
        text = _bad_cells(path, header, sep, decimal_comma, *first, {})  # a logger's text columns, as row 1 shows
        data = None
        if not decimal_comma and not lines.skipped:  # numpy's reader straight over the rest of the stream
            try:
                data = np.loadtxt(itertools.chain([first[1]], lines.stream), comments="#", **_numbers(sep, text))
            except UnicodeDecodeError:
                raise _not_utf8(path) from None
            except ValueError:  # the numbering pass below finds the text cells, or finds and names the bad one
                data = None
            last = _last_content_line(path)
            if data is not None and data.shape[0] == last - first[0] + 1:  # no line skipped: rows in order
                rows = np.arange(first[0], last + 1)
            else:
                data = None
    if data is None:  # decimal commas, blank or comment lines among the rows, or a text cell: number every line
        data, rows, text = _load(path, header, sep, decimal_comma, header_line, text, metadata, meta_rows)
    if data.shape[1] != len(header):  # a one-row file whose row np.loadtxt cut at a '#' (its comments)
        raise RecordingError(path, f"expected {len(header)} cells a row, found {data.shape[1]}", row=int(rows[0]))
    live_record = live_record and metadata.get("source", "").startswith(LIVE_RECORD)
    absent = _absent_groups(header) if ABSENT_KEY in metadata else ()
    _check_values(path, header, data, rows, text, absent if live_record else (),
                  " (a group the module sent empty on that row: the replay, compass attitude --filter, reads it so)"
                  if absent and not live_record else "")
    text_cells = {header[j]: cell for j, cell in text.items()}
    return _interpret(Table(str(path), tuple(header), data, rows, metadata, header_line, text_cells=text_cells),
                      options, meta_rows, live_record)


def _numbers(sep, text) -> dict:
    """``np.loadtxt``'s options for the data lines: the cells of the columns ``text`` (indices) skipped as NaN."""
    return dict(delimiter=sep, ndmin=2, dtype=float, converters=dict.fromkeys(text, _skip_cell))


def _skip_cell(cell: str) -> float:
    """A text column's cell, as the table holds it: NaN."""
    return np.nan


def _load(path, header, sep, decimal_comma, header_line, text, metadata, meta_rows) -> tuple:
    """``np.loadtxt`` over the numbered data lines: (data, each row's line number, the text columns).

    ``text`` (column index -> (row, cell)) are the columns known to hold text; a column found to hold a cell that
    is not a number (:func:`_scan_for_bad_cells`) joins them and the file is read again, at most once a column.
    """
    while True:
        with open(path, encoding="utf-8-sig", newline=None) as stream:
            lines = _Lines(path, stream)
            for _ in lines.content(metadata, meta_rows):
                break
            lines.peek_data()
            try:
                data = np.loadtxt(lines.data(sep, decimal_comma), comments=None, **_numbers(sep, text))
                return data, lines.rows(), text
            except UnicodeDecodeError:
                raise _not_utf8(path) from None
            except RecordingError:
                raise
            except ValueError:  # a text cell in a column of numbers so far, or a bad cell count: found below
                pass
        text = text | _scan_for_bad_cells(path, header, sep, decimal_comma, header_line, text)


def _last_content_line(path) -> int:
    """1-based number of the file's last line that is not blank (newlines counted in blocks)."""
    count, tail = 0, b""
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            count += block.count(b"\n")
            tail = (tail + block)[-(1 << 16):]
    return count - tail[len(tail.rstrip()):].count(b"\n") + 1


def format_table(columns: dict, metadata: dict | None = None, formats: dict | None = None, *,
                 default: str = "%.4f", block_rows: int = 1 << 15) -> str:
    """CSV text that :func:`read_table` reads back: ``# key: value`` lines, a header, the rows.

    Parameters
    ----------
    columns : dict of str to array_like, each shape (n,)
        Column name -> values (bool columns are written as 0/1).
    metadata : dict, optional
    formats : dict of str to str, optional
        printf format per column; ``default`` for the others.
    block_rows : int
        Rows formatted at a time: the Python floats and row strings of one block are alive at once,
        not those of the whole table (about 30 bytes per cell instead of 130).
    """
    formats = formats or {}
    row_format = ",".join(formats.get(name, default) for name in columns)
    arrays = [np.asarray(v, dtype=int if np.asarray(v).dtype == bool else None) for v in columns.values()]
    parts = ["".join(f"# {k}: {v}\n" for k, v in (metadata or {}).items()) + ",".join(columns) + "\n"]
    n = len(arrays[0]) if arrays else 0
    for start in range(0, n, block_rows):
        block = [a[start:start + block_rows].tolist() for a in arrays]
        parts.append("\n".join(map(row_format.__mod__, zip(*block))) + "\n")
    return "".join(parts)


class _Lines:
    """The file's lines, numbered, read once as a stream (no list of the whole file).

    :meth:`content` yields the lines before the header; :meth:`data` yields the body's data
    lines for ``np.loadtxt`` and remembers the numbers of the lines it skipped (blank, comment),
    from which :meth:`rows` rebuilds each data row's line number.
    """

    def __init__(self, path, stream):
        self.path, self.stream, self.number, self.any_text = path, stream, 0, False
        self.skipped: list[int] = []
        self.first_data = self.last_data = None
        self._peeked = None
        self.metadata, self.meta_rows = None, None

    def _next(self):
        try:
            line = next(self.stream)
        except UnicodeDecodeError:
            raise _not_utf8(self.path) from None
        self.number += 1
        return line

    def content(self, metadata, meta_rows):
        """(line number, stripped line) of non-blank, non-comment lines; metadata collected."""
        self.metadata, self.meta_rows = metadata, meta_rows
        while True:
            try:
                line = self._next()
            except StopIteration:
                return
            stripped = line.strip()
            self.any_text |= bool(stripped)
            if self._comment(stripped):
                continue
            yield self.number, stripped

    def _comment(self, stripped: str) -> bool:
        if not stripped:
            return True
        if stripped.startswith("#"):
            key, sep, value = stripped[1:].partition(":")
            if sep and key.strip():
                self.metadata[key.strip()] = value.strip()
                self.meta_rows[key.strip()] = self.number
            return True
        return False

    def peek_data(self):
        """The first data line after the header, (number, line without its newline), without consuming it."""
        while True:
            try:
                line = self._next()
            except StopIteration:
                return None
            stripped = line.strip()
            if self._comment(stripped):
                self.skipped.append(self.number)
                continue
            self._peeked = (self.number, line.rstrip("\n"))  # a tab file's empty last cell kept
            self.first_data = self.number
            return self._peeked

    def data(self, sep, decimal_comma: bool):
        if self._peeked is not None:
            yield self._taken(*self._peeked, sep, decimal_comma)
        for line in self.stream:
            self.number += 1
            stripped = line.strip()
            if self._comment(stripped):
                self.skipped.append(self.number)
                continue
            yield self._taken(self.number, line.rstrip("\n"), sep, decimal_comma)

    def _taken(self, number: int, line: str, sep, decimal_comma: bool) -> str:
        """A data line as ``np.loadtxt`` reads it (decimal commas as points, cells :func:`_unquoted`), its number
        kept."""
        self.last_data = number
        if '"' in line:
            return (sep or " ").join(_unquoted(c) for c in _split(line, sep, decimal_comma))
        return line.replace(",", ".") if decimal_comma else line

    def rows(self) -> np.ndarray:
        rows = np.arange(self.first_data, self.last_data + 1)
        if self.skipped:
            rows = np.setdiff1d(rows, np.asarray(self.skipped), assume_unique=True)
        return rows


def _sniff(path: Path) -> None:
    """RecordingError for a folder, an unreadable, binary or UTF-16 file (before any text is decoded)."""
    if path.is_dir():
        raise RecordingError(path, "is a folder: expected a CSV file")
    try:
        with open(path, "rb") as f:
            head = f.read(_SNIFF_BYTES)
    except OSError as exc:
        raise RecordingError(path, f"cannot read file ({exc.strerror})") from None
    if head[:2] in (b"\xff\xfe", b"\xfe\xff"):
        raise RecordingError(path, "UTF-16 text: save the CSV as UTF-8 (or ASCII)", row=1)
    if b"\x00" in head:
        raise RecordingError(path, "binary data (NUL bytes): expected a text CSV file",
                             row=head[: head.index(b"\x00")].count(b"\n") + 1)


def _not_utf8(path) -> RecordingError:
    """The error for a file that is not UTF-8, at the line of its first bad byte."""
    row = None
    with open(path, "rb") as f:
        done = 0
        decoder = codecs.getincrementaldecoder("utf-8")()
        for block in iter(lambda: f.read(1 << 20), b""):
            try:
                decoder.decode(block)
            except UnicodeDecodeError as exc:
                row = done + block[: exc.start].count(b"\n") + 1
                break
            done += block.count(b"\n")
    return RecordingError(path, "not UTF-8 text: save the CSV as UTF-8 (or ASCII)", row=row)


def _separator(header: str) -> str | None:
    """The header's separator: semicolon or tab when present (spreadsheets), else comma; None
    (blanks) for a header of blank-separated names without any of them."""
    for sep in (";", "\t", ","):
        if sep in header:
            return sep
    return None if len(header.split()) > 1 else ","


def _unquote(name: str) -> str:
    name = name.strip()
    if len(name) >= 2 and name[0] == name[-1] and name[0] in "\"'":
        name = name[1:-1].strip()
    return name


def _check_header(path, header, row) -> None:
    for i, name in enumerate(header):
        if not name:
            raise RecordingError(path, f"empty column name at position {i + 1}", row=row)
        if _strict_float(name) is not None:
            raise RecordingError(path, f"header expected, found a number {name!r} (the file needs a header row "
                                       "naming its columns, or a '# columns:' line is not enough)", row=row, column=name)
        if header.index(name) != i:
            raise RecordingError(path, "duplicate column name", row=row, column=name)


def _strict_float(cell: str) -> float | None:
    """The number a CSV cell spells (decimal point, optional exponent, nan/inf), None if none.

    Stricter than ``float()``: no ``1_5`` (Python reads 15), no hexadecimal, no blanks inside.
    """
    return float(cell) if _NUMBER.match(cell) else None


def _unquoted(cell: str) -> str:
    """A data cell without the one pair of double quotes around it (``"12.5"``, a spreadsheet's export), if any."""
    inner = cell.strip()
    return inner[1:-1] if len(inner) >= 2 and inner[0] == inner[-1] == '"' else cell


def _is_number(cell: str) -> bool:
    """Whether a data cell is a number: :func:`_strict_float`'s form, bare or :func:`_unquoted`."""
    return _strict_float(_unquoted(cell)) is not None


def _not_a_number(path, column: str, row: int, cell: str) -> RecordingError:
    """The error for a cell of a used column that is not a number: its own column's name is a header repeated (a
    logger that restarted mid-file writes its header again)."""
    if _unquoted(cell).strip() == column.strip():
        hint = (" (the row repeats the header: a logger that restarted and wrote it again? delete that row, or split "
                "the file there)")
    else:
        hint = " (digit separators such as '_' are not read)" if "_" in cell else ""
    return RecordingError(path, f"expected a number, found {cell!r}{hint}", row=row, column=column)


def _split(line: str, sep, decimal_comma: bool) -> list[str]:
    cells = line.split(sep) if sep else line.split()
    return [c.replace(",", ".") for c in cells] if decimal_comma else cells


def _bad_cells(path, header, sep, decimal_comma, row, line, text) -> dict:
    """The cells of one data line that are not numbers, in the columns not in ``text``: column index ->
    (row, cell); RecordingError for a line with the wrong number of cells."""
    cells = _split(line, sep, decimal_comma)
    if len(cells) != len(header):
        hint = ""
        if sep == "," and len(cells) > len(header):
            hint = ("; decimal commas with a comma separator? Save the file with ';' between cells (decimal commas "
                    "are then read) or with decimal points")
        raise RecordingError(path, f"expected {len(header)} cells, found {len(cells)}{hint}", row=row)
    return {j: (row, cell.strip()) for j, cell in enumerate(cells) if j not in text and not _is_number(cell)}


def _scan_for_bad_cells(path, header, sep, decimal_comma, header_line, text) -> dict:
    """:func:`_bad_cells` of the first data line that has some (the slow path, only after ``np.loadtxt`` failed).

    Raises
    ------
    RecordingError
        A line with the wrong number of cells, or no line with such a cell.
    """
    with open(path, encoding="utf-8-sig", newline=None, errors="replace") as stream:
        for number, line in enumerate(stream, start=1):
            stripped = line.strip()
            if number <= header_line or not stripped or stripped.startswith("#"):
                continue
            found = _bad_cells(path, header, sep, decimal_comma, number, line.rstrip("\n"), text)
            if found:
                return found
    raise RecordingError(path, "could not parse the data rows as numbers")


def _absent_groups(header) -> list:
    """Column indices of each optional group the header has whole (:data:`ABSENT_KEY`)."""
    return [[header.index(c) for c in group] for group in _OPTIONAL_GROUPS if all(c in header for c in group)]


def _check_values(path, header, data, rows, text, absent=(), hint: str = "") -> None:
    """RecordingError at the first non-finite cell (``hint`` added to its words), or the first beyond
    ``MAX_ABS_VALUE``; ``text``: column indices whose cells were skipped (NaN); ``absent``: column indices of groups
    whose cells may be NaN together (that group not sent on that row)."""
    lo, hi = data.min(), data.max()  # NaN propagates; no copy of the data
    if -units.MAX_ABS_VALUE <= lo and hi <= units.MAX_ABS_VALUE:
        return
    finite = np.isfinite(data)
    finite[:, list(text)] = True
    for group in absent:
        finite[:, group] |= np.isnan(data[:, group]).all(axis=1)[:, None]
    if not finite.all():
        i, j = np.argwhere(~finite)[0]
        every = "" if finite[:, j].any() else (f" (as in all {len(data)} rows of {header[j]}: a sensor not recorded? "
                                                "leave its columns out)")
        raise RecordingError(path, f"expected a finite number, found {float(data[i, j])!r}{every or hint}",
                             row=int(rows[i]), column=header[j])
    big = np.abs(np.nan_to_num(data)) > units.MAX_ABS_VALUE
    if big.any():
        i, j = np.argwhere(big)[0]
        raise RecordingError(path, f"{data[i, j]:g} is beyond {units.MAX_ABS_VALUE:g} in magnitude, which no sensor "
                                   "output, time or angle reaches in any unit (a 32-bit ADC counts to 4.3e9; 45 T, the "
                                   "strongest steady laboratory field, is 4.5e10 nT): a corrupted cell?",
                             row=int(rows[i]), column=header[j])


def _interpret(table: Table, options: ReadOptions, meta_rows: dict, time_may_go_back: bool = False) -> Table:
    """Names and units: mapping, log headers, case; conversions to SPEC's units; t_s and field_ut."""
    path, header = table.path, list(table.columns)
    original = dict(zip(header, header))
    named_units: dict[str, str] = {}
    mapping, source = dict(options.columns), "--columns"
    if not mapping and "columns" in table.metadata:
        try:
            mapping, source = parse_column_map(table.metadata["columns"], source="'# columns:'"), "'# columns:' line"
        except ValueError as exc:
            raise RecordingError(path, str(exc), row=meta_rows.get("columns")) from None
    negate, as_read, taken = [], tuple(header), {}  # every name maps to the header as read: mx=my,my=mx swaps two
    for ours, theirs in mapping.items():
        sign = -1 if theirs.startswith("-") and theirs not in as_read else 1
        theirs = theirs[1:].strip() if sign < 0 else theirs
        matches = [i for i, c in enumerate(as_read) if c == theirs] or \
                  [i for i, c in enumerate(as_read) if c.lower() == theirs.lower()]
        if len(matches) != 1:
            raise RecordingError(path, f"{source} maps {ours} to '{theirs}', which the header does not have "
                                       f"(header has: {', '.join(as_read)})", row=table.header_line, column=theirs)
        if matches[0] in taken:
            raise RecordingError(path, f"{source} maps both {taken[matches[0]]} and {ours} to '{theirs}': one column "
                                       "reads one quantity", row=table.header_line, column=theirs)
        taken[matches[0]] = ours
        header[matches[0]] = ours
        if ours in _TIME_COLUMNS:  # t_ms=COLUMN, t_us=COLUMN: a time in ms, us (as compass live's --columns names it)
            header[matches[0]], named_units["t_s"] = "t_s", _TIME_COLUMNS[ours]
        if sign < 0:
            negate.append(matches[0])
    for ours in mapping:
        if header.count(ours) > 1:  # the header's own column of that name was not mapped away
            raise RecordingError(path, f"{source} maps {ours} to another column, and the header's own column '{ours}' "
                                       f"is left as it is: map that one too (two columns cannot both be {ours})",
                                 row=table.header_line, column=ours)
    if negate:
        table.data[:, negate] *= -1.0
    recognised: dict[str, list] = {}
    for i, name in enumerate(header):
        if name in mapping:
            continue
        canon, unit = log_column_name(name)
        if canon is not None and canon not in header:
            header[i] = canon
            recognised.setdefault(canon[0] if canon != "t_s" else canon, []).append((canon, name, unit))
            if unit:
                named_units[canon] = unit
    if recognised:
        groups = [f"{','.join(c for c, _, _ in cols)} = '{cols[0][1]}'{'...' * (len(cols) > 1)}"
                  for cols in recognised.values()]
        note(f"{path}: read the log's header as {'; '.join(groups)} (units as the header names them)")
    vocabulary = {v.lower(): v for v in VOCABULARY}
    for i, name in enumerate(header):
        canon = vocabulary.get(name.lower())
        if canon is not None and canon != name:
            if canon in header:
                raise RecordingError(path, f"two columns are named '{canon}' (names match without regard to case)",
                                     row=table.header_line, column=name)
            header[i] = canon
    folded = [name.lower() for name in header]
    for i, name in enumerate(folded):
        if folded.index(name) != i:
            raise RecordingError(path, f"two columns are named '{header[i]}' (names match without regard to case; "
                                       f"in the header: '{table.columns[folded.index(name)]}' and '{table.columns[i]}')",
                                 row=table.header_line, column=header[i])
    original = {new: original[old] for new, old in zip(header, table.columns)}
    text_cells = {new: table.text_cells[old] for new, old in zip(header, table.columns) if old in table.text_cells}
    _check_named_numbers(path, header, original, text_cells)
    data = table.data
    converted, gyro_ratio = _convert_units(table, header, data, options, named_units)
    table = Table(path, tuple(header), converted, table.rows, table.metadata, table.header_line, original, named_units,
                  gyro_ratio, text_cells)
    if not time_may_go_back:
        _check_time(table)
    _check_field_ut(table, meta_rows)
    return table


def _check_named_numbers(path, header, original, text_cells) -> None:
    """RecordingError at the first cell (by row) that is not a number in a column SPEC names (:data:`VOCABULARY`):
    the reader itself uses those (units, ``t_s``); another column's text is refused only where it is used
    (:meth:`Table.column`)."""
    named = [(row, header.index(name), name, cell) for name, (row, cell) in text_cells.items() if name in VOCABULARY]
    if named:
        row, _, name, cell = min(named)
        raise _not_a_number(path, original[name], row, cell)


def magnetometer_axis(name: str) -> str | None:
    """The magnetometer axis (``"x"``, ``"y"`` or ``"z"``) a column's name says, as this reader reads the name.

    ``mx``, ``my``, ``mz`` in any case, a log's ``Magnetometer X (uT)``, ``mag_x``, ``MagX`` (:func:`log_column_name`),
    and a bare ``x``, ``y``, ``z``; None for any other name (``v1``, ``ch_a``).

    Examples
    --------
    >>> [magnetometer_axis(n) for n in ("MY", "Magnetometer Z (uT)", "mag_x", "x", "v1", "ay")]
    ['y', 'z', 'x', 'x', None, None]
    """
    canon = name.lower() if name.lower() in _MAG else log_column_name(name)[0]
    if canon in _MAG:
        return canon[1]
    return name.lower() if name.lower() in ("x", "y", "z") else None


def log_column_name(name: str) -> tuple[str | None, str | None]:
    """A log header's sensor column as (toolkit name, unit): ``"Gyroscope X (deg/s)"`` -> ``("gx", "deg/s")``."""
    m = _TIME_NAME.match(name)
    if m:
        return "t_s", m.group("unit")
    m = _LOG_NAME.match(name)
    if not m or m.group("sensor").lower() not in _LOG_SENSORS:
        return None, None
    letter = _LOG_SENSORS[m.group("sensor").lower()]
    kind = {"g": "gyro", "a": "accel", "m": "mag"}[letter]
    unit = units.unit_of_header(kind, m.group("unit")) if m.group("unit") else None
    return letter + m.group("axis").lower(), unit


def _convert_units(table: Table, header, data, options: ReadOptions, named: dict) -> tuple[np.ndarray, float | None]:
    """Scale columns to SPEC's units (in place on ``data``, which the table owns); the data and the gyro's
    turn ratio (:func:`compass.io.units.check_gyro_unit`, None without a gyro, an accelerometer and ``t_s``)."""
    path = table.path

    def scale(cols, factor):
        idx = [header.index(c) for c in cols if c in header]
        if idx and factor != 1.0:
            data[:, idx] *= factor

    for group, unit_option, table_units, kind in ((_GYRO, options.gyro_unit, units.GYRO_UNITS, "gyro"),
                                                  (_ACCEL, options.accel_unit, units.ACCEL_UNITS, "accel"),
                                                  (_MAG, options.mag_unit, units.MAG_UNITS, "mag")):
        header_unit = next((named[c] for c in group if c in named), None)
        unit = unit_option or header_unit
        for c in group:
            named.pop(c, None)
        if unit is None or not any(c in header for c in group):
            continue
        if kind == "accel":
            named.update({c: unit for c in group if c in header})
            continue  # the accelerometer keeps its unit (any unit, SPEC); the unit is used for checks
        scale(group, table_units[unit])
        named.update({c: unit for c in group if c in header})
    if "t_s" in named and named["t_s"] != "s":
        scale(("t_s",), {"ms": 1e-3, "us": 1e-6}[named["t_s"]])
    if options.accel_sign == -1:
        scale(_ACCEL, -1.0)
    if options.angle_unit != "deg":
        scale([c for c in header if c.endswith("_deg")], units.ANGLE_UNITS[options.angle_unit])
    _check_accel_unit(path, header, data, named.get("ax"))
    ratio = None
    if all(c in header for c in _GYRO + _ACCEL + ("t_s",)):
        sent = np.isfinite(data[:, [header.index(c) for c in _GYRO + _ACCEL]]).all(axis=1)  # ABSENT_KEY's rows out
        cols = lambda names: data[sent][:, [header.index(c) for c in names]]  # noqa: E731
        ratio = units.check_gyro_unit(data[sent, header.index("t_s")], cols(_GYRO), cols(_ACCEL),
                                      named=options.gyro_unit is not None or "gx" in named, where=path)
    return data, ratio


def _check_accel_unit(path, header, data, unit) -> None:
    """Warn when the accelerometer's typical |a| is not 1 g in the unit named."""
    if unit is None or not all(c in header for c in _ACCEL):
        return
    norm = float(np.nanmedian(np.linalg.norm(data[:, [header.index(c) for c in _ACCEL]], axis=1)))
    g = norm * units.ACCEL_UNITS[unit]
    if not 0.8 <= g <= 1.25:
        other = [u for u, f in units.ACCEL_UNITS.items() if 0.8 <= norm * f <= 1.25]
        hint = f"; in {other[0]} it would be 1 g: --accel-unit {other[0]}" if other else ""
        note(f"{path}: the accelerometer's median |a| is {norm:.3g} {unit} = {g:.3g} g, not 1 g{hint}")


def _check_time(table: Table) -> None:
    if not table.has("t_s"):
        return
    t_s = table.column("t_s")
    back = np.flatnonzero(t_s[1:] < t_s[:-1])
    if back.size:
        i = back[0]
        raise RecordingError(table.path, f"t_s must not decrease (goes from {t_s[i]} to {t_s[i + 1]})",
                             row=int(table.rows[i + 1]), column="t_s")


def _check_field_ut(table: Table, meta_rows: dict) -> None:
    """``# field_ut:`` must be |B| in uT: a positive finite number; warn outside the Earth's range."""
    if "field_ut" not in table.metadata:
        return
    text = table.metadata["field_ut"]
    value = _strict_float(text)
    if value not in FIELD_UT:
        raise RecordingError(table.path, f"metadata 'field_ut' must be |B| in uT, {FIELD_UT.describe()}, got {text!r}",
                             row=meta_rows.get("field_ut"), column="field_ut")
    lo, hi = units.EARTH_FIELD_UT
    if not 0.5 * lo <= value <= 2 * hi:
        note(f"{table.path}: metadata field_ut {value:g} uT is not the Earth's {lo:g}-{hi:g} uT (gauss or nT?); "
             "a coil's field may be")
