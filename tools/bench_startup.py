"""Benchmark of the command line's start-up: ``compass --help`` and the time to each command's first line.

Every measurement is a fresh ``python -m compass ...`` process (what a user waits for), repeated
``--repeats`` times; the median and the minimum are printed (the machine is shared: the minimum is
the cost, the median what one waits).  With ``--baseline REF`` (default ``main``) the same
commands run on that git revision too (``git archive`` into a temporary folder, put first on
``PYTHONPATH``), in the same run, so the two columns are comparable.

- ``help``: ``compass --help`` and ``compass CMD --help`` for every command (parser built);
- ``first line``: from the start of the process to its first line on stdout or stderr, for
  ``calibrate`` (a 1-degree four-flip, the fit's progress line), ``attitude``, ``simulate``,
  ``export``, ``live`` (on a simulated module, ``compass device --pty``) and the whole run of each;
- ``imports``: what ``python -X importtime`` charges each command's run-time imports (cumulative,
  this tree only), to show where the time goes.

Targets (issue 15.7): ``compass --help`` under 0.3 s; under 0.5 s to the first line of any command.

Usage: ``python tools/bench_startup.py [--quick] [--baseline REF|none] [--write-docs]``

``--write-docs`` writes the start-up table into docs/benchmarks.md (``tools/_doc_table.py``).
"""

from __future__ import annotations

import argparse
import selectors
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _baseline import export_tree, tree_env
from _doc_table import markdown_table, parse_args, publish

TIMEOUT_S = 120.0


def first_line_s(argv, env, cwd, *, timeout_s=TIMEOUT_S, stop_after_first=False) -> tuple[float, float, str]:
    """(seconds to the first output line, seconds to exit, the line) of one process; killed on timeout.

    Raises RuntimeError when a process that ran to its end failed, so a failing command is never
    timed as a fast one (a process stopped after its first line is judged by that line).
    """
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env, cwd=cwd)
    first, line = float("nan"), ""
    try:
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)
        if sel.select(timeout_s):
            line = proc.stdout.readline().decode(errors="replace").strip()
            first = time.perf_counter() - t0
        if stop_after_first:
            proc.terminate()
        rest = proc.communicate(timeout=timeout_s)[0].decode(errors="replace")
        if proc.returncode != 0 and not stop_after_first:  # stopped by us: its summary may call it a failure
            raise RuntimeError(f"{' '.join(map(str, argv[2:]))}: exit {proc.returncode}: {line} {rest[-300:]}")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return first, time.perf_counter() - t0, line


