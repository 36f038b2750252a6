"""What the field's unit checks say of honest streams and of streams read in a wrong unit or with another board's
calibration: before (the rule at 03c7b4c: the median ``|W(m - h)| / |B|`` of the first 25 samples within 1.5 taken,
else a unit's factor bringing it within 1.25 named) and now (:func:`compass.io.streams.judge_field_unit`, then the
session's turn check, :attr:`compass.live.LiveSession.wrong_field`), side by side.

Simulated boards (``compass.sim.device.simulate_device``: a magnetometer in uT with 0.15 uT noise, |B| 50 uT, dip
60 deg, accelerometer, gyro) run 30 s at 100 Hz of the fake board's "turns" (heading at 20 deg/s, pitch 15 deg and
roll 10 deg sines) or a tumble, or lie still; the calibration is the board's own unless said.  BROAD's trials
(the first 60 s, the raw magnetometer as its own calibration: hard iron 0, |B| its median, noise 0.7 uT) must pass.

    python tools/bench_field_unit.py [--data ../shared/data/broad] [--write-docs]
"""

from __future__ import annotations

import argparse
import io
import math
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from _doc_table import markdown_table, parse_args, publish  # noqa: E402

from compass.io import units  # noqa: E402
from compass.io.streams import JUDGE_SAMPLES, field_scale_check, judge_field_unit, unit_pairs  # noqa: E402
from compass.live import LiveSession  # noqa: E402
from compass.model import SensorModel  # noqa: E402
from compass.replay import replay  # noqa: E402
from compass.response import LinearResponse  # noqa: E402
from compass.sim.device import simulate_device, tumble_motion  # noqa: E402

FACTORS = sorted({a / b for a in units.MAG_UNITS.values() for b in units.MAG_UNITS.values()} - {1.0})
HARD_IRON = np.array([18.0, -11.0, 32.0])  # the fake board's, 38.4 uT: 0.77 |B|


def turns(t):
    t = np.asarray(t, float)
    return (np.mod(30 + 20.0 * t, 360.0), 15.0 * np.sin(2 * np.pi * t / 7.0), 10.0 * np.sin(2 * np.pi * t / 5.0),
            np.zeros(t.shape))


def still(t):
    t = np.asarray(t, float)
    return np.full(t.shape, 30.0), np.zeros(t.shape), np.zeros(t.shape), np.zeros(t.shape)


def roll_north(t):
    """Rolled by +-25 deg facing magnetic North: near the magnetic equator the field lies along the roll's axis."""
    t = np.asarray(t, float)
    return np.zeros(t.shape), np.zeros(t.shape), 25.0 * np.sin(2 * np.pi * t / 6.0), np.zeros(t.shape)


def board(hard_iron=HARD_IRON, gain=1.0, field_norm=50.0, dip_deg=60.0):
    directions = Rotation.from_rotvec([0.004, -0.006, 0.003]).apply(np.eye(3))
    responses = tuple(LinearResponse(o, k * gain, (-1e4, 1e4)) for o, k in zip(hard_iron, (0.96, 1.04, 1.01)))
    return SensorModel(("mx", "my", "mz"), directions, responses, field_norm, field_norm, dip_deg,
                       noise=np.full(3, 0.15 * gain))


def before(model, raw) -> str:
    """The rule at 03c7b4c."""
    def ratio(r):
        n = np.linalg.norm(model.field(r)[0], axis=1)
        return float(np.median(n[np.isfinite(n)])) / model.field_norm

    first = raw[:JUDGE_SAMPLES]
    r1 = ratio(first)
    if abs(math.log(r1)) <= math.log(1.5):
        return "taken"
    fits = [(abs(math.log(r)), k) for k in FACTORS for r in (ratio(k * first),) if abs(math.log(r)) < math.log(1.25)]
    return f"unit: {unit_pairs(min(fits)[1]).split(' or ')[0]} (x{min(fits)[1]:g})" if fits else "taken"


def verdict(words: str | None) -> str:
    if words is None:
        return "taken"
    if "--mag-unit" in words and "scaled by" in words and "a unit taken for another" not in words:
        k = float(words.split("scaled by ")[1].split(" ")[0])
        return f"unit: {unit_pairs(k).split(' or ')[0]} (x{k:g})"
    if "this board's calibration" in words:
        return "calibration"
    return "cannot tell yet"


