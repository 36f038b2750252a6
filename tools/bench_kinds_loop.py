"""The residual loop of the tumble and the installation: gain drift named, sigmas that cover what stays unexplained.

Seeded, this tree beside a baseline revision in the same run (default ``1453ea3``, before
``gain_drift`` and the widening came to these kinds).  Cases, the same seeds in each:

- ``clean``: the simulators as they are;
- ``gain drift`` (vocabulary): each channel's gain changing linearly over the session, a uniform
  random -1..+1 % of it per channel at the end (about the hard iron: the field part of the reading);
- ``field wander`` (outside the vocabulary): the local field in the world frame wandering as a
  smoothed random walk, 0.4 uT RMS (iron moved about near the bench during the recording);
- ``offset walk`` (outside): the sensor's offsets walking as a smoothed random walk, 0.4 uT RMS
  per channel.

Kinds:

- ``tumble``: :func:`compass.sim.tumble.simulate_tumble` (3000 rows at 50 Hz, noise 0.3 uT),
  :func:`calibrate.tumble.calibrate_tumble` with ``t_s``; the error is the calibrated field's
  direction at the reference time against the truth (RMS over 500 directions, deg), and the
  hard iron's error over its stated sigma;
- ``inst tumble`` and ``inst swing``: :func:`compass.sim.installation.simulate_installation`
  (2000 rows, a swing within +-10 deg) of a simulated bench sensor in a product, on the true
  bench model (so what is measured is the installation fit, not the bench's error), calibrated
  by :class:`calibrate.installation.InstallationCalibrator`; the error is the installed model's
  heading RMS at runtime (pitch and roll within +-30 deg, 2000 rows, deg) and the hard iron's
  error over its stated sigma.

Per kind, case and version: the commonest set of named effects, how often anything was named,
how often ``unexplained``, the hard iron's error over its stated sigma (RMS over components and
seeds: 1 when honest; 0.8-1.25 is the target), the same over the recordings called unexplained,
the RMS error, the worst CPU time.

Usage::

    python tools/bench_kinds_loop.py [--n 20] [--seed 0] [--baseline REF|none] [--kinds tumble,inst tumble]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy is imported: one BLAS thread per process

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _doc_table import markdown_table, parse_args, publish  # noqa: E402

CASES = ("clean", "gain drift", "field wander", "offset walk")
KINDS = ("tumble", "inst tumble", "inst swing")
BASELINE = "1453ea3"
WANDER_UT = 0.4
GAIN_DRIFT = 0.01


def _walk(rng, n: int, size: float, width: int = 301) -> np.ndarray:
    """A smoothed random walk, shape (n, 3), of RMS ``size`` about its mean."""
    steps = rng.normal(size=(n + width, 3))
    kernel = np.hanning(width) / np.hanning(width).sum()
    walk = np.cumsum(np.column_stack([np.convolve(steps[:, k], kernel, "same") for k in range(3)]), axis=0)[:n]
    walk -= walk.mean(axis=0)  # about the session's mean: the file's hard iron is the session's when nothing is named
    return walk * size / max(float(np.sqrt(np.mean(walk**2))), 1e-12)


def _tumble(case: str, seed: int) -> dict:
    from calibrate.tumble import calibrate_tumble
    from compass.sim.tumble import simulate_tumble

    sim = simulate_tumble(seed=seed, n=3000)
    h = np.array(sim.truth["hard_iron"])
    w = np.linalg.inv(np.array(sim.truth["soft_iron"]))  # the reading's field part is w b
    mag = sim.mag.copy()
    extra = np.random.default_rng([seed, 77])
    tau = sim.t_s / sim.t_s[-1]
    if case == "gain drift":
        mag = h + (mag - h) * (1.0 + np.outer(tau, extra.uniform(-1, 1, 3) * GAIN_DRIFT))
    elif case == "field wander":
        d_housing = sim.attitude.apply(_walk(extra, len(mag), WANDER_UT), inverse=True)  # world -> housing
        rot = np.array(sim.truth["mag_to_accel"])
        mag = mag + (d_housing @ rot) @ w.T  # housing -> magnetometer frame (mag_to_accel maps mag -> housing)
    elif case == "offset walk":
        mag = mag + _walk(extra, len(mag), WANDER_UT)
    start = time.process_time()
    res = calibrate_tumble(mag, sim.accel, t_s=sim.t_s)
    cpu = time.process_time() - start
    fit = res.fit
    u = np.random.default_rng(5).normal(size=(500, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    cal = (u @ w.T * sim.truth["field_ut"] + h - fit.hard_iron) @ fit.soft_iron.T
    cal /= np.linalg.norm(cal, axis=1, keepdims=True)
    err = float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(np.sum(cal * u, axis=1), -1, 1)) ** 2))))
    return {"effects": list(res.diagnosis.block["effects"]) if res.diagnosis else [],
            "unexplained": bool(res.diagnosis.block["unexplained"]) if res.diagnosis else False,
            "ratio": ((fit.hard_iron - h) / fit.hard_iron_sigma).tolist(), "err": err, "cpu": cpu}


def _installation(case: str, seed: int, kind: str) -> dict:
    from calibrate.installation import InstallationCalibrator
    from compass.attitude import solve_attitude
    from compass.calibration import from_dict, model_to_dict
    from compass.frames import r_world_from_housing
    from compass.io.installation import InstallationRecording
    from compass.sim.fourflip import simulate_fourflip
    from compass.sim.installation import random_installation, simulate_installation, true_model

    truth = simulate_fourflip(seed=seed).truth
    model = true_model(truth)
    bench = from_dict(model_to_dict(model) | {"format": "compass-calibration/1", "model": "channels"})
    inst = random_installation(500 + seed, yaw_deg=0.0)
    sim = simulate_installation(truth, inst, kind="tumble" if kind == "inst tumble" else "swing", n=2000,
                                max_tilt_deg=10.0, seed=700 + seed)
    off, gains, dirs = (np.asarray(truth[k]) for k in ("offsets", "gains_per_ut", "directions"))
    out = sim.outputs.copy()
    extra = np.random.default_rng([seed, 77])
    tau = (sim.t_s - sim.t_s.mean()) / np.ptp(sim.t_s)  # zero at the installation's reference (the mean time)
    if case == "gain drift":
        out = off + (out - off) * (1.0 + np.outer(tau, extra.uniform(-1, 1, out.shape[1]) * GAIN_DRIFT))
    elif case == "field wander":
        housing = r_world_from_housing(sim.heading_deg, sim.pitch_deg, sim.roll_deg)
        d_h = housing.apply(_walk(extra, len(out), WANDER_UT), inverse=True) @ np.asarray(inst.soft_iron).T
        out = out + gains * (d_h @ dirs.T)
    elif case == "offset walk":
        out = out + gains * _walk(extra, len(out), WANDER_UT)[:, :out.shape[1]]
    rec = InstallationRecording("sim", sim.kind, sim.channels, out, sim.accel, sim.t_s, None, None, False,
                                np.arange(len(sim.t_s)), {})
    start = time.process_time()
    res = InstallationCalibrator(base=bench).fit(rec)
    cpu = time.process_time() - start
    use = simulate_installation(truth, inst, kind="runtime", n=2000, max_tilt_deg=30.0, seed=900 + seed)
    heading = solve_attitude(res.model, use.outputs, accel=use.accel).heading_deg
    err = float(np.sqrt(np.mean((np.mod(heading - use.heading_deg + 180, 360) - 180) ** 2)))
    block = res.diagnosis.block
    return {"effects": list(block["effects"]), "unexplained": bool(block["unexplained"]),
            "ratio": ((res.hard_iron_ut - inst.hard_iron_ut) / res.hard_iron_sigma_ut).tolist(), "err": err,
            "cpu": cpu}


def run_one(kind: str, case: str, seed: int) -> dict:
    row = _tumble(case, seed) if kind == "tumble" else _installation(case, seed, kind)
    return {"kind": kind, "case": case, "seed": seed, **row}


def _summary(rows) -> dict:
    named = Counter(", ".join(sorted(r["effects"])) or "none" for r in rows)
    top, count = named.most_common(1)[0]
    ratios = np.concatenate([r["ratio"] for r in rows])
    flagged = [r["ratio"] for r in rows if r["unexplained"]]
    return {"named": f"{top} {count}/{len(rows)}", "any": sum(bool(r["effects"]) for r in rows),
            "unexplained": sum(r["unexplained"] for r in rows), "ratio": float(np.sqrt(np.mean(ratios**2))),
            "ratio_unexplained": float(np.sqrt(np.mean(np.concatenate(flagged) ** 2))) if flagged else None,
            "err": float(np.sqrt(np.mean(np.square([r["err"] for r in rows])))),
            "worst_cpu": float(max(r["cpu"] for r in rows)), "n": len(rows)}


def _spawn(tree: Path | None, kinds, seed: int, n: int) -> subprocess.Popen:
    from _baseline import tree_env

    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--kinds", ",".join(kinds),
           "--seed", str(seed), "--n", str(n)]
    env = tree_env(tree if tree is not None else Path(__file__).resolve().parents[1])
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20, help="seeds per case (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--kinds", default=",".join(KINDS), help=f"comma-separated among {', '.join(KINDS)}")
    parser.add_argument("--baseline", default=BASELINE, help=f"git revision to compare with, or none (default {BASELINE})")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parse_args(parser, argv)
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    bad = [k for k in kinds if k not in KINDS]
    if bad:
        parser.error(f"unknown kind(s) {bad}; known: {', '.join(KINDS)}")
    if args.worker:
        for kind in kinds:
            for case in CASES:
                for seed in range(args.seed, args.seed + args.n):
                    print(json.dumps(run_one(kind, case, seed)), flush=True)
        return 0
    from _baseline import export_tree

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        versions = {"this tree": None}
        if args.baseline != "none":
            versions = {f"before ({args.baseline})": export_tree(args.baseline, Path(tmp)), "this tree": None}
        procs = {name: _spawn(tree, kinds, args.seed, args.n) for name, tree in versions.items()}
        rows = {name: [json.loads(line) for line in p.stdout] for name, p in procs.items()}
        for name, p in procs.items():
            if p.wait() != 0:
                print(f"{name}: the worker failed (exit {p.returncode})", file=sys.stderr)
                return 1
    print(f"seeds {args.seed}..{args.seed + args.n - 1}; gain drift {100 * GAIN_DRIFT:.0f} % per channel at most, "
          f"wander and walk {WANDER_UT} uT RMS")
    head = (f"{'kind':<12} {'case':<13} {'version':<17} {'named (commonest)':<28} {'any':>5} {'unexpl':>6} "
            f"{'err/sig':>7} {'(unexpl)':>8} {'error':>7} {'worst CPU s':>11}")
    print(head)
    table = []
    for kind in kinds:
        unit = "deg dir" if kind == "tumble" else "deg hdg"
        for case in CASES:
            cells = {}
            for name in versions:
                s = _summary([r for r in rows[name] if r["kind"] == kind and r["case"] == case])
                flagged = "-" if s["ratio_unexplained"] is None else f"{s['ratio_unexplained']:.2f}"
                print(f"{kind:<12} {case:<13} {name:<17} {s['named']:<28} {s['any']:>2}/{s['n']:<2} "
                      f"{s['unexplained']:>3}/{s['n']:<2} {s['ratio']:>7.2f} {flagged:>8} {s['err']:>7.3f} "
                      f"{s['worst_cpu']:>11.2f}")
                cells[name] = s | {"flagged": flagged}
            table.append([kind, case] + [" / ".join(str(cells[v][key]) if key != "ratio" and key != "err"
                                                    else f"{cells[v][key]:.{2 if key == 'ratio' else 3}f}"
                                                    for v in versions)
                                         for key in ("named", "unexplained", "ratio", "flagged", "err")]
                         + [" / ".join(f"{cells[v]['worst_cpu']:.2f}" for v in versions)])
        print(f"  (error: {unit} RMS)")
    print(f"\ntotal {time.perf_counter() - start:.0f} s")
    order = " / ".join("base" if name.startswith("before") else "this" for name in versions)
    publish(args, "docs/benchmarks.md", "bench_kinds_loop",
            markdown_table(["kind", "case", f"named ({order})", f"unexplained ({order})", f"err/sig ({order})",
                            f"err/sig unexplained ({order})", f"error, deg ({order})", f"worst CPU s ({order})"],
                           table),
            caption=f"seeds {args.seed}-{args.seed + args.n - 1}, {args.n} per case"
                    + (f"; base: {args.baseline}" if args.baseline != "none" else "")
                    + "; error: the tumble's field direction, the installation's heading at runtime (RMS)", echo=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
