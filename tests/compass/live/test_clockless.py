"""A module that sends no t_s, read in bursts: ``compass live`` dates its samples (``SampleClock``), and
``--record`` writes them so the replay gives the same rows."""

import datetime as dt
import io
from argparse import Namespace

import numpy as np
import pytest

from compass.calibration import model_to_dict, save
from compass.cli import main
from compass.commands.live import _replay_options
from compass.filter import FilterConfig, run_filter
from compass.io.lines import Sample
from compass.io.sample_log import SampleLog, parse_replay_line
from compass.io.streams import StreamOptions
from compass.io.table import RecordingError, read_table
from compass.live import LiveSession
from compass.serial_reader import Chunk
from compass.site import Site, reference_from_site
from compass.sim.device import default_model, simulate_device, tumble_motion

RATE_HZ = 100.0
COLUMNS = ("ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")


def wrap(d):
    return np.mod(np.asarray(d) + 180.0, 360.0) - 180.0


def _bursts(t_send, seed):
    """Each sample's arrival: reads every 1-20 ms, 2 % of them after a 50-200 ms stall (a busy host)."""
    rng = np.random.default_rng(seed)
    gaps = rng.uniform(0.001, 0.020, int(2 * t_send[-1] / 0.001) + 10)
    stalls = rng.random(len(gaps)) < 0.02
    gaps[stalls] = rng.uniform(0.05, 0.2, int(stalls.sum()))
    reads = 100.0 + np.cumsum(gaps)
    return reads[np.searchsorted(reads, 100.0 + t_send + 0.001)]


@pytest.fixture(scope="module")
def clockless():
    """A tumbling module's samples as bare numbers without t_s, and when each arrived."""
    model = default_model()
    t = np.arange(0.0, 30.0, 1.0 / RATE_HZ)
    s = simulate_device(model, t, motion=tumble_motion, seed=3)
    lines = [(",".join(map(repr, row)) + "\r\n").encode() for row in np.column_stack([s.accel, s.gyro, s.raw]).tolist()]
    return model, t, s, lines, _bursts(t, 3)


def _live(model, lines, t_rx, record=None, events=None, **options):
    out = io.StringIO()
    session = LiveSession(model, out=out, stream=StreamOptions(columns=COLUMNS), record=record,
                          on_event=None if events is None else lambda level, text: events.append(text), **options)
    k = 0
    while k < len(lines):
        m = int(np.searchsorted(t_rx, t_rx[k], side="right"))
        session.feed(Chunk(float(t_rx[k]), b"".join(lines[k:m])))
        k = m
    session.close()
    return session, out.getvalue()


def _rows(text):
    return [line.split(",") for line in text.splitlines() if not line.startswith("#")]


def test_live_dates_a_bursty_stream_at_its_period_and_solves_it_as_with_the_module_clock(clockless):
    """Dated at each burst's arrival the gyro is integrated over the wrong steps (0, then the burst); dated by the
    sample clock the attitude is the one the module's own times give, within a fraction of the arrival dating's
    error."""
    model, t, s, lines, t_rx = clockless
    assert np.mean(np.diff(t_rx) == 0.0) > 0.3 and np.max(np.diff(t_rx)) > 0.05
    events = []
    session, text = _live(model, lines, t_rx, events=events)
    said = [e for e in events if "sends no t_s" in e]
    assert len(said) == 1 and "(100.0 Hz)" in said[0]
    rows = _rows(text)[1:]
    assert session.samples == len(rows) == len(t)
    t_live = np.array([float(r[0]) for r in rows])
    settled = (t >= 2.0) & (t < t[-1] - 0.25)  # the module's last lines may come in a late read: a pause, dated so
    np.testing.assert_allclose(np.diff(t_live)[settled[1:]], 1.0 / RATE_HZ, atol=2.5e-3)  # the CSV's 4 decimals
    heading = np.array([float(r[1]) for r in rows])
    field = model.field(s.raw)[0]
    config = FilterConfig.from_model(model)
    with_module_clock = run_filter(t, s.accel, s.gyro, field, config).heading_deg
    on_arrival = run_filter(t_rx - t_rx[0], s.accel, s.gyro, field, config).heading_deg
    dated_error = np.abs(wrap(heading - with_module_clock))[settled]
    arrival_error = np.abs(wrap(on_arrival - with_module_clock))[settled]
    assert np.sqrt(np.mean(dated_error ** 2)) < 0.2 * np.sqrt(np.mean(arrival_error ** 2))
    assert np.max(dated_error) < 1.0


