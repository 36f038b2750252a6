"""Benchmark: the bench accelerometer's alignment with the housing (mag_to_accel) and the turntable's tilt.

Simulates ``--n`` seeded four-flip sessions (three channels as in ``bench_fourflip.py``) with an
accelerometer in the housing misaligned by ``--misalign-deg`` RMS per rotation-vector component
(white noise ``--noise-g``) on a turntable tilted ``--tilt-deg`` from level toward a random
azimuth, calibrates each (``ml``, diagnosis on), and prints side by side:

- the error of the estimated ``mag_to_accel`` (rotation vector, accelerometer frame, per axis),
  the reported sigma and ``sqrt(mean((err / sigma)^2))`` (1 when the sigma is honest);
- the turntable tilt's error and pull;
- the dip: the magnetic fit's (against the turntable axis) and the one referred to gravity with
  the measured tilt, both against the true dip (against gravity), with their pulls;
- runtime pitch/roll errors (``--samples`` random attitudes within +-40 deg, the same simulated
  module and accelerometer) solved three ways: the accelerometer as recorded (``before``: the
  calibration's ``mag_to_accel`` ignored, as the toolkit did), rotated into the housing by the
  calibration's ``mag_to_accel`` (``after``), and an ideally aligned accelerometer with the same
  noise (``floor``).

A second block repeats the runtime comparison with accelerometer offsets (``--offset-g`` RMS) and
scale errors (``--scale-error`` RMS): the calibration measures and reports them, the runtime does
not remove them (what is left).  A third has cube faces off square (the simulator's ``flip_error``,
0.45-1 deg): the gravity directions in H then are not square either; the toolkit uses the flip errors
the magnetic diagnosis fitted, beside the same accelerometer fit that ignores them (the baseline).

Usage::

    python tools/bench_bench_accel.py [--n 20] [--seed 0] [--misalign-deg 1] [--tilt-deg 0.3] [--write-docs]

``--write-docs`` writes the three blocks as one table into docs/calibration.md (``tools/_doc_table.py``).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from calibrate import calibrate_fourflip
from calibrate.fourflip.accelerometer import fit_accelerometer
from compass.attitude import solve_attitude
from compass.calibration import from_dict
from compass.sim.fourflip import SimAccelerometer, simulate_fourflip
from compass.sim.runtime import simulate_runtime

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _doc_table import markdown_table, parse_args, publish  # noqa: E402

RUNTIME = (("before", "before (mag_to_accel ignored)"), ("rotated", "rotated into H, offsets kept"),
           ("after", "after (offsets, scales undone)"), ("floor", "floor (aligned accelerometer)"))


def _truth(session, name):
    return next(e["parameters"] for e in session.truth["effects"] if e["name"] == name)


def _rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x**2)))


def _pitch_roll_error(model, runtime, accel) -> np.ndarray:
    res = solve_attitude(model, runtime.outputs, accel=accel)
    return np.concatenate([res.pitch_deg - runtime.pitch_deg, res.roll_deg - runtime.roll_deg])


def run(n, seed, accelerometer, tilt_deg, samples, effects=()) -> dict:
    out = {k: [] for k in ("rot_err", "rot_sigma", "tilt_err", "tilt_sigma", "dip_axis_err", "dip_axis_sigma",
                           "dip_g_err", "dip_g_sigma", "before", "rotated", "after", "floor", "warnings", "blind_err",
                           "blind_sigma")}
    for i in range(n):
        session = simulate_fourflip(seed=seed + i, accelerometer=accelerometer, turntable_tilt_deg=tilt_deg,
                                    effects=effects, effect_scale=1.5)
        rec = session.recording()
        result = calibrate_fourflip(rec, diagnose=True)  # as compass calibrate does
        doc = result.to_json()
        block = doc["accelerometer"]
        true = Rotation.from_matrix(np.array(_truth(session, "accelerometer")["mag_to_accel"]))
        out["rot_err"].append((Rotation.from_matrix(np.array(doc["mag_to_accel"])) * true.inv()).as_rotvec(degrees=True))
        out["rot_sigma"].append(block["mag_to_accel_rotvec_sigma_deg"])
        if effects:  # the baseline: the same fit told no flip errors
            blind = fit_accelerometer(rec.accel, rec.platform_deg, rec.flip_deg, rec.flip_index)
            out["blind_err"].append((Rotation.from_matrix(blind.mag_to_accel) * true.inv()).as_rotvec(degrees=True))
            out["blind_sigma"].append(blind.rotvec_sigma_deg)
        if tilt_deg:
            up = np.array(_truth(session, "turntable_tilt")["up_in_turntable_frame"])
            out["tilt_err"].append(block["turntable_tilt_deg"] - np.degrees(np.arcsin(np.linalg.norm(up[:2]))))
            out["tilt_sigma"].append(block["turntable_tilt_sigma_deg"])
        out["dip_axis_err"].append(block["dip_turntable_axis_deg"] - session.truth["dip_deg"])
        out["dip_axis_sigma"].append(np.degrees(result.parameters["dip_rad"][1]))
        out["dip_g_err"].append(block["dip_gravity_deg"] - session.truth["dip_deg"])
        out["dip_g_sigma"].append(block["dip_gravity_sigma_deg"])
        out["warnings"] += [w for w in result.warnings if w.startswith("accelerometer")]
        cal = from_dict(doc)
        model = cal.model
        runtime = simulate_runtime(session.truth, samples, seed=1000 + seed + i, max_tilt_deg=40.0)
        aligned = simulate_runtime({**session.truth, "effects": []}, samples, seed=1000 + seed + i, max_tilt_deg=40.0)
        out["before"].append(_pitch_roll_error(model, runtime, runtime.accel))
        out["rotated"].append(_pitch_roll_error(model, runtime, cal.imu.apply(runtime.accel, bench=False)))
        out["after"].append(_pitch_roll_error(model, runtime, cal.imu.in_model_frame(runtime.accel)[0]))
        out["floor"].append(_pitch_roll_error(model, aligned, aligned.accel))
        print(f"  {i + 1}/{n}", file=sys.stderr, flush=True) if (i + 1) % 10 == 0 else None
    return {k: np.array(v) if k != "warnings" else v for k, v in out.items()}


def _rotation_rows(err, sig, indent: str) -> None:
    """RMS error, mean sigma and err/sigma of each rotation-vector component."""
    for label, values, fmt in (("RMS error", [_rms(err[:, j]) for j in range(3)], "10.4f"),
                               ("mean reported sigma", [np.mean(sig[:, j]) for j in range(3)], "10.4f"),
                               ("err/sigma (1: honest sigma)", [_rms(err[:, j] / sig[:, j]) for j in range(3)], "10.2f")):
        print(f"{indent}{label:{34 - len(indent)}s}" + "".join(f"{v:{fmt}}" for v in values))


def report(r, title) -> None:
    print(title)
    print("  mag_to_accel (rotation vector, deg)   x         y         z")
    _rotation_rows(r["rot_err"], r["rot_sigma"], "    ")
    if len(r["blind_err"]):
        print("    baseline: flip errors ignored")
        _rotation_rows(r["blind_err"], r["blind_sigma"], "      ")
    if len(r["tilt_err"]):
        print(f"  turntable tilt: RMS error {_rms(r['tilt_err']):.4f} deg, mean sigma {np.mean(r['tilt_sigma']):.4f}, "
              f"err/sigma {_rms(r['tilt_err'] / r['tilt_sigma']):.2f}")
    print("  dip against gravity (the truth)    RMS error    mean sigma   err/sigma")
    print(f"    magnetic fit (turntable axis) {_rms(r['dip_axis_err']):12.4f} {np.mean(r['dip_axis_sigma']):12.4f} "
          f"{_rms(r['dip_axis_err'] / r['dip_axis_sigma']):10.2f}")
    print(f"    referred to gravity (tilt)    {_rms(r['dip_g_err']):12.4f} {np.mean(r['dip_g_sigma']):12.4f} "
          f"{_rms(r['dip_g_err'] / r['dip_g_sigma']):10.2f}")
    print("  runtime pitch/roll error, deg     RMS       max |err|")
    for name, label in RUNTIME:
        e = r[name]
        print(f"    {label:30s} {_rms(e):8.4f} {np.max(np.abs(e)):10.4f}")
    counts = {}
    for w in r["warnings"]:
        key = re.sub(r"[-+]?\d+\.?\d*", "#", w.split(":", 1)[1]).strip()[:70]
        counts[key] = counts.get(key, 0) + 1
    for key, k in counts.items():
        print(f"  warned in {k} of {len(r['rot_err'])} sessions: {key} ...")


def summary(r) -> dict[str, str]:
    """One block's figures as table cells: RMS error (err/sigma) and the runtime RMS, degrees."""
    def pulled(err, sig) -> str:
        return f"{_rms(err):.4f} ({_rms(np.asarray(err) / np.asarray(sig)):.2f})"

    def per_axis(err, sig) -> str:
        return " / ".join(f"{_rms(err[:, j]):.4f}" for j in range(3)) + " (" + \
            " / ".join(f"{_rms(err[:, j] / sig[:, j]):.2f}" for j in range(3)) + ")"

    cells = {"mag_to_accel x / y / z": per_axis(r["rot_err"], r["rot_sigma"])}
    if len(r["blind_err"]):
        cells["mag_to_accel, flip errors ignored (baseline)"] = per_axis(r["blind_err"], r["blind_sigma"])
    if len(r["tilt_err"]):
        cells["turntable tilt"] = pulled(r["tilt_err"], r["tilt_sigma"])
    cells["dip, magnetic fit (turntable axis)"] = pulled(r["dip_axis_err"], r["dip_axis_sigma"])
    cells["dip referred to gravity"] = pulled(r["dip_g_err"], r["dip_g_sigma"])
    cells |= {f"runtime pitch/roll RMS, {label}": f"{_rms(r[name]):.4f}" for name, label in RUNTIME}
    return cells


