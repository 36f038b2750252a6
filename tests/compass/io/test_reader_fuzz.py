"""A generated corpus of malformed recordings for every reader, through the command line in-process.

For each recording kind (four-flip, tumble, 3-D platform, reference fields, attitude) a clean
simulated file is mutated in the usual ways.  A refused case must exit 2 with one line on stderr
naming the file (and the row and column where there is one), write nothing, and leave an existing
output untouched even with ``--force``.  A tolerated case (BOM, CRLF, semicolons, tabs, decimal
commas with a semicolon, upper-case names) must read as the clean file does.
"""

import os
import re

import numpy as np
import pytest

from compass.cli import main
from compass.io.table import read_table

KINDS = ("fourflip", "tumble", "platform3d", "reference", "attitude")
# a required column to drop, a channel to corrupt or hold constant, and what one row gives
SPEC = {
    "fourflip": {"drop": "platform_deg", "channel": "v2", "one_row": "flip_deg"},
    "tumble": {"drop": "mz", "channel": "mz", "one_row": "mx"},
    "platform3d": {"drop": "platform_z_deg", "channel": "my", "one_row": "platform_z_deg"},
    "reference": {"drop": "bx_ref", "channel": "s1_y", "one_row": "bx_ref"},
    "attitude": {"drop": "v2", "channel": "v2", "one_row": None},  # one row, or a still sensor: fine
}


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """{kind: path of a clean recording}, plus the calibration the attitude kind is solved with."""
    from compass.sim.fourflip import simulate_fourflip, write_fourflip
    from compass.sim.platform3d import simulate_platform3d, write_platform3d
    from compass.sim.reference import simulate_reference, write_reference
    from compass.sim.runtime import simulate_runtime, write_runtime
    from compass.sim.tumble import simulate_tumble, write_tumble

    folder = tmp_path_factory.mktemp("clean")
    session = simulate_fourflip(seed=1, step_deg=10, effects=("offset_drift",))
    paths = {"fourflip": write_fourflip(session, folder / "fourflip.csv")[0],
             "tumble": write_tumble(simulate_tumble(seed=1, n=200), folder / "tumble.csv")[0],
             "platform3d": write_platform3d(simulate_platform3d(seed=1), folder / "platform3d.csv")[0],
             "reference": write_reference(simulate_reference(seed=1), folder / "reference.csv")[0],
             "attitude": write_runtime(simulate_runtime(session.truth, 50, seed=2), folder / "attitude.csv")[0]}
    cal = folder / "cal.json"
    assert main(["calibrate", str(paths["fourflip"]), "--out", str(cal), "--quiet", "--no-diagnose"]) == 0
    return paths, cal


def _parts(path):
    """(comment lines, header, data rows as lists of cells) of a clean recording."""
    lines = path.read_text().splitlines()
    comments = [line for line in lines if line.startswith("#")]
    body = [line for line in lines if not line.startswith("#")]
    return comments, body[0].split(","), [row.split(",") for row in body[1:]]


def _text(comments, header, rows, sep=","):
    return "\n".join(comments + [sep.join(header)] + [sep.join(r) for r in rows]) + "\n"


def _set_cell(rows, header, k, column, value):
    rows = [list(r) for r in rows]
    rows[k][header.index(column)] = value
    return rows


