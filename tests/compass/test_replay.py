"""One pipeline, live or replayed (issue 22): ``compass live``, the replay and ``run_filter`` give the same
attitudes on the same samples; the filter starts from a window, never from one row."""

import io
import re
import time
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.cli import main
from compass.filter import FilterConfig, run_filter
from compass.io.lines import format_line
from compass.io.table import RecordingError, format_table, read_table
from compass.live import LiveSession
from compass.replay import replay
from compass.serial_reader import Chunk
from compass.sim.device import default_model, simulate_device

RATE_HZ = 100.0
GYRO_BIAS = np.array([0.004, -0.003, 0.002])  # rad/s


def wrap(d):
    return np.mod(np.asarray(d) + 180.0, 360.0) - 180.0


@pytest.fixture(scope="module")
def stream():
    model = default_model()
    t = np.arange(0.0, 30.0, 1.0 / RATE_HZ)
    s = simulate_device(model, t, seed=5, gyro_bias=GYRO_BIAS)
    return model, t, s


def _lines(model, t, s, gyro=True):
    """The module's byte stream with every value written exactly (repr), so the decoder reads the arrays' floats."""
    names = ["t_s", *model.channels, "ax", "ay", "az"] + (["gx", "gy", "gz"] if gyro else [])
    rows = np.column_stack([t, s.raw, s.accel] + ([s.gyro] if gyro else []))
    return format_line(names) + b"".join(format_line([repr(v) for v in row.tolist()]) for row in rows)


def _csv_rows(text):
    return [line.split(",")[:-5] + line.split(",")[-4:] for line in text.splitlines() if not line.startswith("#")]


def _with_own_uncertainty(model):
    """``model`` with a calibration's own uncertainty (each channel's direction 0.2 deg, offset and gain 0.2 %),
    which compass live, the replay and run_filter add to the reported heading sigma."""
    a = model.unit_directions
    cov = np.radians(0.2) ** 2 * (np.eye(3)[None] - a[:, :, None] * a[:, None, :])
    sigma = 0.002 * np.abs(model.gains)[:, None] * np.array([model.field_norm, 1.0])
    return replace(model, direction_covariance=cov, response_sigma=sigma)


@pytest.mark.parametrize("gyro", [True, False])
def test_live_replay_and_run_filter_give_identical_attitudes(stream, gyro):
    """... and the same heading sigma, the calibration's own uncertainty included (run_filter reported the
    filter's alone: issue 24)."""
    model, t, s = stream
    model = _with_own_uncertainty(model)
    live_out, replay_out = io.StringIO(), io.StringIO()
    live = LiveSession(model, out=live_out, quaternion=True)
    data = _lines(model, t, s, gyro)
    for k in range(0, len(data), 997):  # arbitrary chunk boundaries, as a port delivers them
        live.feed(Chunk(time.perf_counter(), data[k:k + 997]))
    live.close()
    replayed = replay(LiveSession(model, out=replay_out, quaternion=True), t, s.raw, s.accel, s.gyro if gyro else None)
    # the same rows, every column but the latency equal as written
    assert live.samples == replayed.samples == len(t)
    assert _csv_rows(live_out.getvalue()) == _csv_rows(replay_out.getvalue())
    # run_filter, the documented offline path, seeds and starts the same way
    track = run_filter(t, s.accel, s.gyro if gyro else None, model.field(s.raw)[0], FilterConfig.from_model(model))
    table = read_table(_write(replay_out.getvalue()))
    quat = np.column_stack([table.column(c) for c in ("qx", "qy", "qz", "qw")])
    angle = np.degrees((Rotation.from_quat(quat).inv() * Rotation.from_quat(track.quat)).magnitude())
    assert np.max(angle) < 1e-5  # the CSV's 9 decimals
    np.testing.assert_allclose(wrap(table.column("heading_deg") - track.heading_deg), 0.0, atol=1e-3)
    np.testing.assert_allclose(table.column("heading_sigma_deg"), track.heading_sigma_deg, atol=5.1e-4)
    noise_only = run_filter(t, s.accel, s.gyro if gyro else None, model.field(s.raw)[0],
                            replace(FilterConfig.from_model(model), calibration_uncertainty=None))
    assert np.all(track.heading_sigma_deg > noise_only.heading_sigma_deg + 1e-3)


def _write(text):
    import tempfile
    from pathlib import Path

    path = Path(tempfile.mkdtemp()) / "att.csv"
    path.write_text(text)
    return path


def test_the_quaternion_is_housing_to_world_as_the_angles_say(stream):
    model, t, s = stream
    out = io.StringIO()
    replay(LiveSession(model, out=out, quaternion=True), t, s.raw, s.accel, s.gyro)
    table = read_table(_write(out.getvalue()))
    quat = np.column_stack([table.column(c) for c in ("qx", "qy", "qz", "qw")])
    # SPEC section 1: R_world<-housing = Rz(-heading) Ry(-pitch) Rx(roll)
    expected = Rotation.from_euler("ZYX", np.column_stack([-table.column("heading_deg"), -table.column("pitch_deg"),
                                                            table.column("roll_deg")]), degrees=True)
    assert np.max(np.degrees((expected.inv() * Rotation.from_quat(quat)).magnitude())) < 2e-3  # angles: 3 decimals
    assert np.all(table.column("qw") >= 0)


