"""The gyro's scale error as a Gauss-Markov rate-error state (``FilterConfig.scale_error_state``, issue 22).

The gyro filter's error state ``(eps, db)`` is augmented by ``r``, the world-frame rate error the gyro's scale and
cross-axis errors make while the housing turns (``eps' = r - R db``): a first-order Gauss-Markov process of
correlation time ``T`` (``_SCALE_CORRELATION_S``, 1 s) and variance ``s^2 |w|^2 / 2`` per axis, whose low-frequency
density ``s^2 |w|^2 T`` is the white attitude noise it replaces.  Coloured, it makes the attitude error grow as
``t^2`` over less than ``T``: the Kalman loop on the tilt becomes second order, and the accelerometer's leak at the
hand's periods (0.3-3 s) is cut more steeply at the same mean age (``tools/leak_shape.py``; docs/benchmarks.md).

The 6x6 block of ``(eps, db)`` stays :attr:`GyroState.covariance` (packed, 21 floats: everything that reads it is
unchanged); the rest, ``extra``, is 24 floats: the 6x3 cross-covariance of ``(eps, db)`` with ``r`` row by row, then
``r``'s own 3x3 block packed.  The steps are numpy on the 9x9 matrix: the option is a measurement, not the per-sample
fast path.
"""

from __future__ import annotations

import numpy as np


__all__ = ["EXTRA_ZERO", "full", "split", "predict", "update", "restart"]

_UPPER3 = [(i, j) for i in range(3) for j in range(i, 3)]
EXTRA_ZERO = (0.0,) * 24
"""No rate error and no correlation with it."""


def _layout() -> tuple[np.ndarray, tuple, tuple]:
    """Where each of the 81 entries of the 9x9 matrix sits in ``p + extra`` (45 floats), and the rows and columns
    of the 45 in the matrix."""
    where = np.empty((9, 9), int)
    rows, cols = [], []
    for k, (i, j) in enumerate([(i, j) for i in range(6) for j in range(i, 6)]
                               + [(i, 6 + j) for i in range(6) for j in range(3)]
                               + [(6 + i, 6 + j) for i, j in _UPPER3]):
        where[i, j] = where[j, i] = k
        rows.append(i)
        cols.append(j)
    return where.ravel(), np.array(rows), np.array(cols)


_WHERE, _ROWS, _COLS = _layout()


def full(p: tuple, extra: tuple) -> np.ndarray:
    """The 9x9 covariance of ``(eps, db, r)`` from the packed 6x6 block ``p`` and ``extra``."""
    return np.array(p + extra)[_WHERE].reshape(9, 9)


def split(m: np.ndarray) -> tuple[tuple, tuple]:
    """``(p, extra)`` of a 9x9 covariance (symmetrised)."""
    values = ((m[_ROWS, _COLS] + m[_COLS, _ROWS]) / 2.0).tolist()
    return tuple(values[:21]), tuple(values[21:])


def predict(p: tuple, extra: tuple, r: tuple, dt: float, q_att: float, q_bias: float, q_rate: float,
            decay: float) -> tuple[tuple, tuple]:
    """``F P F^T + Q``, ``F = [[I, -R dt, I dt], [0, I, 0], [0, 0, decay I]]``, ``Q = diag(q_att I, q_bias I, q_rate I)``.

    Parameters
    ----------
    p, extra : tuple
        The covariance's two parts (module docstring).
    r : tuple of 9 floats
        ``R_world<-housing`` row-major.
    dt : float
        Time step, s.
    q_att, q_bias, q_rate : float
        Process noise variances over the step: attitude (rad^2), bias and rate error ((rad/s)^2).
    decay : float
        ``exp(-dt / T)``, the rate error's.
    """
    f = np.eye(9)
    f[:3, 3:6] = -dt * np.reshape(r, (3, 3))
    f[:3, 6:] = dt * np.eye(3)
    f[6:, 6:] *= decay
    m = f @ full(p, extra) @ f.T
    m[np.diag_indices(9)] += (q_att,) * 3 + (q_bias,) * 3 + (q_rate,) * 3
    return split(m)


def update(p: tuple, extra: tuple, x: list, h, z: float, var: float, estimated) -> tuple[tuple, tuple]:
    """One scalar measurement ``z = h . x_true + n`` (``var n = var``) of the 9 error states.

    ``estimated`` (9 bools): the states the update may move; the others are *considered* (Schmidt: gain zero, their
    uncertainty still counts), and the covariance is the Joseph form's for that gain,
    ``P - K c^T - c K^T + s K K^T`` (``c = P h``, ``s = h . c + var``).  ``x`` (the error state accumulated so far this
    sample; the innovation is ``z - h . x``) is updated in place.
    """
    m, h = full(p, extra), np.array(h)
    c = m @ h
    s = float(h @ c) + var
    nu = z - float(h @ np.array(x))
    if all(estimated):
        k = c / s
        m -= k[:, None] * c
    else:
        k = np.where(estimated, c / s, 0.0)
        kc = k[:, None] * c
        m += s * k[:, None] * k - kc - kc.T
    for i, v in enumerate((k * nu).tolist()):
        x[i] += v
    return split(m)


def restart(extra: tuple) -> tuple:
    """``extra`` after the attitude restarts (its covariance reset, the bias kept): the attitude's and the bias's
    correlation with the rate error dropped; its own variance kept."""
    return EXTRA_ZERO[:18] + tuple(extra[18:])
