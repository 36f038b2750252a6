"""Bad four-flip recordings: exit status 2 and one line naming file, row and column."""

import numpy as np
import pytest

from compass.cli import main
from compass.io.fourflip import read_fourflip
from compass.io.table import RecordingError

GOOD_HEADER = "flip_deg,platform_deg,v1"


def _rows(n_per_flip=36):
    rows = []
    for flip in (0, 90, 180, 270):
        for i in range(n_per_flip):
            phi = 10.0 * i
            rows.append(f"{flip},{phi},{1 + 0.5 * np.cos(np.radians(phi + flip)):.6f}")
    return rows


def _write(tmp_path, lines, name="bad.csv"):
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


CASES = {
    "empty": ([], "empty file", None, None),
    "header only": ([GOOD_HEADER], "header only", 1, None),
    "missing column": (["flip_deg,v1"] + ["0,1.0"] * 3, "missing required column 'platform_deg'", None, None),
    "non-numeric": ([GOOD_HEADER] + _rows()[:5] + ["0,50,abc"] + _rows()[5:], "expected a number", 7, "v1"),
    "nan cell": ([GOOD_HEADER, "0,0,nan"] + _rows(), "finite", 2, "v1"),
    "bad flip": ([GOOD_HEADER] + _rows()[:3] + ["45,30,1.0"] + _rows()[3:], "not within", 5, "flip_deg"),
    "missing flip": ([GOOD_HEADER] + [r for r in _rows() if not r.startswith("270,")], "flip 270", None, "flip_deg"),
    "coverage gap": ([GOOD_HEADER] + [r for r in _rows() if not (r.startswith("90,") and 100 < float(r.split(",")[1]) < 250)],
                     "never visits", None, "platform_deg"),
    "wrong cell count": ([GOOD_HEADER, "0,1"] + _rows(), "expected 3 cells", 2, None),
    "no channel": (["flip_deg,platform_deg,t_s", "0,0,0"], "no magnetic channel", 1, None),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_recording_raises_with_location(tmp_path, case):
    lines, message, row, column = CASES[case]
    path = _write(tmp_path, lines)
    with pytest.raises(RecordingError, match=message) as info:
        read_fourflip(path)
    assert str(path) in str(info.value)
    if row is not None:
        assert info.value.row == row
    if column is not None:
        assert info.value.column == column


def test_constant_channel(tmp_path):
    lines = [GOOD_HEADER + ",v2"] + [r + ",0.5" for r in _rows()]
    with pytest.raises(RecordingError, match="never changes") as info:
        read_fourflip(_write(tmp_path, lines))
    assert info.value.column == "v2"


def test_binary_garbage(tmp_path):
    p = tmp_path / "garbage.csv"
    p.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(RecordingError, match="binary"):
        read_fourflip(p)


def test_cli_bad_input_exit_2_one_line_no_traceback(tmp_path, capsys):
    path = _write(tmp_path, [GOOD_HEADER] + _rows()[:5] + ["0,50,abc"] + _rows()[5:])
    code = main(["calibrate", str(path), "--out", str(tmp_path / "cal.json")])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1
    assert "row 7" in err and "column 'v1'" in err and "Traceback" not in err
    assert not (tmp_path / "cal.json").exists()


def test_rows_in_any_order_and_comments(tmp_path):
    rows = _rows()
    rng = np.random.default_rng(0)
    shuffled = [rows[i] for i in rng.permutation(len(rows))]
    rec = read_fourflip(_write(tmp_path, ["# field_ut: 48.5", "# note: bench 2", GOOD_HEADER] + shuffled))
    assert rec.field_ut == 48.5
    assert rec.n_samples == len(rows)
    assert sorted(np.unique(rec.flip_index)) == [0, 1, 2, 3]


def test_unwritable_output_fails_before_work(tmp_path, capsys):
    rec = tmp_path / "rec.csv"
    rec.write_text("\n".join([GOOD_HEADER] + _rows()) + "\n")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["calibrate", str(rec), "--out", str(blocker / "cal.json"), "--quiet"]) == 2
    assert "cannot create its folder" in capsys.readouterr().err
    assert main(["calibrate", str(rec), "--out", str(tmp_path), "--quiet", "--force"]) == 2


