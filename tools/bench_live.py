"""Benchmark of the live pipeline: latency and sustained rate, pty module to attitude.

The module is ``compass device --pty`` in its own process (so it does not share the GIL with the
receiver); the receiver is :class:`compass.live.LiveSession` fed by :class:`compass.serial_reader.SerialReader`
in this process, writing the attitude CSV (and, with Rerun on, an .rrd file) to a temporary folder.

- latency: chunk read from the port -> estimate available (decode, field, filter), and -> outputs
  done (CSV row written, Rerun row buffered or, every 50 ms, the batch sent), p50 and p99, at
  100 Hz and 1 kHz.  Time bytes wait in the kernel while the receiver is busy is not counted;
  the sweep's lost-line and backlog criteria catch a receiver that falls behind;
- sustained rate: the highest rate of a sweep at which the receiver lost no line (no ``seq`` gap:
  a receiver that falls behind fills the pty and the module drops lines; no garbage or partial
  line besides the first fragment after opening) and received at >= 97 % of the rate, with
  Rerun on and off;
- processing capacity: lines decoded, solved and filtered per second from memory (no port), with
  Rerun off, with :class:`compass.viz.RerunSink` (batched ``send_columns``, 3-D frames at 30 per
  second of sample time) and with a baseline that logs every sample with ``rr.log``; the cost of
  Rerun per sample is the difference of the inverse rates;
- the sinks alone: the session's outputs replayed into each sink, CPU time per sample (Rerun's
  threads included), which a loaded machine disturbs less than the rates above.

Targets (issue 5): p99 < 5 ms at 100 Hz; >= 1 kHz sustained with Rerun recording to a file;
(issue 13) keeping up with 2 kHz with Rerun on.

- the command: ``compass live --rerun FILE.rrd --out CSV --quiet`` in its own process on a ``compass device
  --pty`` stream, a sweep of rates: lines sent in its window (decoded + lost), decoded, lost, the
  received rate, its CPU per sample in the steady state (``/proc/PID/stat`` over the CSV rows written
  in the middle 60 % of the run: Rerun's threads included, no start-up) and the rate one core could
  carry at that cost, with how busy the machine was (``/proc/stat``: the other users' work
  included) and its load average.

Usage: ``python tools/bench_live.py [--quick] [--command-only]``
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from compass.attitude import solve_attitude
from compass.filter import FilterConfig, run_filter
from compass.live import LiveSession
from compass.serial_reader import Chunk, LinkEvent, SerialReader
from compass.sim.device import PtyDevice, default_model, simulate_device
from compass.calibration import load as load_calibration


def run_port(rate_hz: float, duration_s: float, rerun: bool, folder: Path) -> dict:
    """Stream ``duration_s`` from a device process at ``rate_hz`` into a LiveSession."""
    cal, link = folder / f"cal{rate_hz:g}.json", folder / f"dev{rate_hz:g}"
    device = subprocess.Popen(
        [sys.executable, "-m", "compass", "device", "--pty", "--save-cal", str(cal), "--force", "--link", str(link),
         "--rate", str(rate_hz), "--duration", str(duration_s + 4.0)],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        device.stdout.readline()
        model = load_calibration(cal).model
        sink = None
        if rerun:
            from compass.viz import RerunSink
            sink = RerunSink.for_model(folder / f"live{rate_hz:g}.rrd", model, FilterConfig.from_model(model))
        with open(folder / "att.csv", "w", buffering=1 << 16) as out:
            session = LiveSession(model, out=out, sink=sink)
            stop = threading.Event()
            timer = threading.Timer(duration_s + 1.5, stop.set)  # 1.5 s for the first header
            timer.start()
            reader = SerialReader(str(link))
            start = None
            for item in reader.items(stop):
                if isinstance(item, LinkEvent) and item.kind == "disconnected":
                    break
                session.feed(item)
                if start is None and session.samples:
                    start = (time.perf_counter(), session.samples)
            timer.cancel()
            reader.close()
            session.close()
        end = time.perf_counter()
    finally:
        device.terminate()
        device.wait(10)
    s = session.decoder.stats
    p50, p99 = session.latency_ms()
    out50, out99 = session.latency_ms(outputs=True)
    received = (session.samples - start[1]) / (end - start[0]) if start else 0.0
    return {"rate": rate_hz, "rerun": rerun, "samples": session.samples, "received_hz": received,
            "lost": s.lost, "bad": s.garbage + s.partial, "p50": p50, "p99": p99, "out50": out50, "out99": out99}


_SUMMARY = re.compile(r"(\d+) attitudes from (\d+) samples; dropped lines \d+ \(garbage (\d+), invalid \d+, "
                      r"partial (\d+), before a header \d+, repeated seq \d+, lost in transit (\d+)\)")


def _busy_jiffies() -> tuple[int, int]:
    """(busy, total) CPU jiffies of the whole machine so far, all cores (``/proc/stat``)."""
    with open("/proc/stat") as f:
        values = [int(v) for v in f.readline().split()[1:]]
    idle = values[3] + values[4]  # idle + iowait
    return sum(values) - idle, sum(values)


def _cpu_s(pid: int) -> float:
    """User + system CPU time of a running process, all its threads, seconds (``/proc/PID/stat``)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _after_flush(csv: Path, pid: int, timeout_s: float = 3.0):
    """``(CPU s, rows)`` of the live process just after its next CSV flush (it flushes every second: the row
    count is then exact), or None if it ended first."""
    size = csv.stat().st_size if csv.exists() else 0
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        time.sleep(0.005)
        now = csv.stat().st_size if csv.exists() else 0
        if now != size:
            try:
                cpu = _cpu_s(pid)
            except FileNotFoundError:
                return None
            return cpu, csv.read_bytes().count(b"\n")
    return None


