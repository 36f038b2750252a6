"""Broken-module checks: false alarms on clean sessions of every simulator, and what each defect gives.

    python tools/bench_health.py [--n 100] [--seed0 1000]

For each kind, ``--n`` seeded clean sessions are calibrated through the kind's calibrator (as
``compass calibrate`` does, without the residual diagnosis, which the checks do not use) and the
broken-module warnings and refusals are counted (target: at most 1 % of sessions).  Then every
defect of issue Z is injected into the same sessions, one channel at a time:

- dead: the channel's output constant plus a third of its noise;
- drowned: 20 times the channel's noise added;
- off axis: the channel's sensing direction 20 deg from its housing axis;

and the share of sessions refused (dead) or warned about the right channel (drowned, off axis) is
printed beside the same count for the kind's fit without these checks (its library function, as
``compass calibrate`` ran before them: a refusal or any warning that names the channel counts).
Seeds start at ``--seed0``, none of which the tests use.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibrate import calibrate_fourflip  # noqa: E402
from calibrate.contract import CannotCalibrate  # noqa: E402
from calibrate.tumble.fit import calibrate_tumble  # noqa: E402
from calibrate.fourflip import FourFlipCalibrator  # noqa: E402
from calibrate.platform3d import Platform3DCalibrator  # noqa: E402
from calibrate.reference import ReferenceCalibrator  # noqa: E402
from calibrate.tumble import TumbleCalibrator  # noqa: E402
from compass.io.fourflip import read_fourflip  # noqa: E402
from compass.io.platform3d import read_platform3d  # noqa: E402
from compass.io.reference import read_reference  # noqa: E402
from compass.io.tumble import read_tumble  # noqa: E402
from compass.sim.fourflip import simulate_fourflip, write_fourflip  # noqa: E402
from compass.sim.platform3d import simulate_platform3d, write_platform3d  # noqa: E402
from compass.sim.reference import simulate_reference, write_reference  # noqa: E402
from compass.sim.tumble import simulate_tumble, write_tumble  # noqa: E402

WORDS = ("signal-to-noise", "housing axis")


def verdict(calibrator, rec) -> tuple[str, list[str]]:
    """``("refused", [reason])`` or ``("ok", health warnings)``."""
    try:
        result = calibrator.fit(rec)
    except CannotCalibrate as exc:
        return "refused", [str(exc)]
    return "ok", [w for w in result.warnings if any(word in w for word in WORDS)]


def said(label: str, name: str, state: str, words: list[str]) -> bool:
    """Whether a verdict says the case: anything on a clean session (a false alarm); the channel named."""
    if label == "clean":
        return state == "refused" or bool(words)
    if label == "dead":
        return state == "refused" and f"'{name}'" in words[0]
    return state == "ok" and any(w.startswith(f"channel {name}:") for w in words)


def before(kind: str, rec, name: str) -> tuple[str, list[str]]:
    """The fit without the checks: refused, or the warnings that name the channel."""
    try:
        if kind == "four-flip":
            result = calibrate_fourflip(rec)
        else:
            result = calibrate_tumble(rec.mag, rec.accel, t_s=rec.t_s)
            if result.refused:
                return "refused", [f"'{name}'" * (name in result.refused) + result.refused]
    except CannotCalibrate as exc:
        return "refused", [str(exc)]
    named = [w for w in result.warnings if name in w]
    return "ok", [f"channel {name}: {w}" for w in named]


def tilt_one(directions: np.ndarray, c: int, angle_deg: float, rng) -> np.ndarray:
    """Turn channel ``c``'s direction by ``angle_deg`` away from its axis, toward a random perpendicular."""
    a = directions[c]
    perp = np.cross(a, rng.normal(size=3))
    out = directions.copy()
    out[c] = Rotation.from_rotvec(np.radians(angle_deg) * perp / np.linalg.norm(perp)).apply(a)
    return out


