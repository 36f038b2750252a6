"""Seeded benchmark of the 3-D platform fit (seed 001), the K-matrix fit (seed 003) and the tumble diagnosis.

Numbers that were measured ad hoc, made rerunnable.  Every recording is simulated with a fixed
seed (``--seed .. --seed + n - 1``), so two runs print the same table apart from the timings.

1. **3-D platform (seed 001)**: ``--n`` grid sessions (``simulate_platform3d``, 12 x 3 x 4 poses,
   3 samples each) with the seed's two-axis inclinometer and again with a three-axis
   accelerometer, written to CSV and read back as a user would, fitted by
   ``calibrate_platform3d``.  Per parameter group (magnetometer scales, non-orthogonality,
   offsets; tilt-sensor scales, non-orthogonality, offsets; each sensor's rotation from the
   housing; mag-to-tilt rotation; base level; |B|; dip; field azimuth) it prints
   ``sqrt(mean((error / sigma)^2))`` over parameters and recordings (1 when the reported sigmas
   are honest) with its Monte Carlo standard error, and the RMS error itself.
   Then the tilt-compensated heading error on fresh random attitudes of the same sensors
   (``poses="random"``: the simulator draws the sensors before the poses), all through the
   runtime solver ``compass.attitude.solve_attitude`` the way ``compass attitude`` does:
   the platform calibration (``compass.calibration.from_dict`` + ``TiltSensor.up``), beside two
   baselines on the SAME samples: the free-motion tumble calibration (``calibrate_tumble``
   on the platform recording's ``mx, my, mz`` and ``ax, ay, az``, the platform angles ignored;
   its housing frame is the accelerometer's) and the raw sensor (identity directions, zero
   offsets, unit gains, the true dip).  The tumble needs three accelerometer axes, so the
   heading table uses the three-axis sessions; the two-axis platform calibration is shown on
   its own (upright) samples for reference.
2. **K matrix (seed 003)**: ``--n`` sessions of a two-sensor array under ``--fields``
   random reference fields (``simulate_reference``), fitted by ``calibrate_reference``
   (outputs regressed on the known fields).  RMS error/sigma and RMS error of K, the offsets
   V0, the scale factors a, b, c and the axis angles alpha1..gamma3, and the field error on 500
   held-out noise-free fields of 50 uT, beside two baselines in the same table: the seed's
   formula (1) taken literally (the known field regressed on the outputs, ``B = K V - B0``,
   written here: the toolkit has no such routine) and the raw sensor (``K = I``, ``V0 = 0``).
   Then the refusal of degenerate fields (``calibrate.reference.fit._design_check``, raising
   ``CannotCalibrate``; the reader's ``MIN_FIELDS`` check comes first for a file) counted
   over seeded coplanar sessions and sessions with 3 and 4 fields, with random fields as control.
3. **Tumble diagnosis**: 3000-sample simulated tumbles, ``--tumble-seeds`` per case: clean,
   offset drift (warm-up and linear), temperature (offset and gain), and a 2 uT hard-iron step
   halfway (an effect the diagnosis does not model: the honest verdict is ``unexplained``).
   ``nonlinear_response`` is in the diagnosis' vocabulary but ``simulate_tumble`` cannot inject
   it: the table says so instead of simulating it here.  Printed: which effects the loop named
   and how often it said ``unexplained``, the residual rms before and after over the estimated
   noise floor, and the hard-iron error (against the truth at the effects' reference time and
   temperature) of the plain ellipsoid and of the final result.

4. **Platform and K-matrix diagnosis**: ``--diag-seeds`` recordings per case of each fit, with
   ``t_s`` over a 1800 s session and a ``temp_c`` cycle of +-10 degC recorded in every case:
   clean; an offset drift (2 uT linear on the platform, 0.5 output units on the array); a warm-up
   (the same with tau 300 s); a temperature coefficient (0.1 uT/degC, 0.03 per degC).  The platform
   is the default grid (3 samples per pose), the array 24 fields applied 3 times each.  Printed:
   what the loop named, how often ``unexplained`` was true, the residual rms before and after over
   the injected noise and over the estimated floor, and the offset error at the effects'
   reference over its reported sigma (RMS over channels and seeds).

Wall time of every method is printed too (median per call; the machine may be shared, so read
them as rough).  One BLAS thread, one process.

Usage::

    python tools/bench_platform_reference.py [--quick] [--n 50] [--tumble-seeds 10] [--diag-seeds 10] [--seed 0]
        [--fields 12] [--only diagnosis]

``--quick``: 10 sessions per seed section, 3 tumbles and 3 diagnosis recordings per case (about 7 s; the full run about 26 s
on two CPUs).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy is imported: timings without oversubscription

import argparse  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from calibrate.platform3d import axis_geometry, calibrate_platform3d  # noqa: E402
from calibrate.contract import CannotCalibrate  # noqa: E402
from calibrate.reference import calibrate_reference  # noqa: E402
from compass.calibration import FORMAT  # noqa: E402
from calibrate.tumble import calibrate_tumble  # noqa: E402
from compass.attitude import solve_attitude  # noqa: E402
from compass.io.platform3d import TiltSensor, platform_rotation, read_platform3d  # noqa: E402
from compass.io.reference import ReferenceRecording, read_reference  # noqa: E402
from compass.io.table import RecordingError  # noqa: E402
from compass.model import SensorModel  # noqa: E402
from compass.sim.platform3d import simulate_platform3d, up_in_bench, write_platform3d  # noqa: E402
from compass.sim.reference import simulate_reference, write_reference  # noqa: E402
from compass.sim.tumble import simulate_tumble  # noqa: E402
from compass.calibration import model_from_dict

AXES = "xyz"
MAX_PITCH_DEG = 70.0
"""Heading samples with |pitch| above this are left out (heading is singular at +-90 deg)."""
UPRIGHT_TILT_DEG = 60.0
"""A two-axis tilt sensor needs the housing's upper hemisphere (as in the tests)."""
ACCEL_NOISE_G = 0.001
"""The simulator's default tilt noise, given to the attitude solver."""


