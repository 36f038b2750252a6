"""``compass live --calibrate tumble`` with and without the gyro in its recording, on simulated partial tumbles.

Run: ``python tools/bench_live_tumble.py [--seeds 4]`` (seeded; about 20 s a seed).

Each case is :func:`compass.sim.partial_tumble.simulate_partial_tumble` (a hand-held motion through 20 uT of
hard iron, 8 % soft iron and a 2 deg rotation to the housing, cut where the field's directions first cover
the case's share of the sphere; the gyro with a 0.5 deg/s bias, +-0.5 % scale errors and noise), sent as the
line protocol (``t_s,mx,my,mz,ax,ay,az,gx,gy,gz``, ten samples a chunk) to the live collector
(:class:`calibrate.tumble.collector.TumbleCollector`), whose recording ``compass calibrate``'s code then
calibrates (:func:`compass.commands.calibrate.calibrate_file`), as the command does.  ``with gyro``: the
recording as written; ``without``: the same recording less ``gx,gy,gz`` (what the command wrote before it
kept the gyro).  ``reset``: the module's clock restarts halfway (t_s from 0 again), with the gyro.  Score: the
heading error at runtime, the noise-free field of the whole (uncut) motion through the calibration, levelled
with the true attitude, against north (deg rms over every orientation), and the hard iron's error (% of |B|);
the calibration's kind, with "gyro" when the gyro-aided fit was used.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calibrate.tumble.collector import TumbleCollector  # noqa: E402
from compass.calibration import load  # noqa: E402
from compass.commands.calibrate import calibrate_file  # noqa: E402
from compass.io.lines import format_line  # noqa: E402
from compass.serial_reader import Chunk  # noqa: E402
from compass.sim.partial_tumble import simulate_partial_tumble  # noqa: E402

CASES = (("slow_rotation", 0.2), ("fast_rotation", 0.2), ("slow_rotation", 0.3), ("fast_rotation", 0.3))
"""(motion, share of the sphere covered when the recording ends)."""
VARIANTS = ("with gyro", "without", "reset")
_CHUNK = 10  # samples a chunk


def stream_lines(sim, reset_at: int | None = None) -> list[bytes]:
    """The simulated samples as line-protocol chunks, the module's clock starting again at sample ``reset_at``."""
    t_s = sim.t_s.copy()
    if reset_at is not None:
        t_s[reset_at:] -= t_s[reset_at]
    head = format_line(["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"])
    rows = [format_line([f"{t:.4f}", *(f"{v:.9g}" for v in (*m, *a, *g))])
            for t, m, a, g in zip(t_s, sim.mag, sim.accel, sim.gyro)]
    return [head + b"".join(rows[:_CHUNK])] + [b"".join(rows[k:k + _CHUNK]) for k in range(_CHUNK, len(rows), _CHUNK)]


def record(sim, folder: Path, name: str, reset_at: int | None = None) -> tuple[Path, list]:
    """The live collector's recording of the simulated stream, and its words."""
    collector, said = TumbleCollector(), []
    for k, chunk in enumerate(stream_lines(sim, reset_at)):
        said += collector.feed(Chunk(100.0 + 0.1 * k, chunk))
    said += collector.finish()
    return collector.write_recording(folder / f"{name}.tumble.csv"), said


def without_gyro(path: Path) -> Path:
    """The recording less its gyro columns."""
    lines = path.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    columns = lines[head].split(",")
    keep = [j for j, c in enumerate(columns) if c not in ("gx", "gy", "gz")]
    out = path.with_name(path.name.replace(".tumble.csv", "_nogyro.tumble.csv"))
    out.write_text("\n".join(lines[:head] + [",".join(line.split(",")[j] for j in keep) for line in lines[head:]])
                   + "\n")
    return out


def score(cal_path: Path, sim, whole) -> tuple[float, float, str]:
    """(runtime heading rms deg, hard iron error % |B|, kind) of a calibration against the truth."""
    cal = json.loads(cal_path.read_text())
    field, _ = load(cal_path).model.field(whole.mag)
    m_w = whole.attitude.apply(field)
    heading = np.degrees(np.arctan2(m_w[:, 1], m_w[:, 0]))
    rms = float(np.sqrt(np.mean((np.mod(heading + 180.0, 360.0) - 180.0) ** 2)))
    h_err = 100 * np.linalg.norm(np.array(cal["hard_iron"]) - sim.truth["hard_iron"]) / sim.truth["field_ut"]
    gyro = (cal["tumble"].get("gyro") or {}).get("used")
    return rms, float(h_err), cal["tumble"]["kind"] + (" gyro" if gyro else "")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4)
    seeds = range(parser.parse_args(argv).seeds)
    print(f"live --calibrate tumble on simulated partial tumbles (compass.sim.partial_tumble), seeds {list(seeds)}: "
          "runtime heading rms deg / hard iron error % |B| (mean over seeds); kinds")
    print(("{:<22}{:>7}" + "{:>36}" * len(VARIANTS)).format("case", "n", *VARIANTS))
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        folder = Path(tmp)
        for kind, coverage in CASES:
            scores, n = {v: [] for v in VARIANTS}, []
            for seed in seeds:
                sim = simulate_partial_tumble(kind, seed=seed, coverage=coverage)
                whole = simulate_partial_tumble(kind, seed=seed, coverage=None, noise_ut=0.0)
                n.append(len(sim.t_s))
                kept, _ = record(sim, folder, "gyro")
                reset, said = record(sim, folder, "reset", reset_at=len(sim.t_s) // 2)
                assert any("clock went back" in text for _, text in said), said
                for variant, rec in zip(VARIANTS, (kept, without_gyro(kept), reset)):
                    out = folder / f"{variant.replace(' ', '_')}.json"
                    with contextlib.redirect_stdout(io.StringIO()):  # its "wrote ..."
                        calibrate_file(rec, out, kind="tumble", force=True, quiet=True)
                    scores[variant].append(score(out, sim, whole))
            cells = []
            for variant in VARIANTS:
                rms, h_err = np.mean([s[:2] for s in scores[variant]], axis=0)
                kinds = sorted({s[2] for s in scores[variant]})
                cells.append(f"{rms:.2f} / {h_err:.2f} ({', '.join(kinds)})")
            print(("{:<22}{:>7}" + "{:>36}" * len(VARIANTS)).format(f"{kind} {100 * coverage:.0f} %",
                                                                  int(np.mean(n)), *cells))


if __name__ == "__main__":
    main()
