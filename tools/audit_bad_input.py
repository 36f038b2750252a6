"""Issue 22's bad-input list from a user's seat: what ``compass attitude --filter`` and ``compass live`` do with it.

Run: ``python tools/audit_bad_input.py [--out-dir DIR] [--path replay|per-row|live] [--baseline REF_OR_TREE]
[--said] [--case NAME]``.  A simulated module (:func:`compass.sim.device.simulate_device`, 30 s at 100 Hz, seed 5,
the scripted motion; a recording that starts moving from :func:`spinning`, one whose gyro saturates from
:func:`flick`) is written as a recording, then
spoiled one way per case (columns dropped, a gyro in deg/s, a first row of garbage, time stamps in ms, going back or
all equal, a NaN in the middle, an accelerometer in m/s^2, a gyro column of NaN, ...), some with the options a user
would give (``--accel-unit``, ``--gravity``).  Each case runs in a process with a timeout, through one path:
``replay`` (the default): ``compass attitude CAL REC --out ATT --filter``; ``per-row``: without ``--filter``
(``--level`` when there is no accelerometer); ``live``: ``compass live --port socket://... --cal CAL --out ATT``, a
local socket sending the recording's lines as the module would (``--duration`` ends it).  Printed per case: the exit
status, the lines said (stderr, and live's ``[warn]`` lines), whether a traceback shows, the output's rows with a
non-finite angle or quaternion (``-``: no output), the share of its rows whose accelerometer and field the filter
used, and the first line said (stderr first, else the first ``[warn]``; ``--said``: every line).
``--baseline REF_OR_TREE`` runs the same cases with another revision's ``compass`` (a git ref, exported; or a
checkout's folder) beside this one's.
"""

from __future__ import annotations

import argparse
import os
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _baseline import export_tree  # noqa: E402
from compass.calibration import model_to_dict, save  # noqa: E402
from compass.io.table import format_table  # noqa: E402
from compass.sim.device import default_model, simulate_device  # noqa: E402

HERE = Path(__file__).resolve().parents[1]
TIMEOUT_S = 120.0
LIVE_DURATION_S = 8.0  # compass live's --duration: the socket sends every line at once, 3000 take about a second
SOCKET_OPEN_S = 1.0  # the peer waits this long after the connection: pyserial's socket open drains what came before
ANGLES = ("heading_deg", "pitch_deg", "roll_deg", "qw", "qx", "qy", "qz")
RAIL_RAD_S = np.radians(250.0)  # the full scale of a low-cost MEMS gyro at its most sensitive range
STANDARD_GRAVITY = 9.80665  # m/s^2 per g


def spinning(t_s):
    """Already turning at the first row: 40 deg/s in heading, pitch and roll swinging (degrees; no magnet)."""
    return 40.0 * t_s, 20.0 * np.sin(2.0 * t_s), 25.0 * np.cos(1.3 * t_s), np.zeros(len(t_s), dtype=bool)


def flick(t_s):
    """Still, rocking gently, then flicked 90 deg in heading in 0.25 s at 10 s and back at 20 s (a half cosine: 565
    deg/s at its peak, beyond a 250 deg/s gyro's range for 0.18 s); degrees, no magnet."""
    t = np.asarray(t_s, dtype=float)
    turn = sum(sign * 0.5 * (1.0 - np.cos(np.pi * np.clip((t - t0) / 0.25, 0.0, 1.0)))
               for t0, sign in ((10, 1), (20, -1)))
    return 30.0 + 90.0 * turn, 10.0 * np.sin(2 * np.pi * t / 7), 8.0 * np.sin(2 * np.pi * t / 5), np.zeros(len(t))


