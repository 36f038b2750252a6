"""The stream decoders (compass.io.streams, compass.io.fixed_lines, compass.io.motioncal's lines)."""

import io
import math

import numpy as np
import pytest

from compass.io import motioncal as mc
from compass.io.fixed_lines import CsvDecoder, MotionCalDecoder, parse_columns
from compass.io.lines import format_line
from compass.io.streams import (HELD_SHARE, JUDGE_SAMPLES, StreamDecoder, StreamOptions, field_scale_check,
                                held_field_words, time_steps_verdict)
from compass.live import LiveSession
from compass.serial_reader import Chunk
from compass.sim.device import simulate_device, tumble_motion
from compass.sim.stream_formats import CSV_COLUMNS, DEVICE_FORMATS, board_model, sample_lines

CHANNELS = ("mx", "my", "mz")


def test_raw_lines_are_counts_of_the_sketches_units():
    # NXPMotionSense.h: 1/8192 g, 1/16 deg/s, 0.1 uT per count
    d = MotionCalDecoder(CHANNELS)
    lines = b"Raw:-4096,0,8192,16,-32,0,200,-15,-400\r\n" * 3
    s = d.feed(lines)[0]
    np.testing.assert_allclose(s.accel, [-0.5, 0.0, 1.0])
    np.testing.assert_allclose(s.gyro, np.radians([1.0, -2.0, 0.0]))
    np.testing.assert_allclose(s.raw, [20.0, -1.5, -40.0])
    assert d.source == "Raw" and d.stats.samples == 3 and s.t_s is None


def test_a_sketch_printing_raw_and_uni_is_read_from_uni_once_per_sample():
    model = board_model()
    smp = simulate_device(model, np.arange(10) / 100.0, seed=1)
    stream = b"Adafruit AHRS - IMU Calibration!\r\n" + b"".join(
        sample_lines("motioncal", smp.t_s, smp.raw, smp.accel, smp.gyro))
    d = MotionCalDecoder(CHANNELS)
    out = d.feed(stream)
    assert d.source == "Uni" and len(out) == 10  # each sample once: the first from Raw:, the rest from Uni:
    assert d.stats.garbage == 1 and d.stats.comments == 10  # the twins skipped
    np.testing.assert_allclose(out[0].raw, smp.raw[0], atol=0.05 + 1e-9)  # half a count of 0.1 uT
    # Uni: prints uT with 2 decimals, m/s^2 with 2 and rad/s with 4
    np.testing.assert_allclose([s.raw for s in out[1:]], smp.raw[1:], atol=0.005 + 1e-9)
    np.testing.assert_allclose([s.accel for s in out[1:]], smp.accel[1:], atol=0.005 / mc.STANDARD_GRAVITY + 1e-9)
    np.testing.assert_allclose([s.gyro for s in out[1:]], smp.gyro[1:], atol=5e-5 + 1e-9)


def test_raw_only_sketch_quantises_to_its_counts():
    model = board_model()
    smp = simulate_device(model, np.arange(10) / 100.0, seed=1)
    d = MotionCalDecoder(CHANNELS)
    out = d.feed(b"".join(sample_lines("motioncal-raw", smp.t_s, smp.raw, smp.accel, smp.gyro)))
    assert d.source == "Raw" and len(out) == 10
    np.testing.assert_allclose([s.raw for s in out], smp.raw, atol=0.05 + 1e-9)  # half a 0.1 uT count
    np.testing.assert_allclose([s.accel for s in out], smp.accel, atol=0.5 / 8192 + 1e-12)
    np.testing.assert_allclose([s.gyro for s in out], smp.gyro, atol=math.radians(0.5 / 16) + 1e-12)


def test_a_raw_line_comes_out_as_it_arrives():
    d = StreamDecoder(CHANNELS)
    assert [s.raw.tolist() for s in d.feed(b"Raw:0,0,8192,0,0,0,200,0,-400\r\n")] == [[20.0, 0.0, -40.0]]
    assert d.describe() == "MotionCal Raw: lines"


