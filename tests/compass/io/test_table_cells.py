"""Cells as loggers and spreadsheets write them: a text column the toolkit does not use, numbers in double quotes.

Each file is compared with the same rows written plainly (no text column, no quotes), so what is read follows
from what was written, never from what the code happened to return.
"""

import subprocess
import sys

import numpy as np
import pytest

from compass.io.table import ReadOptions, RecordingError, read_table
from compass.io.units import RecordingWarning

NAMES = ("t_s", "mx", "my", "mz")


def _rows(n=40, seed=3):
    """Cells (str) of ``n`` rows of t_s, mx, my, mz: time rising, fields of tens of uT."""
    rng = np.random.default_rng(seed)
    data = np.column_stack([0.01 * np.arange(n), rng.normal(0.0, 30.0, (n, 3))])
    return [[f"{v:.6f}" for v in row] for row in data]


def _write(path, header, rows, sep=",", lines_between=()):
    """A CSV of ``header`` and ``rows`` (lists of cells), ``lines_between`` (text) after the third row."""
    body = [sep.join(r) for r in rows]
    path.write_text("\n".join([sep.join(header)] + body[:3] + list(lines_between) + body[3:]) + "\n")
    return path


def _with_status(rows, first_text_row=0):
    """Each row with a ``status`` cell: ``0`` before ``first_text_row``, text (some with '_', quotes) from it."""
    words = ("OK", "NO_FIX", '"OK"', "")
    return [r + (["0"] if k < first_text_row else [words[k % len(words)]]) for k, r in enumerate(rows)]


# how np.loadtxt meets the text: in the first row (one pass), among the rows (read again), numbered lines
READINGS = {"first row": dict(first_text_row=0), "later row": dict(first_text_row=17),
            "comment lines inside": dict(first_text_row=0, lines_between=("", "# a comment", "# site: bench"))}


@pytest.mark.parametrize("reading", READINGS)
@pytest.mark.parametrize("sep", [",", ";", "\t"])
def test_a_text_column_is_skipped_and_the_used_columns_read_as_without_it(tmp_path, reading, sep):
    first_text_row = READINGS[reading]["first_text_row"]
    between = READINGS[reading].get("lines_between", ())
    rows = _rows()
    if sep == ";":  # a spreadsheet's decimal comma
        rows = [[c.replace(".", ",") for c in r] for r in rows]
    plain = read_table(_write(tmp_path / "plain.csv", NAMES, rows, sep, between))
    table = read_table(_write(tmp_path / "status.csv", NAMES + ("status",), _with_status(rows, first_text_row),
                              sep, between))
    assert table.columns == NAMES + ("status",)
    np.testing.assert_array_equal(table.data[:, :4], plain.data)
    np.testing.assert_array_equal(table.rows, plain.rows)
    assert table.metadata == plain.metadata
    with pytest.warns(RecordingWarning, match=r"ignored column status \(not used by a test\)"):
        table.ignore_unknown(NAMES, what="a test")


def test_a_text_column_is_refused_where_a_reader_uses_it(tmp_path):
    rows = _with_status(_rows(), first_text_row=17)
    path = _write(tmp_path / "status.csv", NAMES + ("status",), rows)
    table = read_table(path)
    np.testing.assert_array_equal(table.column("mx"), [float(r[1]) for r in rows])
    # the first text cell: data row 17 is line 19 (the header is line 1)
    with pytest.raises(RecordingError, match=f"^{path}, row 19, column 'status': expected a number, found 'NO_FIX' "
                                             r"\(digit separators"):
        table.column("status")
    with pytest.raises(RecordingError, match="row 19, column 'status'"):
        table.group(("mx", "status"))


@pytest.mark.parametrize("column, cell", [("mx", "OK"), ("t_s", "OK"), ("mz", ""), ("my", "1_5"), ("mx", '"abc"'),
                                          ("my", '"2'), ("mz", '"1"2"'), ("mx", '""')])
@pytest.mark.parametrize("k", [0, 25])
def test_a_text_cell_in_a_used_column_is_refused_at_its_row_and_column(tmp_path, column, cell, k):
    """With a text column beside it, whether the bad cell is in the first row or among the rows."""
    rows = _with_status(_rows())
    rows[k][NAMES.index(column)] = cell
    path = _write(tmp_path / "bad.csv", NAMES + ("status",), rows)
    with pytest.raises(RecordingError) as refused:
        read_table(path)
    assert str(refused.value).startswith(f"{path}, row {k + 2}, column '{column}': expected a number, found {cell!r}")


def test_the_first_bad_cell_of_the_used_columns_is_named_under_its_header_name(tmp_path):
    """Two bad cells: the earlier row's; a mapped column is named as the header spells it."""
    rows = _with_status(_rows())
    rows[30][NAMES.index("my")], rows[12][NAMES.index("mz")] = "x", "y"
    path = _write(tmp_path / "bad.csv", ("t_s", "mx", "my", "Mag Z", "status"), rows)
    with pytest.raises(RecordingError, match=f"^{path}, row 14, column 'Mag Z': expected a number, found 'y'$"):
        read_table(path, ReadOptions(columns={"mz": "Mag Z"}))