def _bias_and_tilt_error(t, s, accel, gravity=None):
    model = default_model()
    cfg = FilterConfig.from_model(model)
    if gravity is not None:
        cfg = replace(cfg, gravity=gravity)
    track = run_filter(t, accel, s.gyro, model.field(s.raw)[0], cfg)
    late = t > 5.0
    tilt = np.hypot(track.pitch_deg - s.pitch_deg, wrap(track.roll_deg - s.roll_deg))
    return track, float(np.max(np.abs(track.gyro_bias[-1] - GYRO_BIAS))), float(np.sqrt(np.mean(tilt[late] ** 2)))


def test_a_first_row_4_5_degrees_off_sets_neither_the_tilt_nor_the_gyro_bias(stream):
    model, t, s = stream
    clean, bias_clean, tilt_clean = _bias_and_tilt_error(t, s, s.accel)
    accel = s.accel.copy()
    accel[0] = Rotation.from_rotvec([np.radians(4.5), 0, 0]).apply(accel[0])  # the board's first row
    off, bias_off, tilt_off = _bias_and_tilt_error(t, s, accel)
    # the start's median ignores one row: the same start, the same bias as without it (the filter is causal:
    # after the first row every sample is the same)
    assert abs(off.pitch_deg[0] - clean.pitch_deg[0]) < 0.05 and abs(off.roll_deg[0] - clean.roll_deg[0]) < 0.05
    assert bias_off == pytest.approx(bias_clean, abs=2e-4)  # rad/s; the simulator's bias is 0.004
    assert tilt_off == pytest.approx(tilt_clean, abs=0.02)


def test_gravity_read_as_1_3_is_learnt_from_the_window_or_given(stream):
    model, t, s = stream
    first_off = s.accel.copy()
    first_off[0] *= 1.3  # one row reading 1.3 g: it decided gravity's size before (then 2 % of rows used)
    for accel, gravity in ((first_off, None), (1.3 * s.accel, None), (1.3 * s.accel, 1.3)):  # the simulator's g
        track, _, tilt = _bias_and_tilt_error(t, s, accel, gravity)
        assert np.mean(track.accel_used[t > 2.0]) > 0.9
        assert tilt < 1.0
    # a first row of garbage (zero, then 1e300): skipped and counted, never fused
    accel = s.accel.copy()
    accel[0], accel[1] = 0.0, 1e300
    track, _, tilt = _bias_and_tilt_error(t, s, accel)
    assert track.skipped.as_dict() == {"accel out of range": 2} and tilt < 1.0
    assert np.all(np.isnan(track.heading_deg[:2])) and np.all(np.isfinite(track.heading_deg[2:]))


def test_a_start_in_motion_takes_the_tilt_from_the_window_in_the_inertial_frame():
    """A housing already turning fast at the first row: the start's median of gravity turned back by the gyro
    is within a degree of the truth at the first sample."""
    model = default_model()
    t = np.arange(0.0, 20.0, 1.0 / RATE_HZ)

    def spinning(t_s):
        return 40.0 * t_s, 20.0 * np.sin(2.0 * t_s), 25.0 * np.cos(1.3 * t_s), np.zeros(len(t_s), dtype=bool)

    s = simulate_device(model, t, motion=spinning, seed=2, gyro_bias=[0.0, 0.0, 0.0])
    track = run_filter(t, s.accel, s.gyro, model.field(s.raw)[0], FilterConfig.from_model(model))
    assert abs(track.pitch_deg[0] - s.pitch_deg[0]) < 1.0 and abs(wrap(track.roll_deg[0] - s.roll_deg[0])) < 1.0


# ---------------------------------------------------------------- the command


@pytest.fixture()
def files(tmp_path, stream):
    """The simulated device's calibration and a 30 s attitude recording of it (SPEC section 2)."""
    model, t, s = stream
    from compass.calibration import model_to_dict, save

    cal = tmp_path / "cal.json"
    save(cal, model_to_dict(model))

    def recording(name="rec.csv", *, gyro=True, accel=True, gyro_scale=1.0, accel_scale=1.0, first_row=None):
        columns = {"t_s": t} | {c: s.raw[:, k] for k, c in enumerate(model.channels)}
        if accel:
            columns |= {c: accel_scale * s.accel[:, k] for k, c in enumerate(("ax", "ay", "az"))}
        if gyro:
            columns |= {c: gyro_scale * s.gyro[:, k] for k, c in enumerate(("gx", "gy", "gz"))}
        path = tmp_path / name
        path.write_text(format_table(columns, {}, {c: "%.17g" for c in columns}))
        return path

    return cal, recording


