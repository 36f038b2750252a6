"""Fuzz corpus of the runtime (generated here, no files) and property tests (hypothesis), issue 16.

- The line protocol: any bytes, cut anywhere, decode to samples or counted rejections, never an
  exception, the same whatever the chunking; well-formed lines round-trip exactly; a live session
  never raises on what a line can carry.
- Calibration files as the commands see them: any JSON is either refused with exit 2 and one line
  naming the file (no traceback, no output written, nothing existing changed) or a model whose
  every number is finite and whose attitudes are finite.
"""

import atexit
import copy
import io
import json
import math
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compass.calibration import FORMAT, load
from compass.cli import main
from compass.io.lines import LineDecoder, format_line
from compass.live import LiveSession
from compass.serial_reader import Chunk
from compass.sim.device import PtyDevice, default_model, simulate_device
from compass.calibration import model_to_dict

CHANNELS = ("mx", "my", "mz")
TOKENS = [b"mx", b"my", b"mz", b"t_s", b"seq", b"ax", b"ay", b"az", b"gx", b"gy", b"gz", b"temp_c", b"foo", b",", b",",
          b"\r", b"\n", b"\r\n", b"*", b"*00", b"#", b" ", b"1", b"-2.5", b"3e2", b"1e300", b"-1e308", b"nan", b"inf",
          b"0x1F", b"1,2,3", b"\xff\xfe", b"\x00", b"\xef\xbb\xbf", b";", b"1,5", b"7" * 3000, b"seq,mx,my,mz\r\n"]
protocolish = st.lists(st.sampled_from(TOKENS), max_size=80).map(b"".join)
streams = st.one_of(st.binary(max_size=2000), protocolish)


def _decode(chunks) -> tuple[LineDecoder, list]:
    decoder, out = LineDecoder(CHANNELS), []
    for chunk in chunks:
        out += decoder.feed(chunk)
    return decoder, out


def _cut(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    return [data[a:b] for a, b in zip([0, *points], [*points, len(data)])]


@settings(max_examples=400, deadline=None)
@given(streams, st.lists(st.integers(0, 10_000), max_size=12))
def test_any_bytes_anywhere_cut_decode_the_same_and_never_raise(data, cuts):
    whole, samples = _decode([data])
    cut, cut_samples = _decode(_cut(data, cuts))
    assert whole.stats == cut.stats
    assert [s.raw.tolist() for s in samples] == [s.raw.tolist() for s in cut_samples]
    for s in samples:
        assert s.raw.shape == (3,) and np.all(np.isfinite(s.raw))
        for group in (s.accel, s.gyro):
            assert group is None or (group.shape == (3,) and np.all(np.isfinite(group)))
    assert whole.stats.samples == len(samples)


finite = st.floats(min_value=-1e12, max_value=1e12)  # the protocol's range (compass.io.units.MAX_ABS_VALUE)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=20), st.booleans(),
       st.sampled_from([b"\r\n", b"\n", b"\r"]))
def test_well_formed_lines_round_trip_exactly(rows, with_checksum, ending):
    lines = [format_line(["seq", *CHANNELS], with_checksum=with_checksum)]
    lines += [format_line([i, *row], with_checksum=with_checksum) for i, row in enumerate(rows)]
    decoder, samples = _decode([b"".join(line[:-2] + ending for line in lines) + b"\n"])
    assert [tuple(s.raw.tolist()) for s in samples] == rows  # str(float) round-trips exactly
    assert [s.seq for s in samples] == list(range(len(rows)))
    assert decoder.stats.dropped == 0


def _device_stream(n: int = 150, seed: int = 1) -> tuple[bytes, list[bytes]]:
    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    return device._header, device._lines(simulate_device(model, np.arange(n) / 100.0, seed=seed), 0)


HEADER, LINES = _device_stream()
CELL = st.sampled_from(["1e300", "-1e300", "nan", "inf", "", "0", "1e-300", "x", "1,5", "99999999999999999999"])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, len(LINES) - 1), st.integers(0, 14), CELL), max_size=8),
       st.lists(st.integers(0, 30_000), max_size=6))
