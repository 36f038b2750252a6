"""Attitude in Rerun: the housing in the world, field and gravity in the housing against their gate
cones, the attitude CSV's columns over time, the raw channels. Shared by ``compass live`` (in
batches, :class:`compass.viz.RerunSink`), ``compass attitude`` and ``compass evaluate``.

Entities (world NWU, magnetic north along +X; housing H is FLU; SPEC section 1). Scalar entities
carry the attitude CSV's column names and meanings:

=================================== =================================================================
entity                              content
=================================== =================================================================
``world/housing``                   ``Transform3D``: ``R_world<-housing`` (quaternion x, y, z, w)
``world/housing/body``, ``/axes``   the housing: slab, nose at +X, fin on top; X/Y/Z arrows (static)
``world/field``                     measured field in the world, over the reference |B|
``world/reference_field``           the reference field (dip), unit length (static); ``/label`` its
                                    label beyond the tip
``world/north``                     N (magnetic north, +X) and W arrows on the floor (static)
``housing/field``                   measured field in H, over the reference |B|
``housing/expected``               ``Transform3D``: ``R_housing<-world`` (the estimate's inverse), so
                                    its children, drawn in the world, appear where the housing
                                    expects them
``housing/expected/field_gate``     cone about the reference field: half angle the gate's dip
                                    tolerance, rings at |B| ratio 1 and 1 -+ its tolerance (static)
``housing/gravity``                 measured gravity (down) in H, over g
``housing/expected/gravity_gate``   cone about down, half angle asin(accel tolerance) (static)
``compass/heading_deg`` ...         ``Scalars``: heading_deg, pitch_deg, roll_deg, heading_true_deg
                                    (with a site), field_ratio,
                                    dip_deg, gate (CSV code: 0 used, 1 |B|, 2 dip, 3 innovation,
                                    4 no field, 5 waits for the tilt a gyro rail left, 6 magnet), mag_used,
                                    accel_used, in_range, disturbed, latency_ms (live)
``compass/<angle>/sigma_band``      ``Scalars`` x2: the angle -1 sigma and +1 sigma
``compass/field_ratio/gate_limits`` ``Scalars`` x2: the gate's limits (also ``dip_deg``)
``compass/state/field``, ``/gravity``, ``StateChange``: the flags in words, a row where they change
``/range``                          (field used or rejected and why, gravity used, in range)
``raw/mag``, ``raw/accel``,         ``Scalars``: the recording's columns (channel names, ax..az,
``raw/gyro``                        gx..gz), recording units
=================================== =================================================================
"""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from . import _layout
from ._stream import index_rows
from ._drawing import FIELD_COLOR, GRAVITY_COLOR, REFERENCE_COLOR, cone_strips, log_housing, log_north

__all__ = ["attitude_views", "log_attitude_statics", "log_reference", "send_attitude", "send_raw", "send_frames",
           "log_attitude", "log_evaluation", "evaluation_views", "record_attitude", "record_evaluation",
           "reference_dip", "GATE_LEGEND", "FLAGS"]

GATE_LEGEND = ("gate: 0 used, 1 |B| off, 2 dip off, 3 heading innovation, 4 no field, 5 waits: gyro rail, "
               "6 turns with the housing: magnet")
# the flags in words, one lane each in the state timeline (``compass/state/<lane>``)
_FIELD_STATES = {0: "field used", 1: "field rejected: |B| off", 2: "field rejected: dip off",
                 3: "field rejected: heading innovation", 4: "no field",
                 5: "field waits: the tilt a gyro rail left", 6: "field rejected: turns with the housing (magnet)"}
_STATES = {"field": None,  # from the gate code, else from disturbed
           "gravity": ("accel_used", {1: "gravity used", 0: "gravity not used (moving)"}),
           "range": ("in_range", {1: "in calibrated range", 0: "OUT of calibrated range"})}
FLAGS = ("gate", "mag_used", "accel_used", "in_range", "disturbed")
_ANGLES = ("heading_deg", "pitch_deg", "roll_deg", "heading_true_deg")
_BAND = [[150, 150, 150]] * 2
_LIMIT = [[220, 60, 60]] * 2


