"""How big a live recording is: chunks and bytes of the .rrd a live session writes, and the time to read it.

A seeded simulated module (``compass.sim.device``, 100 Hz, gyro and accelerometer) is fed to
:class:`compass.live.LiveSession` for ``--seconds`` of sample time, with a
:class:`compass.viz.RerunSink` to a file, twice in one run:

- baseline: batches sent every 0.05 s of sample time (the sink's old default for every target);
- now: the sink's default for a file (:data:`compass.viz.live.FILE_FLUSH_S`).

A viewer loads a recording chunk by chunk; thousands of small chunks took it minutes (issue 25: a
15 s session was 5,700 chunks, 8 MB). Printed: chunks, bytes, samples in the file, and the time
``rerun.chunk.RrdReader`` takes to read every chunk (a proxy for loading; the machine's load shows
in it, the chunk count does not depend on it).

Usage: ``python tools/bench_live_rrd.py [--seconds 20] [--seed 3] [--write-docs]`` (``--write-docs``: the
table into docs/runtime.md, ``tools/_doc_table.py``).
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _doc_table import markdown_table, parse_args, publish  # noqa: E402


def record(folder: Path, seconds: float, seed: int, flush_s: float | None) -> Path:
    from compass.filter import FilterConfig
    from compass.live import LiveSession
    from compass.serial_reader import Chunk, LinkEvent
    from compass.sim.device import PtyDevice, default_model, simulate_device
    from compass.viz import RerunSink

    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    samples = simulate_device(model, np.arange(int(seconds * 100)) / 100.0, seed=seed)
    stream = device._header + b"".join(device._lines(samples, 0))
    path = folder / f"live_{'default' if flush_s is None else flush_s}.rrd"
    options = {} if flush_s is None else {"flush_s": flush_s}
    sink = RerunSink.for_model(path, model, FilterConfig.from_model(model), **options)
    session = LiveSession(model, out=io.StringIO(), sink=sink)
    session.feed(LinkEvent("connected", "connected to the simulated module", 0.0))
    for k in range(0, len(stream), 4096):
        session.feed(Chunk(time.perf_counter(), stream[k:k + 4096]))
    session.close()
    return path


def measure(path: Path) -> tuple[int, int, int, float]:
    """(chunks, bytes, heading samples, seconds to read every chunk)."""
    from rerun.chunk import RrdReader

    start = time.perf_counter()
    chunks = list(RrdReader(str(path)).stream().to_chunks())
    read_s = time.perf_counter() - start
    rows = sum(c.to_record_batch().num_rows for c in chunks if c.entity_path == "/compass/heading_deg"
               and "sample" in c.to_record_batch().schema.names)
    return len(chunks), path.stat().st_size, rows, read_s


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=3)
    args = parse_args(parser, argv)
    from compass.viz.live import FILE_FLUSH_S

    with tempfile.TemporaryDirectory() as tmp:
        print(f"live session of {args.seconds:g} s at 100 Hz (seed {args.seed}) to a file")
        print(f"{'batches every':<28} {'chunks':>7} {'MB':>7} {'samples':>8} {'read s':>7}")
        table = []
        for label, flush in (("0.05 s (baseline)", 0.05), (f"{FILE_FLUSH_S:g} s (file default, now)", None)):
            chunks, size, rows, read_s = measure(record(Path(tmp), args.seconds, args.seed, flush))
            print(f"{label:<28} {chunks:>7} {size / 1e6:>7.2f} {rows:>8} {read_s:>7.2f}")
            table.append([label, f"{chunks:,}", f"{size / 1e6:.2f}", f"{rows:,}", f"{read_s:.2f}"])
    publish(args, "docs/runtime.md", "bench_live_rrd",
            markdown_table(["batches every (sample time)", "chunks", "MB", "samples in the file", "read, s"], table),
            caption=f"a live session of {args.seconds:g} s at 100 Hz (seed {args.seed}) to a file; the read time "
                    "varies with the machine's load, the chunk count does not", echo=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
