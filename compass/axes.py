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

**With a gyro** the axes need no calibration at all.  A constant field turns in the housing against the housing's
turn: between two rows ``a`` and ``b`` whose relative rotation the gyro gives as ``D`` (gyro frame, ``R_b = R_a D``),
a field ``v`` in the gyro's axes goes to ``D^T v``.  A magnetometer whose axes are ``Q`` of the gyro's (``m = h + Q v``,
``Q`` a signed permutation: a chip mounted turned or mirrored against the IMU, as MPU-9250's AK8963 reads the
IMU's ``(y, x, -z)``) then reads

.. math:: m_b - M m_a = (I - M) h, \\qquad M = Q D^T Q^T ,

linear in the hard iron ``h``.  Each signed permutation gets its least-squares ``h`` and misfit (rows
paired :data:`PAIR_TURN_DEG` apart, so the turn is far above the noise; soft iron and latency are a few per cent of
it); ``Q`` and ``-Q`` give the same ``M`` (a reversed field turns as the field does), so the gyro names a pair and the
field's dip sign (the accelerometer, and the site's hemisphere) picks one.  Unlike the accelerometer's test this one
works on a recording that covers a fraction of the sphere, before any fit: a robot path's 18 % with the MPU-9250's
axes calibrated "fine" and gave 114 deg of heading error.  :func:`axes_from_gyro` returns a verdict only when one
pair fits clearly better than the axes as read and than every other pair; it is used by the tumble
calibration and, on the first rows of a stream, by :class:`compass.live.LiveSession`.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import permutations, product

import numpy as np

__all__ = ["AxisVerdict", "GyroAxesVerdict", "accel_axes_from_gyro", "axes_from_gyro", "check_axes", "MIN_SIGNED_DIP_DEG", "PAIR_TURN_DEG",
           "signed_permutations", "turned_enough", "orientations"]

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


PAIR_TURN_DEG = 10.0
"""The gyro's turn between the two rows of a pair, degrees: a 45 uT field moves by 7.8 uT, ten times a low-cost
magnetometer's noise."""
PAIR_SPAN_S = 2.0
"""Longest time between the rows of a pair, s: a still housing's gyro bias (1 deg/s on a low-cost part) turns it
no more than a fifth of :data:`PAIR_TURN_DEG` meanwhile."""
_GYRO_GAIN = 1.5  # the axes named must fit this many times better than the axes as read, and than every other pair
_MIN_PAIRS = 20


@dataclass(frozen=True)
class GyroAxesVerdict:
    """What :func:`axes_from_gyro` found: the magnetometer's axes are not the gyro's.

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        ``Q``, a signed permutation: the magnetometer reads ``h + Q v`` for a field ``v`` in the gyro's axes (the one of
        ``Q``, ``-Q`` the field's dip sign picked; either, when nothing told it).
    left_handed : bool or None
        ``det Q = -1``: one (or three) of the magnetometer's axes reversed against the gyro's; None when the field's
        sign was not told (``Q`` and ``-Q`` differ in handedness).
    misfit, misfit_as_read, misfit_next : float
        RMS misfit of the turned field with ``Q``, with the axes as read, and with the next best pair, recording units.
    columns : str
        The remap as ``--columns NAME=COLUMN`` (a file's header: ``compass calibrate``, ``compass attitude``).
    cells : str
        The remap as ``compass live``'s positional ``--columns`` names the magnetometer's cells, in their order.
    finding : str
        What is wrong, in words.
    remap : str
        The remap in words: both forms, and what the field's sign rests on.
    """

    matrix: np.ndarray
    left_handed: bool | None
    misfit: float
    misfit_as_read: float
    misfit_next: float
    columns: str
    cells: str
    finding: str
    remap: str

    @property
    def text(self) -> str:
        """One line for a calibration: what is wrong and the remap, to be given to the runtime too."""
        return f"{self.finding}; read it in the gyro's axes: {self.remap}"


def signed_permutations() -> list[np.ndarray]:
    """The 48 signed permutation matrices (the identity first): every way three axes can be read as three others."""
    out = []
    for perm in permutations(range(3)):
        for signs in product((1.0, -1.0), repeat=3):
            q = np.zeros((3, 3))
            q[np.arange(3), perm] = signs
            out.append(q)
    return out


