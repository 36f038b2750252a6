"""`compass live` and `live --calibrate tumble` end to end on a simulated board that speaks MotionCal's
Raw: lines or bare CSV numbers (`compass device --pty --format ...`).  Every wait is bounded; both
processes are stopped on the way out."""

import json
import signal

import numpy as np
from tests._proc import Proc, compass_command

from compass.calibration import model_to_dict
from compass.io.table import read_table
from compass.sim.device import scripted_motion
from compass.sim.stream_formats import CSV_COLUMNS, board_model


def _wrap(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def _live_on_device(tmp_path, fmt, *live_args, readouts=4, noise=()):
    cal, link, att = tmp_path / "board.json", tmp_path / "board", tmp_path / "att.csv"
    cal.write_text(json.dumps(model_to_dict(board_model())))
    with Proc(compass_command("live", "--port", str(link), "--cal", str(cal), "--out", str(att), "--wait", "60",
                              *live_args), kill_after_s=150) as live:
        assert live.wait_for(lambda line: "waiting for" in line, 60.0), live.transcript()
        with Proc(compass_command("device", "--pty", "--format", fmt, "--cal", str(cal), "--link", str(link),
                                  "--rate", "100", "--duration", "90", *noise), kill_after_s=120) as device:
            count = {"n": 0}

            def enough(line):
                count["n"] += line.startswith("heading")
                return count["n"] >= readouts

            assert live.wait_for(enough, 90.0), live.transcript() + device.transcript()
            status = live.stop(signal.SIGINT, 20.0)
            device.stop(signal.SIGINT, 10.0)
    assert status == 0, live.transcript()
    return "".join(live.out), read_table(att)


def test_live_reads_a_motioncal_raw_board(tmp_path):
    output, table = _live_on_device(tmp_path, "motioncal-raw", readouts=12)
    assert "stream format: motioncal (found from its Raw:/Uni:/Cal lines)" in output
    assert "[MotionCal Raw: lines]" in output  # stated in the readout
    summary = output.strip().splitlines()[-1]
    assert "garbage 0" in summary  # the Cal1:/Cal2: echoes are the sketch's, not noise
    t, heading = table.column("t_s"), table.column("heading_deg")
    assert len(t) > 500
    # Raw: lines carry no time: t_s is the arrival time from the first sample, which the board sent at some
    # unknown module time; that one offset is found on the whole stream (a 0.01 s grid over 0-5 s)
    offsets = np.arange(0.0, 5.0, 0.01)
    rms = [np.sqrt(np.mean(_wrap(heading - scripted_motion(t + d)[0])[t > 1.0] ** 2)) for d in offsets]
    best = offsets[int(np.argmin(rms))]
    truth = scripted_motion(t + best)
    settled = (t > 1.0) & (truth[3] == 0)  # away from the magnet
    err = _wrap(heading - truth[0])[settled]
    assert np.sqrt(np.mean(err ** 2)) < 1.0, (best, np.sqrt(np.mean(err ** 2)))
    np.testing.assert_allclose(table.column("pitch_deg")[settled], truth[1][settled], atol=1.5)


def test_live_reads_a_headerless_csv_board_named_by_columns(tmp_path):
    output, table = _live_on_device(tmp_path, "csv", "--columns", ",".join(CSV_COLUMNS),
                                    noise=("--garbage", "0.02", "--truncate", "0.02"))
    assert "stream format: csv (as named)" in output and f"[csv {','.join(CSV_COLUMNS)}]" in output
    summary = output.strip().splitlines()[-1]  # the noise is counted, never fatal
    garbage, partial = (int(summary.split(f"{k} ")[1].split(",")[0]) for k in ("garbage", "partial"))
    assert "line noise" in output and garbage > 0 and partial > 0
    t = table.column("t_s")  # the board's own clock: the truth at the same times
    truth = scripted_motion(t)
    settled = (t > t[0] + 1.0) & (truth[3] == 0)
    assert len(t) > 200
    assert np.sqrt(np.mean(_wrap(table.column("heading_deg") - truth[0])[settled] ** 2)) < 1.0
    np.testing.assert_allclose(table.column("pitch_deg")[settled], truth[1][settled], atol=1.0)


def test_live_calibrate_tumble_on_a_motioncal_board(tmp_path):
    cal, link, out = tmp_path / "board.json", tmp_path / "board", tmp_path / "live.json"
    model = board_model()
    cal.write_text(json.dumps(model_to_dict(model)))
    with Proc(compass_command("device", "--pty", "--format", "motioncal-raw", "--motion", "tumble", "--cal", str(cal),
                              "--link", str(link), "--rate", "100", "--seed", "3", "--duration", "100"),
              kill_after_s=130) as device:
        assert device.wait_for(lambda line: line.strip() == str(link), 30.0), device.transcript()
        with Proc(compass_command("live", "--port", str(link), "--calibrate", "tumble", "--out", str(out),
                                  "--min-coverage", "0.5", "--duration", "70"), kill_after_s=110) as live:
            live.wait_for(lambda line: line.startswith("wrote") and line.strip().endswith(".json"), 100.0)
            status = live.stop(sig=0, timeout_s=20.0)
        device.stop()
    assert status == 0, live.transcript()
    assert "stream format: motioncal" in "".join(live.out) and "[MotionCal Raw: lines]" in "".join(live.out)
    found = json.loads(out.read_text())
    hard, sigma = np.array(found["hard_iron"]), np.array(found["tumble"]["hard_iron_sigma"])
    truth = np.array([r.offset for r in model.responses])  # uT, what the Raw: counts carry
    assert np.all(np.abs(hard - truth) < 4.0 * sigma), (hard, truth, sigma)
    assert 45.0 < found["field_norm"] < 55.0  # the board's 50 uT, in uT