def test_the_record_replays_to_the_rows_live_wrote(clockless, tmp_path):
    """``--record``'s file through ``compass attitude --filter``: every column but the latency as live wrote it."""
    model, t, s, lines, t_rx = clockless
    raw = io.StringIO()
    log = SampleLog(raw, model.channels, "socket://test")
    session, live_text = _live(model, lines, t_rx, record=log)
    assert log.rows == len(t) and log.stopped is None
    recording = tmp_path / "raw.csv"
    recording.write_text(raw.getvalue())
    table = read_table(recording)
    assert table.metadata["source"] == "compass live --record, socket://test"
    np.testing.assert_array_equal(table.column("gx"), s.gyro[:, 0])  # exactly the floats the filter took
    cal = tmp_path / "cal.json"
    save(cal, model_to_dict(model))
    att = tmp_path / "att.csv"
    assert main(["attitude", str(cal), str(recording), "--out", str(att), "--filter"]) == 0
    replayed = [r[:-5] + r[-4:] for r in _rows(att.read_text())[1:]]
    live = [r[:-1] for r in _rows(live_text)[1:]]
    assert len(replayed) == len(live) and [r[:12] for r in replayed] == [r[:12] for r in live]


def test_the_plain_replay_takes_the_record_s_options_and_one_given_here_wins(clockless, tmp_path, capsys):
    """A session run with --site and --gyro-scale-error 0.03: the plain replay of its record writes its rows, saying
    in one line which options it took from the '# replay:' line and ignoring one it cannot apply; a --gyro-scale-error
    given on the command line replaces the record's (the rows of a session run with it)."""
    model, t, s, lines, t_rx = clockless
    reference = reference_from_site(Site.parse("48.15,11.58", "2025-06-01"),
                                   field_ut=None if model.field_ut is None else 1.0)  # as compass live
    raw = io.StringIO()
    log = SampleLog(raw, model.channels, "socket://test",
                    "--site 48.15,11.58 --date 2025-06-01 --gyro-scale-error 0.03 --duration 30")
    _, live_text = _live(model, lines, t_rx, record=log, reference=reference,
                         config=FilterConfig.from_model(model, gyro_scale_error=0.03))
    _, other_text = _live(model, lines, t_rx, reference=reference,
                          config=FilterConfig.from_model(model, gyro_scale_error=0.01))
    recording, cal = tmp_path / "raw.csv", tmp_path / "cal.json"
    recording.write_text(raw.getvalue())
    save(cal, model_to_dict(model))
    capsys.readouterr()
    rows = {}
    for name, given in (("plain", []), ("given", ["--gyro-scale-error", "0.01"])):
        att = tmp_path / f"{name}.csv"
        assert main(["attitude", str(cal), str(recording), "--out", str(att), "--filter", *given]) == 0
        rows[name] = [r[:-5] + r[-4:] for r in _rows(att.read_text())[1:]]
        rows[name + " said"] = [line for line in capsys.readouterr().err.splitlines() if "'# replay:' line" in line]
    live, other = [r[:-1] for r in _rows(live_text)[1:]], [r[:-1] for r in _rows(other_text)[1:]]
    assert [r[:12] for r in rows["plain"]] == [r[:12] for r in live] != [r[:12] for r in other]
    assert [r[:12] for r in rows["given"]] == [r[:12] for r in other]
    took, ignored = rows["plain said"]
    assert took == ("[info] raw.csv's '# replay:' line: took --site 48.15,11.58 --date 2025-06-01 --gyro-scale-error "
                    "0.03 (the options the live session ran with)")
    assert ignored == "[warn] raw.csv's '# replay:' line: ignored --duration 30 (not an option of the replay)"
    assert "took --site 48.15,11.58 --date 2025-06-01 (the options the live session ran with); the options given " \
           "here replaced its --gyro-scale-error 0.03" in rows["given said"][0]


