"""The gyro's scale error on low-cost boards (issue 22): the filter before (main's defaults: 0.5 % on every board),
with the scale error its calibration's gyro-aided fit says as the RMS over rate directions (``||E||_F / sqrt 3``,
``FilterConfig.from_model``'s) and as the bound over every direction (largest singular value and worst sigma column:
tried, not kept), beside VQF, in one run.

Run: ``python tools/bench_gyro_scale.py [--dev-seeds 11,12] [--seeds 13-20] [--levels 0,1,3,5] [--aniso 5]
[--broad 01,02,...] [--methods VQF,fitted] [--candidates "start rest from 1.5 s (before)"]`` (``--broad all``: every trial; ``--broad none``: no BROAD; ``--levels ''``: no isotropic
boards; ``--aniso L``: boards whose z axis alone reads L % high; ``--candidates A,B``: a column per
:data:`bench_broad.CANDIDATES` name, its ``FilterConfig`` changes on top of "fitted", the pipeline the calibration
file gives; ``--write-docs``: the tables into docs/benchmarks.md).

Simulated boards: every :mod:`compass.sim.motion` kind, 60 s, the BROAD-like board of ``tools/bench_broad.py``
(:func:`bench_broad.board_errors`) with its gyro scale replaced: per axis, a seeded sign, the largest axis at the
level, the others 0.7-1.0 times it.  Each board's calibration is its own tumble recording (a fast rotation at
another motion seed, the rows at a sixth of the rate) through ``compass calibrate``'s gyro-aided path and the
calibration reader (:func:`bench_broad.file_values`): the filter's scale error comes from that file, never from the
truth.  The seeds the change was developed on (11, 12) are reported apart from the others.  Cells: heading /
inclination RMS over the moving samples (BROAD's metric), deg, mean over the seeds, and the percentage of field
samples the innovation test refused.  BROAD: each trial with the gyro scale error of the tumble file of another
trial (:data:`bench_broad.CAL_TRIALS`, never its own), the same pipeline otherwise (``bench_broad.ours``).  Nothing
here is tuned: the scale error is the held-out file's, so there is no constant to leave a trial out for.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

import bench_broad as bb  # noqa: E402
from _doc_table import markdown_table, parse_args, publish  # noqa: E402
from compass.filter import DEFAULT_GYRO_SCALE_ERROR  # noqa: E402

METHODS = ("VQF", "before", "fitted", "fitted bound")
"""The columns: VQF (online, its defaults), ours with the default 0.5 %, with the fitted scale error as the RMS over
rate directions (``from_model``'s), and as the bound over every direction (:func:`bound_scale_error`, not kept)."""

LOCKOUT_TRIALS = ("01", "02", "04", "06", "10", "15", "24")
"""The seven BROAD trials of the lock-out investigation (/work/brief/lockout.md)."""


def bound_scale_error(fitted) -> float:
    """The scale error as the bound over every rate direction (tried, not kept: docs/benchmarks.md): the largest
    singular value of the seen entries of ``G - I`` and the worst column of their sigmas ``sqrt(max_j sum_i
    sigma_ij^2)``, in quadrature, then with the default (the gyro as read); the default without a fit.

    Parameters
    ----------
    fitted : tuple
        The file's ``(gyro_matrix, gyro_matrix_sigma)`` as written (None, or nested lists with nulls).
    """
    from compass.calibration import gyro_matrix_seen

    matrix, sigma = fitted
    if matrix is None or sigma is None:
        return DEFAULT_GYRO_SCALE_ERROR
    g = np.array(matrix, dtype=float)
    sigma = np.array([[np.inf if v is None else v for v in row] for row in sigma], dtype=float)
    seen = gyro_matrix_seen(g, sigma)
    column_var = np.max(np.sum(np.where(seen, sigma, 0.0) ** 2, axis=0))
    estimate = np.linalg.svd(np.where(seen, g - np.eye(3), 0.0), compute_uv=False)[0]
    return float(np.hypot(DEFAULT_GYRO_SCALE_ERROR, np.sqrt(estimate**2 + column_var)))


def _changes(method: str, scale: dict) -> dict | None:
    """The FilterConfig changes of a column (None: VQF); the default scale error left out (the same filter); a
    :data:`bench_broad.CANDIDATES` name (``--candidates``): its changes on top of "fitted"."""
    if method in bb.CANDIDATES:
        return _changes("fitted", scale) | bb.CANDIDATES[method][0]
    value = {"before": DEFAULT_GYRO_SCALE_ERROR, "fitted": scale.get("rms"),
             "fitted bound": scale.get("bound")}.get(method)
    if method not in ("before", "fitted", "fitted bound"):
        return None
    return {} if value == DEFAULT_GYRO_SCALE_ERROR else {"gyro_scale_error": value}


def scored(trial, scale: dict) -> dict[str, tuple[float, float, float]]:
    """``{method: (heading RMS deg, inclination RMS deg, refused %)}`` of one trial; ``scale``: ``{"rms": , "bound": }``
    the filter's scale error of each formula."""
    from compass.evaluation import error_series
    from compass.io.broad import nwu_to_enu
    from scipy.spatial.transform import Rotation

    out, done = {}, {}
    for method in METHODS:
        changes = _changes(method, scale)
        if changes is not None and repr(sorted(changes.items())) in done:  # the same filter as a column before
            out[method] = out[done[repr(sorted(changes.items()))]]
            continue
        if changes is not None:
            done[repr(sorted(changes.items()))] = method
        if changes is None:
            quat, refused = bb.vqf_online(trial), np.nan
        else:
            track = bb.ours_track(trial, changes)
            quat = nwu_to_enu(Rotation.from_quat(track.quat)).as_quat(scalar_first=True)
            gate = track.gate[trial.movement]
            present = gate != "absent"
            refused = 100.0 * np.mean(gate[present] == "innovation") if present.any() else 0.0
        e = error_series(quat, trial.ref_quat_enu, trial.movement, trial.rate_hz)
        out[method] = (e.heading_rms_deg, e.inclination_rms_deg, refused)
    return out


def board_errors(seed: int, level: float):
    """The BROAD-like board at ``seed`` with its gyro scale at ``level`` (fraction): per axis a seeded sign, the
    largest axis at ``level``, the others 0.7-1.0 times it; a string level ``"z5"``: the z axis alone 5 % high."""
    if isinstance(level, str):
        return replace(bb.board_errors("broad-like", seed), gyro_scale=(0.0, 0.0, float(level[1:]) / 100.0))
    rng = np.random.default_rng(2000 + seed)
    sign = rng.choice([-1.0, 1.0], 3)
    size = level * rng.uniform(0.7, 1.0, 3)
    size[rng.integers(3)] = level
    return replace(bb.board_errors("broad-like", seed), gyro_scale=tuple(sign * size))


def board_scale_error(seed: int, level) -> dict:
    """The filter's gyro scale error from the board's own tumble calibration (as read, no matrix applied), by each
    formula: ``{"rms": from_model's, "bound": the bound's}``."""
    from compass.sim.motion import simulate_motion

    cal = simulate_motion("fast_rotation", seed=500 + seed, errors=board_errors(seed, level))
    keep = np.zeros(len(cal.t_s), bool)
    keep[::6] = True
    values = bb.file_values(cal.t_s, cal.gyro_rad_s, cal.accel_m_s2, cal.mag_ut, keep)
    return {"rms": values["gyro_scale_error"], "bound": bound_scale_error(values["fitted"])}


def _level(level) -> str:
    return f"z {level[1:]} only" if isinstance(level, str) else f"{level:g}"


def simulated(seeds, levels, kinds=None) -> dict:
    """``{level: {kind: {method: (heading, inclination, refused %)}}}``, means over ``seeds``."""
    from compass.sim.motion import KINDS, simulate_motion

    out = {}
    for level in levels:
        size = level if isinstance(level, str) else level / 100.0
        scale = {seed: board_scale_error(seed, size) for seed in seeds}
        print(f"  gyro scale {_level(level)} %: fitted scale error (RMS / bound) "
              + ", ".join(f"{100 * v['rms']:.2f} / {100 * v['bound']:.2f}" for v in scale.values()) + " %",
              file=sys.stderr, flush=True)
        out[level] = {}
        for kind in kinds or KINDS:
            runs = [scored(bb._Simulated(simulate_motion(kind, seed=seed, errors=board_errors(seed, size)),
                                         kind), scale[seed]) for seed in seeds]
            out[level][kind] = {m: tuple(np.mean([r[m] for r in runs], axis=0)) for m in METHODS}
            print(f"  {_level(level)} % {kind}: "
                  + ", ".join(f"{m} {v[0]:.2f}/{v[1]:.2f}" for m, v in out[level][kind].items()),
                  file=sys.stderr, flush=True)
    return out


def _cell(v) -> str:
    return f"{v[0]:.2f} / {v[1]:.2f}" + ("" if np.isnan(v[2]) else f" ({v[2]:.1f})")


def sim_table(sim) -> str:
    rows = []
    for level, kinds in sim.items():
        for kind, cells in kinds.items():
            rows.append([kind, _level(level)] + [_cell(cells[m]) for m in METHODS])
        mean = {m: tuple(np.mean([kinds[k][m] for k in kinds], axis=0)) for m in METHODS}
        rows.append([f"**all {len(kinds)}**", _level(level)] + [_cell(mean[m]) for m in METHODS])
    return markdown_table(["motion", "gyro scale %"] + list(METHODS), rows)


def broad(data: Path, numbers) -> dict:
    """``{trial name: ({"rms": , "bound": } fitted scale errors, {method: cells})}`` of the BROAD trials ``numbers``
    (None: all)."""
    from compass.io.broad import read_broad

    fitted = bb.broad_fitted(data)
    out = {}
    for path in sorted(data.glob("*.mat")):
        if numbers is not None and path.name[:2] not in numbers:
            continue
        trial = read_broad(path)
        values = bb.held_out(trial.name, fitted)
        scale = {"rms": values["gyro_scale_error"], "bound": bound_scale_error(values.get("fitted", (None, None)))}
        out[trial.name] = (scale, scored(trial, scale))
        print(f"  {trial.name} (scale error RMS {100 * scale['rms']:.2f} %, bound {100 * scale['bound']:.2f} %): "
              + ", ".join(f"{m} {v[0]:.2f}/{v[1]:.2f}" for m, v in out[trial.name][1].items()), file=sys.stderr, flush=True)
    return out


def broad_table(res) -> str:
    rows = [[name[:2], f"{100 * scale['rms']:.2f} / {100 * scale['bound']:.2f}"] + [_cell(cells[m]) for m in METHODS]
            for name, (scale, cells) in res.items()]
    geo = {m: tuple(np.exp(np.mean([np.log(c[m][:2]) for _, c in res.values()], axis=0))) + (np.nan,) for m in METHODS}
    rows.append(["**geo-mean**", ""] + [_cell(geo[m]) for m in METHODS])
    return markdown_table(["trial", "scale error % (RMS / bound)"] + list(METHODS), rows)


def _seeds(text: str) -> list[int]:
    if "-" in text:
        lo, hi = text.split("-")
        return list(range(int(lo), int(hi) + 1))
    return [int(s) for s in text.split(",") if s]


def main(argv=None) -> int:
    global METHODS  # --methods: the columns of this run
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dev-seeds", default="11,12", help="the seeds the change was developed on")
    parser.add_argument("--seeds", default="13-20", help="seeds it was not developed on ('' for none)")
    parser.add_argument("--levels", default="0,1,3,5", help="gyro scale errors of the simulated boards, %%")
    parser.add_argument("--aniso", default="", help="z-axis-only gyro scale errors of the simulated boards, %%")
    parser.add_argument("--broad", default=",".join(LOCKOUT_TRIALS), help="BROAD trial numbers, 'all' or 'none'")
    parser.add_argument("--kinds", default="", help="comma-separated compass.sim.motion kinds (default: every one)")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated columns (default: every one)")
    parser.add_argument("--candidates", default="",
                        help="comma-separated bench_broad candidate names: a column each, on top of 'fitted'")
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "broad"))
    args = parse_args(parser, argv)
    unknown = set(args.methods.split(",")) - set(METHODS)
    if unknown:
        parser.error(f"--methods: unknown column(s) {', '.join(sorted(unknown))}; the columns: {', '.join(METHODS)}")
    METHODS = tuple(m for m in METHODS if m in args.methods.split(","))
    extra = [c for c in args.candidates.split(",") if c]
    unknown = [c for c in extra if c not in bb.CANDIDATES or bb.CANDIDATES[c][1:] != (True, False)
               or c in bb.FITTED_CANDIDATES]
    if unknown:
        parser.error(f"--candidates: unknown (or not a FilterConfig change) {unknown}")
    METHODS += tuple(extra)
    kinds = [k for k in args.kinds.split(",") if k]
    boards = (("", [float(v) for v in args.levels.split(",") if v]),
              ("_aniso", [f"z{float(v):g}" for v in args.aniso.split(",") if v]))
    for name, seeds in (("developed on", _seeds(args.dev_seeds)), ("not developed on", _seeds(args.seeds))):
        for suffix, levels in boards:
            if not (seeds and levels):
                continue
            print(f"simulated boards{' (z axis only)' if suffix else ''}, seeds {seeds[0]}-{seeds[-1]} ({name}): "
                  "heading / inclination RMS, deg (innovation refused, % of field samples)",
                  file=sys.stderr, flush=True)
            table = sim_table(simulated(seeds, levels, kinds))
            publish(args, "docs/benchmarks.md", f"bench_gyro_scale.{'dev' if 'not' not in name else 'heldout'}{suffix}",
                    table, caption=f"simulated boards{', the z axis alone off' if suffix else ''}, seeds "
                                   f"{', '.join(map(str, seeds))} ({name})")
    if args.broad != "none":
        res = broad(Path(args.data), None if args.broad == "all" else args.broad.split(","))
        publish(args, "docs/benchmarks.md", f"bench_gyro_scale.broad{'_all' if args.broad == 'all' else ''}",
                broad_table(res), caption="BROAD trials, the scale error from another trial's tumble file")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
