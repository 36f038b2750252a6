"""Word that long work is going on: an elapsed-time line on a terminal's stderr.

A command that works for more than a couple of seconds without a word looks hung (the x-io log's
tumble calibration took up to 17 s under load, ``python -m calibrate.realdata`` 66-89 s). The line
goes to stderr and only when it is a terminal: piped or redirected output stays as it was.
"""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

__all__ = ["working"]


@contextmanager
def working(what: str, *, stream=None, after_s: float = 2.0, every_s: float = 0.5):
    """Show ``what: N s`` on ``stream`` (default stderr) while the block runs, from ``after_s`` on.

    Nothing is written when ``stream`` is not a terminal, nor when the block ends within
    ``after_s``; the line is cleared when it ends.

    Parameters
    ----------
    what : str
        What is being done ("calibrating tumble.csv").
    stream : text file, optional
    after_s, every_s : float
        Seconds before the first update, and between updates.
    """
    stream = sys.stderr if stream is None else stream
    if not getattr(stream, "isatty", lambda: False)():
        yield
        return
    stop = threading.Event()
    start = time.monotonic()

    def tick() -> None:
        if stop.wait(after_s):
            return
        while True:
            stream.write(f"\r{what}: {time.monotonic() - start:.0f} s ")
            stream.flush()
            if stop.wait(every_s):
                break
        stream.write("\r\x1b[K")
        stream.flush()

    thread = threading.Thread(target=tick, name="compass-progress", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(5.0)