def test_the_command_writes_live_columns_and_the_quaternion(files, stream, capsys):
    model, t, s = stream
    cal, recording = files
    out = cal.parent / "att.csv"
    assert main(["attitude", str(cal), str(recording()), "--out", str(out), "--filter"]) == 0
    table = read_table(out)
    from compass.live import CSV_COLUMNS

    assert table.columns == CSV_COLUMNS + ("qw", "qx", "qy", "qz") and len(table.data) == len(t)
    live = LiveSession(model, out=io.StringIO(), quaternion=True)
    replay(live, t, s.raw, s.accel, s.gyro)
    assert _csv_rows(out.read_text()) == _csv_rows(live.out.getvalue())
    assert "filter: gyro" in capsys.readouterr().out
    # never overwritten without --force
    assert main(["attitude", str(cal), str(recording()), "--out", str(out), "--filter"]) == 2


def test_the_command_without_gyro_runs_the_two_vector_filter(files, capsys):
    cal, recording = files
    out = cal.parent / "att.csv"
    assert main(["attitude", str(cal), str(recording(gyro=False)), "--out", str(out), "--filter"]) == 0
    assert "two-vector" in capsys.readouterr().out
    assert np.all(np.isfinite(read_table(out).column("heading_deg")))


@pytest.mark.parametrize("case, words", [
    ("no accel", "has no ax,ay,az columns: the filter needs an accelerometer"),
    ("deg/s", "--gyro-unit deg/s"),
    ("level", "--level cannot go with --filter"),
    ("gravity", "--gravity: must be a number in (0"),
])
def test_the_command_refuses_bad_input_in_one_line(files, capsys, case, words):
    cal, recording = files
    rec = recording(accel=case != "no accel", gyro_scale=np.degrees(1.0) if case == "deg/s" else 1.0)
    extra = {"level": ["--level"], "gravity": ["--gravity", "-1"]}.get(case, [])
    code = main(["attitude", str(cal), str(rec), "--out", str(cal.parent / "att.csv"), "--filter", *extra])
    err = capsys.readouterr().err
    assert code == 2 and words in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (cal.parent / "att.csv").exists()


def test_a_deg_s_gyro_named_as_such_is_used(files, stream):
    model, t, s = stream
    cal, recording = files
    out = cal.parent / "att.csv"
    rec = recording(gyro_scale=np.degrees(1.0))
    assert main(["attitude", str(cal), str(rec), "--out", str(out), "--filter", "--gyro-unit", "deg/s"]) == 0
    heading = read_table(out).column("heading_deg")
    late = t > 5.0
    assert np.sqrt(np.mean(wrap(heading - s.heading_deg)[late & (s.magnet == 0)] ** 2)) < 1.0


def test_the_replay_writes_the_rerun_recording_as_live_does(files):
    pytest.importorskip("rerun")
    cal, recording = files
    rrd = cal.parent / "att.rrd"
    assert main(["attitude", str(cal), str(recording()), "--out", str(cal.parent / "att.csv"), "--filter",
                 "--rerun", str(rrd)]) == 0
    assert rrd.stat().st_size > 0


def test_live_refuses_a_gravity_that_is_not_a_positive_number(files, capsys):
    cal, _ = files
    assert main(["live", "--port", str(cal.parent / "no-port"), "--cal", str(cal), "--gravity", "0"]) == 2
    err = capsys.readouterr().err
    assert "--gravity: must be a number in (0" in err and "Traceback" not in err


# ---------------------------------------------------------------- bad input (issue 22's "Done when")


