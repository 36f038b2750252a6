"""docs/cli.md is what the commands' own --help prints (tools/write_cli_docs.py writes it)."""

import subprocess
import sys
from tests._paths import ROOT



def test_the_cli_page_is_the_commands_help():
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "write_cli_docs.py"), "--check"],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
