"""The serial port of ``compass live`` (and its live tumble calibration): open it, say what its stream is, stop on
Ctrl-C or a time."""

from __future__ import annotations

import contextlib
import signal
import threading

__all__ = ["open_reader", "port_unavailable", "stop_signals", "stop_when_asked", "stream_options"]


def open_reader(args):
    """The reader of ``--port`` (``--baud``, ``--wait``), its options checked; BadInput for bad ones."""
    from ..cli import BadInput
    from ..serial_reader import SerialReader

    reader = SerialReader(args.port, baudrate=args.baud, first_open_s=args.wait)
    try:
        reader.check_url()
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    return reader


def port_unavailable(exc):
    """The BadInput for a port that could not be opened within ``--wait``."""
    from ..cli import BadInput

    return BadInput(f"{exc}: check the name, or --wait S for a port that is not there yet")


def stop_signals() -> list:
    """Ctrl-C, ``kill``, and the terminal or ssh session closed (SIGHUP): each ends a session as Ctrl-C does (files
    kept); one ignored when asked (``nohup``'s SIGHUP) is left alone."""
    signals = [signal.SIGINT, signal.SIGTERM] + ([signal.SIGHUP] if hasattr(signal, "SIGHUP") else [])
    return [sig for sig in signals if signal.getsignal(sig) is not signal.SIG_IGN]


@contextlib.contextmanager
def stop_when_asked(duration_s: float | None):
    """An event that Ctrl-C, SIGTERM, SIGHUP or ``duration_s`` seconds set (the reading loop ends within one
    read timeout); a second Ctrl-C interrupts.  The signal handlers are restored and the timer
    cancelled when the block ends.  Off the main thread only the timer sets it."""
    stop = threading.Event()

    def handler(signum, frame):
        if stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stop.set()

    previous = ({} if threading.current_thread() is not threading.main_thread() else
                {sig: signal.signal(sig, handler) for sig in stop_signals()})
    timer = None
    if duration_s is not None:
        timer = threading.Timer(duration_s, stop.set)
        timer.daemon = True
        timer.start()
    try:
        yield stop
    finally:
        if timer is not None:
            timer.cancel()
        for sig, handler_before in previous.items():
            signal.signal(sig, handler_before)


def stream_options(args):
    """The stream's :class:`compass.io.streams.StreamOptions` from ``--format``, ``--columns``, ``--*-unit``;
    BadInput for options that contradict each other."""
    from ..cli import BadInput
    from ..io.stream_options import StreamOptions

    try:
        return StreamOptions.from_args(args)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