@pytest.mark.parametrize("cell, column, words", [
    ("abc", "t_s", "expected a number, found 'abc'"),
    ("nan", "mx", "expected a finite number, found nan"),
    ("1e300", "ax", "is beyond 1e+12 in magnitude"),
    ("inf", "gx", "expected a finite number, found inf"),
])
def test_the_command_refuses_a_first_row_of_garbage_in_one_line_naming_it(files, capsys, cell, column, words):
    """A first row holding text, NaN, 1e300 or inf in one cell: exit 2, one line naming the file, the row and
    the column, nothing written (nothing fused)."""
    cal, recording = files
    rec = recording()
    lines = rec.read_text().splitlines()
    header = lines[0].split(",")
    first = lines[1].split(",")
    first[header.index(column)] = cell
    lines[1] = ",".join(first)
    rec.write_text("\n".join(lines) + "\n")
    out = cal.parent / "att.csv"
    code = main(["attitude", str(cal), str(rec), "--out", str(out), "--filter"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert f"{rec}, row 2, column '{column}'" in err and words in err
    assert not out.exists()


@pytest.mark.parametrize("cells, reason", [
    ({"ax": "0", "ay": "0", "az": "0"}, "accel out of range"), ({"ay": "1e9"}, "accel out of range"),
    ({"mx": "1e11"}, "field out of range"), ({"gx": "1e5"}, "gyro out of range"),
])
def test_the_command_skips_a_first_row_no_sensor_reads_and_says_it(files, capsys, cells, reason):
    """A first row of finite numbers no sensor reads (a zero accelerometer, 1e9 g, a field of 1e11, a gyro of
    1e5 rad/s): skipped, said once and counted, never fused; every other row written, every number finite."""
    cal, recording = files
    rec = recording()
    lines = rec.read_text().splitlines()
    header, first = lines[0].split(","), lines[1].split(",")
    for column, cell in cells.items():
        first[header.index(column)] = cell
    rec.write_text("\n".join([lines[0], ",".join(first)] + lines[2:]) + "\n")
    out = cal.parent / "att.csv"
    assert main(["attitude", str(cal), str(rec), "--out", str(out), "--filter"]) == 0
    err = capsys.readouterr().err
    assert f"sample skipped, never fused: {reason}" in err and "Traceback" not in err
    table = read_table(out)
    assert len(table.data) == len(lines) - 2 and table.column("t_s")[0] > float(first[header.index("t_s")])
    assert all(np.all(np.isfinite(table.column(c))) for c in table.columns)


def _session_rows(model, data: bytes, events=None):
    """``compass live``'s session fed the module's bytes in arbitrary chunks; its CSV rows without the latency."""
    out = io.StringIO()
    session = LiveSession(model, out=out, quaternion=True,
                          on_event=None if events is None else lambda level, text: events.append((level, text)))
    for k in range(0, len(data), 997):
        session.feed(Chunk(time.perf_counter(), data[k:k + 997]))
    session.close()
    return session, _csv_rows(out.getvalue())


@pytest.mark.parametrize("line", [b"abc,1,2,3\n", b"0.0" + b",nan" * 9 + b"\n", b"0.0" + b",1e300" * 9 + b"\n",
                                  b"0.0" + b",inf" * 9 + b"\n", b"0.0" + b",1e9" * 9 + b"\n"])
def test_live_drops_a_first_line_of_garbage_and_fuses_nothing_of_it(stream, line):
    """``compass live`` on a stream whose first sample line is garbage (text, NaN, 1e300, inf, or 1e9 on every
    sensor, each without the checksum the header carries: the 1e9 line is garbage for that alone): the line is
    dropped, counted and said as line noise; every other sample is solved exactly as without it (the start
    window is the same), and nothing written is non-finite."""
    model, t, s = stream
    data = _lines(model, t, s)
    header, rest = data.split(b"\n", 1)
    first, rest = rest.split(b"\n", 1)
    events = []
    session, rows = _session_rows(model, header + b"\n" + line + rest, events)
    clean, clean_rows = _session_rows(model, header + b"\n" + rest)
    assert rows == clean_rows and session.samples == len(t) - 1
    stats = session.decoder.stats
    assert stats.garbage + stats.partial == 1 and session.skipped == {}
    assert any(level == "warn" and "line noise" in text for level, text in events)
    values = np.array([row for row in rows[1:]], dtype=float)
    assert np.all(np.isfinite(values))


def test_live_skips_a_well_formed_absurd_line_as_the_replay_does(stream):
    """A checksummed line of 1e9 on every sensor is within the decoder's limit (``MAX_ABS_VALUE``, 1e12, the
    recordings'): decoded, not line noise, then skipped by the filter as the replay skips it (the field
    out of range), said once; every other sample solved exactly as without it."""
    model, t, s = stream
    header, rest = _lines(model, t, s).split(b"\n", 1)
    rest = rest.split(b"\n", 1)[1]
    events = []
    session, rows = _session_rows(model, header + b"\n" + format_line(["0.0"] + ["1e9"] * 9) + rest, events)
    _, clean_rows = _session_rows(model, header + b"\n" + rest)
    stats = session.decoder.stats
    assert stats.garbage == stats.partial == stats.invalid == 0 and session.skipped == {"field out of range": 1}
    assert rows == clean_rows
    assert not any("line noise" in text for _, text in events)
    assert any("sample skipped, never fused: field out of range" in text for _, text in events)


def _spinning(t_s):
    """Already turning fast at the first row (40 deg/s in heading, pitch and roll swinging)."""
    return 40.0 * t_s, 20.0 * np.sin(2.0 * t_s), 25.0 * np.cos(1.3 * t_s), np.zeros(len(t_s), dtype=bool)


@pytest.mark.parametrize("gyro", [True, False])
def test_a_recording_that_starts_moving_is_replayed_as_live_finite_and_on_the_truth(gyro):
    """No quiet second at the start: live (bytes) and the replay write the same rows, every one finite,
    and the attitude is on the truth from the first second (the start window's tilt, not one row's)."""
    model = default_model()
    t = np.arange(0.0, 12.0, 1.0 / RATE_HZ)
    s = simulate_device(model, t, motion=_spinning, seed=2, gyro_bias=[0.0, 0.0, 0.0])
    _, live_rows = _session_rows(model, _lines(model, t, s, gyro))
    out = io.StringIO()
    replay(LiveSession(model, out=out, quaternion=True), t, s.raw, s.accel, s.gyro if gyro else None)
    rows = _csv_rows(out.getvalue())
    assert rows == live_rows and len(rows) == len(t) + 1
    table = read_table(_write(out.getvalue()))
    assert all(np.all(np.isfinite(table.column(c))) for c in table.columns)
    heading, pitch = table.column("heading_deg"), table.column("pitch_deg")
    first = t < 1.0
    # the simulator's noise gives ~0.2 deg; the two-vector filter lags a 40 deg/s turn by a few tenths more
    assert np.sqrt(np.mean(wrap(heading - s.heading_deg)[first] ** 2)) < 2.5
    assert np.sqrt(np.mean((pitch - s.pitch_deg)[first] ** 2)) < 1.0
    assert np.sqrt(np.mean(wrap(heading - s.heading_deg) ** 2)) < 1.0


def test_live_says_an_unnamed_deg_s_gyro_and_writes_nothing_non_finite(stream):
    """A gyro in deg/s taken for rad/s (no --gyro-unit): compass live warns once, naming --gyro-unit (the replay
    refuses it, exit 2: test_the_command_refuses_bad_input_in_one_line); nothing written is non-finite."""
    model, t, s = stream
    degrees = replace(s, gyro=np.degrees(s.gyro))
    events = []
    _, rows = _session_rows(model, _lines(model, t, degrees), events)
    said = [text for level, text in events if level == "warn" and "--gyro-unit" in text]
    assert len(said) == 1 and re.search(r"turns \d+ times more", said[0])
    assert np.all(np.isfinite(np.array(rows[1:], dtype=float)))


def _with_column(path, column, values):
    """``path`` rewritten with ``column``'s cells replaced by ``values`` (one per data row)."""
    lines = path.read_text().splitlines()
    k = lines[0].split(",").index(column)
    rows = [line.split(",") for line in lines[1:]]
    for row, value in zip(rows, values):
        row[k] = repr(float(value))
    path.write_text("\n".join([lines[0]] + [",".join(row) for row in rows]) + "\n")
    return path


@pytest.mark.parametrize("case, words", [
    ("t_s constant", "column 't_s': t_s is 0 in all 3000 samples: the filter integrates no gyro"),
    ("t_s in ms", "column 't_s': t_s steps by 10 s (median of 3000 samples): each step is a gap over the filter's "
                  "0.5 s"),
    ("dead gyro", "column 'gx': the gyro gx,gy,gz read in rad/s never turns while the accelerometer sees the housing "
                  "tilt: a dead gyro?"),
    ("rad/s named deg/s", "read in deg/s turns 60 times less than the accelerometer sees the housing tilt"),
    ("five rows", "no attitude from its 5 rows (the filter's start seeds the reference field from at least 10 rows; "
                  "give --site"),
    ("gyro at a rail", "than the accelerometer sees the housing tilt; it holds 4.3633, 4.3633, -4.3633 in every "
                       "sample: a gyro stuck at a rail (disconnected, or a part that failed)? Without gx,gy,gz columns "
                       "the two-vector filter runs"),
    ("gyro all NaN", "row 2, column 'gx': expected a finite number, found nan (as in all 3000 rows of gx: a sensor not "
                     "recorded? leave its columns out)"),
    ("t_s restarting", "row 1502, column 't_s': t_s must not decrease (goes from 14.99"),
    ("gravity in m/s^2", "column 'ax': --gravity 9.80665 is not what 1 g reads: the accelerometer's median |a| over "
                         "the start's 101 rows is 1,"),
])
def test_the_command_refuses_what_it_would_fuse_wrong_in_one_line(files, stream, capsys, case, words):
    """Time stamps that do not tell the time between samples (all equal, or in ms: every step a gap that restarts
    the filter; a clock restarting mid-file), a gyro that reads zero while the housing tilts (fused as a still
    housing) or one value off zero (stuck at a rail: said besides the unit it would be), a rad/s gyro whose header
    says deg/s (fused 57 times too slow), a gyro column of NaN, fewer rows than the start needs, a --gravity in m/s^2
    where --accel-unit m/s2 makes the accelerometer read in g (it was never used: 0 % of the rows): exit 2, one line
    naming the file and column, nothing written (replayed, each gives a wrong attitude, or 3000 restart lines); five
    rows are refused with the reason, not the session's counters."""
    _, t, s = stream
    cal, recording = files
    rec = recording(accel_scale=9.80665 if case == "gravity in m/s^2" else 1.0)
    extra = ["--accel-unit", "m/s2", "--gravity", "9.80665"] if case == "gravity in m/s^2" else []
    if case == "gyro at a rail":
        for column, rail in (("gx", 4.3633), ("gy", 4.3633), ("gz", -4.3633)):
            _with_column(rec, column, np.full(len(t), rail))
    elif case == "gyro all NaN":
        _with_column(rec, "gx", np.full(len(t), np.nan))
    elif case == "t_s restarting":
        _with_column(rec, "t_s", np.where(t < 15.0, t, t - 15.0))
    elif case == "gravity in m/s^2":
        pass
    elif case == "t_s constant":
        _with_column(rec, "t_s", np.zeros(len(t)))
    elif case == "t_s in ms":
        _with_column(rec, "t_s", 1e3 * t)
    elif case == "dead gyro":
        for column in ("gx", "gy", "gz"):
            _with_column(rec, column, np.zeros(len(t)))
    elif case == "rad/s named deg/s":
        text = rec.read_text()
        rec.write_text(text.replace("gx,gy,gz", "Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s)", 1))
    else:
        rec.write_text("\n".join(rec.read_text().splitlines()[:6]) + "\n")
    out = cal.parent / "att.csv"
    code = main(["attitude", str(cal), str(rec), "--out", str(out), "--filter", *extra])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert str(rec) in err and words in err, err
    assert not out.exists()


def test_live_says_a_dead_gyro_instead_of_failing(stream):
    """A module whose gyro sends zeros while the housing tilts (its turn ratio 1 / 0): compass live stops, naming a
    dead gyro once (the replay refuses it in the same words), and writes nothing non-finite."""
    model, t, s = stream
    events = []
    session, rows = _session_rows(model, _lines(model, t, replace(s, gyro=np.zeros_like(s.gyro))), events)
    said = [text for level, text in events if level == "warn" and "dead gyro" in text]
    assert len(said) == 1 and said[0] == session.gyro_unit and len(rows) < len(t) + 1
    assert np.all(np.isfinite(np.array(rows[1:], dtype=float)))


def test_live_says_once_a_t_s_in_milliseconds(stream):
    """A module sending its clock in ms as t_s: every step is a 10 s gap that restarts the filter; the cause is said
    once, after the first samples, and nothing written is non-finite.  A t_s in seconds is
    not so warned."""
    model, t, s = stream
    events = []
    _, rows = _session_rows(model, _lines(model, 1e3 * t, s), events)
    said = [text for level, text in events if level == "warn" and "a time in milliseconds?" in text]
    assert len(said) == 1 and "t_s steps by 10 s" in said[0]
    assert np.all(np.isfinite(np.array(rows[1:], dtype=float)))
    seconds = []
    _session_rows(model, _lines(model, t, s), seconds)
    assert not any("milliseconds" in text for _, text in seconds)


def test_live_says_once_a_t_s_that_never_increases(stream):
    """A module whose t_s stays at one value (a clock not running): the filter integrates no gyro; compass live
    says so once, after the first samples (the replay refuses such a recording), and writes nothing non-finite.  A
    t_s that runs is not so warned."""
    model, t, s = stream
    events = []
    _, rows = _session_rows(model, _lines(model, np.full_like(t, 3.0), s), events)
    said = [text for level, text in events if level == "warn" and "t_s is 3 in all" in text]
    assert len(said) == 1 and not any("milliseconds" in text for _, text in events)
    assert np.all(np.isfinite(np.array(rows[1:], dtype=float)))
    running = []
    _session_rows(model, _lines(model, t, s), running)
    assert not any("does not increase" in text for _, text in running)


@pytest.mark.parametrize("mode", [["--filter"], []])
def test_a_dead_accelerometer_axis_is_refused_naming_it(files, stream, capsys, mode):
    """az reading 0 in every row while ax and ay follow the tilt: fused, the filter would learn gravity and the
    reference's dip from it (dip -6 deg against 60), and the per-row solution flag two thirds of the rows disturbed:
    exit 2 in one line naming the column, replayed or solved per row.  A still housing, whose axes a coarse
    resolution can hold constant, is not refused (test_a_still_log_at_a_coarse_resolution_is_solved)."""
    _, t, _ = stream
    cal, recording = files
    rec = _with_column(recording(), "az", np.zeros(len(t)))
    out = cal.parent / "att.csv"
    code = main(["attitude", str(cal), str(rec), "--out", str(out), *mode])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert f"{rec}, column 'az': is constant (0 in all 3000 rows) while ax, ay change" in err
    assert not out.exists()


def test_a_still_log_at_a_coarse_resolution_is_solved(files, stream, tmp_path):
    """A housing lying still for 3 s, its accelerometer logged at 0.01 g (ax and ay read 0.00 throughout, az
    1.00 or next to it): no axis changes, none is called dead, the recording is solved."""
    model, t, s = stream
    cal, _ = files
    still = t < 3.0
    accel = np.round(s.accel[still], 2)
    accel[:, :2] = 0.0
    columns = {"t_s": t[still]} | {c: s.raw[still, k] for k, c in enumerate(model.channels)} \
        | {c: accel[:, k] for k, c in enumerate(("ax", "ay", "az"))}
    rec = tmp_path / "still.csv"
    rec.write_text(format_table(columns, {}, {c: "%.17g" for c in columns}))
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "att.csv"), "--filter"]) == 0


