"""Benchmark of time and memory against recording size: a 50 MB recording of each kind.

For each kind (four-flip, tumble, 3-D platform, reference fields, attitude) a seeded simulated
recording of about ``--mb`` megabytes is written (the simulators' sessions, made longer: a finer
turntable step, more repeats per pose or field, a tumble path replayed with fresh noise; the
four-flip and platform sessions last an hour and carry ``t_s``), then
each step runs in its own child process, which reports its peak resident memory (``VmHWM``) as
it ends and is killed after ``--timeout`` seconds:

- ``np.loadtxt``: the file parsed by numpy alone (the reference the reader is held to: within 2x);
- ``read_table``: the toolkit's reader (this tree, and the baseline revision in the same run);
- the command: ``compass calibrate REC --out CAL --quiet`` (``compass attitude CAL REC --out ATT``
  for the attitude recording), this tree and the baseline.

Both trees' packages are compiled to bytecode first (``tools/_baseline.compile_tree``), so neither
tree's children compile their sources on every run (as an installed toolkit does not).  Each cell
gives the wall time, the CPU time (user + system, which a loaded machine inflates less) and the peak
memory.  Targets: the tumble under 10 s and 500 MB (issue 23.11), every other kind under a
minute and 1 GB (issue 16.7); the reader within 2x of ``np.loadtxt``'s memory (issue 15.7).  The
tumble's calibration of this tree is compared with the baseline's: the largest difference of each
parameter group in units of its sigma (the robust fits' thinning, ``calibrate.tumble.ellipsoid.ROBUST_ROWS``,
must leave it within a small fraction of a sigma).  With ``--profile`` the slowest command that ran
out of time is profiled in-process on a recording a tenth the size (cProfile, top functions by
cumulative time).  ``--write-docs`` writes the table (with the load average and the BLAS threads
of the run) into docs/benchmarks.md (``tools/_doc_table.py``).

Usage: ``python tools/bench_scale.py [--quick] [--mb 50] [--timeout 120] [--baseline REF|none] [--kinds ...]
[--write-docs]``
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


import numpy as np
from _baseline import ROOT, compile_tree, export_tree, tree_env
from _doc_table import markdown_table, parse_args, publish

KINDS = ("fourflip", "tumble", "platform3d", "reference", "attitude")
TARGETS = {"tumble": (10.0, 500.0)}
"""Kind -> (seconds, MB) its command must stay under (issue 23.11); the others :data:`DEFAULT_TARGET`."""
DEFAULT_TARGET = (60.0, 1024.0)
"""Every kind's command under a minute and 1 GB (issue 16.7)."""
_SESSION_S = 3600.0
"""Length of the four-flip and platform sessions, s: their recordings carry ``t_s``, as real ones do, so the
diagnosis examines the time effects (each sample its own time)."""


# ---- recordings --------------------------------------------------------------------------------

def _write(path: Path, columns, data: np.ndarray, fmt: str, metadata: dict) -> None:
    with open(path, "w") as f:
        for k, v in metadata.items():
            f.write(f"# {k}: {v}\n")
        np.savetxt(f, data, fmt=fmt, delimiter=",", header=",".join(columns), comments="")


def _header_lines(path: Path) -> int:
    """Lines up to and including the header (metadata comments, then the header)."""
    with open(path) as f:
        return next(i for i, line in enumerate(f, start=1) if not line.startswith("#"))


def _rows_for(mb: float, bytes_per_row: float) -> int:
    return max(int(mb * 1e6 / bytes_per_row), 100)


