"""One decoder for every command that reads a module's stream: its format, its units, their checks.

``compass live``, ``live --calibrate tumble`` and ``compass bench`` read a port through
:class:`StreamDecoder`, which speaks three formats (``--format``):

- ``compass``: the toolkit's line protocol, a header naming the columns (:mod:`compass.io.lines`);
- ``motioncal``: the ``Raw:``/``Uni:`` lines the PJRC and Adafruit calibration sketches print for
  MotionCal (:mod:`compass.io.motioncal`, :class:`compass.io.fixed_lines.MotionCalDecoder`);
- ``csv``: bare numbers without a header, their cells named by ``--columns``
  (:class:`compass.io.fixed_lines.CsvDecoder`);

and ``auto`` (the default) tells them apart from the first lines: ``Raw:``, ``Uni:``, ``Cal1:`` or
``Cal2:`` is MotionCal, a log's header (x-io's ``Time (s),Gyroscope X (deg/s),...``) is a CSV whose columns and
units it names, a line naming protocol columns is ours, and bare numbers with no header in
the first seconds are a CSV that needs ``--columns`` (said, the session ends).  ``--columns`` alone
means ``csv``.  The format found is stated as an event and in :meth:`StreamDecoder.describe`.

Units
-----
A unit named for the stream (``--mag-unit``, ``--accel-unit``, ``--gyro-unit``, the same names as
the file readers', :mod:`compass.io.units`) is converted as the file readers convert a recording's:
field to uT, accelerometer to g, gyro to rad/s.  MotionCal's units are fixed by its format (uT, g,
rad/s after its scaling), so naming them is refused.  Unnamed, our protocol's and a CSV's field is in
the calibration's output unit, the accelerometer in any unit, the gyro in rad/s (SPEC).

Checks, like the file readers' (a check never changes the data):

- the field against the calibration (``field_check``, :func:`field_scale_check`): the first
  :data:`JUDGE_SAMPLES` samples are held until the calibration's field of them has the calibration's
  |B|, or differs from it by a unit's factor (a stream in mG against a calibration in uT reads ten
  times too strong): the samples are then held until the housing turned (:func:`housing_turned`, at most
  :data:`UNIT_HOLD_SAMPLES`), which tells a unit (the scaled field keeps its norm and turns with the housing) from
  another board's calibration, and :attr:`StreamDecoder.fatal` says which, with the factor; nothing is handed out
  (the command exits 2, the samples kept under ``--record``: :meth:`StreamDecoder.take_withheld`; a reference seeded
  from such samples made the heading go wrong silently).  A unit too small whose field is |B| all the same (gauss
  read as uT, a hard iron near |B|) stays put in the housing: the session tells it once the housing turns
  (:func:`fixed_field_words`, :attr:`compass.live.LiveSession.wrong_field`);
- an accelerometer whose unit is known reads about 1 g at rest (a warning event otherwise);
- the gyro turns as much as the accelerometer sees the housing tilt (:func:`compass.io.units.gyro_turn_ratio`:
  a deg/s gyro read as rad/s turns 57 times too much; a warning event), judged on the first 10 s window
  in which the housing tilts, within the first minute.

The decoder interface
---------------------
Every decoder here (the facade and the three it wraps) has ``feed(bytes) -> list[Sample]``,
``resync()``, ``stats`` (:class:`compass.io.lines.LineStats`), ``header`` (the
:class:`compass.io.lines.Header` the samples carry), ``mismatch``, ``events`` and ``drain_events()``;
the facade adds ``feed(bytes, t_rx)``, ``flush()`` (end of stream), ``fatal``, ``format`` and
``describe()``.  Samples are :class:`compass.io.lines.Sample`.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..sample_check import new_readings
from . import units
from .fixed_lines import CsvDecoder, MotionCalDecoder
from .lines import _GROUPS, _SCALARS, LineDecoder, LineStats, Sample
from .stream_options import EXAMPLE_COLUMNS, FORMATS, StreamOptions, add_stream_arguments
from .table import log_column_name

__all__ = ["FORMATS", "JUDGE_SAMPLES", "HELD_JUDGE_SAMPLES", "HELD_SHARE", "UNIT_HOLD_SAMPLES", "TURNED_DEG",
           "FIXED_SHARE", "TURN_SHARE", "NORM_SHARE", "MIN_TURNED_PAIRS", "StreamOptions", "StreamDecoder",
           "field_scale_check", "judge_field_unit", "gravity_pairs", "housing_turned", "turn_share", "norm_share",
           "field_unit_factor", "world_fixed_turn", "fixed_field_words", "unit_pairs", "time_steps_verdict",
           "held_field_words", "add_stream_arguments"]

JUDGE_SAMPLES = 25
"""Samples held while the field's unit is judged against the calibration (a quarter second at 100 Hz)."""
HELD_JUDGE_SAMPLES = 200
"""Samples whose magnetometer readings say how often it repeats the last one (:func:`held_field_words`)."""
HELD_SHARE = 0.2
"""Share of rows repeating the last magnetometer reading from which it is said (a working sensor's chance repeats
are about 1e-3 of rows)."""
_MOTIONCAL_TAGS = ("Raw:", "Uni:", "Cal1:", "Cal2:")
_AUTO_WAIT_S = 3.0  # bare numbers for this long without a header: a CSV without --columns
_AUTO_WAIT_LINES = 500  # the same when no receive time is given
_AUTO_MAX_BYTES = 1 << 18
_ACCEL_SAMPLES = 50
_GYRO_WINDOW_S = 10.0
_GYRO_WINDOWS = 6  # windows tried before the gyro check gives up (a module that lies still)


