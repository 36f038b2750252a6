"""Read a serial port (or any pyserial URL) as timestamped byte chunks, surviving disconnects.

:class:`SerialReader` opens ``serial.serial_for_url(url)`` (a device path such as ``/dev/ttyUSB0``,
or ``socket://host:port``, ``rfc2217://...``, ``loop://``), yields whatever bytes arrive with the
time they were read, and turns every failure into a :class:`LinkEvent`:

- a port that cannot be opened (unplugged, not there yet) is retried every ``retry_s``;
- a port that fails while reading (``SerialException``/``OSError``: a pty whose master closed, a
  USB adapter pulled, a socket closed by its peer) is closed and reopened when it returns.

Reads take what is there in bulk: a port with a file descriptor (a posix serial device, a pty,
``socket://``) is waited on with ``select`` and then read without blocking, up to
:data:`MAX_READ_BYTES` at once.  (pyserial's ``in_waiting`` cannot be used for this: over
``socket://`` it is 0 or 1, so reading ``in_waiting`` bytes took one byte a call and a 10 kHz
stream fell behind.)  Other ports (``loop://``, ``rfc2217://``, Windows) report a true
``in_waiting`` and are read that way.

Pitfall handled by the consumer: ``open()`` discards input the device sent before (posix
``tcflush``, socket drain), so the first bytes after a "connected" event usually start mid-line;
:meth:`compass.io.lines.LineDecoder.resync` drops that fragment.
"""

from __future__ import annotations

import io
import math
import select
import threading
import time
from dataclasses import dataclass
from typing import Iterator

import serial

__all__ = ["Chunk", "LinkEvent", "PortUnavailable", "SerialReader", "MAX_READ_BYTES"]

MAX_READ_BYTES = 1 << 16


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


class PortUnavailable(ValueError):
    """The port could not be opened before the reader's first connection (a mistyped name, no device)."""


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
    first_open_s : float or None
        How long to keep trying before the first connection: then :meth:`items` raises
        :class:`PortUnavailable` (0: one attempt; None: for ever).  Once connected, a lost port
        is waited for without limit.
    min_read_interval_s : float
        Shortest time between two reads of a port with a file descriptor, seconds (see ``_read``:
        at most this long a line waits in the kernel, and only when lines come faster).

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

    def __init__(self, url: str, *, baudrate: int = 115200, read_timeout_s: float = 0.05, retry_s: float = 0.25,
                 first_open_s: float | None = None, min_read_interval_s: float = 0.002):
        self.url = url
        self.min_read_interval_s = min_read_interval_s
        self._last_read = -math.inf
        self.first_open_s = first_open_s
        self.connected_once = False
        self.baudrate = baudrate
        self.read_timeout_s = read_timeout_s
        self.retry_s = retry_s
        self.port = None
        self.disconnects = 0
        self._fd = None  # the open port's file descriptor, when it has one

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
            self._fd = None

    def check_url(self) -> None:
        """Raise ValueError now for a URL pyserial cannot understand (not for a port that is absent).

        pyserial reads a ``socket://``, ``rfc2217://`` or ``loop://`` URL only when it opens the port,
        and answers a malformed one with its internals (``'<=' not supported between instances of
        'int' and 'NoneType'``); those are checked here, in words (:func:`check_network_url`).
        """
        check_network_url(self.url)
        try:
            serial.serial_for_url(self.url, do_not_open=True)
        except (ValueError, serial.SerialException) as exc:
            raise ValueError(f"port {self.url!r}: {exc}") from None

    def items(self, stop: threading.Event) -> Iterator[Chunk | LinkEvent]:
        """Yield :class:`Chunk` and :class:`LinkEvent` until ``stop`` is set.

        Raises :class:`PortUnavailable` when the port cannot be opened within ``first_open_s``
        of the first attempt.  Each read waits up to ``read_timeout_s`` for the first byte, then takes everything the
        port holds (up to :data:`MAX_READ_BYTES`), so a line is handed on as soon as its bytes
        arrive and a fast stream is read in few calls.
        """
        waiting = False
        started = time.monotonic()
        while not stop.is_set():
            if self.port is None:
                try:
                    self.port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.read_timeout_s)
                    self._fd = _nonblocking_fd(self.port)
                except (serial.SerialException, OSError, ValueError) as exc:
                    self.close()  # opened, but its timeout could not be set: the device went away
                    if (not self.connected_once and self.first_open_s is not None
                            and time.monotonic() - started >= self.first_open_s):
                        raise PortUnavailable(f"cannot open port {self.url} ({_reason(exc)})") from None
                    if not waiting:
                        waiting = True
                        yield LinkEvent("waiting", f"waiting for {self.url} ({_reason(exc)})", time.perf_counter())
                    stop.wait(self.retry_s)
                    continue
                waiting = False
                self.connected_once = True
                yield LinkEvent("connected", f"connected to {self.url}", time.perf_counter())
            try:
                data = self._read()
            except (serial.SerialException, OSError, ValueError) as exc:  # ValueError: select on a closed fd
                self.close()
                self.disconnects += 1
                yield LinkEvent("disconnected", f"{self.url} disconnected ({_reason(exc)})", time.perf_counter())
                continue
            if data:
                yield Chunk(time.perf_counter(), data)

    def _read(self) -> bytes:
        """What the port holds, after waiting up to ``read_timeout_s`` for a first byte (b"" if none).

        Reads are at least ``min_read_interval_s`` apart: a fast stream (above ~500 lines a second) is
        read a few lines at a time instead of waking the process for every line (each wake-up costs
        more than a sample's decoding and filtering on a busy machine); a slower one is read as each
        line arrives.
        """
        if self._fd is None:
            return self.port.read(self.port.in_waiting or 1)  # blocks up to the port's timeout
        wait = self._last_read + self.min_read_interval_s - time.monotonic()
        if wait > 0.0:
            time.sleep(wait)
        ready, _, _ = select.select([self._fd], [], [], self.read_timeout_s)
        if not ready:
            return b""
        self._last_read = time.monotonic()
        return self.port.read(MAX_READ_BYTES)  # the port's timeout is 0: no blocking


