"""`compass live` over a socket at 2 kHz for 5 s with hostile lines mixed into a good stream (issue 23).

The session keeps running, every good sample's attitude row equals the one the clean stream gives,
every hostile line is counted where it belongs (garbage, invalid, partial, repeated) and none is
lost in transit, and no row holds a number that is not finite.
"""

import io
import json
import math
import os
import re
import signal
import socket
import threading
import time

import numpy as np

from compass.calibration import model_to_dict
from compass.cli import main
from compass.io.lines import format_line
from compass.live import LiveSession
from compass.serial_reader import Chunk
from compass.sim.device import PtyDevice, default_model, simulate_device

RATE_HZ = 2000.0
SECONDS = 5.0
MODEL = default_model()


def _good() -> tuple[bytes, list[bytes]]:
    device = PtyDevice(MODEL, rate_hz=RATE_HZ)
    t = np.arange(int(RATE_HZ * SECONDS)) / RATE_HZ
    return device._header, device._lines(simulate_device(MODEL, t, seed=5, rate_hz=RATE_HZ), 0)


def _cells(line: bytes) -> list[str]:
    return line.split(b"*")[0].decode().split(",")


def _hostile(k: int, previous: bytes) -> tuple[bytes, str]:
    """The k-th hostile line (after the good line ``previous``) and where the decoder must count it."""
    cells = _cells(previous)  # t_s, seq, mx, my, mz, ax, ay, az, gx, gy, gz

    def edit(i, text):
        c = list(cells)
        c[i] = text
        return format_line(c)

    kinds = [
        (b"\x00\xff\xfe\x13 noise\r\n", "garbage"),
        (previous[:-5] + b"*ZZ\r\n", "garbage"),  # a checksum that does not match
        (b"7" * 9000 + b"\r\n", "garbage"),  # overlong
        (format_line([*cells, "1"]), "garbage"),  # a cell too many
        (edit(2, "nan"), "invalid"),
        (edit(3, "1e308"), "invalid"),
        (edit(5, "-1e300"), "invalid"),
        (edit(0, "1e300"), "invalid"),  # t_s
        (edit(1, "-1"), "invalid"),  # seq
        (edit(1, str(10**30)), "invalid"),
        (edit(9, "inf"), "invalid"),
        (format_line(cells, with_checksum=False), "partial"),  # the header carries a checksum: this line must
        (b"1,2\r\n", "partial"),
        (edit(2, "999"), "repeated"),  # the previous line's seq again, other values
        (b"# a comment\r\n", "comments"),
    ]
    return kinds[k % len(kinds)]


def _stream() -> tuple[list[bytes], list[bytes], dict]:
    header, good = _good()
    chunks, expected = [], {"garbage": 0, "invalid": 0, "partial": 0, "repeated": 0, "comments": 0}
    for i, line in enumerate(good):
        chunk = (header if i % int(RATE_HZ) == 0 else b"") + line
        if i % 9 == 5:
            hostile, where = _hostile(i // 9, line)
            chunk += hostile
            expected[where] += 1
        chunks.append(chunk)
    return chunks, [header, *good], expected


def _serve(chunks: list[bytes], server: socket.socket, errors: list, done: threading.Event) -> None:
    """Wait for the reader's hello, then send ``chunks`` paced at RATE_HZ; hold the line until it closes.
    ``done`` is set once everything is sent."""
    try:
        conn, _ = server.accept()
        with conn:
            conn.settimeout(30.0)
            conn.recv(16)
            start = time.perf_counter()
            batch = 20  # 10 ms of lines a send
            for k in range(0, len(chunks), batch):
                delay = start + k / RATE_HZ - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                conn.sendall(b"".join(chunks[k:k + batch]))
            done.set()
            conn.recv(16)
    except OSError as exc:
        errors.append(exc)
    finally:
        done.set()


def _clean_rows(lines: list[bytes]) -> list[str]:
    out = io.StringIO()
    session = LiveSession(MODEL, out=out)
    stream = b"".join(lines)
    for k in range(0, len(stream), 4096):
        session.feed(Chunk(time.perf_counter(), stream[k:k + 4096]))
    session.close()
    return out.getvalue().splitlines()


def _without_latency(rows: list[str]) -> list[str]:
    return [row.rsplit(",", 1)[0] for row in rows]


def _ctrl_c_when_all_is_read(sessions: list, lines: int, done: threading.Event, finished: threading.Event) -> None:
    """Ctrl-C (SIGINT to this process: the handler of `compass live` on the main thread) once the session has
    counted every line sent, as a user would stop it; the session may lag the 2 kHz on a busy machine."""
    while not finished.wait(0.05):
        if done.is_set() and sessions:
            s = sessions[0].decoder.stats
            if s.samples + s.bad_lines + s.comments + s.headers >= lines:
                os.kill(os.getpid(), signal.SIGINT)
                return


def test_live_keeps_every_good_sample_of_a_stream_laced_with_hostile_lines(tmp_path, monkeypatch, capsys):
    import compass.serial_reader as sr

    chunks, clean_lines, expected = _stream()
    original = sr._nonblocking_fd

    def hello(port):  # pyserial's socket open() drains what came before: the peer sends after this
        port.write(b"hello\n")
        return original(port)

    monkeypatch.setattr(sr, "_nonblocking_fd", hello)
    sessions = []
    init = LiveSession.__post_init__

    def keep(self):
        init(self)
        sessions.append(self)

    monkeypatch.setattr(LiveSession, "__post_init__", keep)
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(model_to_dict(MODEL)))
    out = tmp_path / "att.csv"
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(30.0)
    errors, done, finished = [], threading.Event(), threading.Event()
    thread = threading.Thread(target=_serve, args=(chunks, server, errors, done), daemon=True)
    n_lines = sum(chunk.count(b"\n") for chunk in chunks)
    stopper = threading.Thread(target=_ctrl_c_when_all_is_read, args=(sessions, n_lines, done, finished), daemon=True)
    thread.start()
    stopper.start()
    try:  # --duration: the hard bound, should the session never read everything
        status = main(["live", "--port", f"socket://127.0.0.1:{server.getsockname()[1]}", "--cal", str(cal),
                       "--quiet", "--out", str(out), "--duration", "120"])
    finally:
        finished.set()
        stopper.join(10.0)
        thread.join(30.0)
        server.close()
    assert not thread.is_alive() and not stopper.is_alive() and not errors and done.is_set()
    captured = capsys.readouterr()
    assert status == 0, captured.err
    summary = re.search(r"(\d+) attitudes from (\d+) samples; dropped lines (\d+) \(garbage (\d+), invalid (\d+), "
                        r"partial (\d+), before a header (\d+), repeated seq (\d+), lost in transit (\d+)\)",
                        captured.out)
    attitudes, samples, dropped, garbage, invalid, partial, unheaded, repeated, lost = map(int, summary.groups())
    n_good = len(clean_lines) - 1
    assert samples == n_good and lost == 0 and unheaded == 0  # every good line arrived and was used
    assert (garbage, invalid, partial, repeated) == (expected["garbage"], expected["invalid"],
                                                     expected["partial"], expected["repeated"])
    assert dropped == sum(expected.values()) - expected["comments"]
    rows = [row for row in out.read_text().splitlines()]
    clean = _clean_rows(clean_lines)
    assert rows[:2] == clean[:2]  # the gate legend and the columns
    assert attitudes == len(rows) - 2 == len(clean) - 2
    assert _without_latency(rows[2:]) == _without_latency(clean[2:])  # the same attitudes, to the CSV's digits
    assert all(math.isfinite(float(cell)) for row in rows[2:] for cell in row.split(","))