def test_the_replay_line_s_options_are_read_back_and_what_it_cannot_apply_is_named():
    read = parse_replay_line("compass attitude CAL.json THIS.csv --out ATT.csv --filter --accel-unit g --site "
                             "'-33.9, 151.2' --gravity=1.02 --mag-latency --port /dev/ttyUSB0 --gyro-scale-error x")
    assert read.values == {"accel_unit": "g", "site": "-33.9, 151.2", "gravity": 1.02, "mag_latency": True}
    assert read.ignored == ("--port /dev/ttyUSB0 (not an option of the replay)", "--gyro-scale-error x (not a number)")
    assert parse_replay_line("compass attitude 'CAL.json --filter").ignored == ("the whole line (No closing quotation)",)


def test_a_header_with_other_columns_ends_the_record_and_says_so():
    model = default_model()
    s = simulate_device(model, np.arange(0.0, 2.0, 0.01), seed=1)
    raw = io.StringIO()
    log = SampleLog(raw, model.channels, "pty")
    full = [Sample(r, a, g, t_s=float(k)) for k, (r, a, g) in enumerate(zip(s.raw, s.accel, s.gyro))]
    assert log.write(full[:5], accel_in_g=False) is None
    words = log.write([Sample(s.raw[5], s.accel[5], None, t_s=5.0)], accel_in_g=False)
    assert "columns changed after 5 samples" in words
    assert log.write(full[6:], accel_in_g=False) is None and log.rows == 5
    assert raw.getvalue().count("\n") == 5 + 5  # four comment lines, the names, five rows


def test_the_command_records_a_clockless_module_and_the_replay_writes_its_rows(tmp_path, capsys):
    """``compass live --record`` on a socket sending bare numbers without t_s, then ``compass attitude --filter`` on
    the file: the same rows as live's ``--out`` (the latency aside)."""
    from .test_live import _serve_repeatedly

    model = default_model()
    cal = tmp_path / "cal.json"
    save(cal, model_to_dict(model))
    s = simulate_device(model, np.arange(0.0, 0.2, 0.01), seed=4)
    payload = b"".join((",".join(map(repr, row)) + "\r\n").encode()
                       for row in np.column_stack([s.accel, s.gyro, s.raw]).tolist())
    raw, att, replayed = tmp_path / "raw.csv", tmp_path / "att.csv", tmp_path / "replayed.csv"
    server, thread, port = _serve_repeatedly(payload)
    try:
        code = main(["live", "--port", port, "--cal", str(cal), "--columns", ",".join(COLUMNS), "--out", str(att),
                     "--record", str(raw), "--duration", "3", "--quiet"])
    finally:
        server.close()
        thread.join(15)
    out = capsys.readouterr().out
    assert code == 0 and f"{raw} (" in out
    assert main(["attitude", str(cal), str(raw), "--out", str(replayed), "--filter"]) == 0
    live_rows = [r[:-1] for r in _rows(att.read_text())[1:]]
    replay_rows = [r[:-5] for r in _rows(replayed.read_text())[1:]]
    assert len(live_rows) > 100 and live_rows == replay_rows


def test_the_command_refuses_a_record_it_cannot_keep(tmp_path, capsys):
    cal = tmp_path / "cal.json"
    save(cal, model_to_dict(default_model()))
    old = tmp_path / "raw.csv"
    old.write_text("an older recording")
    for args, words in ((["--record", str(old)], "exists"),
                        (["--record", str(tmp_path / "a.csv"), "--out", str(tmp_path / "a.csv")], "two files"),
                        (["--record", str(tmp_path / "b.csv"), "--calibrate", "tumble", "--out", "t.json"],
                         "CAL.tumble.csv")):
        assert main(["live", "--port", "/dev/null", "--cal", str(cal), *args]) == 2
        assert words in capsys.readouterr().err
    assert old.read_text() == "an older recording"


def test_the_record_names_the_replay_options_of_the_session():
    """The site with its day (the field of --site without --date is today's), a given gravity, the flags."""
    args = Namespace(site="52.2,0.1", date=None, gravity=1.02, mag_latency=True, gyro_matrix=False,
                     gyro_scale_error=0.03)
    words = _replay_options(args)
    today = dt.datetime.now(dt.timezone.utc).date().isoformat()
    assert words == f"--site 52.2,0.1 --date {today} --gravity 1.02 --mag-latency --gyro-scale-error 0.03"
    raw = io.StringIO()
    log = SampleLog(raw, ("mx", "my", "mz"), "pty", words)
    log.write([Sample(np.zeros(3), np.ones(3), None, t_s=0.0)], accel_in_g=True)
    assert f"--filter --accel-unit g {words}\n" in raw.getvalue()


