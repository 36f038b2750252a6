"""The bench station in lock step with a simulated bench: each angle source to a calibration, and the
mistakes an operator or a module makes, said in words."""

from __future__ import annotations

import re

import numpy as np
import pytest

from calibrate import calibrate_fourflip
from calibrate.fourflip._mlfit import cramer_rao
from compass.io.fourflip import read_fourflip
from compass.io.stream_options import StreamOptions
from compass.sim.bench import BenchSamples
from compass.sim.bench_rig import BenchRig, Operator, drive
from compass.station import SessionEnded, SessionStore, Station, StationStream, parse_turntable
from compass.station.checks import circle_axis, coverage_gap, face_name, is_still, nearest_face, up_in_housing


def run_session(tmp_path, spec, rig, *, max_s=600.0, on_block=None):
    """Drive a session (``on_block(rig, t_s, station)`` before each block); return (station, events, recording or
    None)."""
    source = parse_turntable(spec)
    stream = StationStream(getattr(source, "column", None))
    store = SessionStore(tmp_path / "cal.json")
    store.start({})
    station = Station(source, rig.channels, on_flip=store.save)
    events = []
    original = station.drain

    def block(r, t):
        events.extend(original())
        if on_block is not None:
            on_block(r, t, station)

    drive(rig, station, stream, max_s=max_s, on_block=block)
    events.extend(station.drain())
    recording = read_fourflip(store.write_recording({"turntable": spec})) if station.finished else None
    return station, events, recording


def direction_error_over_crb(rig, recording, samples_per_row=1):
    """Per channel: angle between the ml fit's direction and the truth over the CRB of the same rows at
    their true angles (the rig's pose at each row's time; a row averaging n samples has noise / sqrt(n))."""
    result = calibrate_fourflip(recording, method="ml")
    truth = np.asarray(rig.truth["directions"])
    error = np.degrees(np.arccos(np.clip(np.sum(result.directions * truth, axis=1), -1.0, 1.0)))
    phi, kappa, _, _ = rig.pose(recording.t_s)
    samples = BenchSamples(np.mod(phi, 360.0), np.mod(np.round(kappa), 360.0), recording.flip_index)
    per_row = rig.noise / np.sqrt(samples_per_row)
    crb, _ = cramer_rao(rig.physics, samples, recording.channels, per_row)
    return error / crb, error


def test_faces_and_the_circle_axis():
    assert face_name(0) == "+Z up (the -Z face on the table)"
    assert face_name(270) == "-Y up (the +Y face on the table)"
    assert nearest_face(up_in_housing(180))[0] == "-Z"
    rig = BenchRig(seed=3)
    phi = np.arange(0.0, 360.0, 5.0)
    for flip in (0.0, 90.0, 180.0, 270.0):
        from compass.sim.bench import bench_outputs

        outputs = bench_outputs(rig.physics, BenchSamples(phi, np.full(phi.size, flip), np.zeros(phi.size, int)))
        assert nearest_face(circle_axis(phi, outputs))[0] == nearest_face(up_in_housing(flip))[0]
    assert circle_axis(phi, np.zeros((phi.size, 2))) is None


def test_stillness_and_coverage():
    rng = np.random.default_rng(0)
    t = np.arange(100) / 100.0
    noise = rng.normal(scale=0.01, size=(100, 3))
    assert is_still(t, noise)
    assert not is_still(t, noise + np.outer(t, [0.0, 0.05, 0.0]))  # a slow ramp, 5x the noise over the window
    covered, gap, start = coverage_gap(np.r_[np.arange(0.0, 200.0, 1.0), np.arange(260.0, 360.0, 1.0)])
    assert (covered, gap, start) == (299.0, 61.0, 199.0)  # 360 less the widest gap


@pytest.mark.parametrize("spec, rig_options, bound", [
    ("column:enc", {"encoder_step_deg": 0.0}, 2.5),  # exact encoder: at the CRB (a single session: rms over 3)
    ("gyro", {"gyro_bias_dps": 0.5, "gyro_scale_error": 0.01}, 12.0),
    ("manual:30", {"operator": Operator(read_half_width_deg=0.5)}, 12.0),
])
def test_each_source_calibrates_a_simulated_bench(tmp_path, spec, rig_options, bound):
    rig = BenchRig(seed=11, **rig_options)
    station, events, recording = run_session(tmp_path, spec, rig)
    assert station.finished, events
    assert not [e for e in events if e[0] == "warn"], events
    assert recording.metadata["turntable"] == spec
    ratio, error = direction_error_over_crb(rig, recording, rig.rate_hz if spec.startswith("manual") else 1)
    assert np.sqrt(np.mean(ratio**2)) < bound, (ratio, error)


