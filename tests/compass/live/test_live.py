import io
import json
import signal
import socket
import threading
import time

import numpy as np
import pytest

from compass.cli import main
from compass.frames import heading_pitch_roll
from compass.io.lines import format_line
from compass.io.table import read_table
from compass.live import LiveSession
from compass.calibration import model_to_dict
from compass.serial_reader import Chunk, LinkEvent, SerialReader
from compass.sim.device import PtyDevice, default_model, scripted_motion, simulate_device
from tests._proc import Proc, compass_command

rr = pytest.importorskip("rerun")
from tests.rrd_read import blueprint_views, entity_paths, read_column, read_static, scalars  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from compass.filter import FilterConfig  # noqa: E402
from compass.viz import ENTITIES, RerunSink  # noqa: E402


def wrap(d):
    return np.mod(np.asarray(d) + 180.0, 360.0) - 180.0


def test_session_logs_what_it_writes(tmp_path):
    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    samples = simulate_device(model, np.arange(300) / 100.0, seed=1)
    lines = device._lines(samples, 0)
    stream = device._header + b"".join(lines[:100]) + b"\x00\xffjunk\r\n" + lines[100][:20] + b"\r\n" + b"".join(lines[101:])
    out, events = io.StringIO(), []
    sink = RerunSink.for_model(tmp_path / "s.rrd", model, FilterConfig.from_model(model), recording_id="s")
    session = LiveSession(model, out=out, sink=sink, on_event=lambda level, text: events.append(text))
    session.feed(LinkEvent("connected", "connected to test", 0.0))
    for k in range(0, len(stream), 700):  # arbitrary chunk boundaries
        session.feed(Chunk(time.perf_counter(), stream[k:k + 700]))
    session.close()
    stats = session.decoder.stats
    assert (stats.samples, stats.garbage, stats.partial, stats.lost) == (299, 1, 1, 0)

    rrd = tmp_path / "s.rrd"
    assert {"/" + e for e in ENTITIES} <= entity_paths(rrd)
    csv_path = tmp_path / "att.csv"
    csv_path.write_text(out.getvalue())
    table = read_table(csv_path)
    seq, heading = read_column(rrd, "/compass/heading_deg", "Scalars:scalars")
    assert len(seq) == len(table.data) == 299 and list(seq) == list(range(1, 300))
    np.testing.assert_allclose([h[0] for h in heading], table.column("heading_deg"), atol=1e-3)  # CSV: 3 decimals
    frames, quat = read_column(rrd, "/world/housing", "Transform3D:quaternion")
    h, p, r = heading_pitch_roll(Rotation.from_quat(np.array([q[0] for q in quat])))
    rows = frames - 1  # sample numbers count from 1
    np.testing.assert_allclose(wrap(h - table.column("heading_deg")[rows]), 0.0, atol=2e-3)  # float32 quaternions
    np.testing.assert_allclose(p, table.column("pitch_deg")[rows], atol=2e-3)
    # the truth: the sample rows are t = seq / 100 of the script
    settled = table.column("t_s") > 0.5
    truth_heading = scripted_motion(table.column("t_s"))[0]
    # the still module's heading error stays within the filter's own 1-sigma (was a fixed 0.5 deg that
    # seed 1 met by luck: over seeds 1-8 the RMS error is 0.2-1.3 deg, the reported sigma 1.6-1.8 deg)
    error_rms = np.sqrt(np.mean(wrap(table.column("heading_deg") - truth_heading)[settled] ** 2))
    assert error_rms < np.sqrt(np.mean(table.column("heading_sigma_deg")[settled] ** 2))
    # 3-D views at display rate: the field in the world, gravity in the housing turned back by the housing
    frames, field = read_column(rrd, "/world/field", "Arrows3D:vectors")
    assert 0 < len(frames) < 299 / 2  # 100 Hz decimated to 30 frames a second
    dip = np.radians(model.dip_deg)
    np.testing.assert_allclose(np.mean([f[0] for f in field], axis=0), [np.cos(dip), 0, -np.sin(dip)], atol=0.01)
    seq_g, gravity = read_column(rrd, "/housing/gravity", "Arrows3D:vectors")
    seq_q, quat = read_column(rrd, "/world/housing", "Transform3D:quaternion")
    assert list(seq_g) == list(seq_q) == list(frames)
    down_w = Rotation.from_quat(np.array([q[0] for q in quat])).apply(np.array([g[0] for g in gravity]))
    np.testing.assert_allclose(np.mean(down_w, axis=0), [0, 0, -1], atol=0.01)
    # in the housing, the gate's cone (drawn in the world under housing/expected = R^-1) holds the field
    _, q_inv = read_column(rrd, "/housing/expected", "Transform3D:quaternion")
    r_inv = Rotation.from_quat(np.array([q[0] for q in q_inv]))
    r = Rotation.from_quat(np.array([q[0] for q in quat]))
    assert np.max((r_inv * r).magnitude()) < 1e-5
    _, field_h = read_column(rrd, "/housing/field", "Arrows3D:vectors")
    cone_axis = r_inv.apply([np.cos(dip), 0, -np.sin(dip)])
    field_h = np.array([f[0] for f in field_h])
    off_axis = np.degrees(np.arccos(np.sum(cone_axis * field_h, axis=1) / np.linalg.norm(field_h, axis=1)))
    assert np.max(off_axis) < FilterConfig.from_model(model).dip_tolerance_deg
    # the CSV's names and meanings: gate 0 is "field used"; the sigma band is the angle -+ its sigma
    _, gate = scalars(rrd, "/compass/gate")
    np.testing.assert_array_equal(gate[:, 0], table.column("gate"))
    assert np.all(gate == 0)
    _, band = scalars(rrd, "/compass/heading_deg/sigma_band")
    sigma = table.column("heading_sigma_deg")
    np.testing.assert_allclose(band, table.column("heading_deg")[:, None] + sigma[:, None] * [-1, 1], atol=2e-3)
    _, latency = scalars(rrd, "/compass/latency_ms")
    np.testing.assert_allclose(latency[:, 0], table.column("latency_ms"), atol=1e-3)
    _, raw = scalars(rrd, "/raw/mag")
    np.testing.assert_allclose(raw, np.delete(samples.raw, 100, axis=0), rtol=1e-4, atol=1e-4)  # line 100 was cut
    _, texts = read_column(rrd, "/events", "TextLog:text")
    assert any("header: t_s,seq" in t[0] for t in texts) and any("line noise" in t[0] for t in texts)
    assert any("connected to test" in t for t in events)
    # the reference the session learnt (first quiet second) is the one drawn, and the layout came along
    (label,) = read_static(rrd, "/world/reference_field/label", "Points3D:labels")[-1]
    assert f"dip {session.reference.dip_deg:.1f} deg" in label  # short: where it came from is an event line
    assert any(session.reference.description in t[0] for t in texts)
    origins = {v.get("origin") for v in blueprint_views(rrd)}
    assert {"/world", "/housing", "/compass/field_ratio", "/compass/dip_deg", "/raw/mag", "/events"} <= origins
    t_events, _ = read_column(rrd, "/events", "TextLog:text", index="t")
    t_first, _ = read_column(rrd, "/compass/heading_deg", "Scalars:scalars", index="t")
    assert min(t_events) >= min(t_first)  # the events timeline starts at the first sample