def after(model, t, raw, accel, gyro) -> str:
    words = judge_field_unit(field_scale_check(model), raw, accel)
    if words is not None:
        return verdict(words)
    session = replay(LiveSession(model, out=io.StringIO()), t, raw, accel, gyro)
    if session.wrong_field is None:
        return "taken"
    return verdict(session.wrong_field) + f" at {session.samples / 100:.0f} s"


def cases():
    own = board()
    for seed in range(3):
        yield f"honest uT, turns, seed {seed}", own, own, turns, 1.0, seed, "taken"
    yield "honest uT, tumble", own, own, tumble_motion, 1.0, 0, "taken"
    yield "honest uT, still", own, own, still, 1.0, 0, "taken"
    for share in (0.9, 1.0, 1.1):
        hi = HARD_IRON / np.linalg.norm(HARD_IRON) * 50.0 * share
        yield f"honest uT, |h| = {share:g} |B| (mirror)", board(hi), board(hi), turns, 1.0, 0, "taken"
    for dip in (5.0, 10.0):
        equator = board(dip_deg=dip)
        yield f"honest uT, dip {dip:g} deg, rolled facing North", equator, equator, roll_north, 1.0, 0, "taken"
        yield f"G read as uT, dip {dip:g} deg, rolled facing North", equator, equator, roll_north, 0.01, 0, "G"
    yield "mG read as uT", own, own, turns, 10.0, 0, "mG"
    yield "nT read as uT", own, own, turns, 1000.0, 0, "nT"
    for share in (0.5, 0.7, 0.77, 1.0, 1.3, 1.6):
        hi = HARD_IRON / np.linalg.norm(HARD_IRON) * 50.0 * share
        yield f"G read as uT, |h| = {share:g} |B|", board(hi), board(hi), turns, 0.01, 0, "G"
    yield "G read as uT, |h| = 0.77 |B|, still", own, own, still, 0.01, 0, "G"
    for hi, gain in (((40.0, 20.0, -10.0), 1.5), ((40.0, 20.0, -10.0), 1.2), ((-30.0, 25.0, 10.0), 0.8),
                     ((60.0, -40.0, 20.0), 1.0), ((5.0, 5.0, 5.0), 3.0)):
        yield f"another board: h {tuple(int(v) for v in hi)}, gain {gain:g}", board(hi, gain), own, turns, 1.0, 0, \
            "no unit named"
        yield "  the same read as mG", board(hi, gain), own, turns, 0.1, 0, "no unit named"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "broad"), help="BROAD's .mat folder")
    args = parse_args(parser, argv)
    t = np.arange(3000) / 100.0
    rows = []
    for name, device, cal, motion, scale, seed, truth in cases():
        s = simulate_device(device, t, motion=motion, seed=seed, gyro_bias=[0.005, -0.004, 0.003])
        raw = s.raw * scale
        rows.append([name, truth, before(cal, raw), after(cal, t, raw, s.accel, s.gyro)])
        print(" | ".join(rows[-1]), file=sys.stderr, flush=True)
    folder = Path(args.data)
    if folder.is_dir():
        from compass.io.broad import read_broad

        for path in sorted(folder.glob("*.mat")):
            trial = read_broad(path)
            n = int(60 * trial.rate_hz)
            tb = np.arange(len(trial.mag_ut))[:n] / trial.rate_hz
            m, a, g = trial.mag_ut[:n], trial.accel_m_s2[:n] / 9.81, trial.gyro_rad_s[:n]
            norm = float(np.median(np.linalg.norm(m, axis=1)))
            up = a / np.linalg.norm(a, axis=1, keepdims=True)
            dip = float(np.degrees(np.arcsin(np.median(np.sum(-up * m, axis=1) / np.linalg.norm(m, axis=1)))))
            model = SensorModel(("mx", "my", "mz"), np.eye(3), tuple(LinearResponse(0.0, 1.0, (-1e4, 1e4))
                                                                   for _ in range(3)), norm, norm, dip,
                                noise=np.full(3, 0.7))  # BROAD's 0.7 uT
            rows.append([f"BROAD {path.stem}", "taken", before(model, m), after(model, tb, m, a, g)])
            print(" | ".join(rows[-1]), file=sys.stderr, flush=True)
    publish(args, "docs/benchmarks.md", "bench_field_unit",
            markdown_table(["stream", "should be", "before (03c7b4c)", "now"], rows),
            caption="what the field's unit checks say; `unit`: the unit named (refused, exit 2), `calibration`: "
                    "refused as another board's calibration, `cannot tell yet`: refused before the housing turned "
                    "(both said), `at N s`: the session's turn check, after N s of attitudes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
