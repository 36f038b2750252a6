"""The samples a live session takes, written as a recording ``compass attitude --filter`` replays.

``compass live --record RAW.csv`` writes, row by row as they arrive, every sample the decoder hands the
session: its time (the module's ``t_s``, or the date :class:`compass.io.clock.SampleClock` gave a stream
without one), the calibration's channels in the unit it reads them (``--mag-unit`` applied), ``temp_c``,
the accelerometer (in g when its unit is known: ``--accel-unit`` or MotionCal's lines) and the gyro in
rad/s, each number written exactly (``repr``), so the replay takes the very floats the live filter took
and writes the same rows.  The first lines say how it was recorded and the replay that reproduces it (with
the session's own options: the site and its date, a given gravity, the calibration's latency and gyro matrix).
The columns are the module's header's; a row on which the module sent an optional group empty (``temp_c``, the
accelerometer's or the gyro's, as the line protocol allows) has ``nan`` in its cells, which the replay reads as
that group not sent on that row, as the live session took it.  A later header with other columns ends the
recording (said once): one file has one set of columns.

:func:`read_replay_line` reads that ``# replay:`` line back: the replay takes its options as defaults, so the plain
``compass attitude CAL THIS.csv --out ATT.csv --filter`` writes the session's rows.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass

from .table import ABSENT_KEY, LIVE_RECORD
from .units import ACCEL_UNITS

__all__ = ["REPLAY_FLAGS", "REPLAY_VALUES", "RecordedReplay", "SampleLog", "parse_replay_line", "read_replay_line"]

REPLAY_FLAGS = {"--mag-latency": "mag_latency", "--gyro-matrix": "gyro_matrix"}
"""The replay's switches a ``# replay:`` line may name -> :func:`compass.replay.replay_file`'s keyword."""
REPLAY_VALUES = {"--site": "site", "--date": "date", "--gravity": "gravity", "--gyro-scale-error": "gyro_scale_error",
                 "--accel-unit": "accel_unit"}
"""The replay's options with a value a ``# replay:`` line may name -> the keyword (``accel_unit``: the
:class:`compass.io.table.ReadOptions` field)."""
_NUMBERS = ("gravity", "gyro_scale_error")
_OWN = {"--out": 1, "--filter": 0}
"""The replay command's own options in the line (with how many values): the command line gives them."""
_MAX_HEADER_LINES = 64
"""Lines read for the ``# source:`` and ``# replay:`` lines (a record writes four before its header)."""

_ABSENT = float("nan")


def _columns(sample) -> tuple:
    """Whether the sample's header has ``temp_c``, the accelerometer and the gyro (the sample's own groups when it
    was made without one)."""
    h = sample.header
    if h is None:
        return sample.temp_c is not None, sample.accel is not None, sample.gyro is not None
    return h.temp_c is not None, h.accel is not None, h.gyro is not None


class SampleLog:
    """Writes a session's samples as a CSV recording (SPEC section 2 columns).

    Parameters
    ----------
    out : text file
        Receives the lines (the command's atomic stream).
    channels : tuple of str
        The calibration's channel names, in the order of ``Sample.raw``.
    source : str
        Where the samples came from (the port), for the first line.
    replay_options : str
        The session's options the replay needs too (``--site LAT,LON --date YYYY-MM-DD --gravity G`` ...).
    """

    def __init__(self, out, channels, source: str, replay_options: str = ""):
        self.out, self.channels, self.source = out, tuple(channels), source
        self.replay_options = replay_options
        self.rows = 0
        self.stopped: str | None = None
        self._shape: tuple | None = None

    def write(self, samples: list, accel_in_g: bool) -> str | None:
        """Write the samples; words when this ends the recording (the columns changed), else None.

        Parameters
        ----------
        samples : list of compass.io.lines.Sample
            Each with its ``t_s`` (the module's, or its date), s.
        accel_in_g : bool
            The accelerometer's unit is known, so it is in g (said in the first lines, with the replay's
            ``--accel-unit g``).
        """
        for sample in samples:
            if self.stopped is not None:
                return None
            shape = _columns(sample)
            if self._shape is None:
                self._begin(shape, accel_in_g)
            elif shape != self._shape:
                self.stopped = (f"the module's columns changed after {self.rows} samples: --record holds those "
                                f"(one file has one set of columns)")
                return self.stopped
            cells = [sample.t_s, *sample.raw.tolist()]
            if shape[0]:
                cells.append(_ABSENT if sample.temp_c is None else sample.temp_c)
            for present, vector in zip(shape[1:], (sample.accel, sample.gyro)):
                if present:
                    cells += [_ABSENT] * 3 if vector is None else vector.tolist()
            self.out.write(",".join(map(repr, map(float, cells))) + "\n")
            self.rows += 1
        return None

    def _begin(self, shape: tuple, accel_in_g: bool) -> None:
        self._shape = shape
        temp, accel, gyro = shape
        unit = " --accel-unit g" if accel and accel_in_g else ""
        names = ["t_s", *self.channels] + (["temp_c"] if temp else []) + (["ax", "ay", "az"] if accel else []) \
            + (["gx", "gy", "gz"] if gyro else [])
        options = f" {self.replay_options}" if self.replay_options else ""
        self.out.write(f"# source: {LIVE_RECORD}, {self.source}\n"
                       f"# replay: compass attitude CAL.json THIS.csv --out ATT.csv --filter{unit}{options}\n"
                       + (f"# {ABSENT_KEY}: nan where the module sent the group empty on that row\n"
                          if temp or accel or gyro else "")
                       + f"# units: the calibration's for {','.join(self.channels)}"
                       + (f"; accelerometer in {'g' if accel_in_g else 'the module unit'}" if accel else "")
                       + ("; gyro in rad/s" if gyro else "") + "\n" + ",".join(names) + "\n")


