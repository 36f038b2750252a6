"""The gyro-aided tumble fit beside the present one, on simulated partial motions and on BROAD.

Run: ``python tools/bench_gyro_tumble.py [--seeds 4] [--quick] [--no-broad] [--no-sim] [--gaps]`` (seeded;
about 25 min with ``--seeds 2`` on the shared machine, BROAD's fast rotation 06 the longest; ``--quick``
one seed and no BROAD); ``python tools/bench_gyro_tumble.py --timing [--baseline main]`` for the timing
part alone (below).

Simulated: :func:`compass.sim.partial_tumble.simulate_partial_tumble` - hand-held motions of
:mod:`compass.sim.motion` (``fast_rotation``, ``slow_rotation``: not the motions the method was
written on) through 20 uT of hard iron, 8 % soft iron and a 2 deg rotation to the housing, cut where
the field's directions first cover 20 %, 30 %, 50 % of the sphere, or the whole 60 s ("full"); the
gyro with a random 0.5 deg/s bias, a scale error per axis drawn within +-0.5 % (cases marked ``gyro 3.0 %``:
+-3 %, the MPU-9250's tolerance) and noise; cases
marked ``late`` have the magnetometer one row (20 ms) late against the accelerometer and gyro.
Columns: ``present`` (:func:`calibrate.tumble.calibrate_tumble`), ``gyro tau=0`` (the gyro-aided fit
tried on every recording, its magnetometer latency held at zero and its gyro matrix at the identity: the model
before the latency), ``gyro G=I`` (the latency fitted, the gyro matrix held at the identity: the model before the
gyro's scale and axes), ``gyro`` (both fitted; the latency's mean and the rms of (fitted - true) / sigma in the
notes, and the gyro matrix's largest error against the truth ``diag(1 / (1 + s))`` and its rms error / sigma); where
the gyro-aided fit is refused (not converged, or the model does not describe the recording) these two
cells are the present fit's, as :func:`calibrate.tumble.gyro.with_gyro` returns it, ``default`` (what
``compass calibrate`` does: the gyro-aided fit only where the present one falls back, including a
rotation withheld for fast motion, and the gyro-aided one is determined).  Errors against the truth:
hard iron (% of |B|), soft iron shape (Frobenius of the det-1 matrices), rotation to the housing (deg), and the heading
error at runtime: the noise-free field of the whole (uncut) motion calibrated, levelled with the
true attitude, its heading against north (deg rms): what the calibration alone costs later, over
every orientation.  ``err/sigma``: rms of the gyro fit's rotation error over its reported sigma.

BROAD (``../shared/data/broad``, undisturbed trials 01-15): each trial's motion phase (every 4th row
for the magnetometer, the gyro integrated over every row) calibrates; every *other* undisturbed trial
scores it (leave one out): its calibrated field levelled with the optical reference, the heading's
spread about its median (deg rms; the offset between magnetic and optical north removed), beside
the raw (the maker's calibration) and the present fit; a refused calibration (nothing written)
scores as the raw.

Gaps (``--gaps``): the same simulated motions with bursts of lines lost (``lost`` s after every ``kept`` s that
arrived; the module turned in each gap), the gyro-aided fit (:func:`calibrate.tumble.gyro.with_gyro`) with its
windows closed at every step over :data:`calibrate.tumble.gyro.GAP_S` (``gaps closed``) beside the same code with the
limit set to infinity here (``across gaps``: the turns integrated across each gap, rate x gap, as before the limit):
samples rejected as outliers, the magnetometer's residual rms (uT; 0.3 injected), the errors against the truth as
above and the largest hard-iron error over its sigma; a fit not used is said.

Timing (``--timing``): the gyro-aided fit (:func:`calibrate.tumble.gyro.fit_with_gyro`, from the
present fit's values as :func:`~calibrate.tumble.gyro.with_gyro` starts it) on long fast recordings:
BROAD 06's motion phase whole (every row; its magnetometer interpolated between its own samples), every
2nd row (the magnetometer's own rate) and every 4th, a seeded simulated fast rotation of 300 s at 100 Hz
and, where the gyro-aided fit is used, two partial motions cut at 20 % of the sphere (seed 0, as the
table above; :func:`compass.sim.partial_tumble.simulate_partial_tumble`).  The inputs and the
start are made once by this tree; the fit runs in a child process of this tree and of the baseline
revision (``tools/_baseline.py``), each reporting the fit's CPU time (all threads; a loaded machine
inflates it less than the wall time, which is printed too) and its parameters.  The children run with one
BLAS thread (``--blas-threads``): on the shared 2-CPU machine OpenBLAS's threads spin against the other
jobs and cost more CPU than the arithmetic (a 30000 x 17 ``J^T J`` measured 0.95 s of CPU with its
default threads, 0.9 ms with one), which would time the machine's load, not the fit.  A refused fit
(:class:`~calibrate.tumble.gyro.GyroMismatch`) is timed too: the user waits for it all the same.  ``max |diff|/sigma``
is the largest difference between the two trees' parameters (hard iron, soft iron, ``|B|``, the
rotation to the housing, dip, gyro bias, latency) in units of this tree's sigma; on the simulated case
each tree's errors against the truth are printed beside each other.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _baseline import export_tree, tree_env  # noqa: E402
from calibrate.tumble import calibrate_tumble  # noqa: E402
from calibrate.tumble.gyro import falls_back, with_gyro  # noqa: E402
from compass.io.tumble import gyro_turns  # noqa: E402
from compass.sim.partial_tumble import simulate_partial_tumble  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "broad"
CASES = (("fast_rotation", 0.2, 0, 0.005), ("slow_rotation", 0.2, 0, 0.005), ("fast_rotation", 0.3, 0, 0.005),
         ("slow_rotation", 0.3, 0, 0.005), ("fast_rotation", 0.5, 0, 0.005), ("fast_rotation", None, 0, 0.005),
         ("fast_rotation", None, 1, 0.005), ("fast_rotation", 0.3, 1, 0.005),
         ("fast_rotation", 0.3, 0, 0.03), ("slow_rotation", 0.3, 0, 0.03), ("fast_rotation", None, 0, 0.03),
         ("slow_rotation", None, 0, 0.03))
"""(motion, coverage or None for the whole 60 s, magnetometer latency in samples: 1 is 20 ms at 50 Hz, the gyro's
scale error: each axis's drawn uniformly within +-this)."""
METHODS = ("present", "gyro tau=0", "gyro G=I", "gyro", "default")


def _heading_rms(mag_h: np.ndarray, attitude: Rotation, north_deg: float = 0.0, about_median: bool = False) -> float:
    """Rms heading error of a housing-frame field levelled with the true attitude, deg."""
    m_w = attitude.apply(mag_h)
    err = np.degrees(np.arctan2(m_w[:, 1], m_w[:, 0])) - north_deg
    if about_median:
        err = err - np.degrees(np.angle(np.median(np.cos(np.radians(err)))
                                        + 1j * np.median(np.sin(np.radians(err)))))
    err = np.mod(err + 180.0, 360.0) - 180.0
    return float(np.sqrt(np.mean(err**2)))


def _errors(h, s, rot, truth, runtime_raw, runtime_att):
    """(hard iron % |B|, soft-iron shape error, rotation error deg, runtime heading rms deg)."""
    s_true = np.array(truth["soft_iron"])
    s_true = s_true / np.cbrt(np.linalg.det(s_true))
    c_true = Rotation.from_matrix(truth["mag_to_accel"])
    rot = Rotation.identity() if rot is None else rot
    mag_h = rot.apply((runtime_raw - h) @ s.T)
    return (100 * np.linalg.norm(h - truth["hard_iron"]) / truth["field_ut"], float(np.linalg.norm(s - s_true)),
            float(np.degrees((c_true.inv() * rot).magnitude())), _heading_rms(mag_h, runtime_att))


def _runtime(kind, seed):
    """The whole motion's noise-free raw field through the simulated iron, and its attitudes."""
    whole = simulate_partial_tumble(kind, seed=seed, coverage=None, noise_ut=0.0)
    return whole.mag, whole.attitude


def _late(sim, rows: int):
    """The recording with the magnetometer ``rows`` samples late: row k reads the field of row k - rows."""
    if rows == 0:
        return sim.t_s, sim.mag, sim.accel, sim.gyro
    return sim.t_s[rows:], sim.mag[:-rows], sim.accel[rows:], sim.gyro[rows:]


def _gyro_matrix_error(block: dict, scale) -> tuple[float, float]:
    """(largest |G - G_true| entry in %, rms of (G - G_true) / sigma) of a fit's ``gyro`` block; the simulated gyro
    reads ``(1 + s) w + b`` per axis: ``G_true = diag(1 / (1 + s))``."""
    truth = np.diag(1.0 / (1.0 + np.asarray(scale)))
    err = np.array(block["gyro_matrix"]) - truth
    sigma = np.array([[np.inf if v is None else v for v in row] for row in block["gyro_matrix_sigma"]])
    return 100 * float(np.max(np.abs(err))), float(np.sqrt(np.mean((err / sigma) ** 2)))


def simulated(seeds):
    print("Simulated partial motions (compass.sim.partial_tumble; mean over seeds "
          f"{list(seeds)}; gyro 0.5 deg/s bias, a scale error per axis within +-the case's; 'late': magnetometer "
          "20 ms late)")
    head = ["case", "n", "cov", "method", "h err %|B|", "S err", "rot err deg", "heading rms", "notes"]
    print(("{:<40}{:>6}{:>6}{:>12}" + "{:>13}" * 4 + "  {}").format(*head))
    for kind, cov, late, scale in CASES:
        rows = {m: [] for m in METHODS}
        ratio, fell, n_s, cov_s, used, tau, g_err = [], 0, [], [], 0, [], []
        for seed in seeds:
            sim = simulate_partial_tumble(kind, seed=seed, coverage=cov, duration_s=60.0 if cov is None else 120.0,
                                          gyro_scale=scale)
            raw, att = _runtime(kind, seed)
            t_s, mag, accel, gyro = _late(sim, late)
            turns = gyro_turns(t_s, gyro, np.ones(len(t_s), bool))
            res = calibrate_tumble(mag, accel, t_s=t_s)
            fixed = with_gyro(res, mag, accel, turns, t_s, fit_latency=False, fit_gyro_matrix=False)
            before = with_gyro(res, mag, accel, turns, t_s, fit_gyro_matrix=False)
            gres = with_gyro(res, mag, accel, turns, t_s)
            default = gres if falls_back(res) else res
            fell += falls_back(res)
            used += falls_back(res) and gres.gyro["used"]
            if gres.gyro.get("gyro_matrix") is not None:  # null when the fit wandered (not usable, not written)
                g_err.append(_gyro_matrix_error(gres.gyro, sim.truth["gyro_scale"]))
            for name, r in zip(METHODS, (res, fixed, before, gres, default)):
                rows[name].append(_errors(r.hard_iron, r.fit.soft_iron, None if r.misalignment is None
                                          else r.misalignment.rotation, sim.truth, raw, att))
            if gres.gyro["used"]:
                c_true = Rotation.from_matrix(sim.truth["mag_to_accel"])
                err = (gres.misalignment.rotation * c_true.inv()).as_rotvec(degrees=True)
                ratio.append(err / gres.misalignment.rotvec_sigma_deg)
            if "mag_latency_s" in gres.gyro:
                tau.append((gres.gyro["mag_latency_s"], gres.gyro["mag_latency_sigma_s"]))
            n_s.append(len(t_s))
            cov_s.append(sim.coverage)
        label = (f"{kind} {'full' if cov is None else f'{100 * cov:.0f} %'}{' late' if late else ''}"
                 f"{f' gyro {100 * scale:.1f} %' if scale != 0.005 else ''}")
        for name, vals in rows.items():
            mean = np.mean(vals, axis=0)
            extra = f"gyro used {used} of {fell} fallbacks, {len(seeds)} seeds" if name == "default" else ""
            if name == "gyro" and tau:
                t_ms = 1e3 * np.array(tau)
                true_ms = 1e3 * late * np.median(np.diff(sim.t_s))
                extra = (f"tau {np.mean(t_ms[:, 0]):.2f} ms (true {true_ms:.0f}), (tau-true)/sig rms "
                         f"{np.sqrt(np.mean(((t_ms[:, 0] - true_ms) / t_ms[:, 1]) ** 2)):.2f}")
                if ratio:
                    extra += f", rot err/sig {np.sqrt(np.mean(np.square(ratio))):.2f}"
                if g_err:
                    extra += (f"; G err max (mean of the seeds') {np.mean([e[0] for e in g_err]):.3f} % "
                              f"({len(g_err)} of {len(seeds)} seeds wrote G), err/sig rms "
                              f"{np.sqrt(np.mean(np.square([e[1] for e in g_err]))):.2f}")
            print(("{:<40}{:>6}{:>6}{:>12}" + "{:>13.3f}" * 4 + "  {}").format(
                label if name == "present" else "", int(np.mean(n_s)) if name == "present" else "",
                f"{100 * np.mean(cov_s):.0f}%" if name == "present" else "", name, *mean, extra))


GAP_CASES = (("fast_rotation", 0.25, 0.6, 1.0), ("fast_rotation", 0.25, 0.6, 0.4), ("slow_rotation", 0.3, 0.6, 1.0),
             ("slow_rotation", 0.3, 1.0, 2.0))
"""(motion, coverage, lines lost s, kept s between losses) of the ``--gaps`` table."""


def _arrived(t_s: np.ndarray, lost_s: float, kept_s: float) -> np.ndarray:
    """The rows that arrive when ``lost_s`` of lines are lost after every ``kept_s`` that arrived."""
    hz = 1.0 / np.median(np.diff(t_s))
    return np.arange(len(t_s)) % int(round((lost_s + kept_s) * hz)) < int(round(kept_s * hz))


def gaps(seeds):
    import calibrate.tumble.gyro as gyro

    print(f"Bursts of lines lost (seeds {list(seeds)}): the gyro-aided fit with its windows closed at each gap beside "
          "the same code integrating the turns across them")
    head = ["case", "seed", "n", "fit", "windows", "outliers", "rms uT", "h err %|B|", "S err", "rot err deg",
            "max h err/sig"]
    print(("{:<44}{:>5}{:>6}{:>13}" + "{:>9}" * 3 + "{:>14}" * 4).format(*head))
    for kind, cov, lost, kept in GAP_CASES:
        for seed in seeds:
            sim = simulate_partial_tumble(kind, seed=seed, coverage=cov)
            keep = _arrived(sim.t_s, lost, kept)
            t_s, mag, accel = sim.t_s[keep], sim.mag[keep], sim.accel[keep]
            turns = gyro_turns(t_s, sim.gyro[keep], np.ones(len(t_s), bool))
            present = calibrate_tumble(mag, accel, t_s=t_s)
            for label, limit in (("gaps closed", gyro.GAP_S), ("across gaps", np.inf)):
                closed, gyro.GAP_S = gyro.GAP_S, limit
                try:
                    r = with_gyro(present, mag, accel, turns, t_s)
                finally:
                    gyro.GAP_S = closed
                case = f"{kind} {100 * cov:.0f} %, {lost:g} s lost every {lost + kept:g} s" if label == "gaps closed" else ""
                lead = ("{:<44}{:>5}{:>6}{:>13}").format(case, seed if case else "", len(t_s) if case else "", label)
                if not r.gyro["used"]:
                    print(lead + "  not used: " + next(w for w in r.warnings if w.startswith("gyro-aided"))[:110])
                    continue
                errors = _errors(r.hard_iron, r.fit.soft_iron, r.misalignment.rotation, sim.truth, sim.mag, sim.attitude)
                h_sig = np.max(np.abs(r.hard_iron - sim.truth["hard_iron"]) / r.fit.hard_iron_sigma)
                print(lead + ("{:>9}{:>9}{:>9.3f}" + "{:>14.3f}" * 4).format(
                    r.gyro["n_windows"], r.gyro["n_outliers"], r.gyro["mag_residual_rms"], *errors[:3], h_sig))


def broad(every=4):
    from compass.io.broad import read_broad

    paths = sorted(p for p in DATA.glob("*.mat") if int(p.stem[:2]) <= 15)
    if not paths:
        print(f"\nBROAD: no trials under {DATA}; skipped")
        return
    trials = [read_broad(p) for p in paths]
    print(f"\nBROAD undisturbed trials {', '.join(t.name[:2] for t in trials)}: calibrate on one trial's motion phase, "
          "heading spread (deg rms about its median) on every other trial, mean over them")
    print(("{:<6}{:>8}{:>9}" + "{:>12}" * 6 + "{:>10}  {}").format("cal", "n", "cov", "raw", *METHODS, "fell back",
                                                                      "latency fitted, ms; G - I, %"))
    scored = {}
    for t in trials:
        rows = np.flatnonzero(t.movement & t.ref_valid)
        scored[t.name] = (t.mag_ut[rows], _attitude(t, rows))
    totals = {m: [] for m in ("raw",) + METHODS}
    for t in trials:
        move = np.flatnonzero(t.movement)
        keep = np.zeros(len(t), bool)
        keep[move[::every]] = True
        turns = gyro_turns(t.t_s, t.gyro_rad_s, keep)
        mag, acc, tt = t.mag_ut[keep], t.accel_m_s2[keep], t.t_s[keep]
        res = calibrate_tumble(mag, acc, t_s=tt)
        fixed = with_gyro(res, mag, acc, turns, tt, fit_latency=False, fit_gyro_matrix=False)
        before = with_gyro(res, mag, acc, turns, tt, fit_gyro_matrix=False)
        gres = with_gyro(res, mag, acc, turns, tt)
        default = gres if falls_back(res) else res
        cells = {}
        for name, r in zip(("raw",) + METHODS, (None, res, fixed, before, gres, default)):
            spreads = []
            for other in trials:
                if other is t:
                    continue
                m, att = scored[other.name]
                if r is not None and not r.refused:  # a refused calibration is not written: the raw stays
                    m = r.calibrated(m)
                    if r.mag_to_accel is not None:
                        m = m @ r.mag_to_accel.T
                spreads.append(_heading_rms(m, att, about_median=True))
            cells[name] = float(np.mean(spreads))
            totals[name].append(cells[name])
        sigma = gres.gyro.get("mag_latency_sigma_s")  # None: the fit gave no sigma (a singular covariance)
        latency = (f"{1e3 * gres.gyro['mag_latency_s']:.2f} +/- "
                   + ("no sigma" if sigma is None else f"{1e3 * sigma:.2f}") + "; " + _matrix_words(gres.gyro)
                   if "mag_latency_s" in gres.gyro else "gyro-aided fit not used")
        print(("{:<6}{:>8}{:>9}" + "{:>12.3f}" * 6 + "{:>10}  {}").format(
            t.name[:2], len(mag), f"{100 * res.coverage.fraction:.0f}%", *cells.values(),
            "refused" if res.refused else "yes" if falls_back(res) else "no", latency))
    print(("{:<23}" + "{:>12.3f}" * 6).format("mean", *(np.mean(v) for v in totals.values())))


def _matrix_words(block: dict) -> str:
    """The fitted ``G - I`` (%): its diagonal and largest off-diagonal entry, with the largest sigma; or that the
    file holds none (a matrix its reader would refuse is not written: ``GyroFit.gyro_matrix_usable``)."""
    if block.get("gyro_matrix") is None:
        return "no gyro matrix written (not usable)"
    g = 100 * (np.array(block["gyro_matrix"]) - np.eye(3))
    sigma = 100 * np.array([[np.inf if v is None else v for v in row] for row in block["gyro_matrix_sigma"]])
    return (f"diag {', '.join(f'{v:+.2f}' for v in np.diag(g))}, off-diag up to "
            f"{np.max(np.abs(g - np.diag(np.diag(g)))):.2f} (sigma up to {np.max(sigma):.2f})")


def _attitude(trial, rows):
    """``R_NWU<-H`` of ``rows`` (all with a reference)."""
    from compass.io.broad import enu_to_nwu

    return enu_to_nwu(Rotation.from_quat(trial.ref_quat_enu[rows], scalar_first=True))


_TIMING_CHILD = r"""
import json, sys, time, warnings
import numpy as np
warnings.simplefilter("ignore")
from calibrate.tumble.gyro import GyroMismatch, fit_with_gyro
d = np.load(sys.argv[1])
start = dict(hard_iron=d["hard_iron"], soft_iron=d["soft_iron"], field_norm=float(d["field_norm"]),
             mag_to_accel=d["mag_to_accel"] if d["mag_to_accel"].size else None,
             dip_deg=float(d["dip_deg"]) if np.isfinite(d["dip_deg"]) else None, noise=float(d["noise"]))
wall, cpu = time.perf_counter(), time.process_time()
try:
    g = fit_with_gyro(d["mag"], d["accel"], d["turns"], d["t_s"], **start)
except GyroMismatch as exc:
    print(json.dumps({"cpu": time.process_time() - cpu, "wall": time.perf_counter() - wall, "refused": str(exc)}))
    sys.exit(0)
cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
names = {"hard_iron": "hard_iron_sigma", "soft_iron": "soft_iron_sigma", "field_norm": "field_norm_sigma",
         "rotvec_deg": "rotvec_sigma_deg", "dip_deg": "dip_sigma_deg", "gyro_bias_rad_s": "gyro_bias_sigma_rad_s",
         "latency_s": "latency_sigma_s"}
out = {"cpu": cpu, "wall": wall, "n_windows": g.n_windows, "inliers": int(np.count_nonzero(g.inliers)),
       "success": bool(g.success)}
for name, sig in names.items():
    out[name] = np.ravel(getattr(g, name)).tolist()
    out[name + "/sigma"] = np.ravel(getattr(g, sig)).tolist()
out["mag_to_accel"] = g.mag_to_accel.as_matrix().tolist()
cs = g.mag_to_accel.as_matrix() @ g.soft_iron
gyro = getattr(g, "gyro_matrix", None)  # a tree before the gyro matrix: the identity
out["p"] = np.concatenate([(g.field_norm * np.linalg.inv(cs)).ravel(), g.hard_iron, [np.radians(g.dip_deg)],
                           g.gyro_bias_rad_s, [g.latency_s], np.zeros(9) if gyro is None else (gyro - np.eye(3)).ravel()]
                          ).tolist()
out["inlier_rows"] = np.flatnonzero(g.inliers).tolist()
print(json.dumps(out))
"""
"""The child that times the gyro-aided fit in one tree: the inputs and the start from an ``.npz``, JSON out."""

_BLAS_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_GROUPS = (("hard iron", "hard_iron"), ("soft iron", "soft_iron"), ("|B|", "field_norm"), ("rotation", "rotvec_deg"),
           ("dip", "dip_deg"), ("gyro bias", "gyro_bias_rad_s"), ("latency", "latency_s"))


def _timing_cases(every: int):
    """(label, inputs, truth or None) of each timed case: BROAD 06 whole and thinned, a long simulated fast rotation."""
    from compass.io.broad import read_broad

    path = DATA / "06_undisturbed_fast_rotation_A.mat"
    if path.exists():
        t = read_broad(path)
        move = np.flatnonzero(t.movement)
        for step in (1, 2, every):
            keep = np.zeros(len(t), bool)
            keep[move[::step]] = True
            yield (f"BROAD 06 {'whole' if step == 1 else 'every 2nd row' if step == 2 else f'every {step}th row'}",
                   dict(mag=t.mag_ut[keep], accel=t.accel_m_s2[keep], turns=gyro_turns(t.t_s, t.gyro_rad_s, keep),
                        t_s=t.t_s[keep]), None)
    else:
        print(f"BROAD 06 not under {DATA}: only the simulated case")
    for label, kind, cov, duration_s, rate_hz in (("sim fast_rotation 300 s 100 Hz", "fast_rotation", None, 300.0, 100.0),
                                                  ("sim fast_rotation cut at 20 %", "fast_rotation", 0.2, 120.0, 50.0),
                                                  ("sim slow_rotation cut at 20 %", "slow_rotation", 0.2, 120.0, 50.0)):
        sim = simulate_partial_tumble(kind, seed=0, coverage=cov, duration_s=duration_s, rate_hz=rate_hz)
        yield (label, dict(mag=sim.mag, accel=sim.accel, t_s=sim.t_s,
                           turns=gyro_turns(sim.t_s, sim.gyro, np.ones(len(sim.t_s), bool))), sim.truth)


def _start(case: dict) -> dict:
    """The present fit's values that :func:`calibrate.tumble.gyro.with_gyro` starts from."""
    res = calibrate_tumble(case["mag"], case["accel"], t_s=case["t_s"])
    mis = res.misalignment
    return dict(hard_iron=res.fit.hard_iron, soft_iron=res.fit.soft_iron, field_norm=res.fit.field_norm,
                mag_to_accel=np.zeros(0) if res.mag_to_accel is None else np.asarray(res.mag_to_accel, float),
                dip_deg=np.nan if mis is None else mis.dip_deg, noise=res.noise)


def _truth_errors(r: dict, truth: dict) -> str:
    """A tree's errors against the simulation's truth, in words."""
    s = np.reshape(r["soft_iron"], (3, 3))
    s_true = np.array(truth["soft_iron"]) / np.cbrt(np.linalg.det(truth["soft_iron"]))
    rot = Rotation.from_matrix(truth["mag_to_accel"]).inv() * Rotation.from_matrix(r["mag_to_accel"])
    bias = np.degrees(np.linalg.norm(np.array(r["gyro_bias_rad_s"]) - truth["gyro_bias_rad_s"]))
    return (f"h {100 * np.linalg.norm(np.array(r['hard_iron']) - truth['hard_iron']) / truth['field_ut']:.3f} %|B|, "
            f"S {np.linalg.norm(s - s_true):.4f}, rotation {np.degrees(rot.magnitude()):.3f} deg, "
            f"dip {r['dip_deg'][0] - truth['dip_deg']:+.3f} deg, bias {bias:.4f} deg/s, "
            f"latency {1e3 * r['latency_s'][0]:+.2f} ms (true 0)")


def _on_inliers(case: dict, data: Path, this: dict, base: dict) -> str:
    """Where the plain fit of this tree converges on each tree's inliers, from each tree's parameters, in words."""
    import calibrate.tumble.gyro as g
    from calibrate.noise import robust_sigma
    from calibrate.tumble.alignment import static_mask
    from calibrate.tumble.ellipsoid import plain_fit

    d = np.load(data)
    mag, accel, turns, t_s = (case[k] for k in ("mag", "accel", "turns", "t_s"))
    dt = np.diff(t_s, prepend=t_s[0])
    a_unit = accel / np.linalg.norm(accel, axis=1, keepdims=True)
    window, rate, static = g._windows(turns, dt), g.turn_rates(turns, dt), static_mask(accel)
    t0 = (d["mag_to_accel"] if d["mag_to_accel"].size else np.eye(3)) @ d["soft_iron"]
    mag_h = (mag - d["hard_iron"]) @ t0.T
    cos = np.sum(mag_h[static] * a_unit[static], axis=1) / np.linalg.norm(mag_h[static], axis=1)
    dip = np.radians(float(d["dip_deg"]) if np.isfinite(d["dip_deg"])
                     else float(np.degrees(np.median(np.arccos(np.clip(cos, -1, 1))))) - 90.0)
    q0 = g._start_orientations(mag_h, a_unit, window, np.array([np.cos(dip), 0.0, -np.sin(dip)]))
    p0 = np.concatenate([(float(d["field_norm"]) * np.linalg.inv(t0)).ravel(), d["hard_iron"], [dip], np.zeros(13)])
    full = g._Problem(mag, turns, dt, window, a_unit, static, q0, float(d["noise"]), 1.0, rate, g.LATENCY_PRIOR_S)
    r_a = full.residuals(full.rows(p0), q0.as_matrix())[1]
    full.sigma_a = max(float(robust_sigma(np.linalg.norm(r_a, axis=1))), 1e-4)  # as fit_with_gyro sets it
    words = []
    for owner, r in (("this tree's", this), ("the baseline's", base)):
        prob, used = g._on_rows(full, t_s, rate, np.array(r["inlier_rows"]), f_scale=None)
        fits = [plain_fit(prob.residual, np.array(x["p"]), prob.jacobian) for x in (this, base)]
        chi2 = float(fits[0].fun @ fits[0].fun) / (fits[0].fun.size - g._Problem.N_GLOBAL - 3 * len(used))
        sigma = np.sqrt(np.diag(g._global_covariance(fits[0].jac, chi2)))
        off = [np.max(np.abs(np.array(x["p"]) - fits[0].x) / sigma) for x in (this, base)]
        words.append(f"on {owner} inliers the plain fit from either tree's parameters meets within "
                     f"{np.max(np.abs(fits[0].x - fits[1].x) / sigma):.1g} sigma, this tree's {off[0]:.2g} sigma "
                     f"from it, the baseline's {off[1]:.2g}")
    return "; ".join(words) + " (parameters D, h, dip, bias, latency, gyro matrix)"


def timing(baseline: str, blas_threads: str, every: int = 4, timeout_s: float = 1800.0):
    """Time the gyro-aided fit in this tree and the baseline on the long fast cases, with their agreement."""
    blas = {} if blas_threads == "default" else {v: blas_threads for v in _BLAS_ENV}
    print(f"Gyro-aided fit, CPU time (all threads) and wall time, this tree beside baseline {baseline} "
          f"(load average {np.round(os.getloadavg(), 1).tolist()} on {os.cpu_count()} CPUs; BLAS threads "
          f"{blas_threads})")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        trees = [("this tree", None)] + ([(f"baseline {baseline}", export_tree(baseline, folder))]
                                         if baseline != "none" else [])
        for label, case, truth in _timing_cases(every):
            data = folder / "case.npz"
            np.savez(data, **case, **_start(case))
            runs = {}
            for name, tree in trees:
                proc = subprocess.run([sys.executable, "-c", _TIMING_CHILD, str(data)], capture_output=True, text=True,
                                      env=tree_env(tree, **blas), cwd=tmp, timeout=timeout_s)
                if proc.returncode != 0:
                    print(f"  {label}, {name}: failed: {(proc.stderr.strip().splitlines() or [''])[-1]}")
                    continue
                runs[name] = json.loads(proc.stdout.strip().splitlines()[-1])
            print(f"\n{label}: {len(case['t_s'])} rows")
            for name, r in runs.items():
                if "refused" in r:
                    print(f"  {name:<16} CPU {r['cpu']:7.1f} s  wall {r['wall']:7.1f} s  refused: {r['refused'][:110]}")
                    continue
                print(f"  {name:<16} CPU {r['cpu']:7.1f} s  wall {r['wall']:7.1f} s  {r['n_windows']} windows, "
                      f"{r['inliers']} inliers, success {r['success']}"
                      + (f"\n  {'':<16} against the truth: {_truth_errors(r, truth)}" if truth is not None else ""))
            if len(runs) == 2 and not any("refused" in r for r in runs.values()):
                this, base = runs.values()
                diffs = []
                for group, key in _GROUPS:
                    diff = np.abs(np.subtract(this[key], base[key])) / np.array(this[key + "/sigma"])
                    diffs.append(f"{group} {np.max(diff):.3g}")
                print(f"  {'':<16} speed-up {base['cpu'] / this['cpu']:.1f}x in CPU; max |this - baseline| / sigma: "
                      + ", ".join(diffs))
                if this["inlier_rows"] != base["inlier_rows"]:
                    print(f"  {'':<16} the outlier tests kept different samples; {_on_inliers(case, data, this, base)}")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--no-broad", action="store_true")
    p.add_argument("--no-sim", action="store_true", help="BROAD only")
    p.add_argument("--gaps", action="store_true", help="only the fit on recordings with bursts of lines lost")
    p.add_argument("--timing", action="store_true", help="only the timing of the gyro-aided fit on long fast recordings")
    p.add_argument("--baseline", default="main", help="git revision the timing compares with ('none' to skip)")
    p.add_argument("--blas-threads", default="1",
                   help="BLAS threads of the timed children ('default': OpenBLAS's own choice; default 1)")
    args = p.parse_args(argv)
    warnings.simplefilter("ignore")
    started = time.perf_counter()
    if args.gaps:
        gaps(range(1 if args.quick else args.seeds))
        print(f"\n({time.perf_counter() - started:.0f} s)")
        return
    if args.timing:
        timing(args.baseline, args.blas_threads)
        print(f"\n({time.perf_counter() - started:.0f} s)")
        return
    if not args.no_sim:
        simulated(range(1 if args.quick else args.seeds))
    if not (args.quick or args.no_broad):
        broad()
    print(f"\n({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
