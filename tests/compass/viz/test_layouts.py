"""What a person sees: every recording's blueprint read back and checked for what makes it read at a glance.

A layout reads right when its time series show the whole recording (not a window about the time
cursor), its text logs show the message (not time, entity path and level first), every 3-D view has
its camera set, no two labels sit on one point, the side panels are collapsed, and each kind of
recording has its own application id (Rerun keeps one layout per id: a tumble opened beside a
four-flip got the four-flip's panels, all empty). A live recording to a file is compacted: a 20 s
session in under 300 chunks (it was 6,200, minutes to load).
"""

import io
import itertools
import json
import time

import numpy as np
import pytest

from compass.cli import main

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402
from tests.rrd_read import (application_ids, blueprint_details, blueprint_timeline, panel_states,  # noqa: E402
                      static_labels)

INFINITE, BODY, COLLAPSED = 3, 3, 2
LABEL_GAP = 0.15  # labels closer than this (world units; a housing is 1.1 long) overlap on screen


def check_layout(path, application_id, timeline):
    """Every property a readable layout needs; returns the views."""
    assert application_ids(path) == {application_id}
    assert blueprint_timeline(path) == timeline
    assert set(panel_states(path).values()) == {COLLAPSED} and len(panel_states(path)) == 3
    views = blueprint_details(path)
    assert views
    for view in views:
        if view["class"] == "TimeSeries":
            assert view["range_kinds"] == (INFINITE, INFINITE), view["name"]
        if view["class"] == "TextLog":
            assert view["text_columns"][0] == (BODY, True) and not any(v for _, v in view["text_columns"][1:])
            assert view["timeline_columns"] and not any(c["visible"] for c in view["timeline_columns"])
            # its lines are on the timeline the time panel shows (a line on another is not listed)
            for c in RrdReader(str(path)).stream().filter(content=view["origin"]).to_chunks():
                rb = c.to_record_batch()
                assert "TextLog:text" not in rb.schema.names or timeline in rb.schema.names, view["name"]
        if view["class"] == "3D":
            assert view["eye"] is not None and np.linalg.norm(view["eye"]) > 2.0, view["name"]
    labels = static_labels(path)
    for view in (v for v in views if v["class"] == "3D"):
        inside = [(e, text, p) for e, text, p in labels if e == view["origin"] or e.startswith(view["origin"] + "/")]
        for (e1, t1, p1), (e2, t2, p2) in itertools.combinations(inside, 2):
            assert np.linalg.norm(p1 - p2) > LABEL_GAP, f"{view['name']}: '{t1}' ({e1}) on '{t2}' ({e2})"
    return views


def names(views):
    return {v["name"] for v in views}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("layouts")


@pytest.fixture(scope="module")
def fourflip(folder):
    rec, cal, rrd = folder / "bench.csv", folder / "bench.json", folder / "fourflip.rrd"
    assert main(["simulate", "fourflip", "--out", str(rec), "--seed", "4", "--effect", "offset_drift"]) == 0
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--rerun", str(rrd)]) == 0
    return rec, cal, rrd


def test_fourflip_layout(fourflip):
    rec, cal, rrd = fourflip
    views = check_layout(rrd, "compass_calibrate_fourflip", "turntable_deg")
    # outputs against the turntable angle: every sample has its whole degree
    chunks = RrdReader(str(rrd)).stream().filter(content="/fourflip/v1/measured").to_chunks()
    angles = np.concatenate([c.to_record_batch().column("turntable_deg").to_numpy() for c in chunks
                             if "turntable_deg" in c.to_record_batch().schema.names])
    assert angles.min() >= 0 and angles.max() <= 359 and len(np.unique(angles)) > 300
    assert any("(recording units)" in n for n in names(views))
    # the diagnosis's bars are named by their step (one entity each) and the floor stands beside them
    steps = json.loads(cal.read_text())["diagnosis"]["steps"]
    bars = sorted(c.entity_path for c in RrdReader(str(rrd)).stream().to_chunks()
                  if c.entity_path.startswith("/diagnosis/residual_rms/"))
    assert len(bars) == len(steps) + 1 and "/diagnosis/residual_rms/noise_floor" in bars
    assert any("offset_drift" in b for b in bars)


def test_kinds_have_their_own_application_id_and_layout(folder, fourflip):
    from compass.sim.platform3d import simulate_platform3d, write_platform3d
    from compass.sim.reference import simulate_reference, write_reference
    from compass.sim.tumble import simulate_tumble, write_tumble

    seen = {}
    for kind, (sim, write) in {"tumble": (lambda: simulate_tumble(seed=2, n=1500), write_tumble),
                               "platform3d": (lambda: simulate_platform3d(seed=1), write_platform3d),
                               "reference": (lambda: simulate_reference(seed=1), write_reference)}.items():
        rec, _ = write(sim(), folder / f"{kind}.csv")
        rrd = folder / f"{kind}.rrd"
        assert main(["calibrate", str(rec), "--out", str(folder / f"{kind}.json"), "--quiet", "--rerun", str(rrd)]) == 0
        seen[kind] = check_layout(rrd, f"compass_calibrate_{kind}", "sample")
    assert "|m| / field_norm (ratio): raw orange, calibrated blue" in names(seen["tumble"])
    assert "housing in each pose" in names(seen["platform3d"])
    assert len(application_ids(fourflip[2]) | {f"compass_calibrate_{k}" for k in seen}) == 4


