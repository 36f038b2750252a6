"""A flip set down turned on the turntable: the four-flip calibration beside a baseline revision, one run.

Each case is a simulated three-channel session (``compass.sim.fourflip.simulate_fourflip``, clean) whose flips'
turntable angles are then read from another zero: the true angle is ``platform_deg + D_k``, so the recording's
``platform_deg`` is the true one less ``D_k`` (flip 0's zero is the field azimuth's).  The same recordings go through
``calibrate_fourflip(diagnose=True)`` of this tree and of the baseline (``git archive``, default 045ed30: before the
diagnosis had ``turntable_zero``), each in its own process.  Printed per case and tree: the effects named, how many
recordings were called unexplained, the RMS direction error against the simulator's directions (deg) and its RMS
over the file's direction sigma (1: honest; a widened sigma makes it small).

Cases: one flip (180) 3, 8 and 14 deg off (seeds 3 and 5, the figures of docs/calibration.md), flips 90 and 270
8 deg either way (seed 3), and the flips' zeros drawn at 0.3-1 deg each (seeds 0-9, as the simulator's
``turntable_zero`` effect draws them at scale 1).

Run: ``python tools/bench_turntable_zero.py [--baseline REF|none]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

DRAWN_SEEDS = tuple(range(10))
CASES = {
    **{f"flip 180 {d:g} deg off": [(seed, (0.0, 0.0, d, 0.0)) for seed in (3, 5)] for d in (3.0, 8.0, 14.0)},
    "flips 90, 270 at +8, -8 deg": [(3, (0.0, 8.0, 0.0, -8.0))],
}


def _drawn(seed: int) -> tuple:
    """Flips 90-270's zeros drawn as the simulator's effect draws them at scale 1: 0.3-1 deg, either sign."""
    rng = np.random.default_rng([seed, 7])
    return (0.0, *(rng.choice([-1.0, 1.0], 3) * rng.uniform(0.3, 1.0, 3)))


def _run_case(seed: int, zeros) -> dict:
    """One recording calibrated by the tree on the path: what the table prints of it."""
    from calibrate import calibrate_fourflip
    from calibrate.contract import CannotCalibrate
    from compass.sim.fourflip import simulate_fourflip

    session = simulate_fourflip(seed=seed)
    rec = session.recording()
    rec = replace(rec, platform_deg=np.mod(rec.platform_deg - np.asarray(zeros)[rec.flip_index], 360.0))
    try:
        result = calibrate_fourflip(rec, diagnose=True)
    except CannotCalibrate:
        return {"effects": ["(refused)"], "unexplained": False, "err": [], "ratio": []}
    truth = np.asarray(session.truth["directions"])
    err = np.degrees(np.arccos(np.clip(np.sum(result.directions * truth, axis=1), -1.0, 1.0)))
    sigma = np.array([c.direction_sigma_deg for c in result.channels])
    return {"effects": result.diagnosis["effects"], "unexplained": bool(result.diagnosis["unexplained"]),
            "err": err.tolist(), "ratio": (err / sigma).tolist()}


def worker() -> None:
    """Every case's recordings, one JSON line each (case, row)."""
    cases = dict(CASES, **{"zeros drawn 0.3-1 deg": [(s, _drawn(s)) for s in DRAWN_SEEDS]})
    for name, runs in cases.items():
        for seed, zeros in runs:
            print(json.dumps({"case": name, **_run_case(seed, zeros)}), flush=True)


def _rows(tree: Path | None) -> list[dict]:
    from _baseline import tree_env

    env = tree_env(tree if tree is not None else ROOT)
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker"], env=env, capture_output=True,
                         text=True, cwd=tempfile.gettempdir(), timeout=3600)
    if out.returncode != 0:
        raise SystemExit(f"bench_turntable_zero: the worker of {tree or ROOT} failed:\n{out.stderr}")
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def _summary(rows: list[dict]) -> str:
    named = {}
    for r in rows:
        key = ", ".join(r["effects"]) or "none"
        named[key] = named.get(key, 0) + 1
    err = np.concatenate([r["err"] for r in rows])
    ratio = np.concatenate([r["ratio"] for r in rows])
    unexplained = sum(r["unexplained"] for r in rows)
    words = "; ".join(f"{k} {v}/{len(rows)}" for k, v in named.items())
    rms = (lambda x: f"{np.sqrt(np.mean(x**2)):>9.4f}" if len(x) else f"{'-':>9}")  # noqa: E731
    return f"{words:<26} {unexplained:>3}/{len(rows):<3} {rms(err)} {rms(ratio)}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default="045ed30", help="git revision to compare with, or none")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        worker()
        return 0
    from _baseline import export_tree

    with tempfile.TemporaryDirectory() as folder:
        trees = {"this": None} | ({} if args.baseline == "none" else
                                  {f"base {args.baseline}": export_tree(args.baseline, Path(folder))})
        results = {name: _rows(tree) for name, tree in trees.items()}
    print("A flip set down turned: calibrate_fourflip(diagnose=True), three channels, directions against the truth")
    print(f"{'case':<30}{'tree':<14}{'named':<27}{'unexpl.':>7} {'err deg':>9} {'err/sig':>9}")
    for case in dict.fromkeys(r["case"] for r in results["this"]):
        for name, rows in results.items():
            print(f"{case:<30}{name:<14}{_summary([r for r in rows if r['case'] == case])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