def _tilting_accel(g: float = 9.80665, count_g: float = 1.0 / 21.33):
    """A housing rocking +-10 deg about x and +-8 deg about y (periods 7 s and 5 s, 30 s at 100 Hz), its
    accelerometer logged to ``count_g`` g (an MMA7660-like 6-bit part): near level the vertical axis moves by
    ``1 - cos``, under one count, while x and y move by ``sin``, several counts."""
    t = np.arange(0.0, 30.0, 0.01)
    rot = Rotation.from_euler("xy", np.radians(np.column_stack([10 * np.sin(2 * np.pi * t / 7),
                                                                8 * np.sin(2 * np.pi * t / 5)])))
    up = rot.inv().apply([0.0, 0.0, g])
    return np.round(up / (count_g * g)) * (count_g * g)


@pytest.mark.parametrize("dead", [False, True])
def test_a_coarse_axis_a_gentle_tilt_leaves_on_one_code_is_not_called_dead(tmp_path, dead):
    """The live coarse az reads one code throughout while ax and ay follow the tilt; the vector keeps its length
    (within the counts), so it is no dead axis.  The same log with az reading 0 (the length then ax and ay's alone,
    0 to 0.2 g) is refused naming az."""
    accel = _tilting_accel()
    assert np.ptp(accel[:, 2]) == 0.0 and np.all(np.ptp(accel[:, :2], axis=0) > 0.1 * 9.80665)
    if dead:
        accel[:, 2] = 0.0
    path = tmp_path / "coarse.csv"
    columns = {"t_s": np.arange(len(accel)) * 0.01} | {c: accel[:, k] for k, c in enumerate(("ax", "ay", "az"))}
    path.write_text(format_table(columns, {}, {c: "%.17g" for c in columns}))
    table = read_table(path)
    if dead:
        with pytest.raises(RecordingError, match="column 'az': is constant"):
            table.check_dead_axis(("ax", "ay", "az"))
    else:
        table.check_dead_axis(("ax", "ay", "az"))


