"""The samples a live session takes, written as a recording ``compass attitude --filter`` replays.

``compass live --record RAW.csv`` writes, row by row as they arrive, every sample the decoder hands the
session: its time (the module's ``t_s``, or the date :class:`compass.io.clock.SampleClock` gave a stream
without one), the calibration's channels in the unit it reads them (``--mag-unit`` applied), ``temp_c``,
the accelerometer (in g when its unit is known: ``--accel-unit`` or MotionCal's lines) and the gyro in
rad/s, each number written exactly (``repr``), so the replay takes the very floats the live filter took
and writes the same rows.  The first lines say how it was recorded and the replay that reproduces it (with
the session's own options: the site and its date, a given gravity, the calibration's latency and gyro matrix).
The columns are the module's header's; a row on which the module sent an optional group empty (``temp_c``, the
accelerometer's or the gyro's, as the line protocol allows) has ``nan`` in its cells, which the replay reads as
that group not sent on that row, as the live session took it.  A later header with other columns ends the
recording (said once): one file has one set of columns.
"""

from __future__ import annotations

from .table import ABSENT_KEY, LIVE_RECORD

__all__ = ["SampleLog"]

_ABSENT = float("nan")


def _columns(sample) -> tuple:
    """Whether the sample's header has ``temp_c``, the accelerometer and the gyro (the sample's own groups when it
    was made without one)."""
    h = sample.header
    if h is None:
        return sample.temp_c is not None, sample.accel is not None, sample.gyro is not None
    return h.temp_c is not None, h.accel is not None, h.gyro is not None


class SampleLog:
    """Writes a session's samples as a CSV recording (SPEC section 2 columns).

    Parameters
    ----------
    out : text file
        Receives the lines (the command's atomic stream).
    channels : tuple of str
        The calibration's channel names, in the order of ``Sample.raw``.
    source : str
        Where the samples came from (the port), for the first line.
    replay_options : str
        The session's options the replay needs too (``--site LAT,LON --date YYYY-MM-DD --gravity G`` ...).
    """

    def __init__(self, out, channels, source: str, replay_options: str = ""):
        self.out, self.channels, self.source = out, tuple(channels), source
        self.replay_options = replay_options
        self.rows = 0
        self.stopped: str | None = None
        self._shape: tuple | None = None

    def write(self, samples: list, accel_in_g: bool) -> str | None:
        """Write the samples; words when this ends the recording (the columns changed), else None.

        Parameters
        ----------
        samples : list of compass.io.lines.Sample
            Each with its ``t_s`` (the module's, or its date), s.
        accel_in_g : bool
            The accelerometer's unit is known, so it is in g (said in the first lines, with the replay's
            ``--accel-unit g``).
        """
        for sample in samples:
            if self.stopped is not None:
                return None
            shape = _columns(sample)
            if self._shape is None:
                self._begin(shape, accel_in_g)
            elif shape != self._shape:
                self.stopped = (f"the module's columns changed after {self.rows} samples: --record holds those "
                                f"(one file has one set of columns)")
                return self.stopped
            cells = [sample.t_s, *sample.raw.tolist()]
            if shape[0]:
                cells.append(_ABSENT if sample.temp_c is None else sample.temp_c)
            for present, vector in zip(shape[1:], (sample.accel, sample.gyro)):
                if present:
                    cells += [_ABSENT] * 3 if vector is None else vector.tolist()
            self.out.write(",".join(map(repr, map(float, cells))) + "\n")
            self.rows += 1
        return None

    def _begin(self, shape: tuple, accel_in_g: bool) -> None:
        self._shape = shape
        temp, accel, gyro = shape
        unit = " --accel-unit g" if accel and accel_in_g else ""
        names = ["t_s", *self.channels] + (["temp_c"] if temp else []) + (["ax", "ay", "az"] if accel else []) \
            + (["gx", "gy", "gz"] if gyro else [])
        options = f" {self.replay_options}" if self.replay_options else ""
        self.out.write(f"# source: {LIVE_RECORD}, {self.source}\n"
                       f"# replay: compass attitude CAL.json THIS.csv --out ATT.csv --filter{unit}{options}\n"
                       + (f"# {ABSENT_KEY}: nan where the module sent the group empty on that row\n"
                          if temp or accel or gyro else "")
                       + f"# units: the calibration's for {','.join(self.channels)}"
                       + (f"; accelerometer in {'g' if accel_in_g else 'the module unit'}" if accel else "")
                       + ("; gyro in rad/s" if gyro else "") + "\n" + ",".join(names) + "\n")
