"""Rerun output of every command: read each recording back and check entities, components, timelines
and the blueprint against what the command computed (rerun-sdk 0.41, ``rerun.chunk.RrdReader``)."""

import json

import numpy as np
import pytest

from compass.cli import main
from compass.io.table import read_table
from compass.viz import spawn_problem

rr = pytest.importorskip("rerun")
from tests.rrd_read import (blueprint_timeline, blueprint_views, entity_paths, read_column, read_static,  # noqa: E402
                      scalars, timelines)
from scipy.spatial.transform import Rotation  # noqa: E402
from compass.calibration import model_to_dict


def views_by_name(path):
    return {v.get("name"): v for v in blueprint_views(path)}


def test_spawn_is_refused_where_no_viewer_can_open(tmp_path, capsys, monkeypatch):
    assert "no display" in spawn_problem({"PATH": "/usr/bin"}) or "linux" not in __import__("sys").platform
    assert "not on PATH" in spawn_problem({"DISPLAY": ":0", "PATH": str(tmp_path)})
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    cal = tmp_path / "cal.json"
    from compass.sim.device import default_model

    cal.write_text(json.dumps(model_to_dict(default_model())))
    # refused at once (before the port is opened), one line, exit 2, naming the way out
    assert main(["live", "--port", str(tmp_path / "no-such-port"), "--cal", str(cal), "--rerun", "spawn"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no display" in err and "--rerun out.rrd" in err
    # a mistyped 'spawn' does not become a file; an existing file is not overwritten without --force
    assert main(["live", "--port", "x", "--cal", str(cal), "--rerun", "spwan"]) == 2
    assert "ending in .rrd" in capsys.readouterr().err and not (tmp_path / "spwan").exists()
    (tmp_path / "old.rrd").write_text("keep")
    assert main(["live", "--port", "x", "--cal", str(cal), "--rerun", str(tmp_path / "old.rrd")]) == 2
    assert (tmp_path / "old.rrd").read_text() == "keep"


@pytest.fixture(scope="module")
def fourflip(tmp_path_factory):
    """A four-flip recording with an offset drift the diagnosis adds, calibrated with --rerun."""
    folder = tmp_path_factory.mktemp("fourflip")
    rec, cal, rrd = folder / "bench.csv", folder / "cal.json", folder / "cal.rrd"
    assert main(["simulate", "fourflip", "--out", str(rec), "--seed", "4", "--effect", "offset_drift"]) == 0
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--rerun", str(rrd)]) == 0
    return rec, json.loads(cal.read_text()), rrd


def test_calibrate_fourflip_replays_the_session(fourflip):
    rec, cal, rrd = fourflip
    names = list(cal["channels"])
    paths = entity_paths(rrd)
    for name in names:
        assert {f"/fourflip/{name}/measured", f"/fourflip/{name}/fit", f"/fourflip/{name}/residual",
                f"/fourflip/{name}/residual/noise_band"} <= paths
    assert {"/bench/field", "/bench/turntable", "/bench/turntable/cube", "/bench/turntable/cube/directions",
            "/diagnosis/residual_rms/noise_floor", "/diagnosis/log"} <= paths
    # 3-sigma cones of a few hundredths of a degree are not drawn (lines on the arrows); their sigma is labelled
    assert "/bench/turntable/cube/direction_cones" not in paths
    assert {"sample", "t"} <= timelines(rrd, "/fourflip/v1/measured")
    table = read_table(rec)
    order = np.argsort(table.column("t_s"), kind="stable")
    # measured = the recording (replayed in time order); fit + residual(after) = measured
    _, measured = scalars(rrd, "/fourflip/v1/measured")
    _, fit = scalars(rrd, "/fourflip/v1/fit")
    _, residual = scalars(rrd, "/fourflip/v1/residual")
    assert residual.shape[1] == 2  # the diagnosis added an effect: before (base model) and after
    np.testing.assert_allclose(measured[:, 0], table.column("v1")[order], rtol=1e-6)
    np.testing.assert_allclose(fit[:, 0] + residual[:, 1], measured[:, 0], atol=1e-5)
    # before/after are the diagnosis's first and last steps (rms over every channel, as the file gives it)
    both = np.concatenate([scalars(rrd, f"/fourflip/{n}/residual")[1] for n in names])
    steps = cal["diagnosis"]["steps"]
    np.testing.assert_allclose(np.sqrt(np.mean(both**2, axis=0)), [steps[0]["residual_rms"],
                                                                  cal["diagnosis"]["residual_rms_after"]], rtol=1e-3)
    # the cube turns as the bench did: R_W<-H = Rz(phi) Rx(kappa) at each drawn sample
    seq, q_table = read_column(rrd, "/bench/turntable", "Transform3D:quaternion")
    _, q_cube = read_column(rrd, "/bench/turntable/cube", "Transform3D:quaternion")
    phi = table.column("platform_deg")[order][seq]
    kappa = table.column("flip_deg")[order][seq]
    r = Rotation.from_quat([q[0] for q in q_table]) * Rotation.from_quat([q[0] for q in q_cube])
    expected = Rotation.from_euler("ZX", np.column_stack([phi, kappa]), degrees=True)
    assert np.max((r.inv() * expected).magnitude()) < 1e-5
    # sensing directions as fitted, one labelled arrow each
    directions = np.array(read_static(rrd, "/bench/turntable/cube/directions", "Arrows3D:vectors")[-1]) / 1.2
    np.testing.assert_allclose(directions, [cal["channels"][n]["direction"] for n in names], atol=1e-6)
    # the diagnosis: one bar per step (its own entity, named in the legend), the last at the final residual
    steps = cal["diagnosis"]["steps"]
    bars = sorted(p for p in paths if p.startswith("/diagnosis/residual_rms/step"))
    assert len(steps) >= 2 and len(bars) == len(steps)
    values = [read_static(rrd, bar, "BarChart:values")[-1][0]["buffer"] for bar in bars]
    np.testing.assert_allclose(np.concatenate(values), [step["residual_rms"] for step in steps], rtol=1e-6)
    _, log = read_column(rrd, "/diagnosis/log", "TextLog:text")
    assert any("offset_drift" in t[0] for t in log)
    views = views_by_name(rrd)
    assert views["cube on the turntable: sensing directions +-1 sigma, field (orange)"]["class"] == "3D"
    assert views["v1: residual (recording units), noise band"]["origin"] == "/fourflip/v1/residual"
    assert {v["class"] for v in views.values()} == {"3D", "TimeSeries", "BarChart", "TextLog"}


def test_calibrate_tumble_point_clouds(tmp_path):
    from compass.sim.tumble import simulate_tumble, write_tumble

    rec, _ = write_tumble(simulate_tumble(seed=2, n=1500), tmp_path / "tumble.csv")
    rrd, cal = tmp_path / "t.rrd", tmp_path / "cal.json"
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--rerun", str(rrd)]) == 0
    paths = entity_paths(rrd)
    assert {"/tumble/raw/samples", "/tumble/raw/ellipsoid", "/tumble/calibrated/samples", "/tumble/calibrated/sphere",
            "/tumble/coverage", "/tumble/field_ratio", "/diagnosis/log"} <= paths
    calibrated = np.array(read_static(rrd, "/tumble/calibrated/samples", "Points3D:positions")[-1])
    raw = np.array(read_static(rrd, "/tumble/raw/samples", "Points3D:positions")[-1])
    assert len(calibrated) == len(raw) == len(read_table(rec).data)
    # after: on the unit sphere within the noise; before: off it by the soft iron
    spread = np.std(np.linalg.norm(calibrated, axis=1))
    assert abs(np.median(np.linalg.norm(calibrated, axis=1)) - 1.0) < 0.01 and spread < 0.02
    assert np.std(np.linalg.norm(raw, axis=1)) > 2 * spread
    _, ratio = scalars(rrd, "/tumble/field_ratio")
    assert ratio.shape == (len(raw), 2)
    views = views_by_name(rrd)
    assert views["raw, on the fitted ellipsoid (colour: coverage)"]["origin"] == "/tumble/raw"


def test_calibrate_platform_and_reference(tmp_path):
    from compass.sim.platform3d import simulate_platform3d, write_platform3d
    from compass.sim.reference import simulate_reference, write_reference

    for name, (sim, write) in {"platform": (simulate_platform3d, write_platform3d),
                               "reference": (simulate_reference, write_reference)}.items():
        rec, _ = write(sim(seed=1), tmp_path / f"{name}.csv")
        rrd = tmp_path / f"{name}.rrd"
        cal = tmp_path / f"{name}.json"
        assert main(["calibrate", str(rec), "--out", str(cal), "--quiet", "--rerun", str(rrd)]) == 0
        paths = entity_paths(rrd)
        kind = "platform3d" if name == "platform" else "reference"
        series = sorted(p for p in paths if p.startswith(f"/{kind}/") and "bench" not in p)
        assert len(series) >= 3 and any(p.startswith("/diagnosis/residual_rms/") for p in paths)
        _, residual = scalars(rrd, series[0])
        assert len(residual) == len(read_table(rec).data)
    assert "/platform3d/bench/housing" in entity_paths(tmp_path / "platform.rrd")


def test_attitude_rerun_matches_the_csv(tmp_path):
    from compass.sim.fourflip import simulate_fourflip, write_fourflip
    from compass.sim.runtime import simulate_runtime, write_runtime

    session = simulate_fourflip(seed=2)
    bench, _ = write_fourflip(session, tmp_path / "bench.csv")
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(bench), "--out", str(cal), "--quiet", "--no-diagnose"]) == 0
    run, _ = write_runtime(simulate_runtime(session.truth, 200, seed=3), tmp_path / "run.csv")
    att, rrd = tmp_path / "att.csv", tmp_path / "att.rrd"
    assert main(["attitude", str(cal), str(run), "--out", str(att), "--rerun", str(rrd), "--site", "48.1,11.6",
                 "--date", "2026-06-01"]) == 0
    table = read_table(att)
    for name in ("heading_deg", "pitch_deg", "roll_deg", "heading_true_deg", "field_ratio", "dip_deg", "in_range",
                 "disturbed"):
        _, values = scalars(rrd, f"/compass/{name}")
        np.testing.assert_allclose(values[:, 0], table.column(name), atol=1e-3)
    _, band = scalars(rrd, "/compass/pitch_deg/sigma_band")
    np.testing.assert_allclose(band[:, 1] - band[:, 0], 2 * table.column("pitch_sigma_deg"), atol=1e-3)
    _, band = scalars(rrd, "/compass/heading_true_deg/sigma_band")
    np.testing.assert_allclose(band[:, 1] - band[:, 0], 2 * table.column("heading_true_sigma_deg"), atol=1e-3)
    _, limits = scalars(rrd, "/compass/dip_deg/gate_limits")
    site_dip = float(table.metadata["reference_field"].split("dip ")[1].split()[0])  # the gate is about the site's
    np.testing.assert_allclose(limits.mean(axis=1), site_dip, atol=0.01)
    measured = table.column("dip_deg")  # the simulated field is not Munich's: outside the limits, all disturbed
    assert np.all((measured < limits[:, 0]) | (measured > limits[:, 1])) and np.all(table.column("disturbed") == 1)
    _, raw = scalars(rrd, "/raw/mag")
    assert raw.shape == (200, 3)
    paths = entity_paths(rrd)
    assert {"/world/housing", "/world/housing/body", "/world/housing/axes", "/housing/field",
            "/housing/expected/field_gate",
            "/housing/expected", "/housing/gravity", "/housing/expected/gravity_gate"} <= paths
    (labels,) = read_static(rrd, "/world/housing/axes", "Arrows3D:labels")[-1:]
    assert labels == ["+X", "+Y", "+Z"]  # right however the housing is turned
    views = views_by_name(rrd)
    heading_view = views["heading (deg) +-1 sigma; from true north with a site"]
    assert heading_view["class"] == "TimeSeries" and "/compass/heading_deg/**" in heading_view["contents"]
    assert views["in the housing: field (orange), gravity (purple), the gate's cones"][
        "origin"] == "/housing"


