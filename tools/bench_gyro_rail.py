"""A gyro that saturates in flicks: the filter before (``--baseline``) and now, and VQF, on the same clipped samples.

Run: ``python tools/bench_gyro_rail.py [--first-seed 60] [--seeds 10] [--rails 250,500] [--baseline 5e858bb]
[--lever-m 0.1]`` (VQF from ``PYTHONPATH=...:/tmp/lever_pkgs`` or ``pip install -e '.[bench]'``).

Each seed is the simulated module (:func:`compass.sim.device.simulate_device`, 200 Hz, 58 s, 0.15 uT) rocked
gently (pitch and roll 5-10 deg, seeded frequencies) and flicked four times, 12 s apart from 10 s: about the
vertical (90 deg of heading) twice, about pitch and about roll (60 deg) once each, in a seeded order, each a half
cosine whose peak rate is 1.2-3 times the rail (seeded).  Its gyro is read as a 16-bit part at that full scale
(quantised to rail / 32768 and clipped at the rail), once at 250 and once at 500 deg/s, the accelerometer
``--lever-m`` from the turn's centre (a wrist's 0.1 m: up to 3 g in a flick; 0: at it); at 2000 deg/s nothing
clips, and the filter before and now must agree bit for bit (printed).  Printed per rail and method, pooled over
the seeds: heading and inclination RMS over the run (after 5 s), the same over the 10 s after each flick, and the
time from the flick's end until both errors stay within 2 deg for 1 s (10 s: not within the window); per flick
axis below.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from _baseline import export_tree, tree_env  # noqa: E402

RATE_HZ = 200.0
DURATION_S = 58.0
FLICK_T_S = (10.0, 22.0, 34.0, 46.0)
FLICK_AXES = ("z", "z", "y", "x")
ANGLE_DEG = {"z": 90.0, "y": 60.0, "x": 60.0}
RATIO = (1.2, 3.0)
AFTER_S = 10.0
WITHIN_DEG, HOLD_S = 2.0, 1.0
SKIP_S = 5.0
COUNTS = 32768.0  # a 16-bit part
STANDARD_GRAVITY = 9.80665
RUN_CHILD = """
import sys, numpy as np
from compass.filter import FilterConfig, run_filter
from compass.sim.device import default_model
d = np.load(sys.argv[1])
config = FilterConfig.from_model(default_model())
out = {}
for key in sorted({k.split('/')[0] for k in d.files}):
    out[key] = run_filter(d[key + '/t'], d[key + '/accel'], d[key + '/gyro'], d[key + '/field'], config).quat
np.savez(sys.argv[2], **out)
"""


def flicks(seed: int, rail_deg_s: float) -> list:
    """``[(t0_s, axis, angle_deg, duration_s), ...]`` of a seed: each half cosine's peak ``pi A / (2 D)`` is
    1.2-3 times the rail."""
    rng = np.random.default_rng(seed)
    axes = rng.permutation(FLICK_AXES)
    ratios = rng.uniform(*RATIO, len(axes))
    signs = rng.choice([-1.0, 1.0], len(axes))
    return [(t0, axis, sign * ANGLE_DEG[axis], np.pi * ANGLE_DEG[axis] / (2.0 * ratio * rail_deg_s))
            for t0, axis, ratio, sign in zip(FLICK_T_S, axes, ratios, signs)]


def motion(seed: int, rail_deg_s: float):
    """The seed's motion: ``motion(t_s) -> (heading, pitch, roll, magnet)``, degrees (as ``scripted_motion``)."""
    rng = np.random.default_rng(seed + 1000)
    f = rng.uniform(0.1, 0.3, 3)
    a = rng.uniform(5.0, 10.0, 3)
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    moves = flicks(seed, rail_deg_s)

    def run(t_s):
        t = np.asarray(t_s, dtype=float)
        angles = [30.0 + a[0] * np.sin(2 * np.pi * f[0] * t + phase[0]), a[1] * np.sin(2 * np.pi * f[1] * t + phase[1]),
                  a[2] * np.sin(2 * np.pi * f[2] * t + phase[2])]
        for t0, axis, angle, duration in moves:
            step = 0.5 * (1.0 - np.cos(np.pi * np.clip((t - t0) / duration, 0.0, 1.0)))
            k = "zyx".index(axis)
            angles[k] = angles[k] + angle * (step - (0.5 if k else 0.0))  # pitch and roll flicked through level
        return angles[0], angles[1], angles[2], np.zeros(len(t))

    return run, moves