def test_a_short_turn_is_said_and_redone(tmp_path):
    rig = BenchRig(seed=4, encoder_step_deg=0.1, operator=Operator(mistakes=("short_turn",)))
    station, events, recording = run_session(tmp_path, "column:enc", rig)
    redo = [text for level, text in events if "redo" in text]
    assert len(redo) == 1 and "flip 180: the turn stopped short: 300 of 360 deg covered" in redo[0], events
    assert station.finished and set(recording.flip_index) == {0, 1, 2, 3}


def test_a_short_gyro_turn_is_said_and_redone(tmp_path):
    rig = BenchRig(seed=5, gyro_bias_dps=0.5, operator=Operator(mistakes=("short_turn",)))
    station, events, _ = run_session(tmp_path, "gyro", rig)
    redo = [text for level, text in events if "redo" in text]
    assert len(redo) == 1, events
    # 300 deg, read by a gyro with a 1 % scale error
    assert re.search(r"flip 180: the turn was about (29[5-9]|30[0-5]) deg, not one full turn", redo[0])
    assert station.finished


def test_the_wrong_face_down_is_said_and_waited_for(tmp_path):
    rig = BenchRig(seed=6, encoder_step_deg=0.1, operator=Operator(mistakes=("wrong_face",)))
    station, events, recording = run_session(tmp_path, "column:enc", rig)
    wrong = [text for level, text in events if "wrong face" in text]
    assert len(wrong) == 1, events
    assert "the accelerometer shows -Y up; flip 90 needs +Y up (the -Y face on the table)" in wrong[0]
    assert station.finished
    # the flip 90 rows are the right face: gravity along +Y
    assert recording.accel[recording.flip_index == 1].mean(axis=0) == pytest.approx([0, 1, 0], abs=0.01)


def test_without_an_accelerometer_the_wrong_face_shows_in_the_field_circle(tmp_path):
    rig = BenchRig(seed=6, encoder_step_deg=0.1, operator=Operator(mistakes=("wrong_face",)))
    rig.send_accel = False
    station, events, _ = run_session(tmp_path, "column:enc", rig)
    wrong = [text for level, text in events if "wrong face" in text]
    assert len(wrong) == 1 and "the field's circle shows -Y up; flip 90 needs +Y up" in wrong[0], events
    assert station.finished


def test_a_rate_change_ends_the_session_and_keeps_the_flips(tmp_path):
    rig = BenchRig(seed=7, encoder_step_deg=0.1)

    def halve_at_flip_180(r, t, station):
        if station_flips() >= 2 and r.rate_hz == 100.0:
            r.rate_hz = 50.0

    store_dir = tmp_path
    station_flips = lambda: len(list(store_dir.glob("cal.flips/flip_*.csv")))  # noqa: E731
    with pytest.raises(SessionEnded, match="sample rate changed from 100 Hz to 50 Hz during flip 180; "
                                           "flips kept: 0, 90"):
        run_session(tmp_path, "column:enc", rig, on_block=halve_at_flip_180)
    assert sorted(SessionStore(tmp_path / "cal.json").finished()) == [0.0, 90.0]


def test_a_header_change_ends_the_session():
    rig = BenchRig(seed=8, encoder_step_deg=0.1)
    stream = StationStream("enc")
    assert len(stream.feed(rig.header() + rig.lines(np.arange(10) / 100.0))) == 10
    rig.send_accel = False
    with pytest.raises(SessionEnded, match=r"header changed from t_s,seq,v1,v2,v3,ax,ay,az,gx,gy,gz,enc to "
                                           r"t_s,seq,v1,v2,v3,gx,gy,gz,enc"):
        stream.feed(rig.header() + rig.lines(np.arange(10, 20) / 100.0))


def test_an_encoder_column_missing_from_the_header_is_said():
    rig = BenchRig(seed=8)
    with pytest.raises(SessionEnded, match="has no column 'angle' \\(--turntable column:angle\\)"):
        StationStream("angle").feed(rig.header())


@pytest.mark.parametrize("text, message", [
    ("manual:7", "the step must divide 360"),
    ("manual:x", "expected manual:STEP_DEG"),
    ("column:", "needs the encoder column's name"),
    ("laser", "unknown source"),
    ("grbl:", "needs the GRBL controller's port"),
])
def test_bad_turntable_sources(text, message):
    with pytest.raises(ValueError, match=message):
        parse_turntable(text)


