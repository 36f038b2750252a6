"""The block test under an explained fit on white noise and on a random walk: its false-alarm rate and its power.

A four-flip-like linear design in time (4 turns of 360 rows, 1 s a row, 60 s between turns, 3 channels), per
channel: an offset, ``cos phi`` and ``sin phi`` of the turn, a level read from the turns' level differences
(``+1, -1, +1, -1`` by turn) and a cubic in time (the named drift).  The weighted residual is what the fit leaves
of white noise of unit variance plus, where ``q > 0``, a random walk of each channel's offset of ``q`` noise
sigmas per square root of a second (tools/bench_loop.py's: 0.004 uT a 1 s sample over 0.15 uT of noise, 0.027).
Under white noise the block sums are exactly ``N(0, keep)``, so the rates are the tests' own, no model's.

Per replicate it prints nothing; at the end, for each ``q``: how often the band family alone at ``BAND_P_VALUE``
(the test before, 1000 null draws), the band family at half of it (2000 draws), the walk's likelihood-ratio
test at half of it, and the two by Bonferroni (the four-flip's ``block_test`` now) fire, each with its binomial
standard error.

Run: ``python tools/bench_walktest.py [--n 1000] [--seed 0] [--q 0,0.015,0.027]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse

import numpy as np

from calibrate.diagnosis.robust import BAND_P_VALUE, NULL_DRAWS, band_p_values, family_p_value
from calibrate.diagnosis.walk import walk_p_value

ROWS, TURNS, DT_S, GAP_S, CHANNELS = 360, 4, 1.0, 60.0, 3


def design() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row times (s), the Jacobian of the weighted residual (rows time-major, channels inner) and its bread."""
    turn = np.repeat(np.arange(TURNS), ROWS)
    t_s = np.arange(turn.size) * DT_S + turn * GAP_S
    phi = 2 * np.pi * (np.arange(turn.size) % ROWS) / ROWS
    tau = (t_s - t_s.mean()) / np.ptp(t_s)
    own = np.column_stack([np.ones_like(phi), np.cos(phi), np.sin(phi), np.array([1.0, -1.0, 1.0, -1.0])[turn],
                           tau, tau**2, tau**3])
    k = own.shape[1]
    jac = np.zeros((turn.size * CHANNELS, k * CHANNELS))
    for ch in range(CHANNELS):
        jac[ch::CHANNELS, ch * k:(ch + 1) * k] = -own
    return t_s, jac, np.linalg.inv(jac.T @ jac)


def residual(rng: np.random.Generator, t_s: np.ndarray, jac: np.ndarray, bread: np.ndarray, q: float) -> np.ndarray:
    """What the least-squares fit leaves of white noise plus a walk of ``q`` per square root of a second, (n, c)."""
    data = rng.standard_normal((t_s.size, CHANNELS))
    if q > 0:
        steps = rng.standard_normal((t_s.size, CHANNELS)) * np.sqrt(np.diff(t_s, prepend=t_s[0]))[:, None]
        data += q * np.cumsum(steps, axis=0)
    flat = data.ravel()
    return (flat - jac @ (bread @ (jac.T @ flat))).reshape(data.shape)


def rates(n: int, seed: int, q: float) -> dict:
    """Each test's firing count over ``n`` replicates at walk size ``q``."""
    t_s, jac, bread = design()
    rng = np.random.default_rng(seed)
    count = dict.fromkeys(("bands (before)", "bands / 2", "walk / 2", "combined"), 0)
    for _ in range(n):
        weighted = residual(rng, t_s, jac, bread, q)
        bands = band_p_values(jac, weighted, t_s, bread, draws=2 * NULL_DRAWS)
        before = family_p_value(band_p_values(jac, weighted, t_s, bread))
        half = family_p_value(bands)
        walk = walk_p_value(jac, weighted, t_s, bread)
        count["bands (before)"] += before <= BAND_P_VALUE
        count["bands / 2"] += half <= BAND_P_VALUE / 2
        count["walk / 2"] += walk <= BAND_P_VALUE / 2
        count["combined"] += family_p_value(np.array([half, walk])) <= BAND_P_VALUE
    return count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000, help="replicates per walk size (default 1000)")
    parser.add_argument("--seed", type=int, default=0, help="the replicates' seed (default 0)")
    parser.add_argument("--q", default="0,0.015,0.027", help="walk sizes, noise sigmas per sqrt(s), comma-separated")
    args = parser.parse_args()
    for q in (float(v) for v in args.q.split(",")):
        count = rates(args.n, args.seed, q)
        cells = []
        for name, k in count.items():
            p = k / args.n
            cells.append(f"{name} {p:.4f} +- {np.sqrt(max(p * (1 - p), 1.0 / args.n) / args.n):.4f}")
        print(f"q {q:g} ({args.n} replicates, seed {args.seed}): " + "; ".join(cells), flush=True)


if __name__ == "__main__":
    main()
