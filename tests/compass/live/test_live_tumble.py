"""`compass live --calibrate tumble` against the simulated module (`compass device --pty --motion tumble`)."""

import json

import numpy as np
import pytest
from tests._proc import Proc, compass_command

from compass.cli import main
from compass.sim.device import simulate_device, tumble_motion

rr = pytest.importorskip("rerun")
from tests.rrd_read import blueprint_views, entity_paths, read_column, scalars  # noqa: E402
from compass.calibration import load as load_calibration


def test_live_tumble_reaches_the_offline_hard_iron(tmp_path):
    cal, link = tmp_path / "dev.json", tmp_path / "dev"
    out, rrd = tmp_path / "live.json", tmp_path / "live.rrd"
    with Proc(compass_command("device", "--pty", "--motion", "tumble", "--save-cal", str(cal), "--link", str(link),
                              "--rate", "100", "--seed", "3", "--duration", "90"), kill_after_s=120) as device:
        assert device.wait_for(lambda line: line.strip() == str(link), 30.0), device.transcript()
        with Proc(compass_command("live", "--port", str(link), "--calibrate", "tumble", "--out", str(out), "--rerun",
                                  str(rrd), "--min-coverage", "0.5", "--duration", "60"), kill_after_s=100) as live:
            live.wait_for(lambda line: line.startswith("wrote") and line.strip().endswith(".rrd"), 90.0)
            status = live.stop(sig=0, timeout_s=20.0)  # it ends by itself (coverage, or --duration): wait for it
            stdout = "".join(live.out)
        device.stop()
    assert status == 0, live.transcript()
    assert "coverage reached" in stdout and "never along the field yet" in stdout  # said in words while turning
    live_cal = json.loads(out.read_text())
    live_h, live_sigma = np.array(live_cal["hard_iron"]), np.array(live_cal["tumble"]["hard_iron_sigma"])

    # the offline fit: the same module through an independent, longer tumble, by `compass calibrate`
    model = load_calibration(cal).model
    s = simulate_device(model, np.arange(0.0, 40.0, 0.01), motion=tumble_motion, seed=11)
    rec = tmp_path / "offline.csv"
    rec.write_text("mx,my,mz,ax,ay,az\n" + "\n".join(",".join(f"{v:.9g}" for v in row)
                                                       for row in np.hstack([s.raw, s.accel])) + "\n")
    assert main(["calibrate", str(rec), "--out", str(tmp_path / "offline.json"), "--quiet"]) == 0
    offline = json.loads((tmp_path / "offline.json").read_text())
    off_h, off_sigma = np.array(offline["hard_iron"]), np.array(offline["tumble"]["hard_iron_sigma"])
    # two independent estimates of one hard iron: their difference has sigma sqrt(s1^2 + s2^2)
    assert np.all(np.abs(live_h - off_h) < 3.0 * np.hypot(live_sigma, off_sigma)), (live_h, off_h, live_sigma)
    truth = np.array([r.offset for r in model.responses])  # linear channels: the ellipsoid's centre
    assert np.all(np.abs(live_h - truth) < 4.0 * live_sigma)

    # the same code path as `compass calibrate`: the samples it kept give the same file
    kept = tmp_path / "live.tumble.csv"
    assert main(["calibrate", str(kept), "--out", str(tmp_path / "again.json"), "--quiet"]) == 0
    np.testing.assert_array_equal(json.loads((tmp_path / "again.json").read_text())["hard_iron"], live_h)

    # the recording: coverage growing, the fit converging, the missing axes in words, then the final clouds
    paths = entity_paths(rrd)
    assert {"/tumble/live", "/tumble/coverage", "/tumble/coverage_fraction", "/tumble/hard_iron/x",
            "/tumble/hard_iron/x/sigma_band", "/tumble/calibrated/samples", "/tumble/raw/ellipsoid",
            "/events"} <= paths
    _, fraction = scalars(rrd, "/tumble/coverage_fraction")
    assert np.all(np.diff(fraction[:, 0]) >= -0.05) and fraction[-1, 0] >= 0.5 > fraction[0, 0]
    _, band = scalars(rrd, "/tumble/hard_iron/x/sigma_band")
    assert band[-1, 1] - band[-1, 0] < band[0, 1] - band[0, 0]  # converging
    _, texts = read_column(rrd, "/events", "TextLog:text")
    assert any("never pointed along" in t[0] for t in texts) and "seen from every side" in texts[-1][0]
    names = {v.get("name") for v in blueprint_views(rrd)}
    assert {"coverage: cells seen (green)", "raw, on the fitted ellipsoid (colour: coverage)"} <= names


