"""The gyro-aided tumble's sigmas when its residual is unexplained: naive and widened against the truth, one run.

Each seed is a 60 s fast tumble with a gyro (``compass.sim.partial_tumble.simulate_partial_tumble("fast_rotation",
coverage=None)``) whose hard iron walks: a random walk smoothed over 2 s, ``--rms`` uT about its mean per axis, an
effect the gyro-aided model lacks (the hard iron the fit should find is the session's mean).  It is calibrated as
``compass calibrate`` does (``calibrate_tumble`` then ``with_gyro``); printed per seed: whether the diagnosis called it
unexplained, the hard iron's error and its naive and widened sigmas (the diagnosis's ``unexplained_cost``), and over
the seeds the RMS of error / sigma for both (1: honest; the naive sigma is what the file stated before the widening).
A clean seed (no walk) is run too: it must come back explained, not widened.

Run: ``python tools/bench_gyro_widen.py [--seeds 8] [--rms 1.0]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibrate.tumble.fit import calibrate_tumble  # noqa: E402
from calibrate.tumble.gyro import with_gyro  # noqa: E402
from compass.io.tumble import gyro_turns  # noqa: E402
from compass.sim.partial_tumble import simulate_partial_tumble  # noqa: E402

_AXES = ("mx", "my", "mz")


def walked(sim, seed: int, rms_ut: float):
    """``sim``'s magnetometer with its hard iron walking (``rms_ut`` about its mean, per axis), and the session's mean
    hard iron."""
    rng = np.random.default_rng([seed, 99])
    path = np.cumsum(rng.normal(size=(len(sim.t_s), 3)), axis=0)
    width = int(2.0 / np.median(np.diff(sim.t_s)))
    path = np.column_stack([np.convolve(p, np.ones(width) / width, mode="same") for p in path.T])
    path -= path.mean(axis=0)
    path *= rms_ut / np.sqrt(np.mean(path**2))
    return sim.mag + path, np.array(sim.truth["hard_iron"]) + path.mean(axis=0)


def calibrated(sim, mag):
    turns = gyro_turns(sim.t_s, sim.gyro, np.ones(len(sim.t_s), bool))
    return with_gyro(calibrate_tumble(mag, sim.accel, t_s=sim.t_s), mag, sim.accel, turns, sim.t_s)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--rms", type=float, default=1.0, help="the hard iron's walk, uT RMS per axis (default 1)")
    args = parser.parse_args(argv)
    print(f"Gyro-aided tumble, 60 s fast rotation, hard iron walking {args.rms:g} uT RMS: error / sigma per axis")
    print(f"{'seed':>4} {'unexpl.':>8}  {'error uT (mx, my, mz)':<26} {'naive sigma':<22} {'widened sigma':<22}")
    naive_ratios, wide_ratios = [], []
    for seed in range(args.seeds):
        sim = simulate_partial_tumble("fast_rotation", seed=seed, coverage=None, duration_s=60.0)
        mag, truth = walked(sim, seed, args.rms)
        res = calibrated(sim, mag)
        block = res.diagnosis.block
        err = res.fit.hard_iron - truth
        cost = block.get("unexplained_cost")
        naive = (np.array([cost["hard_iron"][a]["naive"] for a in _AXES]) if cost is not None
                 else res.fit.hard_iron_sigma)
        wide = res.fit.hard_iron_sigma
        naive_ratios.append(err / naive)
        wide_ratios.append(err / wide)
        show = (lambda v: " ".join(f"{x:+.3f}" for x in v))  # noqa: E731
        print(f"{seed:>4} {str(block['unexplained']):>8}  {show(err):<26} {show(naive):<22} {show(wide):<22}")
    rms = (lambda r: float(np.sqrt(np.mean(np.square(r)))))  # noqa: E731
    print(f"\nerror / sigma RMS over {args.seeds} seeds x 3 axes: naive {rms(naive_ratios):.2f}, widened "
          f"{rms(wide_ratios):.2f} (1: honest)")
    sim = simulate_partial_tumble("fast_rotation", seed=0, coverage=None, duration_s=60.0)
    clean = calibrated(sim, sim.mag)
    print(f"clean seed 0: unexplained {clean.diagnosis.block['unexplained']}, widened: "
          f"{'unexplained_cost' in clean.diagnosis.block}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
