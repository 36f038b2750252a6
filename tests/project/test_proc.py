"""The test harness for subprocesses fails instead of hanging (issue 16.10)."""

import sys
import time

from tests._proc import Proc


def test_a_silent_process_times_out_and_is_killed_on_the_way_out():
    silent = [sys.executable, "-c", "import time; time.sleep(600)"]
    started = time.monotonic()
    with Proc(silent) as proc:
        assert not proc.wait_for(lambda line: True, 0.5)  # nothing printed: False after the timeout, no hang
        assert proc.transcript() == ""  # reading what came so far never blocks
    assert proc.popen.returncode is not None  # killed and reaped
    assert not any(t.is_alive() for t in proc._threads)
    assert time.monotonic() - started < 30.0


def test_the_hard_limit_kills_a_process_nobody_stops():
    with Proc([sys.executable, "-c", "print('up', flush=True); import time; time.sleep(600)"], kill_after_s=1.0) as proc:
        assert proc.wait_for(lambda line: line.strip() == "up", 30.0)
        proc.popen.wait(30)  # ends by the timer, not by the test
    assert proc.popen.returncode != 0
