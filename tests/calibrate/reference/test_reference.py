"""Seed 003's K-matrix calibration: a hand-worked case, simulated truth, degenerate fields, arrays, CLI."""

import json

import numpy as np
import pytest

from calibrate.contract import CannotCalibrate as DegenerateReference
from calibrate.reference import calibrate_reference
from compass.cli import main
from tests.conftest import assert_calibrate_refuses
from compass.io.reference import read_reference
from compass.sim.reference import simulate_reference, write_reference
from compass.calibration import load as load_calibration


def record(tmp_path, name="ref.csv", **kwargs):
    sim = simulate_reference(**kwargs)
    path, _ = write_reference(sim, tmp_path / name)
    return sim, path


def test_hand_worked_axis_angles(tmp_path):
    # one sensor: x axis tipped 2 deg toward y, scales 2, 1, 1, offsets (1, 2, 3); no noise
    t = np.radians(2.0)
    g = np.array([[2 * np.cos(t), 2 * np.sin(t), 0.0], [0, 1, 0], [0, 0, 1]])
    ref = np.array([[10, 0, 0], [0, 10, 0], [0, 0, 10], [-10, -10, -10], [5, -5, 5.0]])
    out = ref @ g.T + [1, 2, 3]
    rows = "\n".join(",".join(f"{v:.10f}" for v in r) for r in np.hstack([ref, out]))
    (tmp_path / "hand.csv").write_text("bx_ref,by_ref,bz_ref,mx,my,mz\n" + rows + "\n")
    (s,) = calibrate_reference(read_reference(tmp_path / "hand.csv")).sensors
    np.testing.assert_allclose(s.scale, [2, 1, 1], atol=1e-9)
    np.testing.assert_allclose(s.angles_deg[0], [2.0, 88.0, 90.0], atol=1e-6)  # alpha1..3
    np.testing.assert_allclose(s.angles_deg[1:], [[90, 0, 90], [90, 90, 0]], atol=1e-6)
    np.testing.assert_allclose(s.offset, [1, 2, 3], atol=1e-9)
    np.testing.assert_allclose(s.k_matrix @ g, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(s.geometry[3], -2.0, atol=1e-6)  # 88 deg between x and y axes


def test_array_recovers_truth_within_sigma(tmp_path):
    sim, path = record(tmp_path, seed=21, n_sensors=3, n_fields=30, noise=0.05)
    res = calibrate_reference(read_reference(path))
    assert [s.name for s in res.sensors] == ["s1", "s2", "s3"]
    for s in res.sensors:
        t = sim.truth["sensors"][s.name]
        g_true = np.array(t["G"])
        k_true = np.linalg.inv(g_true)
        assert np.all(np.abs(s.k_matrix - k_true) < 4.5 * s.k_sigma)
        assert np.all(np.abs(s.offset - t["offset"]) < 4.5 * s.offset_sigma)
        scale_true = np.linalg.norm(g_true, axis=1)
        angles_true = np.degrees(np.arccos(g_true / scale_true[:, None]))
        assert np.all(np.abs(s.scale - scale_true) < 4.5 * s.scale_sigma)
        assert np.all(np.abs(s.angles_deg - angles_true) < 4.5 * s.angles_sigma_deg)
        # residual rms at the injected noise (dof-corrected); 30 fields give ~13 % scatter per channel
        np.testing.assert_allclose(np.mean(s.residual_rms), sim.truth["noise"], rtol=0.25)
    # brought into the common frame: every sensor now reads the reference fields
    assert res.spread < 3 * sim.truth["noise"]


def test_doubling_noise_doubles_sigma(tmp_path):
    _, a = record(tmp_path, "a.csv", seed=22, n_fields=40, noise=0.05)
    _, b = record(tmp_path, "b.csv", seed=22, n_fields=40, noise=0.10)
    sa, sb = (calibrate_reference(read_reference(p)).sensors[0] for p in (a, b))
    np.testing.assert_allclose(np.median(sb.k_sigma / sa.k_sigma), 2.0, rtol=0.05)


def test_coplanar_fields_are_refused(tmp_path):
    _, path = record(tmp_path, seed=23, fields="coplanar")
    with pytest.raises(DegenerateReference, match="coplanar"):
        calibrate_reference(read_reference(path))


def test_four_fields_fit_exactly_and_say_so(tmp_path):
    _, path = record(tmp_path, seed=24, n_fields=4, n_sensors=1)
    res = calibrate_reference(read_reference(path))
    assert res.sensors[0].k_sigma is None and "exactly 4" in res.warnings[0]


def test_cli_end_to_end_and_runtime_model(tmp_path, capsys):
    sim, path = record(tmp_path, seed=25, n_sensors=2, n_fields=20)
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(path), "--out", str(cal)]) == 0
    assert "alpha1..3" in capsys.readouterr().out
    data = json.loads(cal.read_text())
    assert set(data["reference"]["sensors"]) == {"s1", "s2"} and data["method"] == "reference"
    for key in ("dip_deg", "dip_sigma_deg", "field_ut", "effects", "diagnosis"):
        assert key in data
    assert data["diagnosis"]["effects"] == [] and data["diagnosis"]["steps"][0]["model"] == "base"
    for ch in data["channels"].values():  # SPEC section 2: every channel reports seed 000's angles
        a = np.radians([ch[k] for k in ("theta_deg", "gamma_deg", "elevation_deg", "psi_deg")])
        assert np.isclose(np.tan(a[2]), np.tan(a[1]) * np.cos(a[0]))
        assert np.isclose(np.tan(a[3]), np.tan(a[0]) * np.cos(a[1]))
    model = load_calibration(cal).model
    raw = np.hstack([sim.outputs["s1"], sim.outputs["s2"]])
    field, _ = model.field(raw)
    assert np.sqrt(np.mean((field - sim.reference) ** 2)) < 3 * sim.truth["noise"]


@pytest.mark.parametrize(
    "text, expected",
    [
        ("bx_ref,by_ref,bz_ref,mx,my,mz\n" + "1,0,0,1,2,3\n0,1,0,1,2,3\n0,0,1,1,2,3\n", "at least 4"),
        ("bx_ref,by_ref,bz_ref,s1_x,s1_y\n1,0,0,1,2\n", "column 's1_z'"),
        ("bx_ref,by_ref,bz_ref,mx,my,mz,volts\n1,0,0,1,2,3,4\n", "at least 4"),  # volts ignored, with a warning
        ("bx_ref,by_ref,bz_ref,mx,my,mz\n" + "".join(f"{i},{2 * i},{3 * i},{i},{i % 2},{i % 3}\n" for i in range(6)),
         "one line"),
        ("bx_ref,by_ref,bz_ref,mx,my,mz\n" + "".join(f"{i},{i % 2},0,{i},{i % 2},{i % 3}\n" for i in range(6)),
         "coplanar"),
        ("bx_ref,by_ref,bz_ref,mx,my,mz\n1,0,0,1,2,3\n0,1,0,1,2,?\n", "row 3, column 'mz'"),
    ],
)
def test_bad_recordings_exit_2(tmp_path, capsys, text, expected):
    assert_calibrate_refuses(tmp_path, capsys, text, expected)