def read_as_part(gyro_rad_s: np.ndarray, rail_deg_s: float) -> np.ndarray:
    """The rate a 16-bit gyro of full scale ``rail_deg_s`` sends: counts of ``rail / 32768``, clipped to
    [-32768, 32767], rad/s."""
    lsb = np.radians(rail_deg_s) / COUNTS
    return np.clip(np.round(gyro_rad_s / lsb), -COUNTS, COUNTS - 1.0) * lsb


def with_lever(s, seed: int, lever_m: float):
    """``s`` with the accelerometer ``lever_m`` from the turn's centre (a seeded direction in H): the specific force
    gains ``dw/dt x r + w x (w x r)``, g (``w`` the true rate, from the attitude)."""
    if lever_m == 0.0:
        return s
    rng = np.random.default_rng(seed + 2000)
    r = rng.normal(size=3)
    r *= lever_m / np.linalg.norm(r)
    dt = np.gradient(s.t_s)
    step = (s.rotation[:-1].inv() * s.rotation[1:]).as_rotvec() / np.diff(s.t_s)[:, None]
    w = np.vstack([step[:1], (step[:-1] + step[1:]) / 2.0, step[-1:]])
    dw = np.gradient(w, axis=0) / dt[:, None]
    return replace(s, accel=s.accel + (np.cross(dw, r) + np.cross(w, np.cross(w, r))) / STANDARD_GRAVITY)


def cases(seeds, rails, flick_rail: float | None = None, lever_m: float = 0.0) -> dict:
    """``{(rail, seed): (samples, flicks, field, gyro as read)}``, the flicks 1.2-3 times ``flick_rail`` (None: the
    rail's), the accelerometer ``lever_m`` from the turn's centre."""
    from compass.sim.device import default_model, simulate_device

    model = default_model()
    t = np.arange(0.0, DURATION_S, 1.0 / RATE_HZ)
    out = {}
    for rail in rails:
        for seed in seeds:
            run, moves = motion(seed, rail if flick_rail is None else flick_rail)
            s = with_lever(simulate_device(model, t, motion=run, seed=seed), seed, lever_m)
            out[rail, seed] = (s, moves, model.field(s.raw)[0], read_as_part(s.gyro, rail))
    return out


