"""The ``compass`` command: parse, call, print, exit codes (SPEC section 3).

Exit status 0 on success, 2 on bad input (one line naming file, row and column), 1 on other
failures.  Set ``COMPASS_DEBUG=1`` to see tracebacks.  Each subcommand lives in
``compass/commands/<name>.py`` with a ``register(subparsers)`` function; a command module imports
numpy at most at module level and everything heavier (scipy, the simulators, the fits, matplotlib,
rerun) inside the function that runs it, so ``compass --help`` answers quickly
(``tools/bench_startup.py`` measures it).

Warnings the readers raise about a recording (:class:`compass.io.units.RecordingWarning`: a unit
that looks wrong, a column ignored) are printed as one line each on stderr when the command ends;
bad input prints its one line only.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib
import os
import re
import signal
import sys
import threading
import warnings

from .errors import BadInput

__all__ = ["main", "BadInput", "UsageError", "version"]

SUBCOMMANDS = ("demo", "simulate", "calibrate", "attitude", "live", "device", "bench", "export", "evaluate",
               "batch", "store")


def version() -> str:
    """The installed distribution's version (``compass --version``)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("compass-toolkit")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "unknown (not installed)"


class _Version(argparse.Action):
    """``--version`` that looks the version up only when asked (importlib.metadata is not free)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"compass {version()}")
        parser.exit()


class UsageError(Exception):
    """A command line argparse refuses (an unknown option, a number out of its range)."""


class _Parser(argparse.ArgumentParser):
    """argparse, whose refusal is one line (``compass live: argument --baud: ...``), exit status 2.

    The subcommands' parsers are of this class too (``add_subparsers`` makes them of the parent's);
    :func:`main` prints the line, so calling ``main`` in-process returns 2 instead of exiting.
    """

    def error(self, message):
        raise UsageError(f"{self.prog}: {message} (--help for usage)")


@functools.lru_cache(maxsize=1)
def build_parser() -> argparse.ArgumentParser:
    """The ``compass`` parser, built once a process (argparse's gettext lookups make it 0.1 s; parsing does not
    change it, and the tests call :func:`main` in-process hundreds of times)."""
    parser = _Parser(
        prog="compass",
        description="Calibrate three-axis compasses on a bench (four-flip turntable method) and read attitude.",
    )
    parser.add_argument("--version", action=_Version, help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"compass.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"compass.commands.{name}":
                continue  # not built yet
            raise
        module.register(sub)
    return parser


def _bad_input_types() -> tuple:
    from .io.atomic import OutputError
    from .io.table import RecordingError

    return (RecordingError, BadInput, FileExistsError, OutputError)


_BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _one_blas_thread() -> None:
    """Run BLAS on one thread unless the user chose a number (before numpy loads; no-op after).

    The fits multiply tall, narrow matrices (n samples by a few parameters), which threads do not
    speed up; on a loaded machine OpenBLAS's threads wait for each other instead: a 5 MB tumble
    calibration took 24.7 s with the default threads and 5.1 s with one, a 3-D platform one 20.1 s
    and 3.9 s, a four-flip one 6.2 s and 2.5 s (2 cores, one busy; ``tools/bench_scale.py``).
    """
    if "numpy" in sys.modules or any(name in os.environ for name in _BLAS_THREAD_VARIABLES):
        return
    for name in _BLAS_THREAD_VARIABLES:
        os.environ[name] = "1"


_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
"""glibc's ``mallopt`` parameters (``malloc.h``)."""
_MMAP_THRESHOLD_BYTES = 32 << 20
"""Blocks from this size up are mapped afresh each time (glibc's default grows to this at most)."""
_HEAP_SLACK_BYTES = 256 << 20
"""Freed heap memory glibc keeps for reuse, and the extra it asks for when the heap grows."""


