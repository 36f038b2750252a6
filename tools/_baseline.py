"""A baseline revision of the toolkit beside this tree, for benchmarks that compare the two in one run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def tree_env(tree: Path | None, **extra: str) -> dict:
    """The environment that runs ``tree``'s ``compass`` (first on ``PYTHONPATH``; None: this tree).

    Run the child from a folder outside both trees: Python puts the working folder first on its path.
    """
    env = dict(os.environ, MPLBACKEND="Agg", **extra)
    if tree is not None:
        env["PYTHONPATH"] = str(tree) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def export_tree(ref: str, folder: Path) -> Path:
    """``git archive REF`` unpacked into ``folder/baseline`` and compiled (no first-run bytecode cost)."""
    tree = folder / "baseline"
    tree.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    compile_tree(tree)
    return tree


def compile_tree(tree: Path) -> None:
    """Bytecode for ``tree``'s packages in their ``__pycache__`` folders (git ignores them).

    A child then reads the bytecode instead of compiling the sources on every run, as an installed
    toolkit does: with ``PYTHONDONTWRITEBYTECODE`` set nothing is cached otherwise, and the tumble
    command compiles 66 modules each time (0.2 s of CPU).  A benchmark comparing two trees compiles both.
    """
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "compass"), str(tree / "calibrate")],
                   check=True, capture_output=True)
