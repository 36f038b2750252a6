"""Calibrations in Rerun: the four-flip session replayed, the tumble and the installation before and
after, the platform and reference fits, the diagnosis steps, and the live tumble's coverage.

Inputs are plain arrays and the calibration result's typed attributes (``calibrate``'s result of
each kind: a four-flip's ``channels`` with ``direction`` and ``direction_sigma_deg``, ``dip_deg``,
``azimuth_deg``, ``noise``; a tumble's ``hard_iron``, ``soft_iron``, ``field_norm``; every kind's
``diagnosis``), never its file's JSON.

Entities (timelines ``sample``: the replay order, ``t`` when the recording has ``t_s``, and for the
four-flip ``turntable_deg``: the platform angle in whole degrees, which its layout plots against):

=============================================== ===================================================
entity                                          content
=============================================== ===================================================
``bench/field``                                 the fitted Earth field in the bench frame (static)
``bench/turntable``                             ``Transform3D`` Rz(platform_deg); a ring marks it
``bench/turntable/cube``                        ``Transform3D`` Rx(flip_deg); the housing (FLU)
``bench/turntable/cube/directions``             fitted sensing directions, labelled (static)
``bench/turntable/cube/direction_cones``        their 3-sigma uncertainty cones, those wider than
                                                0.5 deg (static)
``fourflip/<channel>/measured``, ``/fit``       output, recording units
``fourflip/<channel>/residual``                 measured - fit: ``after`` (the final model) and,
                                                with effects added, ``before`` (base model)
``fourflip/<channel>/residual/noise_band``      -+ the noise floor from the data
``fourflip/platform_deg``, ``fourflip/flip_deg`` the bench's angles
``tumble/raw/samples``, ``/ellipsoid``          raw samples coloured by coverage, fitted ellipsoid
``tumble/calibrated/samples``, ``/sphere``      calibrated samples, sphere of radius field_norm
``tumble/coverage``                             the sphere's cells: red (few samples) to green
``tumble/live``, ``tumble/coverage_fraction``,   live tumble: samples so far about the current hard
``tumble/hard_iron/<axis>``                     iron, coverage, the fit converging (+-1 sigma)
``tumble/field_ratio``                          |m| / field_norm: ``raw`` (about the hard iron,
                                                gain-normalised) and ``calibrated``
``installed/{bench,installed}/samples``         installation: the field through the bench calibration
                                                alone and through the installed one, over the site's |B|
``installed/field_ratio``                       their |B| / site |B| per sample
``<kind>/<channel>/residual``                   platform3d, reference: residual per channel
``diagnosis/residual_rms/step<k>_<added>``      ``BarChart``: diagnosis step k's residual rms (one
                                                entity a step, so the legend names it); ``/noise_floor``
``diagnosis/log``                               ``TextLog``: the steps, evidence, verdict
=============================================== ===================================================
"""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy.spatial.transform import Rotation

from ..frames import field_in_bench, sphere_cells
from . import _layout
from ._drawing import AXIS_COLORS, FIELD_COLOR, cone_strips, log_housing, log_north
from ._stream import columns_index

__all__ = ["log_calibration", "log_calibration_result", "record_calibration", "calibration_views", "log_fourflip",
           "log_tumble", "log_fit_residuals", "log_diagnosis", "LiveTumbleRecording"]

_MEASURED, _FIT = [120, 120, 120], [30, 120, 220]
_BEFORE, _AFTER = [230, 120, 40], [30, 120, 220]
_SIGMAS = 3.0  # uncertainty cones: this many sigma
_CONE_MIN_DEG = 0.5  # narrower cones are not drawn (a line on the arrow); the label gives sigma


def _diagnosis_views() -> rrb.Container:
    return rrb.Vertical(
        rrb.BarChartView(origin="/diagnosis/residual_rms", name="residual rms per step",
                         # bottom left: over the bars' feet, not over their heights (the top right hid the floor's)
                         plot_legend=rrb.PlotLegend(corner="LeftBottom", visible=True)),
        _layout.text_log(origin="/diagnosis/log", name="diagnosis steps"), row_shares=[2, 3])