def _keep_freed_memory() -> None:
    """Let glibc's allocator reuse freed array memory instead of returning it to the kernel (no-op elsewhere).

    The fits allocate and free arrays of a column per sample (16.8 MB on a 700000-sample tumble) hundreds of
    times; by default glibc maps each one afresh or trims the heap after it is freed, so every new array's pages
    are faulted in and zeroed again by the kernel: 100000 page faults and 0.9-1.2 s of system time on the 46 MB
    tumble of ``tools/bench_scale.py``, against 42000 and 0.5-0.7 s with the heap kept (peak memory the same,
    446 against 448 MB).  Only where memory comes from changes: the results are the same bytes.
    """
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return
    mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES)
    mallopt(_M_TOP_PAD, _HEAP_SLACK_BYTES)
    mallopt(_M_TRIM_THRESHOLD, _HEAP_SLACK_BYTES)


_NEGATIVE_LIST = re.compile(r"^-\.?\d[^,]*,")


def _attach_negative_lists(argv: list[str]) -> list[str]:
    """``--site -33.87,151.21`` as ``--site=-33.87,151.21``.

    argparse takes a value that starts with ``-`` for an option unless it is a single number, so a
    southern latitude (a comma-separated list) would be refused as "expected one argument".
    """
    out = []
    for arg in argv:
        if out and _NEGATIVE_LIST.match(arg) and out[-1].startswith("--") and "=" not in out[-1]:
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


class _WarningsFirst:
    """``sys.stdout`` that prints the warnings found so far (``emit``) before each write."""

    def __init__(self, stream, emit):
        self._stream, self._emit = stream, emit

    def write(self, text: str) -> int:
        self._emit()
        return self._stream.write(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


class _Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP during a command: raised where it runs, so every output being written is removed (its
    temporary file) or kept whole, as on Ctrl-C; ``compass live`` and ``compass device`` stop on them instead."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def _terminate_as_interrupt():
    """SIGTERM and SIGHUP raise :class:`_Terminated` in the block (the main thread only; handlers restored after).
    Killed by the default handler, a command left its temporary files behind (a replay's ``.att.rrd.*.tmp``)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise _Terminated(signum)

    stops = [signal.SIGTERM] + ([signal.SIGHUP] if hasattr(signal, "SIGHUP") else [])
    # a signal ignored on entry stays so: nohup's SIGHUP, and the terminal closed, must not end the command
    previous = {sig: signal.signal(sig, handler) for sig in stops if signal.getsignal(sig) is not signal.SIG_IGN}
    try:
        yield
    finally:
        for sig, before in previous.items():
            signal.signal(sig, before)


def main(argv=None) -> int:
    _one_blas_thread()
    _keep_freed_memory()
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:  # a newcomer's first try: the commands, not "the following arguments are required"
        parser.print_help()
        return 2
    try:
        args = parser.parse_args(_attach_negative_lists(argv))
    except UsageError as exc:
        print(exc, file=sys.stderr)
        return 2
    from .io.units import RecordingWarning

    show = warnings.showwarning
    pending: list[str] = []

    def emit() -> None:
        while pending:
            print(f"compass {args.command}: warning: {pending.pop(0)}", file=sys.stderr, flush=True)

    def show_in_order(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, RecordingWarning):
            pending.append(str(message))
        else:
            show(message, category, filename, lineno, file, line)

    stdout = sys.stdout
    with warnings.catch_warnings():
        warnings.simplefilter("always", RecordingWarning)
        warnings.showwarning = show_in_order
        # a warning about the input is printed before the next output line it explains (collected to
        # the end, it came after the report and "wrote cal.json"); bad input stays one line
        sys.stdout = _WarningsFirst(stdout, emit)
        try:
            with _terminate_as_interrupt():
                status = int(args.func(args) or 0)
        except _bad_input_types() as exc:  # the one line says it all: no warnings around it
            print(f"compass {args.command}: {exc}", file=sys.stderr)
            return 2
        except _Terminated as exc:
            status = 128 + exc.signum
            print(f"compass {args.command}: stopped by signal {exc.signum}", file=sys.stderr)
        except KeyboardInterrupt:
            status = 130
            print(f"compass {args.command}: interrupted", file=sys.stderr)
        except Exception as exc:  # other failures: one line, exit 1
            if os.environ.get("COMPASS_DEBUG"):
                raise
            print(f"compass {args.command}: failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            status = 1
        finally:
            sys.stdout = stdout
    emit()
    return status


if __name__ == "__main__":
    sys.exit(main())
