"""The accelerometer's own calibration (calibrate/tumble/accelerometer.py) on simulated robot paths, against the truth.

Run: ``python tools/bench_accel_fit.py [--seeds 10] [--first-seed 60]``.  For each of bench_broad's boards and seed
``s``: the fit on the calibration path ``s + 1000`` at a sixth of the rate (as tools/bench_robot.py's files), then
the RMS angle between the true specific force of path ``s`` and the board's noise-free reading of it (deg): raw,
corrected by the still rows' fit alone (:func:`fit_accelerometer`) and by the calibration file's correction
(``compass calibrate``'s path, :func:`bench_broad.file_values`: the held offsets and scales fitted beside the
gyro-aided fit, :func:`calibrate.tumble.gyro.with_gyro`); the parameters the still rows held (not determined) and
did not see, and those the file took from the gyro-aided fit.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from bench_broad import board_errors, file_values  # noqa: E402
from calibrate.tumble.accelerometer import NoAccelCalibration, fit_accelerometer  # noqa: E402
from compass.sim.robot import simulate_robot  # noqa: E402

BOARDS = ("broad-like", "low-cost", "bad-accel")


def angles_deg(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Angle between the rows of ``x`` and ``y`` (n, 3), deg."""
    cos = np.sum(x * y, axis=1) / np.linalg.norm(x, axis=1) / np.linalg.norm(y, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def one(board: str, seed: int) -> tuple:
    """(raw, still rows alone, file RMS deg, held count, unseen count, count the file took from the gyro) of one
    board and seed."""
    errors = board_errors(board, seed)
    cal = simulate_robot(seed + 1000, errors=errors)
    try:
        fit = fit_accelerometer(cal.accel_m_s2[::6], cal.t_s[::6])
    except NoAccelCalibration as exc:
        print(f"  {board} seed {seed}: {exc}")
        fit = None
    keep = np.zeros(len(cal.t_s), bool)
    keep[::6] = True
    values = file_values(cal.t_s, cal.gyro_rad_s, cal.accel_m_s2, cal.mag_ut, keep)
    f = simulate_robot(seed, errors=errors).specific_force_m_s2
    read = f * (1.0 + np.asarray(errors.accel_scale)) + np.asarray(errors.accel_bias_m_s2)
    corrected = read if fit is None else fit.apply(read)
    file = values["accel_correction"]
    in_file = read if file is None else (read - np.asarray(file[1])) @ np.asarray(file[0]).T
    rms = [float(np.sqrt(np.mean(angles_deg(v, f) ** 2))) for v in (read, corrected, in_file)]
    counts = (0, 0) if fit is None else (len(fit.held), len(fit.unseen))
    return (*rms, *counts, len(values["accel_from_gyro"]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=60)
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"robot paths {seeds.start}-{seeds.stop - 1}: the corrected direction's RMS error, deg (mean over seeds; "
          "worst)")
    for board in BOARDS:
        r = np.array([one(board, s) for s in seeds])
        print(f"{board:12s} raw {r[:, 0].mean():7.3f} -> still rows alone {r[:, 1].mean():6.3f} ({r[:, 1].max():.3f})"
              f" -> the file {r[:, 2].mean():6.3f} ({r[:, 2].max():.3f}); held {r[:, 3].mean():.1f}, unseen "
              f"{r[:, 4].mean():.1f} of 9, from the gyro-aided fit {r[:, 5].mean():.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