def test_bad_motioncal_lines_are_counted_never_fatal():
    d = StreamDecoder(CHANNELS, StreamOptions(format="motioncal"))
    good = b"Raw:0,0,8192,0,0,0,200,0,-400\r\n"
    bad = (b"Raw:0,0,8192,0,0,0,200,0\r\n"  # a cell short: partial
           b"Raw:0,0,8192,0,0,0,200,0,-400,7\r\n"  # a cell too many: garbage
           b"Raw:0,0,99999,0,0,0,200,0,-400\r\n"  # out of int16, as MotionCal refuses it: garbage
           b"Raw:0,0,8x92,0,0,0,200,0,-400\r\n"  # not a number: garbage
           b"\xff\xfe\x00Raw:\r\n"  # binary noise: garbage
           b"Wrote calibration\r\n")  # the sketch talking: garbage
    out = d.feed(good * 3 + bad + good)
    assert len(out) == 4 and d.fatal is None
    assert (d.stats.partial, d.stats.garbage) == (1, 5)


def test_cal_echoes_are_kept_and_compared_to_the_decimals_printed():
    packet = mc.CalPacket(np.zeros(3), np.zeros(3), np.array([18.25, -11.5, 32.0]), 49.7,
                          np.array([[1.02, 0.01, -0.02], [0.01, 0.97, 0.003], [-0.02, 0.003, 1.01]]))
    d = MotionCalDecoder(CHANNELS)
    d.feed(mc.cal_lines(packet))
    ok, words = mc.echo_matches(packet, d.echo["Cal1"], d.echo["Cal2"])
    assert ok, words
    other = mc.CalPacket(packet.accel_zero_g, packet.gyro_zero_rate, packet.hard_iron_ut + [0.002, 0, 0],
                         packet.field_ut, packet.soft_iron)
    ok, words = mc.echo_matches(other, d.echo["Cal1"], d.echo["Cal2"])
    assert not ok and "Cal1[6]" in words  # 2e-3 uT is four times what 3 decimals round away


def test_csv_columns_name_sign_and_time_unit():
    d = CsvDecoder(CHANNELS, columns=parse_columns("t_ms,ax,ay,az,skip,mx,my,-mz"))
    s = d.feed(b"1500;0;0;1;42;10;20;30\r\n1510 0 0 1 42 10 20 30\r\n1520,0,0,1,42,10,20,30\r\n")
    assert len(s) == 3 and s[0].t_s == 1.5 and s[0].raw.tolist() == [10.0, 20.0, -30.0] and s[0].gyro is None
    assert "skip" in d.header.ignored


def test_csv_bad_lines_are_counted():
    d = CsvDecoder(CHANNELS, columns=("mx", "my", "mz"))
    out = d.feed(b"1 2 3\r\n1 2\r\n1 2 3 4\r\nmx my mz\r\n1 x 3\r\nnan 2 3\r\n# a comment\r\n4 5 6\r\n1e300 2 3\r\n")
    assert len(out) == 2
    s = d.stats
    assert (s.partial, s.garbage, s.invalid, s.comments) == (1, 3, 2, 1)  # 1e300: no sensor reads it (as the protocol)


def test_csv_columns_without_the_calibration_channels_is_fatal():
    d = StreamDecoder(("a", "b", "c"), StreamOptions(columns=("t_s", "mx", "my", "mz")))
    assert "--columns names t_s,mx,my,mz, not the calibration's channel(s) a,b,c" in d.fatal


@pytest.mark.parametrize("kwargs, match", [
    ({"format": "csv"}, "--format csv needs --columns"),
    ({"format": "motioncal", "columns": ("mx",)}, "--columns names the cells of a headerless"),
    ({"format": "motioncal", "mag_unit": "mG"}, "MotionCal lines have fixed units"),
    ({"mag_unit": "furlong"}, "--mag-unit must be one of"),
    ({"format": "binary"}, "--format must be one of"),
])
def test_contradicting_options_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        StreamOptions(**kwargs)