# ---------------------------------------------------------------------------------------------- printing

def row(name, cells, width=14, first=44):
    print(f"{name:<{first}}" + "".join(f"{c:>{width}}" for c in cells))


def fmt(v, spec=".3f"):
    return "-" if v is None else ("fail" if not np.isfinite(v) else format(v, spec))


def rms(x) -> float:
    x = np.asarray(x, float).ravel()
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def rms_with_error(z) -> str:
    """``rms(z) +- its Monte Carlo standard error`` (delta method: rms / sqrt(2 k) for k values)."""
    z = np.asarray(z, float).ravel()
    r = rms(z)
    se = float(np.std(z**2) / np.sqrt(z.size) / (2 * r)) if z.size > 1 and r > 0 else float("nan")
    return f"{r:.2f}+-{se:.2f}"


def wrap_deg(x):
    return np.mod(np.asarray(x, float) + 180.0, 360.0) - 180.0


def median_ms(times) -> str:
    return f"{1e3 * float(np.median(times)):.1f}"


# ---------------------------------------------------------------------------------------------- seed 001

GROUPS = (
    # label, unit, derived-name builder (tilt columns -> names) or a special key
    ("mag scales", "out/uT", lambda tc: [f"mag_scale_m{a}" for a in AXES]),
    ("mag non-orthogonality", "deg", lambda tc: ["mag_nonorthogonality_mx_my_deg", "mag_nonorthogonality_mx_mz_deg",
                                                 "mag_nonorthogonality_my_mz_deg"]),
    ("mag offsets", "out", "mag_offset"),
    ("tilt scales", "out/g", lambda tc: [f"tilt_scale_{c}" for c in tc]),
    ("tilt non-orthogonality", "deg", lambda tc: (
        ["tilt_nonorthogonality_ax_ay_deg"] if len(tc) == 2 else
        ["tilt_nonorthogonality_ax_ay_deg", "tilt_nonorthogonality_ax_az_deg", "tilt_nonorthogonality_ay_az_deg"])),
    ("tilt offsets", "out", "tilt_offset"),
    ("housing alignment: mag rotation from H", "deg", lambda tc: [f"mag_rotvec_{a}_deg" for a in AXES]),
    ("housing alignment: tilt rotation from H", "deg", lambda tc: [f"tilt_rotvec_{a}_deg" for a in AXES]),
    ("mag-to-tilt rotation", "deg", lambda tc: [f"mag_to_tilt_rotvec_{a}_deg" for a in AXES]),
    ("base level error", "deg", lambda tc: ["base_tilt_x_deg", "base_tilt_y_deg"]),
    ("|B| (output units at unit gain)", "out", lambda tc: ["field_norm_recording_units"]),
    ("dip", "deg", lambda tc: ["dip_deg"]),
    ("field azimuth from the platform zero", "deg", lambda tc: ["field_azimuth_deg"]),
)


def platform_truth(sim) -> dict:
    """The simulator's truth under the names of ``Platform3DResult.derived``."""
    t = sim.truth
    m_true, a_true = np.array(t["mag_matrix"]), np.array(t["tilt_matrix"])
    gm, gt = axis_geometry(m_true), axis_geometry(a_true)
    tc = ("ax", "ay", "az")[: len(a_true)]
    n_pair = 3 if len(tc) == 3 else 1
    out = {}
    for i, a in enumerate(AXES):
        out[f"mag_scale_m{a}"] = gm[i]
        out[f"mag_rotvec_{a}_deg"] = gm[6 + i]
        out[f"tilt_rotvec_{a}_deg"] = gt[len(tc) + n_pair + i]
    for i, name in enumerate(("mx_my", "mx_mz", "my_mz")):
        out[f"mag_nonorthogonality_{name}_deg"] = gm[3 + i]
    for i, c in enumerate(tc):
        out[f"tilt_scale_{c}"] = gt[i]
    pairs = ("ax_ay", "ax_az", "ay_az")[:n_pair]
    for i, name in enumerate(pairs):
        out[f"tilt_nonorthogonality_{name}_deg"] = gt[len(tc) + i]
    q = Rotation.from_rotvec(gt[-3:], degrees=True) * Rotation.from_rotvec(gm[-3:], degrees=True).inv()
    for a, v in zip(AXES, q.as_rotvec(degrees=True)):
        out[f"mag_to_tilt_rotvec_{a}_deg"] = v
    out["base_tilt_x_deg"], out["base_tilt_y_deg"] = t["base_tilt_deg"]
    out["field_norm_recording_units"] = float(np.mean(np.linalg.norm(m_true, axis=1)) * t["field_ut"])
    out["dip_deg"] = t["dip_deg"]
    out["field_azimuth_deg"] = float(np.mod(t["azimuth_deg"], 360.0))
    return out


def platform_errors(res, sim) -> dict:
    """Group label -> (errors, errors / sigma) of one calibration."""
    truth = platform_truth(sim)
    n_tilt = len(res.tilt_columns)
    k = 14 + 3 * n_tilt
    sig = res.sigma
    out = {}
    for label, _, names in GROUPS:
        if names == "mag_offset":
            err, s = res.mag_offset - np.array(sim.truth["mag_offset"]), sig[9:12]
        elif names == "tilt_offset":
            err, s = res.tilt_offset - np.array(sim.truth["tilt_offset"]), sig[k:k + n_tilt]
        else:
            keys = names(res.tilt_columns)
            err = np.array([res.derived[n][0] - truth[n] for n in keys])
            if label.startswith("field azimuth"):
                err = wrap_deg(err)
            s = np.array([res.derived[n][1] for n in keys])
        out[label] = (np.asarray(err, float), np.asarray(err, float) / np.asarray(s, float))
    return out


