"""What the bench station judges from the data as each turn comes: stillness, coverage, the face down.

Frames (SPEC section 1): the cube in flip kappa has the housing's ``(0, sin kappa, cos kappa)``
pointing up; an accelerometer riding in the housing reads that direction (specific force, +1 g up).
"""

from __future__ import annotations

import numpy as np

__all__ = ["FACES", "face_name", "up_in_housing", "nearest_face", "is_still", "coverage_gap",
           "circle_axis"]

FACES = {"+X": (1.0, 0.0, 0.0), "-X": (-1.0, 0.0, 0.0), "+Y": (0.0, 1.0, 0.0), "-Y": (0.0, -1.0, 0.0),
         "+Z": (0.0, 0.0, 1.0), "-Z": (0.0, 0.0, -1.0)}
"""Housing axis pointing up -> that axis as a unit vector in H."""

_STILL_T = 6.0  # slope t-statistic above which a channel is moving (pure noise: |N(0,1)|)


def up_in_housing(flip_deg: float) -> np.ndarray:
    """The housing-frame direction that points up in flip ``flip_deg`` (about the turntable's X axis).

    >>> up_in_housing(90.0).round(12).tolist()
    [0.0, 1.0, 0.0]
    """
    k = np.radians(flip_deg)
    return np.array([0.0, np.sin(k), np.cos(k)])


def face_name(flip_deg: float) -> str:
    """Words for the cube's pose in a flip: which axis points up, which face lies on the table.

    >>> face_name(90)
    '+Y up (the -Y face on the table)'
    """
    up = nearest_face(up_in_housing(flip_deg))[0]
    down = {"+": "-", "-": "+"}[up[0]] + up[1]
    return f"{up} up (the {down} face on the table)"


def nearest_face(up_h) -> tuple[str, float]:
    """The housing axis nearest to ``up_h`` (any length) and the angle to it, degrees."""
    u = np.asarray(up_h, float)
    u = u / np.linalg.norm(u)
    names = list(FACES)
    cosines = np.array([FACES[n] for n in names]) @ u
    best = int(np.argmax(cosines))
    return names[best], float(np.degrees(np.arccos(np.clip(cosines[best], -1.0, 1.0))))


def is_still(t_s: np.ndarray, values: np.ndarray, *, floor: np.ndarray | None = None) -> bool:
    """Whether a window of samples shows no motion: no channel has a significant linear trend.

    Each channel's least-squares slope over the window is tested against its own scatter about the
    line: moving when ``|b| sqrt(S_tt) / s > 6`` for any channel (a t-statistic; under noise alone
    it is ``|N(0, 1)|``).  A turn at 1 deg/s changes a horizontal channel by about 2 % of the
    horizontal field a second, hundreds of times the noise of a second's samples.

    Parameters
    ----------
    t_s : ndarray, shape (n,)
        Sample times, seconds.
    values : ndarray, shape (n, c)
        Channel outputs, any unit.
    floor : ndarray, shape (c,), optional
        Smallest scatter to assume per channel (a quantised channel can scatter zero), output units.
    """
    t = np.asarray(t_s, float)
    v = np.asarray(values, float)
    if len(t) < 5 or np.ptp(t) <= 0:
        return False
    tc = t - t.mean()
    s_tt = float(tc @ tc)
    vc = v - v.mean(axis=0)
    slope = tc @ vc / s_tt
    resid = vc - np.outer(tc, slope)
    scatter = np.sqrt(np.sum(resid**2, axis=0) / max(len(t) - 2, 1))
    if floor is not None:
        scatter = np.maximum(scatter, floor)
    scatter = np.where(scatter > 0, scatter, np.finfo(float).tiny)
    return bool(np.all(np.abs(slope) * np.sqrt(s_tt) / scatter <= _STILL_T))


def coverage_gap(platform_deg: np.ndarray) -> tuple[float, float, float]:
    """Degrees of the circle covered and the widest gap between neighbouring angles.

    Returns
    -------
    covered_deg : float
        360 less the widest gap (0 for fewer than two samples).
    gap_deg : float
        The widest gap, degrees.
    gap_start_deg : float
        Where the widest gap begins, degrees in [0, 360).
    """
    a = np.sort(np.mod(np.asarray(platform_deg, float), 360.0))
    if len(a) < 2:
        return 0.0, 360.0, float(a[0]) if len(a) else 0.0
    gaps = np.diff(np.concatenate([a, a[:1] + 360.0]))
    worst = int(np.argmax(gaps))
    return float(360.0 - gaps[worst]), float(gaps[worst]), float(a[worst])


def circle_axis(platform_deg: np.ndarray, outputs: np.ndarray) -> np.ndarray | None:
    """The turntable axis in the channels' frame from the field's circle over a turn (three channels).

    Over a turn the field in H traces a circle about the turntable axis ``u``; the first harmonics
    of the outputs in the turntable angle, ``c cos(phi) + s sin(phi)``, span its plane, and for
    channels along H's axes with one gain ``c x s = -H^2 u`` (the field turns clockwise in H when the
    table turns counterclockwise).  Channels off the axes or with unequal gains tilt the result by
    the distortion of the channel matrix (a few degrees for a typical module), far less than the
    90 degrees between faces.

    Returns
    -------
    ndarray, shape (3,), or None
        Unit vector (up, in the channels' frame), None unless there are exactly three channels.
    """
    v = np.asarray(outputs, float)
    if v.ndim != 2 or v.shape[1] != 3:
        return None
    phi = np.radians(platform_deg)
    design = np.column_stack([np.ones_like(phi), np.cos(phi), np.sin(phi)])
    coef, *_ = np.linalg.lstsq(design, v, rcond=None)
    axis = -np.cross(coef[1], coef[2])
    norm = np.linalg.norm(axis)
    return axis / norm if norm > 0 else None