@dataclass(frozen=True)
class RecordedReplay:
    """The options a live record's ``# replay:`` line names.

    Attributes
    ----------
    values : dict
        Keyword (:data:`REPLAY_FLAGS`, :data:`REPLAY_VALUES`) -> value: ``True`` for a switch, a float for
        ``gravity`` and ``gyro_scale_error``, else the text.
    written : dict of str to str
        Keyword -> the option as the line writes it (``--site 48.15,11.58``), for the words.
    ignored : tuple of str
        The line's options the replay does not take (a port, a duration) or cannot read, as written, each with why.
    """

    values: dict
    written: dict
    ignored: tuple = ()


def read_replay_line(path) -> RecordedReplay:
    """The options of ``path``'s ``# replay:`` line when it is a ``compass live --record`` file (its ``# source:``
    line); none otherwise, and for a file that cannot be read (the table's reader then says why)."""
    metadata = {}
    try:
        with open(path, encoding="utf-8-sig") as f:
            for _, line in zip(range(_MAX_HEADER_LINES), f):
                stripped = line.strip()
                if stripped and not stripped.startswith("#"):
                    break
                key, sep, value = stripped[1:].partition(":")
                if sep:
                    metadata.setdefault(key.strip(), value.strip())
    except (OSError, UnicodeDecodeError):
        return RecordedReplay({}, {})
    if not metadata.get("source", "").startswith(LIVE_RECORD) or "replay" not in metadata:
        return RecordedReplay({}, {})
    return parse_replay_line(metadata["replay"])


def parse_replay_line(text: str) -> RecordedReplay:
    """The options of a ``# replay:`` line (``compass attitude CAL.json THIS.csv --out ATT.csv --filter ...``).

    Examples
    --------
    >>> r = parse_replay_line("compass attitude CAL.json THIS.csv --out ATT.csv --filter --gravity 1.02 --port /dev/x")
    >>> r.values, r.ignored
    ({'gravity': 1.02}, ('--port /dev/x (not an option of the replay)',))
    """
    try:
        words = shlex.split(text)
    except ValueError as exc:
        return RecordedReplay({}, {}, (f"the whole line ({exc})",))
    values, written, ignored = {}, {}, []
    k = next((i for i, w in enumerate(words) if w.startswith("--")), len(words))  # compass attitude CAL THIS
    while k < len(words):
        option, _, value = words[k].partition("=")
        k += 1
        if not value and option in REPLAY_VALUES and k < len(words) and not words[k].startswith("--"):
            value, k = words[k], k + 1
        if option in _OWN:
            k += 0 if value else _OWN[option]
        elif option in REPLAY_FLAGS:
            values[REPLAY_FLAGS[option]], written[REPLAY_FLAGS[option]] = True, option
        elif option in REPLAY_VALUES:
            key, why = REPLAY_VALUES[option], _unreadable(REPLAY_VALUES[option], value)
            if why:
                ignored.append(f"{option} {value}".strip() + f" ({why})")
            else:
                values[key] = float(value) if key in _NUMBERS else value
                written[key] = f"{option} {shlex.quote(value)}"
        else:
            rest = [words[k - 1]]
            while k < len(words) and not words[k].startswith("--"):
                rest.append(words[k])
                k += 1
            why = "not an option" if not option.startswith("--") else "not an option of the replay"
            ignored.append(f"{' '.join(rest)} ({why})")
    return RecordedReplay(values, written, tuple(ignored))


def _unreadable(key: str, value: str) -> str:
    """Why a ``# replay:`` line's value of ``key`` cannot be taken ('' when it can)."""
    if not value:
        return "no value"
    if key in _NUMBERS:
        try:
            float(value)
        except ValueError:
            return "not a number"
    if key == "accel_unit" and value not in ACCEL_UNITS:
        return f"not one of {', '.join(ACCEL_UNITS)}"
    return ""
