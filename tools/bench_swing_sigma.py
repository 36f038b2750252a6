"""Why a clean installation swing's hard-iron sigma under-covers: error against sigma, per component.

Seeded Monte Carlo of :class:`calibrate.installation.InstallationCalibrator` on clean swings
(:func:`compass.sim.installation.simulate_installation`, on the true bench model, as in
``tools/bench_kinds_loop.py``), varying one thing at a time from the benchmark's swing (+-10 deg,
2000 rows, the bench's noise): the tilt, the number of rows, and which noise is there (the
magnetometer's alone, none).  Per hard-iron component (H frame): the mean error
(uT) with its standard error over seeds, the mean and the spread (SD) of error/sigma, and the RMS of
error/sigma (1: honest).  A spread near or under 1 with a mean away from 0 is a bias, not a sigma
too small; a bias that stays as the rows grow is one the estimator does not average away.

Each case beside a baseline revision in the same run (default ``75a6b36``, before
:func:`calibrate.installation.model.debiased`).

Usage::

    python tools/bench_swing_sigma.py [--n 12] [--seed 0] [--baseline REF|none]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

BASELINE = "75a6b36"

# (label, tilt deg, rows, magnetometer noise scale, accelerometer noise g)
CASES = (("swing +-10, 2000 rows", 10.0, 2000, 1.0, 0.002),
         ("tilt +-5", 5.0, 2000, 1.0, 0.002),
         ("tilt +-20", 20.0, 2000, 1.0, 0.002),
         ("500 rows", 10.0, 500, 1.0, 0.002),
         ("8000 rows", 10.0, 8000, 1.0, 0.002),
         ("magnetometer noise only", 10.0, 2000, 1.0, 0.0),
         ("no noise", 10.0, 2000, 0.0, 0.0))


def run_one(seed: int, tilt_deg: float, n: int, mag_scale: float, accel_g: float) -> tuple[np.ndarray, np.ndarray]:
    """(error uT, sigma uT) of the hard iron, shape (3,) each, for one clean swing."""
    from calibrate.installation import InstallationCalibrator
    from compass.calibration import from_dict, model_to_dict
    from compass.io.installation import InstallationRecording
    from compass.sim.fourflip import simulate_fourflip
    from compass.sim.installation import random_installation, simulate_installation, true_model

    truth = simulate_fourflip(seed=seed).truth
    # the bench model states the noise the recording has (1e-4 of the bench's for none: the fit divides by it)
    stated = truth | {"noise": (np.asarray(truth["noise"]) * max(mag_scale, 1e-4)).tolist()}
    bench = from_dict(model_to_dict(true_model(stated)) | {"format": "compass-calibration/1", "model": "channels"})
    inst = random_installation(500 + seed, yaw_deg=0.0)
    sim = simulate_installation(truth | {"noise_ut": truth["noise_ut"] * mag_scale}, inst, kind="swing", n=n,
                                max_tilt_deg=tilt_deg, seed=700 + seed, accel_noise_g=accel_g)
    rec = InstallationRecording("sim", sim.kind, sim.channels, sim.outputs, sim.accel, sim.t_s, None, None, False,
                                np.arange(n), {})
    res = InstallationCalibrator(base=bench, accel_noise_g=max(accel_g, 1e-6)).fit(rec)  # likewise
    return res.hard_iron_ut - inst.hard_iron_ut, res.hard_iron_sigma_ut


def _spawn(tree: Path | None, seed: int, n: int) -> subprocess.Popen:
    from _baseline import tree_env

    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--seed", str(seed), "--n", str(n)]
    env = tree_env(tree if tree is not None else Path(__file__).resolve().parents[1])
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=12, help="seeds per case (default 12)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--baseline", default=BASELINE, help=f"git revision to compare with, or none (default {BASELINE})")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    seeds = range(args.seed, args.seed + args.n)
    if args.worker:
        for label, tilt, n, mag, acc in CASES:
            for s in seeds:
                err, sig = run_one(s, tilt, n, mag, acc)
                print(json.dumps({"case": label, "err": err.tolist(), "sig": sig.tolist()}), flush=True)
        return 0
    from _baseline import export_tree

    start = time.perf_counter()
    print(f"running {len(CASES)} cases x {args.n} seeds per version ...", file=sys.stderr, flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        versions = {"this tree": None}
        if args.baseline != "none":
            versions = {f"before ({args.baseline})": export_tree(args.baseline, Path(tmp)), "this tree": None}
        procs = {name: _spawn(tree, args.seed, args.n) for name, tree in versions.items()}
        rows = {name: [json.loads(line) for line in p.stdout] for name, p in procs.items()}
        for name, p in procs.items():
            if p.wait() != 0:
                print(f"{name}: the worker failed (exit {p.returncode})", file=sys.stderr)
                return 1
    print(f"seeds {args.seed}..{args.seed + args.n - 1}; per component x, y, z (H)")
    print(f"{'case':<26} {'version':<17} {'mean error uT (+- s.e.)':<48} {'mean err/sig':<20} {'SD err/sig':<18} "
          f"{'RMS err/sig':<18}")
    for label, *_ in CASES:
        for name in versions:
            got = [r for r in rows[name] if r["case"] == label]
            err, sig = np.array([r["err"] for r in got]), np.array([r["sig"] for r in got])
            ratio = err / sig
            mean = "  ".join(f"{m:+.4f}+-{e:.4f}" for m, e in zip(err.mean(0), err.std(0, ddof=1) / np.sqrt(len(err))))
            print(f"{label:<26} {name:<17} {mean:<48} {' '.join(f'{v:+.2f}' for v in ratio.mean(0)):<20} "
                  f"{' '.join(f'{v:.2f}' for v in ratio.std(0, ddof=1)):<18} "
                  f"{' '.join(f'{v:.2f}' for v in np.sqrt(np.mean(ratio**2, axis=0))):<18}")
    print(f"\ntotal {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
