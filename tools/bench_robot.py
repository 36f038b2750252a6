"""Simulated robot-arm paths (compass.sim.robot) through our filter and VQF, side by side (issue 22).

Run: ``PYTHONPATH=$PWD:/tmp/lever_pkgs python tools/bench_robot.py [--seeds 5] [--first-seed 0] [--candidates A,B]``.

Issue 22's hidden check turns low-cost boards on an industrial robot's flange (point-to-point moves, dwells,
the board at a lever arm).  Each seed is a 60 s :func:`compass.sim.robot.simulate_robot` path read by
:func:`bench_broad.board_errors`' two boards (the board's errors drawn from the same seed), run through
bench_broad's pipeline (its :func:`bench_broad.ours`, FilterConfig from the initial rest, the hard-iron tracker)
with the candidates "defaults" and "lever arm" (``--candidates``: any of bench_broad's candidates and turn
variants), and through VQF given the same samples (skipped with a word when
not installed).  The scores: heading and inclination RMS (BROAD's error quaternion, no offset removed) over the
samples after the first 5 s, all of them and split into moves (:attr:`MotionRecording.moving`) and dwells.
``--ablate``: the means with each board error (and the lever arm) removed in turn, where a loss comes from.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from importlib.util import find_spec
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from bench_broad import CANDIDATES, TURN_VARIANTS, _Simulated, board_errors, ours, vqf_online  # noqa: E402
from compass.evaluation import orientation_errors  # noqa: E402
from compass.sim.robot import simulate_robot  # noqa: E402

BOARDS = ("broad-like", "low-cost")
CANDIDATES_RUN = "defaults,lever arm"
PHASES = ("all", "moves", "dwells")
SKIP_S = 5.0
REMOVED = {  # name: (SensorErrors changes, simulate_robot path options)
    "gyro scale": ({"gyro_scale": (0.0, 0.0, 0.0)}, {}),
    "accel bias and scale": ({"accel_bias_m_s2": (0.0, 0.0, 0.0), "accel_scale": (0.0, 0.0, 0.0)}, {}),
    "magnetometer latency": ({"mag_latency_s": 0.0}, {}),
    "lever arm": ({}, {"lever_arm_range_m": (0.0, 0.0)}),
}


def methods(names) -> dict:
    """Our candidates ``names`` (bench_broad's) and VQF when it is installed."""
    out = {name: ours(*(CANDIDATES | TURN_VARIANTS)[name]) for name in names}
    if find_spec("vqf") is None:
        print("skipping vqf: not installed (PYTHONPATH=$PWD:/tmp/lever_pkgs, or pip install -e '.[bench]')")
    else:
        out["vqf"] = vqf_online
    return out


def scores(trial, quat_enu) -> dict[str, tuple[float, float]]:
    """``{phase: (heading RMS, inclination RMS)}``, deg, over the samples after :data:`SKIP_S`."""
    ref = Rotation.from_quat(trial.ref_quat_enu, scalar_first=True)
    heading, _, inclination = orientation_errors(Rotation.from_quat(quat_enu, scalar_first=True), ref)
    late = trial.t_s >= SKIP_S
    rows = {"all": late, "moves": late & trial.movement, "dwells": late & ~trial.movement}
    return {p: (float(np.sqrt(np.mean(heading[k] ** 2))), float(np.sqrt(np.mean(inclination[k] ** 2))))
            for p, k in rows.items()}


def run(seeds, runners, removed=(), quiet=False) -> dict:
    """``{board: {seed: {method: {phase: (heading, inclination)}}}}``, the errors of :data:`REMOVED` named in
    ``removed`` taken out of the board (or the path)."""
    errors = {k: v for name in removed for k, v in REMOVED[name][0].items()}
    path = {k: v for name in removed for k, v in REMOVED[name][1].items()}
    out = {}
    for board in BOARDS:
        out[board] = {}
        for seed in seeds:
            rec = simulate_robot(seed, errors=replace(board_errors(board, seed), **errors), **path)
            trial = _Simulated(rec, f"robot {seed}")
            out[board][seed] = {name: scores(trial, fn(trial)) for name, fn in runners.items()}
            if not quiet:
                print(f"  {board} seed {seed}: " + ", ".join(f"{m} {v['all'][0]:.3f}/{v['all'][1]:.3f}"
                                                             for m, v in out[board][seed].items()), flush=True)
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
    args = parser.parse_args(argv)
    names = [c.strip() for c in args.candidates.split(",") if c.strip()]
    unknown = [c for c in names if c not in CANDIDATES | TURN_VARIANTS or c.endswith("fitted")]
    if unknown or not names:
        parser.error(f"--candidates: unknown or fitted (no tumble recording here) {unknown}")
    runners = methods(names)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"robot-arm paths (compass.sim.robot, 60 s, seeds {seeds.start}-{seeds.stop - 1}), two boards")
    if args.ablate:
        ablation(seeds, runners)
    else:
        table(run(seeds, runners), list(runners))
    return 0


if __name__ == "__main__":
    sys.exit(main())
