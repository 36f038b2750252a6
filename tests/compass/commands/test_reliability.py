"""Reliability round 2 (issue 23): one test per failure found, each failing before its fix.

Every case runs in-process (``compass.cli.main``) unless it needs a port.  The broader corpus of the
same classes (every numeric option, every key of every calibration kind, counters at every extreme)
is in ``tests/compass/commands/test_fuzz.py``; the live session under adversarial lines over a socket is in
``tests/compass/live/test_live_adversarial.py``.
"""

import copy
import io
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.io import savemat

from compass.calibration import FORMAT, model_to_dict
from compass.cli import main
from compass.io.lines import MAX_GAP_SAMPLES, format_line
from compass.live import LiveSession
from compass.serial_reader import Chunk
from compass.sim.device import default_model, simulate_device

MODEL = default_model()
SIM = simulate_device(MODEL, np.arange(300) / 100.0, seed=1)


def _stream(with_seq: bool = True, edits: dict | None = None, seq_of=lambda i: i) -> bytes:
    """The device's 300 samples as protocol lines; ``edits`` = {line index: (column, text)}."""
    names = (["seq"] if with_seq else []) + ["t_s", *MODEL.channels, "ax", "ay", "az"]
    lines = [format_line(names)]
    for i, (t, raw, a) in enumerate(zip(SIM.t_s, SIM.raw, SIM.accel)):
        cells = ([seq_of(i)] if with_seq else []) + [f"{t:.4f}", *(f"{v:.6g}" for v in raw), *(f"{v:.6g}" for v in a)]
        if edits and i in edits:
            column, text = edits[i]
            cells[names.index(column)] = text
        lines.append(format_line(cells))
    return b"".join(lines)


def _session(stream: bytes) -> tuple[LiveSession, list[str], list[str]]:
    out, events = io.StringIO(), []
    session = LiveSession(MODEL, out=out, on_event=lambda level, text: events.append(text))
    session.feed(Chunk(time.perf_counter(), stream))
    session.close()
    return session, out.getvalue().splitlines()[2:], events


def _finite_rows(rows: list[str]) -> bool:
    return all(math.isfinite(float(cell)) and len(cell) < 20 for row in rows for cell in row.split(","))


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and "Warning" not in err, err
    return lines[0]


# 1-3: live with extreme counters and values ----------------------------------------------------

@pytest.mark.parametrize("with_seq, column, text", [
    (False, "t_s", "1e308"),  # was OverflowError: cannot convert float infinity to integer (exit 1)
    (True, "seq", "1" + "0" * 30),  # was "lost in transit 999999999999999999999999999950"
    (True, "seq", "-5"),  # was taken as a counter restart (155 lost)
    (False, "t_s", "1e300"),  # was 2e303 lost
    (True, "t_s", "-1e308"),  # was a row with a 309-digit time
    (True, "mx", "1e300"),  # was a row of nan
    (True, "ax", "-1e13"),
])
def test_one_extreme_cell_is_an_invalid_line_and_nothing_else(with_seq, column, text):
    session, rows, _ = _session(_stream(with_seq, {150: (column, text)}))
    s = session.decoder.stats
    assert (s.samples, s.invalid, s.lost, s.garbage) == (299, 1, 0, 0)
    assert len(rows) == session.samples == 299 and _finite_rows(rows)


def test_a_counter_that_jumps_beyond_any_gap_is_said_and_not_counted_as_lost():
    jump = 10 * MAX_GAP_SAMPLES
    session, rows, events = _session(_stream(True, seq_of=lambda i: i if i < 150 else i + jump))
    assert session.decoder.stats.lost == 0 and session.decoder.stats.samples == 300
    assert any("seq jumped from 149" in e and "not counted as lost" in e for e in events)
    # a real gap is still counted: five lines missing
    session, _, _ = _session(_stream(True, seq_of=lambda i: i if i < 150 else i + 5))
    assert session.decoder.stats.lost == 5


def test_a_clock_that_jumps_without_seq_is_not_counted_as_lost():
    t_jump = SIM.t_s + np.where(np.arange(300) >= 150, 1e9, 0.0)  # 1e9 s: within the cells' range
    names = ["t_s", *MODEL.channels, "ax", "ay", "az"]
    stream = format_line(names) + b"".join(format_line([f"{t:.4f}", *raw, *a]) for t, raw, a in
                                           zip(t_jump, SIM.raw, SIM.accel))
    session, rows, events = _session(stream)
    assert session.decoder.stats.lost == 0 and _finite_rows(rows)
    assert any("t_s jumped" in e for e in events)