def test_a_gyro_turning_less_with_no_unit_named_is_said_not_refused(files, capsys):
    """A gyro turning 60 times less than the tilt with no unit named matches no unit taken for another (rad/s read
    as deg/s needs the header's deg/s, refused in test_the_command_refuses_what_it_would_fuse_wrong_in_one_line;
    a board still most of the time, its accelerometer jittering by degrees, reads so too): the reader's warning,
    and the recording is replayed."""
    cal, recording = files
    out = cal.parent / "att.csv"
    code = main(["attitude", str(cal), str(recording(gyro_scale=1.0 / 60.0)), "--out", str(out), "--filter"])
    err = capsys.readouterr().err
    assert code == 0 and "times less" in err and "Traceback" not in err, err
    assert np.all(np.isfinite(read_table(out).column("heading_deg")))


def test_an_accelerometer_unit_named_is_read_in_g_on_both_paths(files, stream, capsys):
    """A recording whose accelerometer is in m/s^2, named with --accel-unit m/s2: the replay reads it in g as compass
    live does, so --gravity 1 means the same on both paths and they write the same rows (the replay kept m/s^2 and
    never used the accelerometer at --gravity 1, 0 % of the rows); the accelerometer is used in most rows."""
    from compass.io.streams import StreamOptions

    model, t, s = stream
    cal, recording = files
    out = cal.parent / "att.csv"
    rec = recording(accel_scale=9.80665)
    assert main(["attitude", str(cal), str(rec), "--out", str(out), "--filter", "--accel-unit", "m/s2",
                 "--gravity", "1"]) == 0
    assert "Traceback" not in capsys.readouterr().err
    live = LiveSession(model, config=FilterConfig.from_model(model, gravity=1.0), out=io.StringIO(), quaternion=True,
                       stream=StreamOptions(accel_unit="m/s2"))
    data = _lines(model, t, replace(s, accel=9.80665 * s.accel))
    for k in range(0, len(data), 997):
        live.feed(Chunk(time.perf_counter(), data[k:k + 997]))
    live.close()
    assert _csv_rows(out.read_text()) == _csv_rows(live.out.getvalue())
    assert np.mean(read_table(out).column("accel_used")) > 0.9


