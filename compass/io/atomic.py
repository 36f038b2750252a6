"""Atomic file writes: a reader never sees half a file, a crash never leaves one behind for long.

Every output goes to a temporary file in the target's folder, named ``.NAME.PID.RANDOM.tmp``, is
flushed to disk and renamed over the target in one step (``os.replace``).  The result has the mode
a plain ``open()`` would give it: ``0o666`` less the user's umask for a new file, the old file's
mode when ``--force`` replaces one.  A symbolic link is followed (its target is replaced, the link kept), and
a character device or a pipe (``/dev/stdout``, ``/dev/null``, a named pipe) is written through, as it comes: there
is no file to replace.  A writer killed in the write window (``kill -9``) leaves its
temporary file; the next write to the same target removes the ones whose writer process is gone
(only files of this naming pattern, and never one whose process still runs), except a stream's
(:func:`atomic_stream`, ``.NAME.PID.RANDOM.stream.tmp``: a ``compass live`` session killed with ``kill -9`` or a
power cut), which holds the rows that session had: it is kept, renamed ``STEM.partial-PID.SUFFIX`` beside the
target, and said.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path

__all__ = ["OutputError", "atomic_open", "atomic_stream", "atomic_write_text",
           "check_writable", "save_figure", "output_mode",
           "remove_stale_temporaries"]


class OutputError(ValueError):
    """An output path that cannot be written (exit status 2 on the command line)."""


def check_writable(path, force: bool, inputs=()) -> Path:
    """Refuse to overwrite ``path`` unless ``force``; make sure it can be written (before long work).

    Parameters
    ----------
    path : path-like
    force : bool
    inputs : sequence of path-like or None
        The command's input files: ``path`` may be none of them, ``--force`` or not (it would be read
        and replaced by what was made of it).

    Raises
    ------
    FileExistsError
        The file exists and ``force`` is False.
    OutputError
        The path is a folder or one of ``inputs``, or its folder cannot be created or written.
    """
    path = _target(path)
    if path.is_dir():
        raise OutputError(f"{path} is a folder: expected a file name")
    for source in inputs:
        if source is not None and path.exists() and Path(source).exists() and path.samefile(source):
            raise OutputError(f"{path} is also an input of this command ({source}): give another file")
    if _written_through(path):
        return path
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; use --force to overwrite it")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{path}: cannot create its folder ({exc.strerror})") from None
    if not os.access(path.parent, os.W_OK):
        raise OutputError(f"{path}: its folder is not writable")
    return path


@contextlib.contextmanager
def atomic_open(path, mode: str = "w"):
    """Open a temporary file that replaces ``path`` when the block ends without an exception.

    Parameters
    ----------
    path : path-like
        The target.  Its folder is created if needed.
    mode : {"w", "wb"}
        Text (UTF-8) or binary.

    Yields
    ------
    file object
        Write to it; on an exception (including ``KeyboardInterrupt``) the temporary file is
        removed and ``path`` is left as it was.

    Raises
    ------
    OutputError
        The folder cannot be created or written, or the file cannot be replaced.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    path = _target(path)
    if _written_through(path):
        with _open_through(path, mode) as fh:
            yield fh
        return
    fd, tmp = _temporary(path)
    try:
        with os.fdopen(fd, mode, **({"encoding": "utf-8"} if mode == "w" else {})) as fh:
            yield fh
            fh.flush()
            os.fchmod(fh.fileno(), output_mode(path))
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from None
        raise


