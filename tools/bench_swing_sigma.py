"""An installation swing's hard-iron error against its stated sigma, per component: clean and with a field wander.

Seeded Monte Carlo of :class:`calibrate.installation.InstallationCalibrator` on swings
(:func:`compass.sim.installation.simulate_installation`, on the true bench model, as in
``tools/bench_kinds_loop.py``), varying one thing at a time from the benchmark's swing (+-10 deg,
2000 rows, the bench's noise): the tilt, the number of rows, which noise is there (the
magnetometer's alone, none), and the local field wandering in the world frame (``field wander``:
``bench_kinds_loop``'s smoothed random walk, 0.4 uT RMS, the same seeds; outside the vocabulary, so
the recording is called unexplained and its sigmas widened, :mod:`calibrate.diagnosis.blocks`), and the
accelerometer disturbed slowly (``accelerometer slow``: 2 % of g RMS over ~1 s, as a hand-held swing's,
which makes the angle rows noisier than their floor but not the |B| rows).
Per hard-iron component (H frame): the mean error (uT) with its standard error over seeds, the mean
and the spread (SD) of error/sigma, and the RMS of error/sigma (1: honest; over every recording,
and for the wander over those called unexplained as ``bench_kinds_loop``'s column), per set of seeds.
A spread near or under 1 with a mean away from 0 is a bias, not a sigma too small; a bias that stays
as the rows grow is one the estimator does not average away.

Each case beside a baseline revision in the same run (default ``84b91b3``, before
:func:`calibrate.installation.model.debiased` counted an unexplained recording's excess over the
floor; ``75a6b36`` is before that correction), and the median over seeds of the block sandwich's
degrees of freedom for each component (:func:`calibrate.diagnosis.blocks.sandwich_dof`; this tree's).

Usage::

    python tools/bench_swing_sigma.py [--n 12] [--seed 0] [--sets 0-19,20-29,30-49] [--cases A,B]
                                      [--baseline REF|none]
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

BASELINE = "84b91b3"

# (label, tilt deg, rows, magnetometer noise scale, accelerometer noise g)
CASES = (("swing +-10 deg 2000 rows", 10.0, 2000, 1.0, 0.002),
         ("tilt +-5", 5.0, 2000, 1.0, 0.002),
         ("tilt +-20", 20.0, 2000, 1.0, 0.002),
         ("500 rows", 10.0, 500, 1.0, 0.002),
         ("8000 rows", 10.0, 8000, 1.0, 0.002),
         ("magnetometer noise only", 10.0, 2000, 1.0, 0.0),
         ("no noise", 10.0, 2000, 0.0, 0.0),
         ("field wander", 10.0, 2000, 1.0, 0.002),
         ("accelerometer slow", 10.0, 2000, 1.0, 0.002))
WANDER = "field wander"
ACCEL_SLOW = "accelerometer slow"
ACCEL_SLOW_G = 0.02
"""RMS of the slow accelerometer disturbance, in units of g (about 1 s: a hand-held swing's motion)."""


def run_one(seed: int, tilt_deg: float, n: int, mag_scale: float, accel_g: float,
            wander: bool = False, accel_slow: bool = False) -> tuple[np.ndarray, np.ndarray, bool]:
    """(error uT, sigma uT) of the hard iron, shape (3,) each, and whether it was called unexplained, for
    one swing (with ``wander``, the field wandering as in ``bench_kinds_loop``; with ``accel_slow``, the
    accelerometer disturbed by a smoothed isotropic noise of :data:`ACCEL_SLOW_G` RMS over ~1 s)."""
    from bench_kinds_loop import WANDER_UT, _walk
    from calibrate.installation import InstallationCalibrator
    from compass.calibration import from_dict, model_to_dict
    from compass.frames import r_world_from_housing
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
    out = sim.outputs
    if wander:  # bench_kinds_loop's field wander, its random numbers drawn the same way
        housing = r_world_from_housing(sim.heading_deg, sim.pitch_deg, sim.roll_deg)
        walk = _walk(np.random.default_rng([seed, 77]), n, WANDER_UT)
        d_h = housing.apply(walk, inverse=True) @ np.asarray(inst.soft_iron).T
        out = out + np.asarray(truth["gains_per_ut"]) * (d_h @ np.asarray(truth["directions"]).T)
    accel = np.array(sim.accel, dtype=float)
    if accel_slow:  # a hand-held swing's motion: the angle rows noisier than their floor, the |B| rows not
        kernel = np.hanning(101) / np.hanning(101).sum()
        rng = np.random.default_rng([seed, 5])
        slow = np.column_stack([np.convolve(rng.normal(size=n), kernel, "same") for _ in range(3)])
        accel = accel + slow * ACCEL_SLOW_G / np.sqrt(np.mean(slow**2)) * np.linalg.norm(accel, axis=1, keepdims=True)
    rec = InstallationRecording("sim", sim.kind, sim.channels, out, accel, sim.t_s, None, None, False,
                                np.arange(n), {})
    res = InstallationCalibrator(base=bench, accel_noise_g=max(accel_g, 1e-6)).fit(rec)  # likewise
    return (res.hard_iron_ut - inst.hard_iron_ut, res.hard_iron_sigma_ut, bool(res.diagnosis.block["unexplained"]),
            _hard_iron_dof(res))


def _hard_iron_dof(res) -> list | None:
    """Bell and McCaffrey's degrees of freedom of the block sandwich's variance of each hard-iron component
    (:func:`calibrate.diagnosis.blocks.sandwich_dof`) over the blocks the installation's widening uses
    (``calibrate.installation.diagnosis._widen``; the rows are in time order); None in a tree without it."""
    try:
        from calibrate.diagnosis.blocks import sandwich_dof, time_blocks
    except ImportError:  # a baseline from before it: the design's number, so this tree's line says it
        return None
    fit = res.diagnosis.fit
    blocks = np.tile(time_blocks(np.arange(fit.n_rows, dtype=float)), fit.n_obs // fit.n_rows)
    nu = sandwich_dof(fit.jac[:fit.n_obs], blocks, np.linalg.pinv(fit.jac.T @ fit.jac))
    out = np.full(3, np.nan)
    out[~fit.fixed[:3]] = nu[:int(np.sum(~fit.fixed[:3]))]  # the hard iron's moved columns come first
    return out.tolist()


def _spawn(tree: Path | None, seeds: list, cases: list) -> subprocess.Popen:
    from _baseline import tree_env

    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--seeds", ",".join(map(str, seeds)),
           "--cases", ";".join(cases)]
    env = tree_env(tree if tree is not None else Path(__file__).resolve().parents[1])
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())


