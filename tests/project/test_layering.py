"""The layering docs/architecture.md states, read from the imports.

Data flows one way: recordings -> ``calibrate`` -> calibration file -> ``compass`` -> attitude.
``compass`` (the runtime) never imports ``calibrate``; the one exception is the command-line layer
(``compass/cli.py``, ``compass/__main__.py``, ``compass/commands/``), which sits on top of both (it runs
calibrations, live ones included) and which no library module imports.  No module of either package
is in an import circle, and only :mod:`compass.calibration` reads a calibration's document.
"""

import ast
import warnings
from pathlib import Path
from tests._paths import ROOT

CLI_ON_TOP = "compass/commands/"


def imported_modules(path: Path) -> set[str]:
    """Absolute module names a file imports (relative imports resolved against its package)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = path.relative_to(ROOT).with_suffix("").parts[:-1]
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = list(package[:len(package) - node.level + 1]) if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            names.add(module)
    return names


def test_compass_never_imports_calibrate_except_the_command_layer():
    offenders = {}
    for path in sorted((ROOT / "compass").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        on_top = rel.startswith(CLI_ON_TOP)
        bad = sorted(m for m in imported_modules(path) if m == "calibrate" or m.startswith("calibrate."))
        if bad and not on_top:
            offenders[rel] = bad
    assert offenders == {}


def test_the_exception_is_real():
    # the test above must be able to fail: the calibrate command does import calibrate
    assert any(m.startswith("calibrate") for m in imported_modules(ROOT / "compass/commands/calibrate.py"))


def test_importing_calibrate_does_not_import_scipy_stats():
    # issue 15.7: scipy.stats was 0.84 s of calibrate's 0.9 s import (for chi2.sf and a MAD)
    import subprocess
    import sys

    code = "import sys, calibrate, calibrate.kinds; print('scipy.stats' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0 and done.stdout.strip() == "False", done.stderr


def _modules(package: str) -> dict[str, Path]:
    """Dotted module name -> file, for every module of ``package``."""
    out = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imports(name: str, path: Path, modules: dict) -> list[tuple[str, list[str]]]:
    """(module imported, names taken from it) for every import of a module, also those inside
    functions (a lazy import still makes a circle), except under ``if TYPE_CHECKING:``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                   and getattr(node.test, "id", None) == "TYPE_CHECKING" for n in ast.walk(node)}
    out = []
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            names = [a.name for a in node.names]
            subs = [f"{module}.{n}" for n in names if f"{module}.{n}" in modules]
            out += [(s, []) for s in subs] + ([(module, [n for n in names if f"{module}.{n}" not in modules])]
                                              if len(subs) < len(names) else [])
        elif isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names]
    return out


def test_no_private_name_is_imported_from_another_calibrate_module():
    offenders = []
    for package in ("calibrate",):  # compass: see the note on issue 12 (filter and viz modules still do)
        modules = _modules(package)
        for name, path in modules.items():
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom) and node.module not in (None, "__future__"):
                    offenders += [f"{name}: {node.module}.{a.name}" for a in node.names
                                  if a.name.startswith("_") and not a.name.startswith("__")]
    assert offenders == []


COMMAND_LAYER = ("compass.cli", "compass.__main__", "compass.commands")


