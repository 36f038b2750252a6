"""The bench session on disk: each finished flip kept as it is done, the recording written at the end.

Beside ``CAL.json`` the station keeps ``CAL.flips/``: ``session.json`` (the module's columns, its
sample rate, the angle source, the metadata) and one ``flip_KKK.csv`` per finished flip, each
written atomically (:mod:`compass.io.atomic`), so Ctrl-C or a crash loses at most the turn in
progress and ``compass bench --resume`` continues from the flips found.  At the end the flips
are joined into ``CAL.fourflip.csv`` (SPEC section 2's four-flip recording with the station's
metadata, and a ``# clock:`` line when the module's clock restarted between flips: its ``t_s`` goes
on across each restart, :meth:`compass.station.Station`), which ``compass calibrate`` reads.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_write_text
from ..io.fourflip import NOMINAL_FLIPS_DEG

__all__ = ["FlipRows", "SessionStore", "recording_path", "flips_folder"]


def recording_path(out) -> Path:
    """The recording written beside a calibration file: ``CAL.json`` -> ``CAL.fourflip.csv``."""
    out = Path(out)
    return out.with_name(out.stem + ".fourflip.csv")


def flips_folder(out) -> Path:
    """The folder holding the finished flips of a session: ``CAL.json`` -> ``CAL.flips/``."""
    out = Path(out)
    return out.with_name(out.stem + ".flips")


@dataclass(frozen=True)
class FlipRows:
    """The rows one flip adds to the recording.

    Attributes
    ----------
    flip_deg : float
        Nominal flip, degrees.
    columns : tuple of str
        ``t_s, flip_deg, platform_deg``, the channels, then ``ax,ay,az`` and ``temp_c`` when the
        module sends them.
    table : ndarray, shape (n, len(columns))
    angle_sigma_deg : float
        The angle source's stated uncertainty for this flip, degrees.
    clock : str or None
        The module's clock restarted before this flip, in words (its ``t_s`` goes on from the flips kept).
    """

    flip_deg: float
    columns: tuple[str, ...]
    table: np.ndarray
    angle_sigma_deg: float
    clock: str | None = None


def _first_t_s(rows: FlipRows) -> float:
    """When a kept flip began on the recording's clock, seconds (-inf without ``t_s`` or rows: first)."""
    if "t_s" not in rows.columns or not len(rows.table):
        return -np.inf
    return float(rows.table[0, rows.columns.index("t_s")])


class SessionStore:
    """Finished flips and the session's description in ``CAL.flips/``.

    Parameters
    ----------
    out : path-like
        The calibration file the session ends in.
    """

    def __init__(self, out):
        self.out = Path(out)
        self.folder = flips_folder(out)

    def exists(self) -> bool:
        return (self.folder / "session.json").exists()

    def start(self, description: dict) -> None:
        """Begin a new session (the folder must not hold one)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.folder / "session.json", json.dumps(description, indent=2) + "\n")

    def description(self) -> dict:
        return json.loads((self.folder / "session.json").read_text())

    def save(self, rows: FlipRows) -> Path:
        """Keep a finished flip (atomically)."""
        path = self.folder / f"flip_{int(rows.flip_deg):03d}.csv"
        lines = [f"# angle_sigma_deg: {rows.angle_sigma_deg:.6g}"] + [f"# clock: {rows.clock}"] * (rows.clock is not None)
        lines.append(",".join(rows.columns))
        lines += [",".join(f"{x:.9g}" for x in row) for row in rows.table]
        atomic_write_text(path, "\n".join(lines) + "\n")
        return path

    def finished(self) -> dict[float, FlipRows]:
        """The flips kept so far, by nominal flip."""
        found = {}
        for flip in NOMINAL_FLIPS_DEG:
            path = self.folder / f"flip_{int(flip):03d}.csv"
            if not path.exists():
                continue
            text = path.read_text().splitlines()
            meta = {k.strip(): v.strip() for k, v in (line[1:].split(":", 1) for line in text if line.startswith("#"))}
            rows = [line for line in text if line and not line.startswith("#")]
            columns = tuple(rows[0].split(","))
            table = np.array([[float(x) for x in line.split(",")] for line in rows[1:]], float)
            found[flip] = FlipRows(flip, columns, table.reshape(-1, len(columns)), float(meta["angle_sigma_deg"]),
                                   meta.get("clock"))
        return found

    def write_recording(self, metadata: dict, force: bool = False) -> Path:
        """Join the four flips into the recording beside the calibration file; returns its path.

        The flips are written in the order they were recorded (by their first ``t_s``), so the recording's
        ``t_s`` does not decrease (SPEC section 2) when a flip was recorded again after the others (its file
        deleted and the session resumed: its ``t_s`` goes on from the flips kept, :meth:`Station._after_kept`);
        the four-flip fit takes each row by its ``flip_deg``, not by its place.  The stated ``angle_sigma_deg``
        is the largest of the flips'; the flips' clock restarts make one ``# clock:`` line, in time order.
        """
        flips = self.finished()
        if len(flips) != len(NOMINAL_FLIPS_DEG):
            raise ValueError(f"{self.folder}: {len(flips)} of 4 flips done")
        columns = flips[0.0].columns
        order = sorted(NOMINAL_FLIPS_DEG, key=lambda f: _first_t_s(flips[f]))
        sigma = max(f.angle_sigma_deg for f in flips.values())
        meta = {**metadata, "angle_sigma_deg": f"{sigma:.4g}"}
        clocks = [flips[f].clock for f in order if flips[f].clock is not None]
        if clocks:
            meta["clock"] = "; ".join(clocks)
        lines = [f"# {k}: {v}" for k, v in meta.items()] + [",".join(columns)]
        for flip in order:
            lines += [",".join(f"{x:.9g}" for x in row) for row in flips[flip].table]
        path = recording_path(self.out)
        if path.exists() and not force:
            raise FileExistsError(f"{path} exists; use --force to overwrite it")
        atomic_write_text(path, "\n".join(lines) + "\n")
        return path

    def discard_empty(self) -> bool:
        """Remove a session that kept no flip (its ``session.json``, and the folder when nothing else is in it);
        whether there was one."""
        if not self.exists() or self.finished():
            return False
        (self.folder / "session.json").unlink()
        if not any(self.folder.iterdir()):
            self.folder.rmdir()
        return True

    def discard(self) -> None:
        """Remove the folder (after the recording holds everything)."""
        shutil.rmtree(self.folder, ignore_errors=True)