def test_json_given_as_recording(tmp_path):
    p = _write(tmp_path, ['{"format": "compass-calibration/1"}'], "cal.json")
    with pytest.raises(RecordingError, match="JSON"):
        read_fourflip(p)


def test_output_folder_given_without_force_names_the_folder(tmp_path, capsys):
    rec = tmp_path / "rec.csv"
    rec.write_text("\n".join([GOOD_HEADER] + _rows()) + "\n")
    assert main(["calibrate", str(rec), "--out", str(tmp_path), "--quiet"]) == 2
    assert "is a folder" in capsys.readouterr().err


def test_failed_write_is_output_error_and_keeps_old_file(tmp_path, monkeypatch):
    from compass.io import atomic

    out = tmp_path / "cal.json"
    out.write_text("precious")

    def refuse(src, dst):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(atomic.os, "replace", refuse)
    with pytest.raises(atomic.OutputError, match=r"cal\.json: cannot write \(Permission denied\)"):
        atomic.atomic_write_text(out, "new")
    assert out.read_text() == "precious"
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]


@pytest.mark.parametrize("header, row", [("t_s,mx,my,mz", "{t},1,2,3"),
                                         ("t_s,platform_z_deg,platform_y_deg,platform_x_deg,mx,my,mz,ax,ay",
                                          "{t},0,0,0,1,2,3,0,0")])
def test_time_going_back_names_its_row(tmp_path, header, row):
    from compass.io.platform3d import platform3d_from_table
    from compass.io.table import read_table
    from compass.io.tumble import tumble_from_table

    parse = tumble_from_table if header.endswith("mz") else platform3d_from_table
    p = _write(tmp_path, [header] + [row.format(t=t) for t in (0, 1, 2, 1.5, 3)])
    with pytest.raises(RecordingError, match=r"row 5, column 't_s': t_s must not decrease \(goes from 2.0 to 1.5\)"):
        parse(read_table(p))


def _simulated(tmp_path, kind, seed, change, columns):
    """``compass simulate KIND``'s recording with ``change`` applied to the cells of ``columns``."""
    source = tmp_path / f"{kind}{seed}.csv"
    assert main(["simulate", kind, "--out", str(source), "--seed", str(seed), "--force"]) == 0
    lines = source.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    names = lines[header].split(",")
    out = lines[: header + 1]
    for line in lines[header + 1:]:
        cells = line.split(",")
        for name in columns:
            cells[names.index(name)] = change(name, float(cells[names.index(name)]))
        out.append(",".join(cells))
    return _write(tmp_path, out, name=f"{kind}{seed}_changed.csv")


@pytest.mark.parametrize("counts_per_volt", [None, 2 ** 16 / 5.0])  # a float log; a 16-bit ADC on 0-5 V
def test_a_clipped_channel_is_named_and_no_healthy_one_blamed(tmp_path, capsys, counts_per_volt):
    def clip_v2(name, volts):  # the simulated channels swing 1.6-3.3 V: v2 railed at 3.0 V
        volts = min(volts, 3.0) if name == "v2" else volts
        return f"{volts:.7f}" if counts_per_volt is None else str(round(volts * counts_per_volt))

    path = _simulated(tmp_path, "fourflip", 1, clip_v2, ("v1", "v2", "v3"))
    with pytest.raises(RecordingError, match="reads its extreme .* clipped \\(saturated\\)") as info:
        read_fourflip(path)
    rail = 3.0 if counts_per_volt is None else round(3.0 * counts_per_volt)
    values = [float(line.split(",")[-2]) for line in path.read_text().splitlines()[1:] if not line.startswith(("#", "t_s"))]
    assert info.value.column == "v2" and values.count(rail) >= 8
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}, row {info.value.row}, column 'v2'" in err and "'v1'" not in err
    assert not (tmp_path / "cal.json").exists()


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("bits", [None, 8, 10, 12, 16])
def test_honest_recordings_quantised_by_an_adc_are_not_called_clipped(tmp_path, seed, bits):
    """An integer channel reads one code for a whole flip along its axis: its extreme repeats honestly."""
    def counts(name, volts):
        return f"{volts:.7f}" if bits is None else str(round(volts * 2 ** bits / 5.0))

    assert read_fourflip(_simulated(tmp_path, "fourflip", seed, counts, ("v1", "v2", "v3"))).n_samples > 0


