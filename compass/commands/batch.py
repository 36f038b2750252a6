"""``compass batch RECORDINGS... --spec SPEC.toml --out DIR``: calibrate, judge, store, report.

A thin adapter: the batch is :func:`calibrate.batch.run_batch`, the spec
:mod:`compass.production.spec`, the store :mod:`compass.production.store`, the report
:mod:`compass.production.report`.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..limits import Range


def register(sub) -> None:
    p = sub.add_parser("batch", help="calibrate many recordings, judge each against an acceptance spec, "
                                     "store every verdict, write a fleet report")
    p.add_argument("recordings", nargs="+", metavar="RECORDING",
                   help="recordings of any kind (a folder: its *.csv); the module id is the '# module_id:' "
                        "metadata, else the file name")
    p.add_argument("--spec", default=None, metavar="SPEC.toml",
                   help="acceptance spec (default: the shipped compass/production/default_acceptance.toml)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for report.html and figures.csv")
    p.add_argument("--store", default=None, metavar="PATH",
                   help="calibration store (SQLite; default DIR/calibrations.sqlite); a re-run skips the "
                        "sessions it holds for this compass version and spec")
    p.add_argument("--workers", type=Range(0, 1024, integer=True).option("--workers"), default=None, metavar="N",
                   help="worker processes (default: the CPU count; 0: one after another in this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDR",
                   help="run on a Dask cluster (tcp://host:8786); needs compass-toolkit[dask]")
    p.add_argument("--dask", action="store_true",
                   help="run on a local Dask cluster of --workers processes instead of a process pool")
    p.add_argument("--force", action="store_true", help="overwrite DIR/report.html and DIR/figures.csv")
    p.set_defaults(func=run)


def _recordings(args) -> list[Path]:
    from ..cli import BadInput

    paths = []
    for name in args.recordings:
        p = Path(name)
        if p.is_dir():
            found = sorted(q for q in p.glob("*.csv") if ".truth" not in q.suffixes)
            if not found:
                raise BadInput(f"{p}: a folder with no *.csv recording")
            paths += found
        elif p.is_file():
            paths.append(p)
        else:
            raise BadInput(f"{p}: no such recording")
    return paths


def run(args) -> int:
    from calibrate.batch import run_batch

    from ..cli import BadInput, version
    from ..io.atomic import check_writable
    from ..production.report import write_report
    from ..production.spec import SpecError, load_spec
    from ..production.store import SessionTimeError, Store, StoreError, module_outcomes

    if args.scheduler is not None and args.workers is not None:
        raise BadInput("--scheduler runs on that cluster's workers: leave out --workers")
    try:
        spec = load_spec(args.spec)
    except SpecError as exc:
        raise BadInput(str(exc)) from None
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise BadInput(f"--out {out}: is a file, expected a folder")
    for name in ("report.html", "figures.csv"):
        try:
            check_writable(out / name, args.force)
        except FileExistsError:
            raise BadInput(f"{out / name} exists (an earlier batch's report: a re-run resumes the batch, skipping what "
                           f"the store has, and writes the report anew with --force; or give another --out)") from None
    paths = _recordings(args)
    out.mkdir(parents=True, exist_ok=True)
    store_path = Path(args.store) if args.store else out / "calibrations.sqlite"
    toolkit = version()
    try:
        store = Store(store_path)
    except StoreError as exc:
        raise BadInput(str(exc)) from None
    with store:
        try:
            summary = run_batch(paths, spec, store, toolkit_version=toolkit, workers=args.workers,
                                scheduler=args.scheduler, dask=args.dask,
                                progress=lambda line: print(line, file=sys.stderr, flush=True))
        except SessionTimeError as exc:
            raise BadInput(str(exc)) from None
        rows = [r for r in store.sessions(hashes=summary.hashes)
                if r.toolkit_version == toolkit and r.spec_sha256 == spec.sha256]
        rivals = store.rivals(rows)
    html_path, csv_path, controls = write_report(out, rows, spec, spec_source=args.spec or "default",
                                                 toolkit_version=toolkit, rivals=rivals)
    c = summary.counts
    print(f"{summary.total} recordings: {sum(c.values())} calibrated now ({c['accepted']} accepted, "
          f"{c['rejected']} rejected, {c['refused']} refused) in {summary.seconds:.1f} s, "
          f"{summary.skipped} already stored")
    modules = module_outcomes(rows, rivals)
    accepted = sum(m.status == "accepted" for m in modules)
    print(f"yield {accepted}/{len(modules)} modules ({100.0 * accepted / max(len(modules), 1):.1f} %; "
          f"{len(rows)} sessions)")
    for (module_id, session_time), shared in summary.duplicates.items():
        print(f"duplicate module id {module_id}: {len(shared)} different recordings claim its session at "
              f"{session_time}: {', '.join(shared)}: none accepted, export --module {module_id} refuses it")
    for control in controls:
        row = control.alarm_row
        if row is not None:
            print(f"drift: {control.figure} left its control limits at session {control.alarm_session} "
                  f"({row.module_id}, {row.session_time})")
    print(f"wrote {html_path}, {csv_path}; store {store_path}")
    return 0