def test_reader_reconnects_when_a_socket_peer_returns():
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(10.0)  # the peer thread's every wait is bounded: it always ends
    port = server.getsockname()[1]

    def peer():
        for k in range(2):
            conn, _ = server.accept()
            with conn:
                conn.settimeout(10.0)
                conn.recv(16)  # wait for the reader: its open() drains earlier bytes
                conn.sendall(f"mx,my,mz\n{k},2,3\n".encode())
                time.sleep(0.2)

    thread = threading.Thread(target=peer, daemon=True)
    thread.start()
    stop, kinds, data = threading.Event(), [], b""
    reader = SerialReader(f"socket://127.0.0.1:{port}", read_timeout_s=0.05, retry_s=0.05)
    deadline = time.monotonic() + 20.0
    try:
        for item in reader.items(stop):
            if isinstance(item, LinkEvent):
                kinds.append(item.kind)
                if item.kind == "connected":
                    reader.port.write(b"hello\n")
                if kinds.count("connected") == 2 and item.kind == "disconnected" or time.monotonic() > deadline:
                    break
            else:
                data += item.data
    finally:
        reader.close()
        thread.join(25)
        server.close()
    assert not thread.is_alive()
    assert kinds[:4] == ["connected", "disconnected", "connected", "disconnected"]
    assert data == b"mx,my,mz\n0,2,3\nmx,my,mz\n1,2,3\n"
    assert reader.disconnects == 2