def raw_model(dip_deg: float, field_ut: float, noise: float) -> SensorModel:
    """The uncalibrated sensor as a calibration file: axes along H, zero offsets, unit gains."""
    channels = {f"m{a}": {"direction": list(np.eye(3)[i]), "response": {"model": "linear", "offset": 0.0, "gain": 1.0}}
                for i, a in enumerate(AXES)}
    return model_from_dict({"format": FORMAT, "channels": channels, "dip_deg": dip_deg, "field_ut": field_ut,
                                  "noise_floor": [noise] * 3})


def heading_errors(model, mag, accel, truth_deg):
    att = solve_attitude(model, mag, accel=accel, accel_noise_g=ACCEL_NOISE_G)
    err = wrap_deg(att.heading_deg - truth_deg)
    return err, err / att.heading_sigma_deg


def run_platform(seeds, workdir: Path) -> dict:
    out = {"groups": {2: {}, 3: {}}, "heading": {}, "time": {}, "warnings": Counter(), "tumble_warnings": Counter(),
           "tumble_refused": [], "tumble_no_rotation": 0}
    heading = {k: ([], []) for k in ("platform3d", "tumble", "tumble_true_up", "raw", "platform3d_2axis")}
    times = {k: [] for k in ("platform3d (2-axis tilt)", "platform3d (3-axis accel)", "tumble baseline",
                             "solve_attitude (platform, per call)")}
    for seed in seeds:
        for tilt_axes in (2, 3):
            sim = simulate_platform3d(seed=seed, tilt_axes=tilt_axes)
            path, _ = write_platform3d(sim, workdir / f"p{tilt_axes}_{seed}.csv")
            rec = read_platform3d(path)
            t0 = time.perf_counter()
            res = calibrate_platform3d(rec)
            times["platform3d (2-axis tilt)" if tilt_axes == 2 else "platform3d (3-axis accel)"].append(
                time.perf_counter() - t0)
            for w in res.warnings:
                out["warnings"][w.split(":")[0]] += 1
            for label, (err, z) in platform_errors(res, sim).items():
                e, zz = out["groups"][tilt_axes].setdefault(label, ([], []))
                e.append(err)
                zz.append(z)
            data = res.to_json()
            model, tilt = model_from_dict(data), TiltSensor.from_json(data)
            check = simulate_platform3d(seed=seed, tilt_axes=tilt_axes, poses="random", repeats=1)
            if tilt_axes == 2:
                keep = check.pitch_deg**2 + check.roll_deg**2 < UPRIGHT_TILT_DEG**2
                e, z = heading_errors(model, check.mag[keep], tilt.up(check.tilt[keep]), check.heading_deg[keep])
                heading["platform3d_2axis"][0].append(e)
                heading["platform3d_2axis"][1].append(z)
                continue
            keep = np.abs(check.pitch_deg) < MAX_PITCH_DEG
            mag, raw_tilt, truth = check.mag[keep], check.tilt[keep], check.heading_deg[keep]
            t0 = time.perf_counter()
            e, z = heading_errors(model, mag, tilt.up(raw_tilt), truth)
            times["solve_attitude (platform, per call)"].append(time.perf_counter() - t0)
            heading["platform3d"][0].append(e)
            heading["platform3d"][1].append(z)
            # baseline 1: the free-motion calibration of the same recording, platform angles ignored
            t0 = time.perf_counter()
            tum = calibrate_tumble(sim.mag, sim.tilt)
            times["tumble baseline"].append(time.perf_counter() - t0)
            for w in tum.warnings:
                if w != tum.refused:
                    out["tumble_warnings"][w.split(":")[0][:70]] += 1
            if tum.refused:
                out["tumble_refused"].append((seed, tum.refused))
            else:
                tdata = tum.to_json()
                out["tumble_no_rotation"] += tdata["mag_to_accel"] is None
                tmodel = model_from_dict(tdata)
                e, z = heading_errors(tmodel, mag, raw_tilt, truth)
                heading["tumble"][0].append(e)
                heading["tumble"][1].append(z)
                # diagnostic: the same tumble model with the true up direction in H instead of the raw accelerometer
                up_h = platform_rotation(*check.angles_deg[keep].T).apply(up_in_bench(sim.truth["base_tilt_deg"]),
                                                                          inverse=True)
                e, z = heading_errors(tmodel, mag, up_h, truth)
                heading["tumble_true_up"][0].append(e)
                heading["tumble_true_up"][1].append(z)
                out.setdefault("tumble_noise", []).append(tum.noise / sim.truth["noise_mag"])
            # baseline 2: the raw sensor, with the true dip and |B| (generous)
            e, z = heading_errors(raw_model(sim.truth["dip_deg"], sim.truth["field_ut"], sim.truth["noise_mag"]),
                                  mag, raw_tilt, truth)
            heading["raw"][0].append(e)
            heading["raw"][1].append(z)
    out["heading"] = heading
    out["time"] = times
    return out