@pytest.mark.parametrize("bad_t_s, reason", [(-1.0, "t_s went back"), (0.0, "t_s went back"),
                                              (1.0, "t_s went back"), (1e11, "t_s jumped ahead"),
                                              (7.5, "t_s jumped ahead")])
def test_one_time_that_goes_back_costs_the_gyro_filter_that_sample_only(bad_t_s, reason):
    """It was a step of zero, and the next sample's step was taken from it: 2.5 s of gyro, a filter restart
    and 1 deg of heading; now the sample is skipped and the step taken from the clock before it.  A time ahead by
    more than the filter's gap (one digit flipped, 1e11) restarted the filter: it too costs only its sample."""
    from compass.filter import AttitudeFilter, FilterConfig

    fields, _ = MODEL.field(SIM.raw)

    def headings(times, drop=None):
        f, out = AttitudeFilter(FilterConfig.from_model(MODEL), gyro=True), []
        for k, (t, a, g, b) in enumerate(zip(times, SIM.accel, SIM.gyro, fields)):
            if k != drop:
                out.append(f.step(t, a, g, b))
        return np.array([e.heading_deg for e in out if e is not None]), f

    times = SIM.t_s.copy()
    times[150] = bad_t_s
    corrupted, f = headings(times)
    dropped, _ = headings(SIM.t_s, drop=150)
    np.testing.assert_array_equal(corrupted, dropped)
    assert f.skipped.as_dict() == {reason: 1} and not f.events


def test_a_real_gap_restarts_the_gyro_filter_at_the_sample_after_it():
    """A pause (every time after it ahead by 3 s): its first sample is kept aside, the next goes on from it, and the
    filter restarts there, said once; the two-vector filter, which solves each sample alone, keeps every sample."""
    from compass.filter import AttitudeFilter, FilterConfig

    fields, _ = MODEL.field(SIM.raw)
    times = np.where(np.arange(300) < 150, SIM.t_s, SIM.t_s + 3.0)
    f = AttitudeFilter(FilterConfig.from_model(MODEL), gyro=True)
    est = [f.step(t, a, g, b) for t, a, g, b in zip(times, SIM.accel, SIM.gyro, fields)]
    assert [k for k, e in enumerate(est) if e is None] == [150] and f.skipped.as_dict() == {"t_s jumped ahead": 1}
    assert [e for e in f.events if "gap" in e] == ["filter restarted after a 3.02 s gap in the samples"]  # from 149
    two = AttitudeFilter(FilterConfig.from_model(MODEL), gyro=False)
    assert all(two.step(t, a, None, b) is not None for t, a, b in zip(times, SIM.accel, fields))
    slow = AttitudeFilter(FilterConfig.from_model(MODEL), gyro=True)  # every step a gap: each sample restarts it,
    est = [slow.step(t, a, g, b) for t, a, g, b in zip(np.arange(300.0), SIM.accel, SIM.gyro, fields)]
    assert all(e is not None for e in est) and not slow.skipped.as_dict()  # none kept aside (every other was)


def test_a_clock_restarted_by_the_module_is_adopted_after_one_sample():
    from compass.filter import AttitudeFilter, FilterConfig

    fields, _ = MODEL.field(SIM.raw)
    f = AttitudeFilter(FilterConfig.from_model(MODEL), gyro=True)
    times = np.where(np.arange(300) < 150, SIM.t_s, SIM.t_s - 1.5)  # the module restarted its clock at 0
    est = [f.step(t, a, g, b) for t, a, g, b in zip(times, SIM.accel, SIM.gyro, fields)]
    assert [k for k, e in enumerate(est) if e is None] == [150] and not f.events
    assert est[-1].t_s == times[-1]


def test_a_field_beyond_the_screen_writes_no_row():
    """mx = 1e11 is a number a line may carry (below 1e12); its field is skipped, and its row is not written
    (it had field_ratio and dip_deg nan)."""
    session, rows, _ = _session(_stream(True, {150: ("mx", "1e11")}))
    assert session.skipped == {"field out of range": 1} and session.unsolved == 1
    assert len(rows) == session.samples == 299 and _finite_rows(rows)
    assert "299 attitudes from 300 samples" in session.summary()


# 4: a failed live --force keeps the existing --out ----------------------------------------------

@pytest.fixture
def cal(tmp_path):
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(model_to_dict(MODEL)))
    return path


