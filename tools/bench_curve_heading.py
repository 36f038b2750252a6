"""A level heading's error over its stated sigma with and without the response curve's uncertainty, by recording.

For :mod:`bench_loop`'s recordings of the cases with a static curve (this tree only, ``calibrate_fourflip(
diagnose=True)``): the RMS over recordings of :func:`bench_loop.heading_error_deg` over the heading sigma of
:func:`bench_loop.with_heading_sigma`, ``base`` without the curve's coefficients (the row's ``curve_covariance``
dropped: direction, offset and gain alone, as before the curve was carried) and ``this`` with them, over every
recording, over those where the loop named the curve (``nonlinear_response``, so the fit carries one) and over
those where it did not (nothing moves there: their error holds the missed curve's static bias, which no sigma
claims), with the named recording whose ratio is the largest.  Same seeds, same recordings: only the sigma differs.

Run: ``python tools/bench_curve_heading.py [--seed 60] [--n 20] [--cases "four stacked,odd cubic"]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_loop as bl  # noqa: E402

CASES = ("four stacked", "odd cubic", "cubic + quad drift", "knee")


def ratios(case: str, seed: int) -> tuple[bool, float, float]:
    """(curve named, heading err/sig without the curve, with it) of one recording."""
    row = bl.run_one(case, seed)
    this = bl.with_heading_sigma(row)["heading_sigma_deg"]
    base = bl.with_heading_sigma(dict(row, curve_covariance=None))["heading_sigma_deg"]
    return "nonlinear_response" in row["effects"], row["heading_err_deg"] / base, row["heading_err_deg"] / this


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=60)
    parser.add_argument("--n", type=int, default=20)
    parser.add_argument("--cases", default=",".join(CASES))
    args = parser.parse_args()
    seeds = range(args.seed, args.seed + args.n)
    print(f"bench_curve_heading: seeds {seeds.start}..{seeds.stop - 1}; heading err/sig RMS, base (no curve) / this")
    print(f"{'case':<20}{'all':>18}{'curve named':>20}{'not named':>18}{'worst named':>18}")
    for case in args.cases.split(","):
        rows = [(seed, *ratios(case, seed)) for seed in seeds]

        def cell(among):
            if not among:
                return "-"
            base, this = (float(np.sqrt(np.mean(np.square([r[i] for r in among])))) for i in (2, 3))
            return f"({len(among)}) {base:.2f} / {this:.2f}"

        named = [r for r in rows if r[1]]
        worst = max(named, key=lambda r: r[3], default=None)
        print(f"{case:<20}{cell(rows):>18}{cell(named):>20}{cell([r for r in rows if not r[1]]):>18}"
              f"{'-' if worst is None else f'seed {worst[0]} {worst[3]:.2f}':>18}", flush=True)


if __name__ == "__main__":
    main()
