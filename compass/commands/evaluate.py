"""``compass evaluate TRIAL.mat... [--cal CAL.json] [--plot DIR]``: attitude error against ground truth.

Runs the toolkit's causal pipeline (optional calibration, hard-iron step tracker, the live filter with
its magnetic gate) on a BROAD trial (gyro, accelerometer, magnetometer and an optical reference) and
reports BROAD's heading and inclination errors during the movement phase: RMS with the reference's
heading offset kept (BROAD's own figure) and removed, per time segment, and as a plot.
"""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path

import numpy as np

from ..viz import add_rerun_option, check_rerun_target
from compass.calibration import load as load_calibration

SEGMENT_S = 20.0


def register(sub) -> None:
    p = sub.add_parser(
        "evaluate", help="heading and inclination error of the attitude pipeline against a ground truth (BROAD trial)",
        description="Run calibration + hard-iron tracker + live filter on a BROAD trial (.mat) and report BROAD's "
                    "heading and inclination errors during the movement phase, with the reference's constant "
                    "heading offset kept (BROAD's figure) and removed.")
    p.add_argument("trial", nargs="+", help="BROAD trial(s), MATLAB .mat (imu_gyr, imu_acc, imu_mag, opt_quat, "
                                            "movement, ...); a pattern ('data/*.mat') is expanded here too")
    p.add_argument("--cal", help="calibration JSON for the magnetometer (tumble form, frame of the accelerometer)")
    p.add_argument("--plot", metavar="DIR", help="write DIR/<trial>_errors.png: errors over time")
    p.add_argument("--no-gate", action="store_true", help="use every field sample (no magnetic-disturbance gate)")
    p.add_argument("--no-hard-iron", action="store_true", help="do not track hard-iron steps")
    add_rerun_option(p)
    p.add_argument("--force", action="store_true", help="overwrite an existing --rerun file or plot")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import BadInput

    trials = expand_trials(args.trial)
    if args.rerun is not None and len(trials) > 1:
        raise BadInput(f"--rerun records one trial; {len(trials)} given ({', '.join(trials[:3])}"
                       f"{', ...' if len(trials) > 3 else ''})")
    target = check_rerun_target(args.rerun, args.force)
    from ..io.progress import working

    scores = []
    what = f"evaluating {Path(trials[0]).name}" if len(trials) == 1 else f"evaluating {len(trials)} trials"
    with working(what, total=len(trials) if len(trials) > 1 else None) as tally:
        for trial in trials:
            errors, result = evaluate_file(trial, cal=args.cal, plot=args.plot, gate=not args.no_gate,
                                           hard_iron=not args.no_hard_iron, force=args.force, tally=tally)
            scores.append((Path(trial).stem, errors))
            tally.advance()
    if target is not None:
        from ..io.broad import read_broad
        from ..viz.attitude import record_evaluation

        record_evaluation(target, read_broad(trials[0]), result, errors)
        print(f"  wrote {target}")
    if len(scores) > 1:
        print(f"{len(scores)} trials: heading RMS (offset kept), heading RMS (offset removed), inclination RMS, deg")
        for name, e in scores:
            print(f"  {name:<45} {e.heading_rms_deg:7.2f} {e.heading_rms_offset_removed_deg:7.2f} "
                  f"{e.inclination_rms_deg:7.2f}")
    return 0


def expand_trials(given) -> list[str]:
    """The trial files named: each as given, or a pattern (``*``, ``?``, ``[``) expanded, in order.

    Raises
    ------
    BadInput
        A pattern that matches no file (a shell passes it on unexpanded, as Windows' always does).
    """
    import glob

    from ..cli import BadInput

    trials = []
    for name in given:
        if Path(name).exists() or not any(c in name for c in "*?["):
            trials.append(name)
            continue
        found = sorted(glob.glob(name))
        if not found:
            raise BadInput(f"{name}: no file matches")
        trials += found
    return trials