def test_a_failed_live_session_with_force_leaves_the_existing_out_as_it_was(tmp_path, cal, capsys):
    out = tmp_path / "att.csv"
    out.write_text("yesterday's session\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["live", "--port", str(tmp_path / "ttyUSB9"), "--cal", str(cal), "--out", str(out), "--force",
                 "--duration", "5"]) == 2
    assert "cannot open port" in _one_line(capsys.readouterr().err)
    assert out.read_text() == "yesterday's session\n" and sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_live_session_without_samples_leaves_the_existing_out_as_it_was(tmp_path, cal, monkeypatch, capsys):
    from tests.compass.live.test_live_mistakes import _live_on_socket

    out = tmp_path / "att.csv"
    out.write_text("yesterday's session\n")
    status, alive, errors = _live_on_socket(monkeypatch, b"\x00 noise \xfe\r\n" * 5, cal, "--duration", "1",
                                            "--out", str(out), "--force")
    assert status == 1 and not alive and not errors
    assert out.read_text() == "yesterday's session\n" and not list(tmp_path.glob(".*.tmp"))


# 5, 6: bad values are exit 2 naming the value ---------------------------------------------------

@pytest.fixture(scope="module")
def fourflip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fourflip")
    assert main(["simulate", "fourflip", "--out", str(folder / "ff.csv")]) == 0
    return folder / "ff.csv"


@pytest.mark.parametrize("argv, names", [
    (["calibrate", "{ff}", "--field-ut", "1e308"], "--field-ut"),
    (["live", "--port", "loop://", "--cal", "{cal}", "--baud", "1000000000000"], "--baud"),
    (["simulate", "fourflip", "--field-ut", "inf"], "--field-ut"),
    (["simulate", "fourflip", "--seed", "-1"], "--seed"),
    (["simulate", "fourflip", "--channels", "100000"], "--channels"),
    (["simulate", "tumble", "--rate-hz", "1e-300"], "--rate-hz"),
    (["simulate", "tumble", "--samples", "100000000000"], "--samples"),
    (["simulate", "installation", "--hard-iron-ut", "nan"], "--hard-iron-ut"),
    (["simulate", "installation", "--yaw-deg", "inf"], "--yaw-deg"),
    (["simulate", "reference", "--sensors", "1000"], "--sensors"),
])
def test_an_option_out_of_its_range_is_one_line_naming_it(tmp_path, cal, fourflip, capsys, argv, names):
    argv = [a.format(ff=fourflip, cal=cal) for a in argv]
    if argv[0] in ("simulate", "calibrate"):
        argv += ["--out", str(tmp_path / "out.csv")]
    assert main(argv) == 2
    assert f"argument {names}: must be" in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "out.csv").exists()


def _rewrite(src: Path, dst: Path, change) -> Path:
    lines = src.read_text().splitlines()
    dst.write_text("\n".join(change(lines)) + "\n")
    return dst