def run_command(rate_hz: float, duration_s: float, folder: Path) -> dict:
    """``compass live --rerun FILE.rrd --out CSV --quiet`` (the command, its own process) on a ``compass device
    --pty`` stream at ``rate_hz`` for ``duration_s``.

    Returns the session's counts (from its summary line; sent = decoded + lost in the window it
    read), its CPU per sample in the steady state (``/proc/PID/stat``, its Rerun threads included,
    over the CSV rows written in the middle 60 % of the run, counted just after its flushes: no
    start-up in it), and how busy the whole machine was meanwhile (``/proc/stat``: every process of
    every user, both cores).
    """
    cal, link, csv = folder / "cal_cmd.json", folder / f"cmd{rate_hz:g}", folder / f"cmd{rate_hz:g}.csv"
    device = subprocess.Popen(
        [sys.executable, "-m", "compass", "device", "--pty", "--save-cal", str(cal), "--force", "--link", str(link),
         "--rate", str(rate_hz), "--duration", str(duration_s + 20.0)],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    live = None
    try:
        device.stdout.readline()
        live = subprocess.Popen(
            [sys.executable, "-m", "compass", "live", "--port", str(link), "--cal", str(cal), "--rerun",
             str(folder / f"cmd{rate_hz:g}.rrd"), "--out", str(csv), "--force", "--quiet", "--duration",
             str(duration_s + 5.0)],  # 5 s for its start-up
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        first = _after_flush(csv, live.pid, 60.0)  # rows flowing: the start-up is over
        time.sleep(0.15 * duration_s)
        marks = [_after_flush(csv, live.pid), None]
        t0, busy0, load0 = time.monotonic(), _busy_jiffies(), os.getloadavg()[0]
        time.sleep(0.6 * duration_s)
        marks[1] = _after_flush(csv, live.pid)
        t1, busy1, load1 = time.monotonic(), _busy_jiffies(), os.getloadavg()[0]
        text, _ = live.communicate(timeout=duration_s + 60.0)
    finally:
        if live is not None and live.poll() is None:
            live.kill()
            live.wait(10)
        device.terminate()
        device.wait(10)
    match = _SUMMARY.search(text)
    if match is None or first is None or None in marks:
        raise RuntimeError(f"compass live printed no summary or ended early:\n{text}")
    attitudes, samples, garbage, partial, lost = (int(v) for v in match.groups())
    (cpu0, rows0), (cpu1, rows1) = marks
    return {"rate": rate_hz, "samples": samples, "attitudes": attitudes, "sent": samples + lost, "lost": lost,
            "bad": garbage + partial, "received_hz": (rows1 - rows0) / (t1 - t0),
            "cpu_us": 1e6 * (cpu1 - cpu0) / max(rows1 - rows0, 1),
            "busy": (busy1[0] - busy0[0]) / max(busy1[1] - busy0[1], 1), "load": (load0, load1)}


def command_sweep(rates, duration_s: float, folder: Path) -> None:
    """The highest rate ``compass live`` with Rerun on sustains, and its CPU per sample (steady state:
    one core then carries at most ``1 / (CPU per sample)`` samples a second)."""
    print(f"\n`compass live --rerun FILE.rrd --out CSV --quiet` (own process) on `compass device --pty`, "
          f"{duration_s:g} s a rate; CPU and rate measured over its middle 60 %")
    print("| rate | sent (window) | decoded | lost | bad lines | received | live CPU / sample | "
          "max rate one core | machine busy (2 cores, all users) | load avg | sustained |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    best = 0
    for rate in rates:
        r = run_command(rate, duration_s, folder)
        ok = sustained(r)
        best = rate if ok and rate > best else best
        print(f"| {rate:g} Hz | {r['sent']} | {r['samples']} | {r['lost']} | {r['bad']} | {r['received_hz']:.0f} Hz | "
              f"{r['cpu_us']:.1f} us | {1e6 / r['cpu_us']:.0f} Hz | {100 * r['busy']:.0f} % | "
              f"{r['load'][0]:.2f} -> {r['load'][1]:.2f} | {'yes' if ok else 'no'} |", flush=True)
    print(f"highest sustained rate of compass live with Rerun on: {f'{best:g} Hz' if best else 'none of the sweep'}")


def sustained(r: dict) -> bool:
    """No line lost or damaged (one fragment after opening allowed) and the receive rate kept up."""
    return r["lost"] == 0 and r["bad"] <= 1 and r["received_hz"] >= 0.97 * r["rate"]


class PerSampleSink:
    """Baseline for the Rerun cost: every sample logged with ``rr.log`` as it comes (``set_time``,
    the housing, the field arrow, six scalars), the way a first version would, without batches,
    decimation or a layout."""

    def __init__(self, path):
        import rerun as rr

        self.rr, self.rec = rr, rr.RecordingStream("bench_per_sample")
        self.rec.save(path)

    def log(self, t_s, sample, estimate, field_h, accel, **_):
        rr, rec, e = self.rr, self.rec, estimate
        rec.set_time("t", duration=t_s)
        rec.set_time("sample", sequence=sample)
        rec.log("world/housing", rr.Transform3D(quaternion=e.rotation.as_quat()))
        rec.log("world/field", rr.Arrows3D(vectors=[e.rotation.apply(field_h)]))
        for name in ("heading_deg", "pitch_deg", "roll_deg", "field_ratio", "dip_deg"):
            rec.log(f"compass/{name}", rr.Scalars(getattr(e, name)))
        rec.log("compass/mag_used", rr.Scalars(float(e.mag_used)))

    def set_reference(self, *_):
        pass

    def event(self, t_s, sample, text, level="info"):
        self.rec.log("events", self.rr.TextLog(text))

    def close(self):
        self.rec.disconnect()


SINKS = ("off", "file", "per-sample rr.log")


def capacity(sink_kind: str, folder: Path, n: int = 20000) -> float:
    """Samples per second through decode + field + filter (+ Rerun) from memory."""
    model = load_calibration(folder / "cal100.json").model
    device = PtyDevice(model, rate_hz=1000.0)
    data = device._header + b"".join(device._lines(simulate_device(model, np.arange(n) / 1000.0), 0))
    sink = None
    if sink_kind == "file":
        from compass.viz import RerunSink
        sink = RerunSink.for_model(folder / "capacity.rrd", model, FilterConfig.from_model(model))
    elif sink_kind != "off":
        sink = PerSampleSink(folder / "per_sample.rrd")
    with open(os.devnull, "w") as out:
        session = LiveSession(model, out=out, sink=sink)
        t0 = time.perf_counter()
        for k in range(0, len(data), 4096):
            session.feed(Chunk(time.perf_counter(), data[k:k + 4096]))
        session.close()
    return session.samples / (time.perf_counter() - t0)


class _Collect:
    """A sink that keeps what it is given (to replay it into a real sink, timed alone)."""

    def __init__(self):
        self.calls = []

    def log(self, *args, **kwargs):
        self.calls.append((args, kwargs))

    def set_reference(self, *args):
        pass

    def event(self, *args):
        pass

    def close(self):
        pass


def sink_cpu_us(folder: Path, n: int = 20000) -> dict:
    """CPU time per sample (this process, Rerun's threads included) of each sink alone, microseconds:
    the session's outputs are collected once, then replayed into each sink (log + close)."""
    model = load_calibration(folder / "cal100.json").model
    device = PtyDevice(model, rate_hz=1000.0)
    data = device._header + b"".join(device._lines(simulate_device(model, np.arange(n) / 1000.0), 0))
    collect = _Collect()
    session = LiveSession(model, sink=collect)
    for k in range(0, len(data), 4096):
        session.feed(Chunk(time.perf_counter(), data[k:k + 4096]))
    from compass.viz import RerunSink

    out = {}
    for kind in SINKS[1:]:
        sink = (RerunSink.for_model(folder / "cpu.rrd", model, session.config) if kind == "file"
                else PerSampleSink(folder / "cpu_per_sample.rrd"))
        t0 = time.process_time()
        for args, kwargs in collect.calls:
            sink.log(*args, **kwargs)
        sink.close()
        out[kind] = 1e6 * (time.process_time() - t0) / len(collect.calls)
    return out


def static_noise(seed: int = 5, rate_hz: float = 100.0, duration_s: float = 30.0) -> dict:
    """Heading standard deviation of a still module: two-vector solution vs the filter (with and
    without gyro), after 5 s of settling; degrees."""
    model = default_model()
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    still = lambda t: (np.full(len(t), 123.0), np.full(len(t), 10.0), np.full(len(t), -5.0), np.zeros(len(t)))  # noqa: E731
    s = simulate_device(model, t, seed=seed, motion=still)
    field, _ = model.field(s.raw)
    settled = t > 5.0
    out = {"two-vector": np.std(solve_attitude(model, s.raw, accel=s.accel).heading_deg[settled])}
    for name, gyro in (("filter, gyro", s.gyro), ("filter, no gyro", None)):
        track = run_filter(t, s.accel, gyro, field, FilterConfig.from_model(model))
        out[name] = np.std(track.heading_deg[settled])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs, smaller sweep")
    parser.add_argument("--command-only", action="store_true", help="only the sweep of the compass live command")
    args = parser.parse_args()
    duration = 3.0 if args.quick else 8.0
    sweep = (1000, 2000) if args.quick else (1000, 2000, 4000, 8000)
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        command_sweep((1000, 2000) if args.quick else (1000, 2000, 3000, 4000), 5.0 if args.quick else 10.0, folder)
        if args.command_only:
            return
        print("\n| rate | Rerun | samples | received | to attitude p50 / p99 | to outputs p50 / p99 | lost | bad lines |")
        print("|---|---|---|---|---|---|---|---|")
        for rate in (100, 1000):
            r = run_port(rate, duration, True, folder)
            print(f"| {rate} Hz | file | {r['samples']} | {r['received_hz']:.0f} Hz | {r['p50']:.2f} / {r['p99']:.2f} ms | "
                  f"{r['out50']:.2f} / {r['out99']:.2f} ms | {r['lost']} | {r['bad']} |")
        print("\n| Rerun | sweep (Hz): lost / bad / received Hz | max sustained |")
        print("|---|---|---|")
        for rerun in (False, True):
            cells, best = [], 0
            for rate in sweep:
                r = run_port(rate, duration / 2, rerun, folder)
                cells.append(f"{rate}: {r['lost']}/{r['bad']}/{r['received_hz']:.0f}")
                if not sustained(r):
                    break
                best = rate
            print(f"| {'file' if rerun else 'off'} | {'; '.join(cells)} | {f'>= {best} Hz' if best else '< ' + str(sweep[0]) + ' Hz'} |")
        noise = static_noise()
        print("\n| still module, 100 Hz, 25 s | heading std | below the two-vector solution |")
        print("|---|---|---|")
        for name, std in noise.items():
            print(f"| {name} | {std:.4f} deg | {noise['two-vector'] / std:.1f}x |")
        repeats = 3 if args.quick else 5
        runs = {kind: [] for kind in SINKS}
        for _ in range(repeats):  # interleaved, so a change in the machine's load hits every kind alike
            for kind in SINKS:
                runs[kind].append(capacity(kind, folder, 10000 if args.quick else 20000))
        off = np.median(runs["off"])
        print(f"\n| Rerun | processing capacity from memory (median of {repeats}) | Rerun's cost per sample |")
        print("|---|---|---|")
        for kind in SINKS:
            rate = np.median(runs[kind])
            cost = "-" if kind == "off" else f"{1e6 * (1.0 / rate - 1.0 / off):.0f} us"
            print(f"| {kind} | {rate:.0f} samples/s | {cost} |")
        cpu = sink_cpu_us(folder, 10000 if args.quick else 20000)
        print("\n| Rerun sink alone | CPU per sample | CPU share at 2 kHz |")
        print("|---|---|---|")
        for kind, us in cpu.items():
            print(f"| {kind} | {us:.1f} us | {100 * us * 2000 / 1e6:.0f} % |")


if __name__ == "__main__":
    main()
