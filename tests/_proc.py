"""Subprocesses for tests that can never hang: every pipe is read by a thread, every wait is bounded,
and whatever was started is killed and joined on the way out (also when an assertion fails)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

__all__ = ["Proc", "compass_command"]


def compass_command(*args: str) -> list[str]:
    """``python -m compass ARGS`` with this interpreter."""
    return [sys.executable, "-m", "compass", *args]


class Proc:
    """A running command whose stdout and stderr lines are collected as they come.

    Use as a context manager: on exit the process is killed if still running, waited for and its
    pipe threads joined, each with a timeout, so a test that fails midway leaves nothing behind.

    Parameters
    ----------
    args : list of str
    kill_after_s : float
        Hard limit on the process's life: a timer kills it then, whatever the test is doing.
    group : bool
        Start the command in its own process group, and kill the whole group (the command and the
        workers it started) wherever this class kills it.
    """

    def __init__(self, args: list[str], *, kill_after_s: float = 120.0, env: dict | None = None,
                 group: bool = False):
        env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.group = group
        self.popen = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True, env=env, start_new_session=group)
        self.out: list[str] = []
        self.err: list[str] = []
        self._changed = threading.Condition()
        self._threads = [threading.Thread(target=self._pump, args=(stream, lines), daemon=True)
                         for stream, lines in ((self.popen.stdout, self.out), (self.popen.stderr, self.err))]
        for thread in self._threads:
            thread.start()
        self._killer = threading.Timer(kill_after_s, self._kill)
        self._killer.daemon = True
        self._killer.start()

    def _pump(self, stream, lines: list[str]) -> None:
        for line in stream:
            with self._changed:
                lines.append(line)
                self._changed.notify_all()
        with self._changed:
            self._changed.notify_all()

    def _kill(self) -> None:
        if self.group:
            self.kill_group()
        elif self.popen.poll() is None:
            self.popen.kill()

    def kill_group(self) -> None:
        """SIGKILL the command's process group (``kill -9`` of a job: the command and its workers)."""
        try:
            os.killpg(self.popen.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass

    def wait_for(self, predicate, timeout_s: float) -> bool:
        """Wait until a stdout line satisfies ``predicate`` (True), or the process ends or time is up (False).

        ``predicate`` sees every line once, in order.
        """
        deadline = time.monotonic() + timeout_s
        checked = 0
        with self._changed:
            while True:
                while checked < len(self.out):
                    checked += 1
                    if predicate(self.out[checked - 1]):
                        return True
                remaining = deadline - time.monotonic()
                if remaining <= 0 or (self.popen.poll() is not None and not any(t.is_alive() for t in self._threads)):
                    return False
                self._changed.wait(min(remaining, 0.1))

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = 20.0) -> int:
        """Send ``sig``, wait up to ``timeout_s`` (then kill), join the pipe threads; the exit status."""
        if self.popen.poll() is None:
            self.popen.send_signal(sig)
        try:
            self.popen.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.popen.kill()
            self.popen.wait(10)
        self._join()
        return self.popen.returncode

    def wait(self, timeout_s: float) -> int:
        """Wait for the command to end (killed after ``timeout_s``), join the pipe threads; the exit status."""
        try:
            self.popen.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self._kill()
            self.popen.wait(10)
        self._join()
        return self.popen.returncode

    def _join(self) -> None:
        self._killer.cancel()
        for thread in self._threads:
            thread.join(10)

    def transcript(self) -> str:
        """What the process printed so far (for assertion messages): stdout, then stderr."""
        return "".join(self.out) + "".join(self.err)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._kill()
        try:
            self.popen.wait(10)
        finally:
            self._join()
            for stream in (self.popen.stdout, self.popen.stderr):
                stream.close()