def test_field_ut_metadata_of_1e308_names_its_line(tmp_path, fourflip, capsys):
    rec = _rewrite(fourflip, tmp_path / "ff.csv",
                   lambda lines: ["# field_ut: 1e308" if x.startswith("# field_ut:") else x for x in lines])
    assert main(["calibrate", str(rec), "--out", str(tmp_path / "cal.json")]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "ff.csv, row 1, column 'field_ut'" in line and "'1e308'" in line
    assert not (tmp_path / "cal.json").exists()


def test_channels_of_1e_300_are_refused_in_one_line_without_numpy_warnings(tmp_path, fourflip, capsys):
    def tiny(lines):
        header = next(i for i, x in enumerate(lines) if not x.startswith("#"))
        names = lines[header].split(",")
        out = lines[:header + 1]
        for x in lines[header + 1:]:
            cells = x.split(",")
            out.append(",".join(repr(float(c) * 1e-300) if n.startswith("v") else c for n, c in zip(names, cells)))
        return out

    rec = _rewrite(fourflip, tmp_path / "tiny.csv", tiny)
    assert main(["calibrate", str(rec), "--out", str(tmp_path / "cal.json")]) == 2
    assert "tiny.csv, column 'v1': spans" in _one_line(capsys.readouterr().err)


def _broad(path: Path, **change) -> Path:
    n = 40
    good = {"imu_gyr": np.zeros((n, 3)), "imu_acc": np.tile([0, 0, 9.81], (n, 1)),
            "imu_mag": np.tile([20.0, 0, -40.0], (n, 1)), "opt_quat": np.tile([1.0, 0, 0, 0], (n, 1)),
            "opt_pos": np.zeros((n, 3)), "movement": np.ones(n, dtype=np.uint8), "sampling_rate": 100.0}
    savemat(path, good | change)
    return path


@pytest.mark.parametrize("change, place", [
    ({"sampling_rate": 1e308}, "column 'sampling_rate'"),
    ({"sampling_rate": 1e-300}, "column 'sampling_rate'"),
    ({"imu_mag": np.r_[np.tile([20.0, 0, -40.0], (7, 1)), [[1e308, 0, 0]], np.tile([20.0, 0, -40.0], (32, 1))]},
     "row 8, column 'imu_mag'"),
])
def test_evaluate_names_the_variable_and_row_of_an_extreme_value(tmp_path, capsys, change, place):
    trial = _broad(tmp_path / "trial.mat", **change)
    assert main(["evaluate", str(trial)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"trial.mat, {place}" in line and "FilterConfig" not in line


@pytest.fixture(scope="module")
def truth(fourflip):
    return json.loads(fourflip.with_name("ff.truth.json").read_text())


TRUTH_CASES = [("dip_deg", math.nan), ("dip_deg", "60"), ("dip_deg", True), ("field_ut", math.inf),
               ("noise_ut", -1.0), ("directions", "x"), ("directions", [[1, 0, 0]]), ("offsets", [math.nan, 0, 0]),
               ("gains_per_ut", {}), ("gains_per_ut", [0, 1, 1]), ("channels", [1, 2, 3]), ("channels", "v1"),
               ("effects", "x"), ("noise", ["a", 1, 2]), ("directions", [["1", 0, 0], [0, 1, 0], [0, 0, 1]])]


@pytest.mark.parametrize("kind", ["runtime", "installation"])
@pytest.mark.parametrize("key, value", TRUTH_CASES)
def test_simulate_refuses_a_truth_file_naming_the_key(tmp_path, truth, capsys, kind, key, value):
    path = tmp_path / "bad.truth.json"
    path.write_text(json.dumps(truth | {key: value}))
    out = tmp_path / "sim.csv"
    assert main(["simulate", kind, "--truth", str(path), "--out", str(out), "--samples", "20"]) == 2
    assert f"bad.truth.json: key '{key}'" in _one_line(capsys.readouterr().err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.truth.json"]


def test_simulate_never_writes_a_non_finite_number(tmp_path, truth, capsys):
    for kind in ("runtime", "installation"):
        assert main(["simulate", kind, "--truth", str(_truth_file(tmp_path, truth)), "--out",
                     str(tmp_path / f"{kind}.csv"), "--samples", "30"]) == 0
    for path in tmp_path.glob("*.*"):
        text = path.read_text().lower()
        assert "nan" not in text and "inf" not in text, path


def _truth_file(folder: Path, truth: dict) -> Path:
    path = folder / "bench.truth.json"
    path.write_text(json.dumps(truth))
    return path


# 7: an installed file's top level; physical bounds of the iron ----------------------------------

TUMBLE = {"format": FORMAT, "model": "tumble", "hard_iron": [12.0, -7.5, 3.0],
          "soft_iron": [[1.02, 0.01, 0.0], [0.01, 0.98, -0.02], [0.0, -0.02, 1.01]], "field_norm": 50.0,
          "mag_to_accel": None, "field_ut": 50.0, "dip_deg": 60.0, "noise_floor": [0.2, 0.2, 0.2]}


def _installed() -> dict:
    return {"format": FORMAT, "model": "installed", "base": model_to_dict(MODEL), "dip_deg": 60.0, "field_ut": 50.0,
            "installation": {"hard_iron_ut": [1.0, 2.0, 3.0], "soft_iron": np.eye(3).tolist()}}


@pytest.mark.parametrize("doc, key", [
    *[(_installed() | {"dip_deg": v}, "'dip_deg'") for v in (math.nan, math.inf, -math.inf, 100, -91, "60")],
    (_installed() | {"installation": {"hard_iron_ut": [1e308, 0, 0], "soft_iron": np.eye(3).tolist()}},
     "'installation.hard_iron_ut'"),
    (TUMBLE | {"hard_iron": [1e308, 0, 0]}, "'hard_iron'"),
    (TUMBLE | {"hard_iron": [6000.0, 0, 0]}, "'hard_iron' must be within 100 times"),
    (TUMBLE | {"soft_iron": (1e308 * np.eye(3)).tolist()}, "'soft_iron'"),
    (TUMBLE | {"soft_iron": (1e-300 * np.eye(3)).tolist()}, "'soft_iron'"),
])
def test_a_calibration_value_beyond_its_physical_bounds_is_refused_by_export(tmp_path, capsys, doc, key):
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))
    out = tmp_path / "fw.h"
    assert main(["export", str(path), "--format", "ardupilot", "--out", str(out)]) == 2
    assert f"cal.json: {key}" in _one_line(capsys.readouterr().err) and not out.exists()


# 8: reserved names are no channels ---------------------------------------------------------------

@pytest.mark.parametrize("name", ["t_s", "ax", "gz", "temp_c", "seq", "flip_deg"])
def test_a_reserved_name_is_refused_as_a_channel(tmp_path, capsys, name):
    doc = model_to_dict(MODEL)
    doc["channels"] = {(name if k == "mx" else k): v for k, v in doc["channels"].items()}
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))
    assert main(["live", "--port", "loop://", "--cal", str(path), "--duration", "1"]) == 2
    assert f"channel '{name}' is not a channel name" in _one_line(capsys.readouterr().err)


