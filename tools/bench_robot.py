"""Simulated robot-arm paths (compass.sim.robot) through our filter and VQF, side by side (issue 22).

Run: ``python tools/bench_robot.py [--seeds 5] [--first-seed 0] [--candidates A,B]`` (VQF from ``pip install -e
'.[bench]'``).

Issue 22's hidden check turns low-cost boards on an industrial robot's flange (point-to-point moves, dwells,
the board at a lever arm).  Each seed is a 60 s :func:`compass.sim.robot.simulate_robot` path read by
:func:`bench_broad.board_errors`' three boards (the board's errors drawn from the same seed), run through
bench_broad's pipeline (its :func:`bench_broad.ours`, FilterConfig from the initial rest, the hard-iron tracker)
with the candidates "defaults" and "lever arm" (``--candidates``: any of bench_broad's candidates and turn
variants), with "fitted": the gyro scale error of the board's calibration file (another path of the same board,
seed + :data:`CAL_SEED`, the rows at a sixth of the rate, through ``compass calibrate``'s gyro-aided path and the
calibration reader, :func:`bench_broad.file_values`, as tools/bench_gyro_scale.py; the truth is never read; the
``--candidates`` "mag_latency_s fitted" and "gyro_matrix fitted" read the same file), and through VQF given the
same samples (skipped with a word when not installed).  The scores: heading and inclination RMS (BROAD's error
quaternion, no offset removed) over the samples after the first 5 s, all of them and split into moves
(:attr:`MotionRecording.moving`) and dwells.  ``--ablate``: the means with each board error (and the lever arm, the
flange's translation) removed in turn, where a loss comes from; ``--files``: the calibration files' gyro scale
against the truth's, the same errors removed, what biases the fit; ``--mag-hz F``: every board's magnetometer converts
at F Hz, each reading held on the rows until the next (a board streaming faster than its magnetometer).
"""

from __future__ import annotations

import argparse
import sys
from copy import copy
from dataclasses import replace
from importlib.util import find_spec
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from bench_broad import (CANDIDATES, TURN_VARIANTS, _Simulated, _values_words, board_errors, file_values,  # noqa: E402
                         ours, vqf_online)
from compass.evaluation import orientation_errors  # noqa: E402
from compass.sim.motion import GRAVITY  # noqa: E402
from compass.sample_check import new_readings  # noqa: E402
from compass.sim.robot import simulate_robot  # noqa: E402

BOARDS = ("broad-like", "low-cost", "bad-accel")
CANDIDATES_RUN = "defaults,lever arm"
CAL_SEED = 1000
"""The calibration path of a board at seed ``s`` is the robot path ``s + CAL_SEED`` (the same SensorErrors)."""
PHASES = ("all", "moves", "dwells")
SKIP_S = 5.0
REMOVED = {  # name: (SensorErrors changes, simulate_robot path options)
    "gyro scale": ({"gyro_scale": (0.0, 0.0, 0.0)}, {}),
    "accel bias and scale": ({"accel_bias_m_s2": (0.0, 0.0, 0.0), "accel_scale": (0.0, 0.0, 0.0)}, {}),
    "magnetometer latency": ({"mag_latency_s": 0.0}, {}),
    "lever arm": ({}, {"lever_arm_range_m": (0.0, 0.0)}),
    "flange translation": ({}, {"reach_m": 0.0}),
}
FILE_REMOVED = ((),) + tuple((name,) for name in REMOVED) + (
    ("accel bias and scale", "lever arm", "flange translation"),)
"""``--files``' rows: nothing removed, each of :data:`REMOVED`, and every error of the accelerometer's gravity."""


def methods(names) -> dict:
    """Our candidates ``names`` (bench_broad's), "fitted" (the scale error and the accelerometer's correction of the
    trial's calibration file, ``trial.fitted``: :func:`calibration`), "fitted, accel as read" (its scale error only)
    and VQF when it is installed (as read, and given the file's accelerometer correction)."""
    out = {name: ours(*(CANDIDATES | TURN_VARIANTS)[name]) for name in names}
    out["fitted, accel as read"] = ours({"gyro_scale_error": "fitted"})
    out["fitted"] = ours({"gyro_scale_error": "fitted", "accel_correction": "fitted"})
    if find_spec("vqf") is None:
        print("skipping vqf: not installed (pip install -e '.[bench]')")
    else:
        out["vqf"] = vqf_online
        out["vqf, accel fitted"] = vqf_accel_fitted
    return out


def vqf_accel_fitted(trial):
    """VQF given the file's accelerometer correction too (``A (a - b)``; as read where the file has none)."""
    correction = trial.fitted["accel_correction"]
    if correction is None:
        return vqf_online(trial)
    matrix, offset, _ = correction
    given = copy(trial)
    given.accel_m_s2 = (trial.accel_m_s2 - np.asarray(offset)) @ np.asarray(matrix).T
    return vqf_online(given)