def recording_text(model, t_s, samples, *, gyro=True, accel=True, gyro_scale=1.0, accel_scale=1.0, names=None) -> str:
    """The module's samples as a recording CSV; ``names`` renames header cells (``{"gx": "Gyroscope X (deg/s)"}``)."""
    columns = {"t_s": t_s} | {c: samples.raw[:, k] for k, c in enumerate(model.channels)}
    if accel:
        columns |= {c: accel_scale * samples.accel[:, k] for k, c in enumerate(("ax", "ay", "az"))}
    if gyro:
        columns |= {c: gyro_scale * samples.gyro[:, k] for k, c in enumerate(("gx", "gy", "gz"))}
    header, body = format_table(columns, {}, {c: "%.9g" for c in columns}).split("\n", 1)
    cells = [(names or {}).get(c, c) for c in header.split(",")]
    return ",".join(cells) + "\n" + body


def _cell(lines: list, row: int, column: str, value: str) -> list:
    """``lines`` with one cell replaced (``row`` 1 is the first data row)."""
    out = list(lines)
    cells = out[row].split(",")
    cells[out[0].split(",").index(column)] = value
    out[row] = ",".join(cells)
    return out


def _column(lines: list, column: str, values) -> list:
    """``lines`` with every data row's ``column`` replaced by ``values`` (text cells kept as they are)."""
    out = list(lines)
    for row, value in enumerate(values, start=1):
        out = _cell(out, row, column, value if isinstance(value, str) else repr(float(value)))
    return out


def cases(model) -> dict:
    """Case name -> (the recording's text, bytes for a binary file; the options a user would give)."""
    t = np.arange(0.0, 30.0, 0.01)
    s = simulate_device(model, t, seed=5, gyro_bias=[0.004, -0.003, 0.002])
    moving = simulate_device(model, t[:1200], motion=spinning, seed=2, gyro_bias=[0.0, 0.0, 0.0])
    flicked = simulate_device(model, t, motion=flick, seed=3, gyro_bias=[0.004, -0.003, 0.002])
    clipped = replace(flicked, gyro=np.clip(flicked.gyro, -RAIL_RAD_S, RAIL_RAD_S))
    good = recording_text(model, t, s)
    lines = good.splitlines()
    xio = {f"g{a}": f"Gyroscope {a.upper()} (deg/s)" for a in "xyz"}
    m_s2 = recording_text(model, t, s, accel_scale=STANDARD_GRAVITY)

    def join(rows):
        return "\n".join(rows) + "\n"

    texts = {
        "good": good,
        "no gyro": recording_text(model, t, s, gyro=False),
        "no accelerometer": recording_text(model, t, s, accel=False),
        "gyro in deg/s": recording_text(model, t, s, gyro_scale=np.degrees(1.0)),
        "gyro in deg/s, header says so": recording_text(model, t, s, gyro_scale=np.degrees(1.0), names=xio),
        "gyro in rad/s, header says deg/s": recording_text(model, t, s, names=xio),
        "dead gyro (zeros)": recording_text(model, t, s, gyro_scale=0.0),
        "gyro stuck at a rail": join(_column(_column(_column(lines, "gx", np.full(len(t), RAIL_RAD_S)), "gy",
                                                     np.full(len(t), RAIL_RAD_S)), "gz", np.full(len(t), -RAIL_RAD_S))),
        "gyro saturating in a flick": recording_text(model, t, clipped),
        "gyro in a flick (not saturating)": recording_text(model, t, flicked),
        "gyro column all NaN": join(_column(lines, "gx", ["nan"] * len(t))),
        "gyro all NaN": join(_column(_column(_column(lines, "gx", ["nan"] * len(t)), "gy", ["nan"] * len(t)), "gz",
                                     ["nan"] * len(t))),
        "first row 1e300": join(_cell(lines, 1, "mx", "1e300")),
        "first row NaN": join(_cell(lines, 1, "ax", "nan")),
        "first row text": join(_cell(lines, 1, "t_s", "garbage")),
        "first row truncated": join([lines[0], ",".join(lines[1].split(",")[:4])] + lines[2:]),
        "first row 1e9 (finite)": join(_cell(lines, 1, "my", "1e9")),
        "starts moving": recording_text(model, t[:1200], moving),
        "cut 5 s in (turning)": join([lines[0]] + lines[501:]),
        "empty file": "",
        "header only": lines[0] + "\n",
        "one row": join(lines[:2]),
        "five rows": join(lines[:6]),
        "duplicated t_s": join(_cell(lines, 101, "t_s", lines[100].split(",")[0])),
        "t_s all equal": join(_column(lines, "t_s", np.zeros(len(t)))),
        "t_s going back": join(_cell(lines, 101, "t_s", "0.5")),
        "t_s restarting mid-file": join(_column(lines, "t_s", np.where(t < 15.0, t, t - 15.0))),
        "t_s in ms": join(_column(lines, "t_s", 1e3 * t)),
        "1 Hz log": join([lines[0]] + lines[1::100]),
        "NaN in the middle": join(_cell(lines, 1500, "my", "nan")),
        "inf in the middle": join(_cell(lines, 1500, "gz", "inf")),
        "text row in the middle": join(lines[:1500] + ["reset"] + lines[1500:]),
        "blank line in the middle": join(lines[:1500] + [""] + lines[1500:]),
        "unknown unit name (gx (deg/s))": recording_text(model, t, s, names={f"g{a}": f"g{a} (deg/s)" for a in "xyz"}),
        "mx (mT): channel renamed": recording_text(model, t, s, names={"mx": "mx (mT)"}),
        "dead accelerometer axis (az = 0)": join(_column(lines, "az", np.zeros(len(t)))),
        "accel in m/s^2": m_s2,
        "binary file": bytes(range(256)) * 10,
    }
    named = {  # a case with the options a user would give: (the text of the case named, options)
        "gyro in deg/s, --gyro-unit deg/s": ("gyro in deg/s", ("--gyro-unit", "deg/s")),
        "accel in m/s^2, --accel-unit m/s2": ("accel in m/s^2", ("--accel-unit", "m/s2")),
        "accel in m/s^2, --accel-unit m/s2 --gravity 1": ("accel in m/s^2", ("--accel-unit", "m/s2", "--gravity", "1")),
        "accel in m/s^2, --accel-unit m/s2 --gravity 9.80665": ("accel in m/s^2",
                                                                ("--accel-unit", "m/s2", "--gravity", "9.80665")),
        "accel in m/s^2, --gravity 9.80665": ("accel in m/s^2", ("--gravity", "9.80665")),
        "accel in g, --accel-unit m/s2": ("good", ("--accel-unit", "m/s2")),
    }
    return {name: (text, ()) for name, text in texts.items()} | {name: (texts[of], options)
                                                                 for name, (of, options) in named.items()}