UNIT_HOLD_SAMPLES = 1000
"""Most samples held while a field a unit's factor would bring to |B| waits for the housing to turn (10 s at 100 Hz):
a unit taken for another and another board's calibration read alike until it does (:func:`field_scale_check`)."""
TURNED_DEG = 20.0
"""Gravity's turn in the housing between two quasi-static rows that shows the housing turned, deg.  A housing turned by
it moves a 50 uT field by 17 uT unless it turned about the field's own axis."""
FIXED_SHARE = 0.2
"""Median ratio of the field's turn in the housing to the turn the gyro gives a field fixed in the world, over pairs
of rows the housing turned :data:`TURNED_DEG` between, under which the field stays put in the housing: a field in its
calibration's unit turns as the gyro says (ratio about 1 at any dip, noise and the gyro's bias aside); one read in a
unit a factor ``k < 1`` too small is ``-W h`` plus ``k`` times the field, and turns ``k |B| / |W h|`` of that
(0.01-0.015 for gauss read as uT)."""
TURN_SHARE = 0.5
"""Median :func:`turn_share` from which a unit-scaled field turns with the housing as a calibrated one does: a tilt
about any horizontal axis turns a field of dip 60 deg by 0.87 of gravity's turn or more, a turn about the vertical by
more than gravity's; another board's calibration leaves a field whose turning part is a fraction of it (0.19 for
``tools/bench_field_unit.py``'s gain 1.5)."""
NORM_SHARE = 0.15
"""Median ratio, over pairs of rows the housing turned between (:func:`gravity_pairs`), of the change in a
unit-scaled field's norm to the change of the field itself, within which the unit explains the readings.  A
calibrated field keeps its norm while it turns: noise and the fit's residual (1 % of |B|) over a change of 0.3 |B|
or more give 0.03-0.06.  Another board's calibration leaves ``c + v``, a constant ``c`` and a part ``v`` that turns,
whose norm changes by ``|cos|`` of the angle between ``c`` and the change of ``v``: 0.5 for a random direction."""
_STILL_SHARE = 0.05  # |a| within this share of its median: a quasi-static row
_PAIR_ROWS = 150  # quasi-static rows (evenly spread) whose pairs are judged
MIN_TURNED_PAIRS = 20
"""Pairs of rows :data:`TURNED_DEG` apart that tell a field that turns from one that stays put."""
_UNIT_FACTORS = sorted({a / b for a in units.MAG_UNITS.values() for b in units.MAG_UNITS.values()} - {1.0})


def gravity_pairs(accel, *, min_deg: float = TURNED_DEG):
    """Pairs of quasi-static rows between which gravity turned by ``min_deg`` or more in the housing.

    Parameters
    ----------
    accel : array_like, shape (n, 3)
        Accelerometer, any unit; a row not finite, or whose ``|a|`` is not within 5 % of the median, is not used.
    min_deg : float

    Returns
    -------
    i, j : ndarray of int, shape (k,)
        Row indices, ``i < j``, of at most :data:`_PAIR_ROWS` rows evenly spread over the quasi-static ones.
    alpha_rad : ndarray, shape (k,)
        Gravity's turn between them, rad.
    """
    accel = np.asarray(accel, dtype=float).reshape(-1, 3)
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(accel, axis=1)
    usable = np.isfinite(norm) & (norm > 0.0)
    empty = np.zeros(0, dtype=int)
    if np.count_nonzero(usable) < 2:
        return empty, empty, np.zeros(0)
    middle = np.median(norm[usable])
    still = np.flatnonzero(usable & (np.abs(norm - middle) < _STILL_SHARE * middle))
    rows = np.unique(still[np.linspace(0, len(still) - 1, min(len(still), _PAIR_ROWS)).astype(int)]) if len(still) \
        else empty
    up = accel[rows] / norm[rows, None]
    alpha = np.arccos(np.clip(up @ up.T, -1.0, 1.0))
    i, j = np.nonzero(np.triu(alpha >= np.radians(min_deg), 1))
    return rows[i], rows[j], alpha[i, j]


def housing_turned(accel) -> bool:
    """Whether gravity turned by :data:`TURNED_DEG` in the housing between enough pairs of
    quasi-static rows of ``accel`` (shape (n, 3), any unit): :data:`MIN_TURNED_PAIRS`, enough to tell a field that
    turns from one that stays."""
    return len(gravity_pairs(accel)[0]) >= MIN_TURNED_PAIRS