def orientations(turns_rad: np.ndarray):
    """``R_k = Exp(turn_0) ... Exp(turn_k)`` for every row (a ``Rotation`` of ``n``), the gyro's turns composed in
    order: a prefix product in ``log2 n`` vectorised steps (each ``R_i <- R_(i-k) R_i`` for ``i >= k``).

    Parameters
    ----------
    turns_rad : ndarray, shape (n, 3)
        The housing's turn from the row before to each row, rad, gyro frame (the first row's: from the start).
    """
    from scipy.spatial.transform import Rotation

    r, k = Rotation.from_rotvec(turns_rad), 1
    while k < len(r):
        r = Rotation.concatenate([r[:k], r[:-k] * r[k:]])
        k *= 2
    return r


def _turn_pairs(turns_rad: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows ``a < b`` in turn, each ``b`` the first row at least :data:`PAIR_TURN_DEG` from ``a`` (at most
    :data:`PAIR_SPAN_S` later; none there: the next ``a`` is the first row beyond), and ``D`` (shape (k, 3, 3)), the
    housing's turn from ``a`` to ``b`` in the gyro frame (``R_b = R_a D``)."""
    attitude = orientations(turns_rad)
    step = np.radians(PAIR_TURN_DEG)
    a, n, out_a, out_b = 0, len(turns_rad), [], []
    while a < n - 1:
        end = max(int(np.searchsorted(t_s, t_s[a] + PAIR_SPAN_S, side="right")), a + 1)
        turned = (attitude[a].inv() * attitude[a + 1:end]).magnitude() >= step if end > a + 1 else np.zeros(0, bool)
        if not turned.any():
            a = end
            continue
        b = a + 1 + int(np.argmax(turned))
        out_a.append(a)
        out_b.append(b)
        a = b
    ia, ib = np.array(out_a, dtype=int), np.array(out_b, dtype=int)
    turns = (attitude[ia].inv() * attitude[ib]).as_matrix() if len(ia) else np.zeros((0, 3, 3))
    return ia, ib, turns


def turned_enough(turns_rad, t_s) -> bool:
    """Whether the housing turned enough for the axis checks (:func:`axes_from_gyro`, :func:`accel_axes_from_gyro`):
    at least their fewest row pairs :data:`PAIR_TURN_DEG` apart.  A housing at rest, or turned more slowly than
    :data:`PAIR_TURN_DEG` in :data:`PAIR_SPAN_S`, gives them nothing to judge.

    Parameters
    ----------
    turns_rad : array_like, shape (n, 3)
        The housing's turn from the row before to each row, rad, gyro frame; a turn not finite is taken as none.
    t_s : array_like, shape (n,)
        The rows' times, s, non-decreasing.
    """
    turns = np.asarray(turns_rad, dtype=float)
    ia, _, _ = _turn_pairs(np.where(np.isfinite(turns), turns, 0.0), np.asarray(t_s, dtype=float))
    return len(ia) >= _MIN_PAIRS


def _misfit(q: np.ndarray, m_a: np.ndarray, m_b: np.ndarray, turns: np.ndarray) -> tuple[float, np.ndarray]:
    """RMS misfit (recording units) of ``m_b - M m_a = (I - M) h`` with ``M = Q D^T Q^T``, and the least-squares
    ``h``."""
    m = np.einsum("ij,nkj,lk->nil", q, turns, q)  # Q D^T Q^T
    design = (np.eye(3) - m).reshape(-1, 3)
    target = (m_b - np.einsum("nij,nj->ni", m, m_a)).reshape(-1)
    h = np.linalg.lstsq(design, target, rcond=None)[0]
    return float(np.sqrt(np.mean((target - design @ h) ** 2))), h


def axes_from_gyro(mag, turns_rad, t_s, *, up=None, site_dip_deg: float | None = None,
                   names=("mx", "my", "mz")) -> GyroAxesVerdict | None:
    """The magnetometer's axes against the gyro's, from the gyro's turns between rows (see the module).

    Each of the 24 signed permutations ``Q`` with a positive first row (``-Q`` fits alike) gets the least-squares
    hard iron and misfit of ``m_b - Q D^T Q^T m_a = (I - Q D^T Q^T) h`` over row pairs :data:`PAIR_TURN_DEG` apart.

    Parameters
    ----------
    mag : array_like, shape (n, 3)
        Raw magnetometer (any unit, any hard iron), its axes as read; rows not finite are left out (their turn kept).
    turns_rad : array_like, shape (n, 3)
        The housing's turn from the row before to each row, rad, gyro frame (:func:`compass.io.tumble.gyro_turns`);
        a turn not finite is taken as none.
    t_s : array_like, shape (n,)
        The rows' times, s, non-decreasing.
    up : array_like, shape (n, 3), optional
        The accelerometer at the rows (gyro frame, any unit, +1 g up at rest): its dip sign picks ``Q`` or ``-Q``.
    site_dip_deg : float, optional
        The site's dip: its sign is the field's (judged for ``|dip| >= 10 deg``); default the northern hemisphere's.
    names : tuple of 3 str
        The magnetometer's axes' names for the words.

    Returns
    -------
    GyroAxesVerdict or None
        None when the axes as read fit best, when the best pair does not fit :data:`_GYRO_GAIN` times better than
        the axes as read and than every other pair (a housing turned about one axis leaves pairs tied), or with
        fewer than 20 pairs.
    """
    m = np.asarray(mag, dtype=float)
    found = _fits(m, turns_rad, t_s, np.ones(len(m), dtype=bool))
    clear = None if found is None else _clear_best(found[0])
    if clear is None:
        return None
    (best_q, _, best, h), as_read, following = clear
    m = m[found[1]]
    up = None if up is None else np.asarray(up, dtype=float)[found[1]]
    q, told, sign_words = _dip_sign(best_q, m - h, up, site_dip_deg, names)
    left = bool(np.linalg.det(q) < 0) if told else None
    how = {True: "mirrored against the gyro (left-handed)", False: "mounted turned against the gyro",
           None: "mounted turned or mirrored against the gyro (the field's sign, not told here, decides which)"}[left]
    finding = (f"the magnetometer's axes are not the gyro's: the field turns as the gyro says only with "
               f"{_read_as(q, names)} (misfit {best:.3g} against {as_read:.3g} as read), so the magnetometer is {how}")
    columns, cells = _remap(q, names), _cells(q, names)
    remap = (f"compass calibrate and compass attitude {columns} (COLUMN(name): the file's column now read as name), "
             f"compass live --columns naming the magnetometer's cells {cells} in their order{sign_words}")
    return GyroAxesVerdict(q, left, best, as_read, following, columns, cells, finding, remap)


def _fits(vectors: np.ndarray, turns_rad, t_s, usable: np.ndarray, turn_signs=(1.0,)):
    """Every signed-permutation pair's (first row's sum positive) fit of a vector sensor's readings (a constant
    vector in the world plus an offset) turned as the gyro's turns (times each of ``turn_signs``) say, over the
    ``usable`` finite rows paired :data:`PAIR_TURN_DEG` apart: ``([(Q, turn sign, misfit, offset), ...] best first,
    rows used)``, or None with fewer than :data:`_MIN_PAIRS` pairs."""
    turns = np.asarray(turns_rad, dtype=float)
    t = np.asarray(t_s, dtype=float)
    rows = np.flatnonzero(np.all(np.isfinite(vectors), axis=1) & np.isfinite(t) & usable)
    if len(rows) < _MIN_PAIRS:
        return None
    turned = np.cumsum(np.where(np.isfinite(turns), turns, 0.0), axis=0)
    kept = np.zeros((len(rows), 3))
    kept[1:] = turned[rows[1:]] - turned[rows[:-1]]  # a row left out still turned the housing
    v, t = vectors[rows], t[rows]
    fits = []
    for sign in turn_signs:
        ia, ib, d = _turn_pairs(sign * kept, t)
        if len(ia) < _MIN_PAIRS:
            return None
        fits += [(q, sign, *_misfit(q, v[ia], v[ib], d)) for q in signed_permutations() if q[0].sum() > 0]
    return sorted(fits, key=lambda f: f[2]), rows


def _clear_best(fits):
    """The best fit when it is not the axes as read and fits :data:`_GYRO_GAIN` times better than they and every
    other pair; else None.  Returns ``(best fit, misfit as read, next misfit)``."""
    as_read = next(f[2] for f in fits if np.array_equal(f[0], np.eye(3)) and f[1] > 0)
    best, following = fits[0], fits[1][2]
    if (np.array_equal(best[0], np.eye(3)) and best[1] > 0) or not (as_read >= _GYRO_GAIN * best[2]
                                                                     and following >= _GYRO_GAIN * best[2]):
        return None
    return best, as_read, following


def accel_axes_from_gyro(accel, turns_rad, t_s, *, names=("ax", "ay", "az")) -> str | None:
    """Words when the accelerometer's axes are not the gyro's (one of them has an axis reversed, or two swapped:
    a board's wiring, a column mapped wrong), None otherwise.

    Gravity is a constant vector in the world, so on rows where the specific force is gravity alone (``|a|`` within
    2 % of its median: a hand's or a robot's acceleration mostly leaves it) the accelerometer turns as the field
    does in :func:`axes_from_gyro`, with its offset for the hard iron.  Negating all three axes turns it alike
    (gravity read as down), so the pair named is up to that sign.  A gyro with one axis reversed (left-handed)
    turns every rotation backwards (``Exp(S w) = S Exp(-w) S`` for a reflection ``S``), which no reading of the
    accelerometer's axes undoes: the gyro's turns negated are tried too.

    Parameters
    ----------
    accel : array_like, shape (n, 3)
        The accelerometer, any unit, its axes as read; rows not finite are left out.
    turns_rad, t_s : array_like
        As :func:`axes_from_gyro`'s.
    names : tuple of 3 str
        The accelerometer's axes' names for the words.
    """
    a = np.asarray(accel, dtype=float)
    norm = np.linalg.norm(a, axis=1)
    if not np.isfinite(norm).any():  # no accelerometer in the stream
        return None
    with np.errstate(invalid="ignore"):
        still = np.abs(norm / np.nanmedian(norm) - 1.0) < _STILL_SHARE
    found = _fits(a, turns_rad, t_s, still, turn_signs=(1.0, -1.0))
    clear = None if found is None else _clear_best(found[0])
    if clear is None:
        return None
    (q, sign, best, _), as_read, _ = clear
    turned = "" if sign > 0 else "the gyro's turns reversed and "
    return (f"the accelerometer's axes are not the gyro's: gravity turns as the gyro says only with {turned}"
            f"{_read_as(q, names)} (misfit {best:.3g} against {as_read:.3g} as read; or every accelerometer sign "
            f"turned): an axis of the accelerometer or of the gyro is reversed, or two swapped, and the attitude is "
            f"wrong; check the columns' order and signs")


_STILL_SHARE = 0.02
"""Rows whose specific force is within this share of its median size are taken as gravity alone
(:func:`accel_axes_from_gyro`)."""


def _dip_sign(q: np.ndarray, centred: np.ndarray, up, site_dip_deg, names) -> tuple[np.ndarray, bool, str]:
    """``Q`` or ``-Q``, whichever gives the field the dip sign expected (the site's, else down); whether the readings
    told it; words for what the choice rests on."""
    dip = 0.0
    if up is not None:
        v = centred @ q  # Q^T m per row: the field in the gyro's axes
        with np.errstate(invalid="ignore", divide="ignore"):
            sine = -np.einsum("ij,ij->i", up, v) / (np.linalg.norm(up, axis=1) * np.linalg.norm(v, axis=1))
        sine = sine[np.isfinite(sine)]
        dip = float(np.degrees(np.arcsin(np.clip(np.median(sine), -1.0, 1.0)))) if len(sine) else 0.0
    if abs(dip) < MIN_SIGNED_DIP_DEG:
        return q, False, (" (the readings do not say which way the field points: if the heading reads 180 deg off, "
                          "every sign in the remap turned)")
    known = site_dip_deg is not None and abs(site_dip_deg) >= MIN_SIGNED_DIP_DEG
    chosen = q if np.sign(dip) == (np.sign(site_dip_deg) if known else 1.0) else -q
    where = "" if known else (" (the field taken to point down, as north of the magnetic equator; south of it, every "
                              "sign in the remap turned, or give the site: # site_lat_deg, # site_lon_deg and # date "
                              "lines in a file, --site to compass live)")
    return chosen, True, (f"{where}; an accelerometer that reads gravity as down (as read) turns the pick: then every "
                          "sign in the remap turned is right, or read the accelerometer negated (--accel-sign -1; "
                          "compass live: -ax,-ay,-az in --columns)")


def _remap(q: np.ndarray, names) -> str:
    """The ``--columns NAME=COLUMN`` option that reads the magnetometer in the gyro's axes: ``v = Q^T m``."""
    parts = []
    for j in range(3):
        i = int(np.argmax(np.abs(q[:, j])))
        parts.append(f"{names[j]}={'-' if q[i, j] < 0 else ''}COLUMN({names[i]})")
    return "--columns " + ",".join(parts)


def _cells(q: np.ndarray, names) -> str:
    """The names of the magnetometer's cells, in their order, that read it in the gyro's axes (cell ``i`` reads
    ``Q_ij v_j``)."""
    return ",".join(f"{'-' if q[i].sum() < 0 else ''}{names[int(np.argmax(np.abs(q[i])))]}" for i in range(3))


def _read_as(q: np.ndarray, names) -> str:
    """``Q`` in words: which of the gyro's axes each magnetometer axis reads."""
    parts = []
    for i in range(3):
        j = int(np.argmax(np.abs(q[i])))
        parts.append(f"{names[i]} read as the gyro's {'+' if q[i, j] > 0 else '-'}{'xyz'[j]}")
    return ", ".join(parts)
