"""What each turntable angle source of ``compass bench`` costs: direction error against the CRB.

For each seeded session a simulated bench (:class:`compass.sim.bench_rig.BenchRig`: three channels
near X, Y, Z, 0.15 uT noise, 100 Hz, an accelerometer, an operator turning at up to 30 deg/s)
is run through the bench station in lock step (:func:`compass.sim.bench_rig.drive`: the station's
own stream decoder, checks and angle source), and the recording it writes is calibrated as
``compass calibrate`` does (the four-flip kind's calibrator, residual diagnosis on).  Side by side
for each source, over the same sessions:

- ``err``: RMS direction error over channels and sessions, degrees;
- ``err/CRB``: ``sqrt(mean((err / CRB)^2))``, the CRB being that of the same rows at their *true*
  angles with the true noise (:func:`calibrate.fourflip._mlfit.cramer_rao`; a row averaging a
  stop's n samples has noise / sqrt(n));
- ``exact/CRB``: the same recording with its ``platform_deg`` replaced by the true angles,
  calibrated alike (the estimator's own efficiency on these rows: the baseline);
- ``err/sigma``: how honest the calibration's ``direction_sigma_deg`` is for that source.

Sources: an exact encoder column, one quantised to 0.1 deg, the gyro (0.5 deg/s RMS bias per axis
and a 1 % RMS scale error per axis), manual stops every 10 and every 30 deg read within
+-0.5 deg (uniform), and a GRBL stepper table (:class:`compass.station.grbl.GrblSource` talking to
the simulated controller :class:`compass.sim.grbl.GrblController` in the same process, polled
every 0.1 s, each status report giving the position up to 10 ms before it is read: the time a
report takes to be formed, sent and read): stops every 10 deg, and one continuous turn at 720 and
at 1800 deg/min, every sample's angle interpolated from the reports.

Usage::

    python tools/bench_station.py [--n 6] [--seed 100]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from calibrate.fourflip._mlfit import cramer_rao
from calibrate.kinds import KINDS
from compass.io.fourflip import read_fourflip
from compass.sim.bench import BenchSamples
from compass.sim.bench_rig import BenchRig, Operator, drive
from compass.sim.grbl import GrblController, LoopbackPort
from compass.station import SessionStore, Station, StationStream, parse_turntable
from compass.station.grbl import GrblSource

SOURCES = {
    "encoder, exact": ("column:enc", dict(encoder_step_deg=0.0), {}),
    "encoder, 0.1 deg steps": ("column:enc", dict(encoder_step_deg=0.1), {}),
    "gyro, 0.5 deg/s bias, 1 % scale": ("gyro", dict(gyro_bias_dps=0.5, gyro_scale_error=0.01), {}),
    "manual, 30 deg stops +-0.5": ("manual:30", {}, dict(read_half_width_deg=0.5)),
    "manual, 10 deg stops +-0.5": ("manual:10", {}, dict(read_half_width_deg=0.5)),
    "GRBL, stops every 10 deg": ("grbl:stops:1800", {}, {}),
    "GRBL, continuous 720 deg/min": ("grbl:continuous:720", {}, {}),
    "GRBL, continuous 1800 deg/min": ("grbl:continuous:1800", {}, {}),
}
REPORT_DELAY_S = 0.01  # a status report's position is up to this old when it is read


def grbl_source(spec: str, rig: BenchRig, seed: int):
    """``grbl:MODE:FEED``: the station's GRBL source on the simulated controller, and the lock step's block hook."""
    _, mode, feed = spec.split(":")
    rig.operator_turns = False
    controller = GrblController(rig, report_delay_s=REPORT_DELAY_S, seed=seed)
    now = [0.0]
    source = GrblSource("simulated", link=LoopbackPort(controller), clock=lambda: now[0], mode=mode,
                        feed_deg_min=float(feed), step_deg=10.0)
    source.open()

    def on_block(rig, t_s):
        controller.advance(t_s)
        now[0] = t_s
        source.poll()  # asks for a report when due
        source.poll()  # reads it at once (its age is the controller's report delay)
        source.clock_pair(t_s, t_s)  # the host's clock is the module's here

    return source, on_block


def session(spec: str, rig: BenchRig, folder: Path, seed: int = 0):
    """Run one station session; the recording it writes (read back), or None if it did not finish."""
    source, on_block = grbl_source(spec, rig, seed) if spec.startswith("grbl") else (parse_turntable(spec), None)
    store = SessionStore(folder / "cal.json")
    store.start({})
    station = Station(source, rig.channels, on_flip=store.save)
    drive(rig, station, StationStream(getattr(source, "column", None)), max_s=1500.0,
          block_s=0.1 if on_block else 0.2, on_block=on_block)
    if not station.finished:
        return None
    return read_fourflip(store.write_recording({"turntable": spec}))


def calibrate(recording):
    return KINDS["fourflip"].calibrator().fit(recording)


def score(rig: BenchRig, recording, averaged: bool) -> dict:
    truth = np.asarray(rig.truth["directions"])

    def error(result):
        return np.degrees(np.arccos(np.clip(np.sum(result.directions * truth, axis=1), -1.0, 1.0)))

    result = calibrate(recording)
    phi, _, _, _ = rig.pose(recording.t_s)
    true_angles = np.mod(phi, 360.0)
    exact = calibrate(type(recording)(recording.flip_deg, recording.flip_index, true_angles, recording.outputs,
                                      recording.channels, recording.t_s, recording.temp_c, recording.accel,
                                      recording.metadata, recording.path))
    noise = rig.noise / np.sqrt(rig.rate_hz if averaged else 1.0)  # a stop's mean: one second of samples
    crb, _ = cramer_rao(rig.physics, BenchSamples(true_angles, recording.flip_deg, recording.flip_index),
                        recording.channels, noise)
    sigma = np.array([c.direction_sigma_deg for c in result.channels])
    return dict(err=error(result), exact=error(exact), crb=crb, sigma=sigma,
                effects=list(result.to_json().get("diagnosis", {}).get("effects", [])))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=6, help="sessions per source (default 6)")
    parser.add_argument("--seed", type=int, default=100, help="first seed (default 100)")
    parser.add_argument("--only", help="run only the sources whose name contains this text")
    args = parser.parse_args()
    rows = []
    t0 = time.perf_counter()
    for name, (spec, rig_options, operator) in SOURCES.items():
        if args.only and args.only not in name:
            continue
        scores, failed = [], 0
        for i in range(args.n):
            rig = BenchRig(seed=args.seed + i, operator=Operator(**operator), **rig_options)
            with tempfile.TemporaryDirectory() as folder:
                recording = session(spec, rig, Path(folder), args.seed + i)
            if recording is None:
                failed += 1
                continue
            scores.append(score(rig, recording, spec.startswith(("manual", "grbl:stops"))))
            print(f"  {name}: {i + 1}/{args.n}, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        rows.append((name, spec, scores, failed))
    print(f"bench_station: {args.n} seeded sessions per source (seeds {args.seed}..{args.seed + args.n - 1}), "
          "three channels, 0.15 uT noise, 100 Hz")
    print(f"{'source':34s} {'--turntable':20s} {'err deg':>8s} {'err/CRB':>8s} {'exact/CRB':>9s} {'err/sigma':>9s} "
          f"{'CRB deg':>8s}  effects added")
    for name, spec, scores, failed in rows:
        if not scores:
            print(f"{name:34s} {spec:20s} no session finished ({failed} abandoned)")
            continue
        err = np.concatenate([s["err"] for s in scores])
        exact = np.concatenate([s["exact"] for s in scores])
        crb = np.concatenate([s["crb"] for s in scores])
        sigma = np.concatenate([s["sigma"] for s in scores])
        effects = sorted({e for s in scores for e in s["effects"]})
        rms = (lambda x: float(np.sqrt(np.mean(np.square(x)))))
        print(f"{name:34s} {spec:20s} {rms(err):8.4f} {rms(err / crb):8.2f} {rms(exact / crb):9.2f} "
              f"{rms(err / sigma):9.2f} {rms(crb):8.4f}  {', '.join(effects) or '-'}"
              + (f" ({failed} abandoned)" if failed else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