def test_a_clipped_tumble_channel_is_named_and_a_quantised_one_read(tmp_path):
    from compass.io.tumble import read_tumble

    clipped = _simulated(tmp_path, "tumble", 2, lambda name, ut: f"{max(-30.0, min(30.0, ut)):.3f}", ("mx",))
    with pytest.raises(RecordingError, match="reads its extreme -30 on .* clipped") as info:
        read_tumble(clipped)
    assert info.value.column == "mx"
    read_tumble(_simulated(tmp_path, "tumble", 2, lambda name, ut: f"{round(ut, 1):.1f}", ("mx", "my", "mz")))


def test_rows_written_twice_are_said_and_dropped(tmp_path, write_session):
    """Every row twice (t_s included): named, dropped, and the fit as on the recording written once."""
    from compass.io.units import RecordingWarning

    once, _ = write_session(seed=3)
    lines = (tmp_path / "rec.csv").read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    twice = _write(tmp_path, lines[:head + 1] + [line for line in lines[head + 1:] for _ in (0, 1)], "twice.csv")
    with pytest.warns(RecordingWarning, match=rf"{len(once.t_s)} of {2 * len(once.t_s)} rows repeat the row before "
                                              rf"exactly, t_s included \(first: row {head + 3} repeats row {head + 2}\)"):
        read = read_fourflip(twice)
    assert np.array_equal(read.outputs, once.outputs) and np.array_equal(read.t_s, once.t_s)


def test_equal_rows_without_a_time_are_kept(tmp_path):
    """Two readings of a quantised channel at one stop may be equal: without t_s they are not judged."""
    rows = _rows()
    rec = read_fourflip(_write(tmp_path, [GOOD_HEADER] + rows[:1] + rows))
    assert rec.n_samples == len(rows) + 1


def test_equal_rows_under_a_coarse_time_are_kept(tmp_path, write_session):
    """A t_s coarser than the samples (whole seconds at a stop): different rows share a time, so two equal rows
    there may be two readings of a quantised channel, and nothing is dropped (the review's case)."""
    once, _ = write_session(seed=3)
    lines = (tmp_path / "rec.csv").read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    t = lines[head].split(",").index("t_s")
    coarse = [",".join(f"{np.floor(float(c)):g}" if j == t else c for j, c in enumerate(line.split(",")))
              for line in lines[head + 1:]]
    path = _write(tmp_path, lines[:head + 1] + coarse[:1] + coarse, "coarse.csv")
    assert read_fourflip(path).n_samples == len(coarse) + 1


def test_rows_written_twice_are_dropped_despite_one_clock_hiccup(tmp_path, write_session):
    """One pair of different rows at one t_s (a clock's hiccup) does not make the whole t_s coarse: the repeats are
    still dropped (the review's case)."""
    once, _ = write_session(seed=3)
    lines = (tmp_path / "rec.csv").read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    t = lines[head].split(",").index("t_s")
    body = lines[head + 1:]
    cells = body[11].split(",")
    cells[t] = body[10].split(",")[t]  # row 11 at row 10's time
    body[11] = ",".join(cells)
    path = _write(tmp_path, lines[:head + 1] + [line for line in body for _ in (0, 1)], "hiccup.csv")
    assert read_fourflip(path).n_samples == len(body)