def _environment(tree: Path) -> dict:
    return os.environ | {"PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def run_attitude(tree: Path, cal: Path, rec: Path, out: Path, args: list) -> tuple:
    """``compass attitude`` with ``tree``'s package: (exit, lines said, traceback, :func:`_non_finite`)."""
    out.unlink(missing_ok=True)
    proc = subprocess.run([sys.executable, "-m", "compass", "attitude", str(cal), str(rec), "--out", str(out), *args],
                          capture_output=True, text=True, timeout=TIMEOUT_S, env=_environment(tree),
                          cwd=rec.parent)  # not ours first
    lines = [line for line in proc.stderr.replace("\r", "\n").splitlines() if line.strip()
             and not line.startswith("replaying")]  # the progress line
    return proc.returncode, lines, "Traceback" in proc.stderr, _non_finite(out)


def _serve(data: bytes) -> tuple:
    """A local socket that sends ``data`` to its first peer and holds the line until the peer leaves: (server, url)."""
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(TIMEOUT_S)

    def peer():
        try:
            conn, _ = server.accept()
        except OSError:
            return
        with conn:
            conn.settimeout(TIMEOUT_S)
            time.sleep(SOCKET_OPEN_S)
            try:
                conn.sendall(data)
                while conn.recv(4096):
                    pass
            except OSError:
                pass  # the reader left

    threading.Thread(target=peer, daemon=True).start()
    return server, f"socket://127.0.0.1:{server.getsockname()[1]}"


def run_live(tree: Path, cal: Path, rec: Path, out: Path, args: list) -> tuple:
    """``compass live`` on a socket sending ``rec``'s lines: as :func:`run_attitude` (lines said: stderr and the
    distinct ``[warn]`` lines on stdout)."""
    out.unlink(missing_ok=True)
    server, url = _serve(rec.read_bytes())
    try:
        proc = subprocess.run([sys.executable, "-m", "compass", "live", "--port", url, "--cal", str(cal), "--out",
                               str(out), "--duration", str(LIVE_DURATION_S), *args], capture_output=True, text=True,
                              timeout=TIMEOUT_S, env=_environment(tree), cwd=rec.parent)
    finally:
        server.close()
    warned = list(dict.fromkeys(line for line in proc.stdout.splitlines() if line.startswith("[warn]")))
    said = [line for line in proc.stderr.splitlines() if line.strip()] + warned
    return proc.returncode, said, "Traceback" in proc.stderr, _non_finite(out)


def _non_finite(path: Path) -> str:
    """Rows of the attitude CSV with a non-finite angle or quaternion, as ``k/n``, and the share of rows whose
    accelerometer and field the filter used (``accel_used``, ``mag_used``; "-" without an output)."""
    if not path.exists():
        return "- | -"
    rows = [line.split(",") for line in path.read_text().splitlines() if not line.startswith("#")]
    if len(rows) < 2:
        return "0/0 | -"
    used = [k for k, name in enumerate(rows[0]) if name in ANGLES]
    values = np.array([[float(row[k]) for k in used] for row in rows[1:]])
    shares = "/".join(f"{100 * np.mean([float(row[rows[0].index(c)]) for row in rows[1:]]):.0f}"
                      if c in rows[0] else "-" for c in ("accel_used", "mag_used"))  # the per-row path has neither
    return f"{int(np.sum(~np.all(np.isfinite(values), axis=1)))}/{len(values)} | {shares}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out-dir", type=Path, help="where the cases are written (default: a temporary folder)")
    parser.add_argument("--path", choices=("replay", "per-row", "live"), default="replay",
                        help="compass attitude --filter (default), compass attitude per row, or compass live")
    parser.add_argument("--case", action="append", help="run only this case (repeatable; default every case)")
    parser.add_argument("--said", action="store_true", help="print every line said under its case")
    parser.add_argument("--baseline", metavar="REF_OR_TREE",
                        help="another revision (a git ref, exported) or checkout (a folder) run beside this one")
    args = parser.parse_args()
    folder = args.out_dir or Path(tempfile.mkdtemp(prefix="bad_input_"))
    folder.mkdir(parents=True, exist_ok=True)
    model = default_model()
    cal = folder / "cal.json"
    save(cal, model_to_dict(model), force=True)
    base = None
    if args.baseline:
        base = Path(args.baseline) if Path(args.baseline).is_dir() else export_tree(args.baseline, folder)
    trees = ([("base", base)] if base is not None else []) + [("this", HERE)]
    command = {"replay": "compass attitude --filter", "per-row": "compass attitude (per row)",
               "live": f"compass live (a socket, --duration {LIVE_DURATION_S:g})"}[args.path]
    print(f"{command}; cases in {folder}")
    print("case | tree | exit | lines said | traceback | non-finite rows | accel/field used % | first line said")
    for name, (text, options) in cases(model).items():
        if args.case and name not in args.case:
            continue
        rec = folder / (re.sub(r"\W+", "_", name).strip("_") + ".csv")
        rec.write_bytes(text) if isinstance(text, bytes) else rec.write_text(text)
        extra = {"replay": ["--filter"], "live": []}.get(args.path, ["--level"] if name == "no accelerometer" else [])
        run = run_live if args.path == "live" else run_attitude
        for label, tree in trees:
            code, said, traceback, bad = run(tree, cal, rec, folder / "att.csv", extra + list(options))
            said = [line.replace(str(folder) + os.sep, "") for line in said]
            print(f"{name} | {label} | {code} | {len(said)} | {'yes' if traceback else 'no'} | {bad} | "
                  f"{said[0][:400] if said else ''}", flush=True)
            for line in said[1:] if args.said else ():
                print(f"    {line[:300]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
