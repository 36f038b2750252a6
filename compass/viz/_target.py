"""``--rerun FILE.rrd|spawn`` on the command line: the option, and the checks made before any work.

Nothing here imports rerun (``compass --help`` stays fast); :func:`check_rerun_target` imports it
once, to say at once when it is missing.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

__all__ = ["add_rerun_option", "check_rerun_target", "spawn_problem"]

SPAWN = "spawn"


def add_rerun_option(parser) -> None:
    """Add ``--rerun FILE.rrd|spawn`` (the same help text on every command)."""
    parser.add_argument("--rerun", metavar="FILE.rrd|spawn",
                        help="record what this command computes to FILE.rrd (open it with `rerun FILE.rrd`), or "
                             "'spawn' to stream it to a Rerun viewer started here (needs a desktop); "
                             "needs pip install 'compass-toolkit[rerun]'")


def spawn_problem(environ=None, which=shutil.which) -> str | None:
    """Why ``rr.spawn`` would log into the void here, or None when a viewer can open.

    ``rr.spawn`` does not raise on a machine without a display: it warns after about 6 s and
    logging goes nowhere. A viewer needs a display (``DISPLAY`` or ``WAYLAND_DISPLAY``; macOS and
    Windows always have one) and the ``rerun`` executable on ``PATH``.
    """
    environ = os.environ if environ is None else environ
    if sys.platform.startswith("linux") and not (environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY")):
        return "no display here (DISPLAY and WAYLAND_DISPLAY are unset)"
    if which("rerun", path=environ.get("PATH")) is None:
        return "the Rerun viewer (`rerun`) is not on PATH"
    return None


def check_rerun_target(target, force: bool) -> Path | str | None:
    """Validate ``--rerun`` before the command does any work; returns the target.

    Raises
    ------
    BadInput
        rerun-sdk missing, ``spawn`` where no viewer can open, or a file name not ending in ``.rrd``
        (a mistyped ``spawn`` would otherwise become a file).
    FileExistsError, OutputError
        The file exists without ``force``, or cannot be written.
    """
    from ..errors import BadInput
    from ..io.atomic import check_writable

    if target is None:
        return None
    try:
        import rerun  # noqa: F401
    except ImportError:
        raise BadInput("--rerun needs rerun-sdk: pip install 'compass-toolkit[rerun]'") from None
    if str(target) == SPAWN:
        problem = spawn_problem()
        if problem is not None:
            raise BadInput(f"--rerun spawn: {problem}, so no viewer can open; record to a file instead "
                           f"(--rerun out.rrd) and open it with `rerun out.rrd` where there is a display")
        return SPAWN
    if Path(target).suffix != ".rrd":
        raise BadInput(f"--rerun {target}: expected 'spawn' or a file name ending in .rrd")
    return check_writable(target, force)
