"""One Rerun recording: an .rrd file (written under a temporary name, renamed when complete) or a
spawned viewer, with the blueprint that lays it out."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import rerun as rr

from ..io.atomic import output_mode, remove_stale_temporaries
from ._target import SPAWN

__all__ = ["Recording", "columns_index", "index_rows"]


class Recording:
    """A Rerun recording stream with its default blueprint.

    Parameters
    ----------
    target : str or path
        ``"spawn"`` (a viewer on this desktop; check it first with
        :func:`compass.viz.check_rerun_target`) or an ``.rrd`` file. The file is written to a
        temporary name in its folder and renamed on :meth:`close`: a reader never sees half a file
        and an existing file is replaced only when the new one is complete.
    application_id : str
        Rerun's application id; the blueprint belongs to it.
    blueprint : rerun.blueprint.Blueprint, optional
        The default layout (views and their contents), stored in the file beside the data.
    recording_id : str, optional

    Attributes
    ----------
    rec : rerun.RecordingStream
        Log through it (``rec.log``, ``rec.send_columns``); never through the global stream.
    path : Path or None
        The .rrd file (None when spawned).
    """

    def __init__(self, target, *, application_id: str, blueprint=None, recording_id: str | None = None):
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        self.path = None if str(target) == SPAWN else Path(target)
        self._tmp = None
        if self.path is None:
            self.rec.spawn(default_blueprint=blueprint)
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            remove_stale_temporaries(self.path)  # ours too: .NAME.PID.*.tmp, as compass.io.atomic names them
            fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.name}.{os.getpid()}.", suffix=".tmp")
            os.close(fd)
            self._tmp = Path(tmp)
            self.rec.save(self._tmp, default_blueprint=blueprint)
        self.rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def close(self) -> None:
        """Flush, write the footer and move the file into place."""
        self.rec.disconnect()
        if self._tmp is not None:
            os.chmod(self._tmp, output_mode(self.path))  # as open() would leave it (mkstemp made it private)
            os.replace(self._tmp, self.path)
            self._tmp = None

    def discard(self) -> None:
        """Stop without writing the file (the command failed)."""
        self.rec.disconnect()
        if self._tmp is not None:
            self._tmp.unlink(missing_ok=True)
            self._tmp = None

    def __enter__(self):
        return self

    def __exit__(self, kind, value, traceback):
        if kind is None:
            self.close()
        else:
            self.discard()


def columns_index(t_s=None, sample=None) -> list:
    """``send_columns`` indexes: the ``t`` timeline (seconds, as a duration) and/or ``sample``."""
    index = []
    if t_s is not None:
        index.append(rr.TimeColumn("t", duration=np.asarray(t_s, dtype=float)))
    if sample is not None:
        index.append(rr.TimeColumn("sample", sequence=np.asarray(sample, dtype=np.int64)))
    return index


class _Rows:
    """Some rows of a ``send_columns`` index (Rerun's ``TimeColumnLike``)."""

    def __init__(self, column, rows):
        self._name, self._array = column.timeline_name(), column.as_arrow_array().take(rows)

    def timeline_name(self) -> str:
        return self._name

    def as_arrow_array(self):
        return self._array


def index_rows(index, rows) -> list:
    """The rows ``rows`` (integer positions) of a ``send_columns`` index."""
    rows = np.asarray(rows, dtype=np.int64)
    return [_Rows(column, rows) for column in index]
