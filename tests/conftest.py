import signal

import numpy as np
import pytest

from compass.io.fourflip import read_fourflip
from compass.sim.fourflip import simulate_fourflip, write_fourflip


def pytest_configure(config):
    """Ctrl-C reaches the commands the tests start, however the run itself was started: a shell's background
    job (``cmd &`` without job control) inherits SIGINT ignored, and an ignored signal stays ignored across
    exec, so a test's SIGINT to ``compass bench`` did nothing (the session ran to its end, status 0).  A
    handler is reset to the default at exec, where Python installs its own."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def angle_deg(a, b):
    """Angle between unit vectors (rows), degrees."""
    return np.degrees(np.arccos(np.clip(np.sum(np.asarray(a) * np.asarray(b), axis=-1), -1.0, 1.0)))


def every_row_alone(*keys):
    """Each row its own group (``SampleGroups.of`` patched with it): the fits on every sample, which the fits
    on means are checked against."""
    from calibrate.diagnosis.offsets import SampleGroups

    n = len(keys[0])
    return SampleGroups(np.arange(n), np.ones(n, dtype=int), np.arange(n))


@pytest.fixture
def write_session(tmp_path):
    """Simulate, write and read back a four-flip session: returns (recording, truth)."""

    def make(name="rec.csv", **kwargs):
        session = simulate_fourflip(**kwargs)
        path, _ = write_fourflip(session, tmp_path / name)
        return read_fourflip(path), session.truth

    return make


def assert_calibrate_refuses(tmp_path, capsys, text: str, expected: str, *extra: str) -> None:
    """`compass calibrate` on a bad CSV: exit 2, one line naming the file and ``expected``, no traceback."""
    from compass.cli import main

    rec = tmp_path / "bad.csv"
    rec.write_text(text)
    assert main(["calibrate", str(rec), "--out", str(tmp_path / "c.json"), *extra]) == 2
    err = capsys.readouterr().err
    assert expected in err and "bad.csv" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.fixture
def progress_terminal(monkeypatch):
    """``patch("module.working", ...)``: those progress lines draw at once (no waiting on the clock) into one
    fake terminal, which ``patch`` returns (``compass.io.progress.working`` for commands importing it late)."""
    import io

    from compass.io.progress import working

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    stream = Terminal()

    def at_once(what, **kw):
        return working(what, **(kw | {"stream": stream, "after_s": 0.0, "every_s": 60.0}))

    def patch(*targets):
        for target in targets:
            monkeypatch.setattr(target, at_once)
        return stream

    return patch