def test_parse_columns_refuses_repeats_and_empty_names():
    with pytest.raises(ValueError, match="named twice"):
        parse_columns("t_s,mx,t_ms")
    with pytest.raises(ValueError, match="expected names"):
        parse_columns("mx,,mz")


def test_auto_finds_each_format_and_says_it():
    header = format_line(["t_s", "mx", "my", "mz"])
    for stream, fmt in ((b"1.0,2,3,4\r\n" + header + format_line(["1.1", 2, 3, 4]), "compass"),
                        (b"hello\r\nCal1:0,0,0,0,0,0,0,0,0,50\r\n", "motioncal")):
        d = StreamDecoder(CHANNELS)
        d.feed(stream)
        assert d.format == fmt and any(f"stream format: {fmt}" in t for _, t in d.drain_events())
    d = StreamDecoder(CHANNELS)
    out = d.feed(b"1.0,2,3,4\r\n" + header + format_line(["1.1", 2, 3, 4]))
    assert len(out) == 1 and d.stats.unheaded == 1  # the line before the header, as the protocol counts it


def test_auto_says_bare_numbers_need_columns():
    d = StreamDecoder(CHANNELS)
    for k in range(40):
        d.feed(b"0.1 0.2 0.3 1 2 3\r\n", t_rx=k * 0.1)
    assert d.format is None and "bare numbers without a header" in d.fatal and "--columns" in d.fatal
    d = StreamDecoder(CHANNELS)
    d.feed(b"\x00\xfe noise at the wrong baud rate\r\n" * 5, t_rx=0.0)
    assert d.fatal is None and d.stats.garbage == 5  # noise is counted, the wait goes on


def test_a_reconnect_before_the_format_is_known_counts_what_it_drops():
    d = StreamDecoder(CHANNELS)
    d.feed(b"1,2,3\r\n4,5")
    d.resync()
    assert (d.stats.unheaded, d.stats.partial) == (1, 1)
    d.feed(format_line(["mx", "my", "mz"]) + b"7,8,9\r\n")
    assert d.format == "compass"


def test_a_log_header_names_the_columns_and_their_units_as_the_file_readers_read_it():
    """x-io's header (the logs in shared/data/xio-fusion): its cells are the columns, its units converted; the line
    after it is whole even after a reconnect; a unit the user names wins, as in the file readers."""
    header = b"Time (s),Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s),Accelerometer X (g)," \
             b"Accelerometer Y (g),Accelerometer Z (g),Magnetometer X (uT),Magnetometer Y (uT),Magnetometer Z (uT)\r\n"
    row = b"0.01,90,0,0,0,0,1,20,0,-40\r\n"
    d = StreamDecoder(CHANNELS)
    d.resync()
    out = d.feed(header + row)
    assert d.format == "csv" and d.describe() == "csv t_s,gx,gy,gz,ax,ay,az,mx,my,mz" and d.fatal is None
    assert len(out) == 1 and d.stats.garbage == d.stats.partial == 0
    np.testing.assert_allclose(out[0].gyro, [np.pi / 2, 0.0, 0.0])
    np.testing.assert_allclose(out[0].raw, [20.0, 0.0, -40.0])
    assert out[0].t_s == 0.01
    assert any("log header" in t and "gyro in deg/s" in t for _, t in d.drain_events())
    d = StreamDecoder(CHANNELS)  # a header's tail after a reconnect is no header (it named 'scope Z (deg/s)' a column)
    d.resync()
    d.feed(header[header.index(b"scope Z"):] + row + header + row)
    assert d.describe() == "csv t_s,gx,gy,gz,ax,ay,az,mx,my,mz"  # the whole header's, read after the cut one
    assert d.stats.partial == 2  # the cut header, and the row after it (untrusted before a header, as any)
    d = StreamDecoder(CHANNELS)  # our names beside a log's, first after a connect: whole (the audit's case)
    d.resync()
    d.feed(b"t_s,Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s),mx,my,mz\r\n" + b"0.01,90,0,0,20,0,-40\r\n")
    assert d.describe() == "csv t_s,gx,gy,gz,mx,my,mz" and d.stats.partial == 0
    d = StreamDecoder(CHANNELS, StreamOptions(gyro_unit="rad/s"))
    np.testing.assert_allclose(d.feed(header + row)[0].gyro, [90.0, 0.0, 0.0])
    d = StreamDecoder(CHANNELS)
    d.feed(b"Time (ms),Accelerometer X (g),Accelerometer Y (g),Accelerometer Z (g)\r\n1,0,0,1\r\n")
    assert d.format is None  # no magnetometer named: not a log header of ours (nothing adopted)