def fourflip_cases(seed: int, folder: Path):
    rng = np.random.default_rng(seed)
    c = int(rng.integers(3))
    name = f"v{c + 1}"
    session = simulate_fourflip(seed=seed)
    rec = read_fourflip(write_fourflip(session, folder / f"ff{seed}.csv", force=True)[0])
    truth = session.truth
    noise = truth["noise"][c]
    dead = rec.outputs.copy()
    dead[:, c] = truth["offsets"][c] + rng.normal(0.0, noise / 3, len(dead))
    drowned = rec.outputs.copy()
    drowned[:, c] += rng.normal(0.0, 20 * noise, len(drowned))
    # off axis: the same session's channels, one of them 20 deg farther from its housing axis than drawn
    nominal = np.eye(3)
    directions = np.asarray(truth["directions"])
    off = tilt_one(nominal, c, 20.0, rng)
    directions = directions.copy()
    directions[c] = Rotation.align_vectors([off[c]], [nominal[c]])[0].apply(directions[c])
    moved = read_fourflip(write_fourflip(simulate_fourflip(seed=seed, directions=directions),
                                         folder / f"ff{seed}off.csv", force=True)[0])
    return name, {"clean": rec, "dead": replace(rec, outputs=dead), "drowned": replace(rec, outputs=drowned),
                  "off axis": moved}


def tumble_cases(seed: int, folder: Path):
    rng = np.random.default_rng(seed)
    c = int(rng.integers(3))
    name = ("mx", "my", "mz")[c]
    sim = simulate_tumble(seed=seed, n=1500)
    cases = {"clean": sim.mag}
    dead = sim.mag.copy()
    dead[:, c] = np.median(dead[:, c]) + rng.normal(0.0, 0.1, len(dead))
    drowned = sim.mag.copy()
    drowned[:, c] += rng.normal(0.0, 20 * 0.3, len(drowned))
    cases |= {"dead": dead, "drowned": drowned}
    out = {}
    for label, mag in cases.items():
        path, _ = write_tumble(replace(sim, mag=mag), folder / f"tb{seed}{label[:2]}.csv", force=True)
        out[label] = read_tumble(path)
    return name, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100, help="sessions per kind (default 100)")
    ap.add_argument("--seed0", type=int, default=1000)
    args = ap.parse_args()
    seeds = range(args.seed0, args.seed0 + args.n)
    start = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for kind, make, calibrator in (("four-flip", fourflip_cases, FourFlipCalibrator(diagnose=False)),
                                       ("tumble", tumble_cases, TumbleCalibrator())):
            counts: dict[str, list[tuple[int, int]]] = {}
            for i, seed in enumerate(seeds):
                name, cases = make(seed, folder)
                for label, rec in cases.items():
                    now = said(label, name, *verdict(calibrator, rec))
                    then = said(label, name, *before(kind, rec, name))
                    counts.setdefault(label, []).append((int(now), int(then)))
                print(f"\r{kind}: {i + 1}/{args.n}", end="", file=sys.stderr, flush=True)
            print(file=sys.stderr)
            rows += [(kind, label, sum(v[0] for v in c), sum(v[1] for v in c), len(c)) for label, c in counts.items()]
        for kind, sim, write, read, calibrator in (
                ("3-D platform", simulate_platform3d, write_platform3d, read_platform3d, Platform3DCalibrator(diagnose=False)),
                ("reference", simulate_reference, write_reference, read_reference, ReferenceCalibrator(diagnose=False))):
            alarms = []
            for seed in seeds:
                path, _ = write(sim(seed=seed), folder / f"{kind[:3]}{seed}.csv", force=True)
                alarms.append(int(said("clean", "", *verdict(calibrator, read(path)))))
            rows.append((kind, "clean", sum(alarms), None, len(alarms)))
    print(f"\nBroken-module checks over {args.n} seeded sessions per kind (seeds {args.seed0}..{args.seed0 + args.n - 1}), "
          f"{time.perf_counter() - start:.0f} s")
    print(f"{'kind':<14}{'case':<10}{'said now':>10}{'without checks':>16}   (clean: false alarms, target <= 1 %)")
    for kind, label, now, then, n in rows:
        then = "-" if then is None else f"{then}/{n}"
        print(f"{kind:<14}{label:<10}{f'{now}/{n}':>10}{then:>16}   now {100 * now / n:.1f} %")


if __name__ == "__main__":
    main()
