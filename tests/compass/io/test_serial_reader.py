"""The reader takes what the port holds in bulk (issue 16.2), over a local socket and a pty.

Every thread here is bounded (socket and select timeouts, a deadline) and joined; the sockets and
file descriptors are closed in ``finally``.
"""

import os
import pty
import select
import socket
import threading
import time
import tty

from compass.io.lines import LineDecoder
from compass.serial_reader import Chunk, LinkEvent, SerialReader

CHANNELS = ("mx", "my", "mz")
N_SAMPLES = 3000
WIDE = 147  # unknown columns after mx,my,mz: a 150-column header


def _stream() -> bytes:
    """A 150-column header, samples, a 1 MB line, more samples (``seq`` 0..N-1)."""
    header = ",".join(["seq", *CHANNELS] + [f"extra{i}" for i in range(WIDE - 1)]).encode() + b"\r\n"
    rows = [f"{i},{i % 7}.5,-2.25,{i * 1e-3:.3f}".encode() + b",0" * (WIDE - 1) + b"\r\n" for i in range(N_SAMPLES)]
    half = N_SAMPLES // 2
    return header + b"".join(rows[:half]) + b"9" * (1 << 20) + b"\r\n" + b"".join(rows[half:])


def _read_all(url: str, on_connect, deadline_s: float = 30.0):
    """Decode from ``url`` until every sample came or the deadline passed: (decoder, chunks read)."""
    decoder, chunks = LineDecoder(CHANNELS), 0
    stop, deadline = threading.Event(), time.monotonic() + deadline_s
    reader = SerialReader(url, read_timeout_s=0.05, retry_s=0.05)
    timer = threading.Timer(deadline_s, stop.set)  # a quiet line yields nothing: the timer ends the loop
    timer.start()
    try:
        for item in reader.items(stop):
            if isinstance(item, LinkEvent):
                if item.kind == "connected":
                    on_connect(reader)
            elif isinstance(item, Chunk):
                chunks += 1
                decoder.feed(item.data)
            if decoder.stats.samples == N_SAMPLES or time.monotonic() > deadline:
                break
    finally:
        timer.cancel()
        timer.join(5.0)
        reader.close()
    return decoder, chunks


def _check(decoder: LineDecoder, chunks: int, n_bytes: int) -> None:
    s = decoder.stats
    assert s.samples == N_SAMPLES and s.dropped == 1 and s.garbage == 1  # the 1 MB line, counted once
    assert s.lost == 0 and s.headers == 1
    # in bulk: one byte a read would be ~1.5 million reads
    assert chunks < n_bytes / 256, f"{chunks} reads for {n_bytes} bytes"


def test_socket_reads_in_bulk_and_keeps_every_sample():
    stream = _stream()
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(10.0)
    port = server.getsockname()[1]
    errors = []

    def module():
        try:
            conn, _ = server.accept()
            with conn:
                conn.settimeout(30.0)
                conn.recv(16)  # the reader's hello: its open() drained what came before
                conn.sendall(stream)
                conn.recv(16)  # hold the line open until the reader is done
        except OSError as exc:
            errors.append(exc)

    thread = threading.Thread(target=module, daemon=True)
    thread.start()
    try:
        decoder, chunks = _read_all(f"socket://127.0.0.1:{port}", lambda reader: reader.port.write(b"hello\n"))
    finally:
        thread.join(40.0)
        server.close()
    assert not thread.is_alive() and not errors
    _check(decoder, chunks, len(stream))


def test_pty_reads_in_bulk_and_keeps_every_sample():
    stream = _stream()
    master, slave = pty.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    opened, done = threading.Event(), threading.Event()
    sent = []

    def module():
        if not opened.wait(10.0):
            return
        view, deadline = memoryview(stream), time.monotonic() + 30.0
        while view and not done.is_set() and time.monotonic() < deadline:
            if select.select([], [master], [], 0.1)[1]:
                try:
                    n = os.write(master, view[:4096])
                except BlockingIOError:
                    continue
                view = view[n:]
        sent.append(len(stream) - len(view))

    thread = threading.Thread(target=module, daemon=True)
    thread.start()
    try:
        decoder, chunks = _read_all(os.ttyname(slave), lambda reader: opened.set())
    finally:
        done.set()
        thread.join(40.0)
        os.close(master)
        os.close(slave)
    assert not thread.is_alive() and sent == [len(stream)]
    _check(decoder, chunks, len(stream))
