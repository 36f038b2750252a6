"""Replay a recording through ``compass live``'s pipeline: the same start, gate and filter, offline.

:func:`replay` feeds recorded arrays to a :class:`compass.live.LiveSession` as decoded samples, so a
logged session is filtered exactly as it would have been live: the calibration's field, the bench
accelerometer's correction, the rotation into the model's frame, the start window
(:class:`compass.filter.FilterStart`: reference field, gravity, first attitude), the gate and the
filter are the session's own code.  :func:`replay_file` is ``compass attitude CAL REC --out ATT
--filter``: it reads the files, checks the recording and writes the session's CSV (the columns of
``compass live --out`` plus the quaternion ``qw,qx,qy,qz``) atomically.
"""

from __future__ import annotations

import io
import sys
import time
from contextlib import nullcontext
from dataclasses import replace
from pathlib import Path

import numpy as np

from . import limits
from .io.lines import Header, Sample
from .io.progress import Tally, working
from .io.table import ReadOptions, RecordingError
from .live import LiveSession

__all__ = ["hemisphere_note", "record_defaults", "replay", "replay_file"]

_CHUNK_ROWS = 4096  # samples handed to the session at once (the pipeline's vectorised parts run per chunk)


def replay(session: LiveSession, t_s, raw, accel=None, gyro=None, temp_c=None, *, progress=None) -> LiveSession:
    """Run recorded samples through a live session, in order; the session is closed at the end.

    Parameters
    ----------
    session : LiveSession
        Made as ``compass live`` makes it (model, reference, ``Calibration.imu``, gyro unit, outputs).
    t_s : array_like, shape (n,)
        Sample times, seconds.
    raw : array_like, shape (n, c)
        The calibration's channel outputs, in its channel order.
    accel, gyro : array_like, shape (n, 3), or None
        Accelerometer (any unit, +up at rest) and gyro (rad/s; the stream's ``--gyro-unit`` converts on decoding) in the
        module's frame, as the module sends them (a row all NaN: not sent on that row).
    temp_c : array_like, shape (n,), optional
        Sensor temperature, degrees Celsius (NaN: not sent in that row).
    progress : callable, optional
        ``progress(rows_done, rows)`` after each chunk.

    Returns
    -------
    LiveSession
        ``session``, closed: its ``samples``, ``skipped`` and :meth:`~LiveSession.summary` tell what happened;
        stopped early when it found the given gravity, or the accelerometer correction's unit, not what 1 g reads
        (its ``wrong_gravity``), the module's times not telling the time between samples (``wrong_time``), the
        field staying put in the housing while it turns (``wrong_field``), or the gyro turning tens of times more than
        the field (``gyro_unit``).
    """
    t_s = np.asarray(t_s, dtype=float)
    raw = np.asarray(raw, dtype=float)
    n, c = raw.shape
    names = tuple(session.model.channels) + (("ax", "ay", "az") if accel is not None else ()) \
        + (("gx", "gy", "gz") if gyro is not None else ()) + ("t_s",) + (("temp_c",) if temp_c is not None else ())
    index = {name: k for k, name in enumerate(names)}
    header = Header(names, np.arange(c), None if accel is None else np.array([index[a] for a in ("ax", "ay", "az")]),
                    None if gyro is None else np.array([index[g] for g in ("gx", "gy", "gz")]), index["t_s"], None,
                    index.get("temp_c"), False, ())
    accel = None if accel is None else np.asarray(accel, dtype=float)
    gyro = None if gyro is None else np.asarray(gyro, dtype=float)
    temps = None if temp_c is None else np.asarray(temp_c, dtype=float)
    for lo in range(0, n, _CHUNK_ROWS):
        hi = min(lo + _CHUNK_ROWS, n)
        samples = [Sample(raw[k], _sent(accel, k), _sent(gyro, k),
                          float(t_s[k]), None,
                          None if temps is None or not np.isfinite(temps[k]) else float(temps[k]), header)
                   for k in range(lo, hi)]
        session.feed_samples(samples, time.perf_counter())
        if progress is not None:
            progress(hi, n)
        if session.stopped:
            break
    session.close()
    return session


def _sent(vectors, k: int):
    """Row ``k`` of a group (None when the group is absent, or NaN on that row: not sent, as a live record says)."""
    if vectors is None or np.isnan(vectors[k]).all():
        return None
    return vectors[k]


