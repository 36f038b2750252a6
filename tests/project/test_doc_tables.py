"""Benchmark tables in docs/ are written by their tools/ script (tools/_doc_table.py), never by hand.

Every ``<!-- table: NAME -->`` marker in docs/ is closed and names a script under tools/ that accepts
``--write-docs``; every table a script publishes has its marker in the doc it names; and the
helper's replacement changes nothing outside the markers and refuses a doc without them.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from tests._paths import ROOT, load_tool
from tests._proc import Proc

DOCS = sorted((ROOT / "docs").glob("*.md"))
PUBLISH_RE = re.compile(r"""publish\(\s*\w+,\s*["']([^"']+)["'],\s*(f?)["']([^"']+)["']""")


def _helper():
    return load_tool("_doc_table")


dt = _helper()


def _markers() -> list[tuple[Path, str]]:
    return [(doc, m.group(1)) for doc in DOCS for m in dt.OPEN_RE.finditer(doc.read_text(encoding="utf-8"))]


def _scripts() -> list[str]:
    return sorted({dt.script_of(name) for _, name in _markers()})


def test_docs_have_table_markers():
    assert len(_markers()) >= 3, "the benchmark tables in docs/ lost their markers"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_marker_is_closed_once_and_names_a_script(doc):
    text = doc.read_text(encoding="utf-8")
    names = dt.OPEN_RE.findall(text)
    assert len(names) == len(set(names)), f"{doc.name}: a table marker repeated"
    closed = len(dt.CLOSE_RE.findall(text))
    assert closed == len(names), f"{doc.name}: {len(names)} tables opened, {closed} closed"
    for name in names:
        assert (ROOT / "tools" / dt.script_of(name)).is_file(), f"{doc.name}: {name} names no script under tools/"
        dt.replace_table(text, name, "", doc=doc.name)  # closed before the next one opens, or raises
        start = next(m.end() for m in dt.OPEN_RE.finditer(text) if m.group(1) == name)
        block = text[start:dt.CLOSE_RE.search(text, start).start()]
        assert f"`python tools/{dt.script_of(name)}" in block and "--write-docs`" in block, \
            f"{doc.name}: table {name} does not say the command that wrote it"


def test_marker_names_are_unique_across_docs():
    names = [name for _, name in _markers()]
    assert len(names) == len(set(names))


@pytest.mark.parametrize("script", _scripts())
def test_each_script_with_a_table_accepts_write_docs(script):
    with Proc([sys.executable, str(ROOT / "tools" / script), "--help"], kill_after_s=120) as proc:
        status = proc.wait(120)
    assert status == 0, proc.transcript()
    assert "--write-docs" in "".join(proc.out), f"{script} --help does not offer --write-docs"


def test_every_published_table_has_its_marker():
    published = [(path.name, doc, formatted, name) for path in sorted((ROOT / "tools").glob("bench_*.py"))
                 for doc, formatted, name in PUBLISH_RE.findall(path.read_text(encoding="utf-8"))]
    assert len(published) >= 8
    for script, doc, formatted, name in published:
        assert dt.script_of(name) == script, f"{script} publishes {name}, which names another script"
        names = dt.OPEN_RE.findall((ROOT / doc).read_text(encoding="utf-8"))
        if formatted:  # f"bench_x.{part}": some marker of that script's, with a part
            prefix = name.split("{", 1)[0]
            assert any(n.startswith(prefix) for n in names), f"{script}: no marker {name} in {doc}"
        else:
            assert name in names, f"{script}: no marker {name} in {doc}"


DOC = """# Title

Prose before, quoting a marker: `<!-- table: bench_x.one -->` and `<!-- /table -->` (text, not markers).

<!-- table: bench_x.one -->
| old | table |
|---|---|
| 1 | 2 |
<!-- /table -->
Prose between.
<!-- table: bench_x.two -->
<!-- /table -->

Prose after: 1.23 deg.
"""


def test_replacement_changes_only_the_text_between_the_markers():
    new = dt.replace_table(DOC, "bench_x.one", "| a |\n|---|\n| 9 |\n")
    head, tail = DOC.split("\n<!-- table: bench_x.one -->\n")
    assert new.startswith(head + "\n<!-- table: bench_x.one -->\n| a |\n|---|\n| 9 |\n<!-- /table -->\nProse between.")
    assert new.endswith(tail.split("\n<!-- /table -->\n", 1)[1])
    assert "`<!-- table: bench_x.one -->` and `<!-- /table -->` (text, not markers)" in new
    assert dt.replace_table(new, "bench_x.one", "| old | table |\n|---|---|\n| 1 | 2 |") == DOC
    empty = dt.replace_table(DOC, "bench_x.two", "| b |")
    assert empty == DOC.replace("<!-- table: bench_x.two -->\n", "<!-- table: bench_x.two -->\n| b |\n")


@pytest.mark.parametrize("text, name, message", [
    (DOC, "bench_x.three", r"the doc: no <!-- table: bench_x.three -->"),
    (DOC + "<!-- table: bench_x.one -->\n<!-- /table -->\n", "bench_x.one", r"2 markers <!-- table: bench_x.one -->"),
    (DOC.replace("<!-- /table -->\nProse between.", "Prose between."), "bench_x.one", r"bench_x.one --> is not closed"),
    ("<!-- table: bench_x.one -->\nno end\n", "bench_x.one", r"is not closed"),
])
def test_bad_markers_are_refused(text, name, message):
    with pytest.raises(dt.DocTableError, match=message):
        dt.replace_table(text, name, "| t |")


def test_write_table_is_exact_on_a_file_and_refuses_a_missing_marker(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text(DOC, encoding="utf-8")
    dt.write_table(doc, "bench_x.two", "| b |")
    assert doc.read_text(encoding="utf-8") == dt.replace_table(DOC, "bench_x.two", "| b |")
    before = doc.read_text(encoding="utf-8")
    with pytest.raises(dt.DocTableError, match=rf"{re.escape(str(doc))}: no <!-- table: bench_x.nine -->"):
        dt.write_table(doc, "bench_x.nine", "| c |")
    assert doc.read_text(encoding="utf-8") == before
    assert [p.name for p in tmp_path.iterdir()] == ["doc.md"]  # no temporary left behind
    with pytest.raises(dt.DocTableError, match="no such doc"):
        dt.write_table(tmp_path / "missing.md", "bench_x.one", "| c |")


def test_publish_prints_always_writes_only_with_the_flag(tmp_path, monkeypatch, capsys):
    import argparse

    monkeypatch.setattr(dt, "ROOT", tmp_path)
    (tmp_path / "doc.md").write_text(DOC, encoding="utf-8")
    parser = argparse.ArgumentParser(prog="anything")
    parser.add_argument("--n", type=int, default=3)
    table = dt.markdown_table(["a", "b"], [[1, 2.5]])
    assert table == "| a | b |\n|---|---|\n| 1 | 2.5 |"

    dt.publish(dt.parse_args(parser, ["--n", "7"]), "doc.md", "bench_x.two", table)
    assert table in capsys.readouterr().out
    assert (tmp_path / "doc.md").read_text(encoding="utf-8") == DOC

    parser = argparse.ArgumentParser(prog="anything")
    parser.add_argument("--n", type=int, default=3)
    args = dt.parse_args(parser, ["--write-docs", "--n", "7"])
    assert args.write_docs and args.n == 7
    block = dt.publish(args, "doc.md", "bench_x.two", table, caption="units")
    assert block == f"Written by `python tools/bench_x.py --n 7 --write-docs`: units.\n\n{table}"
    assert (tmp_path / "doc.md").read_text(encoding="utf-8") == dt.replace_table(DOC, "bench_x.two", block)
    assert "wrote table bench_x.two in doc.md" in capsys.readouterr().err

    with pytest.raises(SystemExit) as exit_:
        dt.publish(args, "doc.md", "bench_x.nine", table)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "doc.md: no <!-- table: bench_x.nine -->" in err[0]


def test_a_row_of_the_wrong_width_is_refused():
    with pytest.raises(ValueError, match="a row of 1 cells under 2 columns"):
        dt.markdown_table(["a", "b"], [["x"]])
