"""Every written file: atomic, refused without --force, the user's umask, no temp file left for long (16.8)."""

import os
import select
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from compass.cli import main
from compass.calibration import model_to_dict


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    try:
        yield 0o640
    finally:
        os.umask(old)


def mode(path) -> int:
    return stat.S_IMODE(Path(path).stat().st_mode)


def temporaries(folder) -> list[str]:
    return sorted(p.name for p in Path(folder).iterdir() if p.name.endswith(".tmp"))


def test_outputs_follow_the_umask_and_a_forced_overwrite_keeps_the_mode(tmp_path, umask_027):
    rec, cal = tmp_path / "rec.csv", tmp_path / "cal.json"
    assert main(["simulate", "fourflip", "--out", str(rec), "--seed", "1"]) == 0
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--no-diagnose", "--report", str(tmp_path / "r")]) == 0
    for path in (rec, cal, tmp_path / "r" / "fit.png", tmp_path / "r" / "residuals.png"):
        assert mode(path) == umask_027, path  # was 0o600 whatever the umask
    cal.chmod(0o644)
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--no-diagnose", "--force"]) == 0
    assert mode(cal) == 0o644  # was turned into 0o600
    assert temporaries(tmp_path) == []


def test_report_plots_are_not_overwritten_without_force(tmp_path, capsys):
    rec, report = tmp_path / "rec.csv", tmp_path / "report"
    assert main(["simulate", "fourflip", "--out", str(rec), "--seed", "2"]) == 0
    report.mkdir()
    (report / "residuals.png").write_bytes(b"precious")
    capsys.readouterr()
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--no-diagnose", "--report", str(report)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "residuals.png exists" in err and "--force" in err
    assert (report / "residuals.png").read_bytes() == b"precious"
    assert not cal.exists() and not (report / "fit.png").exists()  # refused before any output was written
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--no-diagnose", "--report", str(report),
                 "--force"]) == 0
    assert (report / "residuals.png").read_bytes()[:4] == b"\x89PNG"