def median_min(values):
    values = sorted(values)
    return values[len(values) // 2], values[0]


def prepare_inputs(work: Path, trees: list) -> dict:
    """{tree label: inputs}: a 1-degree four-flip recording, a tumble and a runtime one (shared), and
    each tree's own calibrations of them (the calibration file format moves between revisions)."""
    import json

    from compass.sim.fourflip import simulate_fourflip, write_fourflip
    from compass.sim.runtime import simulate_runtime, write_runtime
    from compass.sim.tumble import simulate_tumble, write_tumble

    session = simulate_fourflip(seed=3)
    write_fourflip(session, work / "bench.csv")
    write_runtime(simulate_runtime(json.loads(json.dumps(session.truth)), 1000, seed=1), work / "run.csv")
    write_tumble(simulate_tumble(seed=1, n=600), work / "tumble.csv")
    inputs = {}
    for label, tree in trees:
        tag = label.split()[0]
        for rec, cal, extra in (("bench.csv", f"cal_{tag}.json", ["--no-diagnose"]), ("tumble.csv", f"tumble_{tag}.json", [])):
            subprocess.run([sys.executable, "-m", "compass", "calibrate", rec, "--out", cal, "--quiet", *extra],
                           env=tree_env(tree), cwd=work, check=True, capture_output=True, timeout=TIMEOUT_S)
        inputs[label] = {"rec": "bench.csv", "cal": f"cal_{tag}.json", "run": "run.csv",
                         "tumble_cal": f"tumble_{tag}.json"}
    return inputs


def start_device(work: Path, env: dict):
    """``compass device --pty`` on the current tree; returns (process, port path)."""
    link = work / "pty0"
    proc = subprocess.Popen([sys.executable, "-m", "compass", "device", "--pty", "--link", str(link),
                             "--rate", "100"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env, cwd=work)
    deadline = time.monotonic() + 60
    while not link.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    return proc, link


def commands(inputs: dict, work: Path, n: str):
    """(name, argv after 'python -m compass', stop after the first line) for every first-line case."""
    return [
        ("calibrate fourflip 1 deg", ["calibrate", inputs["rec"], "--out", str(work / f"o{n}.json")], False),
        ("attitude 1000 rows", ["attitude", inputs["cal"], inputs["run"], "--out", str(work / f"a{n}.csv")], False),
        ("simulate fourflip", ["simulate", "fourflip", "--out", str(work / f"s{n}.csv")], False),
        ("export fusion", ["export", inputs["tumble_cal"], "--format", "fusion"], False),
        ("live (pty module)", ["live", "--port", str(work / "pty0"), "--cal", inputs["cal"], "--duration", "2"], True),
    ]


def measure(trees: list, work: Path, inputs: dict, repeats: int) -> dict:
    """{tree label: {measurement: [seconds per repeat]}}, the trees interleaved run by run (the
    machine's load then weighs on both alike)."""
    py = [sys.executable, "-m", "compass"]
    out: dict[str, dict] = {label: {} for label, _ in trees}
    helps = [["--help"]] + [[c, "--help"] for c in ("calibrate", "attitude", "simulate", "live", "device", "export",
                                                     "evaluate", "demo")]
    device, _ = start_device(work, tree_env(None, PYTHONDONTWRITEBYTECODE="1"))
    try:
        for r in range(repeats):
            for label, tree in trees:
                env, res = tree_env(tree, PYTHONDONTWRITEBYTECODE="1"), out[label]
                for argv in helps:
                    _, total, _ = first_line_s(py + argv, env, work)
                    res.setdefault("help: compass " + " ".join(argv), []).append(total)
                for name, argv, stop in commands(inputs[label], work, f"{label.split()[0]}{r}"):
                    first, total, line = first_line_s(py + argv, env, work, stop_after_first=stop)
                    res.setdefault(f"first line: {name}", []).append(first)
                    if not stop:
                        res.setdefault(f"whole run: {name}", []).append(total)
                    if r == 0:
                        print(f"  {label}: {name}: first line {line[:90]!r}", flush=True)
    finally:
        device.terminate()
        try:
            device.wait(timeout=10)
        except subprocess.TimeoutExpired:
            device.kill()
            device.wait()
    return out


def import_costs(tree: Path | None, work: Path) -> list[tuple[str, float]]:
    """Cumulative import time (s) of each command module's run-time imports (``-X importtime``)."""
    targets = {"parser (compass.cli.build_parser)": "import compass.cli as c; c.build_parser()",
               "calibrate (the fits)": "import calibrate",
               "scipy.stats": "import scipy.stats",
               "live (filter, live, serial)": "import compass.filter, compass.live, compass.serial_reader",
               "attitude (model, attitude)": "import compass.model, compass.attitude"}
    rows = []
    for name, code in targets.items():
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], env=tree_env(tree, PYTHONDONTWRITEBYTECODE="1"), cwd=work, check=True, capture_output=True,
                       timeout=TIMEOUT_S)
        rows.append((name, time.perf_counter() - t0))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="3 repeats instead of 7")
    parser.add_argument("--baseline", default="main", help="git revision to compare with ('none' to skip)")
    args = parse_args(parser, argv)
    repeats = 3 if args.quick else 7
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        trees = [("this tree", None)]
        if args.baseline != "none":
            trees.insert(0, (f"baseline {args.baseline}", export_tree(args.baseline, work)))
        inputs = prepare_inputs(work, trees)
        results = measure(trees, work, inputs, repeats)
        imports = {label: import_costs(tree, work) for label, tree in trees}
    labels = [label for label, _ in trees]
    print(f"\nstart-up, seconds, median / min of {repeats} (targets: --help < 0.3, first line < 0.5)")
    print(f"{'measurement':<44}" + "".join(f"{label:>24}" for label in labels))
    table = []
    for key in results[labels[-1]]:
        cells = []
        for label in labels:
            values = results[label].get(key)
            cells.append("-" if not values else "%.3f / %.3f" % median_min(values))
        print(f"{key:<44}" + "".join(f"{c:>24}" for c in cells))
        table.append([key, *cells])
    print("\nimport cost (one process each, seconds, includes ~0.03 s of interpreter start)")
    for i, (name, _) in enumerate(imports[labels[-1]]):
        print(f"{name:<44}" + "".join(f"{imports[label][i][1]:>24.3f}" for label in labels))
    publish(args, "docs/benchmarks.md", "bench_startup", markdown_table(["measurement", *labels], table), echo=False,
            caption=f"seconds, median / minimum of {repeats} fresh processes (the machine is shared: the minimum "
                    "is the cost); targets: --help under 0.3 s, first line under 0.5 s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
