"""Write docs/cli.md from the commands' own ``--help``, so the page cannot drift from the code.

    python tools/write_cli_docs.py            # rewrites docs/cli.md
    python tools/write_cli_docs.py --check    # exit 1 when docs/cli.md differs from what it would write
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "cli.md"

INTRO = """# Command line

Every command's options, as `python -m compass CMD --help` prints them (the installed `compass` script
is the same program). What the commands do, step by step: the [README](../README.md); the physics behind
the options: [calibration](calibration.md), [runtime](runtime.md) and [production](production.md). Bad
input exits 2 with one line naming the file, row and column; no output file is overwritten without
`--force`.

This page is written by `python tools/write_cli_docs.py` from the commands' own help.
"""


def help_text(*args: str) -> str:
    env = {**os.environ, "COLUMNS": "100", "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "compass", *args, "--help"], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=120)
    if done.returncode != 0:
        raise SystemExit(f"compass {' '.join(args)} --help failed: {done.stderr.strip()}")
    return done.stdout.rstrip()


def page() -> str:
    sys.path.insert(0, str(ROOT))
    from compass.cli import SUBCOMMANDS, build_parser

    parser = build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    parts = [INTRO, "## compass\n\n```\n" + help_text() + "\n```\n"]
    for name in SUBCOMMANDS:
        parts.append(f"## compass {name}\n\n```\n{help_text(name)}\n```\n")
        nested = [a for a in subparsers.choices[name]._actions if isinstance(a, argparse._SubParsersAction)]
        for kind in (nested[0].choices if nested else ()):
            parts.append(f"### compass {name} {kind}\n\n```\n{help_text(name, kind)}\n```\n")
    return "\n".join(parts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare with docs/cli.md instead of writing it")
    args = ap.parse_args()
    text = page()
    if args.check:
        same = PAGE.read_text(encoding="utf-8") == text
        print("docs/cli.md is up to date" if same else "docs/cli.md differs: run python tools/write_cli_docs.py")
        return 0 if same else 1
    PAGE.write_text(text, encoding="utf-8")
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