def print_platform(r: dict, n: int, seed: int) -> None:
    print(f"\n(1) 3-D platform calibration (seed 001): {n} simulated grid sessions per tilt sensor, seeds {seed}.."
          f"{seed + n - 1}")
    print("    (12 platform_z x 3 platform_y x 4 platform_x poses, 3 samples each; noise 0.1 uT, 0.001 g; "
          "|B| 50 uT given as metadata)")
    row("parameter group", ["2-axis tilt", "", "3-axis accel", "", "unit"], width=13)
    row("", ["err/sigma", "rms err", "err/sigma", "rms err", ""], width=13)
    for label, unit, _ in GROUPS:
        cells = []
        for axes in (2, 3):
            err, z = r["groups"][axes][label]
            cells += [rms_with_error(np.concatenate(z)), f"{rms(np.concatenate(err)):.3g}"]
        row(label, cells + [unit], width=13)
    print("  err/sigma: sqrt(mean((fitted - true) / reported sigma)^2) over the group's parameters and all sessions, "
          "+- its Monte Carlo error; 1 when the sigmas are honest")
    print("  housing alignment: rotation vector of each sensor's orthonormalised axes relative to the housing frame H; "
          "out = output units")
    if r["warnings"]:
        print("  fit warnings: " + "; ".join(f"{k} x{v}" for k, v in r["warnings"].most_common()))
    else:
        print("  fit warnings: none")

    h = r["heading"]
    print(f"\n(1b) Tilt-compensated heading error on fresh random attitudes of the same sensors (|pitch| < "
          f"{MAX_PITCH_DEG:g} deg), through compass.attitude.solve_attitude, deg")
    row("method (3-axis accel sessions)", ["rms", "p95 |err|", "max |err|", "err/sigma", "samples"], width=12)
    labels = {"platform3d": "platform3d (seed 001)",
              "tumble": "tumble baseline (angles ignored)",
              "tumble_true_up": "  diagnostic: tumble + true up in H",
              "raw": "raw sensor (true dip, |B|)"}
    for key, label in labels.items():
        if not h[key][0]:
            row(label, ["none"], width=12)
            continue
        e, z = np.concatenate(h[key][0]), np.concatenate(h[key][1])
        row(label, [f"{rms(e):.3f}", f"{np.percentile(np.abs(e), 95):.3f}", f"{np.max(np.abs(e)):.3f}",
                    f"{rms(z):.2f}", str(e.size)], width=12)
    e, z = np.concatenate(h["platform3d_2axis"][0]), np.concatenate(h["platform3d_2axis"][1])
    row(f"platform3d, 2-axis tilt (tilt < {UPRIGHT_TILT_DEG:g} deg)", [
        f"{rms(e):.3f}", f"{np.percentile(np.abs(e), 95):.3f}", f"{np.max(np.abs(e)):.3f}", f"{rms(z):.2f}",
        str(e.size)], width=12)
    notes = (
        "same samples in the first four rows; the last row is the 2-axis sessions' own upright samples.",
        "The tumble is calibrated on the platform recording's mx,my,mz,ax,ay,az (angles ignored); its housing frame is",
        "the accelerometer's, so the accelerometer's own misalignment to H stays in its heading, and it calibrates no",
        "accelerometer (the raw ax,ay,az go to the solver).  Diagnostic row: the same tumble field with the true up",
        "direction in H instead of the raw accelerometer: what is left is the tumble's frame against the housing's.",
        "err/sigma: error over the solver's heading_sigma_deg.  The tumble model has no direction covariance, and its",
        "noise comes from second differences of consecutive samples, which on a platform recording (a jump every 3",
        f"samples) is {np.median(r.get('tumble_noise', [np.nan])):.0f} x the true noise (median): its err/sigma "
        "means nothing here.",
    )
    for line in notes:
        print("  " + line)
    print(f"  tumble baseline: refused {len(r['tumble_refused'])}x (its heading rows cover the other sessions), no "
          f"mag-to-accel rotation {r['tumble_no_rotation']}x; other warnings: "
          + ("; ".join(f"'{k}' x{v}" for k, v in r["tumble_warnings"].most_common()) or "none"))
    for seed, why in r["tumble_refused"]:
        print(f"    refused seed {seed}: {why}")


# ---------------------------------------------------------------------------------------------- seed 003

def literal_seed_fit(reference: np.ndarray, outputs: np.ndarray):
    """Seed 003's formula (1) as written, ``B = K V - B0``: the known field regressed on the outputs.

    Returns ``(K, V0)`` with ``V0 = K^-1 B0``.
    """
    design = np.hstack([outputs, np.ones((len(outputs), 1))])
    coef, *_ = np.linalg.lstsq(design, reference, rcond=None)  # (4, 3): rows K^T, then -B0
    k = coef[:3].T
    return k, np.linalg.solve(k, -coef[3])


def axis_terms(g: np.ndarray):
    """Scale factors and axis angles (deg, row c: angles of axis c to x, y, z) of ``G = K^-1``."""
    scale = np.linalg.norm(g, axis=1)
    return scale, np.degrees(np.arccos(np.clip(g / scale[:, None], -1.0, 1.0)))


