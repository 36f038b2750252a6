"""The layering the README states, read from the imports (issue 12, item 6).

Data flows one way: recordings -> ``calibrate`` -> calibration file -> ``compass`` -> attitude.
``compass`` (the runtime) never imports ``calibrate``; the one exception is the command-line layer,
``compass/commands/``, which sits on top of both (it runs calibrations, live ones included).
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
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


def test_calibrate_has_no_import_cycles():
    modules = _modules("calibrate")
    graph = {name: {m for m, _ in _imports(name, path, modules) if m in modules and m != name}
             for name, path in modules.items()}
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
    assert cycles == []
