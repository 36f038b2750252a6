"""Mistakes that looked like success (issue 15.5): each is now a clear refusal or a clear 'nothing came'."""

import json
import socket
import threading

import numpy as np
import pytest

from compass.cli import main
from compass.live import GYRO_UNIT_WINDOW_S
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


def _live_on_socket(monkeypatch, lines: bytes, cal, *extra, quiet=True):
    """Run `compass live` on a local socket serving ``lines`` (``quiet``: with --quiet; ``cal`` None: no --cal, for
    --calibrate tumble); (exit status, thread alive, errors)."""
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
        status = main(["live", "--port", url, *([] if cal is None else ["--cal", str(cal)]),
                       *(["--quiet"] if quiet else []), *extra])
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
    """The field is judged on the first samples before any is used (it used to seed a 10x reference), the unit named
    once the housing turned (a tumble)."""
    from compass.sim.device import simulate_device, tumble_motion
    from compass.sim.stream_formats import board_model

    model = board_model()
    cal = tmp_path / "board.json"
    cal.write_text(json.dumps(model_to_dict(model)))
    s = simulate_device(model, np.arange(300) / 100.0, seed=2, motion=tumble_motion)
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


# ---------------------------------------------------------------- issue 22's bad input, through `compass live`

def _spinning(t_s):
    """Already turning at the first line: 40 deg/s in heading, pitch and roll swinging (degrees, no magnet)."""
    return 40.0 * t_s, 20.0 * np.sin(2.0 * t_s), 25.0 * np.cos(1.3 * t_s), np.zeros(len(t_s))


def _module_lines(case: str) -> bytes:
    """The simulated module's 30 s at 100 Hz as it sends them (t_s, channels, ax,ay,az, gx,gy,gz), spoiled as
    ``case`` says."""
    from compass.sim.device import simulate_device

    model = default_model()
    t = np.arange(0.0, 30.0, 0.01)
    s = simulate_device(model, t, motion=_spinning, seed=2) if case == "starts moving" else \
        simulate_device(model, t, seed=5, gyro_bias=[0.004, -0.003, 0.002])
    names = ["t_s", *model.channels] + ([] if case == "no accelerometer" else ["ax", "ay", "az"]) \
        + ([] if case == "no gyro" else ["gx", "gy", "gz"])
    accel = 9.80665 * s.accel if case.startswith("accel in m/s^2") else s.accel
    gyro = {"gyro in deg/s": np.degrees(s.gyro), "gyro at a rail": np.tile([4.3633, 4.3633, -4.3633], (len(t), 1)),
            "gyro all NaN": np.full_like(s.gyro, np.nan)}.get(case, s.gyro)
    columns = [1e3 * t if case == "t_s in ms" else t, s.raw] + ([] if case == "no accelerometer" else [accel]) + ([] if case == "no gyro" else [gyro])
    rows = [",".join(f"{v:.9g}" for v in row) for row in np.column_stack(columns).tolist()]
    if case == "first line garbage":
        rows[0] = "reset" + rows[0][5:]
    return (",".join(names) + "\r\n" + "\r\n".join(rows) + "\r\n").encode()