def run_reference(seeds, n_fields: int, workdir: Path) -> dict:
    metrics = ("K", "V0", "scale", "angles", "field")
    acc = {m: {k: [] for k in ("ours", "literal", "raw")} for m in metrics}
    z = {m: [] for m in ("K", "V0", "scale", "angles")}
    times = {"calibrate_reference (2 sensors)": [], "literal formula (1) (2 sensors)": []}
    warnings = Counter()
    held = np.random.default_rng(12345)
    for seed in seeds:
        sim = simulate_reference(seed=seed, n_fields=n_fields)
        path, _ = write_reference(sim, workdir / f"ref_{seed}.csv")
        rec = read_reference(path)
        t0 = time.perf_counter()
        res = calibrate_reference(rec)
        times["calibrate_reference (2 sensors)"].append(time.perf_counter() - t0)
        for w in res.warnings:
            warnings[w.split(":")[0][:60]] += 1
        t0 = time.perf_counter()
        literal = {s: literal_seed_fit(rec.reference[s], rec.outputs[s]) for s in rec.sensors}
        times["literal formula (1) (2 sensors)"].append(time.perf_counter() - t0)
        directions = held.normal(size=(500, 3))
        b_test = 50.0 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
        for s in res.sensors:
            t = sim.truth["sensors"][s.name]
            g_true, v0_true = np.array(t["G"]), np.array(t["offset"])
            k_true = np.linalg.inv(g_true)
            scale_true, angles_true = axis_terms(g_true)
            v_test = b_test @ g_true.T + v0_true  # noise-free: the field error is the calibration's alone
            fits = {"ours": (s.k_matrix, s.offset), "literal": literal[s.name], "raw": (np.eye(3), np.zeros(3))}
            for key, (k, v0) in fits.items():
                scale, angles = axis_terms(np.linalg.inv(k))
                acc["K"][key].append((k - k_true).ravel())
                acc["V0"][key].append(v0 - v0_true)
                acc["scale"][key].append(scale - scale_true)
                acc["angles"][key].append((angles - angles_true).ravel())
                acc["field"][key].append(((v_test - v0) @ k.T - b_test).ravel())
            if s.k_sigma is not None:
                z["K"].append(((s.k_matrix - k_true) / s.k_sigma).ravel())
                z["V0"].append((s.offset - v0_true) / s.offset_sigma)
                z["scale"].append((s.scale - scale_true) / s.scale_sigma)
                z["angles"].append(((s.angles_deg - angles_true) / s.angles_sigma_deg).ravel())
    return {"acc": acc, "z": z, "time": times, "warnings": warnings}


def run_refusals(seeds, workdir: Path) -> list:
    """Per degenerate case: (label, counts of outcomes) over the seeds."""
    cases = (
        ("random fields, 12 (control)", dict(n_fields=12)),
        ("coplanar fields, 12", dict(n_fields=12, fields="coplanar")),
        ("coplanar fields, 30", dict(n_fields=30, fields="coplanar")),
        ("3 random fields (file)", dict(n_fields=3)),
        ("3 random fields (fit alone)", dict(n_fields=3)),
        ("4 random fields", dict(n_fields=4)),
    )
    out = []
    for label, kwargs in cases:
        counts = Counter()
        for seed in seeds:
            sim = simulate_reference(seed=seed, **kwargs)
            try:
                if label.endswith("(fit alone)"):  # bypass the reader: does the fit refuse by itself?
                    names = tuple(sim.outputs)
                    rec = ReferenceRecording(f"<seed {seed}>", names, {s: tuple(f"{s}_{a}" for a in AXES) for s in names},
                                             dict(sim.outputs), {s: sim.reference for s in names},
                                             np.arange(2, 2 + len(sim.reference)), {})
                else:
                    path, _ = write_reference(sim, workdir / f"deg_{len(out)}_{seed}.csv")
                    rec = read_reference(path)
                res = calibrate_reference(rec)
            except CannotCalibrate:
                counts["refused by the fit (CannotCalibrate)"] += 1
            except RecordingError:
                counts["refused by the reader (RecordingError)"] += 1
            else:
                counts["accepted with a warning" if res.warnings else "accepted"] += 1
        out.append((label, counts))
    return out


def print_reference(r: dict, refusals: list, n: int, seed: int, n_fields: int, n_ref_seeds: int) -> None:
    print(f"\n(2) K-matrix calibration from known reference fields (seed 003): {n} simulated sessions, seeds {seed}.."
          f"{seed + n - 1},")
    print(f"    2 sensors each, {n_fields} random fields of 50 uT +- 30 %, output noise 0.05, gains ~1 per uT, "
          "offsets up to 5")
    row("metric (RMS over elements, sensors, sessions)", ["ours", "seed (1)", "raw", "unit"], width=13, first=46)
    row("", ["V on B", "B on V", "K=I, V0=0", ""], width=13, first=46)
    acc, z = r["acc"], r["z"]
    labels = {"K": ("K error", "uT/out"), "V0": ("offset V0 error", "out"), "scale": ("scale factor a,b,c error", "out/uT"),
              "angles": ("axis angles alpha1..gamma3 error", "deg"),
              "field": ("field error, 500 held-out fields", "uT")}
    for key, (label, unit) in labels.items():
        row(label, [f"{rms(np.concatenate(acc[key][m])):.4g}" for m in ("ours", "literal", "raw")] + [unit],
            width=13, first=46)
    dof = n_fields - 4
    expected = np.sqrt(dof / (dof - 2)) if dof > 2 else float("nan")
    for key, (label, _) in labels.items():
        if key in z:
            cells = [rms_with_error(np.concatenate(z[key])) if z[key] else "-", "-", "-", ""]
            row(f"{label.replace(' error', '')} err/sigma", cells, width=13, first=46)
    print(f"  err/sigma: the sigma comes from the residual on n - 4 = {dof} dof, so for honest sigmas the ratio is "
          f"Student-t:")
    print(f"  expected sqrt(dof / (dof - 2)) = {fmt(expected)} (not 1). The literal form has no sigma in the toolkit; "
          "the seed's ellipsoid")
    print("  estimate of a, b, c does not apply to fields of varying magnitude and is not implemented: not shown.")
    if r["warnings"]:
        print("  fit warnings: " + "; ".join(f"{k} x{v}" for k, v in r["warnings"].most_common()))
    print(f"\n(2b) Degenerate reference fields, {n_ref_seeds} seeds each (2 sensors): what happens")
    outcomes = ["refused by the fit (CannotCalibrate)", "refused by the reader (RecordingError)",
                "accepted with a warning", "accepted"]
    row("case", ["fit refused", "reader refused", "warned", "accepted"], width=15, first=34)
    for label, counts in refusals:
        row(label, [str(counts.get(o, 0)) for o in outcomes], width=15, first=34)
    print("  the fit's check: calibrate.reference.fit._design_check (fewer than 4 fields, or the column-scaled design [B, 1] "
          "with condition > 1e8);")
    print("  the reader's: compass.io.reference MIN_FIELDS = 4.  The simulator has no 'nearly coplanar' or 'collinear' "
          "option: not counted.")