def base_quats(tree: Path, data: dict) -> dict:
    """The baseline tree's ``run_filter`` quaternions (NWU, scipy order) per case, in a child process."""
    with tempfile.TemporaryDirectory() as folder:
        inputs, outputs = Path(folder) / "in.npz", Path(folder) / "out.npz"
        arrays = {}
        for (rail, seed), (s, _, field, gyro) in data.items():
            key = f"{rail:g}_{seed}"
            arrays |= {f"{key}/t": s.t_s, f"{key}/accel": s.accel, f"{key}/gyro": gyro, f"{key}/field": field}
        np.savez(inputs, **arrays)
        subprocess.run([sys.executable, "-c", RUN_CHILD, str(inputs), str(outputs)], check=True, cwd=folder,
                       env=tree_env(tree, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1"))
        with np.load(outputs) as d:
            return {(rail, seed): d[f"{rail:g}_{seed}"] for rail, seed in data}


def this_quats(data: dict) -> dict:
    from compass.filter import FilterConfig, run_filter
    from compass.sim.device import default_model

    config = FilterConfig.from_model(default_model())
    return {k: run_filter(s.t_s, s.accel, gyro, field, config).quat for k, (s, _, field, gyro) in data.items()}


def vqf_quats(data: dict) -> dict | None:
    """VQF's 9D quaternions put into NWU (its North is the field's, as the simulation's), scipy order."""
    try:
        from vqf import VQF
    except ImportError:
        print("skipping vqf: not installed (PYTHONPATH=...:/tmp/lever_pkgs, or pip install -e '.[bench]')")
        return None
    from compass.io.broad import NWU_FROM_ENU

    out = {}
    for k, (s, _, field, gyro) in data.items():
        q = VQF(1.0 / RATE_HZ).updateBatch(np.ascontiguousarray(gyro), np.ascontiguousarray(s.accel * STANDARD_GRAVITY),
                                           np.ascontiguousarray(field))["quat9D"]
        out[k] = (NWU_FROM_ENU * Rotation.from_quat(q, scalar_first=True)).as_quat()
    return out


def errors(s, quat) -> tuple[np.ndarray, np.ndarray]:
    """Heading and inclination error per sample, deg (NaN before the filter's first attitude: counted as 180)."""
    from compass.evaluation import orientation_errors

    ok = np.all(np.isfinite(quat), axis=1)
    heading, inclination = np.full(len(quat), 180.0), np.full(len(quat), 180.0)
    h, _, i = orientation_errors(Rotation.from_quat(quat[ok]), s.rotation[ok])
    heading[ok], inclination[ok] = h, i
    return heading, inclination


def recovery_s(t, heading, inclination, start_s) -> float:
    """Seconds from ``start_s`` until both errors stay within :data:`WITHIN_DEG` for :data:`HOLD_S`
    (:data:`AFTER_S` when they do not within it)."""
    window = (t >= start_s) & (t < start_s + AFTER_S)
    good = ((heading <= WITHIN_DEG) & (inclination <= WITHIN_DEG))[window]
    hold = int(round(HOLD_S * RATE_HZ))
    runs = np.convolve(good.astype(int), np.ones(hold, dtype=int), mode="valid")
    hits = np.flatnonzero(runs == hold)
    return float(hits[0] / RATE_HZ) if len(hits) else AFTER_S


def scores(data: dict, quats: dict) -> dict:
    """Per rail: ``{"all": (h, i), "after": (h, i), "recover": [s...], axis: (h, i, mean recovery)}``."""
    out = {}
    for rail in sorted({r for r, _ in data}):
        pooled = {"all": ([], []), "after": ([], []), **{a: ([], []) for a in "zyx"}}
        recover = {a: [] for a in "zyx"}
        for (r, seed), (s, moves, _, _) in data.items():
            if r != rail:
                continue
            h, i = errors(s, quats[r, seed])
            late = s.t_s >= SKIP_S
            pooled["all"][0].append(h[late])
            pooled["all"][1].append(i[late])
            for t0, axis, _, duration in moves:
                w = (s.t_s >= t0 + duration) & (s.t_s < t0 + duration + AFTER_S)
                for key in ("after", axis):
                    pooled[key][0].append(h[w])
                    pooled[key][1].append(i[w])
                recover[axis].append(recovery_s(s.t_s, h, i, t0 + duration))
        rms = {k: tuple(float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for v in pair) for k, pair in pooled.items()}
        out[rail] = rms | {"recover": recover}
    return out


def table(results: dict, rails) -> None:
    for rail in rails:
        print(f"\nrail {rail:g} deg/s: heading / inclination RMS, deg; recovery (within {WITHIN_DEG:g} deg for "
              f"{HOLD_S:g} s), s, mean over flicks [worst]")
        print(f"{'method':<8} {'all':>13} {'10 s after':>13} {'recover':>13}   "
              + "   ".join(f"{a} flicks: after / recover" for a in "zyx"))
        for name, res in results.items():
            r = res[rail]
            every = sum(r["recover"].values(), [])
            cells = "   ".join(f"{r[a][0]:5.2f} {r[a][1]:5.2f} / {np.mean(r['recover'][a]):4.2f} "
                               f"[{max(r['recover'][a]):4.1f}]" for a in "zyx")
            print(f"{name:<8} {r['all'][0]:6.2f} {r['all'][1]:6.2f} {r['after'][0]:6.2f} {r['after'][1]:6.2f} "
                  f"{np.mean(every):5.2f} [{max(every):4.1f}]   {cells}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first-seed", type=int, default=60)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--rails", default="250,500", help="full scales, deg/s, comma-separated")
    parser.add_argument("--baseline", default="5e858bb", help="git ref of the filter before")
    parser.add_argument("--lever-m", type=float, default=0.1,
                        help="the accelerometer's distance from the flick's centre, m (a wrist: 0.1)")
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rails = [float(v) for v in args.rails.split(",")]
    data = cases(seeds, rails, lever_m=args.lever_m)
    unclipped = cases(seeds, [2000.0], min(rails), args.lever_m)
    with tempfile.TemporaryDirectory() as folder:
        tree = export_tree(args.baseline, Path(folder))
        base, base_free = base_quats(tree, data), base_quats(tree, unclipped)
    results = {"base": scores(data, base), "this": scores(data, this_quats(data))}
    vqf = vqf_quats(data)
    if vqf is not None:
        results["vqf"] = scores(data, vqf)
    print(f"seeds {seeds.start}-{seeds.stop - 1}; flicks 1.2-3 x the rail; "
          f"{RATE_HZ:g} Hz; lever arm {args.lever_m:g} m; baseline {args.baseline}")
    table(results, rails)
    free = this_quats(unclipped)
    same = all(np.array_equal(free[k], base_free[k], equal_nan=True) for k in free)
    print(f"\nrail 2000 deg/s (nothing clips): this == base bit for bit: {same}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