def test_a_broken_line_is_a_sample_lost_and_the_next_is_dated_after_it(clockless):
    """A line cut short (the decoder drops it as partial) stands for a sample: the next one is dated two periods
    after the one before, at once (a silent loss would be seen only after 0.25 s of chunks)."""
    model, t, s, lines, _ = clockless
    lines = list(lines)
    lines[1000] = lines[1000][:12] + b"\r\n"  # the line cut after a few cells
    out = io.StringIO()
    session = LiveSession(model, out=out, stream=StreamOptions(columns=COLUMNS))
    for t_k, line in zip(100.0 + t + 0.001, lines):  # one line a read, on time
        session.feed(Chunk(float(t_k), line))
    session.close()
    assert session.decoder.stats.partial == 1
    t_live = np.array([float(r[0]) for r in _rows(out.getvalue())[1:]])
    np.testing.assert_allclose(t_live, np.delete(t, 1000), atol=1e-4)  # the CSV's 4 decimals


def test_a_broken_line_inside_a_chunk_is_dated_in_its_place(clockless):
    """Lines read ten at a time, on time, one in the middle of a chunk cut short: the samples before it in the chunk
    keep their times and those after it are a period later (counted at the chunk's start, every sample of the chunk
    before it would be a period late)."""
    model, t, s, lines, _ = clockless
    lines = list(lines)
    lines[1005] = lines[1005][:12] + b"\r\n"
    out = io.StringIO()
    session = LiveSession(model, out=out, stream=StreamOptions(columns=COLUMNS))
    for k in range(0, len(lines), 10):
        session.feed(Chunk(100.0 + float(t[min(k + 9, len(t) - 1)]) + 0.001, b"".join(lines[k:k + 10])))
    session.close()
    error = np.array([float(r[0]) for r in _rows(out.getvalue())[1:]]) - np.delete(t, 1005)
    np.testing.assert_allclose(error[500:], error[-1], atol=1e-4)  # the CSV's 4 decimals; the first chunks wait


def _record_then_replay(model, lines, tmp_path):
    """``lines`` through a live session recording them (chunks of 700 bytes), then its record through the replay
    command: the log, the session, the record's path, live's rows and the replay's (the latency and the quaternion
    left out of both)."""
    raw, out = io.StringIO(), io.StringIO()
    log = SampleLog(raw, model.channels, "pty")
    session = LiveSession(model, out=out, record=log)
    stream = b"".join(lines)
    for k in range(0, len(stream), 700):
        session.feed(Chunk(100.0 + k / 1e5, stream[k:k + 700]))
    session.close()
    recording, cal, att = tmp_path / "raw.csv", tmp_path / "cal.json", tmp_path / "att.csv"
    recording.write_text(raw.getvalue())
    save(cal, model_to_dict(model))
    assert main(["attitude", str(cal), str(recording), "--out", str(att), "--filter"]) == 0
    replayed = [r[:-5] + r[-4:] for r in _rows(att.read_text())[1:]]
    live = [r[:-1] for r in _rows(out.getvalue())[1:]]
    return log, session, recording, [r[:12] for r in live], [r[:12] for r in replayed]


def test_a_group_sent_empty_on_some_lines_is_recorded_and_replayed_as_live_took_it(tmp_path):
    """The line protocol lets a module leave ``temp_c`` (here on most lines), the gyro or the accelerometer empty on
    a line: the record keeps every sample (it stopped at the first such line) and replays to live's rows."""
    import dataclasses

    from compass.io.lines import format_line
    from compass.temperature import TemperatureCompensation

    base = default_model()
    gains = np.array([r.gain for r in base.responses])
    model = dataclasses.replace(base, temperature=TemperatureCompensation(25.0, 2e-3 * gains, np.zeros(3)))
    n = 600
    s = simulate_device(model, np.arange(n) / RATE_HZ, seed=5)
    lines = [format_line(["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz", "temp_c"])]
    for i in range(n):
        accel = [""] * 3 if i == 250 else s.accel[i].tolist()
        gyro = [""] * 3 if i in (300, 301) else s.gyro[i].tolist()
        temp = 25.0 + i / 60.0 if i % 50 == 7 else ""
        lines.append(format_line([float(s.t_s[i]), *s.raw[i].tolist(), *accel, *gyro, temp]))
    log, _, recording, live, replayed = _record_then_replay(model, lines, tmp_path)
    assert log.stopped is None and log.rows == n
    assert len(live) > n - 100 and replayed == live
    table = read_table(recording, live_record=True)
    assert np.isnan(table.column("gx")[300]) and np.isnan(table.column("ax")[250])
    with pytest.raises(RecordingError, match="expected a finite number"):
        read_table(recording)  # the calibration's and the per-row solver's reader: no sensor left out silently
    assert np.sum(np.isfinite(table.column("temp_c"))) == n // 50