def test_a_log_header_sent_again_in_another_order_is_read_from_there_and_unicode_units_are_read():
    """A module that restarts with other firmware sends its header again, mag before gyro: the lines after it are
    read in its order (they were read in the old one, 105 deg RMS of heading off); units written with ° and µ are
    read as the file readers read them."""
    first = "Time (s),Gyroscope X (°/s),Gyroscope Y (°/s),Gyroscope Z (°/s),Magnetometer X (µT),Magnetometer Y (µT)," \
            "Magnetometer Z (µT)\r\n"
    again = "Time (s),Magnetometer X (mG),Magnetometer Y (mG),Magnetometer Z (mG),Gyroscope X (°/s)," \
            "Gyroscope Y (°/s),Gyroscope Z (°/s)\r\n"
    d = StreamDecoder(CHANNELS)
    out = d.feed((first + "0.0,90,0,0,20,0,-40\r\n" + again + "0.01,200,0,-400,0,90,0\r\n").encode("utf-8"))
    assert d.format == "csv" and len(out) == 2 and d.stats.garbage == 0
    np.testing.assert_allclose(out[0].gyro, [np.pi / 2, 0.0, 0.0])
    np.testing.assert_allclose(out[1].gyro, [0.0, np.pi / 2, 0.0])
    np.testing.assert_allclose(out[0].raw, [20.0, 0.0, -40.0])
    np.testing.assert_allclose(out[1].raw, [20.0, 0.0, -40.0])  # 200 mG is 20 uT
    assert any(level == "warn" and "log header came again" in t for level, t in d.drain_events())
    d = StreamDecoder(CHANNELS)
    d.feed((first + "0.0,90,0,0,20,0,-40\r\n" + first + "0.01,90,0,0,20,0,-40\r\n").encode("utf-8"))
    assert not any("came again" in t for _, t in d.drain_events()) and d.stats.garbage == 0  # the same: no word
    d = StreamDecoder(CHANNELS)  # the same columns in other units: the samples after it in those (review)
    out = d.feed((first + "0.0,90,0,0,20,0,-40\r\n" + first.replace("µT", "mG") + "0.01,90,0,0,200,0,-400\r\n")
                 .encode("utf-8"))
    np.testing.assert_allclose([s.raw for s in out], [[20.0, 0.0, -40.0]] * 2)