def test_a_live_session_never_raises_on_what_a_line_can_carry(edits, cuts):
    """Corrupted cells (huge, nan, empty, words) in well-checksummed lines, at any chunking."""
    lines = list(LINES)
    for index, cell, value in edits:
        cells = lines[index].split(b"*")[0].decode().split(",")
        cells[cell % len(cells)] = value
        lines[index] = format_line(cells)
    session = LiveSession(default_model())
    for chunk in _cut(HEADER + b"".join(lines), cuts):
        session.feed(Chunk(time.perf_counter(), chunk))
    s = session.decoder.stats
    assert s.samples + s.dropped >= len(LINES) - len(edits)  # every line is used or counted
    if session.estimate is not None:
        e = session.estimate
        assert all(math.isfinite(v) for v in (e.heading_deg, e.pitch_deg, e.roll_deg))


# ---------------------------------------------------------------------------------------------
# calibration files as the commands see them

def _channel_doc() -> dict:
    return model_to_dict(default_model())


def _tumble_doc() -> dict:
    return {"format": FORMAT, "model": "tumble", "hard_iron": [12.0, -7.5, 3.0],
            "soft_iron": [[1.02, 0.01, 0.0], [0.01, 0.98, -0.02], [0.0, -0.02, 1.01]], "field_norm": 50.0,
            "mag_to_accel": None, "field_ut": 50.0, "dip_deg": 60.0, "noise_floor": [0.2, 0.2, 0.2]}


def _recording(doc: dict, path: Path) -> Path:
    """300 rows of the document's sensor (channels and ax,ay,az) in the device's scripted motion."""
    with tempfile.TemporaryDirectory() as folder:
        cal = Path(folder) / "cal.json"
        cal.write_text(json.dumps(doc))
        model = load(cal).model
    s = simulate_device(model, np.arange(300) / 100.0, seed=3)
    names = ["t_s", *model.channels, "ax", "ay", "az"]
    rows = [",".join(f"{v:.10g}" for v in (t, *raw, *a)) for t, raw, a in zip(s.t_s, s.raw, s.accel)]
    path.write_text(",".join(names) + "\n" + "\n".join(rows) + "\n")
    return path


BASES = {"channels": _channel_doc(), "tumble": _tumble_doc()}
_RECORDINGS = {}


def _recording_for(kind: str) -> Path:
    if kind not in _RECORDINGS:
        folder = Path(tempfile.mkdtemp(prefix="compass-fuzz-"))
        atexit.register(shutil.rmtree, folder, True)  # shared by the examples, removed when the run ends
        _RECORDINGS[kind] = _recording(BASES[kind], folder / f"{kind}.csv")
    return _RECORDINGS[kind]


def _paths(node, prefix=()):
    """Every place in a JSON document: (path, node)."""
    yield prefix, node
    children = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, child in children:
        yield from _paths(child, (*prefix, key))


BAD_VALUES = st.one_of(
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 1e300, 0, 0.0, -1, -50.0, 1e-300, "fifty", "",
                     None, True, [], {}, [[]], [1.0, 2.0], [[1, 0, 0], [0, 1, 0], [0, 0, -1]]]),
    st.floats(), st.integers(), st.text(max_size=4), st.lists(st.floats(), max_size=4))


def _all_finite(node) -> bool:
    if isinstance(node, float):
        return math.isfinite(node)
    if isinstance(node, dict):
        return all(_all_finite(v) for v in node.values())
    if isinstance(node, list):
        return all(_all_finite(v) for v in node)
    return True


def _run(argv, capsys) -> tuple[int, str, str]:
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _assert_refused(code: int, err: str, cal: Path) -> None:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and cal.name in lines[0] and "Traceback" not in err, err


# derandomized: the same 150 documents in every CI run (the verdicts rest on every command's loading and
# on the calibration-file validation); explore more with --hypothesis-seed=N (seeds 1-32 pass here)
# an overflow inside a command is a failure (exit 1), not a warning: a file is refused before any sum overflows
@pytest.mark.filterwarnings("error::RuntimeWarning")
@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from(sorted(BASES)), data=st.data())
def test_any_calibration_json_is_refused_clearly_or_gives_finite_attitudes(kind, data, capsys):
    doc = copy.deepcopy(BASES[kind])
    for _ in range(data.draw(st.integers(1, 3))):
        places = list(_paths(doc))[1:]
        path, _ = data.draw(st.sampled_from(places))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        if isinstance(parent, dict) and data.draw(st.booleans()):
            del parent[path[-1]]
        else:
            parent[path[-1]] = copy.deepcopy(data.draw(BAD_VALUES))  # the constants must stay as they are
    with tempfile.TemporaryDirectory() as folder:
        cal, out = Path(folder) / "cal.json", Path(folder) / "att.csv"
        cal.write_text(json.dumps(doc))  # NaN and Infinity as Python's json writes them
        before = cal.read_bytes()
        code, _, err = _run(["attitude", str(cal), str(_recording_for(kind)), "--out", str(out)], capsys)
        assert cal.read_bytes() == before and not [p for p in Path(folder).iterdir() if p.suffix == ".tmp"]
        if code != 0:
            _assert_refused(code, err, cal)
            assert not out.exists()
            return
        assert _all_finite(model_to_dict(load(cal).model))
        lines = [line for line in out.read_text().splitlines() if not line.startswith("#")]
        table = np.genfromtxt(lines, delimiter=",", names=True)
        used = table["skipped"] == 0
        assert used.any() and np.all(np.isfinite(table["heading_deg"][used]))


