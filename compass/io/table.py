"""CSV tables of SPEC section 2: ``# key: value`` metadata, one header row, numeric rows.

Every problem is reported as a :class:`RecordingError` naming the file, the row (1-based line
number in the file) and the column, so the command line can print one line and exit 2.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["RecordingError", "Table", "read_table"]


class RecordingError(ValueError):
    """Bad input in a recording, with its location.

    Parameters
    ----------
    path : str
        The file.
    message : str
        What was expected and what was found.
    row : int, optional
        1-based line number in the file.
    column : str, optional
        Column name.
    """

    def __init__(self, path, message: str, row: int | None = None, column: str | None = None):
        self.path, self.row, self.column, self.reason = str(path), row, column, message
        where = [self.path]
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        super().__init__(f"{', '.join(where)}: {message}")


@dataclass(frozen=True)
class Table:
    """A parsed numeric CSV.

    Attributes
    ----------
    path : str
    columns : tuple of str
        Header names, stripped.
    data : ndarray, shape (n_rows, n_columns)
        Finite floats.
    rows : ndarray of int, shape (n_rows,)
        1-based file line number of each data row (for error messages).
    metadata : dict of str to str
        ``# key: value`` comment lines.
    """

    path: str
    columns: tuple[str, ...]
    data: np.ndarray
    rows: np.ndarray
    metadata: dict

    def has(self, name: str) -> bool:
        return name in self.columns

    def column(self, name: str) -> np.ndarray:
        """One column's values; RecordingError naming the column if it is missing."""
        if name not in self.columns:
            raise RecordingError(
                self.path, f"missing required column '{name}' (header has: {', '.join(self.columns)})", row=self.header_row
            )
        return self.data[:, self.columns.index(name)]

    def time_s(self) -> np.ndarray | None:
        """The optional ``t_s`` column, None when absent; RecordingError at the first step back in time."""
        if not self.has("t_s"):
            return None
        t_s = self.column("t_s")
        back = np.flatnonzero(np.diff(t_s) < 0)
        if back.size:
            raise RecordingError(self.path, f"t_s must not decrease (goes from {t_s[back[0]]} to {t_s[back[0] + 1]})",
                                 row=int(self.rows[back[0] + 1]), column="t_s")
        return t_s

    @property
    def header_row(self) -> int:
        return int(self.rows[0]) - 1 if len(self.rows) else 1

    def metadata_float(self, key: str) -> float | None:
        """A numeric metadata value, or None when absent; RecordingError when not a number."""
        if key not in self.metadata:
            return None
        try:
            return float(self.metadata[key])
        except ValueError:
            raise RecordingError(self.path, f"metadata '{key}' should be a number, got {self.metadata[key]!r}") from None


def read_table(path) -> Table:
    """Read and validate a numeric CSV recording.

    Raises
    ------
    RecordingError
        Unreadable or binary file, no header, no data rows, duplicate column, wrong number of
        cells, or a cell that is not a finite number.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise RecordingError(path, f"cannot read file ({exc.strerror})") from None
    if b"\x00" in raw:
        raise RecordingError(path, "binary data (NUL bytes): expected a text CSV file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise RecordingError(path, "not UTF-8 text: expected a CSV file", row=line) from None
    if not text.strip():
        raise RecordingError(path, "empty file: expected a header row and data rows")
    if text.lstrip()[:1] in ("{", "["):
        raise RecordingError(path, "this is JSON (a calibration file?): expected a CSV recording", row=1)

    lines = text.splitlines()
    metadata: dict[str, str] = {}
    header, header_line = None, 0
    for number, stripped in _content(lines, 0, metadata):
        header, header_line = [c.strip() for c in stripped.split(",")], number
        break
    if header is None:
        raise RecordingError(path, "no header row: expected comma-separated column names")
    for i, name in enumerate(header):
        if not name:
            raise RecordingError(path, f"empty column name at position {i + 1}", row=header_line)
        if _is_number(name):
            raise RecordingError(path, f"header expected, found a number {name!r}", row=header_line, column=name)
        if header.index(name) != i:
            raise RecordingError(path, "duplicate column name", row=header_line, column=name)

    data = _parse_plain_body(lines[header_line:], len(header))
    if data is not None:
        rows = np.arange(header_line + 1, header_line + 1 + len(data))
        return Table(str(path), tuple(header), data, rows, metadata)
    body = list(_content(lines, header_line, metadata))
    body_rows = [number for number, _ in body]
    body_lines = [stripped for _, stripped in body]
    if not body_lines:
        raise RecordingError(path, "header only: no data rows", row=header_line)

    data = _parse_body(path, header, body_lines, body_rows)
    return Table(str(path), tuple(header), data, np.asarray(body_rows), metadata)


def _content(lines: list[str], start: int, metadata: dict):
    """(1-based line number, stripped text) of the data lines from ``lines[start]`` on.

    Blank lines are skipped; ``# key: value`` comments go into ``metadata``, other comments are
    skipped.
    """
    for number, line in enumerate(lines[start:], start=start + 1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            key, sep, value = stripped[1:].partition(":")
            if sep and key.strip():
                metadata[key.strip()] = value.strip()
            continue
        yield number, stripped


def _parse_plain_body(lines: list[str], n_cols: int) -> np.ndarray | None:
    """Fast path for a body of data rows only (no comment, no blank line): one ``np.loadtxt``.

    None when the body is anything else or does not parse; the line-by-line path then finds the
    comments and names the bad cell.
    """
    text = "\n".join(lines)
    if "#" in text or not text.strip():
        return None
    try:
        data = np.loadtxt(io.StringIO(text), delimiter=",", ndmin=2, dtype=float)
    except ValueError:
        return None
    if data.shape != (len(lines), n_cols) or not np.all(np.isfinite(data)):
        return None
    return data


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _parse_body(path, header, lines, rows) -> np.ndarray:
    n_cols = len(header)
    try:
        data = np.loadtxt(io.StringIO("\n".join(lines)), delimiter=",", ndmin=2, dtype=float)
        if data.shape[1] == n_cols and np.all(np.isfinite(data)):
            return data
    except ValueError:
        pass
    # slow path: find the first bad cell and name it
    for line, row in zip(lines, rows):
        cells = line.split(",")
        if len(cells) != n_cols:
            raise RecordingError(path, f"expected {n_cols} cells, found {len(cells)}", row=row)
        for name, cell in zip(header, cells):
            try:
                value = float(cell)
            except ValueError:
                raise RecordingError(path, f"expected a number, found {cell.strip()!r}", row=row, column=name) from None
            if not np.isfinite(value):
                raise RecordingError(path, f"expected a finite number, found {cell.strip()!r}", row=row, column=name)
    raise RecordingError(path, "could not parse the data rows as numbers")