def test_attitude_layout_names_units_and_flags(folder, fourflip):
    _, cal, _ = fourflip
    run, rrd = folder / "run.csv", folder / "attitude.rrd"
    assert main(["simulate", "runtime", "--truth", str(folder / "bench.truth.json"), "--out", str(run),
                 "--seed", "5"]) == 0
    assert main(["attitude", str(cal), str(run), "--out", str(folder / "att.csv"), "--rerun", str(rrd)]) == 0
    views = check_layout(rrd, "compass_attitude", "t")
    assert "StateTimeline" in {v["class"] for v in views}
    # the flags as words, one lane each, a row where a lane changes
    chunks = RrdReader(str(rrd)).stream().filter(content="/compass/state/**").to_chunks()
    lanes = {c.entity_path for c in chunks}
    assert {"/compass/state/field", "/compass/state/range"} <= lanes
    # the world has a north marker; the reference is labelled beyond its tip, away from the housing's X
    texts = {text for _, text, _ in static_labels(rrd)}
    assert "N (magnetic north)" in texts and "+Z" in texts and not any("up" == t.split()[-1] for t in texts)


def test_live_recording_is_compacted_and_laid_out(tmp_path):
    """A 20 s session at 100 Hz through the live session into a file: under 300 chunks (6,222 at the
    old 50 ms batches), every sample in it."""
    from compass.filter import FilterConfig
    from compass.live import LiveSession
    from compass.serial_reader import Chunk, LinkEvent
    from compass.sim.device import PtyDevice, default_model, simulate_device
    from compass.viz import RerunSink
    from tests.rrd_read import read_column

    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    stream = device._header + b"".join(device._lines(simulate_device(model, np.arange(2000) / 100.0, seed=3), 0))
    rrd = tmp_path / "live.rrd"
    sink = RerunSink.for_model(rrd, model, FilterConfig.from_model(model))
    session = LiveSession(model, out=io.StringIO(), sink=sink)
    session.feed(LinkEvent("connected", "connected to test", 0.0))
    for k in range(0, len(stream), 4000):
        session.feed(Chunk(time.perf_counter(), stream[k:k + 4000]))
    session.close()
    chunks = list(RrdReader(str(rrd)).stream().to_chunks())
    assert len(chunks) < 300
    seq, _ = read_column(rrd, "/compass/heading_deg", "Scalars:scalars")
    assert len(seq) == session.samples > 1900
    check_layout(rrd, "compass_live", "t")


def test_live_tumble_layout(tmp_path):
    from compass.viz.calibration import LiveTumbleRecording

    recording = LiveTumbleRecording(tmp_path / "lt.rrd")
    recording.close(None, None)  # no calibration reached: the live views alone
    check_layout(tmp_path / "lt.rrd", "compass_live_tumble", "sample")


def test_demo_layout(tmp_path):
    assert main(["demo", "--workdir", str(tmp_path)]) == 0
    views = check_layout(tmp_path / "demo.rrd", "compass_demo", "t")
    assert {"3D", "TimeSeries", "TextLog", "BarChart", "StateTimeline"} <= {v["class"] for v in views}


def test_evaluate_layout(tmp_path):
    from tests.compass.io.test_broad import MAGNET, _crop

    if not MAGNET.exists():
        pytest.skip("BROAD data not found")
    rrd = tmp_path / "eval.rrd"
    assert main(["evaluate", str(_crop(MAGNET, tmp_path / "magnet.mat", 45.0)), "--rerun", str(rrd)]) == 0
    check_layout(rrd, "compass_evaluate", "t")


def test_bench_layout(tmp_path):
    """A bench session (encoder, in lock step) recorded as compass bench --rerun records it: the cube turning,
    each flip's ring filling in, the degrees covered and the station's words on the module's time."""
    from compass.sim.bench_rig import BenchRig, drive
    from compass.station import Station, StationStream, parse_turntable
    from compass.viz.bench import BenchRecording

    rig = BenchRig(seed=3, encoder_step_deg=0.1)
    viz = BenchRecording(tmp_path / "bench.rrd", rig.channels)
    station = Station(parse_turntable("column:enc"), rig.channels, on_flip=viz.flip)
    stream = StationStream("enc")
    said = []

    def on_block(r, t_s):
        for level, text in station.drain():
            viz.event(t_s, level, text)
            said.append(text)
        viz.progress(t_s, station.progress.flip_deg, station.progress.covered_deg)

    t_end = drive(rig, station, stream, max_s=400.0, on_block=on_block)
    on_block(rig, t_end)  # the words of the last block
    viz.close()
    assert station.finished
    views = check_layout(tmp_path / "bench.rrd", "compass_bench", "t")
    assert {"3D", "TimeSeries", "TextLog"} <= {v["class"] for v in views}
    reader = RrdReader(str(tmp_path / "bench.rrd"))
    turns = [c for c in reader.stream().filter(content="/bench/turntable").to_chunks()
             if "t" in c.to_record_batch().schema.names]
    assert sum(c.num_rows for c in turns) >= 4 * 60  # every flip's turn drawn
    texts = {text for _, text, _ in static_labels(tmp_path / "bench.rrd")}
    assert {"flip 0", "flip 90", "flip 180", "flip 270"} <= texts
    assert any("flip 270 kept" in s for s in said)