def calibration_views(kind: str, channels=()) -> rrb.Container:
    """The layout of a calibration of ``kind`` (``fourflip``, ``tumble``, ``platform3d``, ``reference``)."""
    if kind == "fourflip":
        # legends hidden (they covered the right tenth of every plot): the title names the colours
        rows = [rrb.Horizontal(_layout.series(origin=f"/fourflip/{ch}", legend=None,
                                              name=f"{ch}: output (recording units): measured grey, fit blue",
                                              contents=["$origin/measured", "$origin/fit"]),
                               _layout.series(origin=f"/fourflip/{ch}/residual", legend=None,
                                              name=f"{ch}: residual (recording units): blue (orange before the "
                                                   f"diagnosis's effects), noise band grey"))
                for ch in channels]
        return rrb.Horizontal(
            _layout.spatial(origin="/bench", name="cube on the turntable: sensing directions +-1 sigma, field (orange)",
                            eye=(3.0, 2.2, 1.8)),
            rrb.Vertical(*rows), _diagnosis_views(), column_shares=[2, 3, 1], name="four-flip calibration")
    if kind == "tumble":
        return rrb.Horizontal(
            rrb.Vertical(rrb.Horizontal(
                _layout.spatial(origin="/tumble/raw", name="raw, on the fitted ellipsoid (colour: coverage)",
                                eye=(2.2, 1.8, 1.4)),
                _layout.spatial(origin="/tumble/calibrated", name="calibrated, on the sphere", eye=(2.2, 1.8, 1.4))),
                _layout.series(origin="/tumble/field_ratio", legend=None,
                               name="|m| / field_norm (ratio): raw orange, calibrated blue"),
                row_shares=[3, 1]),
            rrb.Vertical(_layout.spatial(origin="/tumble/coverage", name="coverage: cells seen (green)",
                                         eye=(2.2, 1.8, 1.4)),
                         _diagnosis_views()), column_shares=[3, 1], name="tumble calibration")
    if kind == "installed":
        return rrb.Horizontal(
            rrb.Vertical(rrb.Horizontal(
                _layout.spatial(origin="/installed/bench", name="bench calibration alone: the product's iron bends "
                                                               "the sphere", eye=(2.2, 1.8, 1.4)),
                _layout.spatial(origin="/installed/installed", name="installed calibration: back on the sphere",
                                eye=(2.2, 1.8, 1.4))),
                _layout.series(origin="/installed/field_ratio", legend=None,
                               name="|B| / site |B| (ratio): bench calibration alone orange, installed blue"),
                row_shares=[3, 1]),
            _diagnosis_views(), column_shares=[3, 1], name="installation calibration")
    residuals = rrb.Vertical(*(_layout.series(origin=f"/{kind}/{ch}", name=f"{ch}: residual (recording units)",
                                              legend=None) for ch in channels))
    parts = [_layout.spatial(origin="/platform3d/bench", name="housing in each pose")] if kind == "platform3d" else []
    return rrb.Horizontal(*parts, residuals, _diagnosis_views(), name=f"{kind} calibration")


def log_calibration(rec, result, **arrays) -> None:
    """Log one calibration result; ``arrays`` are those :func:`log_fourflip`, :func:`log_tumble` or
    :func:`log_fit_residuals` take for its kind."""
    kind = result.calibration_kind
    if kind in ("fourflip", "tumble", "installed"):
        {"fourflip": log_fourflip, "tumble": log_tumble, "installed": log_installed}[kind](rec, result, **arrays)
    else:
        log_fit_residuals(rec, **arrays)
    log_diagnosis(rec, diagnosis_block(result), t_s=arrays.get("t_s"))


def diagnosis_block(result) -> dict | None:
    """The result's residual diagnosis as SPEC section 4's block (``steps``, ``noise_floor``, ``effects``,
    ``unexplained``): a four-flip keeps the block itself as ``diagnosis``, the other kinds a record whose
    ``block`` it is (:class:`calibrate.diagnosis.report.Diagnosis`); None when the diagnosis did not run."""
    diagnosis = result.diagnosis
    return diagnosis if diagnosis is None or isinstance(diagnosis, dict) else diagnosis.block