def test_a_time_that_goes_back_is_recorded_and_replayed_as_live_took_it(tmp_path):
    """One corrupted t_s (skipped by the filter) and a module that restarts its clock (adopted): the record keeps
    the times as sent and the replay, which refused a t_s that decreases, gives live's rows; any other file's
    decreasing t_s is still refused."""
    from compass.io.lines import format_line

    model = default_model()
    n = 700
    s = simulate_device(model, np.arange(n) / RATE_HZ, seed=8)
    t_sent = s.t_s.copy()
    t_sent[200] = 0.5  # one corrupted time
    t_sent[400:] -= t_sent[400] - 0.01  # the module restarted its clock
    lines = [format_line(["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"])]
    lines += [format_line([float(t_sent[i]), *s.raw[i].tolist(), *s.accel[i].tolist(), *s.gyro[i].tolist()])
              for i in range(n)]
    log, session, recording, live, replayed = _record_then_replay(model, lines, tmp_path)
    assert log.rows == n and session.skipped.get("t_s went back", 0) >= 2
    assert len(live) > n - 100 and replayed == live
    other = tmp_path / "other.csv"
    other.write_text(recording.read_text().replace("# source: compass live --record", "# source: a logger"))
    with pytest.raises(RecordingError, match="must not decrease"):
        read_table(other, live_record=True)


def test_live_says_once_at_the_start_that_a_field_pointing_up_rests_on_the_hemisphere(tmp_path, capsys):
    """A calibration whose field points up (a reversed magnetometer axis in the northern hemisphere, as its
    calibration warned), a stream that reads it so too, and no --site: said once, under --quiet too, with what
    fixes it."""
    from dataclasses import replace

    from .test_live import _serve_repeatedly

    model = default_model()
    cal = tmp_path / "cal.json"
    save(cal, model_to_dict(model) | {"dip_deg": -60.0})
    s = simulate_device(replace(model, dip_deg=-60.0), np.arange(0.0, 0.2, 0.01), seed=4)
    payload = b"".join((",".join(map(repr, row)) + "\r\n").encode()
                       for row in np.column_stack([s.accel, s.gyro, s.raw]).tolist())
    server, thread, port = _serve_repeatedly(payload)
    try:
        code = main(["live", "--port", port, "--cal", str(cal), "--columns", ",".join(COLUMNS), "--duration", "1",
                     "--quiet"])
    finally:
        server.close()
        thread.join(15)
    said = [line for line in capsys.readouterr().err.splitlines() if "180 deg off" in line]
    assert code == 0 and len(said) == 1
    assert said[0].startswith(f"compass live: warning: {cal}: its field points up (dip -60.0 deg)")
    assert "Give --site LAT,LON" in said[0] and "recalibrate with that axis negated" in said[0]


def test_bare_numbers_without_columns_are_refused_naming_the_columns_not_the_calibration(tmp_path, capsys):
    from .test_live import _serve_repeatedly

    model = default_model()
    cal = tmp_path / "cal.json"
    save(cal, model_to_dict(model))
    s = simulate_device(model, np.arange(0.0, 0.5, 0.01), seed=4)
    payload = b"".join((",".join(map(repr, row)) + "\r\n").encode()
                       for row in np.column_stack([s.accel, s.gyro, s.raw]).tolist())
    server, thread, port = _serve_repeatedly(payload)
    try:
        code = main(["live", "--port", port, "--cal", str(cal), "--duration", "10", "--quiet"])
    finally:
        server.close()
        thread.join(15)
    err = capsys.readouterr().err
    assert code == 2 and "bare numbers without a header" in err
    assert "name its cells with --columns, e.g. --columns t_s,ax,ay,az,gx,gy,gz,mx,my,mz\n" in err
    assert "calibration" not in err
