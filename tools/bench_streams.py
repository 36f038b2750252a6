"""What each stream format costs: heading error against the truth and decoding speed, our protocol beside.

The same simulated board (``compass.sim.stream_formats.board_model``: a magnetometer in uT with 0.15 uT
noise, accelerometer, gyro) runs the 40 s attitude script at 100 Hz; its samples go through
``compass.live.LiveSession`` as our line protocol (7 significant digits, the baseline), as MotionCal
``Raw:`` counts (PJRC's sketch), as ``Raw:`` + ``Uni:`` lines (Adafruit's) and as bare CSV numbers.
Samples are dated by their arrival in every case (MotionCal carries no time).  Printed: the heading's
RMS error against the script away from the magnet, after the first second, per seed, and the decoding
rate from memory (samples/s, the decoder alone).

    python tools/bench_streams.py [--seeds 3] [--seconds 40] [--write-docs]

``--write-docs`` writes the table into docs/runtime.md (``tools/_doc_table.py``).
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from pathlib import Path

import numpy as np

from compass.io.lines import format_line
from compass.io.streams import StreamDecoder, StreamOptions
from compass.live import LiveSession
from compass.serial_reader import Chunk
from compass.sim.device import simulate_device
from compass.sim.stream_formats import CSV_COLUMNS, board_model, sample_lines

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _doc_table import markdown_table, parse_args, publish  # noqa: E402

NAMES = ("seq", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz")
FORMATS = {"compass (baseline)": None, "motioncal Raw: (PJRC)": "motioncal-raw",
           "motioncal Raw:+Uni: (Adafruit)": "motioncal", "csv --columns": "csv"}


def lines_of(fmt, smp):
    if fmt is None:
        return [(format_line(NAMES) if k == 0 else b"") + format_line([k, *(f"{v:.7g}" for v in (*m, *a, *g))])
                for k, (m, a, g) in enumerate(zip(smp.raw, smp.accel, smp.gyro))]
    return sample_lines(fmt, smp.t_s, smp.raw, smp.accel, smp.gyro)


def options_of(fmt):
    return StreamOptions(columns=CSV_COLUMNS) if fmt == "csv" else None


def heading_rms(model, smp, fmt) -> float:
    out = io.StringIO()
    session = LiveSession(model, out=out, stream=options_of(fmt))  # no "connected" event: the first line is whole
    for t, chunk in zip(smp.t_s, lines_of(fmt, smp)):
        session.feed(Chunk(float(t), chunk))
    session.close()
    rows = [line for line in out.getvalue().splitlines() if not line.startswith("#")]
    names = rows[0].split(",")
    data = np.loadtxt(rows[1:], delimiter=",", ndmin=2)
    heading = data[:, names.index("heading_deg")]
    keep = (smp.t_s >= 1.0) & (smp.magnet == 0)
    err = (heading - smp.heading_deg + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(err[keep] ** 2)))


def decode_rate(model, smp, fmt) -> float:
    data = b"".join(lines_of(fmt, smp))
    chunks = [data[k:k + 4096] for k in range(0, len(data), 4096)]
    decoder = StreamDecoder(model.channels, options_of(fmt))
    start = time.process_time()
    n = sum(len(decoder.feed(c)) for c in chunks)
    return n / (time.process_time() - start)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=40.0)
    args = parse_args(parser, argv)
    model = board_model()
    t = np.arange(0.0, args.seconds, 0.01)
    samples = [simulate_device(model, t, seed=seed) for seed in range(args.seeds)]
    print(f"heading RMS error against the truth (deg), {args.seconds:g} s of the script at 100 Hz, seeds "
          f"0-{args.seeds - 1}; decoding rate from memory")
    print(f"{'format':34s} " + " ".join(f"seed {s:<3d}" for s in range(args.seeds)) + "   mean   samples/s")
    table = []
    for name, fmt in FORMATS.items():
        rms = [heading_rms(model, smp, fmt) for smp in samples]
        rate = decode_rate(model, samples[0], fmt)
        print(f"{name:34s} " + " ".join(f"{r:8.3f}" for r in rms) + f" {np.mean(rms):6.3f}   {rate:9.0f}")
        table.append([name, *(f"{r:.3f}" for r in rms), f"{np.mean(rms):.3f}", f"{rate:,.0f}"])
    publish(args, "docs/runtime.md", "bench_streams",
            markdown_table(["format", *(f"seed {s}" for s in range(args.seeds)), "mean", "decoded samples/s (CPU)"],
                           table), echo=False,
            caption=f"heading RMS error against the truth, deg, {args.seconds:g} s of the script at 100 Hz; "
                    "decoding rate from memory, one run on a shared machine (it varies with the load)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