def refused_cases(kind, path):
    """name -> (file content (str, bytes, or 'DIR'), expected text, row, column); row/column None if none."""
    comments, header, rows = _parts(path)
    first = len(comments) + 2  # the first data row's line
    spec = SPEC[kind]
    ch = spec["channel"]
    j = header.index(ch)
    cases = {
        "empty": ("", "empty file", None, None),
        "blank lines only": ("\n\n  \n", "empty file", None, None),
        "comments only": ("# a: b\n# c\n", "no header row", None, None),
        "header only": (_text(comments, header, []), "header only", first - 1, None),
        "binary": (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)), "binary", 3, None),  # the NUL is on line 3
        "utf-16": (_text(comments, header, rows).encode("utf-16"), "UTF-16", 1, None),
        "latin-1": (_text(comments, header, rows).replace(header[0], header[0] + "\u00e9", 1).encode("latin-1"),
                    "not UTF-8", len(comments) + 1, None),
        "json": ('{"format": "compass-calibration/1"}\n', "JSON", 1, None),
        "decimal commas, comma separator": (
            _text(comments, header, [[c.replace(".", ",") for c in r] for r in rows]), "decimal commas", first, None),
        "nan": (_text(comments, header, _set_cell(rows, header, 5, ch, "nan")), "finite", first + 5, ch),
        "inf": (_text(comments, header, _set_cell(rows, header, 6, ch, "-inf")), "finite", first + 6, ch),
        "huge": (_text(comments, header, _set_cell(rows, header, 7, ch, "1e300")), "beyond", first + 7, ch),
        "underscore": (_text(comments, header, _set_cell(rows, header, 8, ch, "1_5")), "'1_5'", first + 8, ch),
        "text cell": (_text(comments, header, _set_cell(rows, header, 9, ch, "abc")), "'abc'", first + 9, ch),
        "empty cell": (_text(comments, header, _set_cell(rows, header, 9, ch, "")), "expected a number", first + 9, ch),
        "ragged row": (_text(comments, header, rows[:3] + [rows[3][:-1]] + rows[4:]), "cells", first + 3, None),
        "duplicate column": (_text(comments, [header[0]] + header[1:j] + [header[0]] + header[j + 1:], rows),
                             "duplicate", first - 1, header[0]),
        "case duplicate": (_text(comments, header[:j] + [header[j - 1].upper()] + header[j + 1:], rows),
                           "two columns", first - 1, None),
        "missing column": (_text(comments, [h for h in header if h != spec["drop"]],
                                 [[c for h, c in zip(header, r) if h != spec["drop"]] for r in rows]),
                           f"missing required column '{spec['drop']}'", first - 1, spec["drop"]),
        "field_ut not a number": (_text(["# field_ut: fifty"] + [c for c in comments if "field_ut" not in c],
                                        header, rows), "field_ut", 1, None),
        "field_ut negative": (_text(["# field_ut: -50"] + [c for c in comments if "field_ut" not in c],
                                    header, rows), "field_ut", 1, None),
        "field_ut nan": (_text(["# field_ut: nan"] + [c for c in comments if "field_ut" not in c], header, rows),
                         "field_ut", 1, None),
        "directory": ("DIR", "is a folder", None, None),
    }
    if "t_s" in header:
        cases["t_s going back"] = (_text(comments, header, _set_cell(rows, header, 10, "t_s", "-1")),
                                   "must not decrease", first + 10, "t_s")
    if spec["one_row"] is not None:
        cases["one row"] = (_text(comments, header, rows[:1]), "", None, spec["one_row"])
        const = [list(r) for r in rows]
        for r in const:
            r[j] = "7.25"
        cases["constant channel"] = (_text(comments, header, const), "never changes", None, ch)
    return cases


TOLERATED = ("bom", "crlf", "semicolons", "tabs", "semicolons and decimal commas", "upper case", "quoted names",
             "blank and comment lines inside")


def tolerated_text(name, path):
    comments, header, rows = _parts(path)
    text = _text(comments, header, rows)
    if name == "bom":
        return "\ufeff" + text
    if name == "crlf":
        return text.replace("\n", "\r\n")
    if name == "semicolons":
        return _text(comments, header, rows, sep=";")
    if name == "tabs":
        return _text(comments, header, rows, sep="\t")
    if name == "semicolons and decimal commas":
        return _text(comments, header, [[c.replace(".", ",") for c in r] for r in rows], sep=";")
    if name == "upper case":
        return _text(comments, [h.upper() for h in header], rows)
    if name == "quoted names":
        return _text(comments, [f'"{h}"' for h in header], rows)
    lines = text.splitlines()
    return "\n".join(lines[: len(comments) + 4] + ["", "# a comment", "   "] + lines[len(comments) + 4:]) + "\n"