def turn_share(field, i, j, alpha_rad) -> float:
    """Median ratio of the field's turn between rows ``i`` and ``j`` to a reference turn ``alpha_rad``: gravity's
    (:func:`gravity_pairs`), or the one the gyro gives a field fixed in the world (:data:`FIXED_SHARE` then tells a
    field that stays put in the housing).

    Parameters
    ----------
    field : array_like, shape (n, 3)
        The calibrated field in the housing frame, any unit.
    i, j, alpha_rad : ndarray, shape (k,)
        The pairs of rows and the reference turn between them, rad.
    """
    field = np.asarray(field, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        unit = field / np.linalg.norm(field, axis=1, keepdims=True)
    beta = np.arccos(np.clip(np.sum(unit[i] * unit[j], axis=1), -1.0, 1.0))
    share = beta / alpha_rad
    share = share[np.isfinite(share)]
    return float(np.median(share)) if share.size else math.nan


def _norms(model, raw: np.ndarray) -> np.ndarray:
    """``|B_H|`` of every row over the calibration's |B| (NaN where not finite)."""
    with np.errstate(over="ignore", invalid="ignore"):  # a factor of 1e5 on a wild reading
        fields, _ = model.field(raw)
        norms = np.linalg.norm(fields, axis=1) / float(model.field_norm)
    return np.where(np.isfinite(norms), norms, np.nan)


def _ratio(norms: np.ndarray) -> float:
    """The median of the finite ``norms`` (NaN without one)."""
    finite = norms[np.isfinite(norms)]
    return float(np.median(finite)) if finite.size else math.nan


def norm_share(field, i, j) -> float:
    """Median ratio of the change in the field's norm between rows ``i`` and ``j`` to the change of the field
    (:data:`NORM_SHARE`): near 0 for a field that keeps its norm while it turns.

    Parameters
    ----------
    field : array_like, shape (n, 3)
        The calibrated field in the housing frame, any unit.
    i, j : ndarray of int, shape (k,)
    """
    field = np.asarray(field, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        norms = np.linalg.norm(field, axis=1)
        share = np.abs(norms[i] - norms[j]) / np.linalg.norm(field[i] - field[j], axis=1)
    share = share[np.isfinite(share)]
    return float(np.median(share)) if share.size else math.nan


def unit_pairs(k: float) -> str:
    """``"mG taken as uT"``: the units of :data:`compass.io.units.MAG_UNITS` a factor ``k`` lies between."""
    return " or ".join(f"{a} taken as {b}" for a, fa in units.MAG_UNITS.items() for b, fb in units.MAG_UNITS.items()
                       if a != b and math.isclose(fa / fb, k))


def world_fixed_turn(field, i, turn) -> np.ndarray:
    """The turn of ``field[i]`` as a field fixed in the world, by the housing's turn ``turn`` (``R_j = R_i D``: it reads
    ``D^T field[i]`` at ``j``), rad, shape (k,): what an honest field turns by between the rows, at any dip.

    Parameters
    ----------
    field : array_like, shape (n, 3)
        The calibrated field in the housing frame, any unit.
    i : ndarray of int, shape (k,)
    turn : scipy.spatial.transform.Rotation, k rotations
        ``D``, the gyro's turn of the housing from each ``i`` to its pair.
    """
    v = np.asarray(field, dtype=float)[i]
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.sum(v * turn.inv().apply(v), axis=1) / np.sum(v * v, axis=1)
    return np.arccos(np.clip(np.nan_to_num(cosine, nan=1.0), -1.0, 1.0))


def field_unit_factor(model, raw, i, j, alpha_rad, turn=None) -> tuple[float, float, float] | None:
    """The unit factor between two of :data:`compass.io.units.MAG_UNITS` that explains the readings, None when none
    does.

    A factor explains them when the field of the readings scaled by it has the calibration's |B| (median within
    1.25), keeps its norm while the housing turns (:func:`norm_share` within :data:`NORM_SHARE`) and turns with it
    (:func:`turn_share` at least :data:`TURN_SHARE` of gravity's turn, or of its own :func:`world_fixed_turn` where the
    gyro's ``turn`` is given), over the pairs of rows the housing turned between.

    Parameters
    ----------
    model : compass.model.SensorModel
    raw : array_like, shape (n, c)
        The stream's channel values, as read.
    i, j, alpha_rad : ndarray, shape (k,)
        :func:`gravity_pairs`.
    turn : scipy.spatial.transform.Rotation, k rotations, optional
        The gyro's turn of the housing over each pair (then the reference turn, which gravity's is only where the
        field is far from the turn axis: at low dip a roll facing North turns it by ``sin(dip)`` of gravity's).

    Returns
    -------
    (k, ratio, norm_share) or None
        The factor, the scaled field's median |B_H| / |B| and its :func:`norm_share`; the best one.
    """
    raw = np.asarray(raw, dtype=float)
    fits = []
    for k in _UNIT_FACTORS:
        with np.errstate(over="ignore", invalid="ignore"):
            field = model.field(k * raw)[0]
        r = _ratio(np.linalg.norm(field, axis=1) / float(model.field_norm))
        if not (r > 0 and abs(math.log(r)) < math.log(1.25)):
            continue
        share = norm_share(field, i, j)
        reference = alpha_rad if turn is None else world_fixed_turn(field, i, turn)
        if share <= NORM_SHARE and turn_share(field, i, j, reference) >= TURN_SHARE:
            fits.append((abs(math.log(r)), k, r, share))
    return min(fits)[1:] if fits else None


def field_scale_check(model):
    """A ``field_check`` for :class:`StreamDecoder`: words when a stream's field is not the calibration's |B| but a
    unit's factor (10, 1000, 0.01, ...) would bring it there, None otherwise.

    Parameters
    ----------
    model : compass.model.SensorModel
        ``field(raw)`` gives the field in H in the calibration's field unit, whose magnitude is
        ``field_norm``.

    Returns
    -------
    callable
        ``check(raw, accel=None) -> str | None`` with ``raw`` of shape (n, c), the stream's channel values, and
        ``accel`` of shape (n, 3) its accelerometer (any unit) or None.

    Notes
    -----
    The median ``|B_H| / |B|`` of the first :data:`JUDGE_SAMPLES` rows is taken as is when within 1.5 of 1 (noise,
    a magnet nearby and the site's |B| stay within it; the filter's gate judges those): None.  Outside, the same
    ratio is computed with the readings scaled by each factor between two of :data:`compass.io.units.MAG_UNITS`;
    none within 1.25 of 1 (a strong magnet): None.  One within it is a unit taken for another only if it explains
    every row (:func:`field_unit_factor`), which the rows tell once the housing turned (:func:`housing_turned`):
    another board's calibration makes the scaled field's norm vary with the attitude.  Words either way: the unit
    to name, or that the calibration does not fit the board, or, the housing not turned, both.
    """
    magnitude = float(model.field_norm)
    unit = "uT" if model.field_ut is not None else "in the calibration's unit"

    def check(raw, accel=None) -> str | None:
        raw = np.asarray(raw, dtype=float)
        first = raw[:JUDGE_SAMPLES]
        r1 = _ratio(_norms(model, first))
        if math.isfinite(r1) and abs(math.log(r1)) <= math.log(1.5):
            return None
        near = [(abs(math.log(r)), k, r) for k in _UNIT_FACTORS for r in (_ratio(_norms(model, k * first)),)
                if math.isfinite(r) and r > 0 and abs(math.log(r)) < math.log(1.25)]
        if not near:
            return None
        said = f"the calibration makes this stream's field {r1:.3g} times its |B| ({magnitude:.4g} {unit})"
        pairs = None if accel is None else gravity_pairs(accel)
        if pairs is None or len(pairs[0]) < MIN_TURNED_PAIRS:  # not housing_turned: its pairs are used below
            _, k, r = min(near)
            return (f"{said}; scaled by {k:g} it would be {r:.3f} times: a unit taken for another "
                    f"({unit_pairs(k)}: --mag-unit names the stream's unit) or a calibration not this board's, which "
                    f"the module's turns tell apart: it did not turn by {TURNED_DEG:g} deg in its first {len(raw)} "
                    f"samples (turn it as the session starts)")
        fit = field_unit_factor(model, raw, *pairs)
        if fit is None:
            _, k, r = min(near)
            with np.errstate(over="ignore", invalid="ignore"):
                field = model.field(k * raw)[0]
            return (f"{said}; scaled by {k:g} ({unit_pairs(k)}) it would be {r:.3f} times, but as the module turns it "
                    f"turns {turn_share(field, *pairs):.2f} times as much as gravity and its norm changes by "
                    f"{norm_share(field, *pairs[:2]):.2f} of its change (a unit's turns {TURN_SHARE:g} times as "
                    f"much or more, its norm kept within {NORM_SHARE:g}): the calibration does not fit this board; "
                    f"is --cal this board's calibration?")
        k, r, share = fit
        return (f"{said}; scaled by {k:g} it would be {r:.3f} times, its norm kept as the module turns: the "
                f"stream's field is in another unit than the calibration's ({unit_pairs(k)}): name the stream's "
                f"unit with --mag-unit (converted to uT), or use a calibration made in the stream's unit")

    return check


def fixed_field_words(model, raw, i, j, alpha_rad, turn) -> str | None:
    """Words when the calibrated field stays put in the housing while the housing turns (a unit's factor ``k < 1``
    too small: it turns less than :data:`FIXED_SHARE` of what the gyro's turn gives a field fixed in the world),
    None when it turns with the housing.

    Parameters
    ----------
    model : compass.model.SensorModel
    raw : array_like, shape (n, c)
        The stream's channel values, as read.
    i, j, alpha_rad : ndarray, shape (k,)
        Pairs of rows between which the housing turned (:func:`gravity_pairs`, confirmed by the gyro), and gravity's
        turn between them, rad (the unit's factor is judged against it: :func:`field_unit_factor`).
    turn : scipy.spatial.transform.Rotation, k rotations
        The gyro's turn of the housing from ``i`` to ``j``: the field is judged against its :func:`world_fixed_turn`,
        what an honest field turns by at any dip (against gravity's turn, a roll about the field's own direction at
        low dip would read as a field that stays put).

    Notes
    -----
    Gauss read as uT with a hard iron ``|W h|`` near |B| passes :func:`field_scale_check`: the field read is about
    ``-W h``, of about the right norm, and fixed in the housing.  A correct stream whose ``|W h|`` is about |B| reads
    as near |B| scaled by 0.01, so only the turn tells them apart.  The factor named (:func:`field_unit_factor`) is
    the one that makes the field both of the calibration's |B| and turning; none: the calibration does not fit.
    """
    raw = np.asarray(raw, dtype=float)
    field = model.field(raw)[0]
    expected = world_fixed_turn(field, i, turn)
    share = turn_share(field, i, j, expected)
    if not share < FIXED_SHARE:
        return None
    turned = float(np.degrees(np.max(expected)))
    said = (f"the calibrated field turns {share:.3f} times what the gyro's turns give a field fixed in the world "
            f"(median over {len(i)} pairs of rows, up to {turned:.0f} deg; a field in the calibration's unit turns "
            f"about as much): it stays put in the housing")
    fit = field_unit_factor(model, raw, i, j, alpha_rad, turn)
    if fit is None:
        return (f"{said}, and no unit's factor makes it turn at the calibration's |B|: the calibration does not fit "
                f"this board (or a magnet on the housing outweighs the Earth's field); is --cal this board's "
                f"calibration?")
    k, r, _ = fit
    return (f"{said}; scaled by {k:g} it is {r:.3f} times the calibration's |B|, keeps it and turns with "
            f"the housing: the stream's field is in another unit than the calibration's ({unit_pairs(k)}): name the "
            f"stream's unit with --mag-unit (converted to uT), or use a calibration made in the stream's unit")


def judge_field_unit(check, raw, accel=None) -> str | None:
    """What :class:`StreamDecoder` says of a whole recording's field with ``check`` (:func:`field_scale_check`):
    judged on the first :data:`JUDGE_SAMPLES` rows, and while it has words on the first :data:`UNIT_HOLD_SAMPLES`
    in steps of :data:`JUDGE_SAMPLES` until the housing turned (:func:`housing_turned`).

    Parameters
    ----------
    raw : array_like, shape (n, c)
    accel : array_like, shape (n, 3), optional
    """
    raw = np.asarray(raw, dtype=float)
    n = min(JUDGE_SAMPLES, len(raw))
    while True:
        words = check(raw[:n], None if accel is None else accel[:n])
        if words is None or accel is None or n >= min(len(raw), UNIT_HOLD_SAMPLES) or housing_turned(accel[:n]):
            return words
        n = min(n + JUDGE_SAMPLES, len(raw), UNIT_HOLD_SAMPLES)


def time_steps_verdict(t_s, max_gap_s: float) -> str | None:
    """Words when the sample times ``t_s`` (s, shape (n,)) do not tell a filter the time between samples, None
    otherwise.

    Every value the same: the filter integrates no gyro and predicts nothing.  A median step over the filter's
    ``max_gap_s`` (s): each step is a gap that restarts it (a time in ms read as s steps 1000 times too far).
    Fewer than two times are not judged.
    """
    t_s = np.asarray(t_s, dtype=float)
    if len(t_s) < 2:
        return None
    if t_s.max() == t_s.min():
        return (f"t_s is {t_s[0]:g} in all {len(t_s)} samples: the filter integrates no gyro while it does not "
                "increase (t_s is each sample's time in seconds)")
    step = float(np.median(np.diff(t_s)))
    if step > max_gap_s:
        return (f"t_s steps by {step:g} s (median of {len(t_s)} samples): each step is a gap over the filter's "
                f"{max_gap_s:g} s and restarts it; a time in milliseconds? (t_s is in seconds)")
    return None


def held_field_words(raw, t_s=None) -> str | None:
    """Words when the magnetometer repeats its last reading on :data:`HELD_SHARE` of the rows or more (it converts
    slower than the stream sends), None otherwise.

    Parameters
    ----------
    raw : array_like, shape (n, c)
        The magnetometer's readings as sent, in order.
    t_s : array_like, shape (n,), optional
        Their times, s: the words then give both rates (median steps).
    """
    raw = np.asarray(raw, dtype=float)
    if len(raw) < 2:
        return None
    new = new_readings(raw)
    share = 1.0 - float(np.mean(new))
    if share < HELD_SHARE:
        return None
    rates = ""
    if t_s is not None and len(t_s) == len(raw) and np.count_nonzero(new) > 1:
        t_s = np.asarray(t_s, dtype=float)
        stream, magnetometer = np.median(np.diff(t_s)), np.median(np.diff(t_s[new]))
        if stream > 0.0 and magnetometer > 0.0:
            rates = f" (a new reading every {1e3 * magnetometer:.0f} ms, at {1.0 / stream:.0f} Hz rows)"
    return (f"the magnetometer repeats its last reading on {100 * share:.0f} % of the first {len(raw)} rows"
            f"{rates}: it converts slower than the stream; each reading is fused once, on the row it is new")


class StreamDecoder:
    """Decode a module's stream in any of :data:`FORMATS`, in the units named, with the checks of the module docstring.

    Parameters
    ----------
    channels : sequence of str
        The calibration's channel names (``("mx", "my", "mz")`` for a tumble).
    options : StreamOptions
    field_check : callable, optional
        ``check(raw (n, c), accel (n, 3) or None) -> str | None`` (:func:`field_scale_check`): the first
        :data:`JUDGE_SAMPLES` samples are held for it, and while it has words until the housing turned
        (:data:`UNIT_HOLD_SAMPLES` at most); words set :attr:`fatal`.
    unscaled : sequence of str
        Channels carried beside the field that ``--mag-unit`` leaves as sent (a turntable's encoder
        column, degrees).

    Attributes
    ----------
    stats : compass.io.lines.LineStats
        Shared with the format's decoder: lines dropped while the format was being found are counted too.
    format : str or None
        ``compass``, ``motioncal`` or ``csv`` once known.
    fatal : str or None
        Why the stream cannot be used (channels it lacks, a unit taken for another, bare numbers without
        ``--columns``), in words for a one-line error; the samples are then withheld.
    events : list of (str, str)

    Examples
    --------
    >>> d = StreamDecoder(("mx", "my", "mz"))
    >>> [s.raw.tolist() for s in d.feed(b"Uni:0.00,0.00,9.81,0.0000,0.0000,0.0000,20.00,0.00,-40.00\\r\\n")]
    [[20.0, 0.0, -40.0]]
    >>> d.format, d.describe()
    ('motioncal', 'MotionCal Uni: lines')
    """

    def __init__(self, channels, options: StreamOptions | None = None, *, field_check=None, unscaled=()):
        self.channels = tuple(channels)
        unknown = set(unscaled) - set(self.channels)
        if unknown:
            raise ValueError(f"unscaled channel(s) {', '.join(sorted(unknown))} are not among {', '.join(self.channels)}")
        self._field_unit = np.array([c not in set(unscaled) for c in self.channels])
        self.options = StreamOptions() if options is None else options
        self._given = self.options  # what the user said (a log header's units are taken where it said none)
        self.stats = LineStats()
        self.events: list = []
        self.format: str | None = None
        self._fatal: str | None = None
        self._inner = None
        self._pending = b""  # bytes read while the format is being found
        self._numeric_lines = 0
        self._seen = 0  # kept lines already counted
        self._first_numeric_t: float | None = None
        self._resynced = False
        self._cut_first = False  # the next complete line may be the tail of one (after a resync)
        self._check = field_check
        self._held: list = []
        self._judge_at = JUDGE_SAMPLES
        self._factors = (1.0, 1.0, 1.0)
        self._factors_before: dict = {}  # id(header) -> factors, of a chunk's samples read before a header came again
        self._accel_known = False
        self._accel: list = []
        self._gyro_rows: list = []
        self._gyro_judged = False
        self.gyro_unit_said = False  # the gyro's unit (or a dead gyro) said: from the accelerometer's tilt, or by its user
        self.gyro_unit_right = False  # the gyro turned as the accelerometer saw the housing tilt
        self.gyro_fault: str | None = None  # why the gyro would be fused wrong (units.gyro_fault_words): live stops
        self._gyro_windows = 0
        if self.options.requested != "auto":
            self._adopt(self.options.requested, "as named")

    # ----------------------------------------------------------------- the interface

    @property
    def header(self):
        """The header (or fixed columns) samples are decoded under; None before one is known."""
        return None if self._inner is None else self._inner.header

    @property
    def mismatch(self):
        """``(names, missing channels)`` of a stream that does not carry the calibration's channels."""
        return None if self._inner is None else self._inner.mismatch

    @property
    def echo(self) -> dict:
        """A MotionCal sketch's latest ``Cal1``/``Cal2`` echoes (empty for other formats)."""
        return getattr(self._inner, "echo", {})

    @property
    def fatal(self) -> str | None:
        """Why the stream cannot be used, in words (None while it can): the command ends on it (exit 2)."""
        if self._fatal is None and self.mismatch is not None:
            names, missing = self.mismatch
            if self.format == "compass":
                return f"the module's header {','.join(names)} lacks the calibration's channel(s) {','.join(missing)}"
            what = "--columns names" if self.format == "csv" else "MotionCal lines carry"
            return (f"{what} {','.join(names)}, not the calibration's channel(s) {','.join(missing)} (a tumble "
                    f"calibration's are mx,my,mz)")
        return self._fatal

    def describe(self) -> str:
        """The format in a few words, for the readout."""
        if self.format is None:
            return "format not known yet"
        if self.format == "motioncal":
            source = getattr(self._inner, "source", None)
            return f"MotionCal {source}: lines" if source else "MotionCal lines"
        if self.format == "csv":
            return f"csv {','.join(self.options.columns)}"
        return "compass line protocol"

    def drain_events(self) -> list:
        """Return and clear the pending ``(level, text)`` events."""
        events, self.events = self.events, []
        return events

    def resync(self) -> None:
        """After a (re)connect: the next line may be a fragment (see :meth:`LineDecoder.resync`)."""
        if self._inner is not None:
            self._inner.resync()
            return
        lines = self._pending.replace(b"\r", b"\n").split(b"\n")
        self.stats.unheaded += len(lines) - 1  # the bare-number lines kept: samples before any header
        self.stats.partial += bool(lines[-1])  # a line the (re)connect cut
        self._pending, self._seen, self._resynced, self._cut_first = b"", 0, True, True

    def feed(self, chunk: bytes, t_rx: float | None = None) -> list[Sample]:
        """Samples of the complete lines so far, in the toolkit's units; ``t_rx`` (s, any clock) dates the chunk
        for the format's detection and the gyro check of streams without ``t_s``."""
        if self._inner is None:
            self._pending += chunk
            chunk = self._detect(t_rx)
            if self._inner is None:
                return []
        samples = self._inner.feed(chunk)
        if self._inner.events:
            self.events += self._inner.drain_events()
        return self._out(samples, t_rx) if samples else []

    def flush(self) -> list[Sample]:
        """At the end of the stream: the samples still held for the unit check, judged on what came."""
        if self._inner is None:  # never knew the format: what it kept were samples before any header
            self.stats.unheaded += len(self._pending.replace(b"\r", b"\n").split(b"\n")[:-1])
            self._pending = b""
            return []
        return self._judge(final=True) if self._held and self._fatal is None else []

    # ----------------------------------------------------------------- internals

    def _adopt(self, fmt: str, how: str) -> None:
        common = {"stats": self.stats}
        if fmt == "compass":
            self._inner = LineDecoder(self.channels, **common)
        elif fmt == "motioncal":
            self._inner = MotionCalDecoder(self.channels, **common)
        else:
            self._inner = CsvDecoder(self.channels, columns=self.options.columns, **common)
        self.format = fmt
        self._factors = self.options.factors(fmt)
        self._accel_known = self.options.accel_known(fmt)
        if self._resynced:
            self._inner.resync()
        self.events.append(("info", f"stream format: {fmt} ({how})"))

    def _detect(self, t_rx: float | None) -> bytes:
        """Look at the complete lines read so far; adopt a format when one shows (returns the bytes to feed it).

        Until then only bare-number lines are kept (samples of a CSV, or of our protocol before its header);
        lines that are no format's (binary noise, a banner) are counted as garbage and dropped."""
        data = self._pending.replace(b"\r", b"\n")
        lines = data.split(b"\n")
        tail = lines.pop()
        known = set(self.channels) | set(_SCALARS) | {n for g in _GROUPS.values() for n in g}
        kept = []
        for k, line in enumerate(lines):
            try:
                text = line.decode("utf-8").strip()  # a log's header may name its units so (deg as °, u as µ)
            except UnicodeDecodeError:
                self.stats.garbage += 1
                continue
            star = text.rfind("*")
            cells = [c.strip() for c in (text[:star] if star > 0 else text).split(",")]
            if text.startswith(_MOTIONCAL_TAGS):
                return self._decided("motioncal", "found from its Raw:/Uni:/Cal lines", kept + lines[k:], tail)
            cut, self._cut_first = self._cut_first, False
            log = _log_header(cells)
            if log is not None and cut and log_column_name(cells[0])[0] is None and cells[0] not in known:
                self.stats.partial += 1  # a header's tail after a (re)connect ("scope Z (deg/s),Magnetometer X...")
                continue
            if log is not None:
                self._resynced &= bool(kept)  # a whole header line: the line after it starts whole
                return self._log_decided(*log, text, kept + lines[k + 1:], tail)
            if text and not text.startswith("#") and not _number(cells[0]) and known & set(cells):
                return self._decided("compass", "found from its header line", kept + lines[k:], tail)
            if not text:
                continue
            if text.startswith("#"):
                self.stats.comments += 1
            elif _number(cells[0]) or _number(text.split()[0]):
                kept.append(line)
                if k >= self._seen:
                    self._numeric_lines += 1
                    if self._first_numeric_t is None:
                        self._first_numeric_t = t_rx
            else:
                self.stats.garbage += 1
        self._seen = len(kept)
        if len(kept) > _AUTO_WAIT_LINES:
            self.stats.unheaded += len(kept) - _AUTO_WAIT_LINES
            kept, self._seen = kept[-_AUTO_WAIT_LINES:], _AUTO_WAIT_LINES
        self._pending = b"".join(line + b"\n" for line in kept) + tail
        waited = (t_rx is not None and self._first_numeric_t is not None
                  and t_rx - self._first_numeric_t >= _AUTO_WAIT_S and self._numeric_lines >= 5)
        if self._fatal is None and (waited or self._numeric_lines >= _AUTO_WAIT_LINES):
            self._fatal = (f"the stream sends bare numbers without a header ({self._numeric_lines} lines; a module "
                           f"that sends its header once, at boot, sent it before the port was open: reset it with the "
                           f"port open): name its cells with --columns, e.g. --columns {EXAMPLE_COLUMNS}")
        if len(self._pending) > _AUTO_MAX_BYTES:  # an endless line: counted once, as the decoders do
            self.stats.garbage += 1
            self._pending = b""
        return b""

    def _log_decided(self, names: tuple, named_units: dict, text: str, lines: list, tail: bytes) -> bytes:
        """A log's header line (``text``): its cells become the CSV's columns, and the units it names are the
        stream's where the user named none (as the file readers read that header); one sent again later is read
        too (:meth:`_relayout`)."""
        said = self._log_options(names, named_units)
        pending = self._decided("csv", f"found from its log header {text[:60]!r}: columns {','.join(names)}"
                                       + (f", {said} as it names them" if said else ""), lines, tail)
        self._inner.relayout = self._relayout
        return pending

    def _log_options(self, names: tuple, named_units: dict) -> str:
        """:attr:`options` with a log header's columns and units (a unit the user named wins); the units taken, in
        words."""
        given = {kind: getattr(self._given, f"{kind}_unit") for kind in ("mag", "accel", "gyro")}
        self.options = replace(self.options, columns=names,
                               **{f"{kind}_unit": given[kind] or named_units.get(kind) for kind in given})
        return ", ".join(f"{kind} in {unit}" for kind, unit in named_units.items() if given[kind] is None)

    def _relayout(self, text: str) -> tuple | None:
        """A log's header sent again (:attr:`compass.io.fixed_lines.CsvDecoder.relayout`): its columns, its units
        taken from here on (said when they changed); None for a line that is no log header."""
        log = _log_header([c.strip() for c in text.split(",")])
        if log is None:
            return None
        before = (self.options.columns, self._factors)
        self._factors_before[id(self._inner.header)] = self._factors  # for the chunk's samples read before it
        said = self._log_options(*log)
        self._factors = self.options.factors(self.format)
        if (self.options.columns, self._factors) != before:
            self.events.append(("warn", f"the stream's log header came again with other columns or units: columns "
                                        f"{','.join(log[0])}{', ' + said if said else ''}, read so from here on"))
        return log[0]

    def _decided(self, fmt: str, how: str, lines: list, tail: bytes) -> bytes:
        self._adopt(fmt, how)
        self._pending = b""
        return b"".join(line + b"\n" for line in lines) + tail

    def _scaled(self, s: Sample) -> Sample:
        """A decoded sample in the toolkit's units: the factors of the header it was read under (one sent again
        within the chunk changed them for the samples after it, :meth:`_relayout`)."""
        mag, acc, gyr = self._factors_before.get(id(s.header), self._factors)
        if (mag, acc, gyr) == (1.0, 1.0, 1.0):
            return s
        return replace(s, raw=s.raw * np.where(self._field_unit, mag, 1.0),
                       accel=None if s.accel is None else s.accel * acc, gyro=None if s.gyro is None else s.gyro * gyr)

    def _out(self, samples: list, t_rx: float | None) -> list:
        samples = [self._scaled(s) for s in samples]
        self._factors_before.clear()  # the chunk's samples are scaled: its headers' ids may be reused
        self._observe(samples, t_rx)
        if self._fatal is not None:
            return []
        if self._check is None:
            return samples
        self._held += samples if t_rx is None else [replace(s, t_rx=t_rx) for s in samples]
        return self._judge() if len(self._held) >= self._judge_at else []

    def take_withheld(self) -> list:
        """The samples held for the unit check and never handed out (its words in :attr:`fatal`): a command keeps
        them under ``--record``, as it keeps what a session received before any other stop."""
        held, self._held = (self._held, []) if self._fatal is not None else ([], self._held)
        return held

    def _judge(self, final: bool = False) -> list:
        """The held samples judged (:func:`field_scale_check`): handed out, or held until the housing turned (words
        that a unit or another board's calibration would both explain; :data:`UNIT_HOLD_SAMPLES` at most), or
        withheld with the words in :attr:`fatal`."""
        held = self._held
        accel = [s.accel for s in held]
        accel = None if any(a is None for a in accel) else np.array(accel)
        words = self._check(np.array([s.raw for s in held]), accel)
        if words is None:
            self._held, self._check = [], None
            return held
        if not final and accel is not None and len(held) < UNIT_HOLD_SAMPLES and not housing_turned(accel):
            if self._judge_at == JUDGE_SAMPLES:  # the first hold: said, or the session looks stalled
                self.events.append(("info", f"the field is not the calibration's |B| but a unit's factor would make "
                                            f"it so: samples held until the module turns by {TURNED_DEG:g} deg (at "
                                            f"most {UNIT_HOLD_SAMPLES}), which tells a unit from another board's "
                                            f"calibration: turn the module"))
            self._judge_at = len(held) + JUDGE_SAMPLES  # judged again on more samples
            return []
        self._fatal, self._check = words, None
        return []

    def _observe(self, samples: list, t_rx: float | None) -> None:
        """The accelerometer's |a| in g (when its unit is known) and the gyro's turn against its tilt: warnings."""
        if self._accel_known and len(self._accel) < _ACCEL_SAMPLES:
            self._accel += [s.accel for s in samples if s.accel is not None]
            if len(self._accel) >= _ACCEL_SAMPLES:
                with np.errstate(over="ignore", invalid="ignore"):  # a corrupted reading squared
                    norm = float(np.median(np.linalg.norm(self._accel, axis=1)))
                if not 0.8 <= norm <= 1.25:
                    self.events.append(("warn", f"the accelerometer reads a median |a| of {norm:.3g} g in its first "
                                                f"{_ACCEL_SAMPLES} samples, not 1 g: is --accel-unit right?"))
        if self._gyro_judged or self.gyro_unit_said:
            return
        self._gyro_rows += [(s.t_s, t_rx, s.accel, s.gyro) for s in samples if s.accel is not None and s.gyro is not None]
        if len(self._gyro_rows) >= 3:
            self._judge_gyro()

    def _judge_gyro(self) -> None:
        rows = self._gyro_rows
        if all(r[0] is not None for r in rows):
            t = np.array([r[0] for r in rows], dtype=float)
        elif all(r[1] is not None for r in rows):  # no module clock: evenly spaced between the first and last chunk
            t = np.linspace(rows[0][1], rows[-1][1], len(rows))
        else:
            self._gyro_judged = True
            return
        if t[-1] - t[0] < _GYRO_WINDOW_S:
            return
        self._gyro_rows = []
        self._gyro_windows += 1
        self._gyro_judged = self._gyro_windows >= _GYRO_WINDOWS  # a housing that never tilts: give up
        accel, gyro = np.array([r[2] for r in rows]), np.array([r[3] for r in rows])
        sane = np.all(np.abs(np.hstack([accel, gyro])) < units.MAX_ABS_VALUE, axis=1)  # corrupted readings: no evidence
        ratio = units.gyro_turn_ratio(t[sane], gyro[sane], accel[sane])
        if ratio is None:
            return  # the housing did not tilt enough in this window: try the next one
        self._gyro_judged = True
        unit = self.options.gyro_unit or "rad/s"
        verdict = units.gyro_unit_verdict(ratio)
        self.gyro_unit_said = ratio == 0.0 or verdict is not None
        self.gyro_unit_right = not self.gyro_unit_said
        named = self._given.gyro_unit is not None or self.format == "motioncal"  # MotionCal's units are its own
        labelled = self._given.gyro_unit is None and self.options.gyro_unit == "deg/s"  # a log header says deg/s
        fault = units.gyro_fault_words(ratio, gyro[sane], named=named, labelled_deg=labelled)
        if fault is not None:  # the session stops on it, in its words
            self.gyro_fault = f"the gyro read in {unit} {fault}"
        elif ratio == 0.0:  # every rate exactly zero (no unit gives that): the check_gyro_unit words
            self.events.append(("warn", "the gyro never turns while the accelerometer sees the housing tilt: a dead "
                                        "gyro?"))
        elif verdict is not None:
            more = f"{ratio:.0f} times more" if verdict == "more" else f"{1 / ratio:.0f} times less"
            self.events.append(("warn", f"the gyro read in {unit} turns {more} than the accelerometer sees the housing "
                                        f"tilt (a unit taken for another gives 57): is --gyro-unit right?"
                                        f"{units.stuck_gyro_words(gyro[sane])}"))


def _log_header(cells) -> tuple[tuple, dict] | None:
    """A log's header (x-io's ``Time (s),Gyroscope X (deg/s),...``, read as the file readers read it,
    :func:`compass.io.table.log_column_name`): the cells as ``--columns`` names (a cell that names nothing of ours
    kept as it is, ignored) and the units it names, ``{"mag"|"accel"|"gyro": unit}``; None unless it renames a cell
    and names a magnetometer's three axes."""
    names, named_units, renamed = [], {}, False
    for cell in cells:
        canon, unit = log_column_name(cell)
        if canon == "t_s":
            canon, unit = {"s": "t_s", "ms": "t_ms", "us": "t_us"}[unit.lower()], None
        renamed |= canon is not None
        names.append(canon or cell)
        if canon is not None and unit is not None:
            named_units[{"g": "gyro", "a": "accel", "m": "mag"}[canon[0]]] = unit
    if not renamed or not {"mx", "my", "mz"} <= set(names) or len(set(names)) != len(names) or "" in names:
        return None
    return tuple(names), named_units


def _number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True