def _graph(packages) -> dict[str, set[str]]:
    """Module -> the modules of ``packages`` it imports (lazily too), over all of them together."""
    modules = {}
    for package in packages:
        modules |= _modules(package)
    return {name: {m for m, _ in _imports(name, path, modules) if m in modules and m != name}
            for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Import circles of a module graph, each as the trail that closes it (a package's own children
    may import it while it imports them: ``compass.filter._base`` -> ``compass.filter``)."""
    state, cycles = {}, []

    def visit(node, trail):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open" and not node.startswith(nxt + "."):  # a package's own children may import siblings
                cycles.append(trail + [nxt])
            elif nxt not in state:
                visit(nxt, trail + [nxt])
        state[node] = "done"

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    return cycles


def test_no_import_circle_anywhere_in_compass_or_calibrate():
    assert _cycles(_graph(("compass", "calibrate"))) == []


def test_the_circle_detector_finds_a_planted_circle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == [["a", "b", "c", "a"]]
    graph = _graph(("compass",))
    graph["compass.model"] = graph["compass.model"] | {"compass.calibration._read"}  # the circle this tree had
    assert any("compass.model" in trail and "compass.calibration._read" in trail for trail in _cycles(graph))


def _in_command_layer(name: str) -> bool:
    return any(name == top or name.startswith(top + ".") for top in COMMAND_LAYER)


def _library_importing_commands(graph) -> dict[str, list[str]]:
    return {name: sorted(m for m in imported if _in_command_layer(m))
            for name, imported in graph.items()
            if not _in_command_layer(name) and any(_in_command_layer(m) for m in imported)}


def test_the_library_never_imports_the_command_layer_which_imports_the_library():
    graph = _graph(("compass", "calibrate"))
    assert _library_importing_commands(graph) == {}
    commands = [n for n in graph if n.startswith("compass.commands.")]
    assert len(commands) >= 8 and all(any(not _in_command_layer(m) for m in graph[n]) for n in commands)
    planted = graph | {"compass.attitude": graph["compass.attitude"] | {"compass.cli"}}
    assert _library_importing_commands(planted) == {"compass.attitude": ["compass.cli"]}


DOCUMENT_ATTRIBUTES = ("data", "document")
"""What a calibration's JSON was (``CalibrationFile.data``) or is (``Calibration.document``) read through."""
NOT_CALIBRATIONS = {"table", "item", "args", "lines"}
"""Receivers of ``.data`` that are no calibration (a recording's table, a port's chunk, argparse, a line)."""


def document_reads(source: str) -> list[str]:
    """``x.data`` / ``x.document`` reads in ``source``, except on receivers known to be no calibration
    (:data:`NOT_CALIBRATIONS`, and a class's own ``self.data``)."""
    found = []
    with warnings.catch_warnings():  # a script's invalid escape in a docstring is not this test's business
        warnings.simplefilter("ignore", (SyntaxWarning, DeprecationWarning))
        tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr in DOCUMENT_ATTRIBUTES:
            receiver = node.value.id if isinstance(node.value, ast.Name) else None
            if receiver not in NOT_CALIBRATIONS and not (receiver == "self" and node.attr == "data"):
                found.append(f"{node.lineno}: {ast.unparse(node)}")
    return found


def test_only_the_calibration_package_reads_a_calibration_document():
    offenders = {}
    for folder in ("compass", "calibrate", "tools", "examples"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel.startswith("compass/calibration/"):
                continue
            reads = document_reads(path.read_text(encoding="utf-8"))
            if reads:
                offenders[rel] = reads
    assert offenders == {}


def test_the_document_check_finds_a_planted_read():
    planted = "cal = load(path)\nrotation = cal.data['mag_to_accel']\nbase = bench.document['base']\n"
    assert document_reads(planted) == ["2: cal.data", "3: bench.document"]
    assert document_reads("rows = table.data[:, 0]\n") == []


def test_the_tests_mirror_the_packages():
    """tests/compass/io/ tests compass/io/, and so on: every folder of tests but the project-wide ones
    (``project``: README, docs, examples, the import graph) names a package (or module) of the project, and no test
    module is left loose at the top."""
    tests = ROOT / "tests"
    unmatched = [folder.relative_to(tests).as_posix() for folder in sorted(tests.rglob("*"))
                 if folder.is_dir() and folder.name not in ("__pycache__", "data") and "data" not in folder.parts
                 and folder.relative_to(tests).parts[0] != "project"
                 and not (ROOT / folder.relative_to(tests)).is_dir()
                 and not (ROOT / folder.relative_to(tests)).with_suffix(".py").is_file()]
    loose = [path.name for path in tests.glob("test_*.py")]
    assert (unmatched, loose) == ([], [])
