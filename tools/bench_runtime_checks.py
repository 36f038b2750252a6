"""What the runtime's two sensor checks say on data they were not tuned on (issue 22): honest data must pass.

- The gyro's unit against the calibrated field's turn (:func:`compass.io.units.gyro_field_ratio`, said over
  :data:`compass.io.units.FIELD_UNIT_RATIO`): the ratio on BROAD's trials, as read and with the gyro in deg/s read as
  rad/s, over the first :data:`compass.live.GYRO_UNIT_WINDOW_S` window that turned the field enough (what ``compass
  live`` and the replay judge: window after window from the start), the largest over every such window (the margin
  to the bound), and the whole trial.
- The accelerometer's axes against the gyro's (:func:`compass.axes.accel_axes_from_gyro`): said or not on every BROAD
  trial as read, with the accelerometer's z reversed and with the gyro's x and y swapped; on the simulated hand-held
  kinds (seeds 0-1) and robot paths (seeds 0-2, a low-cost board) as read and with the gyro's z reversed.

BROAD's magnetometer is raw (its hard iron is small against |B|), so its field stands for the calibrated one here.

Usage::

    python tools/bench_runtime_checks.py [--data ../shared/data/broad]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from compass.axes import accel_axes_from_gyro, turned_enough  # noqa: E402
from compass.io.broad import read_broad  # noqa: E402
from compass.io.tumble import gyro_turns  # noqa: E402
from compass.io.units import FIELD_UNIT_RATIO, gyro_field_ratio  # noqa: E402
from compass.live import GYRO_UNIT_WINDOW_S  # noqa: E402

FIRST_ROWS = 6000  # compass.live.GYRO_AXES_ROWS: the rows live judges
SWAP_XY = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
REVERSE_Z = np.diag([1.0, 1.0, -1.0])


def _said(accel, gyro, t) -> str:
    words = accel_axes_from_gyro(accel, gyro_turns(t, gyro, np.ones(len(t), dtype=bool)), t)
    return "said" if words is not None else "-"


def first_judged(t, gyro) -> slice:
    """The rows ``compass live`` judges: the first :data:`FIRST_ROWS` whose turns are enough, the older half of each
    window that is not dropped (``LiveSession._judge_gyro_axes``); all rows when none is."""
    start = 0
    while start + FIRST_ROWS <= len(t):
        rows = slice(start, start + FIRST_ROWS)
        if turned_enough(gyro_turns(t[rows], gyro[rows], np.ones(FIRST_ROWS, dtype=bool)), t[rows]):
            return rows
        start += FIRST_ROWS // 2
    return slice(0, len(t))


def _ratio(value) -> str:
    return "-" if value is None else f"{value:.1f}"


def unit_windows(t, gyro, field) -> list[tuple[float, float]]:
    """``(end s, ratio)`` of :func:`gyro_field_ratio` over each :data:`compass.live.GYRO_UNIT_WINDOW_S` window that
    turned the field enough, in order (live judges each, and says the first over the bound)."""
    n = int(round(GYRO_UNIT_WINDOW_S / np.median(np.diff(t))))
    ratios = ((t[i + n - 1], gyro_field_ratio(t[i:i + n], gyro[i:i + n], field[i:i + n]))
              for i in range(0, len(t) - n + 1, n))
    return [(end, r) for end, r in ratios if r is not None]


def _said_at(windows) -> str:
    """When live says the unit: the end of the first window over :data:`FIELD_UNIT_RATIO`, s."""
    return next((f"{end:.0f} s" for end, r in windows if r > FIELD_UNIT_RATIO), "never")


def broad_rows(folder: Path) -> list[str]:
    lines = [f"BROAD: the gyro against the field (said over {FIELD_UNIT_RATIO:g}) and the accelerometer's axes",
             f"{'trial':<42} {'ratio first/max/whole':>22} {'said at':>8} {'deg/s said at':>14} {'axes as read':>13} "
             f"{'az reversed':>12} {'gyro x,y swapped':>17}"]
    for path in sorted(folder.glob("*.mat")):
        trial = read_broad(path)
        t = np.arange(len(trial.gyro_rad_s)) / trial.rate_hz
        g, a, m = trial.gyro_rad_s, trial.accel_m_s2, trial.mag_ut
        windows, degrees = unit_windows(t, g, m), unit_windows(t, np.degrees(g), m)
        ratios = f"{_ratio(windows[0][1])} / {_ratio(max(r for _, r in windows))}" if windows else "- / -"
        lines.append(f"{path.stem:<42} {ratios + ' / ' + _ratio(gyro_field_ratio(t, g, m)):>22} "
                     f"{_said_at(windows):>8} {_said_at(degrees):>14} "
                     f"{_said(a, g, t):>13} {_said(a @ REVERSE_Z, g, t):>12} {_said(a, g @ SWAP_XY, t):>17}")
    return lines


def simulated_rows() -> list[str]:
    from compass.sim.motion import KINDS, SensorErrors, simulate_motion
    from compass.sim.robot import simulate_robot

    low_cost = SensorErrors(gyro_bias_rad_s=(0.01, -0.008, 0.005), gyro_scale=(0.015, -0.01, 0.02),
                            accel_bias_m_s2=(0.15, -0.1, 0.12), accel_scale=(0.02, -0.015, 0.01), gyro_noise=3e-4)
    recordings = [(f"{kind} {seed}", simulate_motion(kind, seed=seed, duration_s=30.0)) for kind in KINDS
                  for seed in (0, 1)]
    recordings += [(f"robot {seed} (low-cost)", simulate_robot(seed, duration_s=40.0, errors=low_cost))
                   for seed in (0, 1, 2)]
    lines = ["simulated: the accelerometer's axes (the first 6000 rows that turn)",
             f"{'recording':<28} {'as read':>8} {'gyro z reversed':>16}"]
    for name, rec in recordings:
        n = first_judged(rec.t_s, rec.gyro_rad_s)
        t, g, a = rec.t_s[n], rec.gyro_rad_s[n], rec.accel_m_s2[n]
        lines.append(f"{name:<28} {_said(a, g, t):>8} {_said(a, g @ REVERSE_Z, t):>16}")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "broad"), help="BROAD's .mat folder")
    args = parser.parse_args(argv)
    folder = Path(args.data)
    lines = broad_rows(folder) if folder.is_dir() else [f"{folder}: no BROAD trials, skipped"]
    print("\n".join(lines + [""] + simulated_rows()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
