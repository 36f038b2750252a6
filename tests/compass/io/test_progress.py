"""The progress line of long work: a bar with count and time left on a terminal's stderr, nothing when piped."""

import io
import os
import subprocess
import sys
import textwrap
import threading

from compass.io.progress import BAR_WIDTH, Tally, progress_line, working


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_the_line_is_a_bar_with_count_elapsed_and_time_left():
    assert progress_line("scoring", 12.0, 3, 12) == f"scoring [{'#' * 5}{'.' * 15}] 3/12 25 % 0:12, 0:36 left"
    assert progress_line("scoring", 75.0, 12, 12) == f"scoring [{'#' * BAR_WIDTH}] 12/12 100 % 1:15"
    assert progress_line("scoring", 3.0, 0, 12).endswith("0/12 0 % 0:03")  # nothing done: no estimate yet
    assert progress_line("calibrating x.csv", 3725.0) == "calibrating x.csv: 1:02:05"  # no count: elapsed only


def test_piped_output_and_short_work_stay_silent_and_still_count():
    piped, quick = io.StringIO(), _Terminal()
    with working("scoring", total=3, stream=piped, after_s=0.0) as tally:
        for _ in range(3):
            tally.advance()
        with tally.hidden():
            piped.write("report\n")
    with working("scoring", stream=quick, after_s=30.0):
        pass  # ends long before the line would show
    assert piped.getvalue() == "report\n" and quick.getvalue() == "" and tally.done == 3


def test_a_terminal_sees_each_unit_and_a_report_on_a_clean_line():
    stream = _Terminal()
    with working("scoring", total=2, stream=stream, after_s=0.0, every_s=60.0) as tally:
        tally.advance()
        with tally.hidden():
            stream.write("report\n")
        tally.advance()
    text = stream.getvalue()
    assert text.startswith("\rscoring [") and "1/2 50 %" in text and "2/2 100 %" in text
    assert "\x1b[K\r\x1b[Kreport\n\rscoring [" in text  # cleared before the report, drawn again after it
    assert text.endswith("\r\x1b[K")


CHILD = textwrap.dedent("""
    from compass.io.progress import working
    with working("scoring", total=3, after_s=0.0, every_s=60.0) as tally:
        for _ in range(3):
            tally.advance()
    print("done")
""")


def _run_child(stderr):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    return subprocess.run([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, stderr=stderr, timeout=60, env=env)


def test_a_pseudo_terminal_gets_the_bar_and_a_pipe_gets_nothing():
    """The real check of ``isatty``: stderr on a pty shows the bar, on a pipe nothing at all."""
    piped = _run_child(subprocess.PIPE)
    assert piped.stdout == b"done\n" and piped.stderr == b""
    master, slave = os.openpty()
    seen, reader = [], None
    try:
        def read():
            while True:
                try:
                    chunk = os.read(master, 4096)
                except OSError:  # the child closed its end
                    return
                if not chunk:
                    return
                seen.append(chunk)

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        done = _run_child(slave)
    finally:
        os.close(slave)
        if reader is not None:
            reader.join(10.0)
        os.close(master)
    text = b"".join(seen).decode()
    assert done.stdout == b"done\n"
    assert "scoring [" in text and "3/3 100 %" in text and text.endswith("\r\x1b[K")


def test_a_tally_without_a_line_counts_and_hides_nothing():
    tally = Tally(4)
    tally.advance(3)
    with tally.hidden():
        pass
    assert (tally.done, tally.total) == (3, 4)