def evaluate_file(trial_path, *, cal=None, plot=None, gate=True, hard_iron=True, force=False, tally=None):
    """Evaluate one trial, print the report, optionally plot; returns ``(ErrorSeries, PipelineResult)``.

    ``tally`` is the command's progress line (:class:`compass.io.progress.Tally`): the report is printed
    with it hidden.

    Raises
    ------
    RecordingError, BadInput
        Bad input (exit status 2 on the command line).
    """
    from ..cli import BadInput
    from ..evaluation import error_series, run_pipeline
    from ..io.atomic import check_writable
    from ..io.broad import read_broad

    plot_dir = None
    if plot is not None:
        plot_dir = Path(plot)
        if plot_dir.exists() and not plot_dir.is_dir():
            raise BadInput(f"--plot {plot}: is a file, expected a folder")
    model = None
    if cal is not None:
        try:
            model = load_calibration(cal).model
        except ValueError as exc:
            raise BadInput(str(exc)) from None
        if model.form != "tumble":  # a bench calibration's channels are another sensor, not BROAD's imu_mag
            raise BadInput(f"{cal}: expected a tumble calibration of the trial's magnetometer (mx,my,mz), got a "
                           f"bench calibration of channels {', '.join(model.channels)}")
    trial = read_broad(trial_path)
    if plot_dir is not None:
        check_writable(plot_dir / f"{trial.name}_errors.png", force)
    try:
        result = run_pipeline(trial, model, gate=gate, hard_iron=hard_iron)
        errors = error_series(result.quat_enu, trial.ref_quat_enu, trial.movement, trial.rate_hz)
    except ValueError as exc:
        raise BadInput(f"{trial_path}: {exc}") from None
    with nullcontext() if tally is None else tally.hidden():
        _report(trial, errors, result, plot_dir)
    return errors, result


def _report(trial, errors, result, plot_dir) -> None:
    """The trial's scores on stdout, and its plot."""
    from ..evaluation import METRIC

    print(f"{trial.name}: {result.method}; reference |B| {result.field_ut:.1f} uT, dip {result.dip_deg:.1f} deg")
    print(f"  {METRIC}")
    print(f"  scored {int(errors.scored.sum())} samples ({errors.scored.sum() / trial.rate_hz:.0f} s of movement, "
          f"{int((trial.movement & ~trial.ref_valid).sum())} reference dropouts skipped)")
    print(f"  heading RMS {errors.heading_rms_deg:.2f} deg (offset kept: BROAD's figure); "
          f"{errors.heading_rms_offset_removed_deg:.2f} deg with the constant heading offset "
          f"{errors.heading_offset_deg:+.2f} deg removed (fitted on the same samples)")
    print(f"  inclination RMS {errors.inclination_rms_deg:.2f} deg")
    if result.hard_iron is not None:
        steps = result.hard_iron
        print("  hard-iron steps: " + ("none" if not len(steps.step_t_s) else ", ".join(
            f"{t:.1f} s -> ({', '.join(f'{v:+.1f}' for v in b)}) uT" for t, b in zip(steps.step_t_s,
                                                                                     steps.step_offset_ut))))
    print(f"  field used on {100 * np.mean(~result.disturbed[trial.movement]):.0f} % of the movement samples")
    print(f"  over time (movement, {SEGMENT_S:.0f} s segments): start_s heading_rms heading_rms_offset_removed "
          f"inclination_rms")
    t = errors.t_s
    removed = errors.heading_offset_removed_deg
    for start in np.arange(t[errors.scored][0], t[errors.scored][-1], SEGMENT_S):
        seg = errors.scored & (t >= start) & (t < start + SEGMENT_S)
        if seg.any():
            print(f"    {start:7.1f} {_rms(errors.heading_deg[seg]):8.2f} {_rms(removed[seg]):8.2f} "
                  f"{_rms(errors.inclination_deg[seg]):8.2f}")
    if plot_dir is not None:
        path = _plot(plot_dir, trial, errors, result)
        print(f"  wrote {path}")


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def _plot(folder: Path, trial, errors, result) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io.atomic import save_figure

    folder.mkdir(parents=True, exist_ok=True)
    t = errors.t_s
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    kept = np.where(trial.movement, errors.heading_deg, np.nan)
    axes[0].plot(t, kept, lw=0.7, label=f"offset kept (BROAD), RMS {errors.heading_rms_deg:.2f}")
    axes[0].plot(t, np.where(trial.movement, errors.heading_offset_removed_deg, np.nan), lw=0.7,
                 label=f"offset {errors.heading_offset_deg:+.2f} removed, RMS {errors.heading_rms_offset_removed_deg:.2f}")
    axes[0].set_ylabel("heading error, deg")
    axes[1].plot(t, np.where(trial.movement, errors.inclination_deg, np.nan), lw=0.7, color="C2",
                 label=f"RMS {errors.inclination_rms_deg:.2f}")
    axes[1].set_ylabel("inclination error, deg")
    axes[2].plot(t, np.linalg.norm(trial.mag_ut, axis=1), lw=0.6, color="0.6", label="|B| measured")
    axes[2].plot(t, np.linalg.norm(result.field_h_ut, axis=1), lw=0.6, color="C0", label="|B| after hard-iron track")
    axes[2].plot(t, np.where(result.disturbed, result.field_ut, np.nan), ".", ms=1, color="C3", label="gate closed")
    axes[2].set_ylabel("uT")
    axes[2].set_xlabel("time, s")
    for ax in axes:
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{trial.name}: {result.method} (BROAD metric, movement phase)", fontsize=10)
    fig.tight_layout()
    path = folder / f"{trial.name}_errors.png"
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path
