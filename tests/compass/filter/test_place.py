"""A reference field that follows the place (issue 22, item 3): a new room's field is adopted, a magnet
on the housing is not, and the live session and the replay agree on a stream with a move."""

import io
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.evaluation import orientation_errors
from compass.filter import FilterCoefficients, FilterConfig, run_filter
from compass.filter._place import PlaceDetector, PlaceState
from compass.frames import world_field
from compass.io.lines import format_line
from compass.live import LiveSession
from compass.replay import replay
from compass.serial_reader import Chunk
from compass.sim.device import default_model
from compass.sim.motion import HousingField, Place, SensorErrors, simulate_motion

RATE_HZ = 100.0
ERRORS = SensorErrors(gyro_bias_rad_s=(0.004, -0.003, 0.002), gyro_scale=(0.005, -0.005, 0.003))
NOISE_UT = 0.7  # SensorErrors' default magnetometer noise
MOVED = "the field moved"


def _turning(seconds=8.0, rate_deg_s=40.0):
    """A housing turning about a tilted axis: R_world<-housing at RATE_HZ."""
    t = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    axis = np.array([0.3, -0.4, 1.0]) / np.linalg.norm([0.3, -0.4, 1.0])
    wobble = np.column_stack([0.3 * np.sin(0.7 * t), 0.2 * np.cos(1.1 * t), np.zeros_like(t)])
    return Rotation.from_rotvec(np.radians(rate_deg_s) * t[:, None] * axis + wobble)


def _judge(rotation, field_h, reference=(50.0, 60.0), rate_deg_s=40.0):
    """Feed the detector (the filter's default noise, a 1 deg attitude error); the first move it reports (or None)."""
    cfg = FilterConfig(field_norm=reference[0], dip_deg=reference[1], mag_noise=NOISE_UT)
    c = FilterCoefficients.from_config(cfg)
    detector, state = PlaceDetector(cfg), PlaceState()
    e = tuple(world_field(reference[1], reference[0]))
    one_deg2 = np.radians(1.0) ** 2
    for m, b in zip(rotation.as_matrix().reshape(-1, 9).tolist(), field_h.tolist()):
        if detector.add(state, 1.0 / RATE_HZ, tuple(m), tuple(b), e, np.radians(rate_deg_s) ** 2):
            move = detector.judge(state, reference[0], reference[1], c.env_floor_var, one_deg2, one_deg2,
                                  (c.gyro_var, c.scale_var, 1e-8))
            if move is not None:
                return move
    return None


def test_a_world_fixed_field_is_a_new_place_and_a_housing_fixed_one_is_not():
    rng = np.random.default_rng(1)
    rotation = _turning()
    n = len(rotation)
    new = world_field(40.0, 70.0)  # another room: 70 uT at 40 deg
    move = _judge(rotation, rotation.apply(new, inverse=True) + NOISE_UT * rng.normal(size=(n, 3)))
    assert move is not None
    assert move.field_norm == pytest.approx(70.0, rel=0.01) and move.dip_deg == pytest.approx(40.0, abs=0.5)
    assert abs(np.degrees(move.azimuth_rad)) < 0.5
    assert move.kind == "place" and move.place_rms < move.place_bound_rms and move.magnet_rms > move.magnet_bound_rms
    # the same |B| change made by a magnet on the housing: constant in H, it turns in the world frame
    magnet = np.array([15.0, -10.0, 12.0])
    field_h = rotation.apply(world_field(60.0, 50.0), inverse=True) + magnet + NOISE_UT * rng.normal(size=(n, 3))
    told = _judge(rotation, field_h)
    assert told.kind == "magnet" and told.place_rms > told.place_bound_rms and told.magnet_rms < told.magnet_bound_rms


def test_a_still_housing_cannot_tell_a_place_from_a_magnet():
    rng = np.random.default_rng(2)
    still = Rotation.from_euler("ZYX", np.tile([30.0, 10.0, -5.0], (800, 1)), degrees=True)
    field_h = still.apply(world_field(40.0, 70.0), inverse=True) + NOISE_UT * rng.normal(size=(800, 3))
    assert _judge(still, field_h, rate_deg_s=0.0) is None


