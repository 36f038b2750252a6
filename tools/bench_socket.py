"""What `compass live` keeps of a fast stream over socket:// (issue 16.2), beside the old reader.

A module process (seeded: the simulated device's sensor and motion) streams the line protocol with
``seq`` at ``--rate`` Hz over TCP on 127.0.0.1 for ``--seconds``.  Like firmware it never blocks:
a line that does not fit in its 16 KiB send buffer is dropped (counted by the module).  The
receiver runs the live pipeline (:class:`compass.live.LiveSession`: decode, solve, filter) on the
items of a :class:`compass.serial_reader.SerialReader` until the stream has ended plus 1 s.

Two receivers read the same stream: ``bulk`` (the reader as it is: select, then a non-blocking
read of everything there) and ``one-byte`` (the reader before issue 16.2: ``read(in_waiting or 1)``,
and pyserial's socket ``in_waiting`` is 0 or 1).  Printed: samples sent, dropped by the module
(never on the wire), decoded, reported lost by the receiver (``seq`` gaps), and unaccounted
(neither decoded nor reported: still unread or unprocessed when the receiver stopped).  The
``decode only`` rows skip solving and filtering, to separate the reader's limit from the filter's.

    python tools/bench_socket.py                 # 10 kHz for 5 s
    python tools/bench_socket.py --quick         # 2 kHz for 2 s
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import socket
import threading
import time

import numpy as np

from compass.live import LiveSession
from compass.serial_reader import SerialReader
from compass.sim.device import PtyDevice, default_model, simulate_device

SEND_BUFFER_BYTES = 16 << 10


class OneByteReader(SerialReader):
    """The reader before issue 16.2: ``read(in_waiting or 1)`` with the port's blocking timeout."""

    def _read(self) -> bytes:
        if self.port.timeout != self.read_timeout_s:
            self.port.timeout = self.read_timeout_s
        return self.port.read(self.port.in_waiting or 1)


def module(conn, rate_hz: float, seconds: float, seed: int) -> None:
    """Serve one receiver: header, then paced sample lines; drop what does not fit; report counts."""
    model = default_model()
    device = PtyDevice(model, rate_hz=rate_hz, seed=seed)
    t = np.arange(int(rate_hz * seconds)) / rate_hz
    lines = device._lines(simulate_device(model, t, seed=seed, rate_hz=rate_hz), 0)
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(30.0)
    conn.send(server.getsockname()[1])
    peer, _ = server.accept()
    peer.settimeout(30.0)
    peer.recv(16)  # the receiver's hello: its open() drained what came before
    peer.setblocking(False)
    pending, dropped, header_every = bytearray(), 0, int(rate_hz)
    start = time.perf_counter()
    for i, line in enumerate(lines):
        delay = start + t[i] - time.perf_counter()
        if delay > 0.001:
            time.sleep(delay)
        chunk = (device._header if i % header_every == 0 else b"") + line
        if len(pending) + len(chunk) > SEND_BUFFER_BYTES:
            dropped += 1
        else:
            pending += chunk
        try:
            del pending[:peer.send(pending)]
        except BlockingIOError:
            pass
    conn.send((len(lines), dropped, time.perf_counter() - start))
    peer.setblocking(True)
    try:
        peer.sendall(pending)  # the last lines (fails once the receiver has given up and closed)
        peer.recv(16)  # hold the connection until the receiver has finished
    except OSError:
        pass
    peer.close()
    server.close()


class DecodeOnly(LiveSession):
    """The live session without solving and filtering: what the reader and the decoder alone keep."""

    def _sample(self, sample, t_rx: float) -> None:
        self.samples += 1


def receive(reader_class, session_class, rate_hz: float, seconds: float, seed: int) -> dict:
    parent, child = mp.Pipe()
    proc = mp.get_context("fork").Process(target=module, args=(child, rate_hz, seconds, seed), daemon=True)
    proc.start()
    try:
        port = parent.recv()
        session = session_class(default_model())
        reader = reader_class(f"socket://127.0.0.1:{port}")
        stop = threading.Event()
        timer = threading.Timer(seconds + 1.0, stop.set)
        timer.start()
        calls = 0
        try:
            for item in reader.items(stop):
                if getattr(item, "kind", None) == "connected":
                    reader.port.write(b"hello\n")
                calls += 1
                session.feed(item)
        finally:
            timer.cancel()
            sent, dropped, send_s = parent.recv() if parent.poll(30.0) else (0, 0, float("nan"))
            if reader.port is not None:
                reader.port.write(b"bye\n")
            reader.close()
    finally:
        proc.join(30.0)
        if proc.is_alive():
            proc.kill()
            proc.join(5.0)
    s = session.decoder.stats
    return dict(sent=sent, dropped=dropped, decoded=s.samples, lost=s.lost, attitudes=session.samples, calls=calls,
                unaccounted=sent - s.samples - s.lost, send_s=send_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=10_000.0)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="2 kHz for 2 s")
    args = parser.parse_args()
    if args.quick:
        args.rate, args.seconds = 2000.0, 2.0
    print(f"socket:// at {args.rate:.0f} Hz for {args.seconds:.0f} s (seed {args.seed}); module send buffer "
          f"{SEND_BUFFER_BYTES >> 10} KiB, lines that do not fit are dropped by the module")
    print(f"{'reader':<22} {'sent':>7} {'mod.drop':>8} {'decoded':>8} {'kept %':>7} {'lost(seq)':>9} "
          f"{'unacc.':>7} {'reads':>8}")
    for name, cls, session in (("one-byte", OneByteReader, LiveSession), ("bulk", SerialReader, LiveSession),
                               ("one-byte", OneByteReader, DecodeOnly), ("bulk", SerialReader, DecodeOnly)):
        r = receive(cls, session, args.rate, args.seconds, args.seed)
        name += "" if session is LiveSession else ", decode only"
        print(f"{name:<22} {r['sent']:7d} {r['dropped']:8d} {r['decoded']:8d} {100 * r['decoded'] / r['sent']:7.1f} "
              f"{r['lost']:9d} {r['unaccounted']:7d} {r['calls']:8d}")


if __name__ == "__main__":
    main()
