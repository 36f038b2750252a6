"""Read a serial port (or any pyserial URL) as timestamped byte chunks, surviving disconnects.

:class:`SerialReader` opens ``serial.serial_for_url(url)`` (a device path such as ``/dev/ttyUSB0``,
or ``socket://host:port``, ``rfc2217://...``, ``loop://``), yields whatever bytes arrive with the
time they were read, and turns every failure into a :class:`LinkEvent`:

- a port that cannot be opened (unplugged, not there yet) is retried every ``retry_s``;
- a port that fails while reading (``SerialException``/``OSError``: a pty whose master closed, a
  USB adapter pulled, a socket closed by its peer) is closed and reopened when it returns.

Pitfall handled by the consumer: ``open()`` discards input the device sent before (posix
``tcflush``, socket drain), so the first bytes after a "connected" event usually start mid-line;
:meth:`compass.io.lines.LineDecoder.resync` drops that fragment.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Iterator

import serial

__all__ = ["Chunk", "LinkEvent", "SerialReader"]


@dataclass(frozen=True)
class Chunk:
    """Bytes read from the port.

    Attributes
    ----------
    t_rx : float
        ``time.perf_counter()`` when the read returned, seconds.
    data : bytes
    """

    t_rx: float
    data: bytes


@dataclass(frozen=True)
class LinkEvent:
    """A change of the link.

    Attributes
    ----------
    kind : {"connected", "disconnected", "waiting"}
        ``waiting``: the port cannot be opened (sent once per outage).
    message : str
    t_rx : float
        ``time.perf_counter()``, seconds.
    """

    kind: str
    message: str
    t_rx: float


class SerialReader:
    """Chunks and link events from a pyserial URL; never raises on I/O failures.

    Parameters
    ----------
    url : str
        Device path or pyserial URL.
    baudrate : int
        Ignored by ptys and sockets.
    read_timeout_s : float
        Longest a read blocks, seconds (how often ``stop`` is checked when the line is quiet).
    retry_s : float
        Delay between attempts to (re)open the port, seconds.

    Examples
    --------
    >>> import threading
    >>> reader = SerialReader("loop://")
    >>> items = reader.items(threading.Event())
    >>> next(items).kind
    'connected'
    >>> reader.port.write(b"mx,my,mz\\n")
    9
    >>> next(items).data
    b'mx,my,mz\\n'
    >>> reader.close()
    """

    def __init__(self, url: str, *, baudrate: int = 115200, read_timeout_s: float = 0.05, retry_s: float = 0.25):
        self.url = url
        self.baudrate = baudrate
        self.read_timeout_s = read_timeout_s
        self.retry_s = retry_s
        self.port = None
        self.disconnects = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        """Close the port if open."""
        if self.port is not None:
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass  # already gone: nothing left to release
            self.port = None

    def check_url(self) -> None:
        """Raise ValueError now for a URL pyserial cannot understand (not for a port that is absent)."""
        try:
            serial.serial_for_url(self.url, do_not_open=True)
        except (ValueError, serial.SerialException) as exc:
            raise ValueError(f"port {self.url!r}: {exc}") from None

    def items(self, stop: threading.Event) -> Iterator[Chunk | LinkEvent]:
        """Yield :class:`Chunk` and :class:`LinkEvent` until ``stop`` is set.

        Each read takes what the port holds (at least one byte, or nothing after
        ``read_timeout_s``), so a line is handed on as soon as its bytes arrive.
        """
        waiting = False
        while not stop.is_set():
            if self.port is None:
                try:
                    self.port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.read_timeout_s)
                except (serial.SerialException, OSError, ValueError) as exc:
                    if not waiting:
                        waiting = True
                        yield LinkEvent("waiting", f"waiting for {self.url} ({_reason(exc)})", time.perf_counter())
                    stop.wait(self.retry_s)
                    continue
                waiting = False
                yield LinkEvent("connected", f"connected to {self.url}", time.perf_counter())
            try:
                data = self.port.read(self.port.in_waiting or 1)
            except (serial.SerialException, OSError) as exc:
                self.close()
                self.disconnects += 1
                yield LinkEvent("disconnected", f"{self.url} disconnected ({_reason(exc)})", time.perf_counter())
                continue
            if data:
                yield Chunk(time.perf_counter(), data)


def _reason(exc: BaseException) -> str:
    return str(exc).strip() or type(exc).__name__