def test_an_interactive_session_waits_for_enter():
    rig = BenchRig(seed=9, encoder_step_deg=0.1)
    stream = StationStream("enc")
    station = Station(parse_turntable("column:enc"), rig.channels, ask=True)
    for reading in stream.feed(rig.header() + rig.lines(np.arange(300) / 100.0)):
        station.feed(reading)
    assert station.instruction.do == "flip"  # still and the right face, but nobody pressed Enter
    station.confirm()
    for reading in stream.feed(rig.lines(np.arange(300, 320) / 100.0)):
        station.feed(reading)
    assert station.instruction.do == "turn"


@pytest.mark.parametrize("fmt, options, channels", [
    ("csv", StreamOptions(columns=("t_s", "v1", "v2", "v3", "ax", "ay", "az", "gx", "gy", "gz"), gyro_unit="deg/s"),
     ("v1", "v2", "v3")),
    ("motioncal", StreamOptions(), ("mx", "my", "mz")),
])
def test_the_same_session_in_another_stream_format_gives_the_same_calibration(tmp_path, fmt, options, channels):
    """The rig's noise is drawn per sample time, so the same seed in lock step is the same session: only the
    format's resolution differs, and its clock (MotionCal's lines carry none and are dated on arrival).
    MotionCal's Uni: lines hold 0.01 uT (a noise 0.003 uT against the channels' 0.15 uT: 0.02 sigma) and 1e-4 rad/s
    (3e-5 rad/s RMS against the gyro's 8.7e-4: about 3 % more angle noise, so 3 % of the gyro source's 0.046 deg
    RMS angle cost, tools/bench_station.py): the directions move by about 0.0015 deg; 0.005 deg bounds it."""
    results = []
    for f, opts, names in (("compass", StreamOptions(), None), (fmt, options, channels)):
        rig = BenchRig(seed=12, gyro_bias_dps=0.5, gyro_scale_error=0.01, fmt=f)
        folder = tmp_path / f
        folder.mkdir()
        store = SessionStore(folder / "cal.json")
        store.start({})
        station = Station(parse_turntable("gyro"), names or rig.channels, on_flip=store.save)
        stream = StationStream(None, options=opts)
        drive(rig, station, stream, max_s=300.0)
        assert station.finished and stream.format == f, station.drain() + stream.drain()
        assert not [e for e in station.drain() + stream.drain() if e[0] == "warn"]
        results.append(calibrate_fourflip(read_fourflip(store.write_recording({})), method="ml"))
    ours, theirs = results
    moved = np.degrees(np.arccos(np.clip(np.sum(ours.directions * theirs.directions, axis=1), -1.0, 1.0)))
    assert np.all(moved < 0.005), moved


def test_a_stream_the_station_cannot_read_is_said():
    rig = BenchRig(seed=8, fmt="csv")
    with pytest.raises(SessionEnded, match="bare numbers without a header .* name its cells with --columns"):
        StationStream(None).feed(rig.lines(np.arange(600) / 100.0), 6.0)
    with pytest.raises(SessionEnded, match="MotionCal lines carry no encoder column 'enc'"):
        StationStream("enc").feed(BenchRig(seed=8, fmt="motioncal").lines(np.arange(3) / 100.0), 0.03)
    with pytest.raises(SessionEnded, match=r"--columns t_s,ax,ay,az has no magnetic channel"):
        StationStream(None, options=StreamOptions(columns=("t_s", "ax", "ay", "az"))).feed(b"0 0 0 1\n")


def test_mag_unit_converts_the_field_but_not_the_encoder():
    rig = BenchRig(seed=8, encoder_step_deg=0.1, fmt="csv")
    columns = rig.csv_columns()
    data = rig.lines(np.arange(5) / 100.0)
    as_sent = StationStream("enc", options=StreamOptions(columns=columns, gyro_unit="deg/s")).feed(data)
    in_mg = StationStream("enc", options=StreamOptions(columns=columns, gyro_unit="deg/s", mag_unit="mG")).feed(data)
    assert [r.encoder_deg for r in in_mg] == [r.encoder_deg for r in as_sent]
    assert np.allclose([r.outputs for r in in_mg], 0.1 * np.array([r.outputs for r in as_sent]))
    cells = np.array([line.split() for line in data.decode().splitlines()], float)
    gx = columns.index("gx")
    assert np.allclose([r.gyro for r in as_sent], np.radians(cells[:, gx:gx + 3]))  # --gyro-unit deg/s


