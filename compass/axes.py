"""Is the magnetometer's frame right-handed against the accelerometer's?  Which axis to negate if not.

**Physics.**  With ``u_i`` the unit up direction (accelerometer frame) and ``m_i`` the calibrated
field (magnetometer frame), a proper rotation ``C`` (``det C = +1``) between the frames gives, at
every orientation ``R_i`` of the housing,

.. math:: u_i \\cdot C m_i = z^T R_i\\, R_i^T b_W = -|B| \\sin\\delta ,

the same field-gravity angle ``90 deg + dip`` for all orientations.  A magnetometer with one axis
reversed reads ``D m`` (``D`` a reflection, ``det D = -1``).  Then ``u_i \\cdot C D m_i = z^T R_i (CD)
R_i^T b_W``, which is the same for every ``R_i`` only if ``CD`` commutes with every rotation, i.e.
``CD = \\pm I``; ``det(CD) = -1`` leaves ``CD = -I``: ``C = -D`` (a half turn), and then the angle is
constant with the **dip's sign turned**.  So a reflected pair either reads a field-gravity angle that
wanders with the orientation (no rotation fitted: the issue's 41 degree spread), or, with the best
rotation, a consistent field that points up in the northern hemisphere (the issue's dip -60.9 deg at
40 deg N).  The data alone cannot tell a reflection from a half turn with the field reversed: the
sign patterns ``s`` and ``-s`` of the three axes give one spread and opposite dips.  The site's
hemisphere (its dip's sign) breaks the tie; without a site, the check names both readings.

:func:`check_axes` tries the eight sign patterns of the magnetometer's axes and returns a verdict
when one makes the readings consistent where they were not, or when the dip has the wrong sign for
the site; it names the axis (or axes) to negate.  Used by the tumble and installation calibrations
and, at runtime, by :class:`compass.live.LiveSession` (so ``compass live`` and the replay).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

__all__ = ["AxisVerdict", "check_axes", "MIN_SIGNED_DIP_DEG"]

MIN_SIGNED_DIP_DEG = 10.0
"""The site's |dip| above which its sign is judged (near the magnetic equator a tilt error reaches it)."""
_CONSISTENT_DEG = 10.0  # robust spread of the per-row dip below which readings are consistent (an installation's
# own iron, not yet fitted, spreads the right pattern's dip by a few degrees: 5.6 for 6.7 uT of hard iron)
_GAIN = 3.0  # a pattern must shrink the spread this many times to be named
_MIN_ROWS = 20
_MIN_DIVERSITY = 0.2  # 1 - |mean of the unit up vectors|: below, the housing hardly turned


@dataclass(frozen=True)
class AxisVerdict:
    """What :func:`check_axes` found.

    Attributes
    ----------
    signs : tuple of 3 int
        The sign pattern of the magnetometer's x, y, z that makes the readings consistent (with the
        site's dip sign when known).
    left_handed : bool
        The pattern is a reflection (one or three axes negated): the frames as read are left-handed.
    dip_deg, spread_deg : float
        Median dip and robust spread (1.4826 MAD) of the per-row dip with the pattern, degrees.
    dip_as_read_deg, spread_as_read_deg : float
        The same as read.
    text : str
        One line: what is wrong and what to negate.
    """

    signs: tuple
    left_handed: bool
    dip_deg: float
    spread_deg: float
    dip_as_read_deg: float
    spread_as_read_deg: float
    text: str


def _dips(up: np.ndarray, field: np.ndarray, signs) -> tuple[float, float]:
    """Median dip and robust spread, degrees, with the field's axes multiplied by ``signs``."""
    m = field * np.asarray(signs, dtype=float)
    cos = -np.einsum("ij,ij->i", up, m) / np.sqrt(np.einsum("ij,ij->i", m, m))  # |m| per row
    dip = np.degrees(np.arcsin(np.clip(cos, -1.0, 1.0)))
    centre = float(np.median(dip))
    return centre, float(1.4826 * np.median(np.abs(dip - centre)))


def _negate(signs, names) -> str:
    axes = [n for s, n in zip(signs, names) if s < 0]
    return " and ".join(axes)