def _seed_sets(args, parser) -> list[tuple[str, list]]:
    """``[(label, seeds)]`` from ``--sets A-B,C-D`` or else ``--seed``/``--n``."""
    if not args.sets:
        if args.n < 1:
            parser.error(f"--n: expected at least one seed, got {args.n}")
        return [(f"{args.seed}-{args.seed + args.n - 1}", list(range(args.seed, args.seed + args.n)))]
    out = []
    for part in args.sets.split(","):
        first, _, last = part.strip().partition("-")
        try:
            seeds = list(range(int(first), int(last or first) + 1))
        except ValueError:
            parser.error(f"--sets: expected seed ranges like 0-19,20-29, got {part.strip()!r}")
        if not seeds:
            parser.error(f"--sets: the range {part.strip()!r} holds no seed")
        out.append((part.strip(), seeds))
    return out


def _dof_cell(got: list) -> str:
    dof = [r["dof"] for r in got if r["dof"] is not None]
    return " ".join(f"{v:.1f}" for v in np.nanmedian(np.array(dof, dtype=float), axis=0)) if dof else "-"


def _line(label: str, name: str, got: list) -> str:
    err, sig = np.array([r["err"] for r in got]), np.array([r["sig"] for r in got])
    ratio = err / sig
    mean = "  ".join(f"{m:+.4f}+-{e:.4f}" for m, e in zip(err.mean(0), err.std(0, ddof=1) / np.sqrt(len(err))))
    flagged = ratio[[r["unexplained"] for r in got]]
    unexplained = (f"{np.sqrt(np.mean(flagged**2)):.2f} ({len(flagged)})" if len(flagged) else "-")
    return (f"{label:<26} {name:<17} {mean:<48} {' '.join(f'{v:+.2f}' for v in ratio.mean(0)):<20} "
            f"{' '.join(f'{v:.2f}' for v in ratio.std(0, ddof=1)):<16} "
            f"{' '.join(f'{v:.2f}' for v in np.sqrt(np.mean(ratio**2, axis=0))):<16} "
            f"{np.sqrt(np.mean(ratio**2)):>5.2f} {unexplained:>12} "
            f"{_dof_cell(got):>14}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=12, help="seeds per case (default 12)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--sets", default="",
                        help="sets of seeds, each reported apart: A-B,C-D (overrides --n, --seed)")
    parser.add_argument("--cases", default="", help="semicolon-separated case labels (default all): "
                        + "; ".join(c[0] for c in CASES))
    parser.add_argument("--baseline", default=BASELINE,
                        help=f"git revision to compare with, or none (default {BASELINE})")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--seeds", default="", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    known = [c[0] for c in CASES]
    cases = [c.strip() for c in args.cases.split(";") if c.strip()] or known
    bad = [c for c in cases if c not in known]
    if bad:
        parser.error(f"unknown case(s) {bad}; known: {'; '.join(known)}")
    if args.worker:
        for label, tilt, n, mag, acc in CASES:
            if label not in cases:
                continue
            for s in map(int, args.seeds.split(",")):
                err, sig, unexplained, dof = run_one(s, tilt, n, mag, acc, wander=label == WANDER,
                                                     accel_slow=label == ACCEL_SLOW)
                print(json.dumps({"case": label, "seed": s, "err": err.tolist(), "sig": sig.tolist(),
                                  "unexplained": unexplained, "dof": dof}), flush=True)
        return 0
    from _baseline import export_tree

    sets = _seed_sets(args, parser)
    seeds = sorted({s for _, chosen in sets for s in chosen})
    start = time.perf_counter()
    print(f"running {len(cases)} cases x {len(seeds)} seeds per version ...", file=sys.stderr, flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        versions = {"this tree": None}
        if args.baseline != "none":
            versions = {f"before ({args.baseline})": export_tree(args.baseline, Path(tmp)), "this tree": None}
        procs = {name: _spawn(tree, seeds, cases) for name, tree in versions.items()}
        rows = {name: [json.loads(line) for line in p.stdout] for name, p in procs.items()}
        for name, p in procs.items():
            if p.wait() != 0:
                print(f"{name}: the worker failed (exit {p.returncode})", file=sys.stderr)
                return 1
    for set_label, chosen in sets:
        print(f"\nseeds {set_label}; per component x, y, z (H); RMS all: over components and seeds; "
              f"unexplained: the RMS over the recordings called unexplained (their count); sandwich dof: the median "
              f"of the block sandwich's degrees of freedom (calibrate.diagnosis.blocks.sandwich_dof)")
        print(f"{'case':<26} {'version':<17} {'mean error uT (+- s.e.)':<48} {'mean err/sig':<20} {'SD err/sig':<16} "
              f"{'RMS err/sig':<16} {'all':>5} {'unexplained':>12} {'sandwich dof':>14}")
        for label in cases:
            for name in versions:
                print(_line(label, name, [r for r in rows[name] if r["case"] == label and r["seed"] in chosen]))
    print(f"\ntotal {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