def attitude_views(*, world: str = "/world", housing: str = "/housing", compass: str = "/compass", raw: str = "/raw",
                   events: str = "/events", raw_mag_unit: str = "recording units") -> rrb.Container:
    """The attitude layout: 3-D views left, time series by unit in the middle, events right.

    Parameters
    ----------
    raw_mag_unit : str
        The unit of the raw magnetometer channels, for the panel's title.
    """
    spatial = rrb.Vertical(
        _layout.spatial(origin=world, name="world: housing, field (orange), reference (grey), N north",
                        eye=(2.3, 2.5, 0.9), target=(0.3, 0.0, -0.5)),
        _layout.spatial(origin=housing, name="in the housing: field (orange), gravity (purple), the gate's cones",
                        eye=(2.2, 1.9, 0.7), target=(0.0, 0.0, -0.35)))
    series = rrb.Vertical(
        _layout.series(name="heading (deg) +-1 sigma; from true north with a site",
                       contents=[f"{compass}/heading_deg/**", f"{compass}/heading_true_deg/**"]),
        _layout.series(name="pitch, roll (deg) +-1 sigma", contents=[f"{compass}/pitch_deg/**", f"{compass}/roll_deg/**"]),
        _layout.series(origin=f"{compass}/field_ratio", name="|B| / reference (ratio), gate limits"),
        _layout.series(origin=f"{compass}/dip_deg", name="dip (deg), gate limits"),
        rrb.StateTimelineView(origin=f"{compass}/state", name="what the filter did (field, gravity, range)"),
        rrb.Tabs(_layout.series(origin=f"{raw}/mag", name=f"raw magnetometer ({raw_mag_unit})"),
                 _layout.series(origin=f"{raw}/accel", name="raw accelerometer (recording units)"),
                 _layout.series(origin=f"{raw}/gyro", name="raw gyro (rad/s)"),
                 _layout.series(origin=f"{compass}/latency_ms", name="live: latency, port to estimate (ms)",
                                legend=None)),
        row_shares=[3, 3, 2, 2, 3, 3])
    return rrb.Horizontal(spatial, series, _layout.text_log(origin=events, name="events"), column_shares=[2, 3, 1],
                          name="attitude")


def log_attitude_statics(rec, *, dip_deg: float, channels, field_tolerance: float, dip_tolerance_deg: float,
                         accel_tolerance: float) -> None:
    """Styles, names and the fixed shapes (housings, reference field, the gate's cones)."""
    log_housing(rec, "world/housing", label="housing (estimate)")
    log_north(rec, "world/north", height=-1.3)
    log_housing(rec, "housing", color=(170, 170, 170), label="housing")
    # the measured arrows are named by colour in the views' titles: a label of theirs sits on the
    # reference's (the field measured where it is expected) or on each other's (field along gravity)
    rec.log("world/field", rr.Arrows3D.from_fields(colors=[FIELD_COLOR], radii=[0.025]), static=True)
    for name, color in (("field", FIELD_COLOR), ("gravity", GRAVITY_COLOR)):
        rec.log(f"housing/{name}", rr.Arrows3D.from_fields(colors=[color], radii=[0.025]), static=True)
    log_reference(rec, dip_deg=dip_deg, field_tolerance=field_tolerance, dip_tolerance_deg=dip_tolerance_deg)
    rec.log("housing/expected/gravity_gate", rr.LineStrips3D(
        cone_strips([0.0, 0.0, -1.0], np.arcsin(min(accel_tolerance, 0.99)), 1.0), colors=[GRAVITY_COLOR],
        radii=[0.004]), static=True)
    for name, color in zip(_ANGLES, ([30, 120, 220], [30, 160, 60], [200, 80, 30], [120, 60, 200])):
        rec.log(f"compass/{name}", rr.SeriesLines(names=[name], colors=[color]), static=True)
        rec.log(f"compass/{name}/sigma_band", rr.SeriesLines(names=["-1 sigma", "+1 sigma"], colors=_BAND,
                                                             widths=[0.5, 0.5]), static=True)
    for name in ("field_ratio", "dip_deg"):
        rec.log(f"compass/{name}", rr.SeriesLines(names=[name]), static=True)
        rec.log(f"compass/{name}/gate_limits", rr.SeriesLines(names=["gate low", "gate high"], colors=_LIMIT,
                                                              widths=[0.5, 0.5]), static=True)
    for name in FLAGS:
        rec.log(f"compass/{name}", rr.SeriesPoints(names=[name], marker_sizes=[1.5]), static=True)
    rec.log("raw/mag", rr.SeriesLines(names=list(channels)), static=True)
    rec.log("raw/accel", rr.SeriesLines(names=["ax", "ay", "az"]), static=True)
    rec.log("raw/gyro", rr.SeriesLines(names=["gx", "gy", "gz"]), static=True)


