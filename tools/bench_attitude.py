"""Benchmark of the runtime solver: attitude accuracy against truth, honesty of sigma, throughput.

For each seed: a simulated four-flip bench session (three channels near X, Y, Z with 3 deg RMS
misalignment, |B| = 50 uT, dip in [40, 70] deg, noise ``--noise-ut``) is calibrated in-process
with ``ml`` (the default) and with ``patent`` (seed 000 as written).  The same sensor is then
moved through ``--n`` random attitudes (heading uniform, pitch and roll uniform in +-80 deg;
channel noise ``--noise-ut``, accelerometer noise ``--accel-noise-g`` per axis) and solved by

- ``ml``: :func:`compass.attitude.solve_attitude` with the ml calibration; its RMS error is
  printed beside the RMS of the propagated 1-sigma (``predicted``; ``ratio`` = error/predicted);
- ``patent``: the same solver and data with the patent-mode calibration (its error is dominated
  by the seed's half-angle rule, which reverses a channel with a negative X component, e.g. a Y
  channel tilted slightly backwards; see docs/calibration.md, "Seed corrections"; and by its dip and
  narrow tabulated range);
- ``ahrs TRIAD``: the peer (``pip install ahrs``, a benchmark extra), fed the accelerometer and
  the ml calibration's field vectors, with the same references (``--peer-n`` samples: it loops
  in Python).

Then throughput: samples per second of ``solve_attitude`` in-process for 10^6 samples (best of
3, wall clock and CPU), and ``compass attitude`` on a 10^6-row CSV (a subprocess, wall clock:
start-up, read, solve, write).  Targets: heading ratio <= 1.1; patent heading error >= 10x ml;
>= 10^6 samples/s; CSV < 10 s.  Then the tilt under a disturbed field or a wrong reference
(:func:`disturbed_tilt`) and temperature compensation (:func:`temperature`).

Usage::

    python tools/bench_attitude.py [--seeds 3] [--n 100000] [--noise-ut 0.15] [--accel-noise-g 0.002] [--write-docs]

``--write-docs`` writes the accuracy, tilt and temperature tables into docs/runtime.md
(``tools/_doc_table.py``).
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
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _doc_table import markdown_table, parse_args, publish  # noqa: E402

from calibrate import calibrate_fourflip
from compass.attitude import solve_attitude, two_vector_rotation
from compass.frames import heading_pitch_roll, world_field
from compass.io.fourflip import read_fourflip
from compass.site import known_reference
from compass.model import SensorModel
from compass.sim.fourflip import simulate_fourflip, write_fourflip
from compass.sim.runtime import simulate_runtime, write_runtime
from compass.calibration import model_from_dict
from compass.calibration import model_to_dict


def wrap(d):
    return np.mod(d + 180.0, 360.0) - 180.0


def rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def triad(model: SensorModel, raw, accel):
    """ahrs' TRIAD on the calibrated field and the accelerometer; None if ahrs is not installed."""
    try:
        from ahrs.filters import TRIAD
    except ImportError:
        return None
    field, _ = model.field(raw)
    peer = TRIAD(v1=np.array([0.0, 0.0, 1.0]), v2=world_field(model.dip_deg))  # our NWU references
    body_from_world = np.array([peer.estimate(a, b) for a, b in zip(accel, field)])  # A v_ref = w_body
    return heading_pitch_roll(Rotation.from_matrix(np.transpose(body_from_world, (0, 2, 1))))