# the corpus: files every command must refuse with exit 2 and one line naming the file

def _deep(depth: int) -> str:
    return "[" * depth + "]" * depth


CORPUS = {
    "empty": b"",
    "whitespace": b"  \n",
    "binary": bytes(range(256)),
    "utf16": json.dumps(_tumble_doc()).encode("utf-16"),
    "bom": b"\xef\xbb\xbf" + json.dumps(_tumble_doc()).encode(),
    "truncated": json.dumps(_tumble_doc()).encode()[:-10],
    "array": b"[1, 2, 3]",
    "string": b'"compass"',
    "deeply_nested": _deep(200_000).encode(),
    "deeply_nested_object": ('{"a":' * 100_000 + "1" + "}" * 100_000).encode(),
    "unknown_format": json.dumps({**_tumble_doc(), "format": "compass-calibration/9"}).encode(),
    "no_format": json.dumps({k: v for k, v in _tumble_doc().items() if k != "format"}).encode(),
    "nan_hard_iron": json.dumps({**_tumble_doc(), "hard_iron": [math.nan, 0, 0]}).encode(),
    "inf_field_norm": json.dumps({**_tumble_doc(), "field_norm": math.inf}).encode(),
    "negative_field_norm": json.dumps({**_tumble_doc(), "field_norm": -50}).encode(),
    "asymmetric_soft_iron": json.dumps({**_tumble_doc(), "soft_iron": [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]}).encode(),
    "not_positive_soft_iron": json.dumps({**_tumble_doc(), "soft_iron": [[1, 0, 0], [0, -1, 0], [0, 0, 1]]}).encode(),
    "reflection_mag_to_accel": json.dumps({**_tumble_doc(),
                                          "mag_to_accel": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}).encode(),
    "dip_500": json.dumps({**_tumble_doc(), "dip_deg": 500}).encode(),
    "negative_noise": json.dumps({**_tumble_doc(), "noise_floor": [-1, 0.2, 0.2]}).encode(),
    "huge_number": json.dumps(_tumble_doc()).replace("50.0", "1" + "0" * 400).encode(),
}


def _commands(cal: Path, folder: Path) -> dict:
    trial = folder / "trial.mat"
    trial.write_text("never read: the calibration is refused first")
    return {
        "attitude": ["attitude", str(cal), str(_recording_for("tumble")), "--out", str(folder / "att.csv")],
        "export": ["export", str(cal), "--format", "fusion", "--out", str(folder / "fw.h")],
        "live": ["live", "--port", "loop://", "--cal", str(cal), "--duration", "5", "--out", str(folder / "live.csv")],
        "device": ["device", "--pty", "--cal", str(cal), "--duration", "5"],
        "evaluate": ["evaluate", str(trial), "--cal", str(cal)],
    }


@pytest.mark.parametrize("case", sorted(CORPUS))
def test_every_command_refuses_a_bad_calibration_file_in_one_line(case, tmp_path, capsys):
    cal = tmp_path / f"{case}.json"
    cal.write_bytes(CORPUS[case])
    for name, argv in _commands(cal, tmp_path).items():
        before = sorted(os.listdir(tmp_path))
        code, out, err = _run(argv, capsys)
        _assert_refused(code, err, cal)
        assert sorted(os.listdir(tmp_path)) == before, name  # no output written, no temporary left
        assert cal.read_bytes() == CORPUS[case]


def test_a_folder_given_as_the_calibration_is_refused(tmp_path, capsys):
    cal = tmp_path / "cal.json"
    cal.mkdir()
    for name, argv in _commands(cal, tmp_path).items():
        code, _, err = _run(argv, capsys)
        _assert_refused(code, err, cal)