def log_reference(rec, *, dip_deg: float, field_tolerance: float, dip_tolerance_deg: float) -> None:
    """The reference field (static): its arrow in the world and the field gate's cone about it.

    Logged again when the reference changes (``compass live`` learns it from a site or from the
    stream's first quiet second).
    """
    dip = np.radians(dip_deg)
    reference = [np.cos(dip), 0.0, -np.sin(dip)]
    rec.log("world/reference_field", rr.Arrows3D(vectors=[reference], colors=[REFERENCE_COLOR], radii=[0.015]),
            static=True)
    # labelled beyond its tip: an arrow's label sits at its middle, where the housing's X arrow is
    # when the housing points north
    rec.log("world/reference_field/label", rr.Points3D([1.12 * np.asarray(reference)], colors=[REFERENCE_COLOR],
                                                       radii=[0.02], labels=[f"reference, dip {dip_deg:.1f} deg"],
                                                       show_labels=True), static=True)
    field_cone = cone_strips(reference, np.radians(dip_tolerance_deg), 1.0)
    field_cone += [cone_strips(reference, np.radians(dip_tolerance_deg), r)[0] for r in (1 - field_tolerance,
                                                                                       1 + field_tolerance)]
    rec.log("housing/expected/field_gate", rr.LineStrips3D(field_cone, colors=[FIELD_COLOR], radii=[0.004]),
            static=True)


def send_frames(rec, index, rotation, field_h, down_h=None) -> None:
    """Send 3-D frames as columns: the housing, the measured field (world and H), gravity in H.

    Parameters
    ----------
    index : list of rerun.TimeColumn
    rotation : scipy Rotation, n rotations
        ``R_world<-housing``.
    field_h : ndarray (n, 3)
        Measured field in H over the reference |B|.
    down_h : ndarray (n, 3), optional
        Measured gravity direction (down) in H over g.
    """
    rec.send_columns("world/housing", indexes=index, columns=rr.Transform3D.columns(quaternion=rotation.as_quat()))
    rec.send_columns("housing/expected", indexes=index,
                     columns=rr.Transform3D.columns(quaternion=rotation.inv().as_quat()))
    rec.send_columns("world/field", indexes=index, columns=rr.Arrows3D.columns(vectors=rotation.apply(field_h)))
    rec.send_columns("housing/field", indexes=index, columns=rr.Arrows3D.columns(vectors=field_h))
    if down_h is not None:
        rec.send_columns("housing/gravity", indexes=index, columns=rr.Arrows3D.columns(vectors=down_h))