def doc_table(blocks: dict[str, dict[str, str]]) -> str:
    """Figures down (in the order of the block that has the most), blocks across; a figure a block lacks is empty."""
    figures = list(dict.fromkeys(f for cells in sorted(blocks.values(), key=len, reverse=True) for f in cells))
    return markdown_table(["figure, deg: RMS error (err/sigma)", *blocks],
                          [[f, *(cells.get(f, "") for cells in blocks.values())] for f in figures])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--misalign-deg", type=float, default=1.0)
    p.add_argument("--noise-g", type=float, default=0.002)
    p.add_argument("--tilt-deg", type=float, default=0.3)
    p.add_argument("--offset-g", type=float, default=0.005)
    p.add_argument("--scale-error", type=float, default=0.003)
    p.add_argument("--samples", type=int, default=400, help="runtime attitudes per session")
    a = parse_args(p, argv)
    print(f"bench_bench_accel: {a.n} sessions (seeds {a.seed}..{a.seed + a.n - 1}), accelerometer misaligned "
          f"{a.misalign_deg:g} deg RMS per axis, noise {a.noise_g:g} g, turntable tilted {a.tilt_deg:g} deg, "
          f"{a.samples} runtime attitudes within +-40 deg each\n")
    clean = SimAccelerometer(misalign_deg=a.misalign_deg, noise_g=a.noise_g)
    blocks = {}
    r = run(a.n, a.seed, clean, a.tilt_deg, a.samples)
    report(r, "A. misaligned accelerometer, no offsets or scale errors")
    blocks["A. misaligned"] = summary(r)
    print()
    dirty = SimAccelerometer(misalign_deg=a.misalign_deg, noise_g=a.noise_g, offset_g=a.offset_g,
                             scale_error=a.scale_error)
    r = run(a.n, a.seed, dirty, a.tilt_deg, a.samples)
    report(r, f"B. plus offsets {a.offset_g:g} g and scale errors {a.scale_error:g} RMS per axis (measured on the "
              "bench, undone at runtime)")
    blocks[f"B. plus offsets {a.offset_g:g} g, scales {100 * a.scale_error:g} %"] = summary(r)
    print()
    r = run(a.n, a.seed, clean, a.tilt_deg, a.samples, effects=("flip_error",))
    report(r, "C. as A, cube faces off square (flip_error 0.45-1 deg, fitted by the magnetic diagnosis)")
    blocks["C. as A, cube faces off square 0.45-1 deg"] = summary(r)
    publish(a, "docs/calibration.md", "bench_bench_accel", doc_table(blocks),
            caption=f"{a.n} sessions (seeds {a.seed}-{a.seed + a.n - 1}), accelerometer misaligned "
                    f"{a.misalign_deg:g} deg RMS per axis, noise {a.noise_g:g} g, turntable tilted {a.tilt_deg:g} deg, "
                    f"{a.samples} runtime attitudes within +-40 deg each")
    return 0


if __name__ == "__main__":
    sys.exit(main())