def mag_latency_note(model, has_gyro: bool = True) -> tuple[str, str]:
    """What ``--mag-latency`` does with this calibration: ``(level, words)`` for the event line.

    Parameters
    ----------
    model : compass.model.SensorModel
        Its ``mag_latency_s`` (0 when the file holds no latency its fit saw).
    has_gyro : bool
        Whether the samples carry a gyro (without one nothing can be turned).
    """
    tau = model.mag_latency_s
    if not has_gyro:
        return "warn", "--mag-latency: the recording has no gyro (gx,gy,gz) to turn the field with: nothing compensated"
    if tau > 0.0:
        return "info", (f"--mag-latency: each field reading turned forward by the gyro over the magnetometer's "
                        f"{1e3 * tau:.1f} ms latency (the calibration's tumble.gyro.mag_latency_s)")
    return "warn", ("--mag-latency: the calibration holds no magnetometer latency its fit saw (a tumble with a gyro "
                    "writes tumble.gyro.mag_latency_s): nothing compensated")


def gyro_matrix_note(model, has_gyro: bool = True) -> tuple[str, str]:
    """What ``--gyro-matrix`` does with this calibration: ``(level, words)`` for the event line (the shape of
    :func:`mag_latency_note`).

    Parameters
    ----------
    model : compass.model.SensorModel
        Its ``gyro_matrix`` (None when the file holds no entry its fit saw off the identity).
    has_gyro : bool
        Whether the samples carry a gyro.
    """
    g = model.gyro_matrix
    if not has_gyro:
        return "warn", "--gyro-matrix: the recording has no gyro (gx,gy,gz) to correct: nothing applied"
    if g is not None:
        error = 100.0 * (np.asarray(g, dtype=float) - np.eye(3))
        cross = float(np.max(np.abs(error[~np.eye(3, dtype=bool)])))
        return "info", ("--gyro-matrix: each gyro reading corrected by the calibration's tumble.gyro.gyro_matrix, "
                        "scale x, y, z " + ", ".join(f"{error[i, i]:+.2f}" for i in range(3)) + " %, axes up to "
                        f"{cross:.2f} % (the entries its fit did not see off the identity held at it)")
    return "warn", ("--gyro-matrix: the calibration holds no gyro matrix entry its fit saw off the identity (a tumble "
                    "with a gyro writes tumble.gyro.gyro_matrix): the gyro as read")


def hemisphere_note(cal, site_given: bool) -> tuple[str, str] | None:
    """``(level, words)`` when the calibration's field sign rests on a hemisphere nothing checks, None otherwise:
    ``"info"`` for a four-flip bench's assumed hemisphere (every such bench without a latitude), ``"warn"`` for a
    field that points up (a reversed axis, unless the bench was south of the magnetic equator).

    A four-flip bench whose hemisphere was assumed (its data cannot tell ``(a, B)`` from ``(-a, -B)``), or a field
    that points up (dip at most -10 deg: right in the southern hemisphere, a reversed magnetometer axis in the
    northern, as the calibration warned), with no site whose reference field would stop a session on a field turned
    over (:func:`compass.site.upside_down`): if the assumption is wrong, every heading is 180 deg off.

    Parameters
    ----------
    cal : compass.calibration.Calibration
    site_given : bool
        The session has a site's reference field (``--site``, or the calibration's site block where it is used).
    """
    from .axes import MIN_SIGNED_DIP_DEG

    dip = cal.model.dip_deg
    if site_given:
        return None
    level = "info" if cal.provenance.hemisphere_assumed else "warn"
    if cal.provenance.hemisphere_assumed:
        north = dip is None or dip >= 0.0
        assumed = (f"its bench assumed the {'northern' if north else 'southern'} hemisphere (a four-flip bench cannot "
                   "tell (a, B) from (-a, -B))")
        wrong = f"in the {'southern' if north else 'northern'} hemisphere"
        cure = "recalibrate with the bench's latitude ('# site_lat_deg:' in its recording, or compass calibrate --site)"
    elif dip is not None and dip <= -MIN_SIGNED_DIP_DEG:
        assumed = f"its field points up (dip {dip:+.1f} deg), which is right only in the southern hemisphere"
        wrong = "in the northern hemisphere (a magnetometer axis reversed)"
        cure = "recalibrate with that axis negated, as the calibration's warning says (--columns mz=-COLUMN, ...)"
    else:
        return None
    return level, (f"{assumed}, and no --site checks it: {wrong} every heading is 180 deg off. Give --site LAT,LON (a "
                   f"field pointing the other way from the site's is then refused), or {cure}")