def send_attitude(rec, index, columns: dict, *, field_limits=None, dip_limits=None, compass: str = "compass") -> None:
    """Send attitude columns (CSV names) as Scalars, with sigma bands and gate limits.

    Parameters
    ----------
    rec : rerun.RecordingStream
    index : list of rerun.TimeColumn
    columns : dict of str to ndarray (n,)
        Any of ``heading_deg, pitch_deg, roll_deg, heading_sigma_deg, tilt_sigma_deg,
        pitch_sigma_deg, roll_sigma_deg, field_ratio, dip_deg`` and the :data:`FLAGS`.
    field_limits, dip_limits : (float, float), optional
        The gate's limits on ``field_ratio`` and ``dip_deg`` (a band about the reference).
    """
    sigma_of = {"heading_deg": "heading_sigma_deg", "pitch_deg": "pitch_sigma_deg", "roll_deg": "roll_sigma_deg",
                "heading_true_deg": "heading_true_sigma_deg"}
    for name in _ANGLES:
        if name not in columns:
            continue
        value = np.asarray(columns[name], dtype=float)
        rec.send_columns(f"{compass}/{name}", indexes=index, columns=rr.Scalars.columns(scalars=value))
        tilt = columns.get("tilt_sigma_deg") if name in ("pitch_deg", "roll_deg") else None
        sigma = columns.get(sigma_of[name], tilt)
        if sigma is not None:
            band = value[:, None] + np.asarray(sigma, dtype=float)[:, None] * np.array([-1.0, 1.0])
            rec.send_columns(f"{compass}/{name}/sigma_band", indexes=index, columns=rr.Scalars.columns(scalars=band))
    for name, limits in (("field_ratio", field_limits), ("dip_deg", dip_limits)):
        if name not in columns:
            continue
        value = np.asarray(columns[name], dtype=float)
        rec.send_columns(f"{compass}/{name}", indexes=index, columns=rr.Scalars.columns(scalars=value))
        if limits is not None:
            band = np.broadcast_to(np.asarray(limits, dtype=float), (len(value), 2))
            rec.send_columns(f"{compass}/{name}/gate_limits", indexes=index, columns=rr.Scalars.columns(scalars=band))
    for name in (*FLAGS, "latency_ms"):
        if name in columns:
            rec.send_columns(f"{compass}/{name}", indexes=index,
                             columns=rr.Scalars.columns(scalars=np.asarray(columns[name], dtype=float)))
    send_states(rec, index, columns, compass=compass)


def send_states(rec, index, columns: dict, *, compass: str = "compass") -> None:
    """The flags in words, as state lanes (``compass/state/field``, ``/gravity``, ``/range``): a row
    where a lane changes, so a state timeline shows each as labelled bands (0/1 lines overlaid read as
    nothing)."""
    lanes = {}
    if "gate" in columns:
        lanes["field"] = [_FIELD_STATES.get(int(g), f"gate {g}") if np.isfinite(g) else ""
                          for g in np.asarray(columns["gate"], dtype=float)]
    elif "disturbed" in columns:
        lanes["field"] = ["field disturbed" if d else "field agrees with the reference" for d in columns["disturbed"]]
    for lane, spec in _STATES.items():
        if spec is not None and spec[0] in columns:
            values = np.asarray(columns[spec[0]], dtype=float)
            lanes[lane] = [spec[1].get(int(v), "") if np.isfinite(v) else "" for v in values]
    for lane, words in lanes.items():
        words = np.asarray(words, dtype=object)
        rows = np.flatnonzero(np.concatenate([[True], words[1:] != words[:-1]]))
        rec.send_columns(f"{compass}/state/{lane}", indexes=index_rows(index, rows),
                         columns=rr.StateChange.columns(state=list(words[rows])))


def send_raw(rec, index, *, mag=None, accel=None, gyro=None, raw: str = "raw") -> None:
    """Send the raw channels (recording units) as multi-column Scalars; absent groups skipped."""
    for name, values in (("mag", mag), ("accel", accel), ("gyro", gyro)):
        if values is not None:
            rec.send_columns(f"{raw}/{name}", indexes=index,
                             columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)))


