"""The four-flip calibration and its diagnosis on recordings from an independent simulator.

The toolkit's own simulator shares the forward model with the estimator; this one does not: plain
numpy rotation matrices, 2 degree steps, and effects written here in their own forms, some of
which the toolkit models (a symmetric or asymmetric non-linearity, a per-flip yaw of the cube on the
turntable) and some it does not (a first-order lag of the output, cross-talk between channels).
It prints what the loop named, whether it called the residual unexplained, the residual before
and after over the noise floor, the direction error (degrees) and the direction error over the
reported sigma (1 when the sigma is honest), against the directions the simulator used.

Run: ``python tools/bench_independent_sim.py [--n 5] [--write-docs]`` (``--write-docs``: the table into
docs/calibration.md, ``tools/_doc_table.py``).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from calibrate import calibrate_fourflip
from compass.io.fourflip import FourFlipRecording

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _doc_table import markdown_table, parse_args, publish  # noqa: E402

NOISE_UT = 0.15
FIELD_UT = 50.0
GAIN = 0.02  # volts per uT
CASES = (
    ("clean", 0.0),
    ("odd cubic 1 %", 0.01),
    ("even 1 %", 0.01),
    ("even 3 %", 0.03),
    ("output lag 0.3 sample", 0.7),
    ("per-flip yaw 0.5 deg", 0.5),
    ("cross-talk 2 %", 0.02),
)


def session(seed: int, case: str, size: float) -> tuple[FourFlipRecording, np.ndarray]:
    """One recording and the sensing directions behind it (rows, housing frame)."""
    rng = np.random.default_rng(seed)
    directions = np.eye(3) + rng.normal(scale=0.03, size=(3, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    dip, azimuth = np.radians(rng.uniform(40, 70)), rng.uniform(0, 2 * np.pi)
    field_w = FIELD_UT * np.array([np.cos(dip) * np.cos(azimuth), np.cos(dip) * np.sin(azimuth), -np.sin(dip)])
    flip = np.repeat(np.arange(4), 180)
    phi = np.concatenate([rng.uniform(0, 360) + np.arange(0.0, 360.0, 2.0) for _ in range(4)])
    kappa = 90.0 * flip
    yaw = np.radians(np.array([0.0, size, -size, size / 2]))[flip] if case.startswith("per-flip yaw") else 0.0
    pose = Rotation.from_euler("z", (np.radians(phi) + yaw)[:, None]) * Rotation.from_euler("x", np.radians(kappa)[:, None])
    x = pose.apply(field_w, inverse=True) @ directions.T  # uT along each channel
    if case.startswith("odd cubic"):
        x = x - size * x**3 / FIELD_UT**2
    elif case.startswith("even"):
        x = x + size * x**2 / FIELD_UT
    elif case.startswith("cross-talk"):
        x[:, 0] += size * x[:, 1]  # channel a now senses along d_a + size d_b: that is its direction
        directions = directions.copy()
        directions[0] += size * directions[1]
        directions[0] /= np.linalg.norm(directions[0])
    out = 1.5 + GAIN * x
    if case.startswith("output lag"):
        lagged = out.copy()
        for i in range(1, len(out)):
            if flip[i] == flip[i - 1]:
                lagged[i] = lagged[i - 1] + size * (out[i] - lagged[i - 1])
        out = lagged
    out = out + rng.normal(scale=GAIN * NOISE_UT, size=out.shape)
    t_s = np.arange(len(phi)) * 1.0 + flip * 30.0
    rec = FourFlipRecording(kappa, flip, np.mod(phi, 360.0), out, ("a", "b", "c"), t_s, None, None,
                            {"field_ut": f"{FIELD_UT:g}"})
    return rec, directions


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=5, help="recordings per case (default 5)")
    args = parse_args(parser, argv)
    table = []
    print(f"Independent simulator: {args.n} recordings per case, 4 flips x 180 samples, noise {NOISE_UT} uT\n")
    print(f"{'case':<24}{'named effects':<28}{'unexplained':>12}{'rms/floor before -> after':>28}{'err, deg':>10}"
          f"{'err/sigma':>11}")
    for case, size in CASES:
        named, unexplained, before, after, errors, ratios = Counter(), 0, [], [], [], []
        for seed in range(args.n):
            rec, truth = session(seed, case, size)
            result = calibrate_fourflip(rec, diagnose=True)
            d = result.diagnosis
            named[", ".join(d["effects"]) or "none"] += 1
            unexplained += d["unexplained"]
            before.append(d["residual_rms_before"] / d["noise_floor"])
            after.append(d["residual_rms_after"] / d["noise_floor"])
            err = np.degrees(np.arccos(np.clip(np.sum(result.directions * truth, axis=1), -1, 1)))
            errors.extend(err)
            ratios.extend(err / np.array([c.direction_sigma_deg for c in result.channels]))
        names = "; ".join(f"{k} x{v}" for k, v in named.items())
        rms_error, rms_ratio = np.sqrt(np.mean(np.square(errors))), np.sqrt(np.mean(np.square(ratios)))
        print(f"{case:<24}{names:<28}{unexplained:>9}/{args.n}{np.mean(before):>16.2f} -> {np.mean(after):<9.2f}"
              f"{rms_error:>10.3f}{rms_ratio:>11.2f}")
        table.append([case, names, f"{unexplained}/{args.n}", f"{np.mean(before):.2f} -> {np.mean(after):.2f}",
                      f"{rms_error:.3f}", f"{rms_ratio:.2f}"])
    print("\nerr, deg: RMS of each channel's direction error; err/sigma: the same over its reported sigma (against the"
          "\neffective direction for cross-talk: the leak is part of what the channel senses). A per-flip yaw is the"
          "\nturntable_zero effect (flip 0's is the field azimuth). A lag common to all flips is a shift of the field"
          "\nazimuth.")
    publish(args, "docs/calibration.md", "bench_independent_sim",
            markdown_table(["case", "effects named", "unexplained", "residual / floor, before -> after", "err, deg",
                            "err/sigma"], table),
            caption=f"{args.n} recordings per case, 4 flips x 180 samples, noise {NOISE_UT} uT")
    return 0


if __name__ == "__main__":
    sys.exit(main())