def test_steel_that_turns_the_field_moves_the_heading_reference_with_it():
    rng = np.random.default_rng(3)
    rotation = _turning()
    turned = Rotation.from_euler("z", -15.0, degrees=True).apply(world_field(45.0, 65.0))  # 15 deg east
    move = _judge(rotation, rotation.apply(turned, inverse=True) + NOISE_UT * rng.normal(size=(len(rotation), 3)))
    assert np.degrees(move.azimuth_rad) == pytest.approx(-15.0, abs=0.5)  # toward West: -15


def _walk(follow, *, places=(), housing_field=None, seed=3, reference=None, duration_s=45.0):
    rec = simulate_motion("slow_rotation", duration_s=duration_s, rate_hz=RATE_HZ, seed=seed, errors=ERRORS,
                          places=places, housing_field=housing_field)
    cfg = FilterConfig(field_norm=rec.field_ut, dip_deg=rec.dip_deg, mag_noise=NOISE_UT, follow_place=follow)
    track = run_filter(rec.t_s, rec.accel_m_s2, rec.gyro_rad_s, rec.mag_ut, cfg)
    est = Rotation.from_quat(track.quat)
    heading = orientation_errors(est, rec.rotation)[0]
    return rec, track, heading


def test_a_walk_into_a_new_room_is_followed_and_the_heading_reacquired():
    room = Place(15.0, 65.0, 50.0, declination_deg=12.0)  # the steel there turns North by 12 deg
    rec, track, heading = _walk(True, places=(room,))
    moves = [t for t, text in track.events if text.startswith(MOVED)]
    window = FilterConfig(1.0, 0.0, 1.0).place_window_s
    assert len(moves) == 1 and room.t_s < moves[0] <= room.t_s + room.transition_s + 3 * window
    after = rec.t_s > moves[0] + 2.0
    # back within the noise: three times the filter's own heading sigma at the move (the new reference's
    # North carries the heading error of that moment)
    sigma = track.heading_sigma_deg[np.searchsorted(rec.t_s, moves[0])]
    assert np.sqrt(np.mean(heading[after] ** 2)) < 3.0 * sigma
    assert np.mean(track.mag_used[after]) > 0.9
    # the version before: the gate rejects until its timeout, then re-learns North from the new field, 12 deg off
    _, before, heading_before = _walk(False, places=(room,))
    assert not any(text.startswith(MOVED) for _, text in before.events)
    assert np.sqrt(np.mean(heading_before[after] ** 2)) > 3.0 * np.sqrt(np.mean(heading[after] ** 2))


def test_a_magnet_on_the_housing_is_not_followed_nor_adopted_when_the_gate_times_out():
    """A magnet told on a turning housing is never the reference: not by a move, not by the gate's timeout (whose
    field would be wrong by the magnet's at every attitude); the heading follows the gyro, better than with it."""
    magnet = HousingField(15.0, (15.0, -10.0, 12.0))  # |m| 22 uT against 43 uT: the gate rejects it
    rec, track, heading = _walk(True, housing_field=magnet, duration_s=60.0)
    assert not any(text.startswith(MOVED) or "adopting" in text for _, text in track.events)
    said = [t for t, text in track.events if text.startswith("the field turns with the housing")]
    assert len(said) == 1 and magnet.t_s < said[0] < magnet.t_s + 3 * FilterConfig(1.0, 0.0, 1.0).place_window_s
    assert np.mean(track.mag_used[rec.t_s > 16.0]) < 0.05
    # the timeout's adoption, as the version before the magnet was told did: the heading after it
    late = rec.t_s > magnet.t_s + FilterConfig(1.0, 0.0, 1.0).gate_timeout_s + 2.0
    _, before, heading_before = _walk(False, housing_field=magnet, duration_s=60.0)
    assert any("adopting" in text for _, text in before.events)
    assert np.sqrt(np.mean(heading[late] ** 2)) < 0.5 * np.sqrt(np.mean(heading_before[late] ** 2))