# ---------------------------------------------------------------------------------------------- tumble

TUMBLE_CASES = (
    ("clean", {}, None),
    ("drift: warm-up 3 uT, tau 12 s", dict(drift_ut=3.0, drift_tau_s=12.0), "offset_drift"),
    ("drift: linear 3 uT", dict(drift_ut=3.0), "offset_drift"),
    ("temperature: +-10 degC, 0.2 uT/degC", dict(temp_swing_c=10.0, temp_offset_ut_per_c=0.2, temp_gain_per_c=0.002),
     "temperature"),
    ("hard-iron step 2 uT at 50 % (unmodelled)", dict(step_ut=2.0), "unexplained"),
)
"""Label (the temperature case also has per-axis gains up to 0.002/degC), simulator options, right verdict."""
EFFECT_COLUMNS = ("offset_drift", "temperature", "nonlinear_response")


def tumble_reference_hard_iron(sim) -> np.ndarray:
    """True hard iron at the effects' reference: the first sample, the mean of temp_c (before any step)."""
    h = np.array(sim.truth["hard_iron"])
    temp = sim.truth["temperature"]
    if temp is not None:
        h = h + np.array(temp["hard_iron_ut_per_degc"]) * (np.mean(sim.temp_c) - temp["temp_ref_c"])
    return h


def run_tumble(seeds) -> dict:
    out = {}
    for label, kwargs, _ in TUMBLE_CASES:
        recs = []
        for seed in seeds:
            sim = simulate_tumble(seed=seed, n=3000, **kwargs)
            t0 = time.perf_counter()
            res = calibrate_tumble(sim.mag, sim.accel, t_s=sim.t_s, temp_c=sim.temp_c)
            elapsed = time.perf_counter() - t0
            block = res.diagnosis.block
            base = next(c for c in res.candidates if c.ellipsoid == res.ellipsoid)
            h_true = tumble_reference_hard_iron(sim)
            recs.append({
                "seed": seed, "named": tuple(block["effects"]), "unexplained": bool(block["unexplained"]),
                "not_claimed": tuple(t.split(" ")[0] for t in block["not_claimed"]),
                "floor": block["noise_floor"], "before": block["residual_rms_before"],
                "after": block["residual_rms_after"],
                "h_before": base.hard_iron - h_true, "h_after": res.hard_iron - h_true,
                "time": elapsed,
            })
        out[label] = recs
    return out


def print_tumble(r: dict, n_seeds: int, seed: int) -> None:
    print(f"\n(3) Tumble residual diagnosis: 3000-sample simulated tumbles, {n_seeds} seeds per case ({seed}.."
          f"{seed + n_seeds - 1}), calibrate_tumble(mag, accel, t_s, temp_c)")
    print("    counts of recordings: effects the loop named (the final model), 'unexplained: true', "
          "and effects tried but not claimed")
    row("true case", ["none", "drift", "temp", "nonlin", "other", "unexpl.", "tried,", "time"], width=10, first=42)
    row("", ["", "", "", "", "sets", "", "unclaimed", "med s"], width=10, first=42)
    for label, _, _ in TUMBLE_CASES:
        recs = r[label]
        counts = Counter(rec["named"] for rec in recs)
        singles = [counts.get((), 0)] + [counts.get((e,), 0) for e in EFFECT_COLUMNS]
        other = sum(v for k, v in counts.items() if len(k) > 1)
        unexpl = sum(rec["unexplained"] for rec in recs)
        tried = sum(1 for rec in recs if rec["not_claimed"])
        row(label, [str(v) for v in singles] + [str(other), str(unexpl), str(tried),
                                                f"{np.median([rec['time'] for rec in recs]):.2f}"], width=10, first=42)
    row("nonlinear_response", ["no simulator option: simulate_tumble cannot inject a nonlinear response "
                               "(not simulated here)"], width=0, first=42)
    for label, _, _ in TUMBLE_CASES:
        sets = Counter(rec["named"] for rec in r[label] if len(rec["named"]) > 1)
        tried = Counter(name for rec in r[label] for name in rec["not_claimed"])
        if sets:
            print(f"  other sets for {label}: " + ", ".join(f"{'+'.join(k)} x{v}" for k, v in sets.items()))
        if tried:
            print(f"  tried and not claimed on {label}: " + ", ".join(f"{k} x{v}" for k, v in tried.most_common()))

    print("\n(3b) Before and after the diagnosis (median over seeds of residual rms / noise floor; RMS over axes and "
          "seeds of hard-iron error, uT)")
    row("true case", ["rms/floor", "rms/floor", "hard iron", "hard iron", "verdict"], width=11, first=42)
    row("", ["before", "after", "before", "after", "right"], width=11, first=42)
    for label, _, expect in TUMBLE_CASES:
        recs = r[label]
        if expect is None:
            right = sum(1 for rec in recs if not rec["named"] and not rec["unexplained"])
        elif expect == "unexplained":
            right = sum(1 for rec in recs if not rec["named"] and rec["unexplained"])
        else:
            right = sum(1 for rec in recs if rec["named"] == (expect,) and not rec["unexplained"])
        row(label, [f"{np.median([rec['before'] / rec['floor'] for rec in recs]):.3f}",
                    f"{np.median([rec['after'] / rec['floor'] for rec in recs]):.3f}",
                    f"{rms([rec['h_before'] for rec in recs]):.3f}", f"{rms([rec['h_after'] for rec in recs]):.3f}",
                    f"{right}/{len(recs)}"], width=11, first=42)
    print("  hard iron 'before': the plain ellipsoid the loop starts from; 'after': the final result (effects claimed, "
          "then the joint")
    print("  refinement with the accelerometer). Truth at the effects' reference: the first sample, the mean of temp_c; "
          "for the step,")
    print("  the hard iron before the step (the calibration cannot be right for both halves). Verdict right: clean -> "
          "nothing named and")
    print("  explained; an effect -> exactly it named and explained; the step -> nothing named and unexplained.")


