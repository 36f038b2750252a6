"""``compass store list|show``: the calibration store's sessions (:mod:`compass.production.store`)."""

from __future__ import annotations

import json


def register(sub) -> None:
    p = sub.add_parser("store", help="list or show the sessions of a calibration store (compass batch)")
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    ls = actions.add_parser("list", help="one line a session: time, module, verdict, first reason")
    ls.add_argument("--store", required=True, metavar="PATH", help="the store (SQLite)")
    ls.add_argument("--status", choices=("accepted", "rejected", "refused"), help="only sessions with this verdict")
    ls.set_defaults(func=run_list)
    show = actions.add_parser("show", help="every session of one module: verdict, reasons, figures")
    show.add_argument("module", metavar="ID", help="module id")
    show.add_argument("--store", required=True, metavar="PATH", help="the store (SQLite)")
    show.set_defaults(func=run_show)


def _open(path):
    from ..cli import BadInput
    from ..production.store import Store, StoreError

    try:
        return Store(path, create=False)
    except StoreError as exc:
        raise BadInput(str(exc)) from None


def run_list(args) -> int:
    with _open(args.store) as store:
        rows = [r for r in store.sessions() if args.status is None or r.status == args.status]
    for r in rows:
        why = f"  {r.reasons[0]}" if r.reasons else ""
        print(f"{r.session_time}  {r.module_id:<16} {r.status:<9} {r.kind or '-':<10}{why}")
    print(f"{len(rows)} session(s)")
    return 0


def run_show(args) -> int:
    from ..cli import BadInput

    with _open(args.store) as store:
        rows = store.sessions(module_id=args.module)
    if not rows:
        raise BadInput(f"{args.store}: no session of module '{args.module}'")
    for r in rows:
        print(f"module {r.module_id}, session {r.session_time}: {r.status} ({r.kind or 'not calibrated'})")
        print(f"  recording {r.recording_path} (sha256 {r.recording_sha256[:16]}), compass {r.toolkit_version}, "
              f"stored {r.stored_at}")
        for reason in r.reasons:
            print(f"  reason: {reason}")
        for note in r.notes:
            print(f"  note: {note}")
        figures = {k: v for k, v in r.figures.items() if v is not None}
        if figures:
            print("  figures: " + json.dumps(figures, default=str))
    return 0