def test_named_units_are_converted():
    d = StreamDecoder(CHANNELS, StreamOptions(columns=("mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"),
                                              mag_unit="mG", accel_unit="m/s2", gyro_unit="deg/s"))
    s = d.feed(b"500,0,-100,0,0,9.80665,90,0,0\r\n")[0]
    np.testing.assert_allclose(s.raw, [50.0, 0.0, -10.0])
    np.testing.assert_allclose(s.accel, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(s.gyro, [np.pi / 2, 0.0, 0.0])


def _stream_samples(model, unit_factor=1.0, magnet=0.0, n=JUDGE_SAMPLES, seed=0):
    smp = simulate_device(model, np.arange(n) / 100.0, seed=seed)
    raw = smp.raw + magnet * np.array([1.0, 0.0, 0.0])
    return b"".join(format_line(["mx", "my", "mz"]) if k == 0 else b"" for k in range(1)) + b"".join(
        format_line([f"{v * unit_factor:.6g}" for v in row]) for row in raw)


def test_a_stream_in_mg_against_a_calibration_in_ut_is_said_with_its_factor():
    model = board_model()
    d = StreamDecoder(CHANNELS, field_check=field_scale_check(model))
    out = d.feed(_stream_samples(model, unit_factor=10.0))
    assert out == [] and d.fatal is not None
    assert "scaled by 0.1" in d.fatal and "mG taken as uT" in d.fatal and "--mag-unit" in d.fatal
    assert d.feed(_stream_samples(model, unit_factor=10.0)) == []  # nothing is ever handed out
    # named, it is converted and taken
    d = StreamDecoder(CHANNELS, StreamOptions(mag_unit="mG"), field_check=field_scale_check(model))
    assert len(d.feed(_stream_samples(model, unit_factor=10.0))) == JUDGE_SAMPLES and d.fatal is None


def test_a_magnet_is_not_a_unit():
    model = board_model()
    d = StreamDecoder(CHANNELS, field_check=field_scale_check(model))
    out = d.feed(_stream_samples(model, magnet=60.0))  # |B| about doubled: no unit's factor explains it
    assert len(out) == JUDGE_SAMPLES and d.fatal is None


@pytest.mark.parametrize("t_s, words", [
    (np.full(25, 3.0), "t_s is 3 in all 25 samples"),
    (10.0 * np.arange(25), "t_s steps by 10 s (median of 25 samples)"),
    (np.r_[0.0, 0.01, 0.02, 0.01, 0.0], None),  # back to its first value: not every value the same
    (0.01 * np.arange(25), None),
    (np.array([7.0]), None),
])
def test_time_steps_verdict(t_s, words):
    """A t_s with every value the same, or a median step over max_gap_s (0.5 s), is said; a running one is not."""
    verdict = time_steps_verdict(t_s, 0.5)
    assert verdict is None if words is None else words in verdict


def test_fewer_samples_than_the_check_are_judged_at_the_end():
    model = board_model()
    d = StreamDecoder(CHANNELS, field_check=field_scale_check(model))
    assert d.feed(_stream_samples(model, n=5)) == []
    assert len(d.flush()) == 5
    d = StreamDecoder(CHANNELS, field_check=field_scale_check(model))
    d.feed(_stream_samples(model, unit_factor=1000.0, n=5))
    assert d.flush() == [] and "nT taken as uT" in d.fatal


def test_an_accelerometer_unit_that_does_not_read_1_g_is_warned():
    d = StreamDecoder(CHANNELS, StreamOptions(columns=("mx", "my", "mz", "ax", "ay", "az"), accel_unit="g"))
    d.feed(b"1,2,3,0,0,9.81\r\n" * 60)
    warnings = [t for level, t in d.drain_events() if level == "warn"]
    assert len(warnings) == 1 and "9.81 g" in warnings[0] and "--accel-unit" in warnings[0]


def test_a_deg_per_s_gyro_read_as_rad_per_s_is_a_fault_live_stops_on():
    model = board_model()
    t = np.arange(1200) / 100.0
    smp = simulate_device(model, t, seed=3, motion=tumble_motion)  # turned briskly: tilts of 5 deg in 0.25 s
    columns = ("t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz")

    def decoded(gyro):
        d = StreamDecoder(CHANNELS, StreamOptions(columns=columns))
        rows = np.column_stack([t, smp.raw, smp.accel, gyro])
        d.feed(b"".join((",".join(f"{v:.7g}" for v in r) + "\r\n").encode() for r in rows))
        return d.gyro_fault, [text for level, text in d.drain_events() if level == "warn"]

    assert decoded(smp.gyro) == (None, [])
    fault, said = decoded(np.degrees(smp.gyro))
    assert said == [] and "times more" in fault and "give --gyro-unit deg/s" in fault

    def labelled(gyro, options=StreamOptions()):  # a log header labels the gyro deg/s: the replay's judgement
        d = StreamDecoder(CHANNELS, options)
        header = "Time (s),mx,my,mz,ax,ay,az,Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s)\r\n"
        rows = np.column_stack([t, smp.raw, smp.accel, gyro])
        d.feed(header.encode() + b"".join((",".join(f"{v:.7g}" for v in r) + "\r\n").encode() for r in rows))
        return d.gyro_fault

    assert labelled(np.degrees(smp.gyro)) is None  # deg/s as labelled: fused
    assert "times less" in labelled(smp.gyro) and "give --gyro-unit rad/s" in labelled(smp.gyro)  # rad/s so labelled
    assert labelled(smp.gyro, StreamOptions(gyro_unit="deg/s")) is None  # named by the user: warned, not stopped


def test_device_formats_are_the_commands_choices():
    from compass.commands.device import DEVICE_FORMATS as listed

    assert listed == DEVICE_FORMATS and CSV_COLUMNS[0] == "t_s"


# ------------------------------------------------------------------ the same attitude from every format

def _attitudes(model, stream: bytes, t_rx, options=None) -> np.ndarray:
    """heading, pitch, roll (deg) per sample of a LiveSession fed one line's bytes at a time at ``t_rx``."""
    out = io.StringIO()
    session = LiveSession(model, out=out, stream=options)  # no "connected" event: the first line is whole
    for t, chunk in zip(t_rx, stream):
        session.feed(Chunk(float(t), chunk))
    session.close()
    assert session.decoder.fatal is None and session.decoder.stats.dropped == 0
    lines = [line for line in out.getvalue().splitlines() if not line.startswith("#")]
    names = lines[0].split(",")
    rows = np.loadtxt(lines[1:], delimiter=",", ndmin=2)
    return rows[:, [names.index(c) for c in ("heading_deg", "pitch_deg", "roll_deg", "heading_sigma_deg")]]


def _wrap(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def test_motioncal_and_csv_streams_give_the_attitude_of_the_same_samples_in_our_protocol():
    """Our protocol's stream carries no t_s here (MotionCal has none): samples are dated by their arrival, the same
    in every session."""
    model = board_model()
    t = np.arange(1500) / 100.0  # the script's still start, the first turn with pitch
    smp = simulate_device(model, t, seed=5)
    ours = [format_line(["seq", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"])
            + format_line([k, *(f"{v:.7g}" for v in (*m, *a, *g))])
            for k, (m, a, g) in enumerate(zip(smp.raw, smp.accel, smp.gyro))]
    reference = _attitudes(model, ours, t)
    assert len(reference) == len(t)

    csv = sample_lines("csv", t, smp.raw, smp.accel, smp.gyro)
    same = _attitudes(model, csv, t, StreamOptions(columns=CSV_COLUMNS))
    # the CSV also carries t_s (the module's own clock, equal to the arrival times here) and prints its gyro with
    # 6 decimals (ours: 7 digits): the same attitude to one unit of the output's last digit (3 decimals)
    np.testing.assert_allclose(_wrap(same[:, 0] - reference[:, 0]), 0.0, atol=1.001e-3)
    np.testing.assert_allclose(same[:, 1:3], reference[:, 1:3], atol=1.001e-3)

    # MotionCal's lines carry the samples quantised (Raw: 0.1 uT, 1/16 deg/s, 1/8192 g; Uni: 0.01 uT, 1e-4 rad/s,
    # 0.01 m/s^2): the same quantised samples in our protocol give the same attitude
    for fmt in ("motioncal-raw", "motioncal"):
        lines = sample_lines(fmt, t, smp.raw, smp.accel, smp.gyro)
        decoded = MotionCalDecoder(CHANNELS).feed(b"".join(lines))
        assert len(decoded) == len(t)
        quantised = [format_line(["seq", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"])
                     + format_line([k, *(f"{v:.9g}" for v in (*d.raw, *d.accel, *d.gyro))])
                     for k, d in enumerate(decoded)]
        got, want = _attitudes(model, lines, t), _attitudes(model, quantised, t)
        np.testing.assert_allclose(_wrap(got[:, 0] - want[:, 0]), 0.0, atol=1.001e-3)
        np.testing.assert_allclose(got[:, 1:3], want[:, 1:3], atol=1.001e-3)
        # and the quantisation costs no accuracy the filter does not own: after its first second, the heading's
        # RMS error against the truth stays within the 1-sigma it reports (0.18-0.43 deg against 0.64, seeds 5-7)
        settled = t >= 1.0
        rms = np.sqrt(np.mean(_wrap(got[settled, 0] - smp.heading_deg[settled]) ** 2))
        assert rms < np.mean(got[settled, 3]), (fmt, rms)


def test_the_live_tumble_collects_the_same_samples_from_every_format(tmp_path):
    """`live --calibrate tumble` keeps what it calibrates as a recording: the same one from each format (so
    `compass calibrate` makes the same calibration of it)."""
    from calibrate.tumble.collector import TumbleCollector

    model = board_model()
    t = np.arange(400) / 100.0
    smp = simulate_device(model, t, seed=9, motion=tumble_motion)

    def recording(lines, options, name):
        collector = TumbleCollector(stream=options)  # no "connected" event: the first line is whole
        for tt, chunk in zip(t, lines):
            collector.feed(Chunk(float(tt), chunk))
        collector.finish()
        assert collector.decoder.stats.dropped == 0 and len(collector.rows) == len(t)
        return collector.write_recording(tmp_path / name).read_text().splitlines()[1:]  # after the source line

    raw_lines = sample_lines("motioncal-raw", t, smp.raw, smp.accel, smp.gyro)
    decoded = MotionCalDecoder(CHANNELS).feed(b"".join(raw_lines))
    ours = [format_line(["mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"])
            + format_line([f"{v:.9g}" for v in (*d.raw, *d.accel, *d.gyro)]) for d in decoded]
    assert recording(raw_lines, None, "raw.csv") == recording(ours, None, "ours.csv")
    csv = sample_lines("csv", t, smp.raw, smp.accel, smp.gyro)
    plain = [format_line(["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"])
             + format_line([f"{tt:.4f}", *(f"{v:.7g}" for v in m), *(f"{v:.6f}" for v in (*a, *g))])
             for tt, m, a, g in zip(t, smp.raw, smp.accel, smp.gyro)]
    assert recording(csv, StreamOptions(columns=CSV_COLUMNS), "csv.csv") == recording(plain, None, "plain.csv")


def test_the_first_line_after_a_reconnect_is_trusted_only_when_it_shows_its_start():
    csv = CsvDecoder(CHANNELS, columns=CHANNELS)
    csv.resync()
    assert len(csv.feed(b"45 2 3\r\n1 2 3\r\n")) == 1 and csv.stats.partial == 1  # "45" may be the tail of "12.345"
    mcd = MotionCalDecoder(CHANNELS)
    mcd.resync()
    assert len(mcd.feed(b"Raw:0,0,8192,0,0,0,200,0,-400\r\n")) == 1  # a tagged line starts where it starts
    mcd.resync()
    assert mcd.feed(b"0,0,0,0,200,0,-400\r\n") == [] and mcd.stats.partial == 1


def test_held_field_words_say_the_share_and_both_rates_and_nothing_below_the_share():
    rng = np.random.default_rng(4)
    t = np.arange(300) / 200.0
    fresh = rng.normal(size=(300, 3))
    assert held_field_words(fresh, t) is None
    held = fresh[np.arange(300) // 4 * 4]  # 50 Hz in 200 Hz rows: 3 of 4 rows repeat
    words = held_field_words(held, t)
    assert "75 % of the first 300 rows" in words and "every 20 ms, at 200 Hz rows" in words
    assert "ms" not in held_field_words(held)  # no times: the share only
    few = fresh.copy()
    few[1:int(HELD_SHARE * 300) - 5] = few[0]  # just under the share
    assert held_field_words(few, t) is None
