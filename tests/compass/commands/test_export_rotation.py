"""The rotation ArduPilot's and MotionCal's symmetric matrices leave out: its heading cost is said at the
calibration's dip (more than its angle: a tilt of the field's frame moves the vertical field into the
horizontal plane), and one ``--max-rotation-deg`` limit refuses a larger one for both, naming Fusion."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from compass.cli import main
from compass.commands._export_form import heading_cost_deg
from compass.io.motioncal import decode_packet
from tests.compass.commands.test_export_axes import ardupilot_field, bench, fields, heading_deg, sensor_xyz

DIP_DEG = 60.0  # the bench calibrations' own dip (test_export_axes.bench)


@pytest.mark.parametrize("dip_deg", [0.0, 50.0, 65.0, 75.0])
@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 0, 1), (0.6, 0.0, 0.8), (0.3, -0.5, 0.2)])
def test_the_heading_cost_is_the_first_order_law_never_the_angle_alone(axis, dip_deg):
    """delta h = theta (n_z + tan(dip) n_h cos(psi - psi_n)): up to theta (|n_z| + n_h tan dip), below
    theta (1 + tan dip)."""
    n = np.asarray(axis, float) / np.linalg.norm(axis)
    theta = np.radians(0.05)  # small: the second order is 1e-3 of the first
    rms, worst = heading_cost_deg(Rotation.from_rotvec(theta * n).as_matrix(), dip_deg)
    t, n_h = np.tan(np.radians(dip_deg)), np.hypot(n[0], n[1])
    law_max = np.degrees(theta) * (abs(n[2]) + n_h * t)
    law_rms = np.degrees(theta) * np.sqrt(n[2] ** 2 + (n_h * t) ** 2 / 2)
    np.testing.assert_allclose([rms, worst], [law_rms, law_max], rtol=2e-3, atol=np.degrees(theta ** 2))  # 2nd order
    assert worst <= np.degrees(theta) * (1 + t) * (1 + 1e-9)


def _turned(tmp_path, angle_deg, axis=(1.0, 0.3, 0.0)):
    """A bench of channels mx, my, mz whose axes are turned ``angle_deg`` off the housing's."""
    turn = Rotation.from_rotvec(np.radians(angle_deg) * np.asarray(axis) / np.linalg.norm(axis))
    return bench(tmp_path, ("mx", "my", "mz"), turn.apply(np.eye(3)))


def test_ardupilot_states_the_heading_its_left_out_rotation_costs_and_it_is_what_the_firmware_makes(tmp_path, capsys):
    cal = _turned(tmp_path, 0.76)
    assert main(["export", str(cal), "--format", "ardupilot"]) == 0
    captured = capsys.readouterr()
    comment = next(line for line in captured.out.splitlines() if line.startswith("# not exported"))
    stated = float(comment.split("costs up to ")[1].split(" deg")[0])
    b = fields(360, DIP_DEG)
    error = (heading_deg(ardupilot_field(captured.out, sensor_xyz(cal, b))) - heading_deg(b) + 180) % 360 - 180
    assert stated == pytest.approx(np.max(np.abs(error)), abs=0.01) and stated > 1.5 * 0.76
    assert f"at the calibration's dip {DIP_DEG:.1f} deg" in comment and "left out:" in captured.err


@pytest.mark.parametrize("fmt", ["ardupilot", "motioncal"])
def test_one_limit_refuses_a_larger_rotation_for_both_symmetric_forms_naming_fusion(tmp_path, capsys, fmt):
    cal = _turned(tmp_path, 3.0)
    out = tmp_path / "out"
    assert main(["export", str(cal), "--format", fmt, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is 3.00 deg" in err[0] and "--format fusion" in err[0]
    assert "costs up to" in err[0] and not out.exists()
    assert main(["export", str(cal), "--format", fmt, "--out", str(out), "--max-rotation-deg", "4"]) == 0
    if fmt == "motioncal":  # what was left out is what the device then makes of the field
        packet = decode_packet(out.read_bytes())
        b = fields(360, DIP_DEG)
        got = (sensor_xyz(cal, b) - packet.hard_iron_ut) @ packet.soft_iron.T
        error = (heading_deg(got) - heading_deg(b) + 180) % 360 - 180
        words = capsys.readouterr().err
        stated = float(words.split("costs up to ")[1].split(" deg")[0])
        assert stated == pytest.approx(np.max(np.abs(error)), abs=0.01)
    assert main(["export", str(cal), "--format", "fusion"]) == 0  # Fusion folds it in