def test_live_tumble_bad_options(tmp_path, capsys):
    assert main(["live", "--port", "/dev/null", "--calibrate", "tumble"]) == 2
    assert "needs --out" in capsys.readouterr().err
    assert main(["live", "--port", "/dev/null", "--calibrate", "tumble", "--out", str(tmp_path / "c.json"),
                 "--min-coverage", "1.5"]) == 2
    assert "--min-coverage" in capsys.readouterr().err
    assert main(["live", "--port", "/dev/null"]) == 2
    assert "--cal CAL.json is required" in capsys.readouterr().err


def _protocol_lines(t_s, sim) -> bytes:
    """The samples as the line protocol: t_s, the magnetometer, the accelerometer and the gyro (rad/s)."""
    from compass.io.lines import format_line

    head = format_line(["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"])
    return head + b"".join(format_line([f"{t:.4f}", *(f"{v:.9g}" for v in (*m, *a, *g))])
                           for t, m, a, g in zip(t_s, sim.mag, sim.accel, sim.gyro))


def _recording(path):
    """(header, rows) of a tumble recording, its comment lines apart."""
    lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    return lines[0].split(","), np.array([[float(v) for v in line.split(",")] for line in lines[1:]])


@pytest.fixture(scope="module")
def partial():
    """A hand-held motion with a gyro, cut at 30 % of the sphere: the ellipsoid alone fits only the hard iron."""
    from compass.sim.partial_tumble import simulate_partial_tumble

    return simulate_partial_tumble("slow_rotation", seed=0, coverage=0.3)


def test_live_tumble_keeps_the_gyro_and_the_calibration_fits_its_turns(tmp_path, monkeypatch, partial, capsys):
    """The recording held t_s and the magnetometer and accelerometer only, so a partial tumble got the offset-only
    fit: the gyro is kept in rad/s, as the tumble reader takes gx,gy,gz, and the gyro-aided fit uses it."""
    from tests.compass.live.test_live_mistakes import _live_on_socket

    out = tmp_path / "cal.json"
    status, alive, errors = _live_on_socket(monkeypatch, _protocol_lines(partial.t_s, partial), None, "--calibrate",
                                            "tumble", "--out", str(out), "--duration", "3")
    assert status == 0 and not alive and not errors, capsys.readouterr()
    header, rows = _recording(tmp_path / "cal.tumble.csv")
    assert header == ["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"]
    np.testing.assert_allclose(rows[:, 7:10], partial.gyro, rtol=1e-8, atol=1e-12)  # as sent, to its 9 digits
    cal = json.loads(out.read_text())
    assert cal["tumble"]["kind"] == "full" and cal["tumble"]["gyro"]["used"] is True
    h, sigma = np.array(cal["hard_iron"]), np.array(cal["tumble"]["hard_iron_sigma"])
    assert np.all(np.abs(h - partial.truth["hard_iron"]) < 4.0 * sigma), (h, sigma, partial.truth["hard_iron"])