# ---------------------------------------------------------------------------------------------
# issue 23: every numeric option, counters at every extreme, reserved names, every key of every
# calibration kind, extreme magnitudes in a recording

def _numeric_options():
    """(argv prefix, option, Range) of every numeric option of every command and simulate kind."""
    import argparse

    from compass.cli import build_parser

    def walk(parser, prefix):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield from walk(sub, (*prefix, name))
            elif action.option_strings and action.type is not None and action.choices is None:
                yield prefix, action.option_strings[-1], action.type

    return list(walk(build_parser(), ()))


NUMERIC_OPTIONS = _numeric_options()


def test_every_numeric_option_is_checked_by_its_declared_range():
    from compass.limits import Range

    plain = [(" ".join(p), o) for p, o, t in NUMERIC_OPTIONS if not isinstance(getattr(t, "range", None), Range)
             and o != "--columns"]
    assert not plain, f"numeric options without a compass.limits range: {plain}"
    assert len(NUMERIC_OPTIONS) > 40  # every command's: the walk found them


ALWAYS_REFUSED = ["nan", "inf", "-inf", "1e308", "-1e308", "1e400", "0x10", "1_0", ""]


@pytest.mark.parametrize("prefix, option, convert", NUMERIC_OPTIONS, ids=lambda v: v if isinstance(v, str) else
                         "-".join(v) if isinstance(v, tuple) else "")
def test_every_numeric_option_refuses_every_extreme_in_one_line_changing_nothing(tmp_path, monkeypatch, capsys,
                                                                                 prefix, option, convert):
    if option == "--columns":
        pytest.skip("not a number")
    bounds = convert.range
    values = ALWAYS_REFUSED + [v for v in ("-1", "0", "1e-300", "5e-324", "3.5", str(2**64)) if
                               _parses_outside(bounds, v)]
    monkeypatch.chdir(tmp_path)
    old = tmp_path / "old.csv"
    old.write_text("kept\n")
    for value in values:
        code = main([*prefix, f"{option}={value}", "--out", str(old), "--force"])
        err = capsys.readouterr().err
        assert code == 2, (prefix, option, value)
        line = _one_line(err)
        assert f"argument {option}: must be {bounds.describe()}" in line, line
        assert old.read_text() == "kept\n" and sorted(p.name for p in tmp_path.iterdir()) == ["old.csv"]


def _parses_outside(bounds, text: str) -> bool:
    try:
        bounds.parse(text, "x")
    except ValueError:
        return True
    return False


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


COUNTER_VALUES = {"seq": ["-1", "-0", "0", "1000000000000", "1000000000001", str(2**63), str(10**30), "1e3", "1.5",
                          "nan", " 7 ", "+5"],
                  "t_s": ["-1", "0", "-1e308", "1e308", "1e12", "1.0000001e12", "1e300", "5e-324", "-5e-324", "nan",
                          "inf", "1e-300", "-0"]}
_COUNTER_NAMES = ["seq", "t_s", *CHANNELS, "ax", "ay", "az", "gx", "gy", "gz"]


def _counter_stream(column: str, value: str, at: int, with_seq: bool) -> tuple[bytes, int]:
    names = _COUNTER_NAMES if with_seq else _COUNTER_NAMES[1:]
    s = _SIM_COUNTERS
    lines = [format_line(names)]
    for i in range(len(s.t_s)):
        cells = ([i] if with_seq else []) + [f"{s.t_s[i]:.4f}", *s.raw[i], *s.accel[i], *s.gyro[i]]
        if i == at:
            cells[names.index(column)] = value
        lines.append(format_line(cells))
    return b"".join(lines), len(lines) - 1


_SIM_COUNTERS = simulate_device(default_model(), np.arange(120) / 100.0, seed=4)


@pytest.mark.parametrize("with_seq", [True, False])
@pytest.mark.parametrize("column, value", [(c, v) for c, values in COUNTER_VALUES.items() for v in values])
def test_a_counter_at_any_extreme_never_stops_or_poisons_a_session(column, value, with_seq):
    if column == "seq" and not with_seq:
        pytest.skip("no seq column")
    for at in (1, 60) if with_seq else (60,):  # the first sample after the header, one mid-stream
        stream, n = _counter_stream(column, value, at, with_seq)
        out = io.StringIO()
        session = LiveSession(default_model(), out=out)
        session.feed(Chunk(time.perf_counter(), stream))
        session.close()
        s = session.decoder.stats
        assert s.samples + s.bad_lines == n  # every line used or counted
        assert s.lost <= n  # never more lost than the stream's own span (was 1e30, 2e303)
        rows = out.getvalue().splitlines()[2:]
        assert len(rows) == session.samples and session.samples >= n - 3
        for row in rows:
            cells = row.split(",")
            assert all(math.isfinite(float(c)) and len(c) < 20 for c in cells), row


