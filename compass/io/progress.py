"""Word that long work is going on: a progress line on a terminal's stderr.

A command that works for more than a couple of seconds without a word looks hung (the x-io log's
tumble calibration took up to 17 s under load, ``python -m calibrate.realdata`` 66-89 s). Where the
work has a known count (trials, fits) the line is a bar with the count, the elapsed time and an
estimate of the time left; otherwise it is the elapsed time. The line goes to stderr and only when
it is a terminal, from ``after_s`` on: piped or redirected output, and short work, stay as they were.

Examples
--------
>>> with working("scoring trials", total=len(trials)) as tally:    # doctest: +SKIP
...     for trial in trials:
...         score(trial)
...         tally.advance()
"""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

__all__ = ["Tally", "progress_line", "working"]

BAR_WIDTH = 20
"""Characters of the bar."""


def _clock(seconds: float) -> str:
    """``m:ss`` (``h:mm:ss`` from an hour on)."""
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def progress_line(what: str, elapsed_s: float, done: int | None = None, total: int | None = None) -> str:
    """The text of the line: ``what: 0:12`` without a count, else
    ``what [#####...............] 3/12 25 % 0:12, 0:36 left`` (time left once something is done).

    Parameters
    ----------
    what : str
        What is being done.
    elapsed_s : float
        Seconds since the work started.
    done, total : int, optional
        Units of work done and in all.
    """
    if not total:
        return f"{what}: {_clock(elapsed_s)}"
    done = int(done or 0)  # shown as counted: a count past the total is the caller's error, in view
    filled = BAR_WIDTH * min(max(done, 0), total) // total
    left = f", {_clock(elapsed_s / done * (total - done))} left" if 0 < done < total else ""
    return (f"{what} [{'#' * filled}{'.' * (BAR_WIDTH - filled)}] {done}/{total} {100 * done // total} % "
            f"{_clock(elapsed_s)}{left}")


class Tally:
    """The count of a :func:`working` block: call :meth:`advance` as units of work finish, and print
    inside :meth:`hidden` (the line is cleared and comes back after).

    Attributes
    ----------
    done, total : int or None
        Units done and in all (``total`` None: no count, the line shows the elapsed time only).
    """

    def __init__(self, total: int | None = None, draw=None, clear=None):
        self.done, self.total = 0, total
        self._draw, self._clear = draw, clear
        self._hidden = threading.Event()

    def advance(self, n: int = 1) -> None:
        """``n`` more units done; the line is redrawn at once when it is showing."""
        self.done += n
        if self._draw is not None and not self._hidden.is_set():
            self._draw(False)

    @contextmanager
    def hidden(self):
        """Clear the line while the block writes its own lines (a report, an event), then show it again."""
        if self._clear is None:
            yield
            return
        self._hidden.set()
        self._clear()
        try:
            yield
        finally:
            self._hidden.clear()
            self._draw(False)


@contextmanager
def working(what: str, *, total: int | None = None, stream=None, after_s: float = 2.0, every_s: float = 0.5):
    """Show the progress of the block on ``stream`` (default stderr), from ``after_s`` on; yields a :class:`Tally`.

    Nothing is written when ``stream`` is not a terminal, nor when the block ends within
    ``after_s``; the line is cleared when it ends.

    Parameters
    ----------
    what : str
        What is being done ("calibrating tumble.csv").
    total : int, optional
        Units of work in all: the line is then a bar with the count and the time left.
    stream : text file, optional
    after_s, every_s : float
        Seconds before the line first shows, and between redraws of the elapsed time.
    """
    stream = sys.stderr if stream is None else stream
    if not getattr(stream, "isatty", lambda: False)():
        yield Tally(total)
        return
    stop, lock = threading.Event(), threading.Lock()
    start = time.monotonic()
    shown = [False]

    def draw(by_clock: bool) -> None:
        with lock:
            if stop.is_set() or tally._hidden.is_set() or not (shown[0] or by_clock):
                return
            shown[0] = True
            stream.write("\r" + progress_line(what, time.monotonic() - start, tally.done, total) + "\x1b[K")
            stream.flush()

    def clear() -> None:
        with lock:
            if shown[0]:
                stream.write("\r\x1b[K")
                stream.flush()

    tally = Tally(total, draw, clear)

    def tick() -> None:
        if stop.wait(after_s):
            return
        while True:
            draw(True)
            if stop.wait(every_s):
                break

    if after_s <= 0:
        draw(True)  # at once, before the first unit of work
    thread = threading.Thread(target=tick, name="compass-progress", daemon=True)
    thread.start()
    try:
        yield tally
    finally:
        stop.set()
        thread.join(5.0)
        clear()