def _at_start(rec, t_s=None) -> None:
    """Stamp what follows at the recording's start on every timeline a layout may show (a text
    logged on ``sample`` alone is not listed when the time panel shows ``t`` or ``turntable_deg``)."""
    rec.set_time("sample", sequence=0)
    rec.set_time("turntable_deg", sequence=0)
    if t_s is not None and len(t_s) and np.isfinite(np.nanmin(t_s)):
        rec.set_time("t", duration=float(np.nanmin(t_s)))


def log_fourflip(rec, result, *, platform_deg, flip_deg, outputs, residuals, t_s=None,
                 base_residuals=None, frames: int = 720) -> None:
    """The four-flip session replayed: the cube turning, outputs with fit and residuals.

    Parameters
    ----------
    result : the four-flip result (:mod:`calibrate.fourflip.result`)
        Its ``channels`` (``name``, ``direction`` in H, ``direction_sigma_deg``),
        ``dip_deg``, ``azimuth_deg`` (deg), ``noise`` (per channel, output units).
    platform_deg, flip_deg : ndarray (n,)
        The samples the fit used, degrees.
    outputs, residuals : ndarray (n, c)
        Measured outputs and measured minus fitted (the final model), in channel order.
    t_s : ndarray (n,), optional
    base_residuals : ndarray (n, c), optional
        Residuals of the base model, when the diagnosis added effects.
    frames : int
        At most this many samples drawn in 3-D.
    """
    names = [channel.name for channel in result.channels]
    order = np.argsort(t_s, kind="stable") if t_s is not None else np.lexsort((np.mod(platform_deg, 360.0), flip_deg))
    sample = np.arange(len(order))
    t = None if t_s is None else np.asarray(t_s, dtype=float)[order]
    phi, kappa = np.asarray(platform_deg, dtype=float)[order], np.asarray(flip_deg, dtype=float)[order]
    turntable = np.rint(np.mod(phi, 360.0)).astype(np.int64) % 360
    # a third timeline, the turntable angle in whole degrees: the four flips' outputs drawn against it
    # lie on their four sinusoids (against sample number they are one long scribble)
    index = columns_index(t, sample) + [rr.TimeColumn("turntable_deg", sequence=turntable)]
    outputs, residuals = np.asarray(outputs, dtype=float)[order], np.asarray(residuals, dtype=float)[order]
    noise = np.broadcast_to(np.asarray(result.noise, dtype=float), (len(names),))
    for j, name in enumerate(names):
        rec.log(f"fourflip/{name}/measured",
                rr.SeriesPoints(names=["measured"], colors=[_MEASURED], marker_sizes=[1.0]), static=True)
        # points: at one turntable angle there are four flips' fits, a line would join them
        rec.log(f"fourflip/{name}/fit", rr.SeriesPoints(names=["fit"], colors=[_FIT], marker_sizes=[0.8]),
                static=True)
        rec.send_columns(f"fourflip/{name}/measured", indexes=index, columns=rr.Scalars.columns(scalars=outputs[:, j]))
        rec.send_columns(f"fourflip/{name}/fit", indexes=index,
                         columns=rr.Scalars.columns(scalars=outputs[:, j] - residuals[:, j]))
        parts = [residuals[:, j]] if base_residuals is None else [np.asarray(base_residuals)[order, j], residuals[:, j]]
        labels = ["residual"] if base_residuals is None else ["before (base model)", "after"]
        rec.log(f"fourflip/{name}/residual", rr.SeriesPoints(names=labels, colors=[_BEFORE, _AFTER][-len(parts):],
                                                            marker_sizes=[1.0] * len(parts)), static=True)
        rec.send_columns(f"fourflip/{name}/residual", indexes=index,
                         columns=rr.Scalars.columns(scalars=np.column_stack(parts)))
        rec.log(f"fourflip/{name}/residual/noise_band", rr.SeriesLines(names=["-noise", "+noise"],
                                                                       colors=[[160, 160, 160]] * 2), static=True)
        rec.send_columns(f"fourflip/{name}/residual/noise_band", indexes=index, columns=rr.Scalars.columns(
            scalars=np.broadcast_to([-noise[j], noise[j]], (len(sample), 2))))
    for name, values in (("platform_deg", phi), ("flip_deg", kappa)):
        rec.send_columns(f"fourflip/{name}", indexes=index, columns=rr.Scalars.columns(scalars=values))
    _log_bench(rec, result)
    keep = np.unique(np.linspace(0, len(sample) - 1, min(frames, len(sample))).astype(int))
    subset = columns_index(None if t is None else t[keep], keep) + [rr.TimeColumn("turntable_deg",
                                                                                   sequence=turntable[keep])]
    # R_W<-H = Rz(phi) Rx(kappa) (SPEC section 1): the turntable turns the cube's flip
    turntable = Rotation.from_euler("z", phi[keep][:, None], degrees=True)
    cube = Rotation.from_euler("x", kappa[keep][:, None], degrees=True)
    rec.send_columns("bench/turntable", indexes=subset, columns=rr.Transform3D.columns(quaternion=turntable.as_quat()))
    rec.send_columns("bench/turntable/cube", indexes=subset, columns=rr.Transform3D.columns(quaternion=cube.as_quat()))