def check_axes(up, field, *, rotation=None, site_dip_deg: float | None = None, names=("mx", "my", "mz"),
               note_upward: bool = False) -> AxisVerdict | None:
    """The sign pattern of the magnetometer's axes the readings call for; None when they are right as read.

    Parameters
    ----------
    up : array_like, shape (n, 3)
        Accelerometer readings (any unit; quasi-static rows: ``||a| / median - 1| < 5 %`` are used),
        accelerometer frame.
    field : array_like, shape (n, 3)
        Calibrated field, magnetometer frame (any unit).
    rotation : array_like, shape (3, 3), optional
        ``mag_to_accel`` (the fitted rotation); default identity.
    site_dip_deg : float, optional
        The site's dip: its sign is the field's expected one (judged for ``|dip| >= 10 deg``).
    names : tuple of 3 str
        The magnetometer axes' names for the words.
    note_upward : bool
        Without a site, a consistent field pointing up (dip below -10 deg) is named too: right in the
        southern hemisphere, a reversed axis in the northern (a calibration's warning; not at runtime,
        where it would repeat for every southern user).

    Returns
    -------
    AxisVerdict or None
        None also with fewer than 20 usable rows.
    """
    a = np.asarray(up, dtype=float)
    b = np.asarray(field, dtype=float)
    ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    norm = np.sqrt(np.einsum("ij,ij->i", a, a))
    ok &= norm > 0
    if np.count_nonzero(ok) < _MIN_ROWS:
        return None
    ok &= np.abs(norm / np.median(norm[ok]) - 1.0) < 0.05
    if np.count_nonzero(ok) < _MIN_ROWS:
        return None
    u = a[ok] / norm[ok, None]
    c = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)
    b = b[ok]
    expected = None if site_dip_deg is None or abs(site_dip_deg) < MIN_SIGNED_DIP_DEG else np.sign(site_dip_deg)
    diverse = 1.0 - float(np.linalg.norm(u.mean(axis=0))) >= _MIN_DIVERSITY
    # a pattern and its opposite read one spread with opposite dips (above): half the patterns are computed
    half = {s: _dips(u, (b * np.array(s, dtype=float)) @ c.T, (1, 1, 1)) for s in product((1, -1), repeat=3) if s[0] > 0}
    results = {s: half[s] if s[0] > 0 else (-half[tuple(-v for v in s)][0], half[tuple(-v for v in s)][1])
               for s in product((1, -1), repeat=3)}
    dip0, spread0 = results[(1, 1, 1)]
    right = min((r[1] for r in results.values() if np.sign(r[0]) == (1.0 if expected is None else expected)), default=np.inf)
    if spread0 <= _GAIN * right or not diverse:  # no pattern does much better than the readings as they are
        if spread0 > _CONSISTENT_DEG:
            return None
        if expected is None and note_upward and dip0 <= -MIN_SIGNED_DIP_DEG:
            expected, site_dip_deg = 1.0, None
        elif expected is None or np.sign(dip0) == expected or abs(dip0) < MIN_SIGNED_DIP_DEG:
            return None
        # consistent, but pointing the wrong way for the site: a reflection, with the rotation as it is (a
        # level swing: the pattern alone turns the dip) or with the best rotation a half turn (then the axis
        # whose reflection leaves the smallest turn -C D between the chips: nearly aligned on most boards)
        improper = [p for p in results if sum(v < 0 for v in p) == 1]  # all three reversed: the --accel-sign below
        fits = [p for p in improper if np.sign(results[p][0]) == expected and results[p][1] <= _CONSISTENT_DEG]
        if fits:
            signs, apart = min(fits, key=lambda p: results[p][1]), ""
        else:
            turns = {p: _angle_deg(-c @ np.diag(np.array(p, dtype=float))) for p in improper}
            signs = min(turns, key=turns.get)
            apart = f"; the reversal that leaves the chips {turns[signs]:.0f} deg apart"
        where = ("; right in the southern hemisphere (give --site to decide); in the northern" if site_dip_deg is None
                 else f" where the site's points {'down' if expected > 0 else 'up'} ({site_dip_deg:+.1f} deg)")
        text = (f"the field points {'up' if dip0 < 0 else 'down'} (dip {dip0:+.1f} deg){where}: the magnetometer's "
                f"axes are left-handed against the accelerometer's; negate {_negate(signs, names)} ({_columns(signs, names)}"
                f"{apart}), or, if the "
                "accelerometer reads gravity as down, --accel-sign -1")
        return AxisVerdict(signs, True, -dip0, spread0, dip0, spread0, text)
    # without a site the northern reading comes first and its mirror (the southern) is named beside it
    candidates = {s: r for s, r in results.items() if np.sign(r[0]) == (1.0 if expected is None else expected)}
    best = min(candidates, key=lambda s: candidates[s][1])
    dip, spread = candidates[best]
    if not (spread * _GAIN < spread0 and spread <= _CONSISTENT_DEG):
        return None
    left = int(np.prod(best)) < 0
    what = (f"the field-gravity angle wanders with the orientation (dip {dip0:+.1f} deg, spread {spread0:.1f} deg); "
            f"with {_negate(best, names)} negated it is consistent (dip {dip:+.1f}, spread {spread:.1f} deg): "
            + ("the magnetometer's axes are left-handed against the accelerometer's" if left else
               "the magnetometer is turned half a turn against the accelerometer"))
    fix = f"negate {_negate(best, names)} ({_columns(best, names)})"
    if expected is None:
        mirror = tuple(-s for s in best)
        other = (f"; or, if the site is in the {'southern' if dip > 0 else 'northern'} hemisphere, negate "
                 f"{_negate(mirror, names)}" if any(s < 0 for s in mirror) else
                 f"; or, if the site is in the {'southern' if dip > 0 else 'northern'} hemisphere, the readings are right")
        fix += other + " (give --site to decide)"
    return AxisVerdict(best, left, dip, spread, dip0, spread0, f"{what}; {fix}")


def _columns(signs, names) -> str:
    """The ``--columns`` option that negates the axes of ``signs`` (COLUMN: the file's name)."""
    return ("--columns " + ",".join(f"{n}=-COLUMN" for s, n in zip(signs, names) if s < 0)
            + ", COLUMN its name in your file; or the accelerometer's same axis, if it is the one reversed")


def _angle_deg(matrix: np.ndarray) -> float:
    """Rotation angle of a 3x3 (proper) rotation matrix, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(matrix) - 1.0) / 2.0, -1.0, 1.0))))