def record_defaults(recording, given: dict) -> tuple[dict, list]:
    """The replay's options: each one given, else the one the record's ``# replay:`` line names (a ``compass live
    --record`` file's: :func:`compass.io.sample_log.read_replay_line`), so the plain replay writes the session's rows.

    Parameters
    ----------
    recording : path
    given : dict
        Keyword (:data:`compass.io.sample_log.REPLAY_FLAGS`, :data:`~compass.io.sample_log.REPLAY_VALUES`) -> the
        value given, None when not given.  A ``site`` given also sets aside the record's ``date`` (its site's day).

    Returns
    -------
    options : dict
        ``given`` with the record's values in place of its None.
    notes : list of (level, words)
        Which options came from the record (and which the ones given replaced), which of the line's were ignored.
    """
    from .io.sample_log import read_replay_line

    recorded = read_replay_line(recording)
    options, taken, replaced = dict(given), [], []
    for key, value in recorded.values.items():
        if given[key] is None and not (key == "date" and given["site"] is not None):
            options[key] = value
            taken.append(recorded.written[key])
        else:
            replaced.append(recorded.written[key])
    line = f"{Path(recording).name}'s '# replay:' line"
    words = [f"took {' '.join(taken)} (the options the live session ran with)"] if taken else []
    words += [f"the options given here replaced its {' '.join(replaced)}"] if replaced else []
    notes = [("info", f"{line}: {'; '.join(words)}")] if words else []
    if recorded.ignored:
        notes.append(("warn", f"{line}: ignored {'; '.join(recorded.ignored)}"))
    return options, notes