def test_demo_writes_a_recording_with_calibration_attitude_and_errors(tmp_path, capsys):
    assert main(["demo", "--workdir", str(tmp_path)]) == 0
    rrd = tmp_path / "demo.rrd"
    assert f"rerun {rrd}" in capsys.readouterr().out
    paths = entity_paths(rrd)
    assert {"/fourflip/v1/residual", "/bench/turntable/cube", "/world/housing", "/world/beside/truth",
            "/errors/heading_deg", "/errors/heading_deg/sigma_band", "/compass/heading_deg"} <= paths
    _, error = scalars(rrd, "/errors/heading_deg")
    _, band = scalars(rrd, "/errors/heading_deg/sigma_band")
    assert np.sqrt(np.mean(error**2)) < 2 * np.sqrt(np.mean(band[:, 1] ** 2))  # errors as large as their sigma
    assert blueprint_timeline(rrd) == "t"  # time, shared by the calibration and the attitude (not their sample counts)
    origins = {v.get("origin") for v in blueprint_views(rrd)}
    assert {"/bench", "/world", "/housing", "/errors/heading_deg", "/compass/field_ratio",
            "/diagnosis/residual_rms"} <= origins


def test_evaluate_rerun_two_housings_and_errors(tmp_path, capsys):
    from tests.compass.io.test_broad import MAGNET, _crop

    if not MAGNET.exists():
        pytest.skip("BROAD data not found")
    trial, rrd = _crop(MAGNET, tmp_path / "magnet.mat", 45.0), tmp_path / "eval.rrd"
    assert main(["evaluate", str(trial), "--rerun", str(rrd)]) == 0
    out = capsys.readouterr().out
    paths = entity_paths(rrd)
    assert {"/world/estimate", "/world/beside/truth", "/errors/heading_deg", "/errors/inclination_deg",
            "/compass/field_ratio", "/compass/disturbed", "/events"} <= paths
    _, heading = scalars(rrd, "/errors/heading_deg", index="t")
    rms = float(out.split("heading RMS ")[1].split()[0])
    scored = heading[np.isfinite(heading[:, 0]), 0]  # NaN outside the movement phase (not scored)
    np.testing.assert_allclose(np.sqrt(np.mean(scored**2)), rms, atol=0.01)  # the printed figure
    assert "BarChart" not in {v["class"] for v in blueprint_views(rrd)}