def _log_bench(rec, result) -> None:
    """The static parts of the bench: field, turntable ring, housing, directions and their cones."""
    field_w = field_in_bench(result.dip_deg, result.azimuth_deg, 1.5)
    rec.log("bench/field", rr.Arrows3D(vectors=[field_w], colors=[FIELD_COLOR],
                                       labels=[f"field, dip {result.dip_deg:.2f} deg"]), static=True)
    phi = np.linspace(0.0, 2.0 * np.pi, 73)
    ring = np.column_stack([1.4 * np.cos(phi), 1.4 * np.sin(phi), np.full(phi.shape, -0.3)])
    zero = [[0.0, 0.0, -0.3], [1.4, 0.0, -0.3]]
    rec.log("bench/turntable/ring", rr.LineStrips3D([ring, zero], colors=[[120, 120, 120]]), static=True)
    # the cube's own axes unlabelled: its sensing directions, labelled, lie along them
    log_housing(rec, "bench/turntable/cube", color=(200, 200, 200), label="cube (housing)", scale=0.6,
                axis_labels=False)
    directions, strips, labels = [], [], []
    for j, channel in enumerate(result.channels):
        a = np.asarray(channel.direction, dtype=float)
        sigma = channel.direction_sigma_deg
        directions.append(a)
        labels.append(f"{channel.name}" + ("" if sigma is None else f" +-{sigma:.3f} deg"))
        if sigma is not None and _SIGMAS * sigma >= _CONE_MIN_DEG:
            strips.append((cone_strips(a, np.radians(_SIGMAS * sigma), 1.2), AXIS_COLORS[j % 3]))
    colors = [AXIS_COLORS[j % 3] for j in range(len(directions))]
    rec.log("bench/turntable/cube/directions", rr.Arrows3D(vectors=1.2 * np.array(directions), colors=colors,
                                                           labels=labels, show_labels=True), static=True)
    if strips:  # in the channel's colour, thin: a cone is no arrow
        rec.log("bench/turntable/cube/direction_cones", rr.LineStrips3D(
            [line for cone, _ in strips for line in cone], radii=[0.003],
            colors=[color for cone, color in strips for _ in cone]), static=True)


def log_diagnosis(rec, diagnosis: dict | None, *, t_s=None) -> None:
    """The diagnosis block (SPEC section 4): each step's residual rms as bars, the steps in words
    (stamped at the start of the recording, whose times ``t_s`` are, when it has any)."""
    if not diagnosis or not diagnosis.get("steps"):
        _at_start(rec, t_s)
        rec.log("diagnosis/log", rr.TextLog("no residual diagnosis (not run)"))
        return
    steps = diagnosis["steps"]
    rms = []
    for step in steps:
        value = step.get("residual_rms")
        rms.append(float(np.sqrt(np.mean(np.square(value)))) if value is not None else np.nan)
    floor = diagnosis.get("noise_floor")
    floor_rms = None if floor is None else float(np.sqrt(np.mean(np.square(floor))))
    # one bar chart per step (and the floor), so the legend names each bar: a chart's bars carry no names
    for k, step in enumerate(steps):
        rec.log(f"diagnosis/residual_rms/{_bar_name(k, step)}",
                rr.BarChart([rms[k]], abscissa=[k], color=_BAR_COLORS[k % len(_BAR_COLORS)]), static=True)
    if floor_rms is not None:
        rec.log("diagnosis/residual_rms/noise_floor", rr.BarChart([floor_rms], abscissa=[len(steps)],
                                                                  color=[150, 150, 150]), static=True)
    lines = [f"noise floor {floor_rms:.4g}" if floor_rms is not None else "no noise floor"]
    for k, step in enumerate(steps):
        what = _step_words(step)
        lines.append(f"step {k}: {what}: residual rms {rms[k]:.4g}"
                     + (f"; {step['evidence']}" if step.get("evidence") else ""))
    verdict = diagnosis.get("unexplained")
    lines.append("effects: " + (", ".join(diagnosis.get("effects", [])) or "none")
                 + {True: "; structure above the floor remains UNEXPLAINED", False: "; residual at the noise floor",
                    None: "; no floor to judge by"}[verdict])
    _at_start(rec, t_s)  # at the start of the replay, so the whole story is in view
    for line in lines:
        rec.log("diagnosis/log", rr.TextLog(line))