def log_attitude(rec, attitude, *, t_s=None, raw=None, accel=None, gyro=None, dip_deg: float, channels,
                 field_tolerance: float, dip_tolerance_deg: float, accel_tolerance: float = 0.1) -> None:
    """Log an offline attitude solution (``compass attitude``) on the ``sample`` (and ``t``) timelines.

    Parameters
    ----------
    attitude : compass.attitude.Attitude
    t_s : ndarray (n,), optional
    raw, accel, gyro : ndarray (n, c), optional
        The recording's channels, accelerometer and gyro, recording units.
    dip_deg : float
        The calibration's dip; the gate limits are its +-``dip_tolerance_deg`` and |B| ratio
        ``1 +- field_tolerance``.
    accel_tolerance : float
        The gravity cone's half angle is ``asin(accel_tolerance)``.
    """
    from ..frames import r_world_from_housing

    n = len(attitude.heading_deg)
    index = _index(t_s, np.arange(n))
    log_attitude_statics(rec, dip_deg=dip_deg, channels=channels, field_tolerance=field_tolerance,
                         dip_tolerance_deg=dip_tolerance_deg, accel_tolerance=accel_tolerance)
    rotation = r_world_from_housing(attitude.heading_deg, attitude.pitch_deg, attitude.roll_deg)
    send_attitude(rec, index, attitude.columns(), field_limits=(1 - field_tolerance, 1 + field_tolerance),
                  dip_limits=(dip_deg - dip_tolerance_deg, dip_deg + dip_tolerance_deg))
    send_raw(rec, index, mag=raw, accel=accel, gyro=gyro)
    # the field in H over the reference: the measured |B| ratio and dip, at the azimuth the solution gives it
    dip = np.radians(attitude.dip_deg)
    field_w = attitude.field_ratio[:, None] * np.column_stack([np.cos(dip), np.zeros(n), -np.sin(dip)])
    down_h = None if accel is None else -accel / np.linalg.norm(accel, axis=1, keepdims=True)
    send_frames(rec, index, rotation, rotation.inv().apply(field_w), down_h)


def evaluation_views() -> rrb.Container:
    """Estimate and truth side by side in the world, errors over time, the field."""
    return rrb.Horizontal(
        _layout.spatial(origin="/world", name="estimate (blue) and truth (grey, beside it); N = magnetic north",
                        eye=(2.6, 3.4, 1.8), target=(0.0, -0.9, 0.0)),
        rrb.Vertical(
            _layout.series(origin="/errors",
                           name="BROAD errors (deg): heading, heading offset removed, inclination"),
            _layout.series(origin="/compass/field_ratio", name="|B| / reference (ratio, after the hard-iron track)",
                           legend=None),
            _layout.series(name="field rejected (1) / movement phase (1)",
                           contents=["/compass/disturbed", "/compass/movement"])),
        _layout.text_log(origin="/events", name="events"), column_shares=[2, 3, 1], name="evaluation")


def log_evaluation(rec, *, t_s, quat_enu, ref_quat_enu, errors, field_h_ut, field_ut: float, disturbed, movement,
                   events=(), frames: int = 600) -> None:
    """Log an evaluation (``compass evaluate``): estimate and truth housings, errors over time.

    Parameters
    ----------
    t_s : ndarray (n,)
    quat_enu, ref_quat_enu : ndarray (n, 4)
        ``R_ENU<-H``, scalar first (BROAD); drawn in NWU (``Rz(-90 deg)`` of ENU). NaN reference
        rows are skipped.
    errors : compass.evaluation.ErrorSeries
    field_h_ut : ndarray (n, 3)
    field_ut : float
        Reference |B|.
    disturbed, movement : ndarray of bool (n,)
    events : iterable of (t_s, text)
    frames : int
        At most this many rows drawn in the 3-D view (the time series get every row).
    """
    from scipy.spatial.transform import Rotation

    nwu_from_enu = Rotation.from_euler("z", -90.0, degrees=True)
    index = _index(t_s, None)
    log_housing(rec, "world/estimate", label="estimate")
    log_north(rec, "world/north")
    rec.log("world/beside", rr.Transform3D(translation=[0.0, -1.8, 0.0]), static=True)  # truth to the right
    log_housing(rec, "world/beside/truth", color=(170, 170, 170), label="truth (optical)", axis_labels=False)
    n = len(t_s)
    keep = np.unique(np.linspace(0, n - 1, min(n, frames)).astype(int))
    for name, quats in (("estimate", quat_enu), ("beside/truth", ref_quat_enu)):
        q = np.asarray(quats, dtype=float)[keep]
        ok = np.all(np.isfinite(q), axis=1)
        r = nwu_from_enu * Rotation.from_quat(q[ok][:, [1, 2, 3, 0]])
        rec.send_columns(f"world/{name}", indexes=_index(np.asarray(t_s)[keep][ok], None),
                         columns=rr.Transform3D.columns(quaternion=r.as_quat()))
    for name, values in (("heading_deg", errors.heading_deg),
                         ("heading_offset_removed_deg", errors.heading_offset_removed_deg),
                         ("inclination_deg", errors.inclination_deg)):
        rec.send_columns(f"errors/{name}", indexes=index,
                         columns=rr.Scalars.columns(scalars=np.where(movement, values, np.nan)))
    ratio = np.linalg.norm(field_h_ut, axis=1) / field_ut
    rec.send_columns("compass/field_ratio", indexes=index, columns=rr.Scalars.columns(scalars=ratio))
    for name, flag in (("disturbed", disturbed), ("movement", movement)):
        rec.send_columns(f"compass/{name}", indexes=index,
                         columns=rr.Scalars.columns(scalars=np.asarray(flag, dtype=float)))
    for t, text in events:
        rec.set_time("t", duration=float(t))
        rec.log("events", rr.TextLog(text))


