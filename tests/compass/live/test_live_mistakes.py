"""Mistakes that looked like success (issue 15.5): each is now a clear refusal or a clear 'nothing came'."""

import json
import socket
import threading

import numpy as np
import pytest

from compass.cli import main
from compass.sim.device import default_model
from compass.calibration import model_to_dict


@pytest.fixture
def cal(tmp_path):
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(model_to_dict(default_model())))
    return path


def test_a_mistyped_port_is_refused_at_once_naming_it(tmp_path, cal, capsys):
    port = tmp_path / "ttyUSB9"
    assert main(["live", "--port", str(port), "--cal", str(cal), "--duration", "30"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"cannot open port {port}" in err and "Traceback" not in err


def test_a_mistyped_port_is_refused_at_once_by_the_live_tumble_calibration_too(tmp_path, capsys):
    port = tmp_path / "ttyUSB9"  # it waited for the port until --duration, then blamed too few samples
    assert main(["live", "--port", str(port), "--calibrate", "tumble", "--out", str(tmp_path / "cal.json"),
                 "--duration", "30"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"cannot open port {port}" in err and "Traceback" not in err
    assert not (tmp_path / "cal.json").exists()


def _serve(lines: bytes, server: socket.socket, errors: list) -> None:
    """One connection: wait for the reader's hello, send ``lines``, hold the line until it closes."""
    try:
        conn, _ = server.accept()
        with conn:
            conn.settimeout(20.0)
            conn.recv(16)
            conn.sendall(lines)
            conn.recv(16)
    except OSError as exc:
        errors.append(exc)


def _live_on_socket(monkeypatch, lines: bytes, cal, *extra):
    """Run `compass live` on a local socket serving ``lines``; (exit status, thread alive, errors)."""
    import compass.serial_reader as sr

    original = sr._nonblocking_fd

    def hello(port):  # pyserial's socket open() drains what came before: the peer sends after this
        port.write(b"hello\n")
        return original(port)

    monkeypatch.setattr(sr, "_nonblocking_fd", hello)
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(20.0)
    errors = []
    thread = threading.Thread(target=_serve, args=(lines, server, errors), daemon=True)
    thread.start()
    url = f"socket://127.0.0.1:{server.getsockname()[1]}"
    try:
        status = main(["live", "--port", url, "--cal", str(cal), "--quiet", *extra])
    finally:
        thread.join(30.0)
        server.close()
    return status, thread.is_alive(), errors


def test_a_module_without_the_calibrations_channels_is_refused_naming_them(tmp_path, monkeypatch, cal, capsys):
    header = b"t_s,seq,mx,my,ax,ay,az\r\n"  # the calibration's channels are mx,my,mz: mz is missing
    rows = b"".join(b"%.2f,%d,1,2,0,0,1\r\n" % (i / 100, i) for i in range(150))
    att = tmp_path / "att.csv"
    status, alive, errors = _live_on_socket(monkeypatch, header + rows + header + rows, cal, "--duration", "20",
                                            "--out", str(att))
    err = capsys.readouterr().err.strip()
    assert status == 2 and not alive and not errors
    assert len(err.splitlines()) == 1 and "lacks the calibration's channel(s) mz" in err and str(cal) in err
    assert not att.exists() and not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]  # no output


def test_no_sample_in_the_session_is_said_and_not_a_success(monkeypatch, cal, capsys):
    status, alive, errors = _live_on_socket(monkeypatch, b"\x00\x13 noise at the wrong baud rate \xfe\r\n" * 20, cal,
                                            "--duration", "1")
    captured = capsys.readouterr()
    assert status == 1 and not alive and not errors
    assert "no sample arrived" in captured.err and "bad line" in captured.err
    assert "garbage 20" in captured.out  # the summary line still counts what came


def test_evaluate_refuses_a_bench_calibration(tmp_path, capsys):
    """`compass evaluate --cal` with a four-flip calibration printed 'reference |B| 2207.7 uT'."""
    from compass.sim.fourflip import simulate_fourflip, write_fourflip

    rec, _ = write_fourflip(simulate_fourflip(seed=1), tmp_path / "rec.csv")
    bench = tmp_path / "bench.json"
    assert main(["calibrate", str(rec), "--out", str(bench), "--quiet", "--no-diagnose"]) == 0
    capsys.readouterr()
    trial = tmp_path / "trial.mat"
    trial.write_text("never read")
    assert main(["evaluate", str(trial), "--cal", str(bench)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bench) in err and "tumble calibration" in err


def test_a_module_sending_mg_to_a_calibration_in_ut_is_said_with_the_factor_not_taken(tmp_path, monkeypatch, capsys):
    """The field is judged on the first samples before any is used (it used to seed a 10x reference)."""
    from compass.sim.device import simulate_device
    from compass.sim.stream_formats import board_model

    model = board_model()
    cal = tmp_path / "board.json"
    cal.write_text(json.dumps(model_to_dict(model)))
    s = simulate_device(model, np.arange(300) / 100.0, seed=2)
    rows = b"".join(b"%.2f,%.2f,%.2f,%.5f,%.5f,%.5f\r\n" % (*(10.0 * m), *a) for m, a in zip(s.raw, s.accel))
    att = tmp_path / "att.csv"
    status, alive, errors = _live_on_socket(monkeypatch, b"mx,my,mz,ax,ay,az\r\n" + rows, cal, "--duration", "20",
                                            "--out", str(att))
    err = capsys.readouterr().err
    assert status == 2 and not alive and not errors
    assert len(err.strip().splitlines()) == 1 and "mG taken as uT" in err and "--mag-unit" in err and str(cal) in err
    assert not att.exists()  # nothing was taken
    status, _, _ = _live_on_socket(monkeypatch, b"mx,my,mz,ax,ay,az\r\n" + rows, cal, "--duration", "3",
                                   "--mag-unit", "mG")
    assert status == 0


def test_a_session_whose_field_is_rejected_throughout_ends_with_a_hint():
    """The wrong sensor's calibration (or a reference the module does not read) showed MAG-REJECTED:dip
    throughout and ended without a word: the session now says why and what to check; a right one says nothing."""
    import io
    import time

    import numpy as np

    from compass.live import LiveSession
    from compass.serial_reader import Chunk
    from compass.sim.device import PtyDevice, default_model, simulate_device
    from compass.site import known_reference

    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    stream = device._header + b"".join(device._lines(simulate_device(model, np.arange(400) / 100.0, seed=4), 0))
    hints = {}
    for name, dip in (("right", model.dip_deg), ("wrong", model.dip_deg - 25.0)):
        session = LiveSession(model, out=io.StringIO(), reference=known_reference(dip, model.field_norm))
        for k in range(0, len(stream), 3000):
            session.feed(Chunk(time.perf_counter(), stream[k:k + 3000]))
        session.close()
        hints[name] = session.closing_hint()
    assert hints["right"] is None
    assert "mostly for its dip" in hints["wrong"] and f"against the reference's {model.dip_deg - 25:.1f} deg" in hints["wrong"]
    assert "Is --cal the calibration" in hints["wrong"]