def run_grbl_session(tmp_path, rig, controller, **source_options):
    """Drive a session of the station's GRBL source against ``controller`` in process, in lock step (the host's clock
    is the module's); return (station, events, recording or None).

    Raises
    ------
    SessionEnded
        As the station does.
    """
    from compass.sim.grbl import LoopbackPort
    from compass.station.grbl import GrblSource

    rig.operator_turns = False
    now = [0.0]
    source = GrblSource("simulated", link=LoopbackPort(controller), clock=lambda: now[0], **source_options)
    source.open()
    store = SessionStore(tmp_path / "cal.json")
    store.start({})
    station = Station(source, rig.channels, on_flip=store.save)

    def on_block(r, t_s):
        controller.advance(t_s)
        now[0] = t_s
        source.poll()
        source.poll()
        source.clock_pair(t_s, t_s)

    drive(rig, station, StationStream(None), max_s=600.0, on_block=on_block)
    events = station.drain()
    recording = read_fourflip(store.write_recording({"turntable": source.spec})) if station.finished else None
    return station, events, recording


def test_a_grbl_table_turning_continuously_calibrates_near_the_bound(tmp_path):
    """The station's GRBL source in one continuous turn a flip, against the simulated controller in process
    (reports up to 10 ms old when read, as tools/bench_station.py: 1.6x the CRB RMS over sessions at 720 deg/min;
    one session's RMS over three channels spreads as chi_3 / sqrt(3), x2.3 at 99.9 %: bound 4)."""
    from compass.sim.grbl import GrblController

    rig = BenchRig(seed=13)
    controller = GrblController(rig, report_delay_s=0.01, seed=13)
    station, events, recording = run_grbl_session(tmp_path, rig, controller, mode="continuous", feed_deg_min=720.0)
    assert station.finished and "flip 0: the table turns once round" in [text for _, text in events], events
    truth = np.mod(rig.pose(recording.t_s)[0], 360.0)
    angle_error = (recording.platform_deg - truth + 180.0) % 360.0 - 180.0
    assert np.sqrt(np.mean(angle_error**2)) < 0.1  # 12 deg/s at most, reports 0-10 ms late: 0.05 deg RMS a turn
    ratio, error = direction_error_over_crb(rig, recording)
    assert np.sqrt(np.mean(ratio**2)) < 4.0, (ratio, error)


@pytest.mark.parametrize("mode, turned", [("stops", "went up 330 deg"), ("continuous", "went up 360 deg")])
def test_a_grbl_axis_inverted_by_its_direction_mask_stops_before_a_flip_is_kept(tmp_path, mode, turned):
    """GRBL's $3 mask inverts the axis: the controller's position counts up while the table turns clockwise seen
    from above (mirrored directions).  The module's gyro turned the other way, so the first flip stops the session
    naming the mask; nothing is kept."""
    from compass.sim.grbl import GrblController

    rig = BenchRig(seed=13)
    controller = GrblController(rig, invert_direction=True)
    with pytest.raises(SessionEnded, match=re.escape(turned) + r" over flip 0's turn while the module's gyro turned "
                       r"\d+ deg clockwise seen from above: .*; invert the A axis' direction in the controller "
                       + re.escape("(GRBL's $3, the direction port invert mask)")):
        run_grbl_session(tmp_path, rig, controller, mode=mode, step_deg=30.0, feed_deg_min=720.0)
    assert SessionStore(tmp_path / "cal.json").finished() == {}


def test_the_same_grbl_session_with_the_axis_not_inverted_calibrates(tmp_path):
    """test_a_grbl_axis_inverted_by_its_direction_mask_stops_before_a_flip_is_kept's session, the controller's
    positive move turning the table counterclockwise: stops every 30 deg at exact angles, each the mean of a still
    second, at the CRB of those rows (RMS ratio 1.13, 0.85, 1.23, 0.53 on seeds 13, 1, 2, 3; one session's RMS over
    three channels spreads as chi_3 / sqrt(3), x2.3 at 99.9 %: bound 4)."""
    from compass.sim.grbl import GrblController

    rig = BenchRig(seed=13)
    station, events, recording = run_grbl_session(tmp_path, rig, GrblController(rig), mode="stops", step_deg=30.0,
                                                  feed_deg_min=720.0)
    assert station.finished and not [e for e in events if e[0] == "warn"], events
    ratio, error = direction_error_over_crb(rig, recording, rig.rate_hz)
    assert np.sqrt(np.mean(ratio**2)) < 4.0, (ratio, error)