def _flick(t_s):
    """Rocking gently, flicked 90 deg in heading in 0.25 s at 10 s and back at 20 s (565 deg/s at the peak)."""
    t = np.asarray(t_s, dtype=float)
    turn = sum(sign * 0.5 * (1.0 - np.cos(np.pi * np.clip((t - t0) / 0.25, 0.0, 1.0)))
               for t0, sign in ((10, 1), (20, -1)))
    return 30.0 + 90.0 * turn, 10.0 * np.sin(2 * np.pi * t / 7), 8.0 * np.sin(2 * np.pi * t / 5), np.zeros(len(t))


@pytest.mark.parametrize("saturated", [True, False])
def test_a_gyro_saturating_at_its_range_is_said_once_on_both_paths(tmp_path, capsys, saturated):
    """A 565 deg/s flick read by a 250 deg/s gyro: gz holds its rail for 18 samples, the heading is 35 deg off for
    seconds after (the field's innovation gate rejects the truth).  Replayed (the command) and live (the session fed
    the module's bytes), the rail is said once, naming the axis, its rate and the time, and everything written is
    finite; the same flick within the gyro's range is not said."""
    from compass.calibration import model_to_dict, save

    model = default_model()
    t = np.arange(0.0, 30.0, 1.0 / RATE_HZ)
    s = simulate_device(model, t, motion=_flick, seed=3, gyro_bias=GYRO_BIAS)
    rail = np.radians(250.0)
    if saturated:
        s = replace(s, gyro=np.clip(s.gyro, -rail, rail))
    assert np.count_nonzero(np.abs(s.gyro[:, 2]) >= rail) == 36  # 18 samples a flick beyond (or at) the range
    cal, rec, out = tmp_path / "cal.json", tmp_path / "rec.csv", tmp_path / "att.csv"
    save(cal, model_to_dict(model))
    columns = {"t_s": t} | {c: s.raw[:, k] for k, c in enumerate(model.channels)} \
        | {c: s.accel[:, k] for k, c in enumerate(("ax", "ay", "az"))} \
        | {c: s.gyro[:, k] for k, c in enumerate(("gx", "gy", "gz"))}
    rec.write_text(format_table(columns, {}, {c: "%.17g" for c in columns}))
    words = "the gyro's z axis reads -4.363 rad/s (-250 deg/s) in 10 samples in a row by t_s 10.1"
    assert main(["attitude", str(cal), str(rec), "--out", str(out), "--filter"]) == 0
    err = capsys.readouterr().err
    said = [line for line in err.splitlines() if "saturated at its range?" in line]
    assert len(said) == int(saturated) and all(words in line for line in said) and "Traceback" not in err, err
    table = read_table(out)
    assert all(np.all(np.isfinite(table.column(c))) for c in table.columns)
    events = []
    _, rows = _session_rows(model, _lines(model, t, s), events)
    said = [text for level, text in events if level == "warn" and "saturated at its range?" in text]
    assert len(said) == int(saturated) and all(words in text for text in said)
    assert np.all(np.isfinite(np.array(rows[1:], dtype=float)))