def make_recording(kind: str, folder: Path, mb: float) -> tuple[Path, int]:
    """A seeded recording of about ``mb`` MB; returns (path, rows)."""
    path = folder / f"{kind}.csv"
    rng = np.random.default_rng(1)
    if kind == "fourflip":
        from compass.sim.fourflip import simulate_fourflip

        rows = _rows_for(mb, 48.0)
        s = simulate_fourflip(seed=1, step_deg=4 * 360.0 / rows, sample_period_s=_SESSION_S / rows)
        data = np.column_stack([s.samples.t_s, s.samples.flip_deg, s.samples.platform_deg, s.outputs])
        _write(path, ["t_s", "flip_deg", "platform_deg", *s.channels], data, "%.4f", {"field_ut": 50})
    elif kind == "tumble":
        from compass.sim.tumble import simulate_tumble

        rows = _rows_for(mb, 70.0)
        base = simulate_tumble(seed=1, n=min(rows, 20000))
        reps = -(-rows // len(base.t_s))
        mag = np.tile(base.mag, (reps, 1))[:rows] + rng.normal(scale=0.3, size=(rows, 3))
        accel = np.tile(base.accel, (reps, 1))[:rows] + rng.normal(scale=0.005, size=(rows, 3))
        t_s = np.arange(rows) * (base.t_s[1] - base.t_s[0])
        _write(path, ["t_s", "mx", "my", "mz", "ax", "ay", "az"], np.column_stack([t_s, mag, accel]), "%.5f", {})
    elif kind == "platform3d":
        from compass.sim.platform3d import simulate_platform3d

        rows = _rows_for(mb, 92.0)
        s = simulate_platform3d(seed=1, repeats=max(rows // 144, 1), session_s=_SESSION_S)
        rows = len(s.mag)
        _write(path, ["platform_z_deg", "platform_y_deg", "platform_x_deg", "mx", "my", "mz", "ax", "ay", "t_s"],
               np.column_stack([s.angles_deg, s.mag, s.tilt, s.t_s]), "%.6f", {"field_ut": 50})
    elif kind == "reference":
        from compass.sim.reference import simulate_reference

        rows = _rows_for(mb, 90.0)
        s = simulate_reference(seed=1, n_sensors=1, n_fields=1000, repeats=max(rows // 1000, 1))
        rows = len(s.reference)
        _write(path, ["bx_ref", "by_ref", "bz_ref", "s1_x", "s1_y", "s1_z"],
               np.column_stack([s.reference, s.outputs["s1"]]), "%.6f", {})
    else:
        raise ValueError(kind)
    return path, rows


def make_attitude(folder: Path, mb: float, env: dict) -> tuple[Path, Path, int]:
    """A four-flip calibration (1-degree bench) and an attitude recording of its sensor."""
    from compass.sim.fourflip import simulate_fourflip, write_fourflip
    from compass.sim.runtime import simulate_runtime

    session = simulate_fourflip(seed=2)
    bench, _ = write_fourflip(session, folder / "bench.csv")
    cal = _calibrate(bench, folder / "bench.json", env)
    rows = _rows_for(mb, 66.0)
    run = simulate_runtime(session.truth, rows, seed=3)
    path = folder / "attitude.csv"
    _write(path, ["t_s", *run.channels, "ax", "ay", "az"], np.column_stack([run.t_s, run.outputs, run.accel]),
           "%.5f", {})
    return cal, path, rows


def _calibrate(bench: Path, cal: Path, env: dict) -> Path:
    subprocess.run([sys.executable, "-m", "compass", "calibrate", str(bench), "--out", str(cal), "--quiet"],
                   env=env, check=True, capture_output=True, timeout=600, cwd=tempfile.gettempdir())
    return cal


# ---- child processes ---------------------------------------------------------------------------

_HWM_WRAPPER = """
import os, runpy, sys
def report():
    with open('/proc/self/status') as f:
        hwm = next(line.split()[1] for line in f if line.startswith('VmHWM:'))
    with open(os.environ['BENCH_HWM_FILE'], 'w') as f:
        f.write(hwm)
mode, target, *sys.argv[1:] = sys.argv[1:]
code = 0
try:
    if mode == '-m':
        sys.argv[0] = target
        runpy.run_module(target, run_name='__main__', alter_sys=True)
    else:
        exec(compile(target, '<bench>', 'exec'), {'__name__': '__main__'})
except SystemExit as exc:
    code = exc.code
finally:
    report()
sys.exit(code)
"""


def run_child(argv, env, timeout_s: float) -> dict:
    """Run one Python process; its wall and CPU time, peak RSS (MB), exit status; killed at the timeout.

    ``argv`` is ``["-m", module, args...]`` or ``["-c", code]``.  The peak is the process's own
    ``VmHWM`` (read from ``/proc/self/status`` as it ends): ``ru_maxrss`` of a child would count the
    pages it shared with this (larger) process between fork and exec.
    """
    with tempfile.TemporaryFile() as log, tempfile.NamedTemporaryFile("r") as hwm:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", _HWM_WRAPPER, *argv], stdout=log, stderr=subprocess.STDOUT,
                                env=dict(env, BENCH_HWM_FILE=hwm.name), cwd=tempfile.gettempdir())
        polled_kb, killed = 0.0, False
        while proc.poll() is None:  # the high-water mark so far, for a process killed at the timeout
            polled_kb = max(polled_kb, _vm_hwm_kb(proc.pid))
            if time.perf_counter() - t0 > timeout_s:
                proc.kill()
                killed = True
                break
            time.sleep(0.2)
        code = proc.wait()
        seconds = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)  # children are waited for one at a time
        cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
        log.seek(0)
        tail = log.read().decode(errors="replace").strip().splitlines()[-1:] or [""]
        peak_kb = hwm.read().strip()
    return {"s": seconds, "cpu": cpu, "mb": (float(peak_kb) if peak_kb else polled_kb) / 1024.0, "code": code,
            "timeout": killed, "tail": tail[0]}


def _vm_hwm_kb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            return float(next(line.split()[1] for line in f if line.startswith("VmHWM:")))
    except (OSError, StopIteration):
        return 0.0


def fmt(r: dict | None) -> str:
    if r is None:
        return "-"
    if r["timeout"]:
        return f"> {r['s']:.0f} s (killed), >= {r['mb']:.0f} MB"
    if r["code"] != 0:
        return f"exit {r['code']} ({r['s']:.1f} s, {r['mb']:.0f} MB)"
    return f"{r['s']:.1f} s (cpu {r['cpu']:.1f} s), {r['mb']:.0f} MB"


def meets(kind: str, r: dict) -> str:
    """The kind's target and whether ``r`` met it, the time (wall and CPU) and the memory apart."""
    seconds, mb = TARGETS.get(kind, DEFAULT_TARGET)
    if r["code"] != 0 or r["timeout"]:
        return f"< {seconds:g} s, < {mb:g} MB: NOT met (did not finish)"
    say = {True: "met", False: "NOT met"}
    return (f"< {seconds:g} s: {say[r['s'] < seconds]} (wall), {say[r['cpu'] < seconds]} (CPU); "
            f"< {mb:g} MB: {say[r['mb'] < mb]}")


def tumble_agreement(this: Path, base: Path) -> str:
    """The largest difference between two tumble calibration files per parameter group, in this one's sigmas."""
    a, b = (json.loads(p.read_text()) for p in (this, base))
    ta, tb = a["tumble"], b["tumble"]
    groups = {"hard iron": (a["hard_iron"], b["hard_iron"], ta["hard_iron_sigma"]),
              "soft iron": (a["soft_iron"], b["soft_iron"], ta["soft_iron_sigma"]),
              "|B|": (a["field_norm"], b["field_norm"], ta["field_norm_sigma_recording_units"]),
              "mag_to_accel": (ta["misalignment_rotvec_deg"], tb["misalignment_rotvec_deg"],
                               ta["misalignment_rotvec_sigma_deg"]),
              "dip": (a["dip_deg"], b["dip_deg"], a["dip_sigma_deg"])}
    with np.errstate(invalid="ignore", divide="ignore"):  # an element fixed at zero has no sigma
        words = [f"{name} {np.nanmax(np.abs(np.subtract(x, y)) / np.asarray(sigma, float)):.3f}"
                 for name, (x, y, sigma) in groups.items() if None not in np.ravel([x, y, sigma]).tolist()]
    return (f"largest |this - baseline| / sigma: {', '.join(words)}; outliers {ta['n_outliers']} vs {tb['n_outliers']}; "
            f"effects {a['effects'] and [e['name'] for e in a['effects']]} vs {b['effects'] and [e['name'] for e in b['effects']]}")


def profile(kind: str, rec: Path, cal: Path | None, folder: Path) -> None:
    """cProfile of this tree's command on ``rec`` in-process; prints the top 15 by cumulative time."""
    import cProfile
    import pstats

    from compass.cli import main

    out = folder / f"profile_{kind}.out"
    argv = (["attitude", str(cal), str(rec), "--out", str(out), "--force"] if kind == "attitude"
            else ["calibrate", str(rec), "--out", str(out), "--quiet", "--force"])
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.runcall(main, argv)
    print(f"\nprofile of {kind} on {rec.stat().st_size / 1e6:.1f} MB ({time.perf_counter() - t0:.1f} s), "
          "top 15 by cumulative time:")
    pstats.Stats(prof).sort_stats("cumulative").print_stats(15)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="5 MB recordings, 60 s timeout")
    parser.add_argument("--mb", type=float, default=50.0, help="recording size, MB (default 50)")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds before a command is killed")
    parser.add_argument("--baseline", default="main", help="git revision to compare with ('none' to skip)")
    parser.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    parser.add_argument("--profile", action="store_true",
                        help="profile (in-process, a tenth the size) each kind whose command ran out of time or over 60 s")
    args = parse_args(parser)
    mb, timeout = (5.0, 60.0) if args.quick else (args.mb, args.timeout)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        trees = [("this tree", None)]
        compile_tree(ROOT)  # as the baseline's export is: neither tree's children compile their sources
        if args.baseline != "none":
            trees.append((f"baseline {args.baseline}", export_tree(args.baseline, folder)))
        for kind in args.kinds:
            t0 = time.perf_counter()
            cal = None
            if kind == "attitude":
                cal, rec, rows = make_attitude(folder, mb, tree_env(None))
            else:
                rec, rows = make_recording(kind, folder, mb)
            size = rec.stat().st_size / 1e6
            print(f"{kind}: {size:.1f} MB, {rows} rows (written in {time.perf_counter() - t0:.1f} s)", flush=True)
            row = {"size": size, "rows": rows}
            skip = _header_lines(rec)
            row["loadtxt"] = run_child(["-c", f"import numpy as np; np.loadtxt({str(rec)!r}, delimiter=',', "
                                              f"skiprows={skip}, ndmin=2)"], tree_env(None), timeout)
            for label, tree in trees:
                row[f"read {label}"] = run_child(["-c", f"from compass.io.table import read_table; "
                                                        f"read_table({str(rec)!r})"], tree_env(tree), timeout)
                out = folder / f"out_{kind}_{label.split()[0]}"
                if kind == "attitude" and tree is not None:  # each tree reads its own calibration file format
                    cal = _calibrate(folder / "bench.csv", out.with_suffix(".cal.json"), tree_env(tree))
                argv = (["-m", "compass", "attitude", str(cal), str(rec), "--out", str(out) + ".csv"]
                        if kind == "attitude" else
                        ["-m", "compass", "calibrate", str(rec), "--out", str(out) + ".json", "--quiet"])
                row[f"command {label}"] = run_child(argv, tree_env(tree), timeout)
                r = row[f"command {label}"]
                print(f"  {label}: read {fmt(row[f'read {label}'])}; command {fmt(r)}"
                      + (f"  [{r['tail'][:120]}]" if r["code"] != 0 and not r["timeout"] else ""), flush=True)
            if kind == "tumble" and len(trees) > 1 and all(row[f"command {lb}"]["code"] == 0 for lb, _ in trees):
                row["agreement"] = tumble_agreement(folder / "out_tumble_this.json", folder / "out_tumble_baseline.json")
                print(f"  tumble calibration, this tree against {trees[1][0]}: {row['agreement']}", flush=True)
            results[kind] = row
            if args.profile and (row["command this tree"]["timeout"] or row["command this tree"]["s"] > 60):
                small = folder / "small"
                small.mkdir(exist_ok=True)
                small_cal, small_rec, _ = (make_attitude(small, mb / 10, tree_env(None)) if kind == "attitude"
                                           else (None, *make_recording(kind, small, mb / 10)))
                profile(kind, small_rec, small_cal, folder)
    labels = [label for label, _ in trees]
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "OpenBLAS's default")
    caption = (f"~{mb:g} MB recordings, one child process per cell, peak RSS its VmHWM, killed after {timeout:g} s; "
               f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs, OPENBLAS_NUM_THREADS {threads}")
    print(f"\nscale: {caption}")
    print("targets: tumble command < 10 s and < 500 MB (issue 23.11), the others < 60 s and < 1024 MB; "
          "reader < 2x np.loadtxt's memory")
    head = ["kind", "MB", "rows", "np.loadtxt"] + [f"read_table ({lb})" for lb in labels] \
        + [f"command ({lb})" for lb in labels] + ["target (this tree)", "reader/loadtxt memory"]
    rows = []
    for kind, row in results.items():
        ratio = row["read this tree"]["mb"] / row["loadtxt"]["mb"] if row["loadtxt"]["mb"] else float("nan")
        rows.append([kind, f"{row['size']:.1f}", str(row["rows"]), fmt(row["loadtxt"])]
                    + [fmt(row[f"read {lb}"]) for lb in labels] + [fmt(row[f"command {lb}"]) for lb in labels]
                    + [meets(kind, row["command this tree"]), f"{ratio:.2f}"])
    agreement = [f"{kind} calibration, this tree against the baseline: {row['agreement']}"
                 for kind, row in results.items() if "agreement" in row]
    publish(args, "docs/benchmarks.md", "bench_scale",
            markdown_table(head, rows) + "".join(f"\n\n{line}" for line in agreement), caption=caption)
    return 0


if __name__ == "__main__":
    sys.exit(main())
