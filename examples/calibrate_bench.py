"""Calibrate a simulated four-flip bench session with the joint fit and with the seed's own rule.

The library path a user follows with a real recording, on simulated data so it runs anywhere:

1. ``simulate_fourflip`` plays seed 000's bench: three channels near housing X, Y, Z, four flips
   of the cube, a full turn of the turntable in 1 deg steps each, 0.15 uT noise;
   ``write_fourflip`` writes it as a SPEC recording (CSV, plus the truth beside it);
2. ``read_fourflip`` reads and validates the CSV, as it would a recording from the bench;
3. ``calibrate_fourflip`` estimates every channel's sensing direction, response and the dip,
   with ``method="ml"`` (joint maximum likelihood, with standard errors) and
   ``method="patent"`` (the seed exactly as written: minima picked from the samples);
4. the two are compared with the simulator's truth, which the estimators never see.

Run: ``python examples/calibrate_bench.py``
"""

import tempfile
from pathlib import Path

import numpy as np

from calibrate import calibrate_fourflip
from compass.io.fourflip import read_fourflip
from compass.sim.fourflip import simulate_fourflip, write_fourflip


def angle_deg(a, b, *, axis=False):
    """Angle between unit vectors, degrees; ``axis`` ignores the sign (a and -a are one axis)."""
    dot = float(np.dot(a, b))
    return float(np.degrees(np.arccos(np.clip(abs(dot) if axis else dot, -1.0, 1.0))))


def main() -> None:
    session = simulate_fourflip(seed=7, noise_ut=0.15, step_deg=1.0)
    with tempfile.TemporaryDirectory() as folder:
        path, _ = write_fourflip(session, Path(folder) / "bench.csv")
        rec = read_fourflip(path)
    print(f"recording: {rec.n_samples} samples, channels {', '.join(rec.channels)}, |B| {rec.field_ut:g} uT\n")

    ml = calibrate_fourflip(rec, method="ml")
    patent = calibrate_fourflip(rec, method="patent")
    print(ml.report())
    print()

    truth = session.truth
    print("against the simulator's truth (degrees):")
    print(f"{'channel':>8} {'ml error':>9} {'ml sigma':>9} {'patent error':>13} {'patent axis':>12}")
    for c, name in enumerate(rec.channels):
        true_dir = np.asarray(truth["directions"][c])
        print(f"{name:>8} {angle_deg(ml.directions[c], true_dir):9.4f} {ml.channels[c].direction_sigma_deg:9.4f}"
              f" {angle_deg(patent.directions[c], true_dir):13.2f}"
              f" {angle_deg(patent.directions[c], true_dir, axis=True):12.2f}")
    print(f"{'dip':>8} {ml.dip_deg - truth['dip_deg']:+9.4f} {ml.dip_sigma_deg:9.4f}"
          f" {patent.dip_deg - truth['dip_deg']:+13.2f}")
    print("\n'patent axis' forgives the sign: the seed's angles assume a positive X component, so a Y channel")
    print("(or a Z channel tilted backwards) comes out reversed. See tools/bench_fourflip.py for the statistics.")


if __name__ == "__main__":
    main()
