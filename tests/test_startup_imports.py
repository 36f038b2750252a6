"""Start-up stays light: building the parser imports neither scipy nor the simulators nor the fits.

Timing lives in ``tools/bench_startup.py``; this guards the cause (what is imported), which does not
depend on the machine's load.
"""

import subprocess
import sys


def test_parser_imports_no_scipy_simulator_or_fit():
    code = ("import sys, compass.cli as c; c.build_parser(); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'calibrate', 'matplotlib', 'rerun', "
            "'filterpy', 'pygeomag') or m.startswith('compass.sim')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
