"""Issue 22's bad-input list from a user's seat: what ``compass attitude`` does with a bad recording.

Run: ``python tools/audit_bad_input.py [--out-dir DIR] [--per-row] [--baseline TREE]``.  A simulated module
(:func:`compass.sim.device.simulate_device`, 30 s at 100 Hz, seed 5, the scripted motion; a recording that starts
moving from :data:`SPINNING`) is written as a recording, then spoiled one way per case (columns dropped, a gyro in
deg/s, a first row of garbage, time stamps in ms or all equal, a NaN in the middle, ...).  Each case runs
``compass attitude CAL REC --out ATT --filter`` (``--per-row``: without ``--filter``, ``--level`` when there is no
accelerometer) in a process with a timeout.  Printed per case: the exit status, the lines on stderr (``1`` for a
refusal in one line), whether a traceback shows, the output's rows with a non-finite angle or quaternion (``-``: no
output), and the first stderr line's words.  ``--baseline TREE`` runs the same cases with another checkout's
``compass`` (``PYTHONPATH=TREE``) beside this one's.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from compass.calibration import model_to_dict, save
from compass.io.table import format_table
from compass.sim.device import default_model, simulate_device

HERE = Path(__file__).resolve().parents[1]
TIMEOUT_S = 120.0
ANGLES = ("heading_deg", "pitch_deg", "roll_deg", "qw", "qx", "qy", "qz")


def spinning(t_s):
    """Already turning at the first row: 40 deg/s in heading, pitch and roll swinging (degrees; no magnet)."""
    return 40.0 * t_s, 20.0 * np.sin(2.0 * t_s), 25.0 * np.cos(1.3 * t_s), np.zeros(len(t_s), dtype=bool)


def recording_text(model, t_s, samples, *, gyro=True, accel=True, gyro_scale=1.0, names=None) -> str:
    """The module's samples as a recording CSV; ``names`` renames header cells (``{"gx": "Gyroscope X (deg/s)"}``)."""
    columns = {"t_s": t_s} | {c: samples.raw[:, k] for k, c in enumerate(model.channels)}
    if accel:
        columns |= {c: samples.accel[:, k] for k, c in enumerate(("ax", "ay", "az"))}
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
    """``lines`` with every data row's ``column`` replaced by ``values``."""
    out = list(lines)
    for row, value in enumerate(values, start=1):
        out = _cell(out, row, column, repr(float(value)))
    return out


def cases(model) -> dict:
    """Case name -> the recording's text (bytes for a binary file)."""
    t = np.arange(0.0, 30.0, 0.01)
    s = simulate_device(model, t, seed=5, gyro_bias=[0.004, -0.003, 0.002])
    moving = simulate_device(model, t[:1200], motion=spinning, seed=2, gyro_bias=[0.0, 0.0, 0.0])
    good = recording_text(model, t, s)
    lines = good.splitlines()
    xio = {f"g{a}": f"Gyroscope {a.upper()} (deg/s)" for a in "xyz"}

    def join(rows):
        return "\n".join(rows) + "\n"

    return {
        "good": good,
        "no gyro": recording_text(model, t, s, gyro=False),
        "no accelerometer": recording_text(model, t, s, accel=False),
        "gyro in deg/s": recording_text(model, t, s, gyro_scale=np.degrees(1.0)),
        "gyro in deg/s, header says so": recording_text(model, t, s, gyro_scale=np.degrees(1.0), names=xio),
        "gyro in rad/s, header says deg/s": recording_text(model, t, s, names=xio),
        "dead gyro (zeros)": recording_text(model, t, s, gyro_scale=0.0),
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
        "t_s in ms": join(_column(lines, "t_s", 1e3 * t)),
        "1 Hz log": join([lines[0]] + lines[1::100]),
        "NaN in the middle": join(_cell(lines, 1500, "my", "nan")),
        "inf in the middle": join(_cell(lines, 1500, "gz", "inf")),
        "text row in the middle": join(lines[:1500] + ["reset"] + lines[1500:]),
        "blank line in the middle": join(lines[:1500] + [""] + lines[1500:]),
        "unknown unit name (gx (deg/s))": recording_text(model, t, s, names={f"g{a}": f"g{a} (deg/s)" for a in "xyz"}),
        "mx (mT): channel renamed": recording_text(model, t, s, names={"mx": "mx (mT)"}),
        "dead accelerometer axis (az = 0)": join(_column(lines, "az", np.zeros(len(t)))),
        "binary file": bytes(range(256)) * 10,
    }


def run_case(tree: Path, cal: Path, rec: Path, out: Path, args: list) -> tuple:
    """``compass attitude`` with ``tree``'s package: (exit, stderr lines, traceback, non-finite rows, first line)."""
    out.unlink(missing_ok=True)
    env = os.environ | {"PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "compass", "attitude", str(cal), str(rec), "--out", str(out), *args],
                          capture_output=True, text=True, timeout=TIMEOUT_S, env=env, cwd=rec.parent)  # not ours first
    lines = [line for line in proc.stderr.replace("\r", "\n").splitlines() if line.strip()
             and not line.startswith("replaying")]  # the progress line
    return proc.returncode, len(lines), "Traceback" in proc.stderr, _non_finite(out), lines[0] if lines else ""


def _non_finite(path: Path) -> str:
    """Rows of the attitude CSV with a non-finite angle or quaternion, as ``k/n`` ("-" without an output)."""
    if not path.exists():
        return "-"
    rows = [line.split(",") for line in path.read_text().splitlines() if not line.startswith("#")]
    if len(rows) < 2:
        return "0/0"
    used = [k for k, name in enumerate(rows[0]) if name in ANGLES]
    values = np.array([[float(row[k]) for k in used] for row in rows[1:]])
    return f"{int(np.sum(~np.all(np.isfinite(values), axis=1)))}/{len(values)}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out-dir", type=Path, help="where the cases are written (default: a temporary folder)")
    parser.add_argument("--per-row", action="store_true", help="compass attitude without --filter")
    parser.add_argument("--baseline", type=Path, metavar="TREE", help="another checkout run beside this one")
    args = parser.parse_args()
    folder = args.out_dir or Path(tempfile.mkdtemp(prefix="bad_input_"))
    folder.mkdir(parents=True, exist_ok=True)
    model = default_model()
    cal = folder / "cal.json"
    save(cal, model_to_dict(model), force=True)
    trees = ([("base", args.baseline)] if args.baseline else []) + [("this", HERE)]
    print(f"compass attitude {'(per row)' if args.per_row else '--filter'}; cases in {folder}")
    print("case | tree | exit | stderr lines | traceback | non-finite rows | first stderr line")
    for name, text in cases(model).items():
        rec = folder / (re.sub(r"\W+", "_", name).strip("_") + ".csv")
        rec.write_bytes(text) if isinstance(text, bytes) else rec.write_text(text)
        extra = ["--filter"] if not args.per_row else ["--level"] if name == "no accelerometer" else []
        for label, tree in trees:
            code, n, traceback, bad, first = run_case(tree, cal, rec, folder / "att.csv", extra)
            print(f"{name} | {label} | {code} | {n} | {'yes' if traceback else 'no'} | {bad} | "
                  f"{first.replace(str(folder) + os.sep, '')[:200]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
