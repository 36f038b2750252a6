"""Writing a simulated recording and the truth behind it, side by side, atomically."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_write_text

__all__ = ["csv_text", "write_with_truth"]


def csv_text(columns, data: np.ndarray, formats, metadata: dict | None = None) -> str:
    """SPEC CSV text: ``# key: value`` lines, a header, one row per sample.

    Parameters
    ----------
    columns : sequence of str
    data : ndarray, shape (n, len(columns))
    formats : str or sequence of str
        printf format of every column, or one for all.
    metadata : dict, optional
    """
    formats = [formats] * len(columns) if isinstance(formats, str) else list(formats)
    row_format = ",".join(formats)
    lines = [f"# {k}: {v}" for k, v in (metadata or {}).items()] + [",".join(columns)]
    lines += [row_format % tuple(row) for row in np.asarray(data, dtype=float)]
    return "\n".join(lines) + "\n"


def write_with_truth(path, recording_text: str, truth: dict, *, force: bool = False) -> tuple[Path, Path]:
    """Write a recording and its truth beside it, ``<stem>.truth.json``: every simulator's one convention.

    Raises
    ------
    FileExistsError
        If either file exists and ``force`` is False (nothing is written then).
    """
    path = Path(path)
    truth_path = path.with_suffix(".truth.json")
    for p in (path, truth_path):
        if p.exists() and not force:
            raise FileExistsError(f"{p} exists; use --force to overwrite")
    atomic_write_text(path, recording_text)
    atomic_write_text(truth_path, json.dumps(truth, indent=2) + "\n")
    return path, truth_path