@pytest.mark.parametrize("case, options, status, words", [
    ("no gyro", [], 0, "[info] filter: two-vector"),
    ("no accelerometer", [], 2, "its 3000 samples carry no ax,ay,az (the header: t_s,mx,my,mz,gx,gy,gz): no attitude "
                                "without the accelerometer's tilt"),
    ("gyro in deg/s", [], 2, "--gyro-unit"),  # from the accelerometer's tilt or the field's turn, first
    ("first line garbage", [], 0, "[warn] line noise: 1 garbage, 0 partial and 0 invalid lines so far"),
    ("starts moving", [], 0, "[info] filter: gyro"),
    ("gyro at a rail", [], 2, "it holds 4.3633, 4.3633, -4.3633 in every sample: a gyro stuck at a rail"),
    ("gyro all NaN", [], 1, "3000 invalid (a number no module sends, not finite or beyond 1e+12: gx = nan first)"),
    ("t_s in ms", [], 2, "t_s steps by 10 s (median of 25 samples): each step is a gap over the filter's 0.5 s and "
                         "restarts it; a time in milliseconds? (t_s is in seconds); send t_s in seconds, or leave it"),
    ("accel in m/s^2", ["--accel-unit", "m/s2", "--gravity", "1"], 0, "[info] filter: gyro"),
    ("accel in m/s^2, gravity in m/s^2", ["--accel-unit", "m/s2", "--gravity", "9.80665"], 2,
     "--gravity 9.80665 is not what 1 g reads: the accelerometer's median |a| over the start's 101 rows is 1,"),
])
def test_live_on_bad_input_says_it_and_writes_nothing_non_finite(tmp_path, monkeypatch, cal, capsys, case, options,
                                                                 status, words):
    """Issue 22's bad input through `compass live` (a socket sends the module's lines): no gyro (the two-vector
    filter, said), no accelerometer (refused when the session ends: exit 2 naming the header; it said nothing and
    exited 0), a gyro in deg/s (stopped, as the replay refuses it), a first line of garbage (line noise, said), a
    start in motion, a gyro stuck at a rail (stopped, said besides the unit it would be), a gyro of NaN (every line invalid: 'no sample arrived' names the
    cell), --gravity 9.80665 where --accel-unit m/s2 reads the accelerometer in g (refused; it was never used).
    No traceback; the attitude CSV, when written, holds finite numbers only and a row a sample solved."""
    att = tmp_path / "att.csv"
    code, alive, errors = _live_on_socket(monkeypatch, _module_lines(case), cal, "--duration", "5", "--out", str(att),
                                          *options, quiet=False)
    captured = capsys.readouterr()
    said = captured.out + captured.err
    assert code == status and not alive and not errors, said
    assert words in said and "Traceback" not in said, said
    if status == 2:
        assert len(captured.err.strip().splitlines()) == 1 and not att.exists()
        return
    if status == 0:
        from compass.io.table import read_table

        table = read_table(att)
        assert f"{len(table.data)} attitudes from" in said  # a row a sample solved (the rest: after --duration)
        assert all(np.all(np.isfinite(table.column(c))) for c in table.columns)
        if case.startswith("accel"):
            assert np.mean(table.column("accel_used")) > 0.9


@pytest.mark.parametrize("scale", [1.0, np.degrees(1.0)])
def test_a_deg_per_s_gyro_turned_only_about_the_vertical_is_stopped_from_the_field(scale):
    """A level housing turned slowly about the vertical tilts the accelerometer by nothing, so the stream's unit
    check (the gyro against the accelerometer's tilt) never judges; the field turns with it (by cos(dip) of the
    turn), which tells a gyro in deg/s read as rad/s (ratio 57 / cos(dip)) from one read right (about 1 / cos(dip)):
    the session stops on it (its attitudes turned 57 times too fast), the replay refusing it in words."""
    import io

    from compass.live import LiveSession
    from compass.replay import replay
    from compass.sim.device import simulate_device

    def slow_turn(t_s):
        return 20.0 * np.asarray(t_s), np.zeros_like(t_s), np.zeros_like(t_s), np.zeros_like(t_s)

    model = default_model()
    t = np.arange(0.0, 30.0, 0.01)
    s = simulate_device(model, t, motion=slow_turn, seed=2)
    events = []
    session = LiveSession(model, out=io.StringIO(), on_event=lambda level, text: events.append((session.samples, text)))
    replay(session, t, s.raw, s.accel, s.gyro * scale)
    said = [(n, e) for n, e in events if "--gyro-unit" in e]
    assert len(said) == (1 if scale > 1.0 else 0), said
    if said:
        n, words = said[0]
        assert "times more than the calibrated field turns" in words
        assert not any("axes are not the gyro's" in e for _, e in events)  # no remap offered for a unit's fault
        # said within its first window (GYRO_UNIT_WINDOW_S, 10 s here), not on close, and the session stopped there
        assert n <= 1.2 * GYRO_UNIT_WINDOW_S / 0.01 and session.gyro_unit == words
        assert session.samples <= 1.2 * GYRO_UNIT_WINDOW_S / 0.01 and session.closing_hint() is None
    else:
        assert session.gyro_unit is None and session.samples == len(t)
