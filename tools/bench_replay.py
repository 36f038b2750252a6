"""The filter's start and the one pipeline (issue 22), this tree beside a baseline revision, same run, seeded.

Run: ``python tools/bench_replay.py [--baseline REF] [--broad DATA_DIR] [--trials 01,06,15,24,32]``
(default baseline: the merge base with ``main``; default BROAD trials: bench_broad's quick five).

Each tree runs the same worker (this file with ``--worker``) in its own process and prints per case:

- **offline**: ``run_filter(t, accel, gyro, model.field(raw), FilterConfig.from_model(model))``, the
  README's documented offline path;
- **live**: a :class:`compass.live.LiveSession` fed the same samples as protocol lines (exact floats);

with the heading and inclination RMS against the truth after the first 5 s (BROAD's metric where
scored), the largest gyro-bias error over the first 10 s (deg/s) and the share of samples whose
accelerometer was used.  Cases (none designed for the change's numbers; the simulators' defaults):

- ``device``: the simulated module's 30 s script (``compass.sim.device``), gyro bias 0.2 deg/s;
- ``row0 4.5deg``, ``row0 x1.3``, ``row0 zero``: its first accelerometer row turned 4.5 degrees, read
  1.3 times too large, or zero (the issue's real boards);
- ``all x1.3``: an accelerometer reading 1.3 g at rest throughout (an uncalibrated one);
- ``motion KIND``: ``compass.sim.motion`` trials, 40 s, seed 7, starting in motion (``rest_s=0``), and
  with its default 3 s rest (offline only: the simulator's field is in uT without a sensor model;
  the config is the simulator's |B| and dip, as tests/compass/sim/test_motion.py builds it);
- ``BROAD NN``: BROAD trials through bench_broad's pipeline (config from the trial's initial rest,
  causal hard-iron tracker, run_filter), offline only.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from _baseline import export_tree, tree_env  # noqa: E402

RATE_HZ = 100.0
BIAS = np.array([0.004, -0.003, 0.002])  # rad/s
MOTION_KINDS = ("slow_rotation", "fast_rotation", "fast_translation", "breaks")


def _wrap(d):
    return np.mod(np.asarray(d) + 180.0, 360.0) - 180.0


def _scores(t, heading, pitch, roll, bias, accel_used, truth):
    from scipy.spatial.transform import Rotation

    from compass.evaluation import orientation_errors

    ok = np.isfinite(heading)
    est = Rotation.from_euler("ZYX", np.column_stack([-heading[ok], -pitch[ok], roll[ok]]), degrees=True)
    h, _, inc = orientation_errors(est, truth[np.flatnonzero(ok)])
    late = t[ok] > 5.0
    early = (t < 10.0) & np.all(np.isfinite(bias), axis=1) if bias is not None else None
    out = {"heading": float(np.sqrt(np.mean(h[late] ** 2))), "incl": float(np.sqrt(np.mean(inc[late] ** 2))),
           "accel_used": float(np.mean(accel_used)), "solved": float(np.mean(ok))}
    if bias is not None and early.any():
        out["bias_err"] = float(np.degrees(np.max(np.abs(bias[early] - BIAS))))
    return out


def _live(model, t, raw, accel, gyro):
    """LiveSession fed protocol lines; heading, pitch, roll, accel_used per sample (NaN where none)."""
    import io

    from compass.io.lines import format_line
    from compass.live import LiveSession
    from compass.serial_reader import Chunk

    names = ["t_s", *model.channels, "ax", "ay", "az", "gx", "gy", "gz"]
    rows = np.column_stack([t, raw, accel, gyro])
    data = format_line(names) + b"".join(format_line([repr(v) for v in row.tolist()]) for row in rows)
    out = io.StringIO()
    session = LiveSession(model, out=out)
    for k in range(0, len(data), 4096):
        session.feed(Chunk(time.perf_counter(), data[k:k + 4096]))
    session.close()
    lines = [line.split(",") for line in out.getvalue().splitlines()[2:]]
    index = {round(float(v[0]), 4): v for v in lines}
    angles = np.full((len(t), 4), np.nan)
    for i, ts in enumerate(t):
        v = index.get(round(float(ts), 4))
        if v is not None:
            angles[i] = [float(v[1]), float(v[2]), float(v[3]), float(v[10])]
    return angles


def _device_cases():
    from scipy.spatial.transform import Rotation

    from compass.sim.device import default_model, simulate_device

    model = default_model()
    t = np.arange(0.0, 30.0, 1.0 / RATE_HZ)
    s = simulate_device(model, t, seed=5, gyro_bias=BIAS)
    truth = s.rotation
    cases = {"device": s.accel}
    a = s.accel.copy()
    a[0] = Rotation.from_rotvec([np.radians(4.5), 0.0, 0.0]).apply(a[0])
    cases["row0 4.5deg"] = a
    a = s.accel.copy()
    a[0] *= 1.3
    cases["row0 x1.3"] = a
    a = s.accel.copy()
    a[0] = 0.0
    cases["row0 zero"] = a
    cases["all x1.3"] = 1.3 * s.accel
    for name, accel in cases.items():
        yield name, model, t, s.raw, accel, s.gyro, truth


def worker(broad_dir: str | None, trials: list[str]) -> dict:
    from compass.filter import FilterConfig, run_filter

    results = {}
    for name, model, t, raw, accel, gyro, truth in _device_cases():
        track = run_filter(t, accel, gyro, model.field(raw)[0], FilterConfig.from_model(model))
        results[f"{name} | offline"] = _scores(t, track.heading_deg, track.pitch_deg, track.roll_deg, track.gyro_bias,
                                               track.accel_used, truth)
        live = _live(model, t, raw, accel, gyro)
        results[f"{name} | live"] = _scores(t, live[:, 0], live[:, 1], live[:, 2], None, np.nan_to_num(live[:, 3]),
                                            truth)
    from compass.sim.motion import SensorErrors, simulate_motion

    errors = SensorErrors(gyro_bias_rad_s=tuple(BIAS), gyro_scale=(0.005, -0.005, 0.003))
    for kind in MOTION_KINDS:
        for rest in (0.0, 3.0):
            rec = simulate_motion(kind, duration_s=40.0, seed=7, errors=errors, rest_s=rest)
            cfg = FilterConfig(field_norm=rec.field_ut, dip_deg=rec.dip_deg, mag_noise=rec.errors.mag_noise_ut)
            track = run_filter(rec.t_s, rec.accel_m_s2, rec.gyro_rad_s, rec.mag_ut, cfg)
            results[f"motion {kind} rest {rest:g}s | offline"] = _scores(
                rec.t_s, track.heading_deg, track.pitch_deg, track.roll_deg, track.gyro_bias, track.accel_used,
                rec.rotation)
    if broad_dir:
        results |= _broad(Path(broad_dir), trials)
    return results


def _broad(folder: Path, trials: list[str]) -> dict:
    from scipy.spatial.transform import Rotation

    from compass.evaluation import error_series, initial_field
    from compass.filter import FilterConfig, run_filter
    from compass.hard_iron import track_hard_iron
    from compass.io.broad import nwu_to_enu, read_broad

    out = {}
    for path in sorted(folder.glob("*.mat")):
        if path.name[:2] not in trials:
            continue
        trial = read_broad(path)
        field_ut, dip_deg, noise_ut = initial_field(trial.mag_ut, trial.accel_m_s2, ~trial.movement)
        config = FilterConfig(field_norm=field_ut, dip_deg=dip_deg, mag_noise=noise_ut)
        field = track_hard_iron(trial.mag_ut, trial.accel_m_s2, trial.rate_hz, dip_deg=dip_deg).corrected(trial.mag_ut)
        track = run_filter(trial.t_s, trial.accel_m_s2, trial.gyro_rad_s, field, config)
        quat = nwu_to_enu(Rotation.from_quat(np.nan_to_num(track.quat, nan=0.5))).as_quat(scalar_first=True)
        e = error_series(quat, trial.ref_quat_enu, trial.movement, trial.rate_hz)
        out[f"BROAD {path.name[:2]} | offline"] = {"heading": float(e.heading_rms_deg),
                                                    "incl": float(e.inclination_rms_deg),
                                                    "accel_used": float(np.mean(track.accel_used)), "solved": 1.0}
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="git revision to compare with (default: merge base with main)")
    parser.add_argument("--broad", default=str(ROOT.parent / "shared" / "data" / "broad"),
                        help="BROAD .mat folder ('' to skip)")
    parser.add_argument("--trials", default="01,06,15,24,32", help="BROAD trial numbers")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    trials = args.trials.split(",")
    broad = args.broad if args.broad and Path(args.broad).is_dir() else None
    if args.worker:
        print(json.dumps(worker(broad, trials)))
        return 0
    ref = args.baseline or subprocess.run(["git", "-C", str(ROOT), "merge-base", "HEAD", "main"], check=True,
                                          capture_output=True, text=True).stdout.strip()
    with tempfile.TemporaryDirectory() as folder:
        base_tree = export_tree(ref, Path(folder))
        runs = {}
        for label, tree in (("baseline", base_tree), ("this tree", None)):
            print(f"running {label} ...", file=sys.stderr, flush=True)
            cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--broad", broad or "",
                   "--trials", args.trials]
            done = subprocess.run(cmd, env=tree_env(tree or ROOT), capture_output=True, text=True, cwd=folder,
                                  check=True)
            runs[label] = json.loads(done.stdout.strip().splitlines()[-1])
    print(f"baseline {ref[:10]} vs this tree (seeded; heading/inclination RMS deg after 5 s, BROAD: its metric; "
          f"bias_err: largest gyro-bias error in the first 10 s, deg/s; accel: share of samples tilt-corrected)")
    print(f"{'case':42s} {'heading':>17s} {'inclination':>17s} {'bias_err':>15s} {'accel used':>15s}")
    for case in runs["this tree"]:
        old, new = runs["baseline"].get(case, {}), runs["this tree"][case]

        def pair(key, fmt="%.3f"):
            a, b = old.get(key), new.get(key)
            return f"{fmt % a if a is not None else '-':>7s} -> {fmt % b if b is not None else '-':>7s}"

        print(f"{case:42s} {pair('heading')} {pair('incl')} {pair('bias_err')} {pair('accel_used', '%.2f')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