# ---------------------------------------------------------------------------------------------- diagnosis

DIAG_CASES = (
    # label, platform options, array options, expected effect (None: nothing)
    ("clean", {}, {}, None),
    ("offset drift (linear)", {"drift_ut": 2.0}, {"drift": 0.5}, "offset_drift"),
    ("offset drift (warm-up, tau 300 s)", {"drift_ut": 2.0, "drift_tau_s": 300.0},
     {"drift": 0.5, "drift_tau_s": 300.0}, "offset_drift"),
    ("temperature (offset)", {"temp_offset_ut_per_c": 0.1}, {"temp_offset_per_c": 0.03}, "temperature"),
)
DIAG_SESSION = {"session_s": 1800.0, "temp_swing_c": 10.0}
DIAG_ARRAY = {"n_fields": 24, "repeats": 3}
DIAG_EFFECTS = ("offset_drift", "temperature", "nonlinear_response")


def offset_error_over_sigma(res, sim, fit_kind: str) -> np.ndarray:
    """Offset error at the effects' reference (first sample, mean temp_c) over its reported sigma."""
    temp_ref = None if sim.temp_c is None else float(np.mean(sim.temp_c))
    if fit_kind == "platform":
        truth = np.array(sim.truth["mag_offset"])
        temp = sim.truth["temperature"]
        if temp is not None:
            truth = truth + np.array(temp["offset_ut_per_degc"]) * (temp_ref - temp["temp_ref_c"])
        return (res.mag_offset - truth) / res.mag_response_sigma[:, 0]
    out = []
    for s in res.sensors:
        t = sim.truth["sensors"][s.name]
        truth = np.array(t["offset"])
        if t["temp_offset_per_degc"] is not None:
            truth = truth + np.array(t["temp_offset_per_degc"]) * (temp_ref - sim.truth["temp_ref_c"])
        out.append((s.offset - truth) / s.offset_sigma)
    return np.concatenate(out)


def run_diagnosis(seeds, workdir: Path) -> dict:
    out = {}
    for fit_kind in ("platform", "array"):
        for label, plat_kw, array_kw, _ in DIAG_CASES:
            recs = []
            for seed in seeds:
                if fit_kind == "platform":
                    sim = simulate_platform3d(seed=seed, **DIAG_SESSION, **plat_kw)
                    path, _ = write_platform3d(sim, workdir / f"diag_p_{seed}.csv", force=True)
                    rec, noise = read_platform3d(path), sim.truth["noise_mag"]
                    t0 = time.perf_counter()
                    res = calibrate_platform3d(rec)
                else:
                    sim = simulate_reference(seed=seed, **DIAG_ARRAY, **DIAG_SESSION, **array_kw)
                    path, _ = write_reference(sim, workdir / f"diag_r_{seed}.csv", force=True)
                    rec, noise = read_reference(path), sim.truth["noise"]
                    t0 = time.perf_counter()
                    res = calibrate_reference(rec)
                elapsed = time.perf_counter() - t0
                block = res.diagnosis.block
                recs.append({"named": tuple(block["effects"]), "unexplained": block["unexplained"],
                             "forms": tuple(st["form"] for st in block["steps"][1:]),
                             "noise": noise, "floor": block["noise_floor"], "before": block["residual_rms_before"],
                             "after": block["residual_rms_after"], "z": offset_error_over_sigma(res, sim, fit_kind),
                             "time": elapsed})
            out[(fit_kind, label)] = recs
    return out


def print_diagnosis(r: dict, n_seeds: int, seed: int) -> None:
    print(f"\n(4) Platform (seed 001) and K-matrix (seed 003) residual diagnosis: {n_seeds} seeds per case ({seed}.."
          f"{seed + n_seeds - 1}); every recording has t_s (1800 s) and a +-10 degC temp_c cycle")
    print("    platform: simulate_platform3d grid, 3 samples per pose, noise 0.1 uT, calibrate_platform3d; array: "
          "simulate_reference, 2 sensors, 24 fields x 3, noise 0.05, calibrate_reference")
    row("fit / true case", ["none", "drift", "temp", "nonlin", "other", "unexpl.", "rms/noise", "rms/noise",
                            "rms/floor", "offset", "time"], width=10, first=44)
    row("", ["", "", "", "", "", "", "before", "after", "after", "err/sig", "med ms"], width=10, first=44)
    for (fit_kind, label), recs in r.items():
        counts = Counter(rec["named"] for rec in recs)
        singles = [counts.get((), 0)] + [counts.get((e,), 0) for e in DIAG_EFFECTS]
        other = sum(v for k, v in counts.items() if len(k) > 1)
        unexpl = sum(1 for rec in recs if rec["unexplained"])
        row(f"{fit_kind}: {label}", [str(v) for v in singles] + [
            str(other), str(unexpl),
            f"{np.median([rec['before'] / rec['noise'] for rec in recs]):.3f}",
            f"{np.median([rec['after'] / rec['noise'] for rec in recs]):.3f}",
            f"{np.median([rec['after'] / rec['floor'] for rec in recs]):.3f}",
            f"{rms([rec['z'] for rec in recs]):.2f}", median_ms([rec["time"] for rec in recs])], width=10, first=44)
    forms = Counter((fit_kind, label, f) for (fit_kind, label), recs in r.items() for rec in recs for f in rec["forms"]
                    if "drift" in label)
    if forms:
        print("  drift forms chosen: " + ", ".join(f"{k[0]} {k[1].split(' (')[1].rstrip(')').split(',')[0]} -> {k[2]} x{v}"
                                                   for k, v in sorted(forms.items())))
    print("  rms: median over seeds of the diagnosed channels' residual rms over the injected noise (before: base fit; "
          "after: final) and over")
    print("  the floor the loop estimated (repeat scatter); offset err/sig: RMS over channels and seeds of the final "
          "offsets' error at the")
    print("  effects' reference (first sample, mean temp_c) over their reported sigma (1 when honest). nonlinear_response "
          "is examined on the")
    print("  platform only; neither simulator injects it (tests/calibrate/platform3d/test_diagnose.py bends a recording by hand).")


