"""`compass export --format motioncal`: the 68-byte packet against a C reference of the sketches' receiver,
the refusals, and sending it to a (simulated) device that echoes what it stores."""

import json
import os
import shutil
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from tests._proc import Proc, compass_command

from compass.calibration import load, model_to_dict
from compass.cli import main
from compass.commands._export_motioncal import packet_of, send_packet
from compass.io import motioncal as mc
from compass.sim.device import default_model
from tests._paths import TEST_DATA

RECEIVER = TEST_DATA / "motioncal_receiver.c"


@pytest.fixture(scope="module")
def cals(tmp_path_factory):
    """A tumble (uT), a four-flip bench (volts) and an installation with a 3 deg yaw on that bench."""
    d = tmp_path_factory.mktemp("cals")
    assert main(["simulate", "tumble", "--out", str(d / "t.csv"), "--seed", "7"]) == 0
    assert main(["calibrate", str(d / "t.csv"), "--out", str(d / "t.json"), "--quiet"]) == 0
    assert main(["simulate", "fourflip", "--out", str(d / "bench.csv"), "--seed", "3"]) == 0
    assert main(["calibrate", str(d / "bench.csv"), "--out", str(d / "bench.json"), "--quiet"]) == 0
    assert main(["simulate", "installation", "--truth", str(d / "bench.truth.json"), "--base", str(d / "bench.json"),
                 "--kind", "swing", "--max-tilt-deg", "10", "--heading-ref-sigma-deg", "0.3", "--yaw-deg", "3",
                 "--out", str(d / "swing.csv"), "--seed", "4"]) == 0
    assert main(["calibrate", str(d / "swing.csv"), "--out", str(d / "inst.json"), "--base", str(d / "bench.json"),
                 "--quiet"]) == 0
    return d