@pytest.mark.parametrize("kind, dip_deg, level, words", [
    ("fourflip", 60.0, "info", "its bench assumed the northern hemisphere (a four-flip bench cannot tell (a, B) from (-a, -B)), "
                       "and no --site checks it: in the southern hemisphere every heading is 180 deg off"),
    ("channels", -60.0, "warn", "its field points up (dip -60.0 deg), which is right only in the southern hemisphere, and no "
                        "--site checks it: in the northern hemisphere (a magnetometer axis reversed) every heading is "
                        "180 deg off")])
def test_a_field_sign_resting_on_an_assumed_hemisphere_is_said_once_unless_a_site_checks_it(files, capsys, kind,
                                                                                              dip_deg, level, words):
    """An assumed bench hemisphere (every four-flip without a latitude) is a note; a field pointing up, a warning.
    The recording's field points down: against a calibration that measured it pointing up the session stops too
    (the stream's accelerometer reading gravity, or the module across the magnetic equator: the same dips)."""
    import json

    from compass.calibration import load
    from compass.replay import hemisphere_note

    cal, recording = files
    document = json.loads(cal.read_text()) | {"model": kind, "dip_deg": dip_deg}
    cal.write_text(json.dumps(document))
    status = main(["attitude", str(cal), str(recording()), "--out", str(cal.parent / "att.csv"), "--filter"])
    err = capsys.readouterr().err.splitlines()
    assert status == (0 if kind == "fourflip" else 2)
    said = [line for line in err if "180 deg off" in line and line.startswith("[")]
    assert len(said) == 1 and f"[{level}] {cal}: {words}. Give --site LAT,LON" in said[0]
    stopped = [line for line in err if "against its calibration" in line]
    assert len(stopped) == (status == 2) and all("--accel-sign -1" in line for line in stopped)
    assert hemisphere_note(load(cal), site_given=True) is None
    plain = json.loads(cal.read_text()) | {"model": "channels", "dip_deg": abs(dip_deg)}  # measured, pointing down
    cal.write_text(json.dumps(plain))
    assert hemisphere_note(load(cal), site_given=False) is None