@pytest.mark.parametrize("sep", [",", ";"])
def test_numbers_in_double_quotes_read_as_without_them(tmp_path, sep):
    rows = _rows()
    if sep == ";":
        rows = [[c.replace(".", ",") for c in r] for r in rows]
    plain = read_table(_write(tmp_path / "plain.csv", NAMES, rows, sep))
    quoted = [[f'"{c}"' for c in r] for r in rows]
    table = read_table(_write(tmp_path / "quoted.csv", [f'"{n}"' for n in NAMES], quoted, sep))
    assert table.columns == NAMES
    np.testing.assert_array_equal(table.data, plain.data)
    some = [[f'"{c}"' if (i + k) % 3 == 0 else c for i, c in enumerate(r)] for k, r in enumerate(rows)]
    np.testing.assert_array_equal(read_table(_write(tmp_path / "some.csv", NAMES, some, sep)).data, plain.data)


@pytest.mark.parametrize("cells, found", [(-1, 4), (+1, 6)])
@pytest.mark.parametrize("k", [0, 21])
def test_a_row_with_a_missing_or_extra_cell_is_refused_with_its_row(tmp_path, cells, found, k):
    rows = _with_status(_rows())
    rows[k] = rows[k][:cells] if cells < 0 else rows[k] + ["1.0"]
    path = _write(tmp_path / "ragged.csv", NAMES + ("status",), rows)
    with pytest.raises(RecordingError, match=f"^{path}, row {k + 2}: expected 5 cells, found {found}"):
        read_table(path)


# ---- through the command line: compass attitude --filter on a logger's file --------------------------------

@pytest.fixture(scope="module")
def device(tmp_path_factory):
    """A simulated device's calibration and its 10 s recording's columns (t_s, mx.., ax.., gx..) as cells."""
    from compass.calibration import model_to_dict, save
    from compass.sim.device import default_model, simulate_device

    model = default_model()
    t = np.arange(0.0, 10.0, 0.01)
    s = simulate_device(model, t, seed=5)
    cal = tmp_path_factory.mktemp("device") / "cal.json"
    save(cal, model_to_dict(model))
    header = ("t_s", *model.channels, "ax", "ay", "az", "gx", "gy", "gz")
    rows = [[repr(v) for v in row] for row in np.column_stack([t, s.raw, s.accel, s.gyro]).tolist()]
    return cal, header, rows


def _attitude(cal, rec, out):
    """``python -m compass attitude CAL REC --out OUT --filter``: (exit status, stderr)."""
    run = subprocess.run([sys.executable, "-m", "compass", "attitude", str(cal), str(rec), "--out", str(out),
                          "--filter"], capture_output=True, text=True, timeout=300)
    return run.returncode, run.stderr


def test_compass_attitude_filter_reads_a_status_column_as_the_file_without_it(device, tmp_path):
    cal, header, rows = device
    plain = _write(tmp_path / "plain.csv", header, rows)
    status = _write(tmp_path / "status.csv", header + ("status",), [r + ["OK"] for r in rows])
    assert _attitude(cal, plain, tmp_path / "plain_att.csv")[0] == 0
    code, err = _attitude(cal, status, tmp_path / "status_att.csv")
    assert code == 0, err
    assert "ignored column status" in err
    ours, theirs = read_table(tmp_path / "status_att.csv"), read_table(tmp_path / "plain_att.csv")
    assert ours.columns == theirs.columns
    for name in ours.columns:
        if name != "latency_ms":  # the wall clock's, run to run
            np.testing.assert_array_equal(ours.column(name), theirs.column(name), err_msg=name)


def test_compass_attitude_filter_refuses_text_in_a_used_column_in_one_line(device, tmp_path):
    cal, header, rows = device
    rows = [r + ["OK"] for r in rows]
    rows[300][header.index("my")] = "OK"
    rec = _write(tmp_path / "bad.csv", header + ("status",), rows)
    code, err = _attitude(cal, rec, tmp_path / "att.csv")
    assert code == 2, err
    assert err.strip() == f"compass attitude: {rec}, row 302, column 'my': expected a number, found 'OK'"
    assert not (tmp_path / "att.csv").exists()


@pytest.mark.parametrize("sep", [",", ";"])
def test_a_header_repeated_mid_file_is_named_as_such(tmp_path, sep):
    """A logger that restarted writes its header again: the refusal names the row and says it repeats the header,
    not that a digit separator ('t_s' has a '_') is not read."""
    path = _write(tmp_path / "again.csv", NAMES, _rows(), sep=sep, lines_between=[sep.join(NAMES)])
    with pytest.raises(RecordingError, match=f"^{path}, row 5, column 't_s': expected a number, found 't_s' "
                                             r"\(the row repeats the header"):
        read_table(path).column("t_s")