@pytest.fixture(scope="module")
def receiver(tmp_path_factory):
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("no C compiler (gcc) to build the reference receiver")
    exe = tmp_path_factory.mktemp("c") / "receiver"
    subprocess.run([gcc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-O1", "-o", str(exe), str(RECEIVER)],
                   check=True, timeout=120, capture_output=True)
    return exe


def _receive(exe, data: bytes) -> list[str]:
    done = subprocess.run([str(exe)], input=data, capture_output=True, timeout=60, check=True)
    return done.stdout.decode().splitlines()


def test_crc_is_the_receivers(receiver):
    assert mc.crc16(b"123456789") == 0x4B37  # CRC-16/MODBUS: init 0xFFFF, reflected 0xA001


def test_the_packet_is_what_the_c_receiver_accepts_and_stores_byte_for_byte(cals, receiver, tmp_path):
    out = tmp_path / "cal.bin"
    assert main(["export", str(cals / "t.json"), "--format", "motioncal", "--max-rotation-deg", "5",
                 "--out", str(out)]) == 0
    data = out.read_bytes()
    assert len(data) == 68 and data[:2] == bytes((117, 84))
    lines = _receive(receiver, b"\x00garbage Raw:1,2\r\n" + data)  # noise first: the receiver resyncs on 117, 84
    accepted, stored, rejected = lines
    assert rejected == "rejected 0"
    # the sketch's EEPROM image of what it took (saveCalibration) is the packet, byte for byte
    assert stored.split()[1:] == [f"{b:02x}" for b in data]
    # and the numbers it holds are the calibration's, as float32
    held = np.array([float(v) for v in accepted.split()[1:]], dtype=np.float32)  # %.9g round-trips a float32
    cal = json.loads((cals / "t.json").read_text())
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    np.testing.assert_array_equal(held[:6], 0.0)
    np.testing.assert_array_equal(held[6:9], f32(cal["hard_iron"]))  # recorded in uT: sent as is
    np.testing.assert_array_equal(held[9], f32(cal["field_norm"]))
    packet = mc.decode_packet(data)
    np.testing.assert_array_equal(held[10:], f32(packet.soft_iron).ravel())
    # the soft iron is the symmetric part of the calibration's: with the 2 deg rotation left out, the
    # packet's field has the calibration's magnitude (a rotation keeps lengths)
    raw = np.random.default_rng(1).normal(size=(50, 3)) * 40.0
    soft, hard = np.array(cal["soft_iron"]), np.array(cal["hard_iron"])
    rot = np.array(cal["mag_to_accel"]) if cal.get("mag_to_accel") else np.eye(3)
    np.testing.assert_allclose(np.linalg.norm((raw - packet.hard_iron_ut) @ packet.soft_iron.T, axis=1),
                               np.linalg.norm((raw - hard) @ (rot @ soft).T, axis=1), rtol=1e-5)


def test_a_corrupted_byte_anywhere_is_rejected(cals, receiver):
    packet, _ = packet_of(load(cals / "t.json"), max_rotation_deg=5.0)
    data = mc.encode_packet(packet)
    rng = np.random.default_rng(3)
    for k in list(range(68)) + list(rng.integers(0, 68, 10)):
        bad = bytearray(data)
        bad[k] ^= 1 << int(rng.integers(0, 8))
        lines = _receive(receiver, bytes(bad))
        assert not any(line.startswith("accepted") for line in lines), k
        with pytest.raises(ValueError, match="CRC|starts with|117"):
            mc.decode_packet(bytes(bad))
    assert _receive(receiver, data)[0].startswith("accepted")


def test_refusals_say_why(cals, tmp_path, capsys):
    def refused(path, *extra):
        capsys.readouterr()
        assert main(["export", str(path), "--format", "motioncal", "--out", str(tmp_path / "x.bin"), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and not (tmp_path / "x.bin").exists()
        return err

    # the tumble's 2 deg between magnetometer and accelerometer: the packet's symmetric matrix cannot hold it
    assert "rotation is 2." in refused(cals / "t.json") and "--max-rotation-deg" in refused(cals / "t.json")
    # an installed yaw
    err = refused(cals / "inst.json", "--max-rotation-deg", "10")
    assert "installed calibration" in err and "alignment turns the field 3." in err
    # a four-flip bench with nonlinear channels
    doc = json.loads((cals / "bench.json").read_text())
    for channel in doc["channels"].values():
        channel["response"] |= {"model": "cubic", "cubic": 2e-6}
    cubic = tmp_path / "cubic.json"
    cubic.write_text(json.dumps(doc))
    err = refused(cubic, "--max-rotation-deg", "10", "--axes", "v1,v2,v3")
    assert "fourflip calibration" in err and "nonlinear response" in err and "% of |B|" in err
    # the bench's outputs are volts: the receiver reads uT
    assert "not in uT" in refused(cals / "bench.json", "--max-rotation-deg", "10", "--axes", "v1,v2,v3")
    # a tumble recorded in mG: its |B| is not the Earth's in uT, and the unit that fits is named
    doc = json.loads((cals / "t.json").read_text())
    doc["hard_iron"] = [10 * h for h in doc["hard_iron"]]
    doc["field_norm"] *= 10
    in_mg = tmp_path / "mg.json"
    in_mg.write_text(json.dumps(doc))
    err = refused(in_mg, "--max-rotation-deg", "5")
    assert "not the Earth's field" in err and "--unit mgauss" in err
    capsys.readouterr()
    assert main(["export", str(in_mg), "--format", "motioncal", "--max-rotation-deg", "5", "--unit", "mgauss",
                 "--out", str(tmp_path / "ok.bin")]) == 0
    np.testing.assert_allclose(mc.decode_packet((tmp_path / "ok.bin").read_bytes()).field_ut, doc["field_norm"] / 10,
                               rtol=1e-6)
    # six channels (a sensor array): no three-axis form
    assert main(["simulate", "reference", "--out", str(tmp_path / "r.csv")]) == 0
    assert main(["calibrate", str(tmp_path / "r.csv"), "--out", str(tmp_path / "r.json"), "--quiet"]) == 0
    assert "three magnetometer axes, this sensor has 6 channel(s)" in refused(tmp_path / "r.json")


def _board_cal(tmp_path) -> Path:
    from compass.sim.stream_formats import board_model

    path = tmp_path / "board.json"
    path.write_text(json.dumps(model_to_dict(board_model())))
    return path


def test_export_to_a_simulated_motioncal_board_is_echoed_back(tmp_path):
    """The board (compass device --format motioncal) takes the packet as the sketch's receiveCalibration()
    and echoes Cal1:/Cal2:; export reads them back and compares."""
    cal, link = _board_cal(tmp_path), tmp_path / "board"
    with Proc(compass_command("device", "--pty", "--format", "motioncal", "--cal", str(cal), "--link", str(link),
                              "--duration", "60"), kill_after_s=90) as device:
        assert device.wait_for(lambda line: line.strip() == str(link), 30.0), device.transcript()
        with Proc(compass_command("export", str(cal), "--format", "motioncal", "--port", str(link), "--wait", "30"),
                  kill_after_s=60) as export:
            status = export.stop(sig=0, timeout_s=45.0)
        device.stop()
    assert status == 0, export.transcript()
    assert "the device echoes the values sent" in "".join(export.out)
    assert "1 calibration packet(s) taken" in "".join(device.out)


def test_a_device_that_keeps_other_values_is_said(tmp_path):
    """A sketch that echoes but never takes the packet: exit 1 with the first difference."""
    cal = _board_cal(tmp_path)
    packet, _ = packet_of(load(cal))
    other = mc.CalPacket(np.zeros(3), np.zeros(3), np.zeros(3), 50.0, np.eye(3))
    master, slave = os.openpty()
    stop = threading.Event()

    def echo():
        while not stop.wait(0.05):
            try:
                os.write(master, mc.cal_lines(other))
            except OSError:
                return

    os.set_blocking(master, False)
    thread = threading.Thread(target=echo, daemon=True)
    thread.start()
    try:
        status, words = send_packet(os.ttyname(slave), packet, wait_s=1.0)
    finally:
        stop.set()
        thread.join(5.0)
        os.close(master)
        os.close(slave)
    assert status == 1 and "echoes other values" in words and "Cal1[8] 0.000 for 32.000" in words
    # a slow echo, or one to fewer decimals, comes from a device that may have taken it: never "did not take"
    assert "not confirmed that it took the packet" in words and "did not take" not in words


def test_a_device_lost_while_sending_is_a_failure_not_bad_input(tmp_path, capsys):
    """A module unplugged mid-send exited 2, the bad-input code: a lost device is exit 1, not confirmed."""
    cal = _board_cal(tmp_path)
    master, slave = os.openpty()
    os.set_blocking(master, False)
    closed = threading.Event()

    def unplug():  # reads the first bytes of the packet, then goes away as an unplugged USB device does
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            try:
                if os.read(master, 4096):
                    break
            except BlockingIOError:
                time.sleep(0.01)
        os.close(master)
        closed.set()

    thread = threading.Thread(target=unplug, daemon=True)
    thread.start()
    try:
        code = main(["export", str(cal), "--format", "motioncal", "--port", os.ttyname(slave), "--wait", "5"])
    finally:
        thread.join(15.0)
        if not closed.is_set():
            os.close(master)
        os.close(slave)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and "the device was lost (unplugged?); not confirmed that it took the packet" in err[-1]


def test_no_echo_is_not_a_confirmation_and_exits_1(tmp_path, capsys):
    cal = _board_cal(tmp_path)
    packet, _ = packet_of(load(cal))
    master, slave = os.openpty()
    try:
        status, words = send_packet(os.ttyname(slave), packet, wait_s=0.5)
        code = main(["export", str(cal), "--format", "motioncal", "--port", os.ttyname(slave), "--wait", "0.5"])
    finally:
        os.close(master)
        os.close(slave)
    assert status == 1 and "no Cal1:/Cal2: echo in 0.5 s: not confirmed that the device took it" in words
    said = capsys.readouterr()
    assert code == 1 and "not confirmed that the device took it" in said.err and "not confirmed" not in said.out


def test_export_without_out_prints_the_numbers_and_bytes(tmp_path, capsys):
    cal = _board_cal(tmp_path)
    assert main(["export", str(cal), "--format", "motioncal"]) == 0
    out = capsys.readouterr().out
    packet, _ = packet_of(load(cal))
    assert out.strip().splitlines()[-1] == "bytes " + mc.encode_packet(packet).hex(" ")
    assert main(["export", str(cal), "--format", "fusion", "--port", "/dev/null"]) == 2
    assert "--port is for --format motioncal; it does nothing with --format fusion" in capsys.readouterr().err


def test_a_volts_model_is_refused_by_the_motioncal_device(tmp_path, capsys):
    cal = tmp_path / "volts.json"
    cal.write_text(json.dumps(model_to_dict(default_model())))
    assert main(["device", "--pty", "--format", "motioncal", "--cal", str(cal), "--duration", "1"]) == 2
    assert "MotionCal lines carry the field in uT" in capsys.readouterr().err
