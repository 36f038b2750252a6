"""compass.viz.calibration draws a result from its typed attributes, never from its file's JSON."""

import numpy as np
import pytest

from calibrate import calibrate_fourflip
from calibrate.tumble import calibrate_tumble
from compass.io.fourflip import read_fourflip
from compass.io.tumble import read_tumble
from compass.sim.fourflip import simulate_fourflip, write_fourflip
from compass.sim.tumble import simulate_tumble, write_tumble

pytest.importorskip("rerun")
from tests.rrd_read import read_column, read_static  # noqa: E402

from compass.viz.calibration import record_calibration  # noqa: E402


def no_json(result):
    """The result with ``to_json`` refusing: a drawing that reads the file's dict fails."""
    def refuse():
        raise AssertionError("the viz read result.to_json()")
    object.__setattr__(result, "to_json", refuse)  # frozen dataclass: an instance attribute shadows the method
    return result


def test_a_fourflip_is_drawn_from_its_channels_dip_and_azimuth(tmp_path):
    path, _ = write_fourflip(simulate_fourflip(seed=6), tmp_path / "bench.csv")
    result = calibrate_fourflip(read_fourflip(path), diagnose=False)
    doc = result.to_json()
    record_calibration(tmp_path / "ff.rrd", path, no_json(result))
    labels = read_static(tmp_path / "ff.rrd", "/bench/turntable/cube/directions", "Arrows3D:labels")
    assert [str(v).split(" ")[0] for v in np.ravel(labels)] == list(doc["channels"])
    assert all(f"+-{doc['channels'][n]['direction_sigma_deg']:.3f} deg" in str(v)
               for n, v in zip(doc["channels"], np.ravel(labels)))
    vectors = np.asarray(read_static(tmp_path / "ff.rrd", "/bench/turntable/cube/directions", "Arrows3D:vectors"))
    np.testing.assert_allclose(vectors.reshape(-1, 3) / 1.2, [c["direction"] for c in doc["channels"].values()],
                               atol=1e-6)
    field = str(np.ravel(read_static(tmp_path / "ff.rrd", "/bench/field", "Arrows3D:labels"))[0])
    assert field == f"field, dip {doc['dip_deg']:.2f} deg"
    assert doc["diagnosis"] is None  # diagnose=False: the log says so rather than staying blank
    _, log = read_column(tmp_path / "ff.rrd", "/diagnosis/log", "TextLog:text")
    assert [str(np.ravel(v)[0]) for v in log] == ["no residual diagnosis (not run)"]


def test_a_tumble_is_drawn_from_its_hard_and_soft_iron(tmp_path):
    path, _ = write_tumble(simulate_tumble(seed=2, n=1500), tmp_path / "tumble.csv")
    rec = read_tumble(path)
    result = calibrate_tumble(rec.mag, rec.accel)
    doc = result.to_json()
    record_calibration(tmp_path / "t.rrd", path, no_json(result))
    label = str(np.ravel(read_static(tmp_path / "t.rrd", "/tumble/calibrated/sphere", "Ellipsoids3D:labels"))[0])
    assert label == f"|m| = field_norm ({doc['field_norm']:.4g})"
    points = np.asarray(read_static(tmp_path / "t.rrd", "/tumble/calibrated/samples", "Points3D:positions"))
    m = (rec.mag - np.array(doc["hard_iron"])) @ np.array(doc["soft_iron"]).T / doc["field_norm"]
    np.testing.assert_allclose(points.reshape(-1, 3), m, atol=1e-5)


def test_an_installation_shows_the_product_iron_bending_the_sphere_and_the_installed_field_back_on_it(tmp_path):
    """The product's hard iron (6 uT on 50) moves |B| through the bench calibration alone by several
    percent; through the installed calibration it stays at the site's |B| to the sensor noise."""
    from compass.cli import main
    from tests.rrd_read import scalars

    folder = tmp_path
    assert main(["simulate", "fourflip", "--out", str(folder / "ff.csv"), "--seed", "4"]) == 0
    assert main(["calibrate", str(folder / "ff.csv"), "--out", str(folder / "ff.json"), "--quiet"]) == 0
    assert main(["simulate", "installation", "--out", str(folder / "ins.csv"), "--truth",
                 str(folder / "ff.truth.json"), "--hard-iron-ut", "6"]) == 0
    assert main(["calibrate", str(folder / "ins.csv"), "--base", str(folder / "ff.json"), "--out",
                 str(folder / "ins.json"), "--quiet", "--rerun", str(folder / "ins.rrd")]) == 0
    _, ratio = scalars(folder / "ins.rrd", "/installed/field_ratio")
    bench, installed = np.abs(ratio[:, 0] - 1.0), np.abs(ratio[:, 1] - 1.0)
    assert np.percentile(installed, 90) < 0.01 and np.percentile(bench, 90) > 0.04
    points = np.asarray(read_static(folder / "ins.rrd", "/installed/installed/samples", "Points3D:positions"))
    np.testing.assert_allclose(np.linalg.norm(points.reshape(-1, 3), axis=1), 1.0, atol=0.02)
