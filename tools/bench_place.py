"""A reference field that follows the place (issue 22, item 3): the rule beside the version before it, same run, seeded.

Run: ``python tools/bench_place.py [--broad DATA_DIR] [--seeds 3] [--no-broad] [--trials 01,32]``.

"Before" is the same tree with ``FilterConfig(follow_place=False)``: the filter as it was (the gate
and its timeout; the rule's code is skipped, the numbers are those of the commit before it).

**Simulated walks** (:mod:`compass.sim.motion`, 60 s at 100 Hz, gyro bias and scale error; every
kind of motion the simulator has, seeds 0..N-1, none designed for the rule):

- ``no change``: one place throughout (the rule must not move);
- ``room``: at 20 s a 2 s walk into a room of 60 uT at 55 deg dip whose steel turns North 10 deg east;
- ``room, |B| only``: into one of 35 uT at 66 deg, North unchanged;
- ``issue's building``: the reference given (``reference="config"``) as the calibration's place,
  37.6 uT at 58 deg, the module used where the field is 73 uT at 34 deg from the first sample (the
  issue's real case);
- ``magnet on housing``: at 20 s a magnet fixed to the housing adds a seeded 15-40 uT constant field in H.

Per scenario: heading RMS after 5 s and after the change's first 15 s (the truth is the first place's
frame: a heading that re-learns North from the new room's field is off by its declination), the time
from the change until the field is used again (90 % of the next second), and the number of moves.

**BROAD** (bench_broad's pipeline: configuration from the trial's initial rest, causal hard-iron
tracker, ``run_filter``), every trial: the rule off, and on with windows of 2, 4 (the default) and
8 s; leave one trial out (bench_broad's ``loo_choice``: the candidate best on the other trials,
scored on the held-out one); moves per trial; VQF beside.  The disturbed trials also without the
hard-iron tracker, as ``compass live`` runs (no tracker there): a magnet on the housing must not be
followed.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from compass.evaluation import orientation_errors  # noqa: E402
from compass.filter import FilterConfig, run_filter  # noqa: E402
from compass.sim.motion import KINDS, HousingField, Place, SensorErrors, simulate_motion  # noqa: E402

RATE_HZ = 100.0
DURATION_S = 60.0
CHANGE_S = 20.0
ERRORS = SensorErrors(gyro_bias_rad_s=(0.004, -0.003, 0.002), gyro_scale=(0.005, -0.005, 0.003))
MOVED = "the field moved"
WINDOWS = (2.0, 4.0, 8.0)


def _scenarios(seed: int) -> dict:
    """name: (simulate_motion keywords, the reference given as (|B|, dip) or None, change time s)."""
    rng = np.random.default_rng(1000 + seed)
    direction = rng.normal(size=3)
    magnet = tuple((rng.uniform(15.0, 40.0) * direction / np.linalg.norm(direction)).tolist())
    return {
        "no change": ({}, None, None),
        "room": ({"places": (Place(CHANGE_S, 60.0, 55.0, 10.0),)}, None, CHANGE_S),
        "room, |B| only": ({"places": (Place(CHANGE_S, 35.0, 66.0, 0.0),)}, None, CHANGE_S),
        "issue's building": ({"field_ut": 73.0, "dip_deg": 34.0}, (37.6, 58.0), 0.0),
        "magnet on housing": ({"housing_field": HousingField(CHANGE_S, magnet)}, None, CHANGE_S),
    }


def _walk(kind: str, seed: int, keywords: dict, reference, change_s, follow: bool) -> dict:
    rec = simulate_motion(kind, duration_s=DURATION_S, rate_hz=RATE_HZ, seed=seed, errors=ERRORS, **keywords)
    norm, dip = reference if reference is not None else (rec.field_ut, rec.dip_deg)
    cfg = FilterConfig(field_norm=norm, dip_deg=dip, mag_noise=ERRORS.mag_noise_ut, follow_place=follow)
    track = run_filter(rec.t_s, rec.accel_m_s2, rec.gyro_rad_s, rec.mag_ut, cfg,
                       reference="config" if reference is not None else None)
    ok = np.all(np.isfinite(track.quat), axis=1)
    heading = np.full(len(rec.t_s), np.nan)
    heading[ok] = orientation_errors(Rotation.from_quat(track.quat[ok]), rec.rotation[np.flatnonzero(ok)])[0]
    t = rec.t_s
    out = {"all": _rms(heading[t > 5.0]), "moves": sum(text.startswith(MOVED) for _, text in track.events)}
    if change_s is not None:
        out["after"] = _rms(heading[t > change_s + 15.0])
        out["reacquire"] = _reacquire(t, track.mag_used, change_s)
    return out


def _rms(x) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if len(x) else float("nan")


def _reacquire(t, used, change_s) -> float:
    """Seconds from the change until the field is used in 90 % of the next second (NaN: never)."""
    per_s = int(round(RATE_HZ))
    share = np.convolve(used.astype(float), np.ones(per_s) / per_s, mode="full")[per_s - 1:]  # the next second's
    late = np.flatnonzero((t >= change_s + 0.5) & (share >= 0.9) & (t <= t[-1] - 1.0))
    return float(t[late[0]] - change_s) if len(late) else float("nan")


def simulated(seeds: int) -> None:
    print(f"simulated walks: {len(KINDS)} kinds x {seeds} seeds, {DURATION_S:g} s at {RATE_HZ:g} Hz; mean over runs "
          "(re-acquire: median, never = runs whose field was not used again); before = follow_place off")
    print(f"{'scenario':20s} {'heading RMS':>19s} {'after change':>19s} {'re-acquire s':>19s} {'never':>9s} "
          f"{'moves':>11s}")
    rows: dict = {}
    for seed in range(seeds):
        for name, (keywords, reference, change_s) in _scenarios(seed).items():
            for kind in KINDS:
                for follow in (False, True):
                    run = _walk(kind, seed, keywords, reference, change_s, follow) | {"kind": kind}
                    rows.setdefault(name, {}).setdefault(follow, []).append(run)
        print(f"  seed {seed} done", file=sys.stderr, flush=True)
    for name, by in rows.items():
        cells = []
        for key in ("all", "after", "reacquire"):
            if key not in by[False][0]:
                cells.append(f"{'-':>19s}")
                continue
            old, new = ([r[key] for r in by[f]] for f in (False, True))
            if key == "reacquire":
                cells.append(f"{_median(old):>8s} -> {_median(new):>7s}")
                never = f"{sum(np.isnan(old))} -> {sum(np.isnan(new))}"
            else:
                cells.append(f"{np.mean(old):8.2f} -> {np.mean(new):7.2f}")
        never = never if "reacquire" in by[False][0] else "-"
        moves = f"{sum(r['moves'] for r in by[False])} -> {sum(r['moves'] for r in by[True])}"
        print(f"{name:20s} {' '.join(cells)} {never:>9s} {moves:>11s}")
    print("\nper kind of motion (seeds pooled): re-acquire s (median) and moves, off -> on")
    print(f"{'kind':18s} " + " ".join(f"{name:>26s}" for name, by in rows.items() if "reacquire" in by[False][0]))
    for kind in KINDS:
        cells = []
        for name, by in rows.items():
            if "reacquire" not in by[False][0]:
                continue
            old, new = ([r for r in by[f] if r["kind"] == kind] for f in (False, True))
            cells.append(f"{_median([r['reacquire'] for r in old])} -> {_median([r['reacquire'] for r in new])}, "
                         f"{sum(r['moves'] for r in old)} -> {sum(r['moves'] for r in new)}")
        print(f"{kind:18s} " + " ".join(f"{c:>26s}" for c in cells))
    worst = {name: max(range(len(by[True])), key=lambda i: by[True][i]["all"] - by[False][i]["all"])
             for name, by in rows.items()}
    print("largest change of one run's heading RMS (on - off), deg: " + ", ".join(
        f"{name} {rows[name][True][i]['all'] - rows[name][False][i]['all']:+.2f}" for name, i in worst.items()))


def _median(values) -> str:
    v = [x for x in values if np.isfinite(x)]
    return f"{np.median(v):.1f}" if v else "never"


def broad(folder: Path, trials: list[str]) -> None:
    from bench_broad import _groups, loo_choice, ours_config, vqf_online

    from compass.evaluation import error_series
    from compass.hard_iron import track_hard_iron
    from compass.io.broad import nwu_to_enu, read_broad

    candidates = {"off (before)": {"follow_place": False}} | {
        f"on, window {w:g} s": {"follow_place": True, "place_window_s": w} for w in WINDOWS}
    default = f"on, window {FilterConfig(1.0, 0.0, 1.0).place_window_s:g} s"
    results, moves, raw_rows = {}, {}, {}
    for path in sorted(folder.glob("*.mat")):
        if trials and path.name[:2] not in trials:
            continue
        trial = read_broad(path)
        base = ours_config(trial, trial.mag_ut)
        tracked = track_hard_iron(trial.mag_ut, trial.accel_m_s2, trial.rate_hz, dip_deg=base.dip_deg)
        fields = {"tracker": tracked.corrected(trial.mag_ut)}
        if "_disturbed_" in path.name:
            fields["raw"] = trial.mag_ut
        row, count = {}, {}
        for source, field in fields.items():
            for name, changes in candidates.items():
                if source == "raw" and name not in ("off (before)", default):
                    continue
                track = run_filter(trial.t_s, trial.accel_m_s2, trial.gyro_rad_s, field, replace(base, **changes))
                quat = nwu_to_enu(Rotation.from_quat(np.nan_to_num(track.quat, nan=0.5))).as_quat(scalar_first=True)
                e = error_series(quat, trial.ref_quat_enu, trial.movement, trial.rate_hz)
                key = name if source == "tracker" else f"{name} | no tracker"
                row[key] = (e.heading_rms_deg, e.inclination_rms_deg)
                count[key] = sum(text.startswith(MOVED) for _, text in track.events)
        e = error_series(vqf_online(trial), trial.ref_quat_enu, trial.movement, trial.rate_hz)
        row["vqf"] = (e.heading_rms_deg, e.inclination_rms_deg)
        results[trial.name], moves[trial.name] = row, count
        print(f"  {trial.name}: " + ", ".join(f"{k} {v[0]:.3f}/{v[1]:.3f} ({count.get(k, '-')} moves)"
                                               for k, v in row.items()), file=sys.stderr, flush=True)
    names = list(candidates)
    for t in results:
        choice = loo_choice({k: {c: results[k][c] for c in names} for k in results}, t, names)
        results[t]["LOO"] = results[t][choice]
        moves[t]["LOO"] = f"{moves[t][choice]} ({choice})"
    print("\nBROAD (bench_broad's pipeline and metric): heading / inclination RMS deg, moves; LOO: the candidate "
          "chosen on the other trials")
    columns = ["off (before)", default, "LOO", "vqf"]
    print(f"{'trial':44s} " + " ".join(f"{c:>22s}" for c in columns) + "   LOO choice")
    for t, row in results.items():
        cells = [f"{row[c][0]:6.3f}/{row[c][1]:5.3f} {str(moves[t].get(c, '')).split(' ')[0]:>3s}" for c in columns]
        print(f"{t:44s} " + " ".join(f"{c:>22s}" for c in cells) + f"   {moves[t]['LOO'].split(' ', 1)[1]}")
    groups = _groups(results) | {"all": list(results)}
    print("\ngroups (mean of the trials' RMS), heading / inclination deg")
    for g, ts in groups.items():
        cells = [f"{np.mean([results[t][c][0] for t in ts]):6.3f}/{np.mean([results[t][c][1] for t in ts]):5.3f}"
                 for c in columns]
        print(f"{g + f' ({len(ts)})':44s} " + " ".join(f"{c:>22s}" for c in cells))
    raw = [t for t in results if f"{default} | no tracker" in results[t]]
    if raw:
        print("\ndisturbed trials without the hard-iron tracker (as compass live runs): heading / inclination, moves")
        for t in raw:
            old, new = results[t]["off (before) | no tracker"], results[t][f"{default} | no tracker"]
            print(f"{t:44s} {old[0]:7.3f}/{old[1]:5.3f} -> {new[0]:7.3f}/{new[1]:5.3f}   moves "
                  f"{moves[t]['off (before) | no tracker']} -> {moves[t][f'{default} | no tracker']}")
    print("\nmoves on BROAD with the default window (one room throughout: a move is right only back to the room's "
          "field after the gate's timeout adopted a magnet's): "
          f"{sum(moves[t][default] for t in results)} with the tracker, "
          f"{sum(moves[t].get(f'{default} | no tracker', 0) for t in results)} without")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--broad", default=str(ROOT.parent / "shared" / "data" / "broad"), help="BROAD .mat folder")
    parser.add_argument("--no-broad", action="store_true", help="the simulated walks only")
    parser.add_argument("--no-sim", action="store_true", help="BROAD only")
    parser.add_argument("--trials", default="", help="comma-separated BROAD trial numbers (default: all)")
    parser.add_argument("--seeds", type=int, default=3, help="seeds of the simulated walks")
    args = parser.parse_args(argv)
    if not args.no_sim:
        simulated(args.seeds)
    if not args.no_broad:
        folder = Path(args.broad)
        if not folder.is_dir():
            print(f"no BROAD folder {folder}: skipped (--broad DATA_DIR)")
        else:
            print()
            broad(folder, [t for t in args.trials.split(",") if t])
    return 0


if __name__ == "__main__":
    sys.exit(main())
