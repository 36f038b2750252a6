"""The module's stream as the bench station reads it: protocol lines to :class:`Reading` values.

The station knows no calibration: the module's magnetic channels are the columns of its first
header that are not reserved (SPEC section 2: ``t_s``, ``seq``, ``temp_c``, ``ax..az``,
``gx..gz``) nor the encoder column.  Lines are decoded by :class:`compass.io.lines.LineDecoder`
(checksums, partial lines, lost samples); a later header with other columns ends the session.
"""

from __future__ import annotations

from ..io.lines import LineDecoder
from .session import SessionEnded
from .turn import Reading

__all__ = ["StationStream", "RESERVED"]

RESERVED = ("t_s", "seq", "temp_c", "ax", "ay", "az", "gx", "gy", "gz", "flip_deg", "platform_deg")


class StationStream:
    """Bytes in, readings out.

    Parameters
    ----------
    encoder_column : str, optional
        The turntable's column (``--turntable column:NAME``): required in the header.
    expected_header : tuple of str, optional
        The header of the flips already kept (``--resume``): another one ends the session.

    Attributes
    ----------
    header : tuple of str or None
        The module's first header.
    channels : tuple of str
        Its magnetic channels.
    decoder : LineDecoder or None
    """

    def __init__(self, encoder_column: str | None = None, expected_header: tuple | None = None):
        self.encoder_column = encoder_column
        self.header = tuple(expected_header) if expected_header else None
        self.channels: tuple = ()
        self.decoder = None
        self._sniffer = LineDecoder(())
        self._pending = b""
        self._rejected = 0
        if self.header is not None:
            self._start(self.header)

    def _start(self, names: tuple) -> None:
        if self.encoder_column is not None and self.encoder_column not in names:
            raise SessionEnded(f"the module's header {','.join(names)} has no column {self.encoder_column!r} "
                               f"(--turntable column:{self.encoder_column})")
        self.channels = tuple(n for n in names if n not in RESERVED and n != self.encoder_column)
        if not self.channels:
            raise SessionEnded(f"the module's header {','.join(names)} has no magnetic channel")
        extra = (self.encoder_column,) if self.encoder_column is not None else ()
        self.decoder = LineDecoder(self.channels + extra)
        self.header = names

    def resync(self) -> None:
        """After a (re)connect: the first bytes may be the tail of a line."""
        if self.decoder is not None:
            self.decoder.resync()
        self._pending = b""

    def feed(self, chunk: bytes, t_rx: float | None = None) -> list[Reading]:
        """Readings of the complete lines in ``chunk``; ``t_rx`` stands in for a missing ``t_s``.

        Raises
        ------
        SessionEnded
            A header with other columns than the first (the module changed what it sends).
        """
        if self.decoder is None:
            self._pending += chunk
            self._sniffer.feed(chunk)
            if self._sniffer.header is None:
                self._pending = self._pending[-65536:]
                return []
            self._start(self._sniffer.header.names)
            chunk, self._pending = self._pending, b""
            self.decoder.resync()
        samples = self.decoder.feed(chunk)
        header = self.decoder.header
        if self.decoder.stats.rejected_headers > self._rejected or (header is not None and header.names != self.header):
            names = header.names if header is not None and header.names != self.header else None
            words = ",".join(names) if names else "one lacking its channels"
            raise SessionEnded(f"the module's header changed from {','.join(self.header)} to {words}: the module "
                               f"sends other columns than at the start")
        c = len(self.channels)
        out = []
        for s in samples:
            t = s.t_s if s.t_s is not None else t_rx
            encoder = float(s.raw[c]) if self.encoder_column is not None else None
            out.append(Reading(t, s.raw[:c], s.accel, s.gyro, encoder, s.temp_c))
        return out
