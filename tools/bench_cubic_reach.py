"""How far a four-flip bench sees an odd cubic response, and what a linear calibration that missed one costs.

A diagnosis printer for the ``odd cubic`` recordings of :mod:`bench_loop` (1 % cubic, noise 0.15 uT, 1440
samples): per seed, this tree only,

- ``dip``: the field's dip, deg;
- ``lam``: the cubic's noncentrality against the linear model, the chi-square a linear fit leaves on the
  same recording without noise (weights the true noise): the chi-square drop a refit with the cubic
  expects is ``lam + 3``, its delta-BIC ``lam + 3 - 3 ln 4320 = lam - 22``; ``paper``: ``1000 cos^6(dip)``,
  the third harmonic ``c |B| cos^3(dip) / 4`` of every horizontal turn (1440 samples of the X channel, 720
  of Y and of Z) over the noise (docs/benchmarks.md, "An odd cubic the loop did not name");
- ``named`` and ``unexpl``: what the loop said (``calibrate_fourflip(diagnose=True)``);
- ``gain e/s slope``: the gains' error over their stated sigma (RMS over channels) against the slope at
  zero field (:class:`bench_loop.Truth`); ``best linear``: against the gains of the linear fit of the same
  recording without noise (the best linear gain for this bench's geometry; a fit that named the cubic
  states the slope at zero instead, so there it reads the definition's difference);
- ``level hdg``: a level housing's runtime heading error over its stated sigma (:func:`bench_loop.heading_error_deg`);
- ``tilt 30``: the RMS runtime heading error, deg, of a housing within 30 deg of level (400 attitudes, the
  heading from the field rotated level with the true attitude), of the calibration and of the best
  linear one; ``dip err``: the fitted dip's error, deg.

Run: ``python tools/bench_cubic_reach.py [--seed 60] [--n 20] [--case "odd cubic"]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_loop as bl  # noqa: E402

TILT_DEG = 30.0
N_ATTITUDES = 400


def tilted_heading_error_deg(result, truth: bl.Truth, tilt_deg: float = TILT_DEG, n: int = N_ATTITUDES) -> float:
    """RMS runtime heading error, deg, over ``n`` attitudes (heading uniform, pitch and roll uniform within
    ``tilt_deg``; seeded), the field read through the calibration and rotated level with the true attitude."""
    rng = np.random.default_rng(1)
    dip = np.radians(truth.dip_deg)
    field_w = bl.FIELD_UT * np.array([np.cos(dip), 0.0, -np.sin(dip)])
    attitude = Rotation.from_euler("ZYX", np.column_stack([rng.uniform(0, 360, n), rng.uniform(-tilt_deg, tilt_deg, n),
                                                           rng.uniform(-tilt_deg, tilt_deg, n)]), degrees=True)
    out = truth.output(attitude.apply(field_w, inverse=True))
    x = np.column_stack([ch.response.field_component(out[:, i])[0] for i, ch in enumerate(result.channels)])
    level = attitude.apply(x @ np.linalg.pinv(result.directions).T)
    return float(np.degrees(np.sqrt(np.mean(np.arctan2(level[:, 1], level[:, 0]) ** 2))))


def best_linear(case: str, seed: int, truth: bl.Truth):
    """The linear fit of the recording without noise (weights the true noise) and its chi-square (``lam``)."""
    from calibrate.fourflip._mlfit import fit_ml
    from calibrate.fourflip.fit import physics_from_harmonics, result_from_ml
    from compass.sim.bench import BenchSamples

    rec, _ = bl.session(seed, case, noise_ut=0.0)
    samples = BenchSamples.from_recording(rec)
    noise = bl.NOISE_UT * truth.gains
    fit = fit_ml(samples, rec.outputs, rec.channels, physics_from_harmonics(rec, bl.FIELD_UT, 1.0), noise)
    return result_from_ml(fit, rec, noise, bl.FIELD_UT, samples=samples), fit.chi2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=60)
    parser.add_argument("--n", type=int, default=20)
    parser.add_argument("--case", default="odd cubic", choices=("odd cubic", "four stacked", "cubic + quad drift"))
    args = parser.parse_args()
    from calibrate import calibrate_fourflip

    print(f"bench_cubic_reach: {args.case}, seeds {args.seed}..{args.seed + args.n - 1}, noise {bl.NOISE_UT} uT")
    print(f"{'seed':>4}{'dip':>6}{'lam':>7}{'paper':>7}  {'named':<34}{'unexpl':>6}{'gain e/s slope':>15}"
          f"{'best linear':>12}{'level hdg e/s':>14}{'tilt 30 fit':>12}{'best lin':>9}{'dip err':>8}")
    for seed in range(args.seed, args.seed + args.n):
        rec, truth = bl.session(seed, args.case)
        start, cpu = time.perf_counter(), time.process_time()
        result = calibrate_fourflip(rec, diagnose=True)
        row = bl.with_heading_sigma(bl.summarise(args.case, seed, truth, result, time.perf_counter() - start,
                                                 time.process_time() - cpu))
        linear, lam = best_linear(args.case, seed, truth)
        gain = np.array([c.response.gain for c in result.channels])
        sigma = np.array([c.gain_sigma for c in result.channels], dtype=float)
        best = np.array([c.response.gain for c in linear.channels])
        rms = lambda v: float(np.sqrt(np.mean(np.square(v))))  # noqa: E731
        print(f"{seed:>4}{truth.dip_deg:>6.1f}{lam:>7.1f}{1000 * np.cos(np.radians(truth.dip_deg)) ** 6:>7.1f}  "
              f"{', '.join(row['effects']) or '-':<34}{int(row['unexplained']):>6}{rms(row['gain_ratio']):>15.1f}"
              f"{rms((gain - best) / sigma):>12.1f}{row['heading_err_deg'] / row['heading_sigma_deg']:>14.2f}"
              f"{tilted_heading_error_deg(result, truth):>12.3f}{tilted_heading_error_deg(linear, truth):>9.3f}"
              f"{result.dip_deg - truth.dip_deg:>+8.3f}", flush=True)


if __name__ == "__main__":
    main()
