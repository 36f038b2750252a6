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