def _command(kind, rec, out, cal):
    if kind == "attitude":
        return ["attitude", str(cal), str(rec), "--out", str(out)]
    return ["calibrate", str(rec), "--out", str(out), "--kind", kind, "--quiet"]


def _case_ids():
    return [(kind, name) for kind in KINDS for name in
            ("empty", "blank lines only", "comments only", "header only", "binary", "utf-16", "latin-1", "json",
             "decimal commas, comma separator", "nan", "inf", "huge", "underscore", "text cell", "empty cell",
             "ragged row", "duplicate column", "case duplicate", "missing column", "field_ut not a number",
             "field_ut negative", "field_ut nan", "directory", "t_s going back", "one row", "constant channel")]


@pytest.mark.parametrize("kind, name", _case_ids())
def test_refused_with_one_line_naming_file_row_column_and_nothing_written(clean, tmp_path, capsys, kind, name):
    paths, cal = clean
    cases = refused_cases(kind, paths[kind])
    if name not in cases:
        pytest.skip(f"{kind} recordings have no case '{name}' (no t_s column, or one row is a valid recording)")
    content, expected, row, column = cases[name]
    rec = tmp_path / "bad.csv"
    if content == "DIR":
        rec.mkdir()
    elif isinstance(content, bytes):
        rec.write_bytes(content)
    else:
        rec.write_text(content)
    out = tmp_path / ("att.csv" if kind == "attitude" else "cal.json")
    for existing in (None, "precious\n"):
        if existing is not None:
            out.write_text(existing)
        status = main(_command(kind, rec, out, cal) + (["--force"] if existing else []))
        err = capsys.readouterr().err
        assert status == 2, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in err, err
        assert str(rec) in lines[0] and expected in lines[0], lines[0]
        if row is not None:
            assert re.search(rf"row {row}[,:]", lines[0]), lines[0]
        if column is not None:
            assert f"column '{column}'" in lines[0], lines[0]
        if existing is None:
            assert not out.exists()
        else:
            assert out.read_text() == existing
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary file left


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads a file whatever its permissions")
@pytest.mark.parametrize("kind", KINDS)
def test_unreadable_file_is_refused(clean, tmp_path, capsys, kind):
    paths, cal = clean
    rec = tmp_path / "bad.csv"
    rec.write_text(paths[kind].read_text())
    rec.chmod(0)
    status = main(_command(kind, rec, tmp_path / "out", cal))
    err = capsys.readouterr().err
    assert status == 2 and "cannot read" in err and str(rec) in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", TOLERATED)
def test_tolerated_variants_read_as_the_clean_file(clean, tmp_path, kind, name):
    paths, _ = clean
    reference = read_table(paths[kind])
    rec = tmp_path / "variant.csv"
    rec.write_text(tolerated_text(name, paths[kind]), newline="")
    table = read_table(rec)
    assert [c.lower() for c in table.columns] == [c.lower() for c in reference.columns]  # free names keep their case
    np.testing.assert_array_equal(table.data, reference.data)
    if name != "blank and comment lines inside":
        np.testing.assert_array_equal(table.rows, reference.rows)
    else:
        assert table.rows[-1] == reference.rows[-1] + 3


def test_a_tolerated_variant_calibrates_as_the_clean_file(clean, tmp_path):
    """End to end once: semicolons and decimal commas give the clean file's calibration, number for number."""
    paths, _ = clean
    rec = tmp_path / "variant.csv"
    rec.write_text(tolerated_text("semicolons and decimal commas", paths["fourflip"]))
    for src, out in ((paths["fourflip"], tmp_path / "a.json"), (rec, tmp_path / "b.json")):
        assert main(["calibrate", str(src), "--out", str(out), "--quiet", "--no-diagnose"]) == 0
    a, b = (out.read_text().replace(str(paths["fourflip"]), "").replace(str(rec), "") for out in
            (tmp_path / "a.json", tmp_path / "b.json"))
    assert a == b
