"""``compass demo``: the main job on built-in simulated data, end to end.

Simulates a four-flip bench session, calibrates it (with the residual diagnosis) and prints the
report; then simulates the calibrated module in random attitudes, solves heading, pitch and roll
with the calibration and compares them with the truth.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np


def register(sub) -> None:
    p = sub.add_parser("demo", help="simulate a bench session, calibrate it, solve attitude, print the report")
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    p.add_argument("--effect", action="append", default=[], help="inject a simulator effect (repeatable)")
    p.add_argument("--workdir", default=None, help="keep the files here (default: a temporary folder)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..calibration_file import load
    from ..sim.fourflip import SIM_EFFECTS, simulate_fourflip, write_fourflip
    from ..sim.runtime import simulate_runtime, write_runtime
    from . import attitude as attitude_cmd
    from . import calibrate as calibrate_cmd

    unknown = set(args.effect) - set(SIM_EFFECTS)
    if unknown:
        from ..cli import BadInput

        raise BadInput(f"unknown effect(s) {sorted(unknown)}; known: {', '.join(SIM_EFFECTS)}")
    folder = Path(args.workdir or tempfile.mkdtemp(prefix="compass-demo-"))
    session = simulate_fourflip(seed=args.seed, effects=tuple(args.effect))
    rec_path, _ = write_fourflip(session, folder / "bench.csv", force=True)
    print(f"1. simulated a four-flip bench session: {rec_path}"
          + (f" (effects the estimator is not told about: {', '.join(args.effect)})" if args.effect else ""))
    cal_path = folder / "cal.json"
    print("2. calibrating it (joint maximum likelihood, residual diagnosis):")
    cal_result = calibrate_cmd.calibrate_file(rec_path, cal_path, report=folder / "report", force=True)
    cal = load(cal_path).data
    truth = session.truth
    print("   against the simulator's truth (the estimator never saw it):")
    for name, true_dir in zip(truth["channels"], truth["directions"]):
        ch = cal["channels"][name]
        err = np.degrees(np.arccos(np.clip(np.dot(ch["direction"], true_dir), -1.0, 1.0)))
        print(f"   {name}: direction error {err:.4f} deg (reported sigma {ch['direction_sigma_deg']:.4f} deg)")
    print(f"   dip error {cal['dip_deg'] - truth['dip_deg']:+.4f} deg (reported sigma {cal['dip_sigma_deg']:.4f} deg)")

    print("3. solving attitude: the module in 2000 random attitudes (pitch, roll within +-80 deg):")
    runtime = simulate_runtime(truth, 2000, seed=args.seed)
    run_path, _ = write_runtime(runtime, folder / "runtime.csv", force=True)
    att = attitude_cmd.attitude_file(cal_path, run_path, folder / "attitude.csv", force=True)
    heading_err = np.mod(att.heading_deg - runtime.heading_deg + 180.0, 360.0) - 180.0
    print(f"   heading RMS error {np.sqrt(np.mean(heading_err**2)):.3f} deg "
          f"(propagated 1-sigma {np.sqrt(np.mean(att.heading_sigma_deg**2)):.3f} deg), "
          f"pitch {np.sqrt(np.mean((att.pitch_deg - runtime.pitch_deg) ** 2)):.3f} deg, "
          f"roll {np.sqrt(np.mean((att.roll_deg - runtime.roll_deg) ** 2)):.3f} deg")
    _record(folder / "demo.rrd", rec_path, cal_result, cal_path, att, runtime)
    print(f"files in {folder} (plots in {folder / 'report'})")
    return 0


def _record(path, rec_path, cal_result, cal_path, att, runtime) -> None:
    """demo.rrd: the calibration, the attitude and its errors in Rerun (when rerun-sdk is installed)."""
    try:
        from ..viz.demo import record_demo
    except ImportError:
        print("4. (pip install 'compass-toolkit[rerun]' to also get demo.rrd, the whole run in the Rerun viewer)")
        return
    from ..model import SensorModel
    from .calibrate import _base_residuals

    record_demo(path, rec_path, cal_result, att, SensorModel.from_file(cal_path), t_s=runtime.t_s,
                raw=runtime.outputs, accel=runtime.accel, truth_heading_deg=runtime.heading_deg,
                truth_pitch_deg=runtime.pitch_deg, truth_roll_deg=runtime.roll_deg,
                base_residuals=_base_residuals(cal_result))
    print(f"4. wrote {path}: the calibration, the attitude and its errors against the truth; open it with "
          f"`rerun {path}` (pip install 'compass-toolkit[rerun]' installs the viewer)")
