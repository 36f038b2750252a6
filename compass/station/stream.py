"""The module's stream as the bench station reads it: bytes in any stream format to :class:`Reading` values.

The station knows no calibration, so the module's magnetic channels come from the stream itself:
the columns of our protocol's first header, or of ``--columns`` for bare numbers, that are not
reserved (SPEC section 2: ``t_s``, ``seq``, ``temp_c``, ``ax..az``, ``gx..gz``) nor the encoder
column; MotionCal's ``mx, my, mz``.  The format (``--format auto|compass|motioncal|csv``) and the
units (``--mag-unit``, ``--accel-unit``, ``--gyro-unit``) are those of every command that reads a
stream: :class:`compass.io.streams.StreamDecoder` finds the format from the first lines and
decodes it (checksums, partial lines, lost samples, the unit checks).  A later header with other
columns ends the session.

A stream without a module clock (MotionCal's lines, a CSV without ``t_s``) is dated on arrival
(:class:`compass.io.clock.SampleClock`, as ``compass live`` dates it), so the station then works in the
host's time, which is the module's when the module runs in real time.
"""

from __future__ import annotations

from ..io.clock import SampleClock
from ..io.stream_options import StreamOptions
from ..io.streams import StreamDecoder
from .session import SessionEnded
from .turn import Reading

__all__ = ["StationStream", "RESERVED"]

RESERVED = ("t_s", "seq", "temp_c", "ax", "ay", "az", "gx", "gy", "gz", "flip_deg", "platform_deg")
_MOTIONCAL_CHANNELS = ("mx", "my", "mz")
_PENDING_BYTES = 1 << 16  # kept while the format and the channels are found


class StationStream:
    """Bytes in, readings out.

    Parameters
    ----------
    encoder_column : str, optional
        The turntable's column (``--turntable column:NAME``): required in the stream's columns.
    expected_header : tuple of str, optional
        The columns of the flips already kept (``--resume``): other ones end the session.
    options : compass.io.stream_options.StreamOptions, optional
        ``--format``, ``--columns`` and the units (default: the format found, units as sent).

    Attributes
    ----------
    header : tuple of str or None
        The columns the module sends (our header's names, ``--columns``, or MotionCal's).
    channels : tuple of str
        Its magnetic channels.
    format : str or None
        ``compass``, ``motioncal`` or ``csv`` once found.
    decoder : StreamDecoder or None
        The decoder of the channels, once they are known.
    events : list of (str, str)
        ``(level, text)``: the format found, the decoder's warnings (:meth:`drain`).
    """

    def __init__(self, encoder_column: str | None = None, expected_header: tuple | None = None,
                 options: StreamOptions | None = None):
        self.encoder_column = encoder_column
        self.expected_header = tuple(expected_header) if expected_header else None
        self.options = options or StreamOptions()
        self.header = None
        self.channels: tuple = ()
        self.format = None
        self.decoder = None
        self.events: list = []
        self._probe = StreamDecoder((), self.options)  # finds the format and the columns
        self._pending = b""
        self._cut = False  # the pending bytes may start mid-line (a (re)connect, or kept only in part)
        self._rejected = 0
        self._clock = SampleClock()

    def describe(self) -> str:
        """The stream's format in a few words, for the readout."""
        return (self.decoder or self._probe).describe()

    def drain(self) -> list:
        """Return and clear the pending events."""
        events, self.events = self.events, []
        return events

    def resync(self) -> None:
        """After a (re)connect: the first bytes may be the tail of a line, and the sample clock starts again (its
        period kept)."""
        (self.decoder or self._probe).resync()
        self._pending = b""
        self._cut = True
        self._clock.restart()

    def feed(self, chunk: bytes, t_rx: float | None = None) -> list[Reading]:
        """Readings of the complete lines in ``chunk`` received at ``t_rx`` (seconds, any clock: it dates the
        samples of a stream without ``t_s``).

        Raises
        ------
        SessionEnded
            The stream cannot be read (bare numbers without ``--columns``, no magnetic channel, no encoder
            column), or its columns changed (the module sends other columns than at the start).
        """
        if self.decoder is None:
            self._cut |= len(self._pending) + len(chunk) > _PENDING_BYTES
            self._pending = (self._pending + chunk)[-_PENDING_BYTES:]
            self._probe.feed(chunk, t_rx)
            self.events += [e for e in self._probe.drain_events() if e[1].startswith("stream format:")]
            if self._probe.fatal is not None:
                raise SessionEnded(f"the module's stream: {self._probe.fatal}")
            if self._probe.format is None or self._probe.header is None:
                return []
            self._start(self._probe.format, tuple(self._probe.header.names))
            chunk, self._pending = self._pending, b""
            if self._cut:
                self.decoder.resync()
        samples = self.decoder.feed(chunk, t_rx)
        self.events += self.decoder.drain_events()
        if self.decoder.fatal is not None:
            raise SessionEnded(f"the module's stream: {self.decoder.fatal}")
        self._check_header()
        return self._readings(samples, t_rx)

    # ---------------------------------------------------------------- internals
    def _start(self, fmt: str, names: tuple) -> None:
        """Adopt the format found and its columns: the channels, the encoder's place, the decoder."""
        column = self.encoder_column
        if fmt == "motioncal":
            if column is not None:
                raise SessionEnded(f"MotionCal lines carry no encoder column {column!r} (--turntable column:{column}):"
                                   f" use --turntable gyro, manual:STEP_DEG or grbl:PORT")
            channels = _MOTIONCAL_CHANNELS
        else:
            where = "header" if fmt == "compass" else "--columns"
            if column is not None and column not in names:
                raise SessionEnded(f"the module's {where} {','.join(names)} has no column {column!r} "
                                   f"(--turntable column:{column})")
            channels = tuple(n for n in names if n not in RESERVED and n != column)
            if not channels:
                raise SessionEnded(f"the module's {where} {','.join(names)} has no magnetic channel")
        if self.expected_header is not None and names != self.expected_header:
            raise SessionEnded(f"the module sends {','.join(names)}, the flips kept have {','.join(self.expected_header)}"
                               f": --resume needs the same module sending the same columns")
        extra = (column,) if column is not None else ()
        units = (None,) * 3 if fmt == "motioncal" else (self.options.mag_unit, self.options.accel_unit,
                                                          self.options.gyro_unit)  # MotionCal's are its own
        options = StreamOptions(fmt, self.options.columns if fmt == "csv" else None, *units,
                                accel_sign=self.options.accel_sign)
        self.decoder = StreamDecoder(channels + extra, options, unscaled=extra)
        self.decoder.drain_events()  # the format was said by the probe
        self.format, self.header, self.channels = fmt, names, channels

    def _check_header(self) -> None:
        header = self.decoder.header
        names = None if header is None else tuple(header.names)
        if self.decoder.stats.rejected_headers > self._rejected or (names is not None and names != self.header):
            words = ",".join(names) if names is not None and names != self.header else "one lacking its channels"
            raise SessionEnded(f"the module's header changed from {','.join(self.header)} to {words}: the module "
                               f"sends other columns than at the start")

    def _readings(self, samples, t_rx) -> list[Reading]:
        if not samples:
            return []
        if t_rx is None and any(s.t_s is None for s in samples):
            raise ValueError("a stream without t_s needs the chunks' receive times (t_rx)")
        c = len(self.channels)
        return [Reading(float(s.t_s), s.raw[:c], s.accel, s.gyro,
                        float(s.raw[c]) if self.encoder_column is not None else None, s.temp_c)
                for s in self._clock.dated(samples, t_rx, 0.0)]