def accuracy(args, folder: Path):
    errors = {"ml": [], "patent": [], "ahrs TRIAD": []}
    sigmas = []
    for seed in range(args.seed, args.seed + args.seeds):
        session = simulate_fourflip(seed=seed, noise_ut=args.noise_ut)
        path, _ = write_fourflip(session, folder / f"bench{seed}.csv", force=True)
        rec = read_fourflip(path)
        models = {m: model_from_dict(json.loads(json.dumps(calibrate_fourflip(rec, method=m).to_json())))
                  for m in ("ml", "patent")}
        rt = simulate_runtime(session.truth, args.n, seed=1000 + seed, noise_ut=args.noise_ut,
                              accel_noise_g=args.accel_noise_g)
        truth = (rt.heading_deg, rt.pitch_deg, rt.roll_deg)
        for name, model in models.items():
            att = solve_attitude(model, rt.outputs, accel=rt.accel, accel_noise_g=args.accel_noise_g)
            errors[name].append(np.stack([wrap(e - t) for e, t in zip((att.heading_deg, att.pitch_deg, att.roll_deg), truth)]))
            if name == "ml":
                sigmas.append(np.stack([att.heading_sigma_deg, att.pitch_sigma_deg, att.roll_sigma_deg]))
        k = args.peer_n
        peer = triad(models["ml"], rt.outputs[:k], rt.accel[:k])
        if peer is not None:
            errors["ahrs TRIAD"].append(np.stack([wrap(e - t[:k]) for e, t in zip(peer, truth)]))
    return ({k: np.concatenate(v, axis=1) for k, v in errors.items() if v}, np.concatenate(sigmas, axis=1))


