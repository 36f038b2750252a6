"""Start-up stays light: building the parser imports neither scipy nor the simulators nor the fits.

Timing lives in ``tools/bench_startup.py``; this guards the cause (what is imported), which does not
depend on the machine's load.
"""

import ast
import subprocess
import sys


def test_parser_imports_no_scipy_simulator_or_fit():
    code = ("import sys, compass.cli as c; c.build_parser(); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'calibrate', 'matplotlib', 'rerun', "
            "'filterpy', 'pygeomag') or m.startswith('compass.sim')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"



def test_the_live_pipeline_imports_no_scipy_stats():
    """``compass live`` and the replay start from ``compass.live``: scipy.stats costs a second of start-up
    (``tools/bench_startup.py``), and the filter's chi-square bounds need only ``scipy.special``."""
    code = "import sys, compass.live; print(sorted(m for m in sys.modules if m.startswith('scipy.stats')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"

OTHER_KINDS = ("calibrate.tumble", "calibrate.platform3d", "calibrate.reference", "calibrate.installation",
               "compass.io.tumble", "compass.io.platform3d", "compass.io.reference", "compass.io.installation",
               "compass.sim.tumble", "compass.sim.platform3d", "compass.sim.reference", "compass.sim.installation")
"""Modules of the calibration kinds other than the four-flip."""


def _other_kinds_after(code: str, cwd) -> list[str]:
    """The modules of :data:`OTHER_KINDS` loaded once ``code`` has run in a fresh interpreter."""
    probe = (f"import sys\n{code}\n"
             f"print(sorted(m for m in sys.modules if m.startswith({OTHER_KINDS!r})))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, cwd=cwd)
    assert out.returncode == 0, out.stderr
    return ast.literal_eval(out.stdout.strip().splitlines()[-1])


def test_calibrating_a_fourflip_imports_no_other_kind(tmp_path):
    from compass.sim.fourflip import simulate_fourflip, write_fourflip

    rec, _ = write_fourflip(simulate_fourflip(seed=2), tmp_path / "bench.csv")
    calibrate = ("from compass.cli import main\n"
                 "assert main(['calibrate', 'bench.csv', '--out', 'cal.json', '--quiet', '--no-diagnose']) == 0\n"
                 "assert 'calibrate.fourflip.fit' in sys.modules")
    assert _other_kinds_after(calibrate, tmp_path) == []
    assert (tmp_path / "cal.json").exists()
    # the probe can fail: asking the registry for another kind's calibrator imports that kind
    assert "calibrate.tumble" in _other_kinds_after("from calibrate.kinds import KINDS\nKINDS['tumble'].calibrator",
                                                    tmp_path)