def test_a_corrupted_time_on_the_line_does_not_stop_the_session(tmp_path):
    """A stream without checksums can pass a cut line whose t_s reads 136139 between 136.53 and 136.54: the reading
    is dropped (the next does not follow it), and the session goes on."""
    from compass.station.turn import Reading

    rig = BenchRig(seed=4, encoder_step_deg=0.1)
    source = parse_turntable("column:enc")
    station = Station(source, rig.channels)
    stream = StationStream("enc")
    corrupted = [False]
    original = stream.feed

    def feed(data, t_rx=None):
        readings = original(data, t_rx)
        if readings and readings[0].t_s > 20.0 and not corrupted[0]:
            corrupted[0] = True
            r = readings[0]
            readings.insert(1, Reading(r.t_s * 1000.0, r.outputs, r.accel, r.gyro, r.encoder_deg, r.temp_c))
        return readings

    stream.feed = feed
    drive(rig, station, stream, max_s=300.0)
    assert corrupted[0] and station.finished, station.drain()


@pytest.mark.parametrize("spec, seen, fix, rig_options", [
    # the operator turns counterclockwise as asked, the encoder counts down
    ("column:enc", "went down \\d+ deg over flip 0's turn while the module's gyro turned \\d+ deg counterclockwise",
     "use --turntable column:-enc (the column negated)", {"encoder_step_deg": 0.1}),
    # the operator turns to the marks 30, 60, ... of a compass rose: clockwise
    ("manual:30", "went up 330 deg over flip 0's turn while the module's gyro turned \\d+ deg clockwise",
     "use --turntable manual:-30 (a graduation counting clockwise)", {"operator": Operator(read_half_width_deg=0.5)}),
])
def test_an_angle_counting_clockwise_stops_before_a_flip_is_kept(tmp_path, spec, seen, fix, rig_options):
    """An encoder or a graduation counting clockwise seen from above mirrors the calibration (every direction
    about 175 deg off, at the noise floor): the module's gyro turned the other way, so the first flip stops the
    session, naming the fix; the fix calibrates."""
    rig = BenchRig(seed=5, table_clockwise=True, **rig_options)
    with pytest.raises(SessionEnded, match=re.escape(f"(--turntable {spec}) ") + seen + r" seen from above: the angle counts "
                       r"clockwise, against SPEC's counterclockwise, and would mirror the calibration; "
                       + re.escape(fix)):
        run_session(tmp_path, spec, rig)
    assert SessionStore(tmp_path / "cal.json").finished() == {}
    (tmp_path / "fixed").mkdir()
    rig = BenchRig(seed=5, table_clockwise=True, **rig_options)
    station, events, recording = run_session(tmp_path / "fixed", spec.replace(":", ":-"), rig)
    assert station.finished and not [e for e in events if e[0] == "warn"], events
    ratio, error = direction_error_over_crb(rig, recording, rig.rate_hz if spec.startswith("manual") else 1)
    assert np.sqrt(np.mean(ratio**2)) < 12.0, (ratio, error)  # test_each_source_calibrates_a_simulated_bench's bound


def test_without_a_gyro_the_turn_direction_is_the_sources_word_alone(tmp_path):
    rig = BenchRig(seed=4, encoder_step_deg=0.1)
    source = parse_turntable("column:enc")
    station = Station(source, rig.channels)
    stream = StationStream("enc")
    original = stream.feed
    stream.feed = lambda data, t_rx=None: [r.__class__(r.t_s, r.outputs, r.accel, None, r.encoder_deg, r.temp_c)
                                           for r in original(data, t_rx)]
    drive(rig, station, stream, max_s=300.0)
    said = [text for level, text in station.drain() if level == "warn"]
    assert station.finished
    assert said == ["the module sends no gyro: the turn's direction is --turntable column:enc's word alone (an angle "
                    "counting clockwise seen from above would mirror the calibration unseen: check that it goes up as "
                    "the table turns counterclockwise)"]