def scores(trial, quat_enu) -> dict[str, tuple[float, float]]:
    """``{phase: (heading RMS, inclination RMS)}``, deg, over the samples after :data:`SKIP_S`."""
    ref = Rotation.from_quat(trial.ref_quat_enu, scalar_first=True)
    heading, _, inclination = orientation_errors(Rotation.from_quat(quat_enu, scalar_first=True), ref)
    late = trial.t_s >= SKIP_S
    rows = {"all": late, "moves": late & trial.movement, "dwells": late & ~trial.movement}
    return {p: (float(np.sqrt(np.mean(heading[k] ** 2))), float(np.sqrt(np.mean(inclination[k] ** 2))))
            for p, k in rows.items()}


def calibration(seed, errors, path) -> dict:
    """The values of the board's calibration file (:func:`bench_broad.file_values`) from the robot path
    ``seed + CAL_SEED`` with the board's ``errors`` and the ``path`` options, the rows at a sixth of the rate (a
    magnetometer that holds its readings, ``errors.mag_rate_hz``: its new readings, as ``compass.io.tumble`` reads a
    recording)."""
    cal = simulate_robot(seed + CAL_SEED, errors=errors, **path)
    keep = np.zeros(len(cal.t_s), bool)
    keep[::6] = True
    if errors.mag_rate_hz > 0.0:
        keep = new_readings(cal.mag_ut)
    return file_values(cal.t_s, cal.gyro_rad_s, cal.accel_m_s2, cal.mag_ut, keep)


def file_words(values, errors) -> str:
    """The file's scale error (the filter's, in quadrature with the default) and gyro matrix beside the truth's."""
    true = np.asarray(errors.gyro_scale)
    return (f"scale error {100 * values['gyro_scale_error']:.2f} % (truth's RMS {100 * np.sqrt(np.mean(true**2)):.2f}"
            f" %), {_values_words(values)}; true diag " + ", ".join(f"{v:+.2f}" for v in 100 * (1 / (1 + true) - 1))
            + " %")


def removing(board, seed, removed) -> tuple:
    """The board's SensorErrors and the path options with the errors of :data:`REMOVED` named in ``removed`` out."""
    errors = {k: v for name in removed for k, v in REMOVED[name][0].items()}
    path = {k: v for name in removed for k, v in REMOVED[name][1].items()}
    return replace(board_errors(board, seed), **errors), path


def path_words(rec) -> str:
    """A path in words: its moves (runs of :attr:`MotionRecording.moving`), the median turn of one (the true rate's
    size integrated over it, deg), the peak rate (deg/s) and the peak ``||f| - g|`` (m/s^2)."""
    dt = np.diff(rec.t_s, prepend=rec.t_s[0])
    speed = np.linalg.norm(rec.rate_rad_s, axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rec.moving.astype(int), [0]])))
    turns = [np.degrees(np.sum(speed[a:b] * dt[a:b])) for a, b in zip(edges[::2], edges[1::2])]
    lift = np.abs(np.linalg.norm(rec.specific_force_m_s2, axis=1) - GRAVITY)
    return (f"{len(turns)} moves, median turn {np.median(turns):.0f} deg, peak rate {np.degrees(speed.max()):.0f} "
            f"deg/s, peak ||f| - g| {lift.max():.1f} m/s^2")


def run(seeds, runners, removed=(), quiet=False, mag_hz=0.0) -> dict:
    """``{board: {seed: {method: {phase: (heading, inclination)}}}}``, the errors of :data:`REMOVED` named in
    ``removed`` taken out of the board (or the path); ``mag_hz``: the magnetometer converts at that rate, each
    reading held on the rows until the next (``SensorErrors.mag_rate_hz``; 0: every row)."""
    out = {}
    for board in BOARDS:
        out[board] = {}
        for seed in seeds:
            board_seed, path = removing(board, seed, removed)
            board_seed = replace(board_seed, mag_rate_hz=mag_hz)
            rec = simulate_robot(seed, errors=board_seed, **path)
            if not quiet and board == BOARDS[0]:
                print(f"  path {seed}: {path_words(rec)}", flush=True)
            trial = _Simulated(rec, f"robot {seed}")
            trial.fitted = calibration(seed, board_seed, path)
            out[board][seed] = {name: scores(trial, fn(trial)) for name, fn in runners.items()}
            if not quiet:
                print(f"  {board} seed {seed}: " + ", ".join(f"{m} {v['all'][0]:.3f}/{v['all'][1]:.3f}"
                                                             for m, v in out[board][seed].items()), flush=True)
                print(f"    its file: {file_words(trial.fitted, board_seed)}", flush=True)
    return out