def test_evaluate_plot_is_not_overwritten_without_force(tmp_path, capsys):
    from tests.compass.io.test_broad import MAGNET, _crop

    if not MAGNET.exists():
        pytest.skip("BROAD data not found")
    trial = _crop(MAGNET, tmp_path / "magnet.mat", 45.0)  # movement starts at 41 s
    plots = tmp_path / "plots"
    plots.mkdir()
    (plots / "magnet_errors.png").write_bytes(b"precious")
    assert main(["evaluate", str(trial), "--plot", str(plots)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "magnet_errors.png exists" in err
    assert (plots / "magnet_errors.png").read_bytes() == b"precious"


_SLOW_WRITER = textwrap.dedent("""
    import sys, time
    from compass.io.atomic import atomic_open
    with atomic_open(sys.argv[1], "w") as fh:
        fh.write("half")
        fh.flush()
        print("writing", flush=True)
        time.sleep(600)
        fh.write(" and the rest")
""")


def test_a_write_killed_midway_leaves_the_old_file_and_the_next_write_clears_its_temporary(tmp_path):
    from compass.io.atomic import atomic_write_text

    target = tmp_path / "cal.json"
    target.write_text("old")
    writer = subprocess.Popen([sys.executable, "-c", _SLOW_WRITER, str(target)], stdout=subprocess.PIPE, text=True)
    try:
        assert select.select([writer.stdout], [], [], 60)[0], "the writer never reached its write window"
        assert writer.stdout.readline().strip() == "writing"  # the process prints only when in the write window
        writer.send_signal(signal.SIGKILL)
        writer.wait(30)
    finally:
        if writer.poll() is None:
            writer.kill()
            writer.wait(30)
        writer.stdout.close()
    left = temporaries(tmp_path)
    assert len(left) == 1 and left[0].startswith(f".cal.json.{writer.pid}.") and target.read_text() == "old"
    atomic_write_text(target, "new")
    assert temporaries(tmp_path) == [] and target.read_text() == "new"


def test_stale_temporaries_of_live_writers_and_other_names_are_kept(tmp_path):
    from compass.io.atomic import remove_stale_temporaries

    target = tmp_path / "att.csv"
    alive = tmp_path / f".att.csv.{os.getppid()}.abc.tmp"  # our parent runs: its write may be under way
    other = tmp_path / ".other.csv.1.abc.tmp"
    foreign = tmp_path / ".att.csv.notapid.tmp"
    for path in (alive, other, foreign):
        path.write_text("x")
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait(30)
    stale = tmp_path / f".att.csv.{gone.pid}.abc.tmp"
    stale.write_text("x")
    assert remove_stale_temporaries(target) == [stale]
    assert alive.exists() and other.exists() and foreign.exists()


def test_an_error_inside_the_write_leaves_nothing(tmp_path):
    from compass.io.atomic import atomic_open

    target = tmp_path / "out.csv"
    with pytest.raises(RuntimeError), atomic_open(target) as fh:
        fh.write("partial")
        raise RuntimeError("the writer failed")
    assert not target.exists() and temporaries(tmp_path) == []


def test_live_out_is_streamed_with_the_umask(tmp_path, umask_027, monkeypatch):
    """`compass live --out` is a stream written as it goes (a crash keeps what was recorded), with the umask."""
    from tests.compass.live.test_live_mistakes import _live_on_socket
    from compass.sim.device import PtyDevice, default_model, simulate_device

    cal, att = tmp_path / "cal.json", tmp_path / "att.csv"
    model = default_model()
    cal.write_text(__import__("json").dumps(model_to_dict(model)))
    device = PtyDevice(model, rate_hz=100.0)
    stream = device._header + b"".join(device._lines(simulate_device(model, [i / 100 for i in range(200)], seed=1), 0))
    started = time.monotonic()
    status, alive, errors = _live_on_socket(monkeypatch, stream, cal, "--duration", "2", "--out", str(att))
    assert status == 0 and not alive and not errors and time.monotonic() - started < 60
    assert mode(att) == umask_027 and temporaries(tmp_path) == []
    assert att.read_text().count("\n") > 150


def test_a_symbolic_link_is_followed_and_kept_and_a_pipe_is_written_through(tmp_path):
    from compass.io.atomic import atomic_open, atomic_stream, check_writable
    target, link = tmp_path / "target.csv", tmp_path / "link.csv"
    target.write_text("old\n")
    link.symlink_to(target.name)
    with pytest.raises(FileExistsError):
        check_writable(link, force=False)
    check_writable(link, force=True)
    with atomic_open(link) as fh:
        fh.write("new\n")
    assert link.is_symlink() and target.read_text() == "new\n"  # was: the link replaced by a file
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # a reader, so opening it for writing does not block
    try:
        assert check_writable(fifo, force=False) == fifo  # nothing is replaced: no --force needed
        with atomic_stream(fifo, keep=lambda: False) as fh:
            fh.write("row\n")
        assert os.read(reader, 100) == b"row\n"
    finally:
        os.close(reader)
    assert stat.S_ISFIFO(fifo.lstat().st_mode) and temporaries(tmp_path) == []



def test_an_output_that_is_an_input_is_refused_even_with_force(tmp_path, capsys):
    rec, cal = tmp_path / "rec.csv", tmp_path / "cal.json"
    assert main(["simulate", "fourflip", "--out", str(rec), "--seed", "1"]) == 0
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--no-diagnose"]) == 0
    before = rec.read_bytes(), cal.read_bytes()
    capsys.readouterr()
    assert main(["calibrate", str(rec), "--out", str(rec), "--quiet", "--no-diagnose", "--force"]) == 2
    assert main(["attitude", str(cal), str(rec), "--out", str(cal), "--force"]) == 2
    assert main(["export", str(cal), "--format", "fusion", "--axes", "v1,v2,v3", "--out", str(cal), "--force"]) == 2
    err = capsys.readouterr().err
    assert err.count("is also an input of this command") == 3 and "Traceback" not in err
    assert (rec.read_bytes(), cal.read_bytes()) == before


def test_a_killed_stream_s_rows_are_kept_visible_by_the_next_write(tmp_path):
    """``compass live --out`` killed with kill -9 leaves its stream's temporary file; the next write to the same
    target keeps it as ``STEM.partial-PID.SUFFIX`` and says so (it deleted it), and drops an empty one."""
    from compass.io.atomic import atomic_stream
    from compass.io.units import RecordingWarning

    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait(30)
    target = tmp_path / "att.csv"
    rows = tmp_path / f".att.csv.{gone.pid}.abc.stream.tmp"
    rows.write_text("t_s,heading_deg\n0.01,12.5\n")
    rows.chmod(0o600)  # as mkstemp leaves it
    empty = tmp_path / f".att.csv.{gone.pid}.def.stream.tmp"
    empty.write_text("")
    with pytest.warns(RecordingWarning, match=f"att.partial-{gone.pid}.csv: the rows a session writing"):
        with atomic_stream(target, keep=lambda: True) as fh:
            fh.write("t_s,heading_deg\n")
    kept = tmp_path / f"att.partial-{gone.pid}.csv"
    assert kept.read_text() == "t_s,heading_deg\n0.01,12.5\n" and target.exists()
    assert stat.S_IMODE(kept.stat().st_mode) == stat.S_IMODE(target.stat().st_mode)  # a new output's, not private
    assert temporaries(tmp_path) == []


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_session_is_stopped_not_killed_by_ctrl_c_kill_and_a_closed_terminal(signum):
    """The reading loop's stop event is set by each signal (SIGHUP: an ssh session dropped killed live and its
    files before); the handlers before are restored after."""
    from compass.commands._port import stop_when_asked

    before = signal.getsignal(signum)
    with stop_when_asked(None) as stop:
        os.kill(os.getpid(), signum)
        assert stop.wait(10)
    assert signal.getsignal(signum) is before


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_command_killed_by_sigterm_or_sighup_leaves_no_temporary_file(tmp_path, signum):
    """``kill`` (or a closed terminal) during a write raises where the command runs, so the output's temporary file
    is removed as on Ctrl-C (a replay killed while writing --rerun left 16 MB of ``.att.rrd.*.tmp``); the command's
    exit status is 128 + the signal's number."""
    from compass.cli import _Terminated, _terminate_as_interrupt
    from compass.io.atomic import atomic_open

    target, before = tmp_path / "att.csv", signal.getsignal(signum)
    with pytest.raises(_Terminated) as raised, _terminate_as_interrupt(), atomic_open(target) as fh:
        fh.write("half a row")
        os.kill(os.getpid(), signum)
        time.sleep(5)  # the handler raises here, at once
    assert raised.value.signum == signum and not target.exists() and temporaries(tmp_path) == []
    assert signal.getsignal(signum) is before  # the handler before is back


def test_standard_output_is_written_through_into_a_pipe_or_a_shell_redirect(tmp_path):
    """``--out /dev/stdout``: its link resolves to a ``pipe:[N]`` no name opens (refused, 'No such file'), or to the
    redirect's file (replaced by a rename, the shell's descriptor left on the old one); both are written through."""
    script = "from compass.io.atomic import atomic_write_text, check_writable\n" \
             "atomic_write_text(check_writable('/dev/stdout', False), 'a row\\n')\n"
    piped = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert piped.returncode == 0 and piped.stdout == "a row\n", piped.stderr
    redirect = tmp_path / "out.csv"
    with open(redirect, "w") as fh:
        done = subprocess.run([sys.executable, "-c", script], stdout=fh, stderr=subprocess.PIPE, text=True, timeout=60)
    assert done.returncode == 0 and redirect.read_text() == "a row\n", done.stderr


def test_a_signal_ignored_on_entry_stays_ignored(monkeypatch):
    """``nohup compass live ...``: SIGHUP ignored must not end the command when the ssh session drops."""
    from compass.cli import _terminate_as_interrupt
    from compass.commands._port import stop_when_asked

    before = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with _terminate_as_interrupt(), stop_when_asked(None) as stop:
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.2)
            assert not stop.is_set()
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, before)
