"""One case of :mod:`bench_loop`, recording by recording: what carries its RMS err/sig.

For each seed (this tree only, ``calibrate_fourflip(diagnose=True)`` through :func:`bench_loop.run_one`): the field's
dip, the effects named, whether the loop said ``unexplained``, each channel's direction error over its stated sigma,
a level housing's runtime heading error over the heading sigma (:func:`bench_loop.with_heading_sigma`) with both in
degrees, and each gain's error over its sigma.  Then the RMS over every recording, over the recordings that named
``nonlinear_response`` and those that did not, over those that did not name ``encoder_error``, and over every
recording but the one with the largest heading err/sig (what one recording carries).

Run: ``python tools/bench_loop_records.py [--case "four stacked"] [--seed 60] [--n 20]``.
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


def record(case: str, seed: int) -> dict:
    """One recording's row: dip (deg), effects, unexplained, direction and gain err/sig, heading err, sigma (deg),
    CPU time of the calibration (s)."""
    row = bl.with_heading_sigma(bl.run_one(case, seed))
    return {"seed": seed, "dip": bl.session(seed, case)[1].dip_deg, "effects": row["effects"],
            "unexplained": row["unexplained"], "ratio": np.array(row["ratio"]), "gain": np.array(row["gain_ratio"]),
            "heading_err": row["heading_err_deg"], "heading_sigma": row["heading_sigma_deg"], "cpu_s": row["cpu_s"]}


def _rms(rows: list[dict]) -> str:
    if not rows:
        return "-"
    direction = np.sqrt(np.mean(np.concatenate([r["ratio"] for r in rows]) ** 2))
    heading = np.sqrt(np.mean([(r["heading_err"] / r["heading_sigma"]) ** 2 for r in rows]))
    return f"({len(rows)}) err/sig {direction:.2f}, heading {heading:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="four stacked", choices=bl.CASES)
    parser.add_argument("--seed", type=int, default=60)
    parser.add_argument("--n", type=int, default=20)
    args = parser.parse_args()
    print(f"bench_loop_records: {args.case}, seeds {args.seed}..{args.seed + args.n - 1}, this tree")
    print(f"{'seed':>5}{'dip':>6}  {'named':<64}{'unexpl.':<8}{'err/sig a, b, c':<20}{'hdg e/s':>8}{'hdg err':>9}"
          f"{'hdg sig':>9}{'cpu s':>7}  gain e/s a, b, c")
    rows = []
    for seed in range(args.seed, args.seed + args.n):
        r = record(args.case, seed)
        rows.append(r)
        named, flag = ", ".join(r["effects"]) or "none", "yes" if r["unexplained"] else ""
        print(f"{seed:>5}{r['dip']:>6.1f}  {named:<64}{flag:<8}"
              f"{', '.join(f'{v:.2f}' for v in r['ratio']):<20}{r['heading_err'] / r['heading_sigma']:>8.2f}"
              f"{r['heading_err']:>9.3f}{r['heading_sigma']:>9.3f}{r['cpu_s']:>7.2f}  {', '.join(f'{v:.1f}' for v in r['gain'])}",
              flush=True)
    worst = max(rows, key=lambda r: r["heading_err"] / r["heading_sigma"])
    print(f"\nevery recording {_rms(rows)}")
    print(f"curve named     {_rms([r for r in rows if 'nonlinear_response' in r['effects']])}")
    print(f"curve not named {_rms([r for r in rows if 'nonlinear_response' not in r['effects']])}")
    print(f"encoder missed  {_rms([r for r in rows if 'encoder_error' not in r['effects']])}")
    print(f"without seed {worst['seed']} {_rms([r for r in rows if r is not worst])}")


if __name__ == "__main__":
    main()