def test_a_reserved_name_is_never_a_calibration_channel(tmp_path):
    from compass.calibration import CalibrationFileError
    from compass.io.names import RESERVED_NAMES

    for name in RESERVED_NAMES:
        doc = _channel_doc()
        doc["channels"] = {(name if k == "my" else k): v for k, v in doc["channels"].items()}
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(doc))
        with pytest.raises(CalibrationFileError, match=rf"{path}: channel '{name}' is not a channel name"):
            load(path)


def _installed_doc() -> dict:
    return {"format": FORMAT, "model": "installed", "base": _channel_doc(), "dip_deg": 60.0, "field_ut": 50.0,
            "installation": {"hard_iron_ut": [1.0, 2.0, 3.0], "soft_iron": [[1.0, 0.01, 0], [0.01, 1.0, 0], [0, 0, 1]]}}


KIND_DOCS = {"channels": _channel_doc, "tumble": _tumble_doc, "installed": _installed_doc}
EXTREMES = [math.nan, 1e308, 5e-324, "60"]  # inf and -1e308 take the paths nan and 1e308 take


def _leaves(node, prefix=()):
    if isinstance(node, dict):
        for key, child in node.items():
            yield from _leaves(child, (*prefix, key))
    elif isinstance(node, list):
        for i, child in enumerate(node):
            yield from _leaves(child, (*prefix, i))
    else:
        yield prefix


def _numbers_finite(text: str) -> bool:
    import re

    numbers = re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", text)
    return "nan" not in text.lower() and "inf" not in text.lower() and all(abs(float(n)) < 1e13 for n in numbers)


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("kind", sorted(KIND_DOCS))
def test_every_key_of_every_kind_at_every_extreme_is_refused_or_exports_finite_numbers(tmp_path, capsys, kind):
    base = KIND_DOCS[kind]()
    out = tmp_path / "fw.h"
    refused = 0
    for path in _leaves(base):
        for value in EXTREMES:
            doc = copy.deepcopy(base)
            parent = doc
            for key in path[:-1]:
                parent = parent[key]
            parent[path[-1]] = value
            cal = tmp_path / "cal.json"
            cal.write_text(json.dumps(doc))
            out.write_text("the old export\n")
            code, text, err = _run(["export", str(cal), "--format", "fusion", "--out", str(out), "--force"], capsys)
            if code != 0:
                _assert_refused(code, err, cal)
                assert out.read_text() == "the old export\n", (path, value)
                refused += 1
            else:
                assert _numbers_finite(out.read_text()), (path, value)
            assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.json", "fw.h"]
    assert refused >= 2 * len(list(_leaves(base)))  # nan and "60" are refused wherever a number is read


@pytest.mark.parametrize("column", ["mx", "ax", "t_s"])
@pytest.mark.parametrize("value", [1e308, -1e308, 1e13, 1e-300, 5e-324])
def test_an_extreme_cell_in_a_recording_is_refused_naming_it_or_solved_finitely(tmp_path, capsys, column, value):
    rec = _recording_for("channels")
    lines = rec.read_text().splitlines()
    names = lines[0].split(",")
    cells = lines[120].split(",")
    cells[names.index(column)] = repr(value)
    lines[120] = ",".join(cells)
    bad = tmp_path / "rec.csv"
    bad.write_text("\n".join(lines) + "\n")
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(_channel_doc()))
    out = tmp_path / "att.csv"
    out.write_text("the old attitudes\n")
    code, _, err = _run(["attitude", str(cal), str(bad), "--out", str(out), "--force"], capsys)
    if abs(value) > 1e12 or column == "t_s":  # beyond any sensor's output, or a time going back
        assert code == 2 and f"rec.csv, row 121, column '{column}'" in _one_line(err)
        assert out.read_text() == "the old attitudes\n"
    else:
        assert code == 0, err
        table = np.genfromtxt([x for x in out.read_text().splitlines() if not x.startswith("#")], delimiter=",",
                              names=True)
        assert np.all(np.isfinite(table["heading_deg"]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["att.csv", "cal.json", "rec.csv"]