def ablation(seeds, runners) -> None:
    """Per board, the mean over seeds by phase with each of :data:`REMOVED` taken out in turn."""
    names = list(runners)
    print("\nwhere the errors come from: mean over the seeds, each error removed in turn; heading / inclination RMS, "
          "deg, in the moves | in the dwells")
    print(f"{'board, removed':36s} " + " ".join(f"{m:>33s}" for m in names))
    for removed in ("nothing",) + tuple(REMOVED):
        results = run(seeds, runners, () if removed == "nothing" else (removed,), quiet=True)
        for board, rows in results.items():
            cells = [np.mean([[*row[m]["moves"], *row[m]["dwells"]] for row in rows.values()], axis=0) for m in names]
            print(f"{board + ', ' + removed:36s} " + " ".join(
                f"{c[0]:6.3f} /{c[1]:6.3f} |{c[2]:6.3f} /{c[3]:6.3f}".rjust(33) for c in cells), flush=True)


def file_ablation(seeds) -> None:
    """Per board, the calibration file's gyro scale against the truth's, means over the seeds, with the errors of
    each of :data:`FILE_REMOVED` taken out (of the calibration path; nothing is scored)."""
    print("\nthe calibration file's gyro scale (mean over the seeds): the filter's scale error, the truth's RMS over "
          "the axes,\nthe fitted matrix's diagonal (as written) less the true correction's, RMS, and its stated "
          "sigma, %")
    print(f"{'board, removed':75s} {'file':>6s} {'truth':>6s} {'diag error':>10s} {'sigma':>6s}")
    for board in BOARDS:
        for removed in FILE_REMOVED:
            cells = []
            for seed in seeds:
                errors, path = removing(board, seed, removed)
                values = calibration(seed, errors, path)
                matrix, sigma = (np.full((3, 3), np.nan) if a is None else np.array(a, dtype=float)
                                 for a in values["fitted"])  # None (not fitted, not seen): nan
                true = 1.0 / (1.0 + np.asarray(errors.gyro_scale)) - 1.0
                cells.append([values["gyro_scale_error"], np.sqrt(np.mean(np.asarray(errors.gyro_scale) ** 2)),
                              np.sqrt(np.mean((np.diag(matrix) - 1.0 - true) ** 2)),
                              np.sqrt(np.mean(np.diag(sigma) ** 2))])
            print(f"{board + ', ' + (' and '.join(removed) or 'nothing'):75s} "
                  + " ".join(f"{100 * v:{w}.2f}" for v, w in zip(np.nanmean(cells, axis=0), (6, 6, 10, 6))),
                  flush=True)


def table(results, names) -> None:
    """Per board: each seed and the mean, ``heading / inclination`` per method, for each phase."""
    for board, rows in results.items():
        for phase in PHASES:
            print(f"\n{board}, {phase} (after the first {SKIP_S:g} s): heading RMS / inclination RMS, deg")
            widths = [max(17, len(m)) for m in names]
            print(f"{'seed':>6s} " + " ".join(m.rjust(w) for m, w in zip(names, widths)))
            cells = {seed: [row[m][phase] for m in names] for seed, row in rows.items()}
            cells["mean"] = np.mean(list(cells.values()), axis=0).tolist()
            for seed, row in cells.items():
                print(f"{seed!s:>6s} " + " ".join(f"{h:8.3f} /{i:7.3f}".rjust(w) for (h, i), w in zip(row, widths)))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="number of seeds (paths)")
    parser.add_argument("--first-seed", type=int, default=0, help="seeds first-seed to first-seed + seeds - 1")
    parser.add_argument("--candidates", default=CANDIDATES_RUN, help=f"comma-separated (default: {CANDIDATES_RUN})")
    parser.add_argument("--ablate", action="store_true",
                        help="only the means with each board error (and the lever arm) removed in turn")
    parser.add_argument("--files", action="store_true",
                        help="only the calibration files' gyro scale against the truth's, board errors removed")
    parser.add_argument("--mag-hz", type=float, default=0.0,
                        help="the magnetometer's own rate, Hz: each reading held until the next, on the scored and the "
                             "calibration path (a board streaming faster than its magnetometer; default: every row)")
    args = parser.parse_args(argv)
    if args.mag_hz and (args.ablate or args.files):
        parser.error("--mag-hz runs the table of every board: not with --ablate or --files")
    names = [c.strip() for c in args.candidates.split(",") if c.strip()]
    unknown = [c for c in names if c not in CANDIDATES | TURN_VARIANTS]
    if unknown or not names:
        parser.error(f"--candidates: unknown {unknown}")
    runners = methods(names)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    held = f", the magnetometer held at {args.mag_hz:g} Hz" if args.mag_hz else ""
    print(f"robot-arm paths (compass.sim.robot, 60 s, seeds {seeds.start}-{seeds.stop - 1}), {len(BOARDS)} boards"
          + held)
    if args.files:
        file_ablation(seeds)
    elif args.ablate:
        ablation(seeds, runners)
    else:
        table(run(seeds, runners, mag_hz=args.mag_hz), list(runners))
    return 0


if __name__ == "__main__":
    sys.exit(main())
