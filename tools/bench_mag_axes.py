"""A magnetometer chip whose axes are not the IMU's, calibrated on a robot path (issue 22, item 4).

Run: ``python tools/bench_mag_axes.py [--seeds 3] [--first-seed 0]`` (about 2 min a seed on a loaded 2-core machine).

Real 9-axis boards often carry the magnetometer on its own die or chip with its own axes: MPU-9250's AK8963 reads the
IMU's ``(y, x, -z)``, ICM-20948's AK09916 ``(x, -y, -z)``, and a board's wiring can reverse one axis (left-handed).
One of issue 22's hidden boards sent its magnetometer's z reversed against its accelerometer.  Each seed is a 60 s robot path
(:func:`compass.sim.robot.simulate_robot`) with :func:`bench_broad.board_errors`' low-cost board, the magnetometer read
through hard and soft iron by a chip with each of those axes; the calibration file is another path of the same board
(seed + 1000, the rows at a sixth of the rate: 18-29 % of the sphere), written as a tumble CSV and calibrated by
``compass calibrate``; the scored path is replayed by ``compass attitude --filter``, both in-process through
:func:`compass.cli.main`.  Columns, heading / inclination RMS after the first 5 s (deg, BROAD's error quaternion):

- "check off": ``compass calibrate`` with the gyro's axis check (:func:`compass.axes.axes_from_gyro`) switched off
  here, the attitude replayed with its file ("refused": exit 2; "failed": another exit);
- "this": ``compass calibrate`` as it is: refused (exit 2) where the check names the axes, then rerun with the
  ``--columns`` remap its words give (the verdict's ``columns`` with the file's names put in), the replay given the
  same remap;
- "verdict": what the check named ("named right" or "WRONG" against the chip's axes; "covered": named, and the fitted
  rotation already takes it into the gyro's axes, so the file stands with a warning; ``-``: nothing).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import sys
import tempfile
from pathlib import Path
from unittest import mock

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from bench_broad import board_errors  # noqa: E402

G = 9.80665
CAL_SEED = 1000
SCORED_AFTER_S = 5.0
CHIPS = {"as the IMU": np.eye(3), "MPU-9250 (y, x, -z)": np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]),
         "ICM-20948 (x, -y, -z)": np.diag([1.0, -1, -1]), "x reversed (left-handed)": np.diag([-1.0, 1, 1])}


def write_csv(path: Path, rec, q, hard, soft, step: int) -> None:
    """The path as a board with magnetometer axes ``q`` sends it: ``h + A Q b``, accelerometer in g, gyro in rad/s."""
    rows = slice(None, None, step)
    mag = hard + (rec.mag_ut @ q.T) @ soft.T
    data = np.column_stack([rec.t_s, mag, rec.accel_m_s2 / G, rec.gyro_rad_s])[rows]
    np.savetxt(path, data, delimiter=",", header="t_s,mx,my,mz,ax,ay,az,gx,gy,gz", comments="", fmt="%.6f")


def cli(*args) -> tuple[int, str]:
    """``compass ARGS`` in-process: exit status and what it printed."""
    from compass.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        status = main([str(a) for a in args])
    return status, out.getvalue()


def scores(att: Path, run) -> tuple[float, float]:
    """Heading and inclination RMS of the replay's quaternions against the path's truth, deg."""
    from compass.evaluation import error_series
    from compass.io.broad import nwu_to_enu

    with open(att) as stream:
        table = list(csv.reader(line for line in stream if not line.startswith("#")))
    header, body = table[0], np.array(table[1:], dtype=float)
    q = body[:, [header.index(c) for c in ("qw", "qx", "qy", "qz")]]
    t = body[:, header.index("t_s")]
    rows = np.clip(np.searchsorted(run.t_s, t - 1e-5), 0, len(run.t_s) - 1)  # the file's times carry 6 decimals
    truth = Rotation.from_quat(run.rotation.as_quat()[rows])
    est = nwu_to_enu(Rotation.from_quat(q, scalar_first=True)).as_quat(scalar_first=True)
    e = error_series(est, nwu_to_enu(truth).as_quat(scalar_first=True), t >= SCORED_AFTER_S, 285.714)
    return e.heading_rms_deg, e.inclination_rms_deg


def one(folder: Path, seed: int, name: str, q) -> tuple:
    """``(check off, this, verdict)`` in words for one chip on one seed."""
    from compass.sim.robot import simulate_robot

    errors = board_errors("low-cost", seed)
    rng = np.random.default_rng(seed)
    hard = rng.uniform(-20.0, 20.0, 3)
    soft = np.eye(3) + 0.03 * rng.normal(size=(3, 3))
    soft = (soft + soft.T) / 2.0
    cal, run = simulate_robot(seed + CAL_SEED, errors=errors), simulate_robot(seed, errors=errors)
    write_csv(folder / "cal.csv", cal, q, hard, soft, 6)
    write_csv(folder / "run.csv", run, q, hard, soft, 1)

    def replay(calibration: Path, *columns) -> tuple[float, float]:
        status, text = cli("attitude", calibration, folder / "run.csv", "--out", folder / "att.csv", "--filter",
                           "--force", *columns)
        if status != 0:
            raise RuntimeError(text)
        return scores(folder / "att.csv", run)

    def scored(status: int, calibration: Path, *columns) -> str:
        """The replay's figures, or why there is no calibration to replay."""
        if status != 0:
            return "refused" if status == 2 else f"failed (exit {status})"
        heading, inclination = replay(calibration, *columns)
        return f"{heading:.2f} / {inclination:.2f}"

    with mock.patch("calibrate.tumble.fit.axes_from_gyro", return_value=None):
        status, text = cli("calibrate", folder / "cal.csv", "--out", folder / "off.json", "--force", "--quiet")
    off = scored(status, folder / "off.json")
    status, text = cli("calibrate", folder / "cal.csv", "--out", folder / "on.json", "--force", "--quiet")
    verdict, columns = ("covered: calibrated as read" if "not the gyro's" in text else "-"), ()
    if status == 2 and "not the gyro's" in text:
        from compass.axes import axes_from_gyro  # the named axes, as the words give them
        from compass.io.tumble import read_tumble

        rec = read_tumble(folder / "cal.csv")
        found = axes_from_gyro(rec.mag, rec.gyro_turn_rad, rec.t_s, up=rec.accel)
        verdict = "named right" if np.array_equal(found.matrix, q) else "named WRONG"
        columns = ("--columns", found.columns.removeprefix("--columns ").replace("COLUMN(", "").replace(")", ""))
        status, text = cli("calibrate", folder / "cal.csv", "--out", folder / "on.json", "--force", "--quiet", *columns)
    return off, scored(status, folder / "on.json", *columns), verdict


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=0)
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"robot paths {seeds.start}-{seeds.stop - 1}, low-cost board; heading / inclination RMS after "
          f"{SCORED_AFTER_S:.0f} s, deg", flush=True)
    print("| chip | seed | check off | this | verdict |\n|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, q in CHIPS.items():
            for seed in seeds:
                off, this, verdict = one(Path(tmp), seed, name, q)
                print(f"| {name} | {seed} | {off} | {this} | {verdict} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
