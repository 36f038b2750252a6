"""The gyro-aided tumble fit beside the present one, on simulated partial motions and on BROAD.

Run: ``python tools/bench_gyro_tumble.py [--seeds 4] [--quick] [--no-broad] [--no-sim]`` (seeded;
about 25 min with ``--seeds 2`` on the shared machine, BROAD's fast rotation 06 the longest; ``--quick``
one seed and no BROAD).

Simulated: :func:`compass.sim.partial_tumble.simulate_partial_tumble` - hand-held motions of
:mod:`compass.sim.motion` (``fast_rotation``, ``slow_rotation``: not the motions the method was
written on) through 20 uT of hard iron, 8 % soft iron and a 2 deg rotation to the housing, cut where
the field's directions first cover 20 %, 30 %, 50 % of the sphere, or the whole 60 s ("full"); the
gyro with a random 0.5 deg/s bias, a 0.5 % scale error (not modelled by the fit) and noise; cases
marked ``late`` have the magnetometer one row (20 ms) late against the accelerometer and gyro.
Columns: ``present`` (:func:`calibrate.tumble.calibrate_tumble`), ``gyro tau=0`` (the gyro-aided fit
tried on every recording, its magnetometer latency held at zero: the model before the latency), ``gyro``
(the same with the latency fitted; its mean and the rms of (fitted - true) / sigma in the notes); where
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
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calibrate.tumble import calibrate_tumble  # noqa: E402
from calibrate.tumble.gyro import falls_back, with_gyro  # noqa: E402
from compass.io.tumble import gyro_turns  # noqa: E402
from compass.sim.partial_tumble import simulate_partial_tumble  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "broad"
CASES = (("fast_rotation", 0.2, 0), ("slow_rotation", 0.2, 0), ("fast_rotation", 0.3, 0), ("slow_rotation", 0.3, 0),
         ("fast_rotation", 0.5, 0), ("fast_rotation", None, 0), ("fast_rotation", None, 1), ("fast_rotation", 0.3, 1))
"""(motion, coverage or None for the whole 60 s, magnetometer latency in samples: 1 is 20 ms at 50 Hz)."""
METHODS = ("present", "gyro tau=0", "gyro", "default")


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


def simulated(seeds):
    print("Simulated partial motions (compass.sim.partial_tumble; mean over seeds "
          f"{list(seeds)}; gyro 0.5 deg/s bias, 0.5 % scale error; 'late': magnetometer 20 ms late)")
    head = ["case", "n", "cov", "method", "h err %|B|", "S err", "rot err deg", "heading rms", "notes"]
    print(("{:<28}{:>6}{:>6}{:>12}" + "{:>13}" * 4 + "  {}").format(*head))
    for kind, cov, late in CASES:
        rows = {m: [] for m in METHODS}
        ratio, fell, n_s, cov_s, used, tau = [], 0, [], [], 0, []
        for seed in seeds:
            sim = simulate_partial_tumble(kind, seed=seed, coverage=cov, duration_s=60.0 if cov is None else 120.0)
            raw, att = _runtime(kind, seed)
            t_s, mag, accel, gyro = _late(sim, late)
            turns = gyro_turns(t_s, gyro, np.ones(len(t_s), bool))
            res = calibrate_tumble(mag, accel, t_s=t_s)
            fixed = with_gyro(res, mag, accel, turns, t_s, fit_latency=False)
            gres = with_gyro(res, mag, accel, turns, t_s)
            default = gres if falls_back(res) else res
            fell += falls_back(res)
            used += falls_back(res) and gres.gyro["used"]
            for name, r in zip(METHODS, (res, fixed, gres, default)):
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
        label = f"{kind} {'full' if cov is None else f'{100 * cov:.0f} %'}{' late' if late else ''}"
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
            print(("{:<28}{:>6}{:>6}{:>12}" + "{:>13.3f}" * 4 + "  {}").format(
                label if name == "present" else "", int(np.mean(n_s)) if name == "present" else "",
                f"{100 * np.mean(cov_s):.0f}%" if name == "present" else "", name, *mean, extra))


def broad(every=4):
    from compass.io.broad import read_broad

    paths = sorted(p for p in DATA.glob("*.mat") if int(p.stem[:2]) <= 15)
    if not paths:
        print(f"\nBROAD: no trials under {DATA}; skipped")
        return
    trials = [read_broad(p) for p in paths]
    print(f"\nBROAD undisturbed trials {', '.join(t.name[:2] for t in trials)}: calibrate on one trial's motion phase, "
          "heading spread (deg rms about its median) on every other trial, mean over them")
    print(("{:<6}{:>8}{:>9}" + "{:>12}" * 5 + "{:>10}  {}").format("cal", "n", "cov", "raw", *METHODS, "fell back",
                                                                      "latency fitted, ms"))
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
        fixed = with_gyro(res, mag, acc, turns, tt, fit_latency=False)
        gres = with_gyro(res, mag, acc, turns, tt)
        default = gres if falls_back(res) else res
        cells = {}
        for name, r in zip(("raw",) + METHODS, (None, res, fixed, gres, default)):
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
        latency = (f"{1e3 * gres.gyro['mag_latency_s']:.2f} +/- {1e3 * gres.gyro['mag_latency_sigma_s']:.2f}"
                   if "mag_latency_s" in gres.gyro else "gyro-aided fit not used")
        print(("{:<6}{:>8}{:>9}" + "{:>12.3f}" * 5 + "{:>10}  {}").format(
            t.name[:2], len(mag), f"{100 * res.coverage.fraction:.0f}%", *cells.values(),
            "refused" if res.refused else "yes" if falls_back(res) else "no", latency))
    print(("{:<23}" + "{:>12.3f}" * 5).format("mean", *(np.mean(v) for v in totals.values())))


def _attitude(trial, rows):
    """``R_NWU<-H`` of ``rows`` (all with a reference)."""
    from compass.io.broad import enu_to_nwu

    return enu_to_nwu(Rotation.from_quat(trial.ref_quat_enu[rows], scalar_first=True))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--no-broad", action="store_true")
    p.add_argument("--no-sim", action="store_true", help="BROAD only")
    args = p.parse_args(argv)
    warnings.simplefilter("ignore")
    started = time.perf_counter()
    if not args.no_sim:
        simulated(range(1 if args.quick else args.seeds))
    if not (args.quick or args.no_broad):
        broad()
    print(f"\n({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
