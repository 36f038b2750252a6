"""Word of long work on a terminal's stderr, nothing when piped."""

import io
import time

from compass.io.progress import working


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_terminal_sees_the_elapsed_time_and_the_line_is_cleared():
    stream = _Terminal()
    with working("calibrating x.csv", stream=stream, after_s=0.0, every_s=0.05):
        end = time.monotonic() + 20.0  # until the first update is written (bounded: a loaded machine is slow)
        while "s " not in stream.getvalue() and time.monotonic() < end:
            time.sleep(0.01)
    text = stream.getvalue()
    assert "\rcalibrating x.csv: 0 s" in text and text.endswith("\r\x1b[K")


def test_piped_output_and_short_work_stay_silent():
    piped, quick = io.StringIO(), _Terminal()
    with working("calibrating x.csv", stream=piped, after_s=0.0, every_s=0.05):
        time.sleep(0.2)
    with working("calibrating x.csv", stream=quick, after_s=30.0):
        pass  # ends long before the first update
    assert piped.getvalue() == "" and quick.getvalue() == ""