def disturbed_tilt(args, n=20_000):
    """Pitch and roll when the field's dip is not the reference's, beside two fixed-weight baselines.

    One ml calibration (seed ``args.seed``); the same random attitudes read (a) clean, (b) with a
    magnet of (8, -6, 10) uT NWU on a quarter of the rows, (c) against a reference dip 10 deg off,
    (d) with 7 uT of hard iron in H (a product's iron, no installation calibration).  Solved by
    ``solve_attitude`` (each row's weight from its own dip discrepancy; disturbed rows gravity
    only), by the two-vector solution with the fixed noise-optimal weight it used before
    (``f = s_g^2 / (s_g^2 + s_B^2)``), and by gravity alone (TRIAD, ``f = 0``).  RMS over the
    affected rows, degrees.
    """
    session = simulate_fourflip(seed=args.seed, noise_ut=args.noise_ut)
    truth = session.truth
    model = model_from_dict(json.loads(json.dumps(calibrate_fourflip(session.recording()).to_json())))
    right = known_reference(truth["dip_deg"], truth["field_ut"])
    magnet = np.zeros((n, 3))
    magnet[: n // 4] = (8.0, -6.0, 10.0)
    iron_h = np.array([2.8, 6.6, 2.7])  # uT in H
    cases = {"clean": (None, right, slice(None)),
             "magnet (8, -6, 10) uT on 1/4 of rows": (magnet, right, slice(0, n // 4)),
             "reference dip 10 deg off": (None, known_reference(truth["dip_deg"] + 10.0, truth["field_ut"]), slice(None)),
             "7 uT hard iron in H, not calibrated": ("iron", right, slice(None))}
    field_var = np.sum(model.component_variance(np.zeros(3)) * model.solver**2) / 3.0 / truth["field_ut"] ** 2
    up_var = args.accel_noise_g**2
    print(f"\nTilt when the field's dip is not the reference's (ml calibration, seed {args.seed}, {n} attitudes; "
          f"pitch / roll RMS over the affected rows, deg)")
    print(f"{'case':<38}{'solve_attitude':>18}{'fixed weight':>18}{'gravity only':>18}{'disturbed':>11}")
    table = []
    for label, (extra, reference, rows) in cases.items():
        rt = simulate_runtime(truth, n, seed=77, noise_ut=args.noise_ut, accel_noise_g=args.accel_noise_g,
                              extra_field_ut=None if isinstance(extra, str) else extra)
        raw = rt.outputs
        if isinstance(extra, str):
            raw = raw + np.asarray(truth["gains_per_ut"]) * (np.asarray(truth["directions"]) @ iron_h)
        att = solve_attitude(model, raw, accel=rt.accel, accel_noise_g=args.accel_noise_g, reference=reference)
        field, _ = model.field(raw)
        results = [(att.pitch_deg, att.roll_deg)]
        for f in (up_var / (up_var + field_var), 0.0):
            _, pitch, roll = heading_pitch_roll(two_vector_rotation(rt.accel, field, reference.dip_deg, f))
            results.append((pitch, roll))
        cells = [f"{rms(wrap(p - rt.pitch_deg)[rows]):.3f} / {rms(wrap(r - rt.roll_deg)[rows]):.3f}" for p, r in results]
        print(f"{label:<38}" + "".join(f"{c:>18}" for c in cells) + f"{att.disturbed[rows].mean():>10.0%}")
        table.append([label, *cells, f"{att.disturbed[rows].mean():.0%}"])
    return markdown_table(["case", "solve_attitude", "fixed weight", "gravity only", "rows flagged disturbed"], table)


def throughput(args, folder: Path):
    session = simulate_fourflip(seed=args.seed, noise_ut=args.noise_ut)
    model = model_from_dict(json.loads(json.dumps(
        calibrate_fourflip(read_fourflip(write_fourflip(session, folder / "tp.csv", force=True)[0])).to_json())))
    rt = simulate_runtime(session.truth, 1_000_000, seed=7, accel_noise_g=args.accel_noise_g)
    wall, cpu = [], []
    for _ in range(3):
        t0, c0 = time.perf_counter(), time.process_time()
        solve_attitude(model, rt.outputs, accel=rt.accel)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    cal = folder / "cal.json"
    cal.write_text(json.dumps(model_to_dict(model)))
    rec, _ = write_runtime(rt, folder / "rec.csv", force=True)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "compass", "attitude", str(cal), str(rec), "--out", str(folder / "att.csv"),
                    "--force"], check=True, stdout=subprocess.DEVNULL)
    return min(wall), min(cpu), time.perf_counter() - t0


def temperature(seeds=range(4), temps=(10.0, 45.0), n=300):
    """Field error of a four-flip calibration with a temperature effect, read away from its reference.

    The calibration (diagnosis on) of a session whose channels change with ``temp_c`` (22-32 degC);
    then the true sensor read at ``temps`` in ``n`` random fields of the session's |B|: RMS error of
    the field vector with ``temp_c`` (compensated) and without, beside what the effect's own sigmas
    predict (offset and relative gain sigmas times the temperature difference).
    """
    print(f"\nTemperature compensation ({len(seeds)} four-flip sessions with a temperature effect, field read at "
          f"{', '.join(f'{t:g}' for t in temps)} degC, {n} random fields; uT RMS)")
    print(f"{'seed':<6}{'T degC':>8}{'T - ref':>9}{'compensated':>13}{'predicted':>11}{'ignored':>9}")
    table = []
    for seed in seeds:
        session = simulate_fourflip(seed=seed, effects=("temperature",))
        d = calibrate_fourflip(session.recording(), diagnose=True).to_json()
        model = model_from_dict(d)
        effect = next(e for e in d["effects"] if e["name"] == "temperature")
        b = np.random.default_rng(seed).normal(size=(n, 3))
        b *= session.truth["field_ut"] / np.linalg.norm(b, axis=1, keepdims=True)
        p = effect["parameters"]
        for temp in temps:
            v = session.outputs_at(b, temp)
            dt = temp - effect["reference"]["temp_c"]
            predicted = np.sqrt(sum((p[f"{c}.offset_fieldunit_per_degc"]["sigma"] * dt) ** 2
                                    + (p[f"{c}.gain_rel_per_degc"]["sigma"] * dt) ** 2 * session.truth["field_ut"] ** 2 / 3
                                    for c in model.channels))
            errors = [rms(np.linalg.norm(model.field(v, t)[0] - b, axis=1)) for t in (temp, None)]
            print(f"{seed:<6}{temp:>8.1f}{dt:>9.1f}{errors[0]:>13.3f}{predicted:>11.3f}{errors[1]:>9.3f}")
            table.append([seed, f"{temp:.1f}", f"{dt:.1f}", f"{errors[0]:.3f}", f"{predicted:.3f}", f"{errors[1]:.3f}"])
    return markdown_table(["seed", "T degC", "T - reference", "compensated", "predicted by the sigmas", "ignored"],
                          table)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=3, help="bench sessions (calibrations), default 3")
    p.add_argument("--seed", type=int, default=1, help="first seed, default 1")
    p.add_argument("--n", type=int, default=100_000, help="runtime samples per session, default 100000")
    p.add_argument("--peer-n", type=int, default=10_000, help="samples through the peer, default 10000")
    p.add_argument("--noise-ut", type=float, default=0.15, help="channel noise, uT (default 0.15, the bench's)")
    p.add_argument("--accel-noise-g", type=float, default=0.002, help="accelerometer noise, g (default 0.002)")
    p.add_argument("--no-throughput", action="store_true", help="skip the 10^6-sample timings")
    p.add_argument("--no-temperature", action="store_true", help="skip the temperature compensation section")
    p.add_argument("--no-disturbed", action="store_true", help="skip the disturbed-field tilt section")
    args = parse_args(p, argv)

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        errors, sigmas = accuracy(args, folder)
        predicted = [rms(s) for s in sigmas]
        print(f"Attitude error vs truth: {args.seeds} calibrations x {args.n} samples, pitch/roll within +-80 deg, "
              f"noise {args.noise_ut} uT, accelerometer {args.accel_noise_g} g")
        print(f"{'solver':<14}{'heading RMS':>13}{'pitch RMS':>11}{'roll RMS':>10}  (deg)")
        for name, err in errors.items():
            print(f"{name:<14}" + "".join(f"{rms(e):>{w}.4f}" for e, w in zip(err, (13, 11, 10))))
        print(f"{'predicted':<14}" + "".join(f"{v:>{w}.4f}" for v, w in zip(predicted, (13, 11, 10)))
              + "   (RMS of the propagated 1-sigma, ml)")
        ratio = [rms(e) / v for e, v in zip(errors["ml"], predicted)]
        print(f"{'ml/predicted':<14}" + "".join(f"{v:>{w}.3f}" for v, w in zip(ratio, (13, 11, 10))))
        accuracy_table = markdown_table(
            ["solver", "heading RMS", "pitch RMS", "roll RMS"],
            [[name] + [f"{rms(e):.4f}" for e in err] for name, err in errors.items()]
            + [["predicted (RMS of ml's propagated 1-sigma)"] + [f"{v:.4f}" for v in predicted],
               ["ml / predicted"] + [f"{v:.3f}" for v in ratio]])
        patent_factor = rms(errors["patent"][0]) / rms(errors["ml"][0])
        rows = [("heading RMS / predicted <= 1.1", f"{ratio[0]:.3f}", ratio[0] <= 1.1),
                ("patent / ml heading RMS >= 10", f"{patent_factor:.1f}", patent_factor >= 10)]
        if not args.no_throughput:
            wall, cpu, csv_s = throughput(args, folder)
            rows += [("samples/s in-process >= 1e6", f"{1e6 / wall:.3g} (wall), {1e6 / cpu:.3g} (CPU)", 1e6 / wall >= 1e6),
                     ("10^6-row CSV in to CSV out < 10 s", f"{csv_s:.2f} s", csv_s < 10)]
        tilt = None if args.no_disturbed else disturbed_tilt(args)
        temperatures = None if args.no_temperature else temperature()
        print()
        print(f"{'target':<36}{'measured':>32}  met")
        for label, value, ok in rows:
            print(f"{label:<36}{value:>32}  {'yes' if ok else 'NO'}")
    publish(args, "docs/runtime.md", "bench_attitude.accuracy", accuracy_table,
            caption=f"{args.seeds} calibrations x {args.n} samples (the peer {args.peer_n}), pitch and roll within "
                    f"+-80 deg, noise {args.noise_ut} uT, accelerometer {args.accel_noise_g} g; deg")
    if tilt is not None:
        publish(args, "docs/runtime.md", "bench_attitude.tilt", tilt,
                caption=f"ml calibration of seed {args.seed}, 20000 attitudes; pitch / roll RMS over the affected "
                        "rows, deg")
    if temperatures is not None:
        publish(args, "docs/runtime.md", "bench_attitude.temperature", temperatures,
                caption="four-flip sessions with a temperature effect, 300 random fields of the session's |B| "
                        "read at 10 and 45 degC; field error, uT RMS")
    return 0


if __name__ == "__main__":
    sys.exit(main())