def replay_file(calibration, recording, out, *, site=None, date=None, gravity=None, mag_latency=None, gyro_matrix=None,
                gyro_scale_error=None, force=False, rerun=None, read_options=None, quiet=False) -> LiveSession:
    """``compass attitude CAL REC --out ATT --filter``: the recording through ``compass live``'s pipeline.

    An option not given (None) takes the value a live record's ``# replay:`` line names (:func:`record_defaults`),
    the ``--accel-unit`` of ``read_options`` too.

    Parameters
    ----------
    calibration, recording, out : path
    site : str or compass.site.Site, optional
        ``LAT,LON[,ALT_M]``: the reference field and true north (as ``compass live --site``); default
        the calibration's site block, else the recording's first quiet second.
    date : str, optional
        With ``site``: ``YYYY-MM-DD``.
    gravity : float, optional
        What 1 g reads in the accelerometer's unit (in g when ``read_options`` names the unit, ``--accel-unit``:
        the accelerometer is then converted to g, as ``compass live --accel-unit`` converts it); default: the median |a|
        of the start window.  One beyond a factor 2 of that median is refused (the filter would never use the
        accelerometer: :attr:`compass.filter.FilterStart.gravity_words`).
    mag_latency : bool, optional
        Compensate the calibration's fitted magnetometer latency (``compass live --mag-latency``;
        :meth:`compass.filter.FilterConfig.from_model`); default the record's, else off.
    gyro_matrix : bool, optional
        Default the record's, else off.  Correct each gyro sample by the calibration's fitted gyro matrix (``compass live --gyro-matrix``;
        :meth:`compass.filter.FilterConfig.from_model`).
    gyro_scale_error : float, optional
        The gyro scale error the filter allows for, fraction of the rate (``compass live --gyro-scale-error``); default
        0.005 and, in quadrature, what the calibration's gyro-aided fit saw (:meth:`compass.filter.FilterConfig.from_model`).
    force : bool
        Overwrite ``out`` (and ``rerun``).
    rerun : path or "spawn", optional
        Also write the session's Rerun recording, as ``compass live --rerun`` does.
    read_options : compass.io.table.ReadOptions, optional
    quiet : bool
        No event lines on stderr.

    Returns
    -------
    LiveSession
        Closed.

    Raises
    ------
    BadInput, RecordingError, FileExistsError
        Bad input (exit status 2 on the command line), in one line naming the file (row, column).
    """
    from .calibration import load
    from .errors import BadInput
    from .filter import PLACE_EVENT, FilterConfig
    from .io.atomic import atomic_write_text, check_writable
    from .io.table import read_table
    from .io import units
    from .io.streams import field_scale_check, judge_field_unit, time_steps_verdict
    from .site import MIN_REFERENCE_ROWS, Site, reference_from_site
    from .viz import check_rerun_target

    out = check_writable(out, force, inputs=(calibration, recording))
    rerun = check_rerun_target(rerun, force)
    read_options = read_options or ReadOptions()
    options, notes = record_defaults(recording, dict(site=site, date=date, gravity=gravity, mag_latency=mag_latency,
                                                     gyro_matrix=gyro_matrix, gyro_scale_error=gyro_scale_error,
                                                     accel_unit=read_options.accel_unit))
    site, date, gravity, gyro_scale_error = options["site"], options["date"], options["gravity"], options["gyro_scale_error"]
    mag_latency, gyro_matrix = bool(options["mag_latency"]), bool(options["gyro_matrix"])
    read_options = replace(read_options, accel_unit=options["accel_unit"])
    for level, text in notes if not quiet else ():
        print(f"[{level}] {text}", file=sys.stderr)
    if date is not None and site is None:
        raise BadInput("--date needs --site LAT,LON[,ALT_M]: the date only chooses the field at a site")
    if gravity is not None:
        try:
            limits.GRAVITY.check(gravity, "--gravity")
        except ValueError as exc:
            raise BadInput(str(exc)) from None
    if gyro_scale_error is not None:
        try:
            limits.GYRO_SCALE_ERROR.check(gyro_scale_error, "--gyro-scale-error")
        except ValueError as exc:
            raise BadInput(str(exc)) from None
    try:
        if site is not None and not isinstance(site, Site):
            site = Site.parse(site, date)
        cal = load(calibration)
        model = cal.model
        config = FilterConfig.from_model(model, mag_latency=mag_latency, gravity=gravity, gyro_matrix=gyro_matrix,
                                         gyro_scale_error=gyro_scale_error)
    except ValueError as exc:
        raise BadInput(exc if str(calibration) in str(exc) else f"{calibration}: {exc}") from None
    source = "site"
    if site is None and cal.site is not None:
        site, source = cal.site, "calibration site"
    hemisphere = hemisphere_note(cal, site_given=site is not None)
    if hemisphere is not None and not quiet:
        print(f"[{hemisphere[0]}] {calibration}: {hemisphere[1]}", file=sys.stderr)
    try:
        reference = None if site is None else reference_from_site(
            site, field_ut=None if model.field_ut is None else 1.0, source=source)
    except ValueError as exc:
        raise BadInput(str(exc)) from None

    table = read_table(recording, read_options, live_record=True)  # a live record as the module sent it
    table.ignore_unknown(set(model.channels) | {"t_s", "temp_c", "ax", "ay", "az", "gx", "gy", "gz"},
                         what=f"{calibration} (its channels: {', '.join(model.channels)})")
    if not table.has("t_s"):
        raise RecordingError(table.path, "has no t_s column: the filter needs each sample's time (seconds)",
                             row=table.header_row, column="t_s")
    accel, gyro = table.group(("ax", "ay", "az")), table.group(("gx", "gy", "gz"))
    if accel is None:
        raise RecordingError(table.path, "has no ax,ay,az columns: the filter needs an accelerometer for the tilt "
                                         "(without one: compass attitude --level, no --filter)",
                             row=table.header_row, column="ax")
    table.check_dead_axis(("ax", "ay", "az"))
    if read_options.accel_unit is not None:
        # --accel-unit: in g, as compass live --accel-unit converts; a unit the header names alone stays the file's,
        # as the calibrations (a bench's offsets, a tumble's accelerometer correction) read theirs
        accel = accel * units.ACCEL_UNITS[table.units["ax"]]
    t_s = table.column("t_s")
    wrong_time = time_steps_verdict(t_s, config.max_gap_s)
    if wrong_time is not None:
        raise RecordingError(table.path, f"{wrong_time}; a column in ms is read as such when named 'Time (ms)', and "
                                         "without --filter each row is solved alone",
                             row=table.header_row, column="t_s")
    if gyro is not None:
        _check_gyro_turn(table, gyro, named=read_options.gyro_unit is not None)
    raw = np.column_stack([table.column(name) for name in model.channels])
    wrong_unit = judge_field_unit(field_scale_check(model), raw, accel)  # as the stream decoder judges live
    if wrong_unit is not None:
        raise RecordingError(table.path, f"{wrong_unit} ({calibration}): is it the right calibration?",
                             row=table.header_row, column=model.channels[0])
    temp_c = table.column("temp_c") if table.has("temp_c") else None
    for flag, note in ((mag_latency, mag_latency_note), (gyro_matrix, gyro_matrix_note)):
        if flag and not quiet:
            level, text = note(model, gyro is not None)
            print(f"[{level}] {text}", file=sys.stderr)

    moves = []  # the filter's moves of the reference to a new place
    tally = Tally()  # the progress line's (below), once the replay starts

    def on_event(level, text):
        if text.startswith(PLACE_EVENT):
            moves.append(text)
        if not quiet:
            with tally.hidden():
                print(f"[{level}] {text}", file=sys.stderr)

    buffer, sink = io.StringIO(), None
    if rerun is not None:
        from .viz import RerunSink

        sink = RerunSink.for_model(rerun, model, config)
    session = LiveSession(model, config=config, out=buffer, sink=sink, on_event=on_event, reference=reference,
                          imu=cal.imu, sign_from_bench=cal.provenance.hemisphere_assumed, quaternion=True)
    line = nullcontext(tally) if quiet else working(f"replaying {Path(recording).name}", total=len(t_s))
    try:
        with line as tally:
            replay(session, t_s, raw, accel, gyro, temp_c, progress=lambda done, rows: tally.advance(done - tally.done))
    except BaseException:
        if sink is not None:
            sink.discard()
        raise
    if session.turned_over is not None:
        raise BadInput(f"{calibration}: {session.turned_over}")
    if session.wrong_gravity is not None:
        raise RecordingError(table.path, session.wrong_gravity, column="ax")
    if session.wrong_time is not None:  # its first samples' times, as live judged them (the file's whole passed)
        raise RecordingError(table.path, session.wrong_time, column="t_s")
    if session.wrong_field is not None:
        raise RecordingError(table.path, f"{session.wrong_field} ({calibration})", column=model.channels[0])
    if session.gyro_unit is not None:
        raise RecordingError(table.path, session.gyro_unit, column="gx")
    if session.samples == 0:
        why = (f"the filter's start seeds the reference field from at least {MIN_REFERENCE_ROWS} rows; give --site "
               "LAT,LON --date D" if len(t_s) < MIN_REFERENCE_ROWS and reference is None else session.summary())
        raise RecordingError(table.path, f"no attitude from its {len(t_s)} rows ({why})")
    atomic_write_text(out, buffer.getvalue())
    print(f"wrote {out} ({session.samples} attitudes from {len(t_s)} rows, filter: "
          f"{'gyro' if gyro is not None else 'two-vector (no gx,gy,gz)'}; reference field: "
          f"{session.reference.description}"
          + (f"; it moved to a new place's field {len(moves)} time{'s' if len(moves) > 1 else ''}: {moves[-1]}"
             if moves else "") + ")" + (f"\nwrote {rerun}" if rerun is not None and str(rerun) != "spawn" else ""))
    return session


def _check_gyro_turn(table, gyro: np.ndarray, named: bool) -> None:
    """RecordingError when the gyro would be fused wrong (:func:`compass.io.units.gyro_fault_words` of the table's
    :attr:`~compass.io.table.Table.gyro_turn_ratio`; ``named``: its unit given)."""
    from .io.units import gyro_fault_words

    gyro = gyro[np.all(np.isfinite(gyro), axis=1)]  # a live record's rows the gyro was not sent on
    words = gyro_fault_words(table.gyro_turn_ratio, gyro, named=named, labelled_deg=table.units.get("gx") == "deg/s")
    if words is not None:
        raise RecordingError(table.path, f"the gyro gx,gy,gz read in {table.units.get('gx', 'rad/s')} {words}",
                             row=table.header_row, column="gx")