def test_live_tumble_calibrates_across_a_restart_of_the_modules_clock_and_says_so(tmp_path, monkeypatch, partial,
                                                                                   capsys):
    """A module reset halfway (t_s from 0 again) made `compass calibrate` refuse the recording live had just
    written ("t_s must not decrease", exit 2, no calibration): its t_s now goes on across the restart after a gap
    (RESTART_GAP_S and the stream's median step: the gyro-aided fit integrates no turn across it), said in words,
    and the calibration is, within its stated sigma, the one of the same samples without the reset."""
    from compass.io.clock import RESTART_GAP_S
    from tests.compass.live.test_live_mistakes import _live_on_socket

    half = len(partial.t_s) // 2
    t_s = partial.t_s.copy()
    t_s[half:] -= t_s[half]
    runs = {}
    for name, times in (("reset", t_s), ("steady", partial.t_s)):
        out = tmp_path / f"{name}.json"
        status, alive, errors = _live_on_socket(monkeypatch, _protocol_lines(times, partial), None, "--calibrate",
                                                "tumble", "--out", str(out), "--duration", "3", quiet=name == "steady")
        runs[name] = capsys.readouterr().out
        assert status == 0 and not alive and not errors, runs[name]
    said = runs["reset"]
    assert f"[warn] the module's clock went back from {partial.t_s[half - 1]:.6g} s to 0 s at sample {half + 1}" in said
    assert f"compass live: the module's clock restarted 1 time, at sample {half + 1}" in said  # in the summary too
    assert "clock" not in runs["steady"]
    recording = tmp_path / "reset.tumble.csv"
    assert "# clock: the module's clock restarted 1 time" in recording.read_text()
    _, rows = _recording(recording)
    gap = np.where(np.arange(len(rows)) >= half, RESTART_GAP_S, 0.0)  # the median step is the stream's own
    np.testing.assert_allclose(rows[:, 0], partial.t_s + gap, atol=1e-9)
    cal, steady = (json.loads((tmp_path / f"{name}.json").read_text()) for name in ("reset", "steady"))
    assert cal["tumble"]["gyro"]["used"] is True
    sigma = np.asarray(steady["tumble"]["hard_iron_sigma"])
    assert np.all(np.abs(np.subtract(cal["hard_iron"], steady["hard_iron"])) < sigma)
    # the user may calibrate the recording again: `compass calibrate` reads it as live did
    assert main(["calibrate", str(recording), "--out", str(tmp_path / "again.json"), "--quiet"]) == 0
    np.testing.assert_array_equal(json.loads((tmp_path / "again.json").read_text())["hard_iron"], cal["hard_iron"])


def test_a_live_tumble_killed_outright_keeps_the_samples_it_had(tmp_path):
    """`kill -9` (a laptop that dies) in the middle of a collection: the samples went to a temporary file beside
    CAL.tumble.csv as they came, every row up to the last readout is on disk, and the next write to CAL.tumble.csv
    keeps them as CAL.tumble.partial-PID.csv, a tumble recording `compass calibrate` reads."""
    import signal

    from compass.io.atomic import remove_stale_temporaries
    from compass.io.units import RecordingWarning

    cal, link, out = tmp_path / "dev.json", tmp_path / "dev", tmp_path / "live.json"
    recording = tmp_path / "live.tumble.csv"
    with Proc(compass_command("device", "--pty", "--motion", "tumble", "--save-cal", str(cal), "--link", str(link),
                              "--rate", "100", "--seed", "3", "--duration", "90"), kill_after_s=120) as device:
        assert device.wait_for(lambda line: line.strip() == str(link), 30.0), device.transcript()
        with Proc(compass_command("live", "--port", str(link), "--calibrate", "tumble", "--out", str(out),
                                  "--min-coverage", "1.0", "--duration", "60"), kill_after_s=100) as live:
            said = []  # the readouts "tumble: N samples, ..."

            def enough(line):
                if line.startswith("tumble: ") and " samples" in line:
                    said.append(int(line.split()[1]))
                return len(said) >= 8 and said[-1] >= 500

            assert live.wait_for(enough, 60.0), live.transcript()
            status = live.stop(sig=signal.SIGKILL)
            pid = live.popen.pid
            transcript = live.transcript()
        device.stop()
    assert status == -signal.SIGKILL, transcript
    assert "as they come (a session killed outright leaves it" in transcript
    assert not recording.exists() and not out.exists()
    streams = list(tmp_path.glob(f".live.tumble.csv.{pid}.*.stream.tmp"))
    assert len(streams) == 1, sorted(p.name for p in tmp_path.iterdir())
    header, rows = _recording(streams[0])
    assert header == ["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"]
    assert len(rows) >= said[-1] and np.all(np.isfinite(rows)) and np.all(np.diff(rows[:, 0]) > 0)

    with pytest.warns(RecordingWarning, match=f"had when it was killed \\(process {pid}\\), kept"):
        remove_stale_temporaries(recording)  # what the next write to live.tumble.csv does first
    kept = tmp_path / f"live.tumble.partial-{pid}.csv"
    assert kept.exists() and not streams[0].exists()
    assert "# source: compass live --calibrate tumble (streamed as collected)" in kept.read_text()
    assert main(["calibrate", str(kept), "--out", str(tmp_path / "again.json"), "--quiet"]) == 0
    assert json.loads((tmp_path / "again.json").read_text())["tumble"]["n_samples"] == len(rows)