def _index(t_s, sample) -> list:
    from ._stream import columns_index

    return columns_index(t_s, sample)




def record_attitude(target, attitude, model, *, t_s=None, raw=None, accel=None, gyro=None,
                    application_id: str = _layout.APPLICATION_IDS["attitude"]) -> None:
    """Write an offline attitude solution (``compass attitude --rerun``) with its layout.

    The gate limits drawn are the floors of ``solve_attitude``'s ``disturbed`` test
    (``field_tolerance``, ``dip_tolerance_deg`` about the calibration's dip); the test itself also
    allows ``disturbance_sigma`` times each row's sigma.
    """
    import inspect

    from ..attitude import solve_attitude
    from ._stream import Recording

    defaults = inspect.signature(solve_attitude).parameters
    with Recording(target, application_id=application_id) as out:
        log_attitude(out.rec, attitude, t_s=t_s, raw=raw, accel=accel, gyro=gyro,
                     dip_deg=reference_dip(attitude, model), channels=model.channels,
                     field_tolerance=defaults["field_tolerance"].default,
                     dip_tolerance_deg=defaults["dip_tolerance_deg"].default)
        out.rec.set_time("sample", sequence=0)
        if t_s is not None:
            out.rec.set_time("t", duration=float(t_s[0]))
        out.rec.log("events", rr.TextLog(f"mode {attitude.mode}: {int(np.sum(attitude.disturbed))} of "
                                         f"{len(attitude.disturbed)} rows disturbed, "
                                         f"{int(np.sum(~attitude.in_range))} out of calibrated range"))
        out.rec.send_blueprint(_layout.blueprint(attitude_views(), "sample" if t_s is None else "t"))


def record_evaluation(target, trial, result, errors, *,
                      application_id: str = _layout.APPLICATION_IDS["evaluate"]) -> None:
    """Write an evaluation (``compass evaluate --rerun``) with its layout.

    Parameters
    ----------
    trial : compass.io.broad.BroadTrial
        ``t_s``-less trials are timed by ``rate_hz``.
    result : compass.evaluation.PipelineResult
    errors : compass.evaluation.ErrorSeries
    """
    from ._stream import Recording

    steps = () if result.hard_iron is None else zip(result.hard_iron.step_t_s, result.hard_iron.step_offset_ut)
    events = [(t, f"hard-iron step: ({', '.join(f'{v:+.1f}' for v in b)}) uT") for t, b in steps]
    with Recording(target, application_id=application_id) as out:
        log_evaluation(out.rec, t_s=errors.t_s, quat_enu=result.quat_enu, ref_quat_enu=trial.ref_quat_enu,
                       errors=errors, field_h_ut=result.field_h_ut, field_ut=result.field_ut,
                       disturbed=result.disturbed, movement=trial.movement,
                       events=[(errors.t_s[0], f"{trial.name}: {result.method}")] + events)
        out.rec.send_blueprint(_layout.blueprint(evaluation_views(), "t"))


def reference_dip(attitude, model) -> float:
    """The dip the solution was judged against: its reference field's, else the calibration's."""
    reference = getattr(attitude, "reference", None)
    return float(reference.dip_deg) if reference is not None else float(model.dip_deg)