def test_pty_device_end_to_end_with_noise_disconnect_and_ctrl_c(tmp_path):
    """`compass live` waits for the port, so the module's disconnect (5 s after it starts) comes after the
    receiver is running however slow the machine; every wait is bounded and both processes are killed
    on the way out (the test fails, never hangs)."""
    cal, link = tmp_path / "cal.json", tmp_path / "compass-dev"
    rrd, att = tmp_path / "live.rrd", tmp_path / "att.csv"
    cal.write_text(json.dumps(model_to_dict(default_model())))
    with Proc(compass_command("live", "--port", str(link), "--cal", str(cal), "--rerun", str(rrd), "--out", str(att),
                              "--wait", "60")) as live:
        assert live.wait_for(lambda line: "waiting for" in line, 60.0), live.transcript()
        with Proc(compass_command("device", "--pty", "--cal", str(cal), "--link", str(link), "--rate", "100",
                                  "--garbage", "0.02", "--truncate", "0.02", "--disconnect-at", "5",
                                  "--disconnect-for", "0.8", "--duration", "60")) as device:
            # wait for the reconnect after the module's disconnect, then two more readouts
            state = {"connects": 0, "after": 0}

            def enough(line):
                state["connects"] += "] connected to" in line
                state["after"] += state["connects"] >= 2 and line.startswith("heading")
                return state["after"] >= 2

            assert live.wait_for(enough, 60.0), live.transcript() + device.transcript()
            returncode = live.stop(signal.SIGINT, 20.0)
            device.stop(signal.SIGINT, 10.0)
    err = "".join(live.err)
    assert returncode == 0, err
    output = "".join(live.out)
    summary = output.strip().splitlines()[-1]
    assert summary.startswith("compass live:") and "1 disconnect(s)" in summary and "wrote" in summary
    assert "disconnected" in output and "line noise" in output
    dropped = int(summary.split("dropped lines ")[1].split()[0])
    assert dropped > 0

    table = read_table(att)  # complete after Ctrl-C: every row parses
    t = table.column("t_s")
    assert len(t) > 200 and np.all(np.diff(t) > 0)
    truth = scripted_motion(t)
    restart = t[np.argmax(np.diff(t) > 0.5) + 1]  # the first sample after the disconnect
    settled = (t > t[0] + 1.0) & ((t < 5.0) | (t > restart + 1.0)) & (truth[3] == 0)  # away from the magnet
    heading_error = wrap(table.column("heading_deg") - truth[0])[settled]
    assert np.sqrt(np.mean(heading_error**2)) < 1.0
    np.testing.assert_allclose(table.column("pitch_deg")[settled], truth[1][settled], atol=1.0)

    paths = entity_paths(rrd)
    assert {"/" + e for e in ENTITIES} <= paths
    seq, heading = read_column(rrd, "/compass/heading_deg", "Scalars:scalars")
    assert len(seq) == len(t)
    np.testing.assert_allclose([h[0] for h in heading], table.column("heading_deg"), atol=1e-3)
    _, texts = read_column(rrd, "/events", "TextLog:text")
    texts = [x[0] for x in texts]
    assert any("disconnected" in x for x in texts) and sum("connected to" in x for x in texts) >= 2