@pytest.mark.parametrize("replug", [False, True])
def test_a_restart_of_the_modules_clock_redoes_the_step_and_the_recording_goes_on(tmp_path, replug):
    """The module resets after flip 90 is kept (its t_s from 0 again; the port kept, or unplugged and back): the step
    in progress is redone, the later flips' t_s go on from the flips kept (SPEC: non-decreasing), said once in the
    recording's # clock: line, and the recording calibrates as an uninterrupted one does
    (test_each_source_calibrates_a_simulated_bench's bound)."""
    rig = BenchRig(seed=11, encoder_step_deg=0.0)
    restarted = []

    def reset_after_flip_90(r, t, station):
        if not restarted and len(station.done) == 2:
            restarted.append(t)
            r.restart_clock(t)
            if replug:
                station.link_lost("unplugged")

    station, events, recording = run_session(tmp_path, "column:enc", rig, on_block=reset_after_flip_90)
    assert restarted and station.finished, events
    went_back = [text for level, text in events if "clock went back" in text]
    assert len(went_back) == 1 and went_back[0].endswith("s (a reset?): flip 180's flip is redone"), events
    assert np.all(np.diff(recording.t_s) >= 0)
    clock = recording.metadata["clock"]
    assert clock.startswith("the module's clock restarted before flip 180 (its t_s from ") and \
        clock.count("restarted") == 1 and clock.endswith("the recording's t_s goes on after 1.01 s"), clock  # flip 270
    # is on the same clock
    ratio, error = direction_error_over_crb(rig, recording)
    assert np.sqrt(np.mean(ratio**2)) < 2.5, (ratio, error)


def test_the_flips_keep_the_clock_words_on_disk(tmp_path):
    from compass.station.store import FlipRows

    store = SessionStore(tmp_path / "cal.json")
    store.start({})
    columns = ("t_s", "flip_deg", "platform_deg", "v1")
    for flip in (0.0, 90.0, 180.0, 270.0):
        clock = "the module's clock restarted before flip 180" if flip == 180.0 else None
        store.save(FlipRows(flip, columns, np.array([[flip, flip, 0.0, 1.0]]), 0.1, clock))
    assert store.finished()[180.0].clock == "the module's clock restarted before flip 180"
    text = store.write_recording({"turntable": "column:enc"}).read_text()
    assert "# clock: the module's clock restarted before flip 180\n" in text


def test_a_flip_recorded_again_after_the_others_is_written_in_time_order_and_calibrates(tmp_path):
    """Flip 90's file deleted after the session and the session resumed on a module whose clock started again
    (``compass bench --resume`` after a refusal that says "re-record the flip"): the new flip 90 goes on from the flips
    kept, so it is the latest; the recording is written in time order (t_s non-decreasing, SPEC section 2, which the
    reader checks) and calibrates as an uninterrupted one does (test_each_source_calibrates_a_simulated_bench's
    bound; the exact encoder reads the true turntable angle)."""
    rig = BenchRig(seed=11, encoder_step_deg=0.0)
    station, events, first = run_session(tmp_path, "column:enc", rig)
    assert station.finished, events
    store = SessionStore(tmp_path / "cal.json")
    (store.folder / "flip_090.csv").unlink()
    done = store.finished()
    assert sorted(done) == [0.0, 180.0, 270.0]
    source = parse_turntable("column:enc")
    again = Station(source, rig.channels, done=done, on_flip=store.save, rate_hz=station.rate_hz)
    drive(BenchRig(seed=11, encoder_step_deg=0.0), again, StationStream(source.column), max_s=600.0)
    events = again.drain()
    assert again.finished and sorted(store.finished()) == [0.0, 90.0, 180.0, 270.0], events
    assert any("clock restarted before flip 90" in text for _, text in events), events

    recording = read_fourflip(store.write_recording({"turntable": "column:enc"}, force=True))  # the first one's
    assert np.all(np.diff(recording.t_s) >= 0)
    starts = [recording.t_s[recording.flip_index == k][0] for k in range(4)]
    assert starts[1] > max(starts[0], starts[2], starts[3])  # flip 90 last in time, and last in the file
    assert np.all(recording.flip_index[-len(store.finished()[90.0].table):] == 1)
    assert "clock restarted before flip 90" in recording.metadata["clock"]
    result = calibrate_fourflip(recording, method="ml")
    truth = np.asarray(rig.truth["directions"])
    error = np.degrees(np.arccos(np.clip(np.sum(result.directions * truth, axis=1), -1.0, 1.0)))
    samples = BenchSamples(np.mod(recording.platform_deg, 360.0), recording.flip_deg, recording.flip_index)
    crb, _ = cramer_rao(rig.physics, samples, recording.channels, rig.noise)
    assert np.sqrt(np.mean((error / crb) ** 2)) < 2.5, (error, crb)
