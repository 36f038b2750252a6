"""The samples of one flip as the station keeps them: readings, a turn's arrays, its still spans.

A :class:`Reading` is one sample of the module (the stream decoder's output, the encoder column
split off); :class:`TurnData` is a run of them as arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import is_still, up_in_housing

__all__ = ["Reading", "ReadingBuffer", "TurnData", "TurnRejected", "WrongFace", "gyro_turn_deg", "still_spans",
           "turn_about_deg"]


class TurnRejected(ValueError):
    """A turn the station cannot use; the message says what to redo, in words."""


class WrongFace(TurnRejected):
    """The turn was made with another face down than the flip asks for: the flip is redone first."""


@dataclass(frozen=True)
class Reading:
    """One sample of the module.

    Attributes
    ----------
    t_s : float
        Module time (or receive time when the module sends none), seconds.
    outputs : ndarray, shape (c,)
        Magnetic channel outputs, any unit.
    accel : ndarray, shape (3,), or None
        Accelerometer in H, any unit (specific force: +up).
    gyro : ndarray, shape (3,), or None
        Angular rate of H in H, rad/s.
    encoder_deg : float or None
        The turntable's own reading, degrees (``--turntable column:NAME``).
    temp_c : float or None
    """

    t_s: float
    outputs: np.ndarray
    accel: np.ndarray | None = None
    gyro: np.ndarray | None = None
    encoder_deg: float | None = None
    temp_c: float | None = None


@dataclass(frozen=True)
class TurnData:
    """Readings as arrays (a group is None unless every reading has it).

    Attributes
    ----------
    t_s : ndarray, shape (n,)
    outputs : ndarray, shape (n, c)
    accel, gyro : ndarray, shape (n, 3), or None
    encoder_deg, temp_c : ndarray, shape (n,), or None
    """

    t_s: np.ndarray
    outputs: np.ndarray
    accel: np.ndarray | None
    gyro: np.ndarray | None
    encoder_deg: np.ndarray | None
    temp_c: np.ndarray | None

    @classmethod
    def from_readings(cls, readings) -> "TurnData":
        buffer = ReadingBuffer()
        for r in readings:
            buffer.append(r)
        return buffer.arrays()

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def rate_hz(self) -> float:
        """Samples per second from the median spacing of ``t_s`` (nan for fewer than two samples)."""
        dt = np.diff(self.t_s)
        dt = dt[dt > 0]
        return float(1.0 / np.median(dt)) if dt.size else float("nan")

    def subset(self, keep) -> "TurnData":
        pick = (lambda a: None if a is None else a[keep])
        return TurnData(self.t_s[keep], self.outputs[keep], pick(self.accel), pick(self.gyro),
                        pick(self.encoder_deg), pick(self.temp_c))


class ReadingBuffer:
    """Readings appended one at a time into a growing array, handed out as :class:`TurnData`.

    A group (``accel``, ``gyro``, ``encoder_deg``, ``temp_c``) missing from any reading handed
    out is None.  Appending costs a row copy; :meth:`arrays` copies the rows asked for.
    """

    _SLICES = {"accel": 3, "gyro": 3, "encoder_deg": 1, "temp_c": 1}

    def __init__(self):
        self._rows = None
        self._n = 0

    def clear(self) -> None:
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def append(self, r: Reading) -> None:
        c = len(r.outputs)
        if self._rows is None or self._rows.shape[1] != 1 + c + 8:
            self._rows = np.empty((1024, 1 + c + 8))
            self._n = 0
        elif self._n == len(self._rows):
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        row = self._rows[self._n]
        row[0] = r.t_s
        row[1:1 + c] = r.outputs
        at = 1 + c
        for name, width in self._SLICES.items():
            value = getattr(r, name)
            row[at:at + width] = np.nan if value is None else value
            at += width
        self._n += 1

    @property
    def last_t_s(self) -> float:
        return float(self._rows[self._n - 1, 0])

    def arrays(self, last_s: float | None = None) -> TurnData:
        """All readings, or those of the last ``last_s`` seconds."""
        if self._rows is None:
            return TurnData(np.empty(0), np.empty((0, 0)), None, None, None, None)
        t = self._rows[:self._n, 0]
        start = 0 if last_s is None or not self._n else int(np.searchsorted(t, t[-1] - last_s))
        rows = self._rows[start:self._n]
        c = rows.shape[1] - 9
        group, at = {}, 1 + c
        for name, width in self._SLICES.items():
            block = rows[:, at:at + width]
            at += width
            group[name] = None if not len(rows) or np.isnan(block).any() else (
                block.copy() if width > 1 else block[:, 0].copy())
        return TurnData(rows[:, 0].copy(), rows[:, 1:1 + c].copy(), group["accel"], group["gyro"],
                        group["encoder_deg"], group["temp_c"])


def still_spans(data: TurnData, window_s: float = 0.5) -> np.ndarray:
    """Per sample, whether the table is still around it: windows of ``window_s`` judged by
    :func:`compass.station.checks.is_still`, each sample taking its window's verdict.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    t = data.t_s
    still = np.zeros(len(t), bool)
    if len(t) == 0:
        return still
    edges = np.arange(t[0], t[-1] + window_s, window_s)
    index = np.searchsorted(t, edges)
    for a, b in zip(index[:-1], index[1:]):
        if b - a >= 5:
            still[a:b] = is_still(t[a:b], data.outputs[a:b])
    return still


def gyro_turn_deg(data: TurnData, flip_deg: float) -> float | None:
    """The table's turn over ``data`` as the module's gyro saw it, degrees (counterclockwise seen from above positive).

    The gyro's rate about the housing direction that points up in the flip
    (:func:`compass.station.checks.up_in_housing`: right-hand about up, SPEC's sense of the turntable angle), less
    its bias (the mean rate over the still spans, :func:`still_spans`; none when no span is
    still), integrated in time:

    .. math:: \\psi = \\int (\\omega_H(t) - \\bar\\omega_{still}) \\cdot u_H(\\kappa) \\, dt

    Parameters
    ----------
    data : TurnData
        The samples over the turn (``gyro`` in rad/s, in H).
    flip_deg : float
        The flip the turn is made in, degrees.

    Returns
    -------
    float or None
        Degrees; None when the module sends no gyro (or fewer than three samples).
    """
    if data.gyro is None or len(data) < 3:
        return None
    still = still_spans(data)
    bias = data.gyro[still].mean(axis=0) if still.any() else np.zeros(3)
    return turn_about_deg(data, up_in_housing(flip_deg), bias)


def turn_about_deg(data: TurnData, up_h: np.ndarray, bias: np.ndarray) -> float:
    """The gyro's rate less ``bias`` (rad/s) about ``up_h`` (unit, in H) integrated over ``data``, degrees."""
    return float(np.degrees(np.trapezoid((data.gyro - bias) @ up_h, data.t_s)))