# ---------------------------------------------------------------------------------------------- main

def print_times(*groups) -> None:
    print("\n(5) Wall time per call, ms (one process, one BLAS thread; fits include their covariance propagation,")
    print("    calibrate_tumble its diagnosis and joint refinement)")
    row("method", ["median", "max", "calls"], width=12, first=58)
    for times in groups:
        for name, t in times.items():
            if t:
                row(name, [median_ms(t), f"{1e3 * max(t):.1f}", str(len(t))], width=12, first=58)


def code_version() -> str:
    """The commit the benchmark ran on, and whether the code under test differs from it."""
    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--", "calibrate", "compass"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return head + (" with uncommitted changes in calibrate/ or compass/" if dirty else "")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="10 sessions per seed section, 3 tumbles per case")
    parser.add_argument("--n", type=int, default=None, help="sessions per seed section (default 50; 10 with --quick)")
    parser.add_argument("--tumble-seeds", type=int, default=None, help="tumbles per case (default 10; 3 with --quick)")
    parser.add_argument("--seed", type=int, default=0, help="first seed; session i uses seed + i (default 0)")
    parser.add_argument("--fields", type=int, default=12, help="reference fields per K-matrix session (default 12)")
    parser.add_argument("--diag-seeds", type=int, default=None,
                        help="platform/K-matrix diagnosis recordings per case (default 10; 3 with --quick)")
    parser.add_argument("--only", choices=("diagnosis",), default=None,
                        help="run only section (4), the platform/K-matrix diagnosis")
    args = parser.parse_args(argv)
    n_diag = args.diag_seeds if args.diag_seeds is not None else (3 if args.quick else 10)
    if n_diag < 1:
        parser.error(f"--diag-seeds must be at least 1, got {n_diag}")
    if args.only == "diagnosis":
        print(f"bench_platform_reference (diagnosis only): seed {args.seed}, {n_diag} recordings per case; code "
              f"{code_version()}")
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            print_diagnosis(run_diagnosis(range(args.seed, args.seed + n_diag), Path(tmp)), n_diag, args.seed)
        print(f"\nsection: diagnosis {time.perf_counter() - t0:.1f} s")
        return 0
    n = args.n if args.n is not None else (10 if args.quick else 50)
    n_tumble = args.tumble_seeds if args.tumble_seeds is not None else (3 if args.quick else 10)
    if n < 2 or n_tumble < 1:
        parser.error(f"--n must be at least 2 and --tumble-seeds at least 1, got {n} and {n_tumble}")
    if args.fields < 7:
        parser.error(f"--fields must be at least 7 (the sigma needs n - 4 > 2 dof), got {args.fields}")
    n_ref_seeds = min(n, 10)
    t_start = time.perf_counter()
    load = os.getloadavg()[0]
    print(f"bench_platform_reference: seed {args.seed}, {n} sessions per seed section, {n_tumble} tumbles per case"
          f"{' (quick)' if args.quick else ''}; code {code_version()}; load average at start {load:.2f} on "
          f"{os.cpu_count()} CPUs")
    sections = []
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        t0 = time.perf_counter()
        plat = run_platform(range(args.seed, args.seed + n), workdir)
        sections.append(("platform", time.perf_counter() - t0))
        print_platform(plat, n, args.seed)
        t0 = time.perf_counter()
        ref = run_reference(range(args.seed, args.seed + n), args.fields, workdir)
        refusals = run_refusals(range(args.seed, args.seed + n_ref_seeds), workdir)
        sections.append(("reference", time.perf_counter() - t0))
        print_reference(ref, refusals, n, args.seed, args.fields, n_ref_seeds)
        t0 = time.perf_counter()
        diag = run_diagnosis(range(args.seed, args.seed + n_diag), workdir)
        sections.append(("diagnosis", time.perf_counter() - t0))
    t0 = time.perf_counter()
    tum = run_tumble(range(args.seed, args.seed + n_tumble))
    sections.append(("tumble", time.perf_counter() - t0))
    print_tumble(tum, n_tumble, args.seed)
    print_diagnosis(diag, n_diag, args.seed)
    print_times(plat["time"], ref["time"],
                {f"calibrate_tumble, {label.split(' (')[0]}": [rec["time"] for rec in recs] for label, recs in tum.items()})
    print("\nsections: " + ", ".join(f"{k} {v:.1f} s" for k, v in sections)
          + f"; total {time.perf_counter() - t_start:.1f} s; load average at end {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