def test_a_magnet_taken_off_gives_the_field_back_and_the_heading_its_reference():
    """Told on, refused whole (a sample its field lets through by chance would turn the heading); taken off, the
    reference's field steady in the world frame is said and used again within a few windows."""
    magnet = HousingField(15.0, (15.0, -10.0, 12.0), until_s=35.0)
    rec, track, heading = _walk(True, housing_field=magnet, duration_s=60.0)
    window = FilterConfig(1.0, 0.0, 1.0).place_window_s
    told = [t for t, text in track.events if text.startswith("the field turns with the housing")]
    back = [t for t, text in track.events if text.startswith("the field is the reference's again")]
    assert len(told) == 1 and len(back) == 1 and magnet.until_s < back[0] < magnet.until_s + 3 * window
    on = (rec.t_s > told[0]) & (rec.t_s < magnet.until_s)
    assert not track.mag_used[on].any()
    assert np.mean(track.mag_used[rec.t_s > back[0] + 1.0]) > 0.9
    assert np.sqrt(np.mean(heading[rec.t_s > back[0] + 5.0] ** 2)) < 1.0


def _device_stream(model, rec):
    """The motion's field as the model's channel outputs (as compass.sim.device makes them), exact floats."""
    rng = np.random.default_rng(9)
    x = rec.mag_ut * (model.field_norm / rec.field_ut) @ model.unit_directions.T
    raw = np.column_stack([r.output(x[:, c]) for c, r in enumerate(model.responses)])
    raw = raw + np.asarray(model.noise) * rng.normal(size=raw.shape)
    accel = rec.accel_m_s2 / 9.81
    names = ["t_s", *model.channels, "ax", "ay", "az", "gx", "gy", "gz"]
    rows = np.column_stack([rec.t_s, raw, accel, rec.gyro_rad_s])
    return raw, accel, format_line(names) + b"".join(format_line([repr(v) for v in row.tolist()]) for row in rows)


def test_live_replay_and_run_filter_agree_on_a_stream_with_a_move(tmp_path, capsys):
    model = default_model()
    rec = simulate_motion("slow_rotation", duration_s=40.0, rate_hz=RATE_HZ, seed=4, errors=ERRORS,
                          field_ut=model.field_norm, dip_deg=model.dip_deg, places=(Place(12.0, 75.0, 45.0, 8.0),))
    raw, accel, data = _device_stream(model, rec)
    events, live_out, replay_out = [], io.StringIO(), io.StringIO()
    live = LiveSession(model, out=live_out, quaternion=True, on_event=lambda level, text: events.append(text))
    for k in range(0, len(data), 997):
        live.feed(Chunk(time.perf_counter(), data[k:k + 997]))
    live.close()
    replayed = replay(LiveSession(model, out=replay_out, quaternion=True), rec.t_s, raw, accel, rec.gyro_rad_s)
    assert sum(text.startswith(MOVED) for text in events) == 1

    def rows(text):  # every column but the latency
        return [line.split(",")[:-5] + line.split(",")[-4:] for line in text.splitlines() if not line.startswith("#")]

    assert live.samples == replayed.samples == len(rec.t_s)
    assert rows(live_out.getvalue()) == rows(replay_out.getvalue())
    track = run_filter(rec.t_s, accel, rec.gyro_rad_s, model.field(raw)[0], FilterConfig.from_model(model))
    assert sum(text.startswith(MOVED) for _, text in track.events) == 1
    quat = np.array([[float(v) for v in line.split(",")[-4:]] for line in live_out.getvalue().splitlines()[2:]])
    angle = np.degrees((Rotation.from_quat(quat[:, [1, 2, 3, 0]]).inv() * Rotation.from_quat(track.quat)).magnitude())
    assert np.max(angle) < 1e-5
    # compass attitude --filter: the same pipeline from files, the move named in its closing line
    from compass.calibration import model_to_dict, save
    from compass.cli import main
    from compass.io.table import format_table

    cal, rec_path, out = tmp_path / "cal.json", tmp_path / "rec.csv", tmp_path / "att.csv"
    save(cal, model_to_dict(model))
    columns = {"t_s": rec.t_s} | {c: raw[:, k] for k, c in enumerate(model.channels)} \
        | {c: accel[:, k] for k, c in enumerate(("ax", "ay", "az"))} \
        | {c: rec.gyro_rad_s[:, k] for k, c in enumerate(("gx", "gy", "gz"))}
    rec_path.write_text(format_table(columns, {}, {c: "%.17g" for c in columns}))
    assert main(["attitude", str(cal), str(rec_path), "--out", str(out), "--filter"]) == 0
    captured = capsys.readouterr()
    assert "moved to a new place's field 1 time: the field moved: |B|" in captured.out
    assert captured.err.count(MOVED) == 1