# 9: messages name the right thing ----------------------------------------------------------------

def test_a_recording_in_another_scale_is_named_with_the_evidence(tmp_path, cal, capsys):
    """It was blamed on the calibration alone; which of the two is off the numbers cannot tell (the fuzz
    makes calibrations a hundred times off): both are named, with the channel's reading and reach."""
    names = ["t_s", *MODEL.channels, "ax", "ay", "az"]
    rows = [",".join(f"{v:.10g}" for v in (t, *(1e11 * raw), *a)) for t, raw, a in zip(SIM.t_s, SIM.raw, SIM.accel)]
    rec = tmp_path / "rec.csv"
    rec.write_text(",".join(names) + "\n" + "\n".join(rows) + "\n")
    assert main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "att.csv")]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"compass attitude: {rec} does not fit {cal}: channel mx reads 1.") and "scale" in line


def test_a_calibration_with_no_usable_sensor_is_named_by_its_file(tmp_path, capsys):
    """ArduPilot export said "sensing directions must be finite", naming nothing."""
    doc = copy.deepcopy(TUMBLE)
    doc["soft_iron"] = (1e308 * np.eye(3)).tolist()
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))
    assert main(["export", str(path), "--format", "ardupilot"]) == 2
    assert _one_line(capsys.readouterr().err).startswith(f"compass export: {path}: ")


def test_a_base_line_is_named_as_the_recordings_line_not_as_an_option(tmp_path, truth, capsys):
    rec = tmp_path / "inst.csv"
    assert main(["simulate", "installation", "--truth", str(_truth_file(tmp_path, truth)), "--base", "gone.json",
                 "--out", str(rec), "--samples", "200"]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(rec), "--out", str(tmp_path / "cal.json")]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "inst.csv: its '# base: gone.json' line" in line and "--base" not in line


@pytest.mark.parametrize("url", ["socket://", "socket://host", "socket://:99999", "socket://127.0.0.1:notaport",
                                 "socket://[::1", "rfc2217://x:", "loop://?bad=1", "loop://?logging=x"])
def test_a_malformed_network_url_is_answered_in_words(cal, capsys, url):
    assert main(["live", "--port", url, "--cal", str(cal), "--duration", "1"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"port '{url}'" in line and "NoneType" not in line and "debug|info" not in line


# 10: a date the WMM does not cover ---------------------------------------------------------------

@pytest.mark.parametrize("date, ok", [("1800-01-01", False), ("2009-12-31", False), ("2010-01-01", True),
                                      ("2029-12-31", True), ("2030-01-01", False)])
def test_a_site_date_outside_the_wmm_is_refused(tmp_path, cal, capsys, date, ok):
    names = ["t_s", *MODEL.channels, "ax", "ay", "az"]
    rows = [",".join(f"{v:.10g}" for v in (t, *raw, *a)) for t, raw, a in zip(SIM.t_s, SIM.raw, SIM.accel)]
    rec = tmp_path / "rec.csv"
    rec.write_text(",".join(names) + "\n" + "\n".join(rows) + "\n")
    code = main(["attitude", str(cal), str(rec), "--out", str(tmp_path / "att.csv"), "--site", "10,10", "--date", date])
    err = capsys.readouterr().err
    if ok:
        assert code == 0
    else:
        assert code == 2 and f"site date {date} is outside the World Magnetic Model's" in _one_line(err)
        assert not (tmp_path / "att.csv").exists()