def test_live_bad_input_exits_2(tmp_path, capsys):
    assert main(["live", "--port", "/dev/null", "--cal", str(tmp_path / "missing.json")]) == 2
    assert "cannot read calibration" in capsys.readouterr().err
    cal = tmp_path / "cal.json"
    assert main(["device", "--pty", "--save-cal", str(cal), "--duration", "-1"]) == 2
    assert not cal.exists()  # bad options are refused before anything is written
    cal.write_text(__import__("json").dumps(model_to_dict(default_model())))
    assert main(["live", "--port", "nosuch://x", "--cal", str(cal)]) == 2
    assert "nosuch" in capsys.readouterr().err
    assert main(["live", "--port", "/dev/null", "--cal", str(cal), "--site", "95,0"]) == 2
    assert "latitude" in capsys.readouterr().err
    keep = tmp_path / "keep.txt"
    keep.write_text("keep")
    assert main(["device", "--pty", "--link", str(keep), "--duration", "0.1"]) == 2
    assert "not a symbolic link" in capsys.readouterr().err and keep.read_text() == "keep"
    assert main(["device", "--pty", "--link", str(tmp_path / "nosuch" / "pty"), "--duration", "0.1"]) == 2
    assert "its folder does not exist" in capsys.readouterr().err  # was exit 1, "failed: FileNotFoundError"


def test_live_exits_when_asked_while_waiting_for_the_port(tmp_path, capsys):
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(model_to_dict(default_model())))
    port = tmp_path / "nothing"
    assert main(["live", "--port", str(port), "--cal", str(cal), "--wait", "60", "--duration", "0.3"]) == 1
    captured = capsys.readouterr()
    # a port that never opened is said in one line, without a summary of a session that never ran
    assert "waiting for" in captured.out and "attitudes" not in captured.out
    assert f"no sample arrived from {port}" in captured.err and "never opened" in captured.err


def test_format_line_round_trip_through_loop_url():
    reader = SerialReader("loop://")
    stop = threading.Event()
    items = reader.items(stop)
    assert next(items).kind == "connected"
    reader.port.write(format_line(["mx", "my", "mz"]) + format_line([1, 2, 3]))
    session = LiveSession(default_model())
    session.feed(next(items))
    reader.close()
    assert session.decoder.stats.samples == 1 and session.decoder.header.checksummed


def test_session_reports_the_magnet_gate_closing_and_opening():
    """The scripted magnet (22.5 to 31 s) closes the field gate and the session says so, then reopens it."""
    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    lines = device._lines(simulate_device(model, np.arange(2000, 3400) / 100.0, seed=1), 0)
    stream = device._header + b"".join(lines)
    events = []
    session = LiveSession(model, on_event=lambda level, text: events.append((level, text)))
    for k in range(0, len(stream), 700):
        session.feed(Chunk(time.perf_counter(), stream[k:k + 700]))
    session.close()
    gate = [e for e in events if e[1].startswith("field ")]
    assert gate[0][0] == "warn" and gate[0][1].startswith("field rejected")
    assert ("info", "field used again") in gate


def _site_stream(dip_deg, field_ut, seconds=12.0):
    """The default module used at another site: its stream (header and lines) and the calibration model."""
    from dataclasses import replace

    model = default_model()
    there = replace(model, dip_deg=dip_deg, field_norm=field_ut, field_ut=field_ut)
    device = PtyDevice(there, rate_hz=100.0)
    t = np.arange(int(seconds * 100)) / 100.0
    return model, device._header + b"".join(device._lines(simulate_device(there, t, seed=3), 0)), t


def _run(session, stream):
    for k in range(0, len(stream), 700):
        session.feed(Chunk(time.perf_counter(), stream[k:k + 700]))
    session.close()


