"""The ``compass`` command: parse, call, print, exit codes (SPEC section 3).

Exit status 0 on success, 2 on bad input (one line naming file, row and column), 1 on other
failures.  Set ``COMPASS_DEBUG=1`` to see tracebacks.  Each subcommand lives in
``compass/commands/<name>.py`` with a ``register(subparsers)`` function.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from .io.atomic import OutputError
from .io.table import RecordingError

__all__ = ["main", "BadInput"]

SUBCOMMANDS = ("demo", "simulate", "calibrate", "attitude", "live", "device", "export", "evaluate")


class BadInput(ValueError):
    """A user error the command line reports in one line with exit status 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="compass",
        description="Calibrate three-axis compasses on a bench (four-flip turntable method) and read attitude.",
    )
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


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (RecordingError, BadInput, FileExistsError, OutputError) as exc:
        print(f"compass {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"compass {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # other failures: one line, exit 1
        if os.environ.get("COMPASS_DEBUG"):
            raise
        print(f"compass {args.command}: failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
