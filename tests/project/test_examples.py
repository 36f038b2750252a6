"""Every script in examples/ runs to completion (CI keeps the examples honest)."""

import os
import subprocess
import sys

import pytest
from tests._paths import ROOT

EXAMPLES = sorted((ROOT / "examples").glob("*.py"))


def test_examples_exist():
    assert EXAMPLES, "examples/ holds no scripts"


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(script, tmp_path):
    # a non-interactive backend: an example that plots must not block or need a display
    env = {**os.environ, "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, f"{script.name} exited {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}"