def test_rrd_written_atomically_keeps_the_old_mode_and_clears_stale_temporaries(tmp_path):
    from compass.sim.fourflip import simulate_fourflip, write_fourflip

    rec, _ = write_fourflip(simulate_fourflip(seed=5), tmp_path / "bench.csv")
    rrd = tmp_path / "cal.rrd"
    rrd.write_text("old")
    rrd.chmod(0o640)
    stale = tmp_path / ".cal.rrd.999999999.abc.tmp"  # left by a writer that is gone (no such pid)
    stale.write_text("half a file")
    assert main(["calibrate", str(rec), "--out", str(tmp_path / "c.json"), "--quiet", "--no-diagnose",
                 "--rerun", str(rrd), "--force"]) == 0
    assert (rrd.stat().st_mode & 0o777) == 0o640 and not stale.exists()
    assert "/fourflip/v1/measured" in entity_paths(rrd)
    assert [p.name for p in tmp_path.glob(".cal.rrd.*")] == []


def test_calibrate_rerun_reads_the_recording_with_the_same_column_mapping(tmp_path):
    """`--columns` reached the fit but not the replay (which read the file again): exit 2 after the fit."""
    from compass.sim.tumble import simulate_tumble, write_tumble

    rec, _ = write_tumble(simulate_tumble(seed=2, n=1500), tmp_path / "tumble.csv")
    lines = rec.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    lines[header] = lines[header].replace("mx", "MagA").replace("my", "MagB").replace("mz", "MagC")
    rec.write_text("\n".join(lines) + "\n")
    rrd = tmp_path / "t.rrd"
    assert main(["calibrate", str(rec), "--out", str(tmp_path / "cal.json"), "--quiet", "--rerun", str(rrd),
                 "--columns", "mx=MagA,my=MagB,mz=MagC"]) == 0
    raw = np.array(read_static(rrd, "/tumble/raw/samples", "Points3D:positions")[-1])
    assert len(raw) == 1500