def _nonblocking_fd(port) -> int | None:
    """The port's file descriptor after setting its read timeout to 0, or None if it has none."""
    try:
        fd = port.fileno()
    except (AttributeError, io.UnsupportedOperation, OSError):
        return None
    port.timeout = 0
    return fd


_URL_OPTIONS = {"socket": {"logging"}, "rfc2217": {"logging", "ign_set_control", "poll_modem", "timeout"},
                "loop": {"logging"}}
_LOGGING = ("debug", "info", "warning", "error")


def check_network_url(url: str) -> None:
    """ValueError, in words, for a malformed ``socket://HOST:PORT``, ``rfc2217://HOST:PORT`` or ``loop://``
    (their options after ``?`` included); other ports and URLs pass (pyserial judges them).

    Examples
    --------
    >>> check_network_url("socket://127.0.0.1:5000")
    >>> check_network_url("socket://localhost")
    Traceback (most recent call last):
    ...
    ValueError: port 'socket://localhost': expected socket://HOST:PORT with PORT 1-65535
    """
    from urllib.parse import parse_qs, urlsplit

    scheme = url.partition("://")[0].lower() if "://" in url else ""
    if scheme not in _URL_OPTIONS:
        return
    form = "loop://" if scheme == "loop" else f"{scheme}://HOST:PORT with PORT 1-65535"
    try:
        parts = urlsplit(url)
        port = parts.port
        options = parse_qs(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise ValueError(f"port {url!r}: expected {form}") from None
    if scheme != "loop" and (not parts.hostname or port is None or not 1 <= port <= 65535):
        raise ValueError(f"port {url!r}: expected {form}")
    if scheme == "loop" and (parts.netloc or parts.path):
        raise ValueError(f"port {url!r}: expected {form}")
    unknown = sorted(set(options) - _URL_OPTIONS[scheme])
    if unknown:
        raise ValueError(f"port {url!r}: unknown option {unknown[0]!r} (a {scheme}:// URL takes "
                         f"{', '.join(sorted(_URL_OPTIONS[scheme]))})")
    for value in options.get("logging", ()):
        if value not in _LOGGING:
            raise ValueError(f"port {url!r}: logging must be one of {', '.join(_LOGGING)}, got {value!r}")


def _reason(exc: BaseException) -> str:
    return str(exc).strip() or type(exc).__name__
