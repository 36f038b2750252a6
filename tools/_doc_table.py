"""Benchmark tables written into docs/ by the script that measures them, so a number cannot drift.

A table in a doc sits between two markers; the text around them is the doc's own::

    <!-- table: bench_health -->
    ...written by `python tools/bench_health.py --n 100 --write-docs`, never by hand...
    <!-- /table -->

A marker's name is the script's name under ``tools/`` (without ``.py``), optionally followed by a
dot and the table's part (``bench_attitude.tilt``); each marker is a line of its own. A script
adopts this in two calls::

    args = parse_args(parser, argv)                    # adds --write-docs, keeps the arguments
    publish(args, "docs/calibration.md", "bench_health", markdown_table(header, rows))

Without ``--write-docs`` ``publish`` prints the table; with it the table also replaces the one
between the doc's markers (atomically; nothing else in the doc changes).
"""

from __future__ import annotations

import argparse
import re
import shlex
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from compass.io.atomic import OutputError, atomic_write_text  # noqa: E402

FLAG = "--write-docs"
CLOSE = "<!-- /table -->"
OPEN_RE = re.compile(r"^<!-- table: ([A-Za-z0-9_.-]+) -->$", re.MULTILINE)  # a marker is a line of its own
CLOSE_RE = re.compile(r"^<!-- /table -->$", re.MULTILINE)


class DocTableError(ValueError):
    """A doc whose markers cannot take the table (missing, repeated or unclosed)."""


def opening(name: str) -> str:
    """The marker that opens table ``name``."""
    return f"<!-- table: {name} -->"


def script_of(name: str) -> str:
    """The ``tools/`` script (file name) that writes table ``name``: its part before the first dot."""
    return name.split(".", 1)[0] + ".py"


def markdown_table(header, rows) -> str:
    """A markdown table: ``header`` a sequence of column titles, ``rows`` sequences of cells (str())."""
    lines = ["| " + " | ".join(str(h) for h in header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        cells = [str(c) for c in row]
        if len(cells) != len(header):
            raise ValueError(f"a row of {len(cells)} cells under {len(header)} columns: {cells}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def replace_table(text: str, name: str, table: str, doc: str = "the doc") -> str:
    """``text`` with what lies between table ``name``'s markers replaced by ``table``.

    A marker is a line of its own (a marker quoted inside a line is text). The markers' lines and
    everything outside them are kept byte for byte; the table is put on the lines between them.

    Raises
    ------
    DocTableError
        The opening marker is missing or repeated, or not closed before the next table opens.
    """
    marker = opening(name)
    opens = [m for m in OPEN_RE.finditer(text) if m.group(1) == name]
    if len(opens) != 1:
        raise DocTableError(f"{doc}: {'no' if not opens else f'{len(opens)} markers'} {marker}"
                            + (f" (add it where the table goes, closed by {CLOSE})" if not opens else ""))
    start = opens[0].end()
    close = CLOSE_RE.search(text, start)
    following = OPEN_RE.search(text, start)
    if close is None or (following is not None and following.start() < close.start()):
        raise DocTableError(f"{doc}: {marker} is not closed by {CLOSE}")
    return text[:start] + "\n" + table.strip("\n") + "\n" + text[close.start():]


def write_table(doc, name: str, table: str) -> None:
    """Replace table ``name`` in the file ``doc`` (atomically; see :func:`replace_table`)."""
    doc = Path(doc)
    if not doc.is_file():
        raise DocTableError(f"{doc}: no such doc (for table {name})")
    text = doc.read_text(encoding="utf-8")
    new = replace_table(text, name, table, doc=str(doc))
    if new != text:
        atomic_write_text(doc, new)


def parse_args(parser: argparse.ArgumentParser, argv=None) -> argparse.Namespace:
    """``parser.parse_args(argv)`` with ``--write-docs`` added; ``args.doc_argv`` keeps the arguments.

    ``argv`` None: ``sys.argv[1:]``. :func:`publish` names the command line in each table it writes.
    """
    parser.add_argument(FLAG, action="store_true",
                        help="also write this script's tables into docs/ between their <!-- table: NAME --> "
                             "markers (the tables there are never edited by hand)")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    args.doc_argv = [a for a in argv if a != FLAG]
    return args


def command(name: str, argv) -> str:
    """The command line that writes table ``name``: ``python tools/SCRIPT.py ARGV... --write-docs``."""
    return shlex.join(["python", f"tools/{script_of(name)}", *argv, FLAG])


def publish(args: argparse.Namespace, doc: str, name: str, table: str, caption: str = "", echo: bool = True) -> str:
    """Print ``table``; with ``--write-docs`` also write it into ``doc`` (relative to the repository).

    The written block is a line naming the command that wrote it (``caption`` after it, e.g. the
    units), a blank line, and the table. A doc without the marker is an error: one line on stderr
    naming doc and marker, exit status 2. ``echo`` False: not printed (the script printed it already).

    Returns
    -------
    str
        The block as written between the markers.
    """
    block = f"Written by `{command(name, args.doc_argv)}`{caption and ': ' + caption}.\n\n{table.strip(chr(10))}"
    if echo:
        print(f"\n{table.strip(chr(10))}", flush=True)
    if getattr(args, "write_docs", False):
        try:
            write_table(ROOT / doc, name, block)
        except (DocTableError, OutputError, OSError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        print(f"wrote table {name} in {doc}", file=sys.stderr)
    return block
