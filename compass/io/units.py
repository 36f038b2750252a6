"""Units of a recording's columns: named, converted, and checked against the physics.

SPEC section 2 fixes few units (``t_s`` seconds, ``*_deg`` degrees, ``gx,gy,gz`` rad/s, the
accelerometer "any unit" but reading specific force, +1 g up for a level housing at rest) and
leaves the magnetic channels free.  Real logs bring deg/s gyros, m/s^2 accelerometers, gauss
magnetometers and radians.  This module converts what the user (``--gyro-unit``,
``--accel-unit``, ``--mag-unit``, ``--angle-unit``, ``--accel-sign``) or the log's own header
(``Gyroscope X (deg/s)``) names, and checks the assumptions that can be checked from the data,
with a :class:`RecordingWarning` that says what was seen and which option names the unit:

- a gyro in deg/s read as rad/s turns 57 times more than the accelerometer sees the housing turn
  (:func:`gyro_turn_ratio`);
- a magnetometer in uT reads Earth's 25-65 uT (:func:`check_field_norm`);
- angles in degrees that never leave 0..2*pi are radians (:func:`looks_like_radians`);
- an accelerometer that reads -1 g on Z while the recording starts at rest (:func:`check_accel_up`);
- a two-axis tilt sensor cannot tell upright from upside down (:func:`check_two_axis_tilt`).

A warning never changes the data: the user names the unit and runs again.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["RecordingWarning", "GYRO_UNITS", "ACCEL_UNITS", "MAG_UNITS", "ANGLE_UNITS", "STANDARD_GRAVITY",
           "EARTH_FIELD_UT", "MAX_ABS_VALUE", "MIN_SPAN", "unit_of_header", "gyro_turn_ratio", "GYRO_UNIT_RATIO",
           "gyro_field_ratio", "FIELD_UNIT_RATIO", "FIELD_TURN_WINDOW_S", "FIELD_SMOOTH_S",
           "gyro_unit_verdict", "stuck_gyro_words", "check_gyro_unit",
           "check_field_norm", "looks_like_radians", "check_accel_up", "check_two_axis_tilt", "note", "gyro_fault_words"]

STANDARD_GRAVITY = 9.80665
"""m/s^2 per g."""
GYRO_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0}
"""Gyro units and their factor to rad/s (SPEC's unit)."""
ACCEL_UNITS = {"g": 1.0, "m/s2": 1.0 / STANDARD_GRAVITY}
"""Accelerometer units and their factor to g."""
MAG_UNITS = {"uT": 1.0, "nT": 1e-3, "G": 100.0, "mG": 0.1}
"""Magnetometer units and their factor to uT."""
ANGLE_UNITS = {"deg": 1.0, "rad": 180.0 / np.pi}
"""Units of the ``*_deg`` columns and their factor to degrees."""
EARTH_FIELD_UT = (25.0, 65.0)
"""The Earth's field strength at the surface, uT (World Magnetic Model: 22-67 at the extremes)."""
MAX_ABS_VALUE = 1e12
"""Largest magnitude a recording's cell may have.  No sensor output, time or angle reaches it in
any unit: a 32-bit ADC counts to 4.3e9, the strongest steady laboratory field (45 T) is 4.5e10 nT,
and a Unix time in seconds is 1.8e9.  A larger value is a corrupted cell (or a time in ns), and
its square would already lose the precision every fit needs."""

MIN_SPAN = 1e-12
"""Smallest change a magnetic or tilt channel must show over a recording.  No sensor's turn is
smaller in any unit (1 pT is a SQUID's noise; a tilt of 1e-12 rad is nothing); a channel of
values near 1e-300 is a unit mistake or a dead sensor, and its squares underflow in every fit."""

_UNIT_SPELLINGS = {
    "gyro": {"rad/s": "rad/s", "rads": "rad/s", "rad/sec": "rad/s", "deg/s": "deg/s", "dps": "deg/s",
             "deg/sec": "deg/s", "°/s": "deg/s"},
    "accel": {"g": "g", "m/s2": "m/s2", "m/s^2": "m/s2", "m/s²": "m/s2", "mps2": "m/s2"},
    "mag": {"ut": "uT", "µt": "uT", "μt": "uT", "nt": "nT", "g": "G", "gauss": "G", "mg": "mG", "mgauss": "mG"},
}


class RecordingWarning(UserWarning):
    """Something in a recording the user should know: a unit that looks wrong, a column ignored.

    The command line prints each as one line ``compass CMD: warning: ...`` on stderr.
    """


def note(message: str) -> None:
    """Issue a :class:`RecordingWarning` (attributed to the caller's caller)."""
    warnings.warn(message, RecordingWarning, stacklevel=3)


def unit_of_header(kind: str, text: str) -> str | None:
    """The unit a log's header names for a sensor (``"deg/s"`` from ``"Gyroscope X (deg/s)"``'s
    ``"deg/s"``), None when it is not one of ours (``a.u.``, counts)."""
    key = text.strip().replace(" ", "")
    spellings = _UNIT_SPELLINGS[kind]
    return spellings.get(key if kind == "accel" else key.lower(), spellings.get(key))


def gyro_turn_ratio(t_s, gyro_rad_s, accel, *, window_s: float = 0.25, min_tilt_deg: float = 5.0) -> float | None:
    """How much more the gyro says the housing turned than the accelerometer saw it tilt.

    Over windows of ``window_s``, the integrated angular rate ``|sum(omega dt)|`` (the rotation
    angle, exact for a fixed axis, to second order otherwise) is at least the angle between the
    accelerometer's directions at the two ends (a turn about the vertical tilts nothing), and on a
    hand-moved housing not many times more.  A gyro in deg/s read as rad/s gives about 57.3, one in
    rad/s read as deg/s about 1/57.3.

    Parameters
    ----------
    t_s : ndarray, shape (n,)
        Non-decreasing time, s.
    gyro_rad_s : ndarray, shape (n, 3)
        Angular rate in the unit assumed (rad/s).
    accel : ndarray, shape (n, 3)
        Accelerometer, any unit.
    window_s : float
    min_tilt_deg : float
        Windows where the accelerometer turns less are not used (noise and hand acceleration).

    Returns
    -------
    float or None
        The median ratio over the windows where the housing tilted (both ends quasi-static, within
        5 % of the median ``|a|``), None when fewer than 5 such windows exist.
    """
    t_s, gyro, accel = (np.asarray(a, dtype=float) for a in (t_s, gyro_rad_s, accel))
    if len(t_s) < 3 or not t_s[-1] > t_s[0]:
        return None
    dt = np.diff(t_s, prepend=t_s[0])
    turned = np.cumsum(gyro * dt[:, None], axis=0)
    norm = np.linalg.norm(accel, axis=1)
    still = np.abs(norm - np.median(norm)) < 0.05 * np.median(norm)
    end = np.searchsorted(t_s, t_s + window_s)
    start = np.flatnonzero((end < len(t_s)) & still)
    start = start[still[end[start]]]
    if start.size == 0:
        return None
    stop = end[start]
    unit = accel / np.where(norm > 0, norm, 1.0)[:, None]
    tilt = np.degrees(np.arccos(np.clip(np.sum(unit[start] * unit[stop], axis=1), -1.0, 1.0)))
    turn = np.degrees(np.linalg.norm(turned[stop] - turned[start], axis=1))
    used = tilt > min_tilt_deg
    if np.count_nonzero(used) < 5:
        return None
    return float(np.median(turn[used] / tilt[used]))


FIELD_TURN_WINDOW_S = 1.0
""":func:`gyro_field_ratio`'s windows, s: a hand's slow turn (20 deg/s) moves the field by 10 deg in them at a dip of
60 deg, over the 5 deg a window needs."""
FIELD_SMOOTH_S = 0.05
"""The field is averaged over this long before :func:`gyro_field_ratio` reads its turn, s (BROAD's 0.7 uT of noise on
41 uT turns a still field by 1-4 deg from one sample to another a second later)."""
FIELD_UNIT_RATIO = 25.0
"""A gyro that turns this many times more than the field (:func:`gyro_field_ratio`) reads in another unit: on
BROAD's 14 trials the honest ratio over a whole trial is 1.1-2.2, 5.4 with a magnet in the room (``python
tools/bench_runtime_checks.py``); a deg/s gyro read as rad/s gives 57 times that (the field turns less than the
housing about an axis near it)."""


def gyro_field_ratio(t_s, gyro_rad_s, field) -> float | None:
    """:func:`gyro_turn_ratio` with the field in place of the accelerometer: how much more the gyro says the housing
    turned than the field turned with it, over :data:`FIELD_TURN_WINDOW_S` windows, the field averaged over
    :data:`FIELD_SMOOTH_S` first; rows not finite left out.  A housing turned about the vertical, or slowly, tilts
    the accelerometer by too little to judge, but turns the field (by ``cos(dip)`` of the turn about the vertical).

    Parameters
    ----------
    t_s : ndarray, shape (n,)
        Non-decreasing time, s.
    gyro_rad_s : ndarray, shape (n, 3)
        Angular rate in the unit assumed (rad/s).
    field : ndarray, shape (n, 3)
        The calibrated field in the housing frame, any unit.

    Returns
    -------
    float or None
        The median ratio (:func:`gyro_turn_ratio`), None when too few windows turned the field.
    """
    from scipy.ndimage import uniform_filter1d

    t, gyro, field = (np.asarray(a, dtype=float) for a in (t_s, gyro_rad_s, field))
    sent = np.all(np.isfinite(field), axis=1) & np.all(np.isfinite(gyro), axis=1) & np.isfinite(t)
    t, gyro, field = t[sent], gyro[sent], field[sent]
    if len(t) < 3 or not t[-1] > t[0]:
        return None
    block = max(1, int(round(FIELD_SMOOTH_S * (len(t) - 1) / (t[-1] - t[0]))))
    field = uniform_filter1d(field, block, axis=0)  # a still field's noise alone tilts it by degrees
    return gyro_turn_ratio(t, gyro, field, window_s=FIELD_TURN_WINDOW_S)


GYRO_UNIT_RATIO = 15.0
"""A gyro that turns this many times more (or less) than the accelerometer sees the housing tilt is
read in the wrong unit: deg/s and rad/s are 57.3 apart, a hand-moved housing's honest ratio is near 1."""


def gyro_unit_verdict(ratio: float | None) -> str | None:
    """What a :func:`gyro_turn_ratio` says of the gyro's unit: the one verdict every reader of a gyro gives.

    Returns
    -------
    {"more", "less"} or None
        ``"more"``: it turns over :data:`GYRO_UNIT_RATIO` times more than the tilt (a deg/s gyro read as
        rad/s); ``"less"``: that many times less (rad/s read as deg/s); None: the unit agrees, or
        no ratio (``None`` or NaN: the housing did not tilt enough to tell).
    """
    if ratio is None or not np.isfinite(ratio):
        return None
    if ratio > GYRO_UNIT_RATIO:
        return "more"
    if ratio < 1.0 / GYRO_UNIT_RATIO:
        return "less"
    return None


def gyro_fault_words(ratio: float | None, gyro_rad_s, *, named: bool, labelled_deg: bool = False) -> str | None:
    """Why a gyro would be fused wrong, judged on its turn against the accelerometer's tilt (``ratio``,
    :func:`gyro_turn_ratio`), in words after "the gyro read in UNIT"; None when it is fused as it is.

    Dead (every rate zero while the housing tilts), stuck at a rail (every rate one value off zero, its turn tens of
    times off the tilt, named unit or not: :func:`stuck_gyro_words`), or, its unit not given (``named`` false),
    turning tens of times more than the tilt (a deg/s gyro read as rad/s), or tens of times less where its label says
    deg/s (``labelled_deg``: a rad/s gyro so labelled).  A gyro that turns less with no unit named is not refused: a
    board still most of the time, its accelerometer jittering by degrees, reads so too.  The replay and ``compass
    live`` stop on the same words.

    Parameters
    ----------
    ratio : float or None
    gyro_rad_s : array_like, shape (n, 3)
        The rates judged (finite rows), in the unit assumed.
    named : bool
        The user named the gyro's unit.
    labelled_deg : bool
        The recording's header names deg/s.
    """
    gyro = np.asarray(gyro_rad_s, dtype=float).reshape(-1, 3)
    verdict = gyro_unit_verdict(ratio)
    dead = ratio == 0.0 and len(gyro) > 0 and bool(np.all(np.ptp(gyro, axis=0) == 0.0))
    stuck = "" if verdict is None else stuck_gyro_words(gyro)
    if verdict is None or (not dead and not stuck and (named or (verdict == "less" and not labelled_deg))):
        return None
    if dead:
        return ("never turns while the accelerometer sees the housing tilt: a dead gyro? (without gx,gy,gz columns "
                "the two-vector filter runs)")
    if stuck:  # no unit makes a constant rate turn as the housing does
        return (f"turns {max(ratio, 1 / ratio):.0f} times {'more' if verdict == 'more' else 'less'} than the "
                f"accelerometer sees the housing tilt{stuck} Without gx,gy,gz columns the two-vector filter runs")
    if verdict == "more":
        return (f"turns {ratio:.0f} times more than the accelerometer sees the housing tilt (a deg/s gyro gives 57): "
                "give --gyro-unit deg/s (or --gyro-unit rad/s if it really is)")
    return (f"turns {1 / ratio:.0f} times less than the accelerometer sees the housing tilt (a rad/s gyro read as "
            "deg/s gives 1/57): give --gyro-unit rad/s (or the unit it is in)")


def stuck_gyro_words(gyro_rad_s) -> str:
    """``"; it holds ... in every sample: a gyro stuck at a rail?"`` when every axis reads one value off zero
    throughout, else ``""``: the clause every reader of a gyro adds to a :func:`gyro_unit_verdict`.

    Only where the gyro's turn already disagrees with the accelerometer's tilt: a constant rate that agrees with it
    is a steady turn read without noise (a simulation's).  A turning gyro's noise changes its reading from sample to
    sample; one stuck at its full scale (disconnected, or a part that failed) turns tens of times more or less than
    the housing tilts, which alone would read as a unit taken for another.  All zeros is said as a dead gyro (a turn
    ratio of 0) by the callers.

    Parameters
    ----------
    gyro_rad_s : array_like, shape (n, 3)
        The rates judged, in the unit assumed.
    """
    gyro = np.asarray(gyro_rad_s, dtype=float).reshape(-1, 3)
    if len(gyro) < 2 or not np.any(gyro[0]) or not np.all(np.ptp(gyro, axis=0) == 0.0):
        return ""
    return (f"; it holds {', '.join(f'{v:.6g}' for v in gyro[0])} in every sample: a gyro stuck at a rail "
            "(disconnected, or a part that failed)?")


def check_gyro_unit(t_s, gyro_rad_s, accel, *, named: bool, where: str) -> float | None:
    """Warn when the gyro's turn does not match the accelerometer's (:func:`gyro_unit_verdict`).

    ``named``: the user or the file named the unit (the warning then says the name looks wrong).
    Returns the ratio.
    """
    ratio = gyro_turn_ratio(t_s, gyro_rad_s, accel)
    if ratio is None:
        return None
    source = "as named" if named else "SPEC's unit, the default"
    verdict = gyro_unit_verdict(ratio)
    if verdict == "more":
        note(f"{where}: the gyro gx,gy,gz read in rad/s ({source}) turns {ratio:.0f} times more than the "
             f"accelerometer sees the housing tilt (a deg/s gyro read as rad/s gives 57): if it is in deg/s, "
             f"say so with --gyro-unit deg/s{stuck_gyro_words(gyro_rad_s)}")
    elif ratio == 0.0:
        note(f"{where}: the gyro gx,gy,gz never turns while the accelerometer sees the housing tilt: a dead gyro?")
    elif verdict == "less":
        note(f"{where}: the gyro gx,gy,gz read in rad/s ({source}) turns {1 / ratio:.0f} times less than the "
             f"accelerometer sees the housing tilt (a rad/s gyro read as deg/s gives 1/57): if it is in rad/s, "
             f"say so with --gyro-unit rad/s{stuck_gyro_words(gyro_rad_s)}")
    return ratio


def check_field_norm(field_norm: float, unit: str | None, *, where: str, what: str) -> None:
    """Warn when a magnetometer's field strength is not the Earth's in the unit named.

    Parameters
    ----------
    field_norm : float
        The field strength the data give (e.g. a sphere fit's radius), in the recording's unit.
    unit : str or None
        The magnetometer unit named (``MAG_UNITS``), None when the unit is free.  When None, a
        strength of 0.25-0.65 (gauss) or 25000-65000 (nT) is pointed out, since naming the unit then
        gives results in uT.
    """
    lo, hi = EARTH_FIELD_UT
    if not np.isfinite(field_norm) or field_norm <= 0:
        return
    if unit is not None:
        ut = field_norm * MAG_UNITS[unit]
        if not 0.5 * lo <= ut <= 2.0 * hi:
            guesses = [u for u, f in MAG_UNITS.items() if u != unit and lo <= field_norm * f <= hi]
            hint = (f"; read in {guesses[0]} it is {field_norm * MAG_UNITS[guesses[0]]:.3g} uT, the Earth's: "
                    f"--mag-unit {guesses[0]}") if guesses else "; is the magnetometer unit right (--mag-unit)?"
            said = f"{field_norm:.3g} uT" if unit == "uT" else f"{field_norm:.3g} {unit} = {ut:.3g} uT"
            note(f"{where}: {what} is {said}, not the Earth's {lo:g}-{hi:g} uT{hint} (iron nearby or a coil also "
                 f"change it)")
        return
    for name in ("G", "mG", "nT"):
        if lo <= field_norm * MAG_UNITS[name] <= hi:
            note(f"{where}: {what} is {field_norm:.3g} in the recording's unit, the Earth's field if the unit is "
                 f"{name}: name it with --mag-unit {name} to get results in uT (the unit is free otherwise)")


def looks_like_radians(values) -> bool:
    """True when angles said to be in degrees never leave [-2*pi, 2*pi] but do vary.

    A turntable turned through a full circle in degrees leaves that interval; a few degrees of
    real motion stay inside it, so callers apply this to columns that must span more than 2*pi
    degrees when read correctly.
    """
    v = np.asarray(values, dtype=float)
    return bool(v.size and np.all(np.abs(v) <= 2 * np.pi + 1e-6) and np.ptp(v) > 0.5)


def check_accel_up(accel, rows, *, where: str, still_fraction: float = 0.05, min_rows: int = 10) -> None:
    """Warn when the accelerometer reads -1 g on Z while the recording starts at rest.

    SPEC: accelerometers read specific force, ``(0, 0, +1 g)`` for a level housing at rest.  A
    tumble or attitude recording usually starts with the housing lying still and face up; one
    that starts with ``az`` near ``-|a|`` either started upside down or reads gravity instead
    (or has Z pointing down, as FRD and NED boards do).  Only the start is tested: a tumble turns
    every face down later, legitimately.

    Parameters
    ----------
    accel : ndarray, shape (n, 3)
        As recorded (after any ``--accel-sign``), any unit.
    rows : ndarray of int, shape (n,)
        File line of every sample (for the message).
    """
    accel = np.asarray(accel, dtype=float)
    n = len(accel)
    head = max(min_rows, int(still_fraction * n))
    if n < min_rows:
        return
    a = accel[:head]
    norm = np.linalg.norm(a, axis=1)
    ref = np.median(np.linalg.norm(accel, axis=1))
    still = np.abs(norm - ref) < 0.05 * ref
    if np.count_nonzero(still) < min_rows // 2:
        return
    z = np.median(a[still, 2] / norm[still])
    if z < -0.9:
        az = float(np.median(a[still, 2]))
        note(f"{where}: the accelerometer reads az = {az:.3g} (|a| = {ref:.3g}) while still at the start "
             f"(rows {int(rows[0])}-{int(rows[head - 1])}); SPEC's accelerometer reads specific force, +1 g on +Z "
             f"for a level housing at rest. If the housing lay face up there, this one reads gravity or its Z axis "
             f"points down: negate ax,ay,az with --accel-sign -1, or, for a board whose Y and Z point right and down "
             f"(FRD), map both sensors with --columns ay=-ay,az=-az,my=-my,mz=-mz; if it really started upside "
             f"down, ignore this")


def check_two_axis_tilt(n_flipped: int, n_rows: int, *, where: str) -> None:
    """Say that a two-axis tilt sensor's ``az`` is assumed positive, and how many rows contradict it.

    ``n_flipped``: rows whose field agrees with the calibration only if the housing is upside down.
    """
    if n_flipped == 0:
        return
    note(f"{where}: the calibration's tilt sensor has two axes (ax, ay) and cannot tell an upright housing from "
         f"one upside down; az is assumed positive (upper side up), but in {n_flipped} of {n_rows} rows the field "
         f"fits the calibration only upside down: record az, or keep the housing upright")