def test_an_accelerometer_that_reads_gravity_is_stopped_against_the_calibrations_own_dip():
    """No site given: the calibration's own dip (measured against its accelerometer) judges the stream. A module
    whose accelerometer reads gravity (-a) mirrors the dip and every heading is 180 deg off: stopped, naming
    --accel-sign -1, which reads it right; a four-flip's assumed hemisphere judges nothing."""
    from dataclasses import replace

    from compass.io.streams import StreamOptions

    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    t = np.arange(1200) / 100.0
    honest = simulate_device(model, t, seed=3)
    negated = device._header + b"".join(device._lines(replace(honest, accel=-honest.accel), 0))
    wrong = LiveSession(model, out=io.StringIO(), sign_from_bench=False)
    _run(wrong, negated)
    assert "--accel-sign -1" in wrong.turned_over and f"dip {model.dip_deg:+.1f} deg" in wrong.turned_over
    assumed = LiveSession(model, out=io.StringIO())  # sign_from_bench: the calibration's dip sign an assumption
    _run(assumed, negated)
    assert assumed.turned_over is None
    fixed = LiveSession(model, out=io.StringIO(), sign_from_bench=False, stream=StreamOptions(accel_sign=-1))
    _run(fixed, negated)
    assert fixed.turned_over is None
    rows = np.array([line.split(",") for line in fixed.out.getvalue().splitlines()[2:]], dtype=float)
    err = wrap(rows[:, 1] - scripted_motion(rows[:, 0])[0])
    assert len(rows) == len(t) and np.sqrt(np.mean(err[rows[:, 0] > 2.0] ** 2)) < 1.0


def test_live_at_another_site_seeds_its_reference_from_the_first_quiet_second():
    from compass.site import known_reference

    model, stream, t = _site_stream(48.0, 45.0)  # the bench: dip 60, |B| 50
    seeded = LiveSession(model, out=io.StringIO())
    _run(seeded, stream)
    assert abs(seeded.reference.dip_deg - 48.0) < 0.3 and abs(seeded.reference.field_norm - 45.0) < 0.3
    bench = LiveSession(model, reference=known_reference(model.dip_deg, model.field_norm), out=io.StringIO())
    _run(bench, stream)
    rows = {name: np.array([line.split(",") for line in s.out.getvalue().splitlines()[2:]], dtype=float)
            for name, s in (("seeded", seeded), ("bench", bench))}
    assert len(rows["seeded"]) == len(t)  # the held samples are solved too
    used = {name: r[:, 8].mean() for name, r in rows.items()}  # mag_used
    assert used["seeded"] > 0.99 and used["bench"] < 0.01  # the bench's dip rejects every sample
    err = wrap(rows["seeded"][:, 1] - scripted_motion(rows["seeded"][:, 0])[0])
    assert np.sqrt(np.mean(err[rows["seeded"][:, 0] > 2.0] ** 2)) < 1.0


