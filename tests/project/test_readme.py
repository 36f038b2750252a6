"""The README's commands run in order in a fresh folder, as a new user types them (none refused for an
output an earlier one wrote, none reading a file no earlier one made).

Run: every ``compass ...`` line of the README's bash blocks, in order, except those that need what a test
has not (a serial port or a pseudo-terminal: ``live``, ``device``) and those reading a file the reader
brings (a token naming a .csv/.json/.mat input that no earlier command wrote: ``log.csv``,
``../shared/data/...``) or showing placeholders (``[--site LAT,LON]``).
"""

import re
import shlex
from pathlib import Path


from compass.cli import main
from tests._paths import ROOT

README = ROOT / "README.md"
_NEEDS_A_PORT = ("live", "device")
_OUTPUT_OPTIONS = ("--out", "--report", "--save-cal", "--plot", "--rerun", "--workdir")


def readme_commands() -> list[str]:
    """The ``compass`` command lines of the README's bash blocks (continuations joined, comments cut)."""
    lines, block = [], False
    for line in README.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            block = line.strip() == "```bash"
            continue
        if block:
            lines.append(line)
    joined = re.sub(r"\\\n\s*", " ", "\n".join(lines))
    commands = []
    for line in joined.splitlines():
        line = line.split(" #")[0].strip()
        if line.startswith("compass "):
            commands.append(line)
    return commands


def _runnable(argv: list[str], folder: Path) -> bool:
    if argv[0] in _NEEDS_A_PORT or any(a.startswith("[") for a in argv):
        return False
    inputs = [a for i, a in enumerate(argv) if Path(a).suffix in (".csv", ".json", ".mat")
              and (i == 0 or argv[i - 1] not in _OUTPUT_OPTIONS)]
    return all((folder / a).exists() for a in inputs)


def test_the_readme_shows_commands():
    assert len(readme_commands()) >= 8  # the walk-through: simulate, calibrate, attitude, live, install, export


def test_readme_commands_run_in_order_in_a_fresh_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ran = []
    for line in readme_commands():
        argv = shlex.split(line)[1:]
        if not _runnable(argv, tmp_path):
            continue
        code = main(argv)
        assert code == 0, f"README: `{line}` exited {code} after {len(ran)} commands ran"
        ran.append(argv[0])
    # the walk-through's path: bench, calibration, runtime attitude, the installation, exports
    assert {"simulate", "calibrate", "export", "attitude"} <= set(ran) and len(ran) >= 8