_BAR_COLORS = ([230, 120, 40], [30, 120, 220], [40, 170, 90], [170, 70, 200], [200, 60, 60])


def _step_words(step: dict) -> str:
    return str(step.get("added") or step.get("model", "step"))


def _bar_name(k: int, step: dict) -> str:
    """The entity name of step ``k``'s bar: its number and what it added, as an entity path part."""
    words = "".join(c if c.isalnum() else "_" for c in _step_words(step)).strip("_")
    return f"step{k}_{words or 'step'}"


def _cell_counts(directions: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cell of each direction, samples per cell)."""
    cell = np.argmax(directions @ cells.T, axis=1)
    return cell, np.bincount(cell, minlength=len(cells))


def _coverage_colors(counts: np.ndarray) -> np.ndarray:
    """Red (empty or one sample) through yellow to green (well covered), per count."""
    level = np.clip(np.log1p(counts) / np.log1p(20.0), 0.0, 1.0)[:, None]
    red, green = np.array([220, 50, 40]), np.array([40, 190, 70])
    return np.where(counts[:, None] == 0, [90, 90, 90], (1 - level) * red + level * green).astype(np.uint8)


def log_tumble(rec, result, *, mag, t_s=None, coverage_words: str | None = None,
               n_cells: int = 200) -> None:
    """The tumble before and after: raw points on the fitted ellipsoid, calibrated on the sphere.

    Parameters
    ----------
    result : calibrate.tumble.result.TumbleResult
        ``hard_iron`` (recording units), ``soft_iron`` (``m = S (raw - h)``), ``field_norm``.
    mag : ndarray (n, 3)
        Raw magnetometer samples, recording units.
    coverage_words : str, optional
        What the coverage misses, in words (logged to the diagnosis log).
    n_cells : int
        Cells of the coverage sphere.
    """
    mag = np.asarray(mag, dtype=float)
    hard = np.asarray(result.hard_iron, dtype=float)
    soft = np.asarray(result.soft_iron, dtype=float)
    norm = float(result.field_norm)
    m = (mag - hard) @ soft.T
    cells = sphere_cells(n_cells)
    cell, counts = _cell_counts(m / np.linalg.norm(m, axis=1, keepdims=True), cells)
    point_colors = _coverage_colors(counts)[cell]
    # both clouds at unit size: the raw one about the hard iron, scaled by det(S)^(1/3) / |m|
    raw_unit = abs(np.linalg.det(soft)) ** (1 / 3) / norm
    rec.log("tumble/raw/samples", rr.Points3D((mag - hard) * raw_unit, colors=point_colors, radii=0.01), static=True)
    u, sv, _ = np.linalg.svd(np.linalg.inv(soft))  # raw - h = S^-1 m: axes u, half sizes sv |m|
    if np.linalg.det(u) < 0:
        u[:, -1] *= -1
    rec.log("tumble/raw/ellipsoid", rr.Ellipsoids3D(
        half_sizes=[sv * norm * raw_unit], quaternions=[Rotation.from_matrix(u).as_quat()],
        colors=[[200, 200, 200, 60]], labels=["fitted ellipsoid (about the hard iron)"]), static=True)
    rec.log("tumble/calibrated/samples", rr.Points3D(m / norm, colors=point_colors, radii=0.01), static=True)
    rec.log("tumble/calibrated/sphere", rr.Ellipsoids3D(half_sizes=[[1.0, 1.0, 1.0]], colors=[[200, 200, 200, 60]],
                                                        labels=[f"|m| = field_norm ({norm:.4g})"]), static=True)
    for path in ("tumble/raw/axes", "tumble/calibrated/axes"):
        rec.log(path, rr.Arrows3D(vectors=1.3 * np.eye(3), colors=AXIS_COLORS, labels=["+X", "+Y", "+Z"]), static=True)
    rec.log("tumble/coverage", rr.Points3D(cells, colors=_coverage_colors(counts), radii=0.06,
                                           labels=[f"{c} samples" for c in counts], show_labels=False), static=True)
    sample = np.arange(len(mag))
    index = columns_index(t_s, sample)
    raw_ratio = np.linalg.norm(mag - hard, axis=1)
    rec.log("tumble/field_ratio", rr.SeriesPoints(names=["raw (about the hard iron, over its median)", "calibrated"],
                                                  colors=[_BEFORE, _AFTER], marker_sizes=[1.0, 1.0]), static=True)
    rec.send_columns("tumble/field_ratio", indexes=index, columns=rr.Scalars.columns(
        scalars=np.column_stack([raw_ratio / np.median(raw_ratio), np.linalg.norm(m, axis=1) / norm])))
    if coverage_words:
        _at_start(rec, t_s)
        rec.log("diagnosis/log", rr.TextLog(f"coverage: {coverage_words}"))


def log_installed(rec, result, *, bench_field, installed_field, t_s=None) -> None:
    """An installation: the product's field through the bench calibration alone (the product's iron makes
    the sphere an ellipsoid, off centre) and through the installed calibration (back on the sphere).

    Parameters
    ----------
    result : calibrate.installation.fit.InstallationCalibration
        Its ``field_magnitude`` (the site's |B|, field units) scales both clouds to one.
    bench_field, installed_field : ndarray (n, 3)
        The recording's field in H by the bench model and in the product's frame by the installed model,
        field units.
    """
    norm = float(result.field_magnitude)
    for name, field in (("bench", bench_field), ("installed", installed_field)):
        unit = np.asarray(field, dtype=float) / norm
        rec.log(f"installed/{name}/samples", rr.Points3D(unit[np.all(np.isfinite(unit), axis=1)], radii=0.01,
                                                          colors=[_BEFORE if name == "bench" else _AFTER]), static=True)
        rec.log(f"installed/{name}/sphere", rr.Ellipsoids3D(half_sizes=[[1.0, 1.0, 1.0]], colors=[[200, 200, 200, 60]],
                                                            labels=[f"site |B| ({norm:.4g})"]), static=True)
        rec.log(f"installed/{name}/axes", rr.Arrows3D(vectors=1.3 * np.eye(3), colors=AXIS_COLORS,
                                                      labels=["+X", "+Y", "+Z"]), static=True)
    rec.log("installed/field_ratio", rr.SeriesPoints(names=["bench calibration alone", "installed"],
                                                     colors=[_BEFORE, _AFTER], marker_sizes=[1.0, 1.0]), static=True)
    ratio = np.column_stack([np.linalg.norm(bench_field, axis=1), np.linalg.norm(installed_field, axis=1)]) / norm
    rec.send_columns("installed/field_ratio", indexes=columns_index(t_s, np.arange(len(ratio))),
                     columns=rr.Scalars.columns(scalars=ratio))


def log_fit_residuals(rec, *, prefix: str, residuals: dict, t_s=None) -> None:
    """Residuals of a platform (seed 001) or reference-field (seed 003) fit, one series per channel.

    Parameters
    ----------
    prefix : str
        Entity prefix: the kind (``platform3d``, ``reference``).
    residuals : dict of str to ndarray (n,)
        Channel name -> measured minus fitted, in sample order.
    """
    for name, values in residuals.items():
        values = np.asarray(values, dtype=float)
        rec.log(f"{prefix}/{name}", rr.SeriesPoints(names=[name], marker_sizes=[1.0]), static=True)
        rec.send_columns(f"{prefix}/{name}", indexes=columns_index(t_s, np.arange(len(values))),
                         columns=rr.Scalars.columns(scalars=values))


class LiveTumbleRecording:
    """The live tumble calibration (``compass live --calibrate tumble``) as MotionCal shows it.

    Every :meth:`update` logs the raw samples so far about the current hard iron (coloured by the
    coverage of their cell), the coverage sphere's cells, the coverage fraction and the fit's hard
    iron with its sigma band; :meth:`event` logs a line (what is missing, link events);
    :meth:`close` adds the final calibration (:func:`log_tumble`) and the layout.

    Parameters
    ----------
    target : str or path
        ``spawn`` or an .rrd file.
    n_cells : int
        Cells of the coverage sphere.
    max_points : int
        At most this many samples drawn per update (evenly spread).
    """

    def __init__(self, target, *, n_cells: int = 200, max_points: int = 3000):
        from ._stream import Recording

        self.recording = Recording(target, application_id=_layout.APPLICATION_IDS["live_tumble"])
        self.rec, self.cells, self.max_points = self.recording.rec, sphere_cells(n_cells), max_points
        self.rec.log("tumble/coverage_fraction", rr.SeriesLines(names=["coverage"]), static=True)
        for axis in "xyz":
            self.rec.log(f"tumble/hard_iron/{axis}", rr.SeriesLines(names=[f"hard iron {axis}"]), static=True)
            self.rec.log(f"tumble/hard_iron/{axis}/sigma_band", rr.SeriesLines(
                names=["-1 sigma", "+1 sigma"], colors=[[150, 150, 150]] * 2), static=True)

    @staticmethod
    def views() -> rrb.Container:
        return rrb.Horizontal(
            _layout.spatial(origin="/tumble/live", name="samples so far, about the hard iron (colour: coverage)",
                            eye=(2.2, 1.8, 1.4)),
            rrb.Vertical(_layout.spatial(origin="/tumble/coverage", name="coverage: cells seen (green)",
                                         eye=(2.2, 1.8, 1.4)),
                         _layout.series(origin="/tumble/coverage_fraction", name="coverage (fraction of the sphere)",
                                        legend=None),
                         _layout.series(origin="/tumble/hard_iron",
                                        name="hard iron +-1 sigma (recording units), converging")),
            _layout.text_log(origin="/events", name="what is still missing"), column_shares=[2, 2, 1],
            name="live tumble calibration")

    def _time(self, collector) -> None:
        rows = collector.rows
        self.rec.set_time("sample", sequence=len(rows))
        if rows:
            self.rec.set_time("t", duration=float(rows[-1][0]))

    def update(self, collector) -> None:
        """Log the state of a :class:`calibrate.tumble.collector.TumbleCollector`."""
        if collector.coverage is None:
            return
        rec = self.rec
        self._time(collector)
        mag = collector.samples[:, 1:4]
        mag = mag[np.unique(np.linspace(0, len(mag) - 1, min(len(mag), self.max_points)).astype(int))]
        fit = collector.fit
        d = mag - (fit.hard_iron if fit is not None else np.median(mag, axis=0))
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        cell, counts = _cell_counts(d / norm, self.cells)
        rec.log("tumble/live", rr.Points3D(d / np.median(norm), colors=_coverage_colors(counts)[cell], radii=0.01))
        rec.log("tumble/coverage", rr.Points3D(self.cells, colors=_coverage_colors(counts), radii=0.06))
        rec.log("tumble/coverage_fraction", rr.Scalars(collector.coverage.fraction))
        if fit is not None:
            for k, axis in enumerate("xyz"):
                h, s = fit.hard_iron[k], fit.hard_iron_sigma[k]
                rec.log(f"tumble/hard_iron/{axis}", rr.Scalars(h))
                rec.log(f"tumble/hard_iron/{axis}/sigma_band", rr.Scalars([h - s, h + s]))

    def event(self, collector, text: str) -> None:
        self._time(collector)
        self.rec.log("events", rr.TextLog(text))

    def close(self, result, mag) -> None:
        """Add the calibration (None: none was written), send the layout, finish the file."""
        views = [self.views()]
        if result is not None:
            self.rec.set_time("sample", sequence=0)
            log_calibration(self.rec, result, mag=mag, coverage_words=result.coverage.words())
            views.append(calibration_views("tumble"))
        self.rec.send_blueprint(_layout.blueprint(rrb.Tabs(*views), "sample"))
        self.recording.close()


def log_calibration_result(rec, result, recording_path, *, base_residuals=None, read_options=None) -> rrb.Container:
    """Log a calibration result of any kind; returns its views (for a blueprint).

    Parameters
    ----------
    result : calibrate.contract.Calibration
        The fit's result: ``calibration_kind``, ``diagnosis`` and per kind ``residuals`` and
        ``used(recording)`` (four-flip), ``coverage`` (tumble), ``residuals_mag`` (3-D platform),
        ``sensors`` with their ``residuals`` (reference fields).
    recording_path : path
        The recording the result was fitted to (read again here, with the fit's ``read_options``:
        column mapping and units, :class:`compass.io.table.ReadOptions`).
    base_residuals : callable, optional
        Four-flip: ``base_residuals(recording)`` gives the base model's residuals (n, c), or
        None when the diagnosis added nothing.
    """
    from ..io.table import read_table

    table = read_table(recording_path, read_options)
    kind = result.calibration_kind
    if kind == "tumble":
        from ..io.tumble import tumble_from_table

        recording = tumble_from_table(table)
        channels, arrays = ("mx", "my", "mz"), dict(mag=recording.mag, t_s=recording.t_s,
                                                     coverage_words=result.coverage.words())
    elif kind == "platform3d":
        from ..io.platform3d import platform3d_from_table

        recording, channels = platform3d_from_table(table), ("mx", "my", "mz")
        arrays = dict(prefix=kind, residuals=dict(zip(channels, result.residuals_mag.T)))
        _log_platform_poses(rec, recording.angles_deg)
    elif kind == "reference":
        residuals = {f"{s.name}/{c}": r for s in result.sensors for c, r in zip(s.channels, s.residuals.T)}
        channels, arrays = tuple(residuals), dict(prefix=kind, residuals=residuals)
    elif kind == "installed":
        from ..calibration import from_dict
        from ..io.installation import installation_from_table

        recording, bench = installation_from_table(table), from_dict(result.base_document).model
        raw = recording.raw[:, [recording.channels.index(c) for c in bench.channels]]
        channels, arrays = bench.channels, dict(bench_field=bench.field(raw, recording.temp_c)[0],
                                                installed_field=result.model.field(raw, recording.temp_c)[0],
                                                t_s=recording.t_s)
    elif kind == "fourflip":
        from ..io.fourflip import fourflip_from_table

        recording = fourflip_from_table(table)
        used = result.used(recording)
        channels = used.channels
        arrays = dict(platform_deg=used.platform_deg, flip_deg=used.flip_deg, outputs=used.outputs,
                      residuals=result.residuals, t_s=used.t_s,
                      base_residuals=None if base_residuals is None else base_residuals(recording))
    else:  # a kind this module does not draw yet: its diagnosis only
        log_diagnosis(rec, diagnosis_block(result))
        return rrb.Vertical(_diagnosis_views(), name=f"{kind} calibration")
    log_calibration(rec, result, **arrays)
    return calibration_views(kind, channels)


def record_calibration(target, recording_path, result, *, base_residuals=None, read_options=None) -> None:
    """Write one calibration to ``target`` (.rrd or ``spawn``) with its layout
    (:func:`log_calibration_result`), under its kind's application id (Rerun keeps a layout per
    application id: a tumble opened beside a four-flip would get the four-flip's)."""
    from ._stream import Recording

    kind = result.calibration_kind
    application_id = _layout.APPLICATION_IDS.get(kind, f"compass_calibrate_{kind}")
    with Recording(target, application_id=application_id) as out:
        views = log_calibration_result(out.rec, result, recording_path, base_residuals=base_residuals,
                                       read_options=read_options)
        out.rec.send_blueprint(_layout.blueprint(views, "turntable_deg" if kind == "fourflip" else "sample"))


def _log_platform_poses(rec, angles_deg) -> None:
    """The housing turned through the platform's poses (``R_W<-H = Rz(z) Ry(y) Rx(x)``)."""
    log_housing(rec, "platform3d/bench/housing", label="housing")
    r = Rotation.from_euler("ZYX", np.asarray(angles_deg, dtype=float), degrees=True)
    rec.send_columns("platform3d/bench/housing", indexes=columns_index(None, np.arange(len(r))),
                     columns=rr.Transform3D.columns(quaternion=r.as_quat()))