@contextlib.contextmanager
def atomic_stream(path, keep):
    """:func:`atomic_open` for a stream written as it goes, which replaces ``path`` only if ``keep()``.

    ``compass live --out``: rows go to the temporary file while the session runs (follow it with
    ``tail -f`` on the ``.NAME.PID.*.tmp`` file); when the block ends, also by an exception, the
    file replaces ``path`` if ``keep()`` says it holds what should be kept (rows were recorded),
    else it is removed and ``path`` (an older file ``--force`` would have replaced) is left as it
    was.  An exception from the block is raised again either way.

    Parameters
    ----------
    path : path-like
    keep : callable returning bool
        Asked once, when the block ends.
    """
    path = _target(path)
    if _written_through(path):  # nothing to keep or drop: the rows went where they were sent
        with _open_through(path, "w") as fh:
            yield fh
        return
    fd, tmp = _temporary(path, _STREAM_SUFFIX)
    fh = os.fdopen(fd, "w", encoding="utf-8", buffering=1 << 16)
    kept = False
    try:
        yield fh
    finally:
        try:
            if keep():
                fh.flush()
                os.fchmod(fh.fileno(), output_mode(path))
                os.fsync(fh.fileno())
                fh.close()
                os.replace(tmp, path)
                kept = True
        except OSError as exc:
            raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from None
        finally:
            fh.close()
            if not kept:
                Path(tmp).unlink(missing_ok=True)


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_open`).

    Raises
    ------
    OutputError
        The folder cannot be created or written, or the file cannot be replaced (the old
        file, if any, is left as it was).
    """
    with atomic_open(path, "w") as fh:
        fh.write(text)


def save_figure(fig, path, **savefig_kwargs) -> Path:
    """Save a matplotlib figure to ``path`` atomically, in the format its suffix names; returns the path.

    Refusing an existing file without ``--force`` is the command's job (:func:`check_writable`,
    before the long work).
    """
    path = Path(path)
    savefig_kwargs.setdefault("format", path.suffix.lstrip(".").lower() or "png")
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, **savefig_kwargs)
    return path


_STANDARD_STREAMS = ("/dev/stdout", "/dev/stderr")
_OPEN_FILE_FOLDERS = ("/dev/fd/", "/proc/self/fd/")
"""Names of the process's own open files (with :data:`_STANDARD_STREAMS`): written through whatever they are (a
terminal, a pipe, a shell's ``> f``)."""


def _target(path) -> Path:
    """The path a write to ``path`` goes to: a symbolic link's target (the link stays a link), unless the link names
    a standard stream, a character device or a pipe (written through under the name given: ``/dev/stdout`` resolves
    to a ``pipe:[N]`` that no name opens)."""
    path = Path(path)
    if not path.is_symlink() or _written_through(path):
        return path
    return Path(os.path.realpath(path))


def _written_through(path: Path) -> bool:
    """Whether ``path`` is a standard stream, a character device or a pipe, written as it comes rather than replaced.

    Raises
    ------
    OutputError
        ``path`` is a block device or a socket: never an output.
    """
    if str(path) in _STANDARD_STREAMS or str(path).startswith(_OPEN_FILE_FOLDERS):
        return True
    try:
        mode = path.stat().st_mode
    except OSError:
        return False
    if stat.S_ISBLK(mode) or stat.S_ISSOCK(mode):
        raise OutputError(f"{path} is a {'block device' if stat.S_ISBLK(mode) else 'socket'}: expected a file name")
    return stat.S_ISCHR(mode) or stat.S_ISFIFO(mode)


@contextlib.contextmanager
def _open_through(path: Path, mode: str):
    """``path`` (a character device or a pipe) opened for writing, an error as :class:`OutputError`."""
    try:
        fh = open(path, mode, **({"encoding": "utf-8"} if mode == "w" else {}))
    except OSError as exc:
        raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from None
    with fh:
        yield fh


_STREAM_SUFFIX = ".stream.tmp"
"""How :func:`atomic_stream`'s temporary files end: rows a killed session had, kept by the next write."""


def _temporary(path: Path, suffix: str = ".tmp") -> tuple[int, str]:
    """A new ``.NAME.PID.RANDOM`` + ``suffix`` beside ``path`` (its folder made): (descriptor, name)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(path)
        return tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=suffix)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write ({exc.strerror})") from None


def remove_stale_temporaries(path) -> list[Path]:
    """Remove ``.NAME.PID.*.tmp`` files of ``path`` left by writers that are gone; returns them.  A stream's that
    holds rows (``*.stream.tmp``) is kept instead, renamed and said (:func:`_keep_partial`), not returned."""
    path = Path(path)
    prefix = f".{path.name}."
    removed = []
    try:
        candidates = list(path.parent.glob(f"{_glob_escape(prefix)}*.tmp"))
    except OSError:
        return removed
    for candidate in candidates:
        pid_text = candidate.name[len(prefix):].split(".", 1)[0]
        if not pid_text.isdigit() or _process_exists(int(pid_text)):
            continue
        try:
            info = candidate.lstat()
            if not stat.S_ISREG(info.st_mode):
                continue
            if candidate.name.endswith(_STREAM_SUFFIX) and info.st_size > 0:
                _keep_partial(candidate, path, pid_text)
                continue
            candidate.unlink()
            removed.append(candidate)
        except OSError:
            pass  # gone meanwhile, or not ours to remove
    return removed


def _keep_partial(stream: Path, path: Path, pid: str) -> None:
    """A killed session's stream renamed ``STEM.partial-PID.SUFFIX`` beside ``path`` (left where it is if that
    name is taken), and said."""
    from .units import note

    kept = path.with_name(f"{path.stem}.partial-{pid}{path.suffix}")
    if kept.exists():
        return
    os.chmod(stream, output_mode(kept))  # a new output's mode (mkstemp's is private)
    os.replace(stream, kept)
    note(f"{kept}: the rows a session writing {path} had when it was killed (process {pid}), kept; its last line "
         "may be cut short (delete it to replay the file)")


def _process_exists(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True  # someone else's process (or an impossible pid): leave its file alone
    return True


def output_mode(path: Path) -> int:
    """The mode ``open(path, "w")`` would leave: the old file's, else 0o666 less the umask."""
    try:
        return stat.S_IMODE(path.stat().st_mode)
    except OSError:
        umask = os.umask(0o022)
        os.umask(umask)
        return 0o666 & ~umask


def _glob_escape(text: str) -> str:
    return "".join(f"[{c}]" if c in "*?[" else c for c in text)
