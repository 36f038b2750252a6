"""Production batch benchmark: verdicts against the truth, drift detection, throughput vs workers.

Simulates a line (``compass simulate fleet``: modules from one population, a few with named
defects, the bench's field drifting from a session on), runs ``compass batch``'s library path over it
with the default acceptance spec, and prints:

1. the confusion counts of the verdicts against the truth (should fail / should pass), with every
   wrong verdict and its reasons;
2. where each control chart first leaves its limits against where the drift starts (the delay, in
   sessions), and the alarms before the drift (false alarms);
3. the EWMA chart's operating characteristics on seeded normal noise: how often 250 in-control
   sessions raise a false alarm, and the median delay of a step or a ramp, for the default
   (lambda 0.2, L = 4, 50 baseline sessions) beside the textbook's L = 3 from 20 sessions;
4. throughput (sessions per second) of the serial loop in this process (the baseline), of the local
   process pool with 1 and 2 workers, and of a Dask ``LocalCluster`` with 1 and 2 workers when Dask
   is installed, on the same recordings, each into a fresh store (modules imported beforehand, so
   no executor pays the first imports: a forked pool inherits them, a Dask worker does not);
5. the store's write rate: sessions committed a second, one transaction each, with a real
   calibration's text (what bounds the one writing process, whatever the number of workers).

    python tools/bench_batch.py [--n 300] [--seed 0] [--throughput-n 24] [--write docs/production_bench.md]

Seeded; the machine's load average is printed beside the timings (they are wall-clock times).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")


def _run(paths, spec, store_path, **executor):
    from calibrate.batch import run_batch
    from compass.production.store import Store

    with Store(store_path) as store:
        start = time.perf_counter()
        summary = run_batch(paths, spec, store, toolkit_version="bench", **executor)
        wall = time.perf_counter() - start
        rows = store.sessions(hashes=summary.hashes)
    return summary, rows, wall


def accuracy(fleet: Path, truth: dict, spec, folder: Path, workers: int) -> list[str]:
    from compass.production.report import control_results

    modules = {m["module_id"]: m for m in truth["modules"]}
    paths = [fleet / m["file"] for m in truth["modules"]]
    _, rows, wall = _run(paths, spec, folder / "accuracy.sqlite", workers=workers)
    counts = {"fail_failed": 0, "fail_passed": 0, "pass_failed": 0, "pass_passed": 0}
    wrong = []
    for r in rows:
        m = modules[r.module_id]
        failed = r.status != "accepted"
        key = f"{'fail' if m['should_fail'] else 'pass'}_{'failed' if failed else 'passed'}"
        counts[key] += 1
        if failed != m["should_fail"]:
            wrong.append(f"  {r.module_id} (defect {m['defect']}): {r.status}: {'; '.join(r.reasons) or '-'}")
    by_defect: dict = {}
    for r in rows:
        d = modules[r.module_id]["defect"]
        if d is not None:
            caught = by_defect.setdefault(d, [0, 0])
            caught[0] += r.status != "accepted"
            caught[1] += 1
    lines = [f"## Verdicts against the truth ({len(rows)} sessions, default spec, {wall:.0f} s with {workers} workers)",
             "", "| truth \\ verdict | failed (rejected or refused) | accepted |", "|---|---|---|",
             f"| should fail | {counts['fail_failed']} | {counts['fail_passed']} |",
             f"| should pass | {counts['pass_failed']} | {counts['pass_passed']} |", "",
             "Defects caught: " + ", ".join(f"{d} {c}/{n}" for d, (c, n) in sorted(by_defect.items())) + "."]
    if wrong:
        lines += ["", "Wrong verdicts:", "", "```", *wrong, "```"]
    drift = truth["drift"]
    start_session = drift["start_session"] + 1  # 1-based session number, as the report counts
    lines += ["", f"## Drift detection (truth: {drift['figure']} moves {drift['deg_per_session']:g} deg a session "
                  f"from session {start_session})", "",
              "| chart | first alarm (session) | delay (sessions) | alarms before the drift |", "|---|---|---|---|"]
    for c in control_results(rows, spec):
        if c.chart is None:
            lines.append(f"| {c.figure} | no chart: {c.why} | | |")
            continue
        alarms = [c.positions[k] for k in range(len(c.rows)) if c.chart.out[k]]
        before = sum(1 for a in alarms if a < start_session)
        first = c.alarm_session
        delay = "-" if first is None or first < start_session else str(first - start_session)
        lines.append(f"| {c.figure} | {first if first is not None else 'none'} | {delay} | {before} |")
    return lines


def ewma_characteristics(seed: int, runs: int = 300) -> list[str]:
    import numpy as np

    from compass.production.control import ewma_chart

    rng = np.random.default_rng(seed)
    shifts = {"step 1 sigma": lambda t: 1.0 + 0 * t, "step 2 sigma": lambda t: 2.0 + 0 * t,
              "ramp 0.1 sigma/session": lambda t: 0.1 * t, "ramp 0.5 sigma/session": lambda t: 0.5 * t}
    lines = [f"## EWMA operating characteristics (normal noise, {runs} seeded runs each, lambda 0.2, clip 3 sigma)",
             "", "| limits | baseline | P(false alarm in 250 in-control sessions) | "
             + " | ".join(f"median delay, {k}" for k in shifts) + " |", "|---|---|---|" + "---|" * len(shifts)]
    for width, baseline in ((3.0, 20), (4.0, 50)):
        false = 0
        delays = {k: [] for k in shifts}
        for _ in range(runs):
            false += ewma_chart(rng.normal(size=baseline + 250), baseline=baseline, width_sigmas=width).first_alarm \
                is not None
            for name, shift in shifts.items():
                x = rng.normal(size=baseline + 100)
                x[baseline:] += shift(np.arange(100))
                first = ewma_chart(x, baseline=baseline, width_sigmas=width).first_alarm
                delays[name].append(np.inf if first is None or first < baseline else first - baseline)
        lines.append(f"| L = {width:g} | {baseline} | {false / runs:.2f} | "
                     + " | ".join(f"{np.median(v):g}" for v in delays.values()) + " |")
    return lines


def _warm_up(fleet: Path, truth: dict, spec) -> None:
    """Import and run everything once, untimed (the serial loop would otherwise pay the imports)."""
    from calibrate.batch import SessionJob, calibrate_session, sha256_of

    path = fleet / truth["modules"][0]["file"]
    calibrate_session(SessionJob(str(path), sha256_of(path), spec.site_dip_deg, spec.site_field_ut))


def throughput(fleet: Path, truth: dict, spec, folder: Path, n: int) -> list[str]:
    _warm_up(fleet, truth, spec)
    paths = [fleet / m["file"] for m in truth["modules"][:n]]
    configs = [("serial loop (baseline, this process)", {"workers": 0}),
               ("process pool, 1 worker", {"workers": 1}),
               ("process pool, 2 workers", {"workers": 2})]
    try:
        import dask.distributed  # noqa: F401

        configs += [("Dask LocalCluster, 1 worker", {"workers": 1, "dask": True}),
                    ("Dask LocalCluster, 2 workers", {"workers": 2, "dask": True})]
        dask_note = ""
    except ImportError:
        dask_note = " (Dask not installed: its rows are left out)"
    lines = [f"## Throughput ({n} sessions, wall clock; load average before: "
             f"{', '.join(f'{v:.1f}' for v in os.getloadavg())}, {os.cpu_count()} CPUs){dask_note}", "",
             "| executor | wall (s) | sessions/s | speed-up over serial |", "|---|---|---|---|"]
    serial = None
    for k, (name, executor) in enumerate(configs):
        _, rows, wall = _run(paths, spec, folder / f"throughput{k}.sqlite", **executor)
        if len(rows) != n:
            raise RuntimeError(f"{name}: stored {len(rows)} of {n} sessions")
        rate = n / wall
        serial = serial or rate
        lines.append(f"| {name} | {wall:.1f} | {rate:.2f} | {rate / serial:.2f} |")
        print(lines[-1], file=sys.stderr, flush=True)
    return lines


def store_rate(folder: Path, n: int = 300) -> list[str]:
    from compass.production.store import Store

    with Store(folder / "throughput0.sqlite", create=False) as done:
        row = done.sessions()[0]
    with Store(folder / "rate.sqlite") as store:
        start = time.perf_counter()
        for k in range(n):
            store.add(module_id=f"R{k}", session_time=row.session_time, recording_path=row.recording_path,
                      recording_sha256=f"{k:064x}", toolkit_version="bench", kind=row.kind, status=row.status,
                      reasons=row.reasons, notes=row.notes, figures=row.figures, calibration=row.calibration,
                      spec_text="", spec_sha256="")
        wall = time.perf_counter() - start
    return ["", f"## Store writes: {n} sessions, one transaction each ({len(row.calibration or '')} characters of "
                f"calibration a row): {wall:.2f} s, {n / wall:.0f} sessions/s (this machine's disk, shared)"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300, help="modules in the simulated line (default 300)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2, help="workers of the accuracy run (default 2)")
    parser.add_argument("--throughput-n", type=int, default=24, help="sessions timed per executor (default 24)")
    parser.add_argument("--write", metavar="PATH", help="also write the tables (markdown) to PATH")
    args = parser.parse_args(argv)

    from compass.production.spec import load_spec
    from compass.sim.fleet import FleetOptions, simulate_fleet

    spec = load_spec()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        fleet = folder / "fleet"
        start = time.perf_counter()
        truth = simulate_fleet(fleet, FleetOptions(n=args.n, seed=args.seed))
        print(f"simulated {args.n} sessions in {time.perf_counter() - start:.0f} s", file=sys.stderr, flush=True)
        lines = [f"# compass batch benchmark (tools/bench_batch.py --n {args.n} --seed {args.seed})", ""]
        lines += accuracy(fleet, truth, spec, folder, args.workers)
        lines += [""] + ewma_characteristics(args.seed)
        print("\n".join(lines), flush=True)
        more = [""] + throughput(fleet, truth, spec, folder, min(args.throughput_n, args.n))
        more += store_rate(folder)
        print("\n".join(more), flush=True)
    if args.write:
        Path(args.write).write_text("\n".join(lines + more) + "\n", encoding="utf-8")
        print(f"wrote {args.write}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