def test_live_against_a_site_whose_dip_has_the_other_sign_says_the_field_is_turned_over():
    """A calibration whose field reads upside down at the given site (a four-flip bench calibrated in the other
    hemisphere without its latitude): the first estimates' median dip is the site's turned over."""
    from compass.site import known_reference

    model, stream, _ = _site_stream(48.0, 45.0)
    right = LiveSession(model, reference=known_reference(48.0, 45.0))
    _run(right, stream)
    assert right.turned_over is None and right.samples > 100
    wrong = LiveSession(model, reference=known_reference(-48.0, 45.0))
    _run(wrong, stream)
    assert "upside down" in wrong.turned_over and "site_lat_deg" in wrong.turned_over
    other_kind = LiveSession(model, reference=known_reference(-48.0, 45.0), sign_from_bench=False)
    _run(other_kind, stream)
    assert "upside down" in other_kind.turned_over and "site_lat_deg" not in other_kind.turned_over
    short = LiveSession(model, reference=known_reference(-48.0, 45.0))  # fewer estimates than the check takes
    short.feed(Chunk(time.perf_counter(), stream[: len(stream) // 40]))
    assert short.turned_over is None and short.samples == 0  # held in the start window, as without a site
    short.close()
    assert "upside down" in short.turned_over and 10 < short.samples < 100  # judged on close, on what there was


def test_a_stream_shorter_than_the_quiet_second_is_still_solved_when_it_ends():
    model, stream, _ = _site_stream(48.0, 45.0, seconds=0.4)  # 40 samples: shorter than the quiet second
    session = LiveSession(model, out=io.StringIO())
    session.feed(Chunk(time.perf_counter(), stream))
    assert session.samples == 0 and session.decoder.stats.samples == 40  # held for the reference
    session.close()
    assert session.samples == 40 and abs(session.reference.dip_deg - 48.0) < 1.0


def test_live_with_a_site_writes_true_heading(tmp_path):
    from compass.site import Site, reference_from_site

    site = Site.parse("47.6,-122.3", "2026-06-01")
    wmm = site.field()
    model, stream, t = _site_stream(wmm.dip_deg, wmm.field_ut, seconds=3.0)
    session = LiveSession(model, out=io.StringIO(), reference=reference_from_site(site, field_ut=1.0))
    _run(session, stream)
    (tmp_path / "a.csv").write_text(session.out.getvalue())
    table = read_table(tmp_path / "a.csv")
    assert table.columns[-2:] == ("heading_true_deg", "heading_true_sigma_deg") and len(table.data) == len(t)
    np.testing.assert_allclose(wrap(table.column("heading_true_deg") - table.column("heading_deg")),
                               wmm.declination_deg, atol=2e-3)
    assert np.all(table.column("heading_true_sigma_deg") >= wmm.declination_sigma_deg - 1e-3)
    assert "true" in session.readout(100.0)


def test_live_turns_the_module_into_the_product_frame_of_an_installed_calibration():
    from compass.calibration import ImuCorrection
    from compass.frames import r_world_from_housing
    from compass.installed import installed_model

    model, stream, t = _site_stream(60.0, 50.0, seconds=8.0)
    yaw = Rotation.from_euler("z", 7.0, degrees=True)  # R_product<-housing
    product = installed_model(model, np.zeros(3), np.eye(3), alignment=yaw.as_matrix())
    session = LiveSession(product, out=io.StringIO(), imu=ImuCorrection(alignment=yaw.as_matrix()))
    _run(session, stream)
    rows = np.array([line.split(",") for line in session.out.getvalue().splitlines()[2:]], dtype=float)
    h, p, r, _ = scripted_motion(rows[:, 0])
    truth = r_world_from_housing(h, p, r) * yaw.inv()  # R_world<-product
    est = r_world_from_housing(rows[:, 1], rows[:, 2], rows[:, 3])
    settled = rows[:, 0] > 2.0
    error = np.degrees((est[settled].inv() * truth[settled]).magnitude())
    assert np.sqrt(np.mean(error**2)) < 0.5


def test_a_gyro_in_deg_per_s_with_its_unit_named_gives_the_rad_per_s_attitude():
    """`compass live --gyro-unit deg/s`: the stream decoder converts the module's gyro on arrival."""
    from dataclasses import replace

    from compass.io.stream_options import StreamOptions

    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    t_s = 4.0 + np.arange(600) / 100.0  # the script's first turn: heading, pitch and roll all move
    samples = simulate_device(model, t_s, seed=2)
    in_deg_s = replace(samples, gyro=np.degrees(samples.gyro))

    def headings(stream_samples, gyro_unit):
        out = io.StringIO()
        session = LiveSession(model, out=out, stream=StreamOptions(gyro_unit=gyro_unit))
        session.feed(LinkEvent("connected", "connected to test", 0.0))
        stream = device._header + b"".join(device._lines(stream_samples, 0))
        for k in range(0, len(stream), 700):
            session.feed(Chunk(time.perf_counter(), stream[k:k + 700]))
        session.close()
        lines = [line for line in out.getvalue().splitlines() if not line.startswith("#")]
        rows = np.loadtxt(lines[1:], delimiter=",", ndmin=2)
        return rows[-100:, lines[0].split(",").index("heading_deg")]

    reference = headings(samples, "rad/s")
    # the line protocol prints the gyro with 5 decimals: deg/s keeps more digits than rad/s, so allow
    # the rounding of rad/s (5e-6 rad/s over 6 s is 2e-3 deg) several times over
    np.testing.assert_allclose(wrap(headings(in_deg_s, "deg/s") - reference), 0.0, atol=0.05)
    assert np.max(np.abs(wrap(headings(in_deg_s, "rad/s") - reference))) > 1.0  # unnamed, the attitude spins


def test_a_module_without_accelerometer_holds_nothing_and_says_there_is_no_attitude():
    """No ax,ay,az: nothing to seed the site's field from, so no sample is held (they piled up for ever)."""
    model = default_model()
    samples = simulate_device(model, np.arange(2000) / 100.0, seed=1)
    stream = format_line(["t_s", "seq", *model.channels]) + b"".join(
        format_line([f"{t:.4f}", i, *(f"{v:.7g}" for v in raw)]) for i, (t, raw) in enumerate(zip(samples.t_s, samples.raw)))
    events = []
    session = LiveSession(model, out=io.StringIO(), on_event=lambda level, text: events.append(text))
    for k in range(0, len(stream), 700):
        session.feed(Chunk(time.perf_counter(), stream[k:k + 700]))
    session.close()
    assert session.decoder.stats.samples == 2000 and not session._start.held
    assert any("no accelerometer: no attitude" in e for e in events)


def _serve_repeatedly(payload: bytes):
    """A socket peer that sends ``payload`` to the first reader every 0.2 s until it leaves (10 s at most).

    Repeated because the reader drains what arrived before its port was open.
    """
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(10.0)

    def peer():
        try:
            conn, _ = server.accept()
        except OSError:
            return
        with conn:
            deadline = time.monotonic() + 10.0
            try:
                while time.monotonic() < deadline:
                    conn.sendall(payload)
                    time.sleep(0.2)
            except OSError:
                pass  # the reader closed the link

    thread = threading.Thread(target=peer, daemon=True)
    thread.start()
    return server, thread, f"socket://127.0.0.1:{server.getsockname()[1]}"


@pytest.mark.parametrize("samples_first", [0, 300])
def test_live_failing_on_a_wrong_header_keeps_the_recording_only_if_it_holds_samples(tmp_path, capsys, samples_first):
    model = default_model()
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(model_to_dict(model)))
    device = PtyDevice(model, rate_hz=100.0)
    lines = device._lines(simulate_device(model, np.arange(samples_first) / 100.0, seed=2), 0)
    wrong = format_line(["ax", "ay", "az"])
    payload = (device._header + b"".join(lines) if samples_first else b"") + wrong + b"1,2,3\n" + wrong
    rrd, att = tmp_path / "live.rrd", tmp_path / "att.csv"
    rrd.write_bytes(b"an older recording")  # --force: replaced only by a recording that holds samples
    server, thread, port = _serve_repeatedly(payload)
    try:
        code = main(["live", "--port", port, "--cal", str(cal), "--rerun", str(rrd), "--out", str(att), "--force",
                     "--duration", "20", "--quiet"])
    finally:
        server.close()
        thread.join(15)
    captured = capsys.readouterr()
    assert code == 2 and "lacks the calibration's channel(s) mx,my,mz" in captured.err
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary left behind
    if samples_first:
        assert rrd.read_bytes() != b"an older recording" and att.exists()
        assert f"wrote {att}, {rrd}" in captured.out
        assert {"/" + e for e in ENTITIES} <= entity_paths(rrd)
    else:
        assert rrd.read_bytes() == b"an older recording" and not att.exists()
        assert "wrote" not in captured.out


def test_a_simulated_module_with_a_misaligned_accelerometer_reads_true_in_live():
    """compass device --cal plays the module of a calibration whose accelerometer sits off the housing
    (mag_to_accel): its accelerometer and gyro in their own frame, which live turns back (Calibration.imu).
    Before, the device sent them in the model's frame and live's turn tilted every attitude by it."""
    from compass.calibration import from_dict

    model = default_model()
    turn = Rotation.from_rotvec(np.radians([3.0, -2.0, 1.0]))
    imu = from_dict(model_to_dict(model) | {"mag_to_accel": turn.as_matrix().tolist()}).imu
    device = PtyDevice(model, rate_hz=100.0, imu_from_model=imu.rotation.T)
    samples = simulate_device(model, np.arange(1500) / 100.0, seed=4, imu_from_model=imu.rotation.T)
    session = LiveSession(model, out=io.StringIO(), imu=imu)
    _run(session, device._header + b"".join(device._lines(samples, 0)))
    rows = np.array([line.split(",") for line in session.out.getvalue().splitlines()[2:]], dtype=float)
    _, pitch, roll, _ = scripted_motion(rows[:, 0])
    late = rows[:, 0] > 3.0  # after the filter settled
    assert np.sqrt(np.mean(wrap(rows[late, 2] - pitch[late]) ** 2)) < 0.5
    assert np.sqrt(np.mean(wrap(rows[late, 3] - roll[late]) ** 2)) < 0.5


def test_a_header_without_accelerometer_first_does_not_keep_the_bench_field_in_the_filter():
    """Samples under a header without ax,ay,az reach the filter at once (no attitude to hold them for); the
    reference seeded later from the full header's quiet second must reach the filter (it kept the bench's)."""
    model, stream, _ = _site_stream(30.0, 45.0)
    first = format_line(["t_s", "seq", *model.channels, "gx", "gy", "gz"]) + b"".join(  # the same filter kind
        format_line([f"{k / 100:.2f}", k, 1.9, 1.7, 0.5, 0.0, 0.0, 0.0]) for k in range(5))
    session = LiveSession(model, out=io.StringIO())
    _run(session, first + stream)
    assert abs(session.reference.dip_deg - 30.0) < 0.5 and session._filter.config.dip_deg == session.reference.dip_deg
    rows = np.array([line.split(",") for line in session.out.getvalue().splitlines()[2:]], dtype=float)
    assert rows[:, 8].mean() > 0.95  # mag_used: the field accepted against the site's dip


@pytest.mark.parametrize("unit, applied", [(1.0, True), (9.80665, False)], ids=["g", "m/s2"])
def test_live_undoes_the_bench_accelerometer_offsets_only_in_the_bench_unit(unit, applied):
    """A module whose accelerometer reads 0.03 g off on X and Y, measured on the bench (in g): live undoes it
    and the tilt is the aligned module's; a stream in m/s^2 does not read 1 g as the bench did, so it is said
    once and not applied (the tilt keeps the offset's error)."""
    from dataclasses import replace

    from compass.calibration import ImuCorrection

    model = default_model()
    offset = np.array([0.03, -0.03, 0.0])
    device = PtyDevice(model, rate_hz=100.0)
    samples = simulate_device(model, np.arange(1500) / 100.0, seed=5)
    stream = device._header + b"".join(device._lines(replace(samples, accel=unit * (samples.accel + offset)), 0))
    events = []
    imu = ImuCorrection(offset=offset, scale=np.ones(3), one_g=1.0)
    session = LiveSession(model, out=io.StringIO(), imu=imu, on_event=lambda lv, t: events.append(t))
    _run(session, stream)
    rows = np.array([line.split(",") for line in session.out.getvalue().splitlines()[2:]], dtype=float)
    _, pitch, roll, _ = scripted_motion(rows[:, 0])
    late = rows[:, 0] > 3.0
    tilt = np.sqrt(np.mean(np.concatenate([wrap(rows[late, 2] - pitch[late]), wrap(rows[late, 3] - roll[late])]) ** 2))
    said = any("does not read 1 g" in e for e in events)
    assert said != applied and (tilt < 0.5) == applied  # 0.03 g left in: about 1.7 deg


def test_live_takes_the_calibration_s_site_as_the_replay_does_and_site_wins():
    """The reference field: ``--site``, else the calibration's site block (compass attitude's default too, so a
    replay of the record writes live's rows), else none (the stream's first quiet second)."""
    from types import SimpleNamespace

    from compass.commands.live import _site_reference
    from compass.site import Site

    model = default_model()
    bench = Site.parse("48.15,11.58", "2025-06-01")
    none = SimpleNamespace(site=None, date=None)
    assert _site_reference(none, model, None) is None
    from_file = _site_reference(none, model, bench)
    assert from_file.source == "calibration site" and from_file.dip_deg == pytest.approx(bench.field().dip_deg)
    given = _site_reference(SimpleNamespace(site="-33.9,18.4", date="2025-06-01"), model, bench)
    assert given.source == "site" and given.dip_deg < 0.0 < from_file.dip_deg
